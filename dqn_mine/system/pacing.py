"""The replay-ratio throttle (``--replay-ratio``): both halves, the actors' and the learner's.

Under a fixed ratio both sides count from the same point, the nominal pre-fill
(:func:`prefill_target`): the learner may make ``ratio * (steps - prefill_target)`` updates, and
each actor may step ``prefill`` + its share of ``updates / ratio``, plus slack. Counting the
learner from the steps measured when pre-fill ended instead (which overshoot the nominal
pre-fill) deadlocks once every actor has reached its cap by then: no new steps, so no updates, so
no new budget. Both sides count only this process's updates: a resumed run restores the update
counter, but its actors start again from zero steps.

Without ``--replay-ratio`` both sides run free.
"""

from __future__ import annotations

from dqn_mine.config import Config
from dqn_mine.replay.writer import FLUSH_EVERY


def prefill_target(cfg: Config) -> int:
    """Env steps all actors together must publish before the learner starts."""
    return cfg.prefill * cfg.actors


def actor_step_budget(cfg: Config, updates: int) -> float:
    """Env steps one actor may have taken after ``updates`` updates of this run (inf: no limit).

    The slack covers two batches, and one writer flush: steps an actor has taken but not yet
    published, which the learner cannot see."""
    if not cfg.replay_ratio:
        return float("inf")
    actors = max(1, cfg.actors)
    share = updates / cfg.replay_ratio / actors
    slack = 2 * cfg.batch_size / cfg.replay_ratio / actors + FLUSH_EVERY
    return cfg.prefill + share + slack


def learner_may_update(cfg: Config, updates: int, actor_steps: int) -> bool:
    """Whether the learner, after ``updates`` updates of this run, may make another one while the
    actors have taken ``actor_steps`` env steps in all (always, when free-running)."""
    if not cfg.replay_ratio:
        return True
    return updates < cfg.replay_ratio * (actor_steps - prefill_target(cfg))


class ActorPace:
    """An actor's half: how many env steps it may have taken by now."""

    def __init__(self, cfg: Config, control):
        self.cfg, self.control = cfg, control
        self.updates_at_start = control.updates

    def allowed_steps(self) -> float:
        """Step budget under a fixed replay ratio (inf when free-running)."""
        return actor_step_budget(self.cfg, self.control.updates - self.updates_at_start)

