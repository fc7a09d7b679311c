"""Whole-system throughput: transitions/s the actors deliver into the replay while the learner
trains, and the learner's updates/s in the real pipeline, against the bare environment's steps/s.

Each configuration is a real `python -m dqn_mine.train` run (spawned actors, shared memory);
the figures are the means of its steady-state metrics rows (the first rows are dropped).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dqn_mine.metrics import read_metrics

ENV = dict(task="one-room", room_size=8.0, max_episode_steps=200)  # the smoke preset's task
# (actors, envs per actor). More envs per actor amortise the batched forward pass: on one core the
# network costs ~540 us for 1 frame but ~110 us per frame at 16 (bench.learner's inference table).
CONFIGS = ((1, 1), (1, 4), (1, 16), (2, 1), (2, 8))


def bare_env_steps_per_s(seconds: float) -> float:
    """Random actions in one process, resets included."""
    from dqn_mine.env import MineRescueEnv

    env = MineRescueEnv(**ENV)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for action in rng.integers(0, 6, 256):
            _, _, terminated, truncated, _ = env.step(int(action))
            if terminated or truncated:
                env.reset()
        steps += 256
    rate = steps / (time.perf_counter() - start)
    env.close()
    return rate


def pipeline(actors: int, envs_per_actor: int, updates: int) -> dict:
    """Steady-state figures of a short smoke-preset training run."""
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(tmp) / "run"
        cmd = [sys.executable, "-m", "dqn_mine.train", "--preset", "smoke", "--actors",
               str(actors), "--envs-per-actor", str(envs_per_actor), "--updates", str(updates),
               "--prefill", "500", "--replay-capacity", "65536", "--eval-every", "0",
               "--log-interval", str(max(1, updates // 10)), "--no-progress",
               "--run-dir", str(run_dir)]
        res = subprocess.run(cmd, capture_output=True, text=True)
        if res.returncode != 0:
            raise RuntimeError(f"benchmark run failed: {res.stderr.strip().splitlines()[-1]}")
        rows = read_metrics(run_dir / "metrics.csv")[2:]
        summary = json.loads((run_dir / "summary.json").read_text())
    return {"steps_per_s": float(np.mean([r["env_steps_per_s"] for r in rows])),
            "updates_per_s": float(np.mean([r["updates_per_s"] for r in rows])),
            "replay_ratio": summary["replay_ratio"]}


def run(quick: bool = False) -> str:
    bare = bare_env_steps_per_s(3.0 if quick else 10.0)
    updates = 300 if quick else 1500
    lines = [
        "## System: actors into the replay while the learner trains (CPU)",
        "",
        f"Smoke-preset task (one-room 8x8, 200-step limit), learner on CPU with batch 32, "
        f"{updates} updates per configuration. Bare environment, one process, random actions: "
        f"**{bare:,.0f} steps/s**.",
        "",
        "| actors x envs | transitions/s into replay | vs bare env | learner updates/s | "
        "replay ratio |",
        "|---|---:|---:|---:|---:|",
    ]
    for actors, envs in CONFIGS:
        fig = pipeline(actors, envs, updates)
        lines.append(f"| {actors} x {envs} | {fig['steps_per_s']:,.0f} | "
                     f"{fig['steps_per_s'] / bare:.2f}x | {fig['updates_per_s']:.1f} | "
                     f"{fig['replay_ratio']:.4f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
