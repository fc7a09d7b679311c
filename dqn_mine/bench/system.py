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

from dqn_mine.config import resolve_actor_precision
from dqn_mine.metrics import read_metrics

# name -> (environment, configurations (actors, envs per actor, --precision)). More envs per
# actor amortise the batched forward pass (bench.learner's inference table); from 8 envs per
# actor, actors act in bfloat16 where the CPU has it (auto). The float32 row is the reference.
TASKS = {
    "the smoke-preset task (one-room 8x8, 200-step limit)": (
        dict(task="one-room", room_size=8.0, max_episode_steps=200),
        ((1, 1, "auto"), (1, 4, "auto"), (1, 16, "auto"), (1, 32, "auto"), (2, 1, "auto"),
         (2, 8, "auto"), (2, 16, "float32"), (2, 16, "auto"))),
    "the study's task (two-room, 16x16 rooms, 2,000-step limit)": (
        dict(task="two-room", room_size=16.0, max_episode_steps=None),
        ((2, 16, "float32"), (2, 16, "auto"))),
}


def bare_env_steps_per_s(env_kwargs: dict, seconds: float) -> float:
    """Random actions in one process, resets included."""
    from dqn_mine.env import MineRescueEnv

    env = MineRescueEnv(**env_kwargs)
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


def pipeline(env_kwargs: dict, actors: int, envs_per_actor: int, precision: str,
             updates: int) -> dict:
    """Steady-state figures of a short smoke-preset training run on the environment given."""
    env_flags = [f"--{k.replace('_', '-')}={'none' if v is None else v}"
                 for k, v in env_kwargs.items()]
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(tmp) / "run"
        cmd = [sys.executable, "-m", "dqn_mine.train", "--preset", "smoke", *env_flags, "--actors",
               str(actors), "--envs-per-actor", str(envs_per_actor), "--updates", str(updates),
               "--precision", precision,
               "--prefill", "500", "--replay-capacity", "65536", "--eval-every", "0",
               "--log-interval", str(max(1, updates // 10)),
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
    updates = 300 if quick else 1500
    lines = ["## System: actors into the replay while the learner trains (CPU)", "",
             f"Learner on CPU with batch 32, {updates} updates per configuration, smoke preset "
             "otherwise. Bare environment: one process, random actions, resets included.", ""]
    for name, (env_kwargs, configs) in TASKS.items():
        bare = bare_env_steps_per_s(env_kwargs, 3.0 if quick else 10.0)
        lines += [f"On {name}: bare environment **{bare:,.0f} steps/s**.", "",
                  "| actors x envs | actor precision | transitions/s into replay | vs bare env | "
                  "learner updates/s | replay ratio |",
                  "|---|---|---:|---:|---:|---:|"]
        for actors, envs, precision in configs:
            fig = pipeline(env_kwargs, actors, envs, precision, updates)
            dtype = str(resolve_actor_precision(precision, envs)).replace("torch.", "")
            lines.append(f"| {actors} x {envs} | {dtype} | {fig['steps_per_s']:,.0f} | "
                         f"{fig['steps_per_s'] / bare:.2f}x | {fig['updates_per_s']:.1f} | "
                         f"{fig['replay_ratio']:.4f} |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
