"""The learner's side of the replay: priorities, prioritised sampling, importance weights.

The learner process owns the trees (nobody else touches them, so no lock sits on the sampling
path). Writers only publish counters; :meth:`PrioritizedReplay.ingest` turns them into tree updates.
Leaf ``i`` of both trees is slot ``i`` of the storage; the sum-tree holds ``p_i^zeta``, the
min-tree the same value for live transitions and +inf elsewhere (so it gives the largest weight).
"""

from __future__ import annotations

from collections import deque
from typing import NamedTuple

import numpy as np

from dqn_mine.replay.storage import CURSOR, PUBLISHED, ReplayStorage
from dqn_mine.replay.tree import MinTree, SumTree


class Batch(NamedTuple):
    """A sampled batch; ``B`` = batch size, ``f`` = frame stack, ``h`` = history length."""

    obs: np.ndarray            # uint8 [B, 3f, H, W]  s_t
    history: np.ndarray        # int8 [B, h]          actions before s_t, oldest first, -1 = none
    carrying: np.ndarray       # float32 [B]
    action: np.ndarray         # int64 [B]            a_t
    ret: np.ndarray            # float32 [B]          sum_{i<k} gamma^i r_{t+i+1}
    discount: np.ndarray       # float32 [B]          gamma^k, 0 if it terminated in the window
    next_obs: np.ndarray       # uint8 [B, 3f, H, W]  s_{t+k}
    next_history: np.ndarray   # int8 [B, h]
    next_carrying: np.ndarray  # float32 [B]
    weights: np.ndarray        # float32 [B]          IS weights / max; 0 = overwritten meanwhile
    indices: np.ndarray        # int64 [B]            slots, for update_priorities
    # int64 [B] frame number each sampled slot held, for update_priorities (None: not recorded)
    stamps: np.ndarray | None = None
    demo: np.ndarray | None = None   # bool [B]: a demonstration's transition (None: not recorded)

    @staticmethod
    def empty(layout, batch_size: int) -> Batch:
        """Preallocated arrays to pass as ``sample(..., out=)``."""
        b, f, h = batch_size, layout.frame_stack, layout.history_len
        obs_shape = (b, f * layout.frame_shape[0], *layout.frame_shape[1:])
        return Batch(np.empty(obs_shape, np.uint8), np.empty((b, h), np.int8),
                     np.empty(b, np.float32), np.empty(b, np.int64), np.empty(b, np.float32),
                     np.empty(b, np.float32), np.empty(obs_shape, np.uint8),
                     np.empty((b, h), np.int8), np.empty(b, np.float32), np.empty(b, np.float32),
                     np.empty(b, np.int64), np.empty(b, np.int64), np.empty(b, bool))


BETA0 = 0.4   # PER's and the study's initial importance-sampling exponent


def beta_at(update: int, total_updates: int, beta0: float = BETA0) -> float:
    """Importance-sampling exponent, linear from ``beta0`` at update 0 to 1 at ``total_updates``."""
    if total_updates <= 0:
        return 1.0
    return float(min(1.0, beta0 + (1.0 - beta0) * update / total_updates))


class PrioritizedReplay:
    """Proportional prioritised sampling over a :class:`ReplayStorage` (learner process only).

    Each new transition's priority comes from its writer (Ape-X); one written without Q values
    (NaN) gets the largest priority seen so far. ``zeta=0`` is uniform replay.
    Demonstrations (the layout's last ``demo_streams``) get ``demo_bonus`` added to their
    priority, as DQfD's epsilon_d, so they keep being sampled once learned.
    """

    def __init__(self, storage: ReplayStorage, zeta: float = 0.6, eta: float = 1e-5,
                 seed: int | None = 0, demo_bonus: float = 0.0):
        self.storage, self.zeta, self.eta = storage, float(zeta), float(eta)
        self.demo_from, self.demo_bonus = storage.layout.demo_from, float(demo_bonus)
        self.rng = np.random.default_rng(seed)
        self.sum_tree = SumTree(storage.capacity)
        self.min_tree = MinTree(storage.capacity)
        lay = storage.layout
        self._m, self._lag = lay.stream_capacity, lay.frame_stack - 1
        # [S] per stream: published at the last ingest, and the first live frame number (the
        # first ingest picks up everything already written)
        self._seen = np.zeros(lay.num_streams, dtype=np.int64)
        self._alive_from = np.zeros(lay.num_streams, dtype=np.int64)
        self._live = 0
        self._strata = np.empty(0)
        self._max_p = 1.0                                    # largest |delta| + eta so far
        # (slots, p^zeta, frame numbers or None) from update_priorities, any thread
        self._pending: deque = deque()

    def __len__(self) -> int:
        """Transitions that can be sampled now."""
        return self._live

    # -- writers -> trees ---------------------------------------------------------------------
    def ingest(self) -> int:
        """Add transitions published since the last call, zero those overwritten and apply the
        queued priority updates, in one tree update; returns how many transitions were added."""
        ctr = self.storage.counters
        published = ctr[:, PUBLISHED].copy()          # read before the cursors (see storage)
        cursor = ctr[:, CURSOR].copy()
        alive_from = np.maximum(self._alive_from, cursor - self._m + self._lag)
        moved = np.flatnonzero((published != self._seen) | (alive_from != self._alive_from))
        if moved.size == 0:
            self.apply_priority_updates()
            return 0
        dead, new = [], []
        for k in moved:
            old_from, seen = self._alive_from[k], self._seen[k]
            dead.append(self._slots(k, old_from, min(alive_from[k], seen)))
            new.append(self._slots(k, max(seen, alive_from[k]), published[k]))
        self._seen, self._alive_from = published, alive_from
        dead, new = np.concatenate(dead), np.concatenate(new)
        self._live -= int(np.count_nonzero(self.sum_tree[dead]))
        upd_idx, upd_p = self._drain(exclude=dead if dead.size else None)
        # a lapped ring can kill and refill one slot in the same call: the new one wins (the
        # three index sets below are disjoint, so the order of a fancy assignment never matters)
        if dead.size and new.size:
            dead = dead[~np.isin(dead, new)]
        starts = self.storage.boot_off[new] > 0      # episode-final frames start nothing
        real = new[starts]
        p = self.storage.priority[real].astype(np.float64)
        p[np.isnan(p)] = self._max_p                 # NaN: a writer without Q values
        values = np.zeros(new.size)                  # [new] p^zeta, 0 where nothing starts
        values[starts] = p ** self.zeta
        self._live += int(np.count_nonzero(values))
        self._set(np.concatenate([upd_idx, dead, new]),
                  np.concatenate([upd_p, np.zeros(dead.size), values]))
        return int(real.size)

    def apply_priority_updates(self) -> None:
        """Apply the priorities queued by :meth:`update_priorities` (ingest and sample do)."""
        if self._pending:
            self._set(*self._drain())

    def _drain(self, exclude: np.ndarray | None = None):
        """The queued (slots, p^zeta), minus slots that died since they were sampled (a zero
        leaf, or in ``exclude``): those stay dead; and minus slots that now hold another
        transition than the one sampled (its frame number moved on): the update is not its."""
        chunks = []
        while self._pending:
            chunks.append(self._pending.popleft())
        if not chunks:
            return np.empty(0, dtype=np.int64), np.empty(0)
        idx = np.concatenate([c[0] for c in chunks])
        p = np.concatenate([c[1] for c in chunks])
        keep = self.sum_tree[idx] > 0
        if exclude is not None:
            keep &= ~np.isin(idx, exclude)
        for start, (slots, _, stamps) in zip(np.cumsum([0] + [c[0].size for c in chunks]),
                                             chunks):
            if stamps is not None:
                keep[start:start + slots.size] &= self.frame_numbers(slots) == stamps
        if keep.all():
            return idx, p
        return idx[keep], p[keep]

    def frame_numbers(self, slots: np.ndarray) -> np.ndarray:
        """Frame number (counted since its stream began) each slot holds as of the last ingest:
        the one in ``[alive_from, alive_from + M)`` congruent to the slot's position."""
        m = self._m
        start = self._alive_from.take(slots // m)
        return start + (slots % m - start) % m

    def _slots(self, stream: int, lo: int, hi: int) -> np.ndarray:
        if hi <= lo:
            return np.empty(0, dtype=np.int64)
        return stream * self._m + np.arange(lo, hi, dtype=np.int64) % self._m

    def _set(self, slots: np.ndarray, values: np.ndarray) -> None:
        self.sum_tree.update(slots, values)
        self.min_tree.update(slots, np.where(values > 0, values, np.inf))

    # -- learner ------------------------------------------------------------------------------
    def sample(self, batch_size: int, beta: float, out: Batch | None = None) -> Batch:
        """A stratified prioritised batch; ``out`` (see :meth:`Batch.empty`) is filled in place
        (C-contiguous arrays of the right shapes: e.g. numpy views of pinned torch tensors)."""
        if self._pending:
            self.apply_priority_updates()
        total = self.sum_tree.total()
        if self._live == 0 or not total > 0:
            raise ValueError("the replay holds no transition yet (call ingest() first)")
        b = batch_size
        if self._strata.shape[0] != b:
            self._strata = np.arange(b, dtype=np.float64)
        u = self.rng.random(b)
        u += self._strata
        u *= total / b                                                     # [B] stratified
        idx, p = self.sum_tree.find_with_values(u)                         # [B] slots, p^zeta
        if out is None:
            out = Batch.empty(self.storage.layout, b)
        s = self.storage
        boot = s.boot.take(idx)                                            # [B] slots of s_{t+k}
        s.gather_obs(idx, out.obs)
        s.gather_obs(boot, out.next_obs)
        s.history.take(idx, axis=0, out=out.history, mode="clip")
        s.history.take(boot, axis=0, out=out.next_history, mode="clip")
        s.carrying.take(idx, out=out.carrying, mode="clip")
        s.carrying.take(boot, out=out.next_carrying, mode="clip")
        s.ret.take(idx, out=out.ret, mode="clip")
        s.discount.take(idx, out=out.discount, mode="clip")
        out.action[:] = s.action.take(idx)
        out.indices[:] = idx
        if out.demo is not None:
            np.greater_equal(idx, self.demo_from, out=out.demo)
        if out.stamps is not None:
            out.stamps[:] = self.frame_numbers(idx)
        # w_i = (N P_i)^-beta / max_j (N P_j)^-beta = (p_i / p_min)^-beta
        p /= self.min_tree.min()
        np.power(p, -beta, out=out.weights, casting="same_kind")
        stale = self._drop_overwritten(idx, out.weights)
        if stale is not None:
            # A lapped slot may now start no transition (action -1): its weight is 0, so any
            # valid action will do, but an index of -1 would crash the learner's gather.
            out.action[stale] = np.maximum(out.action[stale], 0)
        return out

    def _drop_overwritten(self, idx: np.ndarray, weights: np.ndarray) -> np.ndarray | None:
        """A writer may have lapped a sampled window while we gathered it: weight and priority 0.
        Returns the mask of such samples (None when there are none).

        Sampled slot ``i`` of stream ``k`` held frame number ``t`` with ``alive_from[k] <= t <
        alive_from[k] + M`` at the last ingest; it is stale once ``cursor[k] - M + lag > t``, so
        compare slot positions relative to ``alive_from``: ``(pos - alive_from) % M`` against
        ``cursor - M + lag - alive_from`` (per stream, computed once)."""
        m = self._m
        lapped = self.storage.counters[:, CURSOR] - (m - self._lag) - self._alive_from   # [S]
        if not (lapped > 0).any():
            return None
        stream = idx // m
        stale = (idx - self._alive_from.take(stream)) % m < lapped.take(stream)
        if not stale.any():
            return None
        weights[stale] = 0.0
        gone = np.unique(idx[stale])
        gone = gone[self.sum_tree[gone] > 0]
        self._live -= gone.size
        self._set(gone, np.zeros(gone.size))
        return stale

    # -- saving and restoring ----------------------------------------------------------------
    def state_dict(self) -> dict:
        """Everything besides the storage that sampling depends on (queued updates applied)."""
        self.apply_priority_updates()
        return {"leaves": self.sum_tree.values.copy(), "seen": self._seen.copy(),
                "alive_from": self._alive_from.copy(), "live": self._live,
                "max_p": self._max_p, "rng": self.rng.bit_generator.state}

    def load_state_dict(self, state: dict) -> None:
        """Restore :meth:`state_dict` over a storage that holds the saved arrays again."""
        leaves = np.asarray(state["leaves"], dtype=np.float64)
        if leaves.shape != (self.storage.capacity,):
            raise ValueError(f"saved priorities are for {leaves.size} slots, the replay has "
                             f"{self.storage.capacity}")
        self._pending.clear()
        self._set(np.arange(leaves.size), leaves)
        self._seen = np.array(state["seen"], dtype=np.int64)
        self._alive_from = np.array(state["alive_from"], dtype=np.int64)
        self._live, self._max_p = int(state["live"]), float(state["max_p"])
        self.rng.bit_generator.state = state["rng"]

    def update_priorities(self, indices, td_abs, stamps=None) -> None:
        """Queue p = |delta| + eta for sampled slots. Applied at the next :meth:`ingest` or
        :meth:`sample`, in the thread that samples: so the learner may call this from its
        training thread without a lock. A slot that died meanwhile stays dead (its transition
        was overwritten; the update would belong to the new one). With ``stamps`` (the batch's
        ``stamps``), a slot already refilled with a newer transition keeps that one's priority."""
        idx = np.array(indices, dtype=np.int64).ravel()
        if stamps is not None:
            stamps = np.array(stamps, dtype=np.int64).ravel()
        p = np.abs(np.asarray(td_abs, dtype=np.float64)).ravel()
        if p.size:
            p += self.eta
            if self.demo_bonus:
                p[idx >= self.demo_from] += self.demo_bonus
            top = float(p.max())
            if not np.isfinite(top):          # NaN/inf would poison every later sample
                raise ValueError("update_priorities: TD errors must be finite")
            self._max_p = max(self._max_p, top)
            p **= self.zeta
            self._pending.append((idx, p, stamps))
