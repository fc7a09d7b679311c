"""The README stays short enough to read in minutes, and no link in the README or the docs
points at a file that is not there (pages move; a dead link is found here, not by a reader)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MAX_README_LINES = 200

# [text](target) and ![alt](target); the target ends at whitespace (an optional "title") or ")".
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^```.*?^```", flags=re.S | re.M)


def pages() -> list[Path]:
    return [README, *sorted((ROOT / "docs").rglob("*.md"))]


def local_targets(text: str) -> list[str]:
    """The relative file targets of the links in markdown ``text``: code blocks, web and mail
    links and links to an anchor of the same page left out, ``#anchor`` parts cut off."""
    targets = []
    for target in LINK.findall(FENCE.sub("", text)):
        if re.match(r"[a-zA-Z][\w+.-]*:", target) or target.startswith("#"):
            continue
        targets.append(target.split("#", 1)[0])
    return targets


def broken_links(page: Path) -> list[str]:
    return [t for t in local_targets(page.read_text()) if not (page.parent / t).exists()]


def test_the_readme_is_short_and_has_the_two_commands():
    text = README.read_text()
    assert len(text.splitlines()) <= MAX_README_LINES
    assert "make train" in text and "make test" in text


def test_the_link_finder_finds_links_and_skips_the_rest():
    text = ("see [a](pages/a.md#part) and ![b](b.png \"title\"), [web](https://x.org/y) "
            "[mail](mailto:a@b.c) [here](#top)\n```\n[code](not/a/link.md)\n```\n")
    assert local_targets(text) == ["pages/a.md", "b.png"]


def test_every_relative_link_resolves():
    broken = {str(p.relative_to(ROOT)): bad for p in pages() if (bad := broken_links(p))}
    assert not broken, broken
