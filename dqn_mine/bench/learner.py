"""Learner and actor-network throughput on synthetic data (no environment, no replay).

- learner: :class:`DQNUpdater` updates/s (forward on s and s', target, backward, Adam) at batch
  32, 64 and 256, with 1 and 2 torch threads, the plain float32 update (the reference) and the
  bfloat16 path side by side: the variants take turns in short rounds and each figure is the
  median over rounds, so a noisy neighbour on a shared machine slows both alike. Each row also
  gives the compute rate the update reaches, against the core's limit measured the same way (a
  2048 x 2048 matrix product in the same dtype and threads);
- actor: batched ``inference_mode`` forward passes per second at batch 1, 4, 8, 16, 32 (one env
  step per row), with one torch thread (what actor processes use), float32 and bfloat16 weights.

`python -m dqn_mine.bench --only learner [--quick]`.
"""

from __future__ import annotations

import os
import statistics
import time
from typing import Callable

import numpy as np
import torch
from torch import nn

from dqn_mine.agent.learning import DQNUpdater, batch_to_device
from dqn_mine.agent.network import DuelingQNetwork, lower_heavy_layers
from dqn_mine.config import native_bf16
from dqn_mine.replay import Batch


def synthetic_batch(b: int, history_len: int = 20, seed: int = 0) -> Batch:
    rng = np.random.default_rng(seed)
    frames = lambda: rng.integers(0, 256, (b, 3, 44, 76), dtype=np.uint8)  # noqa: E731
    hist = lambda: rng.integers(-1, 6, (b, history_len)).astype(np.int8)  # noqa: E731
    return Batch(frames(), hist(), np.zeros(b, np.float32), rng.integers(0, 6, b),
                  rng.random(b).astype(np.float32), np.full(b, 0.99 ** 6, np.float32),
                  frames(), hist(), np.zeros(b, np.float32), np.ones(b, np.float32),
                  np.arange(b))


def rate(step: Callable[[], None], seconds: float, warmup: int = 3, sync=lambda: None) -> float:
    """Calls of ``step`` per second, timed for about ``seconds`` after ``warmup`` calls."""
    for _ in range(warmup):
        step()
    sync()
    n, start = 0, time.perf_counter()
    while n < 3 or time.perf_counter() - start < seconds:
        step()
        n += 1
    sync()
    return n / (time.perf_counter() - start)


def side_by_side(steps: dict[str, Callable[[], None]], seconds: float, rounds: int,
                 sync=lambda: None) -> dict[str, float]:
    """Median calls/s of each step, timed in turns (``rounds`` rounds of ``seconds`` each)."""
    for step in steps.values():
        rate(step, 0.05, warmup=3, sync=sync)
    samples: dict[str, list[float]] = {name: [] for name in steps}
    for _ in range(rounds):
        for name, step in steps.items():
            samples[name].append(rate(step, seconds, warmup=1, sync=sync))
    return {name: statistics.median(v) for name, v in samples.items()}


# -- compute accounting ------------------------------------------------------------------------

def _layer_flops(module: nn.Module, output: torch.Tensor) -> float:
    """Multiply-adds x 2 of one conv or linear layer for one frame (``output``: batch of 1)."""
    if isinstance(module, nn.Conv2d):
        k = module.in_channels // module.groups * module.kernel_size[0] * module.kernel_size[1]
        return 2.0 * k * output[0].numel()
    return 2.0 * module.in_features * module.out_features


def _per_layer_flops(net: nn.Module) -> list[tuple]:
    """(layer, FLOPs) of one frame's forward pass, in the order the layers run."""
    layers: list[tuple] = []
    hooks = [m.register_forward_hook(lambda m, i, out: layers.append((m, _layer_flops(m, out))))
             for m in net.modules() if isinstance(m, (nn.Conv2d, nn.Linear))]
    try:
        with torch.no_grad():
            net(torch.zeros(1, *net.obs_shape, dtype=torch.uint8),
                torch.zeros(1, net.history_len, dtype=torch.int8), torch.zeros(1))
    finally:
        for h in hooks:
            h.remove()
    return layers


def forward_flops(net: nn.Module) -> dict[str, float]:
    """Multiply-adds x 2 of one frame's forward pass, per layer kind (convs, linears)."""
    flops = {"conv": 0.0, "linear": 0.0}
    for module, f in _per_layer_flops(net):
        flops["conv" if isinstance(module, nn.Conv2d) else "linear"] += f
    return flops


def update_flops(net: DuelingQNetwork, batch_size: int) -> float:
    """FLOPs of one update: three forward passes (online on s and s', target on s'), and a
    backward pass of the one on s: weight gradients (as much as its forward) and input gradients
    (as much again, except for the first layer, whose input needs none)."""
    layers = _per_layer_flops(net)
    forward = sum(f for _, f in layers)
    first = layers[0][1]
    return batch_size * (3 * forward + forward + (forward - first))


def gemm_limit(dtype: torch.dtype, n: int = 2048, seconds: float = 1.0) -> float:
    """FLOP/s of a large matrix product in ``dtype`` with the current torch threads."""
    a = torch.rand(n, n).to(dtype)
    b = torch.rand(n, n).to(dtype)
    return rate(lambda: a @ b, seconds, warmup=2) * 2.0 * n ** 3


def _updater(precision: str, device: str) -> DQNUpdater:
    torch.manual_seed(0)
    return DQNUpdater(DuelingQNetwork(), lr=3e-5, device=device, max_grad_norm=40.0,
                      precision=precision)


def _update_step(updater: DQNUpdater, host: Batch, device: str) -> Callable[[], None]:
    # Each update copies a host batch to the device (as the learner does), then reads td_abs back.
    return lambda: updater.update(batch_to_device(host, device))


def learner_rates(precisions: list[str], batch_size: int, device: str, seconds: float,
                  rounds: int) -> dict[str, float]:
    """Updates/s of each precision's update at ``batch_size``, timed side by side."""
    host = synthetic_batch(batch_size)
    steps = {p: _update_step(_updater(p, device), host, device) for p in precisions}
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    return side_by_side(steps, seconds, rounds, sync)


def learner_rate(batch_size: int, device: str, seconds: float, warmup: int = 3,
                 precision: str = "float32") -> float:
    host = synthetic_batch(batch_size)
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    return rate(_update_step(_updater(precision, device), host, device), seconds, warmup, sync)


def _spin(stop) -> None:
    while not stop.is_set():
        sum(range(10_000))


def contended_learner_rate(threads: int, seconds: float, precision: str = "float32") -> float:
    """Batch-32 updates/s while one other process keeps a core busy (as an actor does)."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    proc = ctx.Process(target=_spin, args=(stop,), daemon=True)
    proc.start()
    try:
        time.sleep(0.3)
        torch.set_num_threads(threads)
        return learner_rate(32, "cpu", seconds, warmup=1, precision=precision)
    finally:
        stop.set()
        proc.join(5)
        if proc.is_alive():
            proc.kill()


def cpu_precisions() -> list[str]:
    """The reference, plus bfloat16 where this CPU computes it natively."""
    return ["float32", "bfloat16"] if native_bf16() else ["float32"]


def learner_section(quick: bool) -> list[str]:
    seconds, rounds = (0.3, 3) if quick else (0.6, 7)
    cores = os.cpu_count() or 1
    precisions = cpu_precisions()
    per_sample = update_flops(DuelingQNetwork(), 1)
    lines = [
        "## Learner (synthetic batches)\n",
        f"torch {torch.__version__}; an update = double-DQN target, IS-weighted Huber, backward, "
        "Adam with grad-norm clip 40, host->device batch copy, td_abs back to the host. float32 "
        "is the plain update (the reference); bfloat16 computes convolutions and the first head "
        "layers in bfloat16 with float32 master weights, outputs, loss and Adam "
        "(`--precision`). Variants timed in turns, median of "
        f"{rounds} rounds. An update is {per_sample / 1e6:.1f} MFLOP per sample "
        "(3 forward passes + backward); 'limit' = a 2048^2 matrix product in the same dtype "
        "and threads.\n",
        "| device | torch threads | batch | precision | updates/s | ms/update | vs float32 | "
        "GFLOP/s | limit GFLOP/s | limit / reached |",
        "|---|---|---|---|---|---|---|---|---|---|"]
    for threads in sorted({1, min(2, cores)}):
        torch.set_num_threads(threads)
        limits = {p: gemm_limit(getattr(torch, p)) for p in precisions}
        for b in (32, 64, 256):
            rates = learner_rates(precisions, b, "cpu", seconds, rounds)
            for p in precisions:
                lines.append(_row("cpu", threads, b, p, rates, per_sample, limits[p]))
    if cores > 1:
        for threads in sorted({1, cores}):
            for p in precisions:
                r = contended_learner_rate(threads, seconds * 3, p)
                lines.append(f"| cpu, 1 core busy | {threads} | 32 | {p} | {r:.1f} | "
                             f"{1000 / r:.1f} | | | | |")
    if torch.cuda.is_available():
        lines += cuda_rows(per_sample, seconds, rounds)
    lines += ["", "Alone, 2 threads nearly double batch-32 updates; next to one busy process "
              "(an actor) 2 threads can collapse to a few updates/s, far below 1 thread (the "
              "'1 core busy' rows: OpenMP threads wait on each other across a contended "
              "core). Learner: threads = cores the acting processes leave free, at least 1 "
              "(config.learner_threads); actors: 1 thread.\n"]
    return lines


def cuda_rows(per_sample: float, seconds: float, rounds: int) -> list[str]:
    name = torch.cuda.get_device_name()
    precisions = ["float32"] + (["bfloat16"] if torch.cuda.is_bf16_supported() else [])
    lines = []
    for b in (32, 256, 512):
        rates = learner_rates(precisions, b, "cuda", seconds, rounds)
        for p in precisions:
            lines.append(_row(f"cuda ({name})", "-", b, p, rates, per_sample, float("nan")))
    return lines


def _row(device, threads, b: int, precision: str, rates: dict[str, float],
         per_sample: float, limit: float) -> str:
    """``per_sample``: FLOPs of an update per sample (``update_flops(net, 1)``)."""
    r = rates[precision]
    reached = r * per_sample * b
    ratio = limit / reached if limit == limit else float("nan")
    return (f"| {device} | {threads} | {b} | {precision} | {r:.1f} | {1000 / r:.2f} | "
            f"{r / rates['float32']:.2f}x | {reached / 1e9:.0f} | {limit / 1e9:.0f} | "
            f"{ratio:.1f}x |")


def inference_rate(batch: int, seconds: float, dtype=torch.float32) -> float:
    torch.manual_seed(0)
    net = lower_heavy_layers(DuelingQNetwork(), dtype).eval()   # as an actor holds it
    data = synthetic_batch(batch)
    obs, hist, carrying = (torch.from_numpy(data.obs), torch.from_numpy(data.history),
                           torch.from_numpy(data.carrying))

    def step():
        with torch.inference_mode():
            net(obs, hist, carrying).argmax(1).numpy()
    return rate(step, seconds)


def run(quick: bool = False) -> str:
    seconds = 1.5 if quick else 5.0
    saved_threads = torch.get_num_threads()
    try:
        lines = learner_section(quick)
        torch.set_num_threads(1)
        lines += ["## Actor network (batched inference, 1 torch thread)\n",
                  f"bfloat16 weights (--precision): this CPU computes bfloat16 "
                  f"{'natively' if native_bf16() else 'by emulation'}.\n",
                  "| envs per forward | float32 env steps/s | float32 us/frame | "
                  "bfloat16 env steps/s | bfloat16 us/frame | bfloat16 / float32 |",
                  "|---|---|---|---|---|---|"]
        for b in (1, 4, 8, 16, 32):
            r32 = inference_rate(b, seconds) * b
            r16 = inference_rate(b, seconds, torch.bfloat16) * b
            lines.append(f"| {b} | {r32:.0f} | {1e6 / r32:.0f} | {r16:.0f} | {1e6 / r16:.0f} | "
                         f"{r16 / r32:.2f}x |")
    finally:
        torch.set_num_threads(saved_threads)
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(run(quick=True))
