"""Demonstrations (DQfD): expert episodes kept in a part of the replay that is never overwritten.

``--demos N``: before the actors start, the scripted expert plans N episodes of the run's task
(seeds of their own, never an evaluation's), which are rendered and written into the replay's
demonstration rings once, as n-step transitions like the agent's. ``--demos-from DIR`` loads
recorded episodes instead. The learner samples them with the agent's data, with a priority bonus
(``--demo-bonus``) and a large-margin loss (``--demo-margin``, ``--demo-loss-weight``).

On disk (``python -m dqn_mine.play --record DIR``), a folder of ``episode_NNNNNN.npz`` files:

============  =====================  ===============================================
array         shape, dtype           meaning
============  =====================  ===============================================
frames        [T+1, 3, H, W] uint8   the observations s_0 .. s_T
carrying      [T+1] bool             whether the agent held an item in each state
actions       [T] int64              a_0 .. a_{T-1}
rewards       [T] float32            r_1 .. r_T
terminated    [] bool                the episode ended by delivery (else cut at step T)
seed          [] int64               the episode's seed (-1: unknown)
============  =====================  ===============================================

and ``demos.json``: ``{"format": 1, "episodes": N, "steps": ..., "env": {...}}``, the settings
of the environment they were recorded in (for people; loading checks only the frame shape).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from dqn_mine.env.interface import FRAME_SHAPE

FORMAT = 1
META = "demos.json"
SEEDS = (2 ** 31, 2 ** 32)    # clear of the evaluations' seeds and the backward curriculum's
MAX_UNSOLVED = 20
ARRAYS = ("frames", "carrying", "actions", "rewards", "terminated", "seed")


class DemoError(ValueError):
    """Demonstrations that cannot be loaded or made (one line)."""


class DemoEpisode(NamedTuple):
    """One demonstrated episode (the arrays of the file format)."""

    frames: np.ndarray       # uint8 [T+1, 3, H, W]
    carrying: np.ndarray     # bool [T+1]
    actions: np.ndarray      # int64 [T]
    rewards: np.ndarray      # float32 [T]
    terminated: bool
    seed: int = -1

    @property
    def steps(self) -> int:
        return len(self.actions)


# -- making episodes ---------------------------------------------------------------------------

def expert_plans(env, count: int, seed: int, step_limit: int,
                 progress: bool = False) -> list[tuple[int, list[int]]]:
    """``count`` (seed, expert actions) pairs, planned unrendered; a seed the expert cannot
    solve within ``step_limit`` is passed over (``MAX_UNSOLVED`` in a row: DemoError)."""
    from tqdm import tqdm

    from dqn_mine.env.expert import Unsolved, solve

    rng = np.random.default_rng([seed, 0xDE30])
    plans, failed = [], 0
    with tqdm(total=count, desc="demos: planning", unit="ep", disable=not progress) as bar:
        while len(plans) < count:
            episode_seed = int(rng.integers(*SEEDS))
            try:
                plans.append((episode_seed, solve(env, episode_seed, step_limit)))
            except Unsolved:
                failed += 1
                if failed == MAX_UNSOLVED:
                    raise DemoError(f"the expert solved none of {MAX_UNSOLVED} episodes within "
                                    f"{step_limit} steps: no demonstrations") from None
                continue
            failed = 0
            bar.update(1)
    return plans


def record_actions(env, seed: int, actions) -> DemoEpisode:
    """Play ``actions`` from ``env.reset(seed=seed)``, rendered: the episode they make."""
    actions = list(actions)
    return record_policy(env, lambda env, obs, info, t: actions[t], seed, len(actions))


def record_policy(env, policy: Callable, seed: int, max_steps: int | None = None) -> DemoEpisode:
    """An episode of ``policy(env, obs, info, t) -> action`` from ``env.reset(seed=seed)``, to
    its end, ``max_steps`` steps, or an action of None (a person stops it: cut there)."""
    obs, info = env.reset(seed=seed)
    frames, carrying, actions, rewards = [obs], [info["carrying"]], [], []
    terminated = False
    while max_steps is None or len(actions) < max_steps:
        action = policy(env, obs, info, len(actions))
        if action is None:
            break
        action = int(action)
        obs, reward, terminated, truncated, info = env.step(action)
        frames.append(obs)
        carrying.append(info["carrying"])
        actions.append(action)
        rewards.append(reward)
        if terminated or truncated:
            break
    return DemoEpisode(np.stack(frames), np.array(carrying, bool), np.array(actions, np.int64),
                       np.array(rewards, np.float32), bool(terminated), int(seed))


# -- files -------------------------------------------------------------------------------------

def save_episode(folder, index: int, episode: DemoEpisode) -> Path:
    """Write ``episode`` as ``folder/episode_NNNNNN.npz``."""
    path = Path(folder) / f"episode_{index:06d}.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **{name: np.asarray(getattr(episode, name)) for name in ARRAYS})
    return path


def write_meta(folder, episodes: int, steps: int, env_settings: dict) -> None:
    """``demos.json``: the format, the episode and step counts, the environment's settings."""
    meta = {"format": FORMAT, "episodes": episodes, "steps": steps, "env": env_settings}
    (Path(folder) / META).write_text(json.dumps(meta, indent=1) + "\n")


def episode_files(folder) -> list[Path]:
    """The episode files of a demonstration folder, in order (DemoError if there are none)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DemoError(f"no demonstration folder at {folder}")
    paths = sorted(folder.glob("episode_*.npz"))
    if not paths:
        raise DemoError(f"{folder} holds no episode_*.npz demonstrations")
    return paths


def load_episode(path) -> DemoEpisode:
    """One episode file, checked (DemoError names the file and what is wrong)."""
    try:
        with np.load(path) as z:
            arrays = {name: z[name] for name in ARRAYS}
    except (OSError, ValueError, KeyError, EOFError) as exc:
        raise DemoError(f"unreadable demonstration {path}: {str(exc).splitlines()[0]}") from None
    ep = DemoEpisode(arrays["frames"], arrays["carrying"].astype(bool),
                     arrays["actions"].astype(np.int64), arrays["rewards"].astype(np.float32),
                     bool(arrays["terminated"]), int(arrays["seed"]))
    t = ep.steps
    if ep.frames.dtype != np.uint8 or ep.frames.shape != (t + 1, *FRAME_SHAPE):
        raise DemoError(f"{path}: frames are {ep.frames.dtype} {ep.frames.shape}, expected "
                        f"uint8 {(t + 1, *FRAME_SHAPE)}")
    if ep.carrying.shape != (t + 1,) or ep.rewards.shape != (t,) or t == 0:
        raise DemoError(f"{path}: {t} actions, {ep.rewards.size} rewards and "
                        f"{ep.carrying.size} carrying flags do not make an episode")
    return ep


def read_lengths(paths) -> list[int]:
    """Steps of each episode file (reads only its actions)."""
    lengths = []
    for path in paths:
        try:
            with np.load(path) as z:
                lengths.append(int(z["actions"].shape[0]))
        except (OSError, ValueError, KeyError, EOFError) as exc:
            raise DemoError(f"unreadable demonstration {path}: "
                            f"{str(exc).splitlines()[0]}") from None
    return lengths


# -- into the replay ---------------------------------------------------------------------------

def pack(lengths: list[int], frames_per_stream: int) -> list[list[int]]:
    """Episodes (by index, in order) per demonstration ring: each ring takes whole episodes
    while their frames (steps + 1 each) fit, so none is ever overwritten."""
    rings: list[list[int]] = []
    used = frames_per_stream
    for i, steps in enumerate(lengths):
        if steps + 1 > frames_per_stream:
            raise DemoError(f"a demonstration of {steps} steps does not fit a replay ring of "
                            f"{frames_per_stream} frames: raise --replay-capacity")
        if used + steps + 1 > frames_per_stream:
            rings.append([])
            used = 0
        rings[-1].append(i)
        used += steps + 1
    return rings


def write_episode(writer, episode: DemoEpisode) -> None:
    """Append ``episode`` through an ``NStepWriter`` (no Q values: the replay gives its
    transitions the largest priority so far, as it does any new transition without them)."""
    f, c, a, r = episode.frames, episode.carrying, episode.actions, episode.rewards
    writer.begin_episode(f[0], bool(c[0]))
    last = episode.steps - 1
    for t in range(episode.steps):
        end = t == last
        writer.append(None, int(a[t]), float(r[t]), f[t + 1], bool(c[t + 1]),
                      terminated=end and episode.terminated,
                      truncated=end and not episode.terminated)


class DemoSet:
    """The run's demonstrations: their lengths up front (to size the replay), each episode
    when it is written (rendered from its plan, or read from its file)."""

    def __init__(self, lengths: list[int], episode: Callable[[int], DemoEpisode],
                 frames_per_stream: int, source: str):
        self.lengths, self.episode, self.source = lengths, episode, source
        self.rings = pack(lengths, frames_per_stream)

    @property
    def streams(self) -> int:
        return len(self.rings)

    @property
    def steps(self) -> int:
        return sum(self.lengths)

    @classmethod
    def from_folder(cls, folder, frames_per_stream: int) -> DemoSet:
        """Recorded episodes (``play --record``), read one by one as they are written."""
        paths = episode_files(folder)
        return cls(read_lengths(paths), lambda i: load_episode(paths[i]), frames_per_stream,
                   str(folder))

    @classmethod
    def from_expert(cls, env, count: int, seed: int, frames_per_stream: int,
                    progress: bool = False) -> DemoSet:
        """``count`` episodes of the expert in ``env``, planned now, rendered as written."""
        plans = expert_plans(env, count, seed, env.max_episode_steps, progress)
        return cls([len(actions) for _, actions in plans],
                   lambda i: record_actions(env, *plans[i]), frames_per_stream, "the expert")

    def write(self, storage, progress: bool = False) -> None:
        """Every episode into the replay's demonstration rings (its last streams)."""
        from tqdm import tqdm

        from dqn_mine.replay import NStepWriter

        first = storage.layout.num_streams - storage.layout.demo_streams
        with tqdm(total=len(self.lengths), desc="demos: into the replay", unit="ep",
                  disable=not progress) as bar:
            for k, ring in enumerate(self.rings):
                writer = NStepWriter(storage, first + k)
                for i in ring:
                    write_episode(writer, self.episode(i))
                    bar.update(1)
                writer.flush()
