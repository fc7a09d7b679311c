"""The README's library examples run as written (SB3's is skipped without stable-baselines3)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def examples() -> dict:
    """The python blocks of the 'From Stable-Baselines3 or CleanRL' section, by first line."""
    text = README.read_text()
    section = text.split("### From Stable-Baselines3 or CleanRL", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    return {block.splitlines()[0]: block for block in blocks}


def test_the_section_has_both_examples():
    firsts = list(examples())
    assert len(firsts) == 2 and "Stable-Baselines3" in firsts[0] and "CleanRL" in firsts[1]


def test_stable_baselines3_example():
    pytest.importorskip("stable_baselines3")
    scope: dict = {}
    exec(compile(next(iter(examples().values())), "README-sb3", "exec"), scope)
    assert scope["model"].num_timesteps >= 600 and 0 <= int(scope["action"]) < 6


def test_cleanrl_style_vector_example():
    scope: dict = {}
    exec(compile(list(examples().values())[1], "README-cleanrl", "exec"), scope)
    assert scope["obs"].shape == (4, 3, 44, 76) and scope["obs"].dtype.name == "uint8"
    assert scope["carrying"].shape == (4,)
