"""Exploration: epsilon-greedy, optionally temporally extended ("ez-greedy").

Plain epsilon-greedy replaces each greedy action by a uniform one with probability epsilon: a
random walk whose forward and backward steps cancel, so in 1,000 steps it drifts only about nine
units from where it started. Ez-greedy (Dabney, Ostrovski and Barreto, 2021) instead starts, with
probability epsilon, a *run* of one uniform action repeated for a duration drawn from a zeta
(power-law) distribution, p(n) ~ n^-mu, capped at ``max_duration``. Mostly short runs, now and
then a long straight walk or a half turn: the walk covers a room instead of circling its start.

Unsticking: a greedy policy facing an unchanged frame gets the same input again (the action
history fills with the repeated action), so it repeats its action forever. A fresh network walks
into a wall or an entity and stays there: half of its steps are spent so in the study's tasks, and
epsilon 0.01 turns it away only every few hundred steps. With ``unstick`` a step after which the
frame did not change starts a random action (held like an epsilon one) as if epsilon had fired.
The test uses only what the agent sees, and a policy that does not get stuck never triggers it.
A greedy policy can also loop over two frames: holding a boulder it puts it down, facing it
within reach it takes it up, and so on to the step limit (a left turn undone by a right one is
the same kind of loop). With ``unstick_cycle`` k (kept by :class:`ActingCore`, which compares
the frames) a frame equal to any of the last k counts as stuck.
"""

from __future__ import annotations

import numpy as np

from dqn_mine.env.interface import INTERACT, NUM_ACTIONS

# Actions below INTERACT (forward, backward, the turns) are held; interact and no-op last one step.
HELD_ACTIONS = INTERACT


def zeta_durations(rng: np.random.Generator, size: int, mu: float, cap: int) -> np.ndarray:
    """Durations n in 1..cap with p(n) proportional to n^-mu (the truncated zeta law)."""
    n = np.arange(1, cap + 1)
    p = n ** -float(mu)
    return rng.choice(n, size=size, p=p / p.sum())


class Explorer:
    """Epsilon-greedy over E environments; ``durations`` turns it into ez-greedy.

    ``act(greedy, stuck)`` takes the greedy actions [E] (and, with ``unstick``, which envs' frames
    did not change at their last step [E]) and returns the actions to take [E]. A running random
    action keeps going until its duration is spent; an episode end (``reset(j)``) cancels it.
    """

    def __init__(self, epsilon, num_envs: int, rng: np.random.Generator,
                 durations: bool = False, mu: float = 2.0, max_duration: int = 100,
                 unstick: bool = False):
        self.unstick = unstick
        self.epsilon = np.broadcast_to(np.asarray(epsilon, dtype=np.float64), (num_envs,)).copy()
        self.rng, self.durations = rng, durations
        self.mu, self.max_duration = mu, max_duration
        self.action = np.zeros(num_envs, dtype=np.int64)   # the running random action  [E]
        self.left = np.zeros(num_envs, dtype=np.int64)     # its steps still to take   [E]

    def reset(self, j: int) -> None:
        self.left[j] = 0

    def act(self, greedy: np.ndarray, stuck: np.ndarray | None = None) -> np.ndarray:
        actions = np.asarray(greedy, dtype=np.int64).copy()
        self._start((self.left == 0) & (self.rng.random(len(actions)) < self.epsilon))
        if self.unstick and stuck is not None:
            # drawn after epsilon's: the other envs get the draws they would get without unstick
            self._start(stuck & (self.left == 0))
        running = self.left > 0
        actions[running] = self.action[running]
        self.left[running] -= 1
        return actions

    def _start(self, start: np.ndarray) -> None:
        """Start a uniform random action in the envs of mask ``start`` [E]."""
        k = int(start.sum())
        if not k:
            return
        self.action[start] = self.rng.integers(0, NUM_ACTIONS, k)
        left = np.ones(k, dtype=np.int64)
        if self.durations:  # only motions are held: a held action 4 would pick up and drop
            moving = self.action[start] < HELD_ACTIONS
            left[moving] = zeta_durations(self.rng, int(moving.sum()), self.mu, self.max_duration)
        self.left[start] = left
