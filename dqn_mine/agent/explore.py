"""Exploration: epsilon-greedy, optionally temporally extended ("ez-greedy").

Plain epsilon-greedy replaces each greedy action by a uniform one with probability epsilon: a
random walk whose forward and backward steps cancel, so in 1,000 steps it drifts only about nine
units from where it started. Ez-greedy (Dabney, Ostrovski and Barreto, 2021) instead starts, with
probability epsilon, a *run* of one uniform action repeated for a duration drawn from a zeta
(power-law) distribution, p(n) ~ n^-mu, capped at ``max_duration``. Mostly short runs, now and
then a long straight walk or a half turn: the walk covers a room instead of circling its start.
"""

from __future__ import annotations

import numpy as np

from dqn_mine.env.mine import ACTION_NAMES, INTERACT

NUM_ACTIONS = len(ACTION_NAMES)
# Actions below INTERACT (forward, backward, the turns) are held; interact and no-op last one step.
HELD_ACTIONS = INTERACT


def zeta_durations(rng: np.random.Generator, size: int, mu: float, cap: int) -> np.ndarray:
    """Durations n in 1..cap with p(n) proportional to n^-mu (the truncated zeta law)."""
    n = np.arange(1, cap + 1)
    p = n ** -float(mu)
    return rng.choice(n, size=size, p=p / p.sum())


class Explorer:
    """Epsilon-greedy over E environments; ``durations`` turns it into ez-greedy.

    ``act(greedy)`` takes the greedy actions [E] and returns the actions to take [E]. A running
    random action keeps going until its duration is spent; an episode end (``reset(j)``) cancels it.
    """

    def __init__(self, epsilon, num_envs: int, rng: np.random.Generator,
                 durations: bool = False, mu: float = 2.0, max_duration: int = 100):
        self.epsilon = np.broadcast_to(np.asarray(epsilon, dtype=np.float64), (num_envs,)).copy()
        self.rng, self.durations = rng, durations
        self.mu, self.max_duration = mu, max_duration
        self.action = np.zeros(num_envs, dtype=np.int64)   # the running random action  [E]
        self.left = np.zeros(num_envs, dtype=np.int64)     # its steps still to take   [E]

    def reset(self, j: int) -> None:
        self.left[j] = 0

    def act(self, greedy: np.ndarray) -> np.ndarray:
        actions = np.asarray(greedy, dtype=np.int64).copy()
        idle = self.left == 0
        start = idle & (self.rng.random(len(actions)) < self.epsilon)
        k = int(start.sum())
        if k:
            self.action[start] = self.rng.integers(0, NUM_ACTIONS, k)
            left = np.ones(k, dtype=np.int64)
            if self.durations:  # only motions are held: a held action 4 would pick up and drop
                moving = self.action[start] < HELD_ACTIONS
                left[moving] = zeta_durations(self.rng, int(moving.sum()), self.mu,
                                              self.max_duration)
            self.left[start] = left
        running = self.left > 0
        actions[running] = self.action[running]
        self.left[running] -= 1
        return actions
