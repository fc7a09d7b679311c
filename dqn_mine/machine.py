"""What machine a run ran on, and what the ``auto`` settings chose there.

Minutes to a return are only comparable between runs on like machines: one held-out run of the
`cpu` preset ran on a VM without AVX-512 (float32 matrix products at half the speed, bfloat16
emulated) and made half the updates per second of the others, which nothing in its run folder
said. Each start of a run (a new run or a resume) appends one line to ``machine.jsonl``.
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

# CPU flags that decide which precision ``auto`` picks and how fast the network runs
FLAGS = ("avx2", "avx512f", "avx512_bf16", "amx_bf16", "bf16")
GEMM_SIZE = 512   # square float32 matrix product timed as a one-number speed of a core


def cpu_model(cpuinfo: str = "/proc/cpuinfo") -> tuple[str, list[str]]:
    """The CPU's model name and which of ``FLAGS`` it has (empty where /proc/cpuinfo is not)."""
    try:
        text = Path(cpuinfo).read_text()
    except OSError:
        return platform.processor() or "unknown", []
    name = next((line.split(":", 1)[1].strip() for line in text.splitlines()
                 if line.startswith("model name")), "unknown")
    flags = set(text.split())
    return name, [f for f in FLAGS if f in flags]


def single_thread_inference() -> None:
    """One torch thread for a process that plays one frame at a time (evaluate, play).

    A batch-1 forward pass gains nothing from a second thread (two 2,000-step evaluation
    episodes: 4.2 s with two threads, 4.4 s with one, on an idle 2-core VM), but the thread team
    then waits for both cores: beside one busy process the same episodes took 52-75 s with two
    threads and 4.4 s with one, and a niced evaluation beside a training run had not finished
    after 20 minutes."""
    import torch

    torch.set_num_threads(1)


def gemm_gflops(seconds: float = 0.2) -> float:
    """float32 GFLOP/s of one thread on a GEMM_SIZE^2 matrix product (about 0.2 s)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        a = torch.rand(GEMM_SIZE, GEMM_SIZE)
        a @ a  # warm-up
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            a @ a
            n += 1
        return 2 * GEMM_SIZE ** 3 * n / (time.perf_counter() - t0) / 1e9
    finally:
        torch.set_num_threads(threads)


def describe(cfg) -> dict:
    """This machine and the settings ``cfg`` resolves to on it."""
    import torch

    from dqn_mine.config import resolve_actor_precision, resolve_device, resolve_learner_precision

    device = resolve_device(cfg.device)
    name, flags = cpu_model()
    record = {
        "time": time.strftime("%Y-%m-%d %H:%M:%S"),
        "host": platform.node(),
        "cpu": name,
        "cpu_flags": flags,
        "cores": os.cpu_count(),
        "gemm_float32_gflops_1_thread": round(gemm_gflops(), 1),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "device": str(device),
        "gpu": torch.cuda.get_device_name(0) if device.type == "cuda" else None,
        "learner_precision": resolve_learner_precision(cfg.precision, device),
        "actor_precision": str(resolve_actor_precision(cfg.precision,
                                                       cfg.envs_per_actor)).replace("torch.", ""),
    }
    return record


def record(cfg, run_dir) -> dict:
    """Append this start's machine record to ``run_dir/machine.jsonl`` and return it."""
    entry = describe(cfg)
    with open(Path(run_dir) / "machine.jsonl", "a") as f:
        f.write(json.dumps(entry) + "\n")
    return entry
