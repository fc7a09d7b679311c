"""What a start on the expert's path costs an actor (the backward curriculum).

Per task: the expert's solution length, the time to plan it unrendered (``expert.solve``), the
time of a start (reset from the seed and fast-forward to the middle of the solution), the cost
per episode once a plan serves ``SOLUTION_REUSE`` episodes, and the time of one rendered
environment step for scale (so the cost reads as "about as much as N agent steps"). One process,
the same seeds for every figure.

`python -m dqn_mine.bench --only starts [--quick]`.
"""

from __future__ import annotations

import statistics
import time

TASKS = [
    ("two-room", {"task": "two-room"}),
    ("three-room", {"task": "three-room"}),
    ("rooms, 4 rooms", {"task": "rooms", "num_rooms": 4}),
    ("rooms, 5 rooms", {"task": "rooms", "num_rooms": 5}),
]


def measure(kwargs: dict, episodes: int) -> dict:
    from dqn_mine.env import MineRescueEnv
    from dqn_mine.env.expert import solve

    env = MineRescueEnv(**kwargs)
    limit = env.max_episode_steps
    lengths, plan_s, start_s = [], [], []
    for seed in range(1000, 1000 + episodes):
        t0 = time.perf_counter()
        actions = solve(env, seed, limit)
        t1 = time.perf_counter()
        env.reset(seed=seed)
        env.fast_forward(actions[:len(actions) // 2])
        t2 = time.perf_counter()
        lengths.append(len(actions))
        plan_s.append(t1 - t0)
        start_s.append(t2 - t1)
    t0 = time.perf_counter()
    for i in range(2000):
        env.step(2 + i % 2)       # turns: a rendered step that never ends the episode
    step_s = (time.perf_counter() - t0) / 2000
    env.close()
    return {"length": statistics.mean(lengths), "plan_ms": 1e3 * statistics.mean(plan_s),
            "start_ms": 1e3 * statistics.mean(start_s), "step_ms": 1e3 * step_s}


def run(quick: bool = False) -> str:
    from dqn_mine.system.backward import SOLUTION_REUSE

    episodes = 5 if quick else 20
    lines = ["## Starts on the expert's path (backward curriculum)\n",
             f"{episodes} episodes per task, one process; a plan serves {SOLUTION_REUSE} "
             "episodes.\n",
             "| task | solution (steps) | plan (ms) | start: reset + fast-forward half (ms) | "
             "per episode (ms) | one rendered step (ms) | per episode, in rendered steps |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name, kwargs in TASKS:
        m = measure(kwargs, episodes)
        per_episode = m["plan_ms"] / SOLUTION_REUSE + m["start_ms"]
        lines.append(f"| {name} | {m['length']:.0f} | {m['plan_ms']:.0f} | "
                     f"{m['start_ms']:.1f} | {per_episode:.1f} | {m['step_ms']:.2f} | "
                     f"{per_episode / m['step_ms']:.0f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(run(quick=True))
