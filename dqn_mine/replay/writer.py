"""The actor's side of the replay: one :class:`NStepWriter` per environment stream.

Per step the writer does the least it can: it copies the frame straight into its shared slot
(after claiming the slot with the stream's ``cursor`` counter) and appends the action, reward,
carrying flag and Q values to local lists. Every ``flush_every`` steps, and at every episode end,
one vectorised commit writes the per-frame metadata (carrying, action history, episode step) of
every frame written so far, then the complete transitions (action, n-step return, discount,
bootstrap offset, initial priority), then bumps ``published``. The transition starting at frame
``t`` is complete once the actor has acted in ``s_{t+n}`` (its Q values give the bootstrap value of
the initial priority) or the episode has ended there.
"""

from __future__ import annotations

import numpy as np

from dqn_mine.replay.storage import CURSOR, EPISODES, PUBLISHED, STEPS, ReplayStorage

# Steps between publishes of a stream: the most a stream holds back from the learner (the
# replay-ratio throttle allows for it; config checks a full replay still fills a batch).
FLUSH_EVERY = 64


class NStepWriter:
    """Forms the n-step transitions of one stream and publishes them to the shared ring.

    ``flush_every`` is capped at ``stream_capacity - n_step - frame_stack`` so the writer never
    overwrites a frame its own pending transitions use. A new writer on a stream carries on after
    the previous one (the unpublished frames of a writer that died become non-transitions).
    """

    def __init__(self, storage: ReplayStorage, stream: int, eta: float = 1e-5,
                 flush_every: int = FLUSH_EVERY):
        lay = storage.layout
        if not 0 <= stream < lay.num_streams:
            raise ValueError(f"stream {stream} not in [0, {lay.num_streams})")
        self.storage, self.stream, self.eta = storage, stream, float(eta)
        self.n_step, self.history_len = lay.n_step, lay.history_len
        self.capacity = lay.stream_capacity                # slots of this stream's ring
        self.gamma = lay.gamma
        self.flush_every = max(1, min(int(flush_every),
                                      self.capacity - self.n_step - lay.frame_stack))
        self._slot0 = stream * self.capacity
        self._ctr = storage.counters[stream]                       # [8] int64, shared
        self._frames = storage.frames
        size = self.flush_every + self.n_step + 2          # frames oldest .. current, never more
        self._discounts = self.gamma ** np.arange(self.n_step, dtype=np.float64)      # [n]
        self._ret_idx = np.arange(size)[:, None] + np.arange(self.n_step)             # [size, n]
        self._hist_idx = np.arange(size)[:, None] + np.arange(self.history_len)       # [size, h]
        self._q = np.zeros((size, lay.num_actions), dtype=np.float32)  # Q(s_t, .), local t
        self._has_q = True
        # local window, index i = frame number - oldest: carrying per frame; action and reward
        # of the step taken in each frame but the current one
        self._carry: list = []
        self._acts: list = []
        self._rews: list = []
        self._hist0 = np.full(self.history_len, -1, dtype=np.int8)  # history of frame oldest
        self._step0 = 0                                    # episode step of frame oldest
        self._current: int | None = None                   # frame number of the current state
        self._unpublished_steps = 0
        self._next_frame = int(self._ctr[CURSOR])          # next frame number to write
        if self._ctr[PUBLISHED] < self._next_frame:        # a previous writer died mid-block
            self._commit_none(int(self._ctr[PUBLISHED]), self._next_frame)
            self._publish(self._next_frame)
        self._oldest = self._next_frame                    # the first unpublished frame

    # -- the actor's calls --------------------------------------------------------------------
    def begin_episode(self, frame, carrying) -> None:
        """Store ``s_0``. An unfinished previous episode is dropped (its last n transitions)."""
        if self._current is not None:
            self._abandon()
        self._hist0.fill(-1)
        self._step0 = 0
        self._current = self._next_frame
        self._write_frame(frame, carrying)

    def append(self, q_values, action: int, reward: float, frame, carrying,
               terminated: bool = False, truncated: bool = False, next_q=None) -> None:
        """Record ``a_t`` (chosen with ``q_values`` = Q(s_t, .)), ``r_{t+1}`` and ``s_{t+1}``.

        ``next_q`` = Q(s_{t+1}, .) only matters when ``truncated`` (bootstrap of the initial
        priority; 0 if omitted). With ``q_values=None`` the writer's priorities are NaN and the
        replay gives them its largest priority so far. ``q_values`` is copied.
        """
        cur = self._current
        if cur is None:
            raise RuntimeError("append() before begin_episode()")
        if q_values is None:
            self._has_q = False
        else:
            self._q[cur - self._oldest] = q_values
        self._acts.append(action)
        self._rews.append(reward)
        self._current = cur + 1
        self._unpublished_steps += 1
        self._write_frame(frame, carrying)
        if terminated or truncated:
            self._end_episode(bool(terminated), next_q)
        elif cur + 1 - self.n_step - self._oldest >= self.flush_every:
            self.flush()

    def history(self) -> np.ndarray:
        """The current state's action history: int8 [h], oldest first, -1 = no action yet."""
        h, acts = self.history_len, self._acts
        if len(acts) >= h:
            return np.array(acts[len(acts) - h:], dtype=np.int8)
        return np.concatenate([self._hist0[len(acts):], np.array(acts, dtype=np.int8)])

    def flush(self) -> None:
        """Publish every complete transition (those whose bootstrap state has been acted in)."""
        if self._current is None:
            return
        end = self._current - self.n_step            # Q(s_{t+n}) is known for every t < end
        if end > self._oldest:
            self._commit(end)
            self._publish(end)
            self._shift(end)

    # -- internals ----------------------------------------------------------------------------
    def _write_frame(self, frame, carrying) -> None:
        t = self._next_frame
        self._ctr[CURSOR] = t + 1                 # claim the slot before overwriting it
        self._frames[self._slot0 + t % self.capacity] = frame
        self._carry.append(carrying)
        self._next_frame = t + 1

    def _end_episode(self, terminated: bool, next_q) -> None:
        final = self._current - self._oldest            # local index of the final frame
        boot_final = 0.0 if terminated or next_q is None else float(np.max(next_q))
        self._commit(self._current, final=final, terminated=terminated, boot_final=boot_final)
        self._commit_none(self._current, self._current + 1)
        self._ctr[EPISODES] += 1
        self._publish(self._current + 1)
        self._shift(self._current + 1)
        self._current = None

    def _abandon(self) -> None:
        self.flush()
        self._commit(self._oldest)                  # frame metadata only
        self._commit_none(self._oldest, self._current + 1)
        self._publish(self._current + 1)
        self._shift(self._current + 1)
        self._current = None

    def _commit(self, end: int, final: int | None = None, terminated: bool = False,
                boot_final: float = 0.0) -> None:
        """Write the metadata of every frame written since ``oldest``, then the transitions
        starting at frames ``[oldest, end)`` (all in the current episode; ``final`` is the local
        index of the episode's final frame once it has ended)."""
        s, n = self.storage, self.n_step
        nf, b = self._next_frame - self._oldest, end - self._oldest   # frames held, transitions
        acts = np.array(self._acts, dtype=np.int64)                         # [steps]
        if self.history_len:
            ext = np.concatenate([self._hist0, acts.astype(np.int8)])      # [h + steps]
            self._put(s.history, self._oldest, ext[self._hist_idx[:nf]])   # [nf, h]
        self._put(s.carrying, self._oldest, self._carry)
        self._put(s.ep_step, self._oldest, self._step0 + np.arange(nf))
        if b <= 0:
            return
        t = np.arange(b)                                                    # local starts [b]
        k = np.full(b, n) if final is None else np.minimum(n, final - t)   # steps to bootstrap
        rew = np.zeros(b + n)                                               # zero after the end
        r = self._rews[:b + n - 1]
        rew[:len(r)] = r
        ret = rew[self._ret_idx[:b]] @ self._discounts                      # [b]
        disc = self.gamma ** k
        if terminated:
            disc[t + k == final] = 0.0              # the window reached the terminal state
        if self._has_q:
            boot = t + k                                                    # [b] local
            v = self._q[boot].max(axis=1).astype(np.float64)
            if final is not None:
                v[boot == final] = boot_final
            prio = np.abs(ret + disc * v - self._q[t, acts[:b]]) + self.eta
        else:
            prio = np.full(b, np.nan)
        self._put(s.action, self._oldest, acts[:b])
        self._put(s.ret, self._oldest, ret)
        self._put(s.discount, self._oldest, disc)
        self._put(s.boot_off, self._oldest, k)
        self._put(s.boot, self._oldest, s.slot(self.stream, self._oldest + t + k))
        self._put(s.priority, self._oldest, prio)

    def _commit_none(self, lo: int, hi: int) -> None:
        """Frames ``[lo, hi)`` start no transition (episode-final or dropped)."""
        s = self.storage
        for array, value in ((s.action, -1), (s.ret, 0.0), (s.discount, 0.0),
                             (s.priority, 0.0), (s.boot_off, 0), (s.boot, -1)):
            self._put(array, lo, np.full(hi - lo, value))

    def _put(self, array: np.ndarray, t0: int, values) -> None:
        """``array[slot(t)] = values[t - t0]`` for frames ``t0 ..``, as at most two slices."""
        values = np.asarray(values)
        count, start = values.shape[0], t0 % self.capacity
        first = min(count, self.capacity - start)
        array[self._slot0 + start: self._slot0 + start + first] = values[:first]
        if first < count:                                                   # wrapped
            array[self._slot0: self._slot0 + count - first] = values[first:]

    def _publish(self, end: int) -> None:
        self._ctr[PUBLISHED] = end                 # after the data: readers trust [.., end)
        self._ctr[STEPS] += self._unpublished_steps
        self._unpublished_steps = 0

    def _shift(self, new_oldest: int) -> None:
        """Forget the frames before ``new_oldest`` (the pending ones move to the front)."""
        d = new_oldest - self._oldest
        if d <= 0:
            return
        if self.history_len and d <= len(self._acts):       # history of the new oldest frame
            ext = np.concatenate([self._hist0, np.array(self._acts[:d], dtype=np.int8)])
            self._hist0 = ext[d:d + self.history_len].copy()
        keep = len(self._acts) - d
        if keep > 0:
            self._q[:keep] = self._q[d:d + keep]
        del self._carry[:d], self._acts[:d], self._rews[:d]
        self._step0 += d
        self._oldest = new_oldest
