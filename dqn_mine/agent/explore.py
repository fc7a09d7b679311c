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

:class:`BumpAndPress` is no agent's exploration but a scripted walker: the explore benchmark's
yardstick, and with ``--prefill-explorer bump-and-press`` the policy that fills the replay before
the learner starts (:class:`PrefillFirst`).
"""

from __future__ import annotations

import numpy as np

from dqn_mine.env.interface import FORWARD, INTERACT, NUM_ACTIONS, TURN_LEFT, TURN_RIGHT

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

    scripted = False   # its greedy actions are the network's

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


class BumpAndPress:
    """A scripted undirected walker that ignores the network.

    It walks straight ahead (a uniform random action 5% of the time) until its view stops
    changing, then presses action 4 once and turns away, left or right at random, for 3-19
    steps. Like the agents it sees only whether its view changed, but it does what no
    epsilon-greedy walker does: it tries action 4 at every wall or entity it meets and leaves
    the wall at once. Same interface as :class:`Explorer`. No step is the network's choice, so
    its ``epsilon`` is 1 and it is ``scripted``: its episodes count neither as near-greedy ones
    nor towards the curriculum's switch, which judges the agent.
    """

    unstick = True   # it needs to know when the frame did not change
    scripted = True

    def __init__(self, num_envs: int, rng: np.random.Generator):
        self.rng = rng
        self.epsilon = np.ones(num_envs)
        self.queued: list[list[int]] = [[] for _ in range(num_envs)]   # turns still to take

    def reset(self, j: int) -> None:
        self.queued[j] = []

    def act(self, greedy: np.ndarray, stuck: np.ndarray) -> np.ndarray:
        actions = np.full(len(greedy), FORWARD, np.int64)
        for j, queued in enumerate(self.queued):
            if queued:
                actions[j] = queued.pop()
            elif stuck[j]:
                actions[j] = INTERACT
                turn = int(self.rng.integers(TURN_RIGHT, TURN_LEFT + 1))
                queued.extend([turn] * int(self.rng.integers(3, 20)))
            elif self.rng.random() < 0.05:
                actions[j] = int(self.rng.integers(NUM_ACTIONS))
        return actions


class PrefillFirst:
    """Acts with ``prefill`` for an actor's first ``steps`` environment steps (its share of the
    replay's pre-fill), then with ``then`` for the rest of the run.

    The switch happens mid-episode: the replay does not care which policy took a step (Q-learning
    learns off-policy), and an episode that straddles it is reported with ``then``'s epsilon.
    """

    def __init__(self, prefill, then: Explorer, steps: int):
        self.prefill, self.then, self.left = prefill, then, steps

    @property
    def current(self):
        return self.prefill if self.left > 0 else self.then

    @property
    def unstick(self) -> bool:
        """Whether the acting core compares frames now: the walker needs it, ``then`` may not
        (the core reads it every step, so the comparisons stop with the pre-fill)."""
        return self.current.unstick

    @property
    def epsilon(self) -> np.ndarray:
        return self.current.epsilon

    @property
    def scripted(self) -> bool:
        return self.current.scripted

    def reset(self, j: int) -> None:
        self.prefill.reset(j)
        self.then.reset(j)

    def act(self, greedy: np.ndarray, stuck: np.ndarray | None = None) -> np.ndarray:
        explorer = self.current
        self.left -= len(greedy)
        return explorer.act(greedy, stuck)
