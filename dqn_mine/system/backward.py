"""Starts on the expert's path: the backward curriculum's side in a training actor.

Every episode of every task comes with the scripted expert's solution of it. An episode that
starts ``to_go`` steps before the expert's delivery is reset from its seed and fast-forwarded
through the expert's first ``len(solution) - to_go`` actions, unrendered; the agent plays from
there, with the expert's last actions as its action history (its whole input is then the
demonstration's at that step). ``to_go`` at least the solution's length is the full task. The
expert's steps are not the agent's: nothing of them enters the replay. Which ``to_go`` an episode
gets is the curriculum's choice (``Curriculum.backward_start``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from dqn_mine.env.expert import Unsolved, solve

# A solved seed serves this many episodes (from different starts) before a new one is drawn.
# Planning costs ~75 ms a two-room episode (~200 on five rooms), about as much as 75 agent steps
# of an actor: shared by four episodes it stays a fraction of the short episodes near the
# reward (docs/backward.md).
SOLUTION_REUSE = 4
# Step limit of an episode that starts on the path: the expert's remaining steps times
# BUDGET_PER_STEP, plus BUDGET_BASE, at most the task's limit. A start a few steps from the
# reward then ends in about a hundred steps if it fails, not the task's 1,000-2,000.
BUDGET_PER_STEP = 3
BUDGET_BASE = 100
MAX_UNSOLVED = 20
SEEDS = (2 ** 20, 2 ** 31)    # training seeds: clear of the small seeds evaluations use


def start_budget(to_go: int, step_limit: int) -> int:
    return min(step_limit, BUDGET_PER_STEP * to_go + BUDGET_BASE)


class Start(NamedTuple):
    """An episode's start on the expert's path."""

    obs: np.ndarray
    info: dict
    full: bool              # the task's own start (to_go at least the solution's length)
    share: float            # to_go as a share of the solution, at most 1
    history: np.ndarray     # int8 [h]: the expert's actions before it, oldest first, -1 = none


class PathStarts:
    """One training environment's starts on the expert's solutions of its episodes."""

    def __init__(self, rng: np.random.Generator, step_limit: int, history_len: int = 0):
        self.rng = rng
        self.history_len = history_len
        self.step_limit = step_limit        # the task's; a path start gets less
        self.seed = -1
        self.solution: list[int] = []
        self.uses_left = 0

    def reset(self, env, to_go: int) -> Start:
        """Start ``env``'s next episode ``to_go`` expert steps before the delivery."""
        if self.uses_left == 0:
            self._solve_new_seed(env)
        self.uses_left -= 1
        length = len(self.solution)
        full = to_go >= length
        env.max_episode_steps = self.step_limit if full else start_budget(to_go,
                                                                          self.step_limit)
        obs, info = env.reset(seed=self.seed)
        played = [] if full else self.solution[:length - to_go]
        if played:
            obs, info = env.fast_forward(played)
        return Start(obs, info, full, min(1.0, to_go / length), self._history(played))

    def _history(self, played: list[int]) -> np.ndarray:
        """The expert's last ``history_len`` actions, oldest first, -1 where there were fewer:
        the start's input is then the one the expert's demonstration has at that step."""
        history = np.full(self.history_len, -1, dtype=np.int8)
        recent = played[-self.history_len:] if self.history_len else []
        if recent:
            history[-len(recent):] = recent
        return history

    def _solve_new_seed(self, env) -> None:
        """Draw a seed and plan its solution. A seed whose plan does not deliver within the
        step limit (possible only below a task's own limit, e.g. --max-episode-steps 200 in
        an 8 x 8 room) is passed over; ``MAX_UNSOLVED`` in a row is an impossible setting."""
        for _ in range(MAX_UNSOLVED):
            self.seed = int(self.rng.integers(*SEEDS))
            try:
                self.solution = solve(env, self.seed, self.step_limit)
            except Unsolved:
                continue
            self.uses_left = SOLUTION_REUSE
            return
        raise Unsolved(f"the expert solved none of {MAX_UNSOLVED} episodes within "
                       f"{self.step_limit} steps: the step limit is too short for the "
                       "backward curriculum")
