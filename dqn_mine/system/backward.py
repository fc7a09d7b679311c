"""Starts on the expert's path: the backward curriculum's side in a training actor.

Every episode of every task comes with the scripted expert's solution of it. An episode that
starts ``to_go`` steps before the expert's delivery is reset from its seed and fast-forwarded
through the expert's first ``len(solution) - to_go`` actions, unrendered; the agent plays from
there. ``to_go`` at least the solution's length is the full task. The expert's steps are not the
agent's: nothing of them enters the replay. Which ``to_go`` an episode gets is the curriculum's
choice (``Curriculum.backward_start``).
"""

from __future__ import annotations

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


class PathStarts:
    """One training environment's starts on the expert's solutions of its episodes."""

    def __init__(self, rng: np.random.Generator, step_limit: int):
        self.rng = rng
        self.step_limit = step_limit        # the task's; a path start gets less
        self.seed = -1
        self.solution: list[int] = []
        self.uses_left = 0

    def reset(self, env, to_go: int) -> tuple[np.ndarray, dict, bool, float]:
        """Start ``env``'s next episode ``to_go`` expert steps before the delivery: (obs, info,
        full task?, to_go as a share of the solution, at most 1)."""
        if self.uses_left == 0:
            self._solve_new_seed(env)
        self.uses_left -= 1
        length = len(self.solution)
        full = to_go >= length
        env.max_episode_steps = self.step_limit if full else start_budget(to_go,
                                                                          self.step_limit)
        obs, info = env.reset(seed=self.seed)
        if not full:
            obs, info = env.fast_forward(self.solution[:length - to_go])
        return obs, info, full, min(1.0, to_go / length)

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
