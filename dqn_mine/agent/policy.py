"""A trained agent acting in one environment: ``dqn_mine.load_agent(path)``, used by
`python -m dqn_mine.play --checkpoint` and `python -m dqn_mine.evaluate`.

It feeds the network exactly what the actors fed it during training: the last ``frame_stack``
frames (zeros before the episode start), the last ``history_len`` actions (oldest first, -1 =
none) and the carrying flag.
"""

from __future__ import annotations

import numpy as np
import torch

from dqn_mine.agent.network import DuelingQNetwork


class AgentPolicy:
    """``agent.predict(obs, info) -> action``; call :meth:`reset` at each episode start.

    ``info`` is the step's info dict (the carrying flag is read from it; None = carrying
    nothing). Also callable as ``agent(env, obs, info)``, the form ``play`` takes policies in.
    """

    def __init__(self, net: DuelingQNetwork, frame_stack: int, history_len: int,
                 epsilon: float = 0.0, seed: int = 0):
        self.net = net.eval()
        self.frame_stack, self.history_len = frame_stack, history_len
        self.epsilon = epsilon
        self.rng = np.random.default_rng(seed)
        self.stack: np.ndarray | None = None           # uint8 [3f, H, W]
        self.history = np.full(history_len, -1, dtype=np.int8)

    @classmethod
    def from_checkpoint(cls, path, epsilon: float = 0.0, seed: int = 0) -> AgentPolicy:
        """Raises CheckpointError (one line) for a missing or corrupt checkpoint."""
        from dqn_mine import checkpoint as ckpt
        from dqn_mine.config import network_shape

        state = ckpt.load(path)
        cfg = state["config"]
        net = DuelingQNetwork(**network_shape(cfg))
        try:
            net.load_state_dict(state["updater"]["online"])
        except (RuntimeError, TypeError) as exc:  # wrong or damaged tensors
            raise ckpt.CheckpointError(f"{path}: the network weights do not fit "
                                       f"({str(exc).splitlines()[0]})") from None
        return cls(net, cfg["frame_stack"], cfg["history_len"], epsilon, seed)

    def reset(self) -> None:
        self.stack = None
        self.history[:] = -1

    def __call__(self, env, obs: np.ndarray, info: dict) -> int:
        return self.predict(obs, info)

    def predict(self, obs: np.ndarray, info: dict | None = None) -> int:
        """The action for ``obs`` (uint8 [3, H, W]); greedy unless ``epsilon`` > 0."""
        carrying = float(bool((info or {}).get("carrying", False)))
        if self.stack is None:
            self.stack = np.zeros((self.frame_stack * obs.shape[0], *obs.shape[1:]), np.uint8)
        c = obs.shape[0]
        self.stack[:-c] = self.stack[c:]
        self.stack[-c:] = obs
        with torch.inference_mode():
            q = self.net(torch.from_numpy(self.stack[None]), torch.from_numpy(self.history[None]),
                         torch.tensor([carrying]))[0]   # [A]
        action = int(q.argmax())
        if self.rng.random() < self.epsilon:
            action = int(self.rng.integers(q.numel()))
        if self.history_len:
            self.history[:-1] = self.history[1:]
            self.history[-1] = action
        return action
