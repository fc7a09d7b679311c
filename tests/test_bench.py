"""The benchmarks' own arithmetic and the GPU check's behaviour on a machine without CUDA."""

import subprocess
import sys

import pytest
import torch

from dqn_mine.agent.network import DuelingQNetwork
from dqn_mine.bench.gpu_check import summary_markdown
from dqn_mine.bench.learner import forward_flops, side_by_side, update_flops

# One frame's forward pass by hand (multiply-adds x 2): conv 3->32 8x8 on a 10x18 output, conv
# 32->64 4x4 on 4x8, conv 64->64 3x3 on 2x6, two streams of 889->128 and 128->1 / 128->6.
CONV1 = 2 * 3 * 8 * 8 * 32 * 10 * 18
CONVS = CONV1 + 2 * 32 * 4 * 4 * 64 * 4 * 8 + 2 * 64 * 3 * 3 * 64 * 2 * 6
LINEARS = 2 * (889 * 128) * 2 + 2 * 128 * 1 + 2 * 128 * 6


def test_flop_count_matches_the_layer_shapes_by_hand():
    net = DuelingQNetwork()
    assert forward_flops(net) == {"conv": CONVS, "linear": LINEARS}
    f = CONVS + LINEARS
    # three forward passes, weight gradients (= one forward) and input gradients (one forward
    # less the first layer's, whose input needs none), per sample
    assert update_flops(net, 32) == 32 * (4 * f + f - CONV1)


def test_side_by_side_times_every_variant_in_turns():
    calls = {"a": 0, "b": 0}

    def make(name):
        def step():
            calls[name] += 1
        return step

    rates = side_by_side({"a": make("a"), "b": make("b")}, seconds=0.01, rounds=3)
    assert set(rates) == {"a", "b"} and all(r > 0 for r in rates.values())
    assert calls["a"] > 10 and calls["b"] > 10


def test_gpu_check_summary_lists_figures_and_failures():
    figures = {"machine": "m", "learner": {"device": "H200", "rows": [
        {"batch": 32, "precision": "bfloat16", "updates_per_s": 812.4}]},
        "render": {"error": "RuntimeError: no EGL device"}}
    text = summary_markdown(figures)
    assert "| 32 | bfloat16 | 812 |" in text
    assert "**render failed**: RuntimeError: no EGL device" in text


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the no-CUDA answer")
def test_gpu_check_without_cuda_says_so_in_one_line_and_exits_0(tmp_path):
    res = subprocess.run([sys.executable, "-m", "dqn_mine.bench.gpu_check", "--out",
                          str(tmp_path / "g")], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0
    lines = res.stdout.strip().splitlines()
    assert len(lines) == 1 and "no CUDA" in lines[0]
    assert not (tmp_path / "g").exists()        # nothing half-written
