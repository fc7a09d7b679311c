"""Learner and actor-network throughput on synthetic data (no environment, no replay).

- learner: :class:`DQNUpdater` updates/s (forward on s and s', target, backward, Adam) at batch 32
  and 256, for each torch thread count up to the machine's cores, CPU and (when present) CUDA;
- actor: batched ``inference_mode`` forward passes per second at batch 1, 4, 8, 16, 32 (one env
  step per row), with one torch thread (what actor processes use), float32 and bfloat16 weights.

`python -m dqn_mine.bench --only learner [--quick]`.
"""

from __future__ import annotations

import os
import time
from typing import Callable, List

import numpy as np
import torch

from dqn_mine.agent.learning import DQNUpdater, batch_to_device
from dqn_mine.agent.network import DuelingQNetwork
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


def _spin(stop) -> None:
    while not stop.is_set():
        sum(range(10_000))


def contended_learner_rate(threads: int, seconds: float) -> float:
    """Batch-32 updates/s while one other process keeps a core busy (as an actor does)."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    proc = ctx.Process(target=_spin, args=(stop,), daemon=True)
    proc.start()
    try:
        time.sleep(0.3)
        torch.set_num_threads(threads)
        return learner_rate(32, "cpu", seconds, warmup=1)
    finally:
        stop.set()
        proc.join(5)
        if proc.is_alive():
            proc.kill()


def learner_rate(batch_size: int, device: str, seconds: float, warmup: int = 3) -> float:
    torch.manual_seed(0)
    updater = DQNUpdater(DuelingQNetwork(), lr=3e-5, device=device, max_grad_norm=40.0)
    host = synthetic_batch(batch_size)
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    # Each update copies a host batch to the device (as the learner does), then reads td_abs back.
    return rate(lambda: updater.update(batch_to_device(host, device)), seconds, warmup, sync)


def inference_rate(batch: int, seconds: float, dtype=torch.float32) -> float:
    torch.manual_seed(0)
    net = DuelingQNetwork().to(dtype).eval()   # as an actor holds it (--actor-precision)
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
    cores = os.cpu_count() or 1
    thread_counts = sorted({1, min(2, cores), min(4, cores)} if quick else {1, 2, 4, cores})
    thread_counts = [t for t in thread_counts if t <= cores]
    lines: List[str] = [
        "## Learner (synthetic batches)\n",
        f"torch {torch.__version__}; an update = double-DQN target, IS-weighted Huber, backward, "
        "Adam with grad-norm clip 40, host->device batch copy, td_abs back to the host.\n",
        "| device | torch threads | batch | updates/s | ms/update | transitions/s |",
        "|---|---|---|---|---|---|"]
    try:
        for threads in thread_counts:
            torch.set_num_threads(threads)
            for b in (32, 256):
                r = learner_rate(b, "cpu", seconds)
                lines.append(f"| cpu | {threads} | {b} | {r:.1f} | {1000 / r:.1f} | {r * b:.0f} |")
        if cores > 1:
            for threads in sorted({1, cores}):
                r = contended_learner_rate(threads, seconds)
                lines.append(f"| cpu, 1 core busy | {threads} | 32 | {r:.1f} | {1000 / r:.1f} | "
                             f"{r * 32:.0f} |")
        if torch.cuda.is_available():
            name = torch.cuda.get_device_name()
            for b in (32, 256):
                r = learner_rate(b, "cuda", seconds)
                lines.append(f"| cuda ({name}) | - | {b} | {r:.1f} | {1000 / r:.2f} | "
                             f"{r * b:.0f} |")
        lines += ["", "Alone, 2 threads nearly double batch-32 updates; next to one busy process "
                  "(an actor) 2 threads can collapse to a few updates/s, far below 1 thread (the "
                  "'1 core busy' rows: OpenMP threads wait on each other across a contended "
                  "core). Learner: threads = cores the acting processes leave free, at least 1 "
                  "(Config.learner_threads 0 = auto); actors: 1 thread.\n"]
        torch.set_num_threads(1)
        lines += ["## Actor network (batched inference, 1 torch thread)\n",
                  f"bfloat16 weights (--actor-precision): this CPU computes bfloat16 "
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
