"""Several writer processes (spawn) and a learner sampling while they write: nothing lost,
nothing duplicated, every sampled transition consistent with the episodes that were played."""

import bisect
import multiprocessing as mp

import numpy as np
import pytest

from dqn_mine.replay import NStepWriter, PrioritizedReplay, ReplayLayout, ReplayStorage
from dqn_mine.replay.storage import CURSOR, PUBLISHED
from dqn_mine.shared import SharedBlocks, leftover_segments

GAMMA, N = 0.9, 3
STREAMS_PER_ACTOR, ACTORS, STEPS = 2, 3, 3000


def episode_lengths(stream):
    return [3 + (stream * 5 + e * 7) % 13 for e in range(STEPS)]


def reward(stream, t):
    return ((stream * 31 + t) % 7) / 7


def episodes(stream):
    """(first frame, final frame, terminated) of each episode of ``stream`` in its first STEPS
    environment steps."""
    out, t, steps = [], 0, 0
    for e, length in enumerate(episode_lengths(stream)):
        length = min(length, STEPS - steps)
        if length == 0:
            break
        out.append((t, t + length, e % 2 == 0))
        t, steps = t + length + 1, steps + length
    return out


def frame(stream, t):
    return np.array([stream << 32 | t], dtype=np.int64).view(np.uint8)


def actor(handle, layout, streams):
    blocks = SharedBlocks.attach(handle)
    storage = ReplayStorage(layout, blocks)
    writers = {k: NStepWriter(storage, k, flush_every=8) for k in streams}
    plans = {k: episodes(k) for k in streams}
    q = np.zeros(6, np.float32)
    for i in range(max(len(p) for p in plans.values())):     # interleave the streams
        for k in streams:
            if i >= len(plans[k]):
                continue
            first, final, terminated = plans[k][i]
            writers[k].begin_episode(frame(k, first), 0.0)
            for t in range(first, final):
                writers[k].append(q, t % 6, reward(k, t), frame(k, t + 1), 0.0,
                                  terminated=terminated and t + 1 == final,
                                  truncated=not terminated and t + 1 == final, next_q=q)
    del storage, writers
    blocks.close()


def check(storage, slots, obs, next_obs, ret, discount, plans):
    m = storage.stream_capacity
    ids, next_ids = obs.view(np.int64)[:, 0], next_obs.view(np.int64)[:, 0]
    for slot, i, j, r, d in zip(slots, ids, next_ids, ret, discount):
        stream, t = int(i) >> 32, int(i) & 0xFFFFFFFF
        assert stream == slot // m and t % m == slot % m
        e = bisect.bisect_right(plans[stream], (t, 1 << 62)) - 1
        first, final, terminated = plans[stream][e]
        assert first <= t <= final
        k = min(N, final - t)
        assert t < final and int(j) == (stream << 32 | (t + k))
        assert np.isclose(r, sum(GAMMA ** x * reward(stream, t + x) for x in range(k)))
        assert np.isclose(d, 0.0 if terminated and t + k == final else GAMMA ** k)


@pytest.mark.parametrize("capacity", [4096, 48])
def test_writer_processes_lose_and_duplicate_nothing(capacity):
    """With 4096 slots per stream nothing is overwritten: every transition must arrive once.
    With 48 the rings wrap ~70 times while the learner samples: a sample must be consistent or,
    if a writer lapped it during the gather, carry weight 0; at the end exactly the transitions
    still in the rings are alive."""
    streams = STREAMS_PER_ACTOR * ACTORS
    layout = ReplayLayout(num_streams=streams, stream_capacity=capacity, frame_shape=(8,),
                          history_len=4, n_step=N, gamma=GAMMA)
    plans = {k: episodes(k) for k in range(streams)}
    expected = sum(final - first for p in plans.values() for first, final, _ in p)
    assert expected == streams * STEPS
    ctx = mp.get_context("spawn")
    with SharedBlocks.create(layout.block_specs()) as blocks:
        storage = ReplayStorage(layout, blocks)
        procs = [ctx.Process(target=actor, args=(blocks.handle(), layout,
                                                  list(range(a * STREAMS_PER_ACTOR,
                                                             (a + 1) * STREAMS_PER_ACTOR))))
                 for a in range(ACTORS)]
        for p in procs:
            p.start()
        replay = PrioritizedReplay(storage, seed=0)
        added, sampled, dropped = 0, 0, 0
        while any(p.is_alive() for p in procs) or added < expected:
            added += replay.ingest()
            if len(replay):                       # sample while the writers write
                b = replay.sample(64, 0.5)
                ok = b.weights > 0
                dropped += int((~ok).sum())
                check(storage, b.indices[ok], b.obs[ok], b.next_obs[ok], b.ret[ok],
                      b.discount[ok], plans)
                sampled += 1
            if not any(p.is_alive() for p in procs):
                break
        for p in procs:
            p.join(timeout=60)
            assert p.exitcode == 0
        added += replay.ingest()
        live = np.flatnonzero(replay.sum_tree.values > 0)
        assert sampled > 0 and len(replay) == live.size
        if capacity == 4096:                                            # every one, once
            assert added == expected and live.size == expected
        else:                                   # exactly the published, unlapped transitions
            want = [k * capacity + t % capacity for k in range(streams) for first, final, _ in
                    plans[k] for t in range(first, final)
                    if t >= storage.counters[k, CURSOR] - capacity]
            assert sorted(want) == list(live)
        check(storage, live, storage.frames[live],
              storage.frames[storage.bootstrap_slots(live)], storage.ret[live],
              storage.discount[live], plans)
        assert (storage.counters[:, CURSOR] == storage.counters[:, PUBLISHED]).all()
        assert storage.total_written() == expected
        print(f"{sampled} batches sampled while writing, {dropped} samples lapped meanwhile")
        names = set(blocks._names.values())
        del storage, replay, b
    assert not names & set(leftover_segments())
