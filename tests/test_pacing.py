"""The replay-ratio throttle's two halves (dqn_mine/system/pacing.py), without processes."""

from __future__ import annotations

import pytest

from dqn_mine.config import parse_args
from dqn_mine.shared import SharedBlocks
from dqn_mine.system.control import Control
from dqn_mine.system.pacing import ActorPace, actor_step_budget, learner_may_update, prefill_target


def test_free_running_sides_never_wait():
    cfg = parse_args(["--actors", "2"])
    assert actor_step_budget(cfg, 0) == float("inf")
    assert learner_may_update(cfg, 10**9, 0)


def test_replay_ratio_budget_counts_updates_since_the_actor_started():
    """After a resume the update counter starts high but the actors' steps start at zero: the
    actors' step budget must grow with the updates done since, not with the total."""
    cfg = parse_args(["--actors", "2", "--prefill", "200", "--replay-ratio", "0.05",
                      "--batch-size", "32"])
    with SharedBlocks.create(Control.specs(2)) as blocks:
        control = Control(blocks)
        control.updates = 5000                                     # restored from a checkpoint
        pace = ActorPace(cfg, control)                             # an actor starting now
        slack = 2 * 32 / 0.05 / 2 + 64
        assert pace.allowed_steps() == 200 + slack
        control.updates = 5060
        assert pace.allowed_steps() == 200 + 60 / 0.05 / 2 + slack


@pytest.mark.parametrize("actors,ratio,overshoot", [(9, 0.111, 0), (9, 0.111, 5000),
                                                    (1, 0.05, 300), (7, 0.023, 10_000)])
def test_replay_ratio_never_deadlocks_when_every_actor_is_at_its_cap(actors, ratio, overshoot):
    """Regression: the learner used to count new steps from those measured when pre-fill ended,
    the actors from the nominal pre-fill. Fast actors that had overshot the pre-fill and reached
    their caps by then left neither side a step to take. Whatever the overshoot, actors at their
    caps must leave the learner an update, and the learner's updates must raise the caps."""
    cfg = parse_args(["--actors", str(actors), "--prefill", "2000", "--replay-ratio", str(ratio)])
    prefill_end = prefill_target(cfg) + overshoot   # steps measured when the learner starts
    updates = 0
    for _ in range(200):
        at_cap = actors * int(actor_step_budget(cfg, updates))
        steps = max(prefill_end, at_cap)           # every actor as far as it may go
        assert learner_may_update(cfg, updates, steps)
        while learner_may_update(cfg, updates, steps):
            updates += 1
        assert actor_step_budget(cfg, updates) * actors > steps   # the actors may move again
    # and the ratio holds: updates per step after the nominal pre-fill stay close to the target
    assert updates / (steps - prefill_target(cfg)) == pytest.approx(ratio, rel=0.05)
