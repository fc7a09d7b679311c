"""The replay's shared arrays: what to allocate (:class:`ReplayLayout`) and how to read them.

One ring per environment stream: stream ``k`` owns slots ``[k*M, (k+1)*M)`` and its frame number
``t`` lives in slot ``k*M + t % M``. Per slot (``C = S*M`` slots):

=============  ===================  ==========================================================
block          shape, dtype         meaning (magic fill = never written)
=============  ===================  ==========================================================
frames         [C, 3, H, W] u8      the frame (never pre-touched: pages commit as the ring fills)
carrying       [C] f32              carrying flag of the frame's state (NaN)
history        [C, h] i8            the h actions before the frame, oldest first, -1 = none (-128)
ep_step        [C] i32              step of the frame within its episode (-1)
action         [C] i8               action taken at the frame (-128)
ret            [C] f32              n-step return of the transition starting here (NaN)
discount       [C] f32              gamma^k, or 0 when it terminated within the window (NaN)
boot_off       [C] u8               k: the bootstrap frame is t + k; 0 = starts no transition (255)
boot           [C] i32              slot of that bootstrap frame (saves the sampler the arithmetic)
priority       [C] f32              the actor's initial priority |TD| + eta (NaN)
counters       [S, 8] i64           per stream: cursor, published, env steps, episodes (0)
=============  ===================  ==========================================================

``counters`` rows are 64 bytes apart so writers on different streams never share a cache line.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dqn_mine.env.interface import FRAME_SHAPE, NUM_ACTIONS
from dqn_mine.shared import BlockSpec, SharedBlocks

# columns of the counters block
CURSOR, PUBLISHED, STEPS, EPISODES = 0, 1, 2, 3
_COUNTER_COLS = 8

BLOCK_NAMES = ("frames", "carrying", "history", "ep_step", "action", "ret", "discount",
               "boot_off", "boot", "priority", "counters")


@dataclass(frozen=True)
class ReplayLayout:
    """Sizes of the replay; ``capacity = num_streams * stream_capacity`` transitions."""

    num_streams: int                               # one ring per environment stream
    stream_capacity: int                           # M: slots per stream
    frame_shape: tuple[int, ...] = FRAME_SHAPE     # one RGB frame, channels first
    history_len: int = 20                          # h: actions kept as the action history
    n_step: int = 6                                # n of the n-step return
    gamma: float = 0.99                            # discount per step
    frame_stack: int = 1                           # f: frames stacked into an observation
    num_actions: int = NUM_ACTIONS                 # size of the Q vector an actor supplies
    demo_streams: int = 0                          # the last streams: demonstrations, written once

    def __post_init__(self):
        if not 1 <= self.n_step <= 254:
            raise ValueError("n_step must be in [1, 254]")
        if self.num_streams < 1 or self.frame_stack < 1 or self.history_len < 0:
            raise ValueError("num_streams, frame_stack must be >= 1 and history_len >= 0")
        if not 0 <= self.demo_streams < self.num_streams:
            raise ValueError("demo_streams must be in [0, num_streams)")
        if self.stream_capacity < self.n_step + self.frame_stack + 1:
            raise ValueError(f"stream_capacity {self.stream_capacity} is too small for "
                             f"n_step {self.n_step} and frame_stack {self.frame_stack}")

    @classmethod
    def from_capacity(cls, capacity: int, num_streams: int, **kw) -> ReplayLayout:
        """Split ``capacity`` transitions evenly over ``num_streams`` rings (rounding down)."""
        return cls(num_streams=num_streams, stream_capacity=capacity // num_streams, **kw)

    @property
    def capacity(self) -> int:
        return self.num_streams * self.stream_capacity

    @property
    def demo_from(self) -> int:
        """First slot of the demonstrations (``capacity`` when there are none)."""
        return (self.num_streams - self.demo_streams) * self.stream_capacity

    def block_specs(self) -> list[BlockSpec]:
        """Every shared array of the replay (``SharedBlocks.create`` allocates them)."""
        c, h = self.capacity, self.history_len
        return [
            BlockSpec("frames", (c, *self.frame_shape), "uint8", None),
            BlockSpec("carrying", (c,), "float32", np.nan),
            BlockSpec("history", (c, h), "int8", -128),
            BlockSpec("ep_step", (c,), "int32", -1),
            BlockSpec("action", (c,), "int8", -128),
            BlockSpec("ret", (c,), "float32", np.nan),
            BlockSpec("discount", (c,), "float32", np.nan),
            BlockSpec("boot_off", (c,), "uint8", 255),
            BlockSpec("boot", (c,), "int32" if c < 2 ** 31 else "int64", -1),
            BlockSpec("priority", (c,), "float32", np.nan),
            BlockSpec("counters", (self.num_streams, _COUNTER_COLS), "int64", 0),
        ]

    @property
    def nbytes(self) -> int:
        return sum(s.nbytes for s in self.block_specs())


class ReplayStorage:
    """Numpy views of the replay's shared arrays, plus the gathers the sampler needs."""

    def __init__(self, layout: ReplayLayout, blocks: SharedBlocks):
        self.layout = layout
        self.blocks = blocks
        for name in BLOCK_NAMES:
            setattr(self, name, blocks[name])
        self.capacity = layout.capacity
        self.stream_capacity = layout.stream_capacity

    def total_written(self) -> int:
        """Environment steps published by all writers (the denominator of the replay ratio)."""
        return int(self.counters[:, STEPS].sum())

    def slot(self, stream: int, t):
        """Slot of frame number ``t`` of ``stream`` (int or int array)."""
        return stream * self.stream_capacity + t % self.stream_capacity

    def bootstrap_slots(self, slots: np.ndarray) -> np.ndarray:
        """Slot of each transition's bootstrap frame s_{t+k} (same stream, ``boot_off`` later)."""
        return self.boot.take(slots).astype(np.int64)

    def gather_obs(self, slots: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Observations of ``slots``: uint8 [B, 3f, H, W], frames before the episode start zero."""
        f, fs = self.layout.frame_stack, self.layout.frame_shape
        b = slots.shape[0]
        if out is None:
            out = np.empty((b, f * fs[0], *fs[1:]), dtype=np.uint8)
        if f == 1:                       # 'clip': with 'raise' numpy would buffer a copy of out
            self.frames.take(slots, axis=0, out=out, mode="clip")
            return out
        m = self.stream_capacity
        back = np.arange(f - 1, -1, -1)                                    # [f] oldest first
        idx = slots[:, None] - slots[:, None] % m + (slots[:, None] % m - back) % m  # [B, f]
        stacked = out.reshape(b, f, *fs)
        np.take(self.frames, idx, axis=0, out=stacked, mode="clip")
        before_start = back[None, :] > self.ep_step[slots][:, None]      # [B, f]
        stacked[before_start] = 0
        return out
