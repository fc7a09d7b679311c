# typing.get_type_hints evaluates these annotations, and `X | None` fails there on Python 3.9.
# ruff: noqa: UP007, UP045
"""The run configuration: one frozen dataclass, the command line generated from it, json I/O.

Every field carries a one-line ``help`` that becomes its ``--flag`` help. Precedence of values:
dataclass defaults < ``--preset NAME`` < flags given explicitly. With ``--resume RUN_DIR`` the base
is that run's saved ``config.json`` instead (explicit flags still win, e.g. ``--updates`` to
train longer). Every impossible setting raises :class:`ConfigError` with a one-line message.

The defaults are the study's configuration on ``two-room``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from dqn_mine.env.mine import VIEWS
from dqn_mine.env.tasks import DEFAULT_NUM_ROOMS, MAX_ROOMS, PLACEMENTS, TASKS
from dqn_mine.replay.writer import FLUSH_EVERY

DEVICES = ("auto", "cpu", "cuda")
PRECISIONS = ("auto", "float32", "bfloat16")
EPSILON_SCHEDULES = ("fixed", "apex")
CURRICULA = ("none", "adaptive", "schedule", "backward")
EXPLORATIONS = ("epsilon", "ez")
PREFILL_EXPLORERS = ("agent", "bump-and-press")


DIFFERENCES_KEY = "differs_from_preset"   # in config.json: what the flags changed


class ConfigError(ValueError):
    """An impossible or unreadable configuration; the message is one line."""


def _f(default, help: str, choices: Optional[tuple] = None):
    meta = {"help": help}
    if choices is not None:
        meta["choices"] = choices
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class Config:
    """The whole configuration of one run (saved as ``config.json``; ``--help`` lists it)."""

    # -- task --------------------------------------------------------------------------------
    task: str = _f("two-room", "task to train on", TASKS)
    num_rooms: int = _f(DEFAULT_NUM_ROOMS, "number of rooms of the `rooms` task")
    room_size: float = _f(16.0, "side length of a room in world units")
    max_episode_steps: Optional[int] = _f(None, "episode step limit (none = the task's default)")
    placement: str = _f("fixed", "where agent, kit and miner start (any-room = domain "
                        "randomisation)", PLACEMENTS)
    view: str = _f("study", "study: a level camera, plain floors, the carried item drawn in the "
                   "world; clear: the camera pitched 15 degrees down (an item within reach stays "
                   "in view), each room's floor in a colour of its own, the carried item drawn "
                   "on top (training and evaluation alike)", tuple(VIEWS))
    # -- curriculum ----------------------------------------------------------------------------
    curriculum: str = _f("none", "adaptive: three-room's phases 6->1, one harder when the "
                         "rolling return passes the threshold; schedule: room "
                         "counts by share of updates; backward (every task): start on the "
                         "expert's solution of each episode, d steps before its delivery, d "
                         "growing by --backward-step as the agent succeeds", CURRICULA)
    backward_step: int = _f(10, "backward curriculum: expert steps the start moves back at "
                            "once, and the width of the frontier the starts are drawn from")
    curriculum_threshold: float = _f(0.6, "rolling mean return that advances a curriculum phase")
    curriculum_window: int = _f(50, "episodes in the rolling mean that advances the curriculum")
    curriculum_review: float = _f(0.0, "adaptive and backward curricula: share of episodes that "
                                  "start in an easier phase already passed, or nearer the "
                                  "reward than the backward frontier (0 = the study's rule)")
    curriculum_dr: float = _f(0.0, "adaptive curriculum with domain randomisation: share of "
                              "episodes that start as the full task with --placement any-room's "
                              "random rooms instead of in a phase (they do not count towards "
                              "the phase's switch)")
    rooms_schedule: tuple[int, ...] = _f((3, 4, 5), "room counts of the schedule curriculum, each "
                                         "for an equal share of the updates")
    # -- actors and exploration ---------------------------------------------------------------
    actors: int = _f(7, "number of actor processes")
    envs_per_actor: int = _f(1, "environments per actor, stepped with one batched forward pass")
    epsilon: float = _f(0.01, "exploration rate of every actor (fixed schedule)")
    epsilon_schedule: str = _f("fixed", "fixed: every actor uses --epsilon; apex: env i of the "
                               "N actor envs uses 0.4**(1+7i/(N-1))", EPSILON_SCHEDULES)
    exploration: str = _f("epsilon", "epsilon: a uniform random action with prob. epsilon; ez: "
                          "with prob. epsilon start a random action held for n steps, p(n) ~ "
                          "n**-2 up to 100 (motions only)", EXPLORATIONS)
    unstick: int = _f(0, "training actors: a step whose frame is one of the last N frames (1: "
                      "the view did not change; 2: also the frame two steps back came back, as "
                      "when a boulder is put down and taken up again) is followed by a random "
                      "action, as if epsilon had fired (0 = off)")
    prefill: int = _f(50_000, "environment steps per actor before the learner starts")
    # The study does not say how its pre-fill acted. A fresh network at epsilon 0.01 records
    # no reward in the study's 350 pre-fill episodes of two-room (it stops at the first wall);
    # the scripted walker delivers in about 1% of them, so the replay starts with a few.
    prefill_explorer: str = _f("bump-and-press", "who acts during the pre-fill: bump-and-press "
                               "(a scripted walker: straight ahead until the view stops "
                               "changing, then action 4 and a turn away) or agent (the actors' "
                               "own exploration)", PREFILL_EXPLORERS)
    # -- learner -----------------------------------------------------------------------------
    updates: int = _f(1_000_000, "network updates to train for")
    minutes: Optional[float] = _f(None, "also stop, as finished, after this many minutes of wall "
                                  "time (counted over resumes; none = --updates alone)")
    lr: float = _f(3e-5, "Adam learning rate")
    batch_size: int = _f(32, "transitions per update")
    gamma: float = _f(0.99, "discount factor")
    n_step: int = _f(6, "steps of the n-step return")
    # The study does not state C: Ape-X's (Horgan et al. 2018), as is the gradient clip
    # (system/learner.py).
    target_update_interval: int = _f(2500, "updates between target network syncs (Ape-X value)")
    publish_interval: int = _f(500, "updates between weight broadcasts to the actors")
    replay_ratio: Optional[float] = _f(None, "hold updates per new transition fixed by "
                                       "throttling (none = free-running)")
    device: str = _f("auto", "learner device (auto = cuda when available)", DEVICES)
    precision: str = _f("auto", "compute of the convolutions and first head layers, learner and "
                        "actors: float32, or bfloat16 (float32 master weights, outputs, loss and "
                        "Adam), or auto (bfloat16 where the CPU or GPU computes it natively; "
                        "actors only with --envs-per-actor >= 8)", PRECISIONS)
    # -- network -----------------------------------------------------------------------------
    history_len: int = _f(20, "actions in the one-hot action history input (0 = none)")
    frame_stack: int = _f(1, "frames stacked along channels (1 = no stacking)")
    # -- replay ------------------------------------------------------------------------------
    replay_capacity: int = _f(1_048_576, "transitions the replay holds (oldest overwritten)")
    zeta: float = _f(0.6, "priority exponent: P(i) ~ p_i**zeta (beta 0.4 -> 1 and eta 1e-5 "
                     "as the study's)")
    save_replay: Optional[str] = _f(None, "also save the replay to this folder at the end "
                                    "(large; size printed first); --resume reads it back and "
                                    "skips the pre-fill")
    # -- demonstrations: DQfD (Hester et al. 2018); its margin, loss weight and bonus ----------
    demos: int = _f(0, "expert episodes played before acting and kept in the replay for the "
                    "whole run, never overwritten (DQfD demonstrations; 0 = none)")
    demos_from: Optional[str] = _f(None, "a folder of recorded demonstrations to keep instead "
                                   "(python -m dqn_mine.play --record DIR)")
    demo_bonus: float = _f(1.0, "added to a demonstration's priority")
    demo_margin: float = _f(0.8, "large-margin loss: the demonstrated action must beat every "
                            "other by this much")
    demo_loss_weight: float = _f(1.0, "weight of the large-margin loss on demonstrations "
                                 "(0 = off)")
    demo_pretrain: int = _f(0, "updates on the demonstrations alone before the actors start")
    # -- evaluation --------------------------------------------------------------------------
    eval_every: int = _f(0, "evaluation actor: every N training env steps, play the full task "
                         "near-greedily (epsilon 0.01, no held or unstick actions; a GIF every "
                         "10th time) (0 = off)")
    eval_episodes: int = _f(10, "episodes per evaluation")
    eval_num_rooms: Optional[int] = _f(None, "rooms of the evaluation actor's rooms task (none "
                                       "= --num-rooms, or the schedule's last count)")
    # -- run ---------------------------------------------------------------------------------
    seed: int = _f(0, "random seed")
    preset: str = _f("paper", "named configuration the flags start from (see below; why "
                     "each setting: docs/presets.md)")
    run_dir: Optional[str] = _f(None, "run folder (none = runs/<task>__<preset>__<seed>__<time>)")
    resume: Optional[str] = _f(None, "continue the run in this folder with its saved config")
    checkpoint_interval: int = _f(50_000, "updates between checkpoints (one is always written "
                                  "at the end)")
    log_interval: int = _f(1000, "updates between rows of metrics.csv")
    serial: bool = _f(False, "run actors and learner in one process (tests, debugging)")
    tensorboard: bool = _f(False, "also write every metrics row to TensorBoard event files in "
                           "RUN_DIR/tb (needs the tensorboard package: pip install -e .[tb])")

    # -- derived counts ----------------------------------------------------------------------
    @property
    def num_streams(self) -> int:
        """One replay stream (ring) per training environment."""
        return self.actors * self.envs_per_actor

    @property
    def acting_processes(self) -> int:
        """Training actors plus the evaluation actor (when evaluation is on)."""
        return self.actors + (1 if self.eval_every else 0)

    # -- checks ------------------------------------------------------------------------------
    def validate(self) -> Config:
        """Raise :class:`ConfigError` (one line) for an impossible configuration; return self."""
        for problem in _problems(self):
            raise ConfigError(problem)
        return self

    def with_run_dir(self, now: Optional[float] = None) -> Config:
        """This config with ``run_dir`` filled in (``runs/<task>__<preset>__<seed>__<time>``)."""
        if self.run_dir is not None:
            return self
        stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
        return dataclasses.replace(
            self, run_dir=f"runs/{self.task}__{self.preset}__{self.seed}__{stamp}")

    # -- json --------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def differences(self) -> dict[str, Any]:
        """The settings in which this config differs from its preset, in field order."""
        preset = Config(**{**PRESETS.get(self.preset, {}), "preset": self.preset})
        return {name: value for name, value in self.to_dict().items()
                if value != getattr(preset, name)}

    def preset_differences(self) -> dict[str, Any]:
        """:meth:`differences` without the run folders (what config.json shows people)."""
        return {name: value for name, value in self.differences().items()
                if name not in ("run_dir", "resume")}

    def saved_dict(self) -> dict[str, Any]:
        """All settings under the format version that :func:`migrate` reads back."""
        return {VERSION_KEY: CONFIG_VERSION, **self.to_dict()}

    def to_json(self, path) -> None:
        """All settings, plus (for people; ignored on load) those that differ from the preset."""
        data = {**self.saved_dict(), DIFFERENCES_KEY: self.preset_differences()}
        Path(path).write_text(json.dumps(data, indent=2) + "\n")

    @classmethod
    def from_dict(cls, data: dict[str, Any], where: str = "config") -> Config:
        if not isinstance(data, dict):
            raise ConfigError(f"{where}: expected a json object")
        data = migrate(data, where)
        hints = _hints()
        unknown = sorted(set(data) - set(hints))
        if unknown:
            raise ConfigError(f"{where}: unknown settings {', '.join(unknown)}")
        values = {}
        for name, value in data.items():
            if _is_tuple(hints[name]) and isinstance(value, list):
                value = tuple(value)
            if not _fits(value, hints[name]):
                kind = getattr(hints[name], "__name__", str(hints[name]).replace("typing.", ""))
                raise ConfigError(f"{where}: {name} = {value!r} is not {kind}")
            values[name] = value
        return cls(**values)

    @classmethod
    def from_json(cls, path) -> Config:
        """Load a saved config; a missing, unreadable or corrupt file raises ConfigError."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            raise ConfigError(f"no config file at {path}") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ConfigError(f"corrupt config file {path}: {str(exc).splitlines()[0]}") from None
        return cls.from_dict(data, where=str(path))


# -- saved configs of older versions -----------------------------------------------------------
# config.json and every checkpoint carry VERSION_KEY; a config without it is version 1.
VERSION_KEY = "config_version"
CONFIG_VERSION = 4
# Settings version 2 removed (measured and rejected, or used by no preset), with the value at
# which each changed nothing. A run that used another value cannot be continued as it was.
REMOVED_IN_2 = {"episode_order": "ended", "curriculum_steps": None, "target_update_early": None,
                "curriculum_review_pick": "uniform", "init_priority": "actor"}


def migrate(data: dict[str, Any], where: str = "config") -> dict[str, Any]:
    """A saved config (``config.json`` or a checkpoint's) as this version's settings; keys it
    lacks take :class:`Config`'s defaults later. Raises ConfigError naming the saved version
    when the run used what this version cannot do."""
    data = {k: v for k, v in data.items() if k != DIFFERENCES_KEY}
    version = data.pop(VERSION_KEY, 1)
    if version not in range(1, CONFIG_VERSION + 1):
        raise ConfigError(f"{where}: config version {version!r} is not one this dqn_mine reads "
                          f"(1..{CONFIG_VERSION}); a newer dqn_mine saved it?")
    if version == 1:
        data = _from_version_1(data, where)
    if version <= 2:
        data = _from_version_2(data, where)
    if version <= 3:
        data = _from_version_3(data, where)
    return data


def _drop_removed(data: dict[str, Any], removed: dict[str, Any], version: int,
                  where: str) -> None:
    """Drop settings a version removed; a value other than the one that changed nothing is a
    run this version cannot continue as it was."""
    for name, neutral in removed.items():
        value = data.pop(name, neutral)
        if value != neutral:
            raise ConfigError(f"{where}: a version {version} config with {name} = {value!r}, "
                              f"which version {version + 1} removed; continue it with the "
                              "dqn_mine it was made with")


def _from_version_1(data: dict[str, Any], where: str) -> dict[str, Any]:
    data.setdefault("prefill_explorer", "agent")   # saved before the walker pre-filled
    if data.pop("per", True) is False:
        data["zeta"] = 0.0                         # uniform replay, as --per off sampled
    data.pop("target_update_early_phase", None)    # read only with target_update_early
    if data.get("curriculum") == "uniform":
        raise ConfigError(f"{where}: a version 1 config with curriculum = 'uniform', which "
                          "version 2 removed; continue it with dqn_mine before that change")
    _drop_removed(data, REMOVED_IN_2, 1, where)
    return data


# Version 3 made these constants at the value they had by default.
REMOVED_IN_3 = {"ez_mu": 2.0, "ez_max_duration": 100, "max_grad_norm": 40.0, "beta0": 0.4,
                "eta": 1e-5, "visual_randomisation": False, "eval_task": None}
# ... and these, which change how a run is run or watched, not what it learns.
DROPPED_IN_3 = ("learner_queue", "learner_threads", "return_window", "progress",
                "eval_epsilon", "eval_unstick", "eval_held", "eval_video_every")


def _from_version_2(data: dict[str, Any], where: str) -> dict[str, Any]:
    for name in DROPPED_IN_3:
        data.pop(name, None)
    cycle = data.pop("unstick_cycle", 1)
    if isinstance(data.get("unstick"), bool):
        data["unstick"] = cycle if data["unstick"] else 0
    if data.pop("boulder_phases", False):
        data["curriculum"] = "boulders"
    precisions = [data.pop(k, "auto") for k in ("learner_precision", "actor_precision")]
    data.setdefault("precision", next((p for p in precisions if p != "auto"), "auto"))
    look = {k: data.pop(k) for k in VIEWS["clear"] if k in data}
    if look:
        data["view"] = _view_of(look, where)
    _drop_removed(data, REMOVED_IN_3, 2, where)
    return data


# Version 4 removed three-room's 23-phase table (the backward curriculum with demonstrations
# replaced it, docs/backward.md) and the review unit only its preset used.
REMOVED_IN_4 = {"curriculum_review_unit": "episodes"}


def _from_version_3(data: dict[str, Any], where: str) -> dict[str, Any]:
    if data.get("curriculum") == "boulders":
        raise ConfigError(f"{where}: a config with curriculum = 'boulders' (three-room's 23 "
                          "phases), which version 4 removed; continue it with the dqn_mine it "
                          "was made with")
    _drop_removed(data, REMOVED_IN_4, 3, where)
    return data


def _view_of(look: dict[str, Any], where: str) -> str:
    """The view whose environment settings a version 2 config's look settings are."""
    for name, kwargs in VIEWS.items():
        if all(look.get(k, False) == kwargs.get(k, False) for k in VIEWS["clear"]):
            return name
    raise ConfigError(f"{where}: a version 2 config with {', '.join(look)} = "
                      f"{tuple(look.values())}, neither view of version 3; continue it with the "
                      "dqn_mine it was made with")


# Named starting points; explicit flags override them. Why each setting: docs/presets.md.
PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    "smoke": {
        "task": "one-room", "room_size": 8.0, "max_episode_steps": 200,
        "actors": 2, "envs_per_actor": 1, "epsilon_schedule": "apex",
        "prefill": 2000, "replay_capacity": 50_000, "updates": 20_000,
        "lr": 2e-4, "target_update_interval": 500, "publish_interval": 100,
        "checkpoint_interval": 5000, "log_interval": 250, "prefill_explorer": "agent",
    },
    "cpu": {
        "task": "two-room", "actors": 2, "envs_per_actor": 16, "unstick": 1,
        "epsilon_schedule": "apex", "exploration": "ez", "curriculum": "backward",
        "curriculum_review": 0.3, "replay_ratio": 0.03,
        "prefill": 20_000, "replay_capacity": 262_144, "updates": 300_000,
        "lr": 1e-4, "target_update_interval": 1000, "publish_interval": 250,
        "eval_every": 500_000, "checkpoint_interval": 10_000,
        "log_interval": 500, "prefill_explorer": "agent", "demos": 200,
    },
}
PRESETS["cpu-three-room"] = {**PRESETS["cpu"], "task": "three-room", "updates": 600_000,
                             "view": "clear", "unstick": 2}
PRESETS["cpu-rooms"] = {**PRESETS["cpu-three-room"], "task": "rooms"}
# What each is for, in a line or two (``--help`` lists them).
PRESET_REASONS = {
    "paper": "the study's configuration on two-room (a scripted walker plays the pre-fill)",
    "smoke": "a small one-room that 2 CPU cores learn in minutes",
    "cpu": "full two-room in half an hour on a few CPU cores: 2 actors x 16 envs, Ape-X "
           "epsilons with ez and unstick, the backward curriculum, 200 expert demonstrations "
           "in the replay, a replay ratio of 0.03",
    "cpu-three-room": "full three-room in 90 minutes on a few CPU cores: cpu's settings "
                      "with the clear view and two-frame loops unstuck",
    "cpu-rooms": "the rooms task at any --num-rooms: cpu-three-room's settings",
}


# -- validation --------------------------------------------------------------------------------

def _problems(c: Config) -> list[str]:
    """Every impossible setting, as one-line messages (first one is raised)."""
    return (_choice_problems(c) + _bound_problems(c) + _replay_problems(c) + _rate_problems(c)
            + _task_problems(c))


def _choice_problems(c: Config) -> list[str]:
    """Named values that are not among their choices, and a missing optional package."""
    import importlib.util

    p = []
    if c.tensorboard and importlib.util.find_spec("tensorboard") is None:
        p.append("--tensorboard needs the tensorboard package (pip install -e .[tb])")
    for name, f in Config.__dataclass_fields__.items():
        choices = f.metadata.get("choices")
        if choices is not None and getattr(c, name) not in choices:
            p.append(f"--{_flag(name)}: unknown value {getattr(c, name)!r} "
                     f"(choose from {', '.join(choices)})")
    if c.eval_num_rooms is not None and c.task != "rooms":
        p.append("--eval-num-rooms applies to an evaluation actor on the rooms task only")
    elif c.eval_num_rooms is not None and not 2 <= c.eval_num_rooms <= MAX_ROOMS:
        p.append(f"--eval-num-rooms must be in 2..{MAX_ROOMS}, got {c.eval_num_rooms}")
    if c.preset not in PRESETS:
        p.append(f"--preset: unknown preset {c.preset!r} (choose from {', '.join(PRESETS)})")
    return p


def _bound_problems(c: Config) -> list[str]:
    """Counts below their least value."""
    p = []
    at_least = {"actors": 1, "envs_per_actor": 1, "n_step": 1, "batch_size": 1, "frame_stack": 1,
                "history_len": 0, "prefill": 0, "updates": 1, "target_update_interval": 1,
                "publish_interval": 1, "eval_every": 0, "unstick": 0,
                "eval_episodes": 1, "checkpoint_interval": 1, "log_interval": 1,
                "curriculum_window": 1, "seed": 0,
                "backward_step": 1, "demos": 0, "demo_pretrain": 0}
    for name, low in at_least.items():
        if getattr(c, name) < low:
            p.append(f"--{_flag(name)} must be at least {low}, got {getattr(c, name)}")
    if c.minutes is not None and not 0 < c.minutes < math.inf:
        p.append(f"--minutes must be a positive number, got {c.minutes}")
    if c.n_step > 254:  # the replay stores the bootstrap offset in one byte
        p.append(f"--n-step must be at most 254, got {c.n_step}")
    return p


def _replay_problems(c: Config) -> list[str]:
    """A replay too small for the batch, the n-step windows or the writers' flushes."""
    p = []
    streams = c.num_streams
    if c.replay_capacity < c.batch_size:
        p.append(f"--replay-capacity {c.replay_capacity} is smaller than --batch-size "
                 f"{c.batch_size}")
    elif streams >= 1 and c.replay_capacity // streams <= c.n_step + c.frame_stack:
        p.append(f"--replay-capacity {c.replay_capacity} leaves each of the {streams} actor "
                 f"environments fewer than n-step + frame-stack + 1 slots")
    elif streams >= 1 and min_live_transitions(c) < c.batch_size:
        p.append(f"--replay-capacity {c.replay_capacity} holds as few as "
                 f"{min_live_transitions(c)} sampleable transitions over {streams} actor "
                 f"environments (frames still being written are not sampleable), fewer than "
                 f"--batch-size {c.batch_size}")
    return p


def _rate_problems(c: Config) -> list[str]:
    """Rates and exponents out of their ranges."""
    p = []
    if not 0.0 < c.gamma <= 1.0:
        p.append(f"--gamma must be in (0, 1], got {c.gamma}")
    if not 0.0 <= c.epsilon <= 1.0:
        p.append(f"--epsilon must be in [0, 1], got {c.epsilon}")
    if not 0.0 <= c.curriculum_review < 1.0:
        p.append(f"--curriculum-review must be in [0, 1), got {c.curriculum_review}")
    if not c.lr > 0:
        p.append(f"--lr must be positive, got {c.lr}")
    if c.zeta < 0:
        p.append(f"--zeta must be >= 0, got {c.zeta}")
    if c.replay_ratio is not None and not c.replay_ratio > 0:
        p.append(f"--replay-ratio must be positive, got {c.replay_ratio}")
    return p + _demo_problems(c)


def _demo_problems(c: Config) -> list[str]:
    p = []
    for name in ("demo_bonus", "demo_margin", "demo_loss_weight"):
        if not 0.0 <= getattr(c, name) < math.inf:
            p.append(f"--{_flag(name)} must be >= 0, got {getattr(c, name)}")
    if c.demos and c.demos_from:
        p.append("--demos and --demos-from are two sources of demonstrations: give one")
    if c.demo_pretrain and not (c.demos or c.demos_from):
        p.append("--demo-pretrain trains on demonstrations: add --demos N or --demos-from DIR")
    return p


def _task_problems(c: Config) -> list[str]:
    """Task settings the environment or the curriculum cannot run."""
    p = []
    if not 0 < c.room_size < math.inf:
        p.append(f"--room-size must be a positive finite number, got {c.room_size}")
    if c.max_episode_steps is not None and c.max_episode_steps < 1:
        p.append(f"--max-episode-steps must be at least 1, got {c.max_episode_steps}")
    if not 0.0 <= c.curriculum_dr < 1.0:
        p.append(f"--curriculum-dr must be in [0, 1), got {c.curriculum_dr}")
    if c.curriculum_dr and c.curriculum != "adaptive":
        p.append("--curriculum-dr applies to --curriculum adaptive only (for domain "
                 "randomisation alone use --placement any-room)")
    if c.task == "rooms" and not 2 <= c.num_rooms <= MAX_ROOMS:
        p.append(f"--num-rooms must be in 2..{MAX_ROOMS} for the rooms task, got {c.num_rooms}")
    if c.task != "rooms" and c.num_rooms != _field("num_rooms").default:
        p.append(f"--num-rooms applies to --task rooms only ({c.task} has its own room count)")
    if c.curriculum == "adaptive" and c.placement != "fixed":
        p.append("--curriculum adaptive sets the start of each episode, so it needs "
                 "--placement fixed")
    if c.curriculum == "adaptive" and c.task != "three-room":
        p.append(f"--curriculum adaptive needs --task three-room, got {c.task}")
    if c.curriculum == "schedule" and (c.task != "rooms" or not c.rooms_schedule
                                    or min(c.rooms_schedule) < 2
                                    or max(c.rooms_schedule) > MAX_ROOMS):
        p.append(f"--curriculum schedule needs --task rooms and a --rooms-schedule of counts in "
                 f"2..{MAX_ROOMS}")
    return p


# -- command line ------------------------------------------------------------------------------

class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line instead of usage + message + exit
        raise ConfigError(message)


def _hints() -> dict[str, Any]:
    return typing.get_type_hints(Config)


def _field(name: str) -> dataclasses.Field:
    return Config.__dataclass_fields__[name]


def _flag(name: str) -> str:
    return name.replace("_", "-")


def _is_tuple(hint) -> bool:
    return typing.get_origin(hint) is tuple


def _fits(value, hint) -> bool:
    """Whether a json-loaded value has the type ``hint`` (ints pass for floats)."""
    if value is None:
        return type(None) in typing.get_args(hint)
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if _is_tuple(hint):
        return isinstance(value, tuple) and all(_fits(v, args[0]) for v in value)
    base = args[0] if typing.get_origin(hint) is typing.Union else hint
    if base is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if base is int:
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, base)


def _scalar(hint):
    """(converter, optional?) of a type hint."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    optional = typing.get_origin(hint) is typing.Union and len(args) == 1
    base = args[0] if optional else hint

    def convert(text: str):
        if optional and text.lower() == "none":
            return None
        return base(text)

    convert.__name__ = base.__name__  # argparse names the type in its error messages
    return convert


def _show(value) -> str:
    if value is None:
        return "none"
    if isinstance(value, tuple):
        return " ".join(map(str, value))
    return str(value)


# ``--help`` sections: the first Config field of each (fields are declared section by section).
HELP_SECTIONS = {"task": "task", "curriculum": "curriculum", "actors": "actors and exploration",
                 "updates": "learner", "history_len": "network", "replay_capacity": "replay",
                 "demos": "demonstrations", "eval_every": "evaluation", "seed": "run"}


def _presets_help() -> str:
    import textwrap

    lines = ["presets (--preset NAME):"]
    for name, why in PRESET_REASONS.items():
        lines += textwrap.wrap(why, 78, initial_indent=f"  {name + ':':<16}",
                               subsequent_indent=" " * 18)
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """``--flag`` per Config field; defaults are not filled in, so only explicit flags appear."""
    parser = _Parser(prog="python -m dqn_mine.train",
                     description="Train an Ape-X style DQN agent on the mine rescue task.",
                     epilog=_presets_help(),
                     formatter_class=argparse.RawDescriptionHelpFormatter,
                     argument_default=argparse.SUPPRESS)
    hints = _hints()
    group = parser
    for f in dataclasses.fields(Config):
        if f.name in HELP_SECTIONS:
            group = parser.add_argument_group(HELP_SECTIONS[f.name])
        hint, meta = hints[f.name], f.metadata
        helptext = f"{meta['help']} (default: {_show(f.default)})"
        kwargs: dict[str, Any] = {"help": helptext, "dest": f.name}
        if hint is bool:
            kwargs["action"] = argparse.BooleanOptionalAction
        elif _is_tuple(hint):
            kwargs.update(nargs="+", type=typing.get_args(hint)[0], metavar="N")
        else:
            kwargs["type"] = _scalar(hint)
            kwargs["metavar"] = kwargs["type"].__name__.upper()
        if "choices" in meta:
            kwargs["choices"] = meta["choices"]
            kwargs["metavar"] = "{" + ",".join(meta["choices"]) + "}"
        if f.name == "preset":
            kwargs["metavar"] = "{" + ",".join(PRESETS) + "}"
        group.add_argument(f"--{_flag(f.name)}", **kwargs)
    return parser


def parse_args(argv: Optional[list[str]] = None) -> Config:
    """Command line -> validated Config (``run_dir`` still None unless given or resumed).

    Raises ConfigError (one line) for bad flags, an unknown preset or a missing/corrupt resume.
    """
    explicit = vars(build_parser().parse_args(argv))
    for name, hint in _hints().items():
        if name in explicit and _is_tuple(hint):
            explicit[name] = tuple(explicit[name])
    if explicit.get("resume"):
        try:
            base = Config.from_json(Path(explicit["resume"]) / "config.json")
        except ConfigError as exc:
            raise ConfigError(f"--resume {explicit['resume']}: {exc}") from None
        explicit = {k: v for k, v in explicit.items() if k != "preset"}
        explicit["run_dir"] = explicit["resume"]
        for name in NETWORK_SHAPE:
            if name in explicit and explicit[name] != getattr(base, name):
                raise ConfigError(f"--{_flag(name)} {explicit[name]} differs from the resumed "
                                  f"run's {getattr(base, name)}: the network's shape is fixed")
    else:
        preset = explicit.get("preset", _field("preset").default)
        if preset not in PRESETS:
            raise ConfigError(f"--preset: unknown preset {preset!r} "
                              f"(choose from {', '.join(PRESETS)})")
        base = Config(**{**PRESETS[preset], "preset": preset})
        if "demos_from" in explicit and "demos" not in explicit:
            explicit["demos"] = 0     # the folder's demonstrations replace the preset's
    return dataclasses.replace(base, **explicit).validate()


def min_live_transitions(c: Config) -> int:
    """Sampleable transitions in a full replay at worst: each environment's ring holds back up to
    one writer flush (at most FLUSH_EVERY steps) plus an n-step window and a frame stack of
    frames that start no complete transition yet (NStepWriter)."""
    streams = c.num_streams
    m = c.replay_capacity // streams
    held_back = min(FLUSH_EVERY, m - c.n_step - c.frame_stack) + c.n_step + c.frame_stack + 1
    return streams * max(0, m - held_back)


# Settings that shape the network: a resumed run must keep its checkpoint's.
NETWORK_SHAPE = ("frame_stack", "history_len")


def network_shape(cfg) -> dict[str, int]:
    """The network's constructor arguments, from a Config or its saved dict (a checkpoint's)."""
    values = cfg if isinstance(cfg, dict) else cfg.to_dict()
    return {name: values[name] for name in NETWORK_SHAPE}


def inert_settings(c: Config) -> set[str]:
    """Settings this configuration never reads, so that a run differing only in them (e.g. one
    made before such a default changed) is the same run: a sweep resumes and reports it."""
    inert = set()
    if c.curriculum != "schedule":
        inert.add("rooms_schedule")
    return inert


def learner_threads(cfg: Config, cores: Optional[int] = None) -> int:
    """Torch threads for the learner: the cores the acting processes leave free, at least one.

    Measured (bench.learner): threads competing with busy actor processes for a core cost more
    than they give, so it never oversubscribes.
    """
    import os

    return max(1, (cores or os.cpu_count() or 1) - cfg.acting_processes)


def resolve_device(name: str):
    """``auto`` -> cuda when available, else cpu; an explicit ``cuda`` without CUDA is an error."""
    import torch

    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise ConfigError("--device cuda: no CUDA device is available (use --device cpu)")
    if name not in ("cpu", "cuda"):
        raise ConfigError(f"--device: unknown value {name!r} (choose from {', '.join(DEVICES)})")
    return torch.device(name)


def native_bf16(cpuinfo: str = "/proc/cpuinfo") -> bool:
    """Whether this CPU has bfloat16 dot-product instructions (x86 AVX512-BF16 or AMX-BF16, Arm
    BF16), which oneDNN uses for convolutions; elsewhere bfloat16 is emulated, slower than
    float32. torch's own ``_is_mkldnn_bf16_supported`` also says yes for plain AVX-512."""
    import torch

    try:
        flags = set(Path(cpuinfo).read_text().split())
    except OSError:  # not Linux: stay with float32
        return False
    return torch.backends.mkldnn.is_available() and bool(
        flags & {"avx512_bf16", "amx_bf16", "bf16"})


def resolve_actor_precision(name: str, envs: int):
    """The dtype of an actor's network, which steps ``envs`` environments per forward pass.

    Measured (bench.learner, AVX512-BF16 core, docs/benchmarks.md): bfloat16 weights cost 0.91x
    float32's time per frame at 8 frames per forward, 0.79x at 16 and 0.72x at 32, but 1.18x at 1
    and 0.94x at 4; hence ``auto`` = bfloat16 where native and at least 8 environments per forward.
    """
    import torch

    if name == "auto":
        name = "bfloat16" if envs >= 8 and native_bf16() else "float32"
    return torch.bfloat16 if name == "bfloat16" else torch.float32


def resolve_learner_precision(name: str, device) -> str:
    """``auto`` -> "bfloat16" where ``device`` computes it natively (CUDA with bfloat16 support, or
    a CPU with bfloat16 dot products), else "float32". Measured (bench.learner, AVX512-BF16 core,
    one thread): the bfloat16 update takes 0.64-0.78x the float32 update's time at batch 32 and
    0.5x at batch 256; on CPUs that emulate bfloat16 it would be slower than float32."""
    import torch

    if name != "auto":
        return name
    if torch.device(device).type == "cuda":
        return "bfloat16" if torch.cuda.is_bf16_supported() else "float32"
    return "bfloat16" if native_bf16() else "float32"


def to_argv(cfg: Config) -> list[str]:
    """Flags that :func:`parse_args` turns back into ``cfg`` (the preset plus what differs)."""
    argv: list[str] = [] if cfg.preset == _field("preset").default else ["--preset", cfg.preset]
    for name, value in cfg.differences().items():
        if isinstance(value, bool):
            argv.append(f"--{'' if value else 'no-'}{_flag(name)}")
        elif isinstance(value, tuple):
            argv += [f"--{_flag(name)}", *map(str, value)]
        else:
            text = "none" if value is None else repr(value) if isinstance(value, float) else value
            argv += [f"--{_flag(name)}", str(text)]
    return argv
