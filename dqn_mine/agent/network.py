"""The dueling Q-network, after the classic Atari DQN.

| layer                                   | shape                      |
|-----------------------------------------|----------------------------|
| input (uint8, scaled to [0, 1] inside)  | 3f x 44 x 76               |
| conv 32 8x8 / 4, ReLU                   | 32 x 10 x 18               |
| conv 64 4x4 / 2, ReLU                   | 64 x 4 x 8                 |
| conv 64 3x3 / 1, ReLU, flatten          | 64 x 2 x 6 = 768           |
| concat one-hot history, carrying flag   | 768 + 6h + 1               |
| value: linear 128, ReLU, linear 1       | V(s)                       |
| advantage: linear 128, ReLU, linear 6   | A(s, a)                    |
| combine                                 | Q = V + A - mean_a A(s, a) |
"""

from __future__ import annotations

import copy

import torch
import torch.nn.functional as F
from torch import nn

from dqn_mine.env.interface import FRAME_SHAPE, NUM_ACTIONS


def one_hot_history(history: torch.Tensor, num_actions: int) -> torch.Tensor:
    """[B, h] action ids with -1 meaning "no action yet" -> [B, h * num_actions] float one-hot.

    A -1 slot becomes all zeros, so the start of an episode is distinguishable from any action.
    """
    history = history.long()
    valid = history >= 0  # [B, h]
    onehot = F.one_hot(history.clamp(min=0), num_actions).float()  # [B, h, A]
    onehot = onehot * valid.unsqueeze(-1)  # [B, h, A], -1 slots zeroed
    return onehot.flatten(1)  # [B, h * A]


class DuelingQNetwork(nn.Module):
    """Dueling DQN over a (stacked) camera frame, a one-hot action history and a carrying flag."""

    def __init__(self, frame_stack: int = 1, history_len: int = 20, num_actions: int = NUM_ACTIONS,
                 frame_shape: tuple[int, int, int] = FRAME_SHAPE):
        super().__init__()
        self.frame_stack = frame_stack
        self.history_len = history_len
        self.num_actions = num_actions
        channels, height, width = frame_shape
        self.obs_shape = (channels * frame_stack, height, width)
        self.prescaled = False  # True: the first layer's weights include the 1/255 input scale
        self.conv = nn.Sequential(
            nn.Conv2d(channels * frame_stack, 32, kernel_size=8, stride=4), nn.ReLU(),
            nn.Conv2d(32, 64, kernel_size=4, stride=2), nn.ReLU(),
            nn.Conv2d(64, 64, kernel_size=3, stride=1), nn.ReLU(),
            nn.Flatten(),
        )
        with torch.no_grad():  # 768 for the default frame; computed so other frame sizes work
            self.conv_out = self.conv(torch.zeros(1, *self.obs_shape)).shape[1]
        features = self.conv_out + num_actions * history_len + 1
        self.value = nn.Sequential(nn.Linear(features, 128), nn.ReLU(), nn.Linear(128, 1))
        self.advantage = nn.Sequential(nn.Linear(features, 128), nn.ReLU(),
                                       nn.Linear(128, num_actions))

    def forward(self, obs: torch.Tensor, history: torch.Tensor,
                carrying: torch.Tensor) -> torch.Tensor:
        """obs uint8 [B, 3f, H, W], history int [B, h] (-1: none), carrying float [B] -> Q [B, A]

        Each stage computes in the dtype of its own weights: all float32, or mixed
        (:func:`lower_heavy_layers`: bfloat16 actors and the learner's ``WorkingCopy``), whose
        output layers stay float32 so that Q-values and their action gaps keep float32
        precision.
        """
        x = obs.to(self.conv[0].weight.dtype)
        if not self.prescaled:
            x = x / 255.0
        x = self.conv(x)  # [B, 768]
        dtype = self.value[0].weight.dtype
        parts = [x.to(dtype), carrying.to(dtype).reshape(-1, 1)]  # carrying: [B, 1]
        if self.history_len > 0:
            parts.append(one_hot_history(history, self.num_actions).to(dtype))  # [B, 6h]
        features = torch.cat(parts, dim=1)  # [B, 768 + 6h + 1]
        value = _stream(self.value, features)  # [B, 1]
        advantage = _stream(self.advantage, features)  # [B, A]
        return value + advantage - advantage.mean(dim=1, keepdim=True)  # [B, A]


def _stream(stream: nn.Sequential, features: torch.Tensor) -> torch.Tensor:
    """linear, ReLU, linear; the last layer computes in its own weights' dtype."""
    hidden = stream[1](stream[0](features))
    return stream[2](hidden.to(stream[2].weight.dtype))


def lower_heavy_layers(net: DuelingQNetwork, dtype: torch.dtype) -> DuelingQNetwork:
    """Cast the layers that hold nearly all the compute (convolutions, first layer of each
    stream) to ``dtype`` in place; the output layers stay float32.

    Why the output layers stay: Q-values of a sparse-reward task sit near 0.1-0.6 while the
    gaps between actions are ~1e-3 (gamma = 0.99, a detour of one or two steps). bfloat16's
    spacing there is 1e-3 to 4e-3, so a network computed in bfloat16 to the end ties or swaps
    its best actions, and argmax then takes action 0 (on a trained two-room network it changed
    the greedy action in 4.5-5.9% of the visited states, against 0-0.9% with these layers in
    float32), at a cost of two 128-wide layers."""
    for layer in (net.conv, net.value[0], net.advantage[0]):
        layer.to(dtype)
    return net


class WorkingCopy:
    """A copy of a network whose heavy layers (convolutions, first layer of each stream) compute
    in ``dtype``, for a learner that keeps float32 master weights and optimiser state.

    The copy folds the input scale 1/255 into its first layer's weights: it then reads integer
    pixels, exact in bfloat16, and saves one pass over the batch (measured: 8% of a bfloat16
    update at batch 32). ``pull`` copies the master weights in, ``push_gradients`` hands the
    copy's gradients to the master parameters in float32 (chain rule through the scale).
    """

    def __init__(self, master: DuelingQNetwork, dtype: torch.dtype):
        self.net = lower_heavy_layers(copy.deepcopy(master), dtype)
        self.net.prescaled = True
        self._pairs = list(zip(master.parameters(), self.net.parameters()))
        self._first = self.net.conv[0].weight
        self.pull()

    @torch.no_grad()
    def pull(self) -> None:
        for master, work in self._pairs:
            work.copy_(master / 255.0 if work is self._first else master)

    def push_gradients(self) -> None:
        for master, work in self._pairs:
            if work.grad is None:
                master.grad = None
                continue
            grad = work.grad.to(master.dtype)
            master.grad = grad / 255.0 if work is self._first else grad
