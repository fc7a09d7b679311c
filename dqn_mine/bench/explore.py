"""Exploration: how often each exploring policy reaches each sub-goal of every task.

For every task, a number of episodes (300 by default) of each policy, counting the share of
episodes that ever

- move a boulder (pick one up from its doorway),
- enter another room than the start room,
- pick the kit up (phases that start carrying it count from the first pick-up after a drop),
- deliver the kit (the only reward),

the share of steps in which the agent neither moved nor turned ("idle": blocked by a wall or an
entity, an interaction, a no-op), and the steps to the first reward of the rewarded episodes.
Policies:

- ``uniform``: a uniform random action each step;
- ``ez-uniform``: uniform random actions held for zeta-distributed durations (mu 2, up to 100);
- ``fresh eps=0.01``: a freshly initialised network acting epsilon-greedily (the study's actors);
- ``fresh Ape-X``: the same network, episodes spread over the Ape-X epsilons of 7 actors;
- ``fresh ez eps=0.01`` etc.: the same with temporally extended random actions;
- ``... unstick``: the same, with a random action after every step that left the frame unchanged;
- ``bump-and-press``: a scripted walker, the yardstick (``dqn_mine.agent.explore.BumpAndPress``;
  ``--prefill-explorer bump-and-press`` lets it act during the replay's pre-fill).

``python -m dqn_mine.bench.explore --tasks two-room --policies uniform --quick`` measures a part.

`python -m dqn_mine.bench --only explore [--quick]`; the measurement is deterministic given
``seed`` (env seeds, network init and action noise all derive from it).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

TASKS = [
    ("one-room", {"task": "one-room"}),
    ("two-room", {"task": "two-room"}),
    ("three-room", {"task": "three-room"}),
    ("rooms, 4 rooms", {"task": "rooms", "num_rooms": 4}),
]
SUBGOALS = ("boulder moved", "room entered", "kit picked up", "delivered")


@dataclass(frozen=True)
class Policy:
    name: str
    network: bool            # greedy actions from a fresh network (else: no greedy part)
    epsilon: str             # "1", "0.01" or "apex" (the Ape-X epsilons of 7 actors)
    durations: bool          # ez-greedy: random actions held for zeta-distributed durations
    unstick: bool = False    # a random action after every step that left the frame unchanged
    scripted: bool = False   # BumpAndPress instead of (epsilon-)greedy acting


POLICIES = {p.name: p for p in [
    Policy("uniform", False, "1", False),
    Policy("ez-uniform", False, "1", True),
    Policy("fresh eps=0.01", True, "0.01", False),
    Policy("fresh Ape-X", True, "apex", False),
    Policy("fresh ez eps=0.01", True, "0.01", True),
    Policy("fresh ez Ape-X", True, "apex", True),
    Policy("fresh eps=0.01 unstick", True, "0.01", False, True),
    Policy("fresh ez Ape-X unstick", True, "apex", True, True),
    Policy("bump-and-press", False, "1", False, scripted=True),
]}


def _epsilons(policy: Policy, num_envs: int) -> np.ndarray:
    from dqn_mine.agent.learning import epsilon_for_actor

    if policy.epsilon == "apex":
        return np.array([epsilon_for_actor(j % 7, 7) for j in range(num_envs)])
    return np.full(num_envs, float(policy.epsilon))


class _Tracker:
    """Sub-goal flags of the running episode of one environment."""

    def __init__(self, env, info: dict):
        from dqn_mine.env.entities import BOULDER

        self.env = env
        self.start_room = env.agent_room
        self.boulders = [(e, e.x, e.z) for e in env.entities if e.kind == BOULDER]
        self.flags = dict.fromkeys(SUBGOALS, False)
        self.pose = (env.agent_x, env.agent_z, env.heading)
        self.had_kit = info["carrying_kit"]   # a phase may start with the kit in hand
        self.idle = 0   # steps in which the agent neither moved nor turned

    def update(self, info: dict) -> None:
        """After a step; ``info`` is what the step returned."""
        env, flags = self.env, self.flags
        pose = (env.agent_x, env.agent_z, env.heading)
        self.idle += pose == self.pose
        self.pose = pose
        if not flags["boulder moved"]:
            flags["boulder moved"] = any(b is env.carrying or (b.x, b.z) != (x, z)
                                         for b, x, z in self.boulders)
        if not flags["room entered"] and env.agent_room != self.start_room:
            flags["room entered"] = True
        if info["carrying_kit"] and not self.had_kit:   # taken up by this step
            flags["kit picked up"] = True
        self.had_kit = info["carrying_kit"]


def measure(env_kwargs: dict, policy: Policy, episodes: int, num_envs: int = 32,
            seed: int = 0, network_kwargs: dict | None = None) -> dict[str, float]:
    """Run ``episodes`` episodes (``num_envs`` at a time) and return each sub-goal's share, the
    mean steps to the first reward, the share of idle steps and env steps/s."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)   # one core, as an actor has
    try:
        return _measure(env_kwargs, policy, episodes, num_envs, seed, network_kwargs)
    finally:
        torch.set_num_threads(threads)


def _measure(env_kwargs: dict, policy: Policy, episodes: int, num_envs: int, seed: int,
             network_kwargs: dict | None) -> dict[str, float]:
    import torch

    from dqn_mine.agent.explore import BumpAndPress, Explorer
    from dqn_mine.agent.network import DuelingQNetwork
    from dqn_mine.env import MineRescueEnv

    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    net = DuelingQNetwork(**(network_kwargs or {})).eval() if policy.network else None
    h = net.history_len if net is not None else 0
    envs = [MineRescueEnv(**env_kwargs) for _ in range(num_envs)]
    if policy.scripted:
        explorer = BumpAndPress(num_envs, rng)
    else:
        explorer = Explorer(_epsilons(policy, num_envs), num_envs, rng,
                            durations=policy.durations, unstick=policy.unstick)
    obs = np.zeros((num_envs, *envs[0].observation_space.shape), np.uint8)   # [E, 3, H, W]
    hist = np.full((num_envs, h), -1, np.int8)                              # [E, h]
    carrying = np.zeros(num_envs, np.float32)                                # [E]
    stuck = np.zeros(num_envs, bool)                                         # [E]
    trackers: list[_Tracker | None] = [None] * num_envs
    started = 0

    def begin(j):
        nonlocal started
        obs[j], info = envs[j].reset(seed=seed * 100_003 + started)
        started += 1
        hist[j], carrying[j], stuck[j] = -1, float(info["carrying"]), False
        explorer.reset(j)
        trackers[j] = _Tracker(envs[j], info)

    for j in range(num_envs):
        begin(j)
    counts = dict.fromkeys(SUBGOALS, 0)
    idle = 0
    first_reward: list[int] = []
    done, steps, t0 = 0, 0, time.perf_counter()
    active = np.ones(num_envs, bool)
    while active.any():
        if net is not None:
            with torch.inference_mode():
                q = net(torch.from_numpy(obs), torch.from_numpy(hist), torch.from_numpy(carrying))
            greedy = q.argmax(1).numpy()
        else:
            greedy = np.zeros(num_envs, np.int64)
        actions = explorer.act(greedy, stuck)
        for j in np.flatnonzero(active):
            o, r, term, trunc, info = envs[j].step(int(actions[j]))
            steps += 1
            stuck[j] = np.array_equal(o, obs[j])
            obs[j], carrying[j] = o, float(info["carrying"])
            if h:
                hist[j, :-1], hist[j, -1] = hist[j, 1:], actions[j]
            trackers[j].update(info)
            if not (term or trunc):
                continue
            trackers[j].flags["delivered"] = bool(term)
            if term:
                first_reward.append(envs[j].steps)
            for k in SUBGOALS:
                counts[k] += trackers[j].flags[k]
            idle += trackers[j].idle
            done += 1
            if started < episodes:
                begin(j)
            else:
                active[j] = False
    elapsed = time.perf_counter() - t0
    for env in envs:
        env.close()
    out = {k: counts[k] / done for k in SUBGOALS}
    out["episodes"] = done
    out["mean steps to reward"] = float(np.mean(first_reward)) if first_reward else float("nan")
    out["idle steps"] = idle / steps
    out["steps/s"] = steps / elapsed
    return out


def table(rows: list[tuple]) -> list[str]:
    lines = ["| task | policy | episodes | " + " | ".join(SUBGOALS) +
             " | mean steps to reward | idle steps |",
             "|---|---|---|" + "---|" * (len(SUBGOALS) + 2)]
    for task, name, r in rows:
        shares = " | ".join(f"{100 * r[k]:.1f}%" for k in SUBGOALS)
        steps = r["mean steps to reward"]
        steps = "-" if steps != steps else f"{steps:.0f}"
        lines.append(f"| {task} | {name} | {r['episodes']} | {shares} | {steps} | "
                     f"{100 * r['idle steps']:.0f}% |")
    return lines


def fresh_network_inputs(nets: int = 5, episodes: int = 8, steps: int = 40,
                         seed: int = 0) -> list[dict[str, float]]:
    """What a freshly initialised network's greedy action depends on, for ``nets`` inits.

    Frames come from random play in ``two-room``; each is paired with a random action history.
    For each init: the share of greedy actions that change when the frames are shuffled against
    the histories (the image swapped, the history kept) and when the histories are shuffled (the
    history swapped), and the share of the most frequent greedy action.
    """
    import torch

    from dqn_mine.agent.network import DuelingQNetwork
    from dqn_mine.env import MineRescueEnv

    rng = np.random.default_rng(seed)
    env = MineRescueEnv(task="two-room")
    frames = []
    for ep in range(episodes):
        env.reset(seed=seed * 100_003 + ep)
        for _ in range(steps):
            frames.append(env.step(int(rng.integers(4)))[0])
    env.close()
    obs = torch.from_numpy(np.stack(frames))                                  # [N, 3, H, W]
    n = len(frames)
    hist = torch.from_numpy(rng.integers(0, 6, (n, 20)).astype(np.int8))     # [N, h]
    carrying = torch.zeros(n)
    out = []
    for k in range(nets):
        torch.manual_seed(seed + k)
        net = DuelingQNetwork().eval()
        with torch.inference_mode():
            greedy = net(obs, hist, carrying).argmax(1)
            other_image = net(obs[torch.randperm(n)], hist, carrying).argmax(1)
            other_history = net(obs, hist[torch.randperm(n)], carrying).argmax(1)
        out.append({"image": (greedy != other_image).float().mean().item(),
                    "history": (greedy != other_history).float().mean().item(),
                    "top action": np.bincount(greedy.numpy(), minlength=6).max() / n})
    return out


def inputs_table(rows: list[dict[str, float]]) -> list[str]:
    lines = ["| network init | greedy action changes with the image | with the history | "
             "most frequent greedy action |", "|---|---:|---:|---:|"]
    for k, r in enumerate(rows):
        lines.append(f"| seed {k} | {100 * r['image']:.0f}% | {100 * r['history']:.0f}% | "
                     f"{100 * r['top action']:.0f}% |")
    return lines


def run(quick: bool = False, policies=None, tasks=None) -> str:
    episodes = 64 if quick else 300
    rows = []
    for task, kwargs in tasks or TASKS:
        for name in policies or POLICIES:
            r = measure(kwargs, POLICIES[name], episodes)
            print(f"  {task:16s} {name:20s} " + " ".join(f"{r[k]:.3f}" for k in SUBGOALS) +
                  f"  {r['steps/s']:.0f} steps/s", flush=True)
            rows.append((task, name, r))
    inputs = inputs_table(fresh_network_inputs(nets=2 if quick else 5))
    return "\n".join(["## Exploration\n",
                      f"Share of {episodes} episodes per task and policy that reach each sub-goal "
                      "(`python -m dqn_mine.bench --only explore`).\n", *table(rows), "",
                      "What a fresh network's greedy action depends on (320 two-room frames, "
                      "each with a random action history; the share of greedy actions that "
                      "change when the frames or the histories are shuffled):\n", *inputs, ""])


def main(argv=None) -> None:
    import argparse

    ap = argparse.ArgumentParser(description="exploration measurement, some policies or tasks")
    ap.add_argument("--policies", nargs="+", choices=list(POLICIES), default=list(POLICIES))
    ap.add_argument("--tasks", nargs="+", choices=[t for t, _ in TASKS],
                    default=[t for t, _ in TASKS])
    ap.add_argument("--quick", action="store_true", help="64 episodes instead of 300")
    args = ap.parse_args(argv)
    tasks = [(t, kw) for t, kw in TASKS if t in args.tasks]
    print(run(args.quick, args.policies, tasks))


if __name__ == "__main__":
    main()
