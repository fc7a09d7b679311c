"""A trained agent acting in one environment: ``dqn_mine.load_agent(path)``, used by
`python -m dqn_mine.play --checkpoint` and `python -m dqn_mine.evaluate`.

It acts through the same :class:`~dqn_mine.agent.acting.ActingCore` as the training actors, so it
feeds the network exactly what they fed it: the last ``frame_stack`` frames (zeros before the
episode start), the last ``history_len`` actions (oldest first, -1 = none) and the carrying flag.
"""

from __future__ import annotations

import numpy as np

from dqn_mine.agent.acting import ActingCore
from dqn_mine.agent.explore import Explorer
from dqn_mine.agent.network import DuelingQNetwork


class AgentPolicy:
    """``agent.predict(obs, info) -> action``; call :meth:`reset` at each episode start.

    ``info`` is the step's info dict (the carrying flag is read from it; None = carrying
    nothing). Also callable as ``agent(env, obs, info)``, the form ``play`` takes policies in.
    """

    def __init__(self, net: DuelingQNetwork, frame_stack: int, history_len: int,
                 epsilon: float = 0.0, seed: int = 0, unstick: bool = False,
                 unstick_cycle: int = 1, held: bool = False):
        """``held``: hold random actions as ez-greedy training actors do (else every random
        action lasts one step)."""
        self.net = net.eval()
        self.frame_stack, self.history_len = frame_stack, history_len
        self.epsilon = epsilon
        self.rng = np.random.default_rng(seed)
        explorer = Explorer(epsilon, 1, self.rng, durations=held, unstick=unstick)
        self.core = ActingCore(self.net, explorer, 1, frame_stack, history_len, unstick_cycle)
        self.last_action: int | None = None   # None: the next observation starts an episode

    @classmethod
    def from_checkpoint(cls, path, epsilon: float = 0.0, seed: int = 0,
                        unstick: bool = False, held: bool = False) -> AgentPolicy:
        """``held``: random actions held as the ez training actors hold them.
        Raises CheckpointError (one line) for a missing or corrupt checkpoint."""
        from dqn_mine import checkpoint as ckpt
        from dqn_mine.config import network_shape

        state = ckpt.load(path)
        shape = network_shape(state["config"])
        net = DuelingQNetwork(**shape)
        try:
            net.load_state_dict(state["updater"]["online"])
        except (RuntimeError, TypeError) as exc:  # wrong or damaged tensors
            raise ckpt.CheckpointError(f"{path}: the network weights do not fit "
                                       f"({str(exc).splitlines()[0]})") from None
        # unstick as the run's actors did: the same loop length counts as stuck
        cycle = max(1, state["config"]["unstick"])
        return cls(net, shape["frame_stack"], shape["history_len"], epsilon, seed, unstick, cycle,
                   held)

    def reset(self) -> None:
        self.last_action = None

    def __call__(self, env, obs: np.ndarray, info: dict) -> int:
        return self.predict(obs, info)

    def predict(self, obs: np.ndarray, info: dict | None = None) -> int:
        """The action for ``obs`` (uint8 [3, H, W]); greedy unless ``epsilon`` > 0 (or, with
        ``unstick``, the last step left the frame unchanged or looped back to a recent one)."""
        carrying = bool((info or {}).get("carrying", False))
        if self.last_action is None:
            self.core.begin(0, obs, carrying)
        else:
            self.core.observe(0, self.last_action, obs, carrying)
        actions, _ = self.core.act()
        self.last_action = int(actions[0])
        return self.last_action
