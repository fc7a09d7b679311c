"""The acting core: what the network sees and how an action is chosen, for E environments at once.

One class serves the training actors, the evaluation actor and ``AgentPolicy`` (``play``,
``evaluate``, ``load_agent``), so a trained agent is fed exactly what it was trained on:

- the last ``frame_stack`` frames, oldest first, zeros before the episode start: uint8
  [E, 3f, H, W];
- the last ``history_len`` actions, oldest first, -1 = none yet: int8 [E, h];
- the carrying flag: float32 [E].

One batched forward pass gives the Q values of every environment; the :class:`Explorer` turns the
greedy actions into the actions taken (epsilon, ez-greedy, unstick).
"""

from __future__ import annotations

import numpy as np
import torch

from dqn_mine.agent.explore import Explorer
from dqn_mine.env.interface import FRAME_SHAPE


class ActingCore:
    """Per-environment inputs of the network, the batched Q values and the action choice."""

    def __init__(self, net: torch.nn.Module, explorer: Explorer, num_envs: int,
                 frame_stack: int, history_len: int, unstick_cycle: int = 1):
        self.net, self.explorer = net, explorer
        c, h, w = FRAME_SHAPE
        self.stacks = np.zeros((num_envs, frame_stack * c, h, w), dtype=np.uint8)  # [E, 3f, H, W]
        self.histories = np.full((num_envs, history_len), -1, dtype=np.int8)      # [E, h]
        self.carrying = np.zeros(num_envs, dtype=np.float32)                       # [E]
        # With unstick: the last ``unstick_cycle`` frames, oldest first, and whether the frame
        # a step brought is one of them (a loop of that many steps or fewer).
        self.recent = np.zeros((num_envs, unstick_cycle if explorer.unstick else 0, c, h, w),
                               dtype=np.uint8)                                     # [E, k, 3, H, W]
        self.stuck = np.zeros(num_envs, dtype=bool)                                # [E]

    # -- what the network sees -----------------------------------------------------------------
    def begin(self, j: int, obs: np.ndarray, carrying: bool) -> None:
        """Environment ``j`` starts an episode with frame ``obs``."""
        self.stacks[j] = 0
        self.histories[j] = -1
        self.stuck[j] = False
        self.recent[j] = obs   # before the episode only its first frame has been seen
        self.explorer.reset(j)
        self._push_frame(j, obs)
        self.carrying[j] = float(carrying)

    def observe(self, j: int, action: int, obs: np.ndarray, carrying: bool) -> None:
        """Environment ``j`` took ``action`` and now shows ``obs``."""
        if self.explorer.unstick:   # compared only when used: full-frame comparisons per step
            self.stuck[j] = bool((self.recent[j] == obs).all(axis=(1, 2, 3)).any())
            self.recent[j, :-1] = self.recent[j, 1:]
            self.recent[j, -1] = obs
        self._push_frame(j, obs)
        self.carrying[j] = float(carrying)
        if self.histories.shape[1]:
            self.histories[j, :-1] = self.histories[j, 1:]   # oldest first, newest last
            self.histories[j, -1] = action

    def _push_frame(self, j: int, obs: np.ndarray) -> None:
        c = obs.shape[0]
        self.stacks[j, :-c] = self.stacks[j, c:]   # oldest frame first, newest last
        self.stacks[j, -c:] = obs

    # -- acting --------------------------------------------------------------------------------
    def q_values(self, rows: slice = slice(None)) -> np.ndarray:
        """Q values of the environments in ``rows``: float32 [E, A] (one forward pass)."""
        with torch.inference_mode():
            q = self.net(torch.from_numpy(self.stacks[rows]),
                         torch.from_numpy(self.histories[rows]),
                         torch.from_numpy(self.carrying[rows]))
        return q.float().numpy()

    def act(self) -> tuple[np.ndarray, np.ndarray]:
        """(actions to take [E], the Q values they were chosen from [E, A])."""
        q = self.q_values()
        return self.explorer.act(q.argmax(axis=1), self.stuck), q
