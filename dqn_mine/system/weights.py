"""Weight broadcast: the learner publishes its network into shared memory, actors pull it.

Two blocks (declared by :meth:`WeightBroadcast.specs`, allocated by ``SharedBlocks``):

- ``weights``: every floating tensor of the network's ``state_dict`` (parameters and buffers),
  flattened in ``state_dict`` order into one float32 vector. Filled with NaN at creation, so a
  network that loaded weights before the first publish is obviously broken.
- ``weights_seq``: an int64 sequence lock. The writer makes it odd before copying and even after;
  a reader copies the vector out, then re-reads the counter: an odd or changed value means the
  copy may be torn, so it retries. Version = seq // 2 = number of completed publishes (0: none).

There is one writer (the learner); any number of readers. The lock relies on the stores of one
process becoming visible to another in program order, which holds on x86-64 (TSO); the Python and
numpy calls between the counter and the data are no compiler-reorderable unit either.
"""

from __future__ import annotations

import time

import numpy as np
import torch
from torch import nn

from dqn_mine.shared import BlockSpec, SharedBlocks

WEIGHTS = "weights"
SEQ = "weights_seq"


def _tensors(net: nn.Module) -> list[torch.Tensor]:
    """The floating tensors of ``net`` that travel, in a fixed (state_dict) order."""
    return [t for t in net.state_dict().values() if t.is_floating_point()]


def num_values(net: nn.Module) -> int:
    return sum(t.numel() for t in _tensors(net))


class WeightBroadcast:
    """Publisher (learner) and reader (actor) side of the shared weights of one network."""

    def __init__(self, blocks: SharedBlocks):
        self.flat_np = blocks[WEIGHTS]  # float32 [P]
        self.flat = torch.from_numpy(self.flat_np)  # float32 [P], shares memory with the block
        self.seq = blocks[SEQ]  # int64 [1]
        self._scratch: torch.Tensor | None = None  # reader's private copy, float32 [P]

    @staticmethod
    def specs(net: nn.Module) -> list[BlockSpec]:
        return [BlockSpec(WEIGHTS, (num_values(net),), "float32", fill=np.nan),
                BlockSpec(SEQ, (1,), "int64", fill=0)]

    # -- learner side ------------------------------------------------------------------------
    def publish(self, net: nn.Module) -> int:
        """Copy ``net``'s weights into shared memory; returns the new version."""
        with torch.no_grad():
            # One device-to-host copy of the whole vector (a CUDA net is flattened on the GPU).
            vector = torch.cat([t.detach().reshape(-1).float() for t in _tensors(net)])  # [P]
            if vector.numel() != self.flat.numel():
                raise ValueError(f"network has {vector.numel()} weights, the shared block "
                                 f"{self.flat.numel()}")
            vector = vector.cpu()
            seq = int(self.seq[0])
            self.seq[0] = seq + 1  # odd: writing
            self.flat.copy_(vector)
            self.seq[0] = seq + 2  # even: consistent
        return (seq + 2) // 2

    def version(self) -> int:
        """Completed publishes so far (0 before the first)."""
        return int(self.seq[0]) // 2

    # -- actor side --------------------------------------------------------------------------
    def pull(self, net: nn.Module, last_version: int, timeout: float = 5.0) -> int | None:
        """Load the published weights into ``net`` if the version moved past ``last_version``.

        Returns the version loaded, or None when there is nothing new (or nothing published yet,
        or no consistent copy could be read within ``timeout`` seconds: try again later).
        """
        deadline = time.monotonic() + timeout
        while True:
            seq = int(self.seq[0])
            if seq == 0 or seq // 2 == last_version and seq % 2 == 0:
                return None
            if seq % 2 == 0:
                self._snapshot()
                if int(self.seq[0]) == seq:  # no publish began meanwhile: the copy is whole
                    self._load(net)
                    return seq // 2
            if time.monotonic() > deadline:
                return None
            time.sleep(0.0005)  # a publish is in progress

    def _snapshot(self) -> None:
        """Copy the shared vector into the private scratch buffer (may be torn: caller checks)."""
        if self._scratch is None:
            self._scratch = torch.empty_like(self.flat)
        self._scratch.copy_(self.flat)

    def _load(self, net: nn.Module) -> None:
        offset = 0
        with torch.no_grad():
            for t in _tensors(net):
                n = t.numel()
                t.copy_(self._scratch[offset:offset + n].view_as(t))
                offset += n
