"""The dueling Q-network of SPEC section 4.

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

from typing import Tuple

import torch
import torch.nn.functional as F
from torch import nn

FRAME_SHAPE = (3, 44, 76)
NUM_ACTIONS = 6


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
                 frame_shape: Tuple[int, int, int] = FRAME_SHAPE):
        super().__init__()
        self.frame_stack = frame_stack
        self.history_len = history_len
        self.num_actions = num_actions
        channels, height, width = frame_shape
        self.obs_shape = (channels * frame_stack, height, width)
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

        Computes in the dtype of the weights: float32, or bfloat16 in actors that act in it.
        """
        dtype = self.value[0].weight.dtype
        x = self.conv(obs.to(dtype) / 255.0)  # [B, 768]
        parts = [x, carrying.to(dtype).reshape(-1, 1)]  # carrying: [B, 1]
        if self.history_len > 0:
            parts.append(one_hot_history(history, self.num_actions).to(dtype))  # [B, 6h]
        features = torch.cat(parts, dim=1)  # [B, 768 + 6h + 1]
        value = self.value(features)  # [B, 1]
        advantage = self.advantage(features)  # [B, A]
        return value + advantage - advantage.mean(dim=1, keepdim=True)  # [B, A]
