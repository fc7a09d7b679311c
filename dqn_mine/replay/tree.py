"""Sum-tree and min-tree over ``capacity`` leaves, numpy, vectorised over a batch of indices.

Every operation takes a whole batch of indices and costs a few numpy calls per tree level; no
Python loop runs per sample. Parents are always recomputed from their children (never adjusted by
a delta), so sums cannot drift, and duplicate indices in one update are harmless: each duplicate
writes the same recomputed parent. Levels that are small enough are recomputed whole, which is
cheaper than gathering a batch of parents.

The two trees are shaped by what they do (measured at capacity 2^20, batches of 32 and 512, see
``dqn_mine/bench/replay.py``):

* :class:`SumTree` is searched and updated, so it is binary, in heap order (node ``i`` has children
  ``2i, 2i+1``): a search step is five numpy calls on [B] vectors, cheaper than one step of a
  32-ary tree, which must form prefix sums inside [B, 32] blocks (measured 1.5-3x slower per
  search at B = 16..512). The search starts with one ``np.searchsorted`` on the cumulative sum of
  the 2048-node level, replacing the top 11 steps; the levels above it are not kept at all.
* :class:`MinTree` is only updated (``min()`` reads the root), so it is 32-ary: 4 levels at 2^20,
  a [B, 32] gather and reduction for the two big ones, the two small ones recomputed whole.

Rows are gathered with ``take(..., axis=0)``: 2-D fancy indexing (``a[idx]`` on [n, K]) was half
as fast.
"""

from __future__ import annotations

import numpy as np


class SumTree:
    """Leaves hold non-negative values; :meth:`find` inverts their cumulative sum.

    Only the levels the search walks are kept: depth 11 (2048 nodes, or the leaves when fewer)
    down to the leaves. The search replaces the 11 levels above with one ``np.searchsorted`` on
    the cumulative sum of depth 11, and :meth:`total` is that sum's last entry; both are computed
    once after each change (``_cache``).
    """

    _TOP = 11       # the search starts at depth 11 (2048 nodes) with np.searchsorted
    _WHOLE = 13     # depths 11 and 12 (<= 4096 nodes) are recomputed whole on update

    def __init__(self, capacity: int):
        if capacity < 1:
            raise ValueError("capacity must be >= 1")
        self.capacity = int(capacity)
        self.depth = int(np.ceil(np.log2(self.capacity))) if self.capacity > 1 else 0
        self._p = 1 << self.depth                      # first leaf; leaves are [P, P + capacity)
        self.tree = np.zeros(2 * self._p, dtype=np.float64)   # heap order, root at 1
        self._pairs = self.tree.reshape(-1, 2)         # _pairs[i] = children of node i
        self._top = min(self._TOP, self.depth)
        self._whole = max(self._top, min(self._WHOLE, self.depth))
        self._cum: np.ndarray | None = None         # [2^top + 1] exclusive prefix sums
        self._total = 0.0

    @property
    def values(self) -> np.ndarray:
        """The leaves (a read-only view; write through :meth:`update`)."""
        v = self.tree[self._p: self._p + self.capacity]
        v.flags.writeable = False
        return v

    def __getitem__(self, indices):
        return self.tree[np.asarray(indices) + self._p]

    def total(self) -> float:
        self._cache()
        return self._total

    def update(self, indices, values) -> None:
        """Set ``leaves[indices] = values`` (>= 0) and recompute their ancestors."""
        i = np.asarray(indices, dtype=np.int64).ravel() + self._p
        self.tree[i] = values
        for _ in range(self.depth - self._whole):
            i >>= 1
            pair = self._pairs.take(i, axis=0)                      # [B, 2]
            self.tree[i] = pair[:, 0] + pair[:, 1]
        self._recompute(self._whole)

    def _recompute(self, depth: int) -> None:
        """Recompute the levels above ``depth`` whole, up to the search's top level."""
        self._cum = None
        t = self.tree
        for d in range(depth - 1, self._top - 1, -1):
            lo = 1 << d
            np.add(t[2 * lo: 4 * lo: 2], t[2 * lo + 1: 4 * lo: 2], out=t[lo: 2 * lo])

    def _cache(self) -> np.ndarray:
        if self._cum is None:
            lo = 1 << self._top
            cum = np.zeros(lo + 1)
            self.tree[lo: 2 * lo].cumsum(out=cum[1:])                  # sequential: monotone
            self._total = float(cum[-1])
            cum[-1] = np.inf            # u past the end (rounding): last node, caught by find
            self._cum = cum
        return self._cum

    def find(self, prefix_sums) -> np.ndarray:
        """For each prefix sum ``u`` in ``[0, total())``, the leaf ``i`` with
        ``cumsum[i-1] <= u < cumsum[i]`` (int64 [B]). A leaf whose value is 0 is never returned:
        where rounding lands on one (only at a boundary next to an empty leaf), the row is redone
        against the exact cumulative sum, and a ``u`` past the end takes the last positive leaf."""
        return self.find_with_values(prefix_sums)[0]

    def find_with_values(self, prefix_sums):
        """:meth:`find` and the values of the found leaves: (int64 [B], float64 [B])."""
        if not self.total() > 0:
            raise ValueError("find() on a tree whose total is 0")
        u = np.array(prefix_sums, dtype=np.float64).ravel()                # [B], a copy
        node = self._descend(u)                                            # heap indices
        values = self.tree.take(node)
        node -= self._p
        bad = values <= 0
        if bad.any():
            u = np.asarray(prefix_sums, dtype=np.float64).ravel()
            node[bad] = self._find_exact(u[bad])
            values[bad] = self.tree.take(node[bad] + self._p)
        return node, values

    def _descend(self, u: np.ndarray) -> np.ndarray:
        """Heap index of the leaf holding each ``u`` (``u`` is consumed)."""
        cum = self._cache()
        lo = 1 << self._top
        node = np.searchsorted(cum, u, side="right")                       # 1 .. 2^top
        node -= 1
        u -= cum.take(node)
        node += lo
        tree = self.tree
        for _ in range(self.depth - self._top):  # binary steps: 5 calls on [B] vectors each
            node <<= 1                          # left child
            left = tree.take(node)
            right = u >= left
            u -= left * right
            node += right
        return node

    def _find_exact(self, u: np.ndarray) -> np.ndarray:
        leaves = self.tree[self._p: self._p + self.capacity]
        cum = np.cumsum(leaves)                     # sequential, so monotone: ties skip zeros
        idx = np.searchsorted(cum, u, side="right")
        last = np.flatnonzero(leaves > 0)[-1]
        return np.minimum(idx, last)


class MinTree:
    """Leaves hold values (+inf = empty); :meth:`min` is the smallest, read at the root."""

    ARITY = 32
    WHOLE = 2   # levels of at most WHOLE * K nodes are recomputed whole

    def __init__(self, capacity: int, dtype=np.float64, arity: int = ARITY):
        if capacity < 1:
            raise ValueError("capacity must be >= 1")
        self.capacity = int(capacity)
        self.arity = k = int(arity)
        self.levels = []                   # levels[0] = leaves, levels[-1] = [root]
        n = self.capacity
        while True:                        # each level padded with +inf to a multiple of K
            parents = -(-n // k)
            self.levels.append(np.full(parents * k, np.inf, dtype=dtype))
            n = parents
            if n == 1:
                break
        self.levels.append(np.full(1, np.inf, dtype=dtype))
        self._blocks = [lv.reshape(-1, k) for lv in self.levels[:-1]]     # [parents, K]
        # levels with at most 2K nodes are cheaper to recompute whole than to gather
        self._whole = next(level for level in range(1, len(self.levels))
                           if self._blocks[level - 1].shape[0] <= self.WHOLE * k)

    @property
    def values(self) -> np.ndarray:
        v = self.levels[0][: self.capacity]
        v.flags.writeable = False
        return v

    def min(self) -> float:
        return float(self.levels[-1][0])

    def update(self, indices, values) -> None:
        """Set ``leaves[indices] = values`` and recompute their ancestors."""
        i = np.asarray(indices, dtype=np.int64).ravel()
        self.levels[0][i] = values
        reduce = np.minimum.reduce
        for level in range(1, len(self.levels)):
            block = self._blocks[level - 1]
            if level >= self._whole:
                reduce(block, axis=1, out=self.levels[level][: block.shape[0]])
            else:
                i = i // self.arity
                self.levels[level][i] = reduce(block.take(i, axis=0), axis=1)   # [B, K] -> [B]
