"""Ring storage and n-step writer: values by hand, wrap-around, invalidation of overwritten windows.

Frames are 8 bytes holding their own id (``stream << 32 | frame number``), so every gathered
observation says exactly which frame it is.
"""

import numpy as np
import pytest

from dqn_mine.replay import NStepWriter, PrioritizedReplay, ReplayLayout, ReplayStorage
from dqn_mine.replay.storage import CURSOR, PUBLISHED, STEPS
from dqn_mine.shared import SharedBlocks, leftover_segments

GAMMA = 0.5


def frame(stream, t):
    return np.array([stream << 32 | t], dtype=np.int64).view(np.uint8).reshape(1, 8)


def frame_id(obs):                  # obs [B, f, 8] uint8 -> [B, f] int64
    return np.ascontiguousarray(obs).view(np.int64)[..., 0]


@pytest.fixture
def make_storage():
    made = []

    def make(**kw):
        args = dict(num_streams=1, stream_capacity=64, frame_shape=(1, 8), history_len=3,
                    n_step=3, gamma=GAMMA, frame_stack=1)
        args.update(kw)
        layout = ReplayLayout(**args)
        blocks = SharedBlocks.create(layout.block_specs())
        made.append(blocks)
        return ReplayStorage(layout, blocks)

    yield make
    for b in made:
        b.close()
    assert not [n for n in leftover_segments() if n in {s for b in made for s in b._names.values()}]


def q_row(t):
    """The actor's Q(s_t, .) in these tests: action a has value t + a / 10."""
    return np.float32(t) + np.arange(6, dtype=np.float32) / 10


def play(writer, stream, t0, rewards, end=None, next_q=None, action=lambda t: t % 6):
    """One episode from frame number ``t0``: rewards[i] = r_{i+1}; ``end`` = 'term'/'trunc'."""
    writer.begin_episode(frame(stream, t0), 0.0)
    for i, r in enumerate(rewards):
        t = t0 + i
        last = i == len(rewards) - 1
        writer.append(q_row(t), action(t), r, frame(stream, t + 1), float(t + 1),
                      terminated=last and end == "term", truncated=last and end == "trunc",
                      next_q=next_q if last else None)


def slot_of(storage, stream, t):
    return storage.slot(stream, t)


def test_n_step_returns_by_hand_termination(make_storage):
    s = make_storage()
    w = NStepWriter(s, 0, eta=0.0, flush_every=2)
    rewards = [1.0, 2.0, 4.0, 8.0, 16.0]          # r_1..r_5, terminated at s_5
    play(w, 0, 0, rewards, end="term")
    n = 3
    for t in range(5):
        k = min(n, 5 - t)
        ret = sum(GAMMA ** i * rewards[t + i] for i in range(k))
        assert s.ret[t] == pytest.approx(ret)
        assert s.boot_off[t] == k
        assert s.discount[t] == (0.0 if t + k == 5 else GAMMA ** k)
        # initial priority |ret + disc * max Q(s_{t+k}) - Q(s_t, a_t)|, Q(s_5) unused
        boot = 0.0 if t + k == 5 else q_row(t + k).max()
        assert s.priority[t] == pytest.approx(abs(ret + s.discount[t] * boot - q_row(t)[t % 6]))
        assert s.action[t] == t % 6
    assert s.boot_off[5] == 0 and s.boot[5] == -1 and s.priority[5] == 0   # starts nothing
    assert list(s.ep_step[:6]) == list(range(6))
    assert list(s.carrying[:6]) == [0.0, 1, 2, 3, 4, 5]
    assert s.counters[0, PUBLISHED] == 6 and s.counters[0, CURSOR] == 6
    assert s.total_written() == 5
    np.testing.assert_array_equal(s.history[:6], [[-1, -1, -1], [-1, -1, 0], [-1, 0, 1],
                                                  [0, 1, 2], [1, 2, 3], [2, 3, 4]])
    assert np.isnan(s.ret[6]) and s.boot_off[6] == 255      # magic fill: never written


def test_n_step_truncation_bootstraps_from_the_last_frame(make_storage):
    s = make_storage()
    w = NStepWriter(s, 0, eta=1e-5, flush_every=64)
    rewards = [1.0, 0.0, 3.0, 5.0]
    next_q = np.array([0, 7, 2, 0, 0, 0], np.float32)
    play(w, 0, 0, rewards, end="trunc", next_q=next_q)
    for t in range(4):
        k = min(3, 4 - t)
        ret = sum(GAMMA ** i * rewards[t + i] for i in range(k))
        assert s.ret[t] == pytest.approx(ret)
        assert s.discount[t] == pytest.approx(GAMMA ** k)       # truncated: still bootstraps
        boot = 7.0 if t + k == 4 else q_row(t + k).max()
        assert s.priority[t] == pytest.approx(abs(ret + GAMMA ** k * boot - q_row(t)[t % 6])
                                              + 1e-5)


def test_publication_waits_for_the_bootstrap_q(make_storage):
    s = make_storage()
    w = NStepWriter(s, 0, flush_every=1)
    w.begin_episode(frame(0, 0), 0.0)
    for t in range(3):
        w.append(q_row(t), 0, 1.0, frame(0, t + 1), 0.0)
        assert s.counters[0, PUBLISHED] == 0                    # Q(s_3) not known yet
    w.append(q_row(3), 0, 1.0, frame(0, 4), 0.0)
    assert s.counters[0, PUBLISHED] == 1 and s.counters[0, CURSOR] == 5
    assert s.counters[0, STEPS] == 4
    w.flush()
    assert s.counters[0, PUBLISHED] == 1


def test_wrap_around_and_history_across_episodes(make_storage):
    s = make_storage(stream_capacity=16)
    w = NStepWriter(s, 0, flush_every=4)
    t0 = 0
    lengths = [7, 1, 9, 5, 6]                      # 33 frames: the 16-slot ring wraps twice
    for e, length in enumerate(lengths):
        rewards = [float(t0 + i) for i in range(length)]
        play(w, 0, t0, rewards, end="term" if e % 2 == 0 else "trunc",
             next_q=np.zeros(6, np.float32))
        t0 += length + 1
    assert s.counters[0, CURSOR] == t0 == 33
    # the last 16 frames are in the ring; check each by hand
    starts = np.cumsum([0] + [n + 1 for n in lengths])
    for t in range(t0 - 16, t0):
        e = np.searchsorted(starts, t, side="right") - 1
        ep_t, final = t - starts[e], lengths[e]
        slot = slot_of(s, 0, t)
        assert s.ep_step[slot] == ep_t
        hist = [t - j - 1 if ep_t - j - 1 >= 0 else -1 for j in range(3)][::-1]
        np.testing.assert_array_equal(s.history[slot], [h % 6 if h >= 0 else -1 for h in hist])
        if ep_t == final:
            assert s.boot_off[slot] == 0
            continue
        k = min(3, final - ep_t)
        assert s.boot_off[slot] == k and s.boot[slot] == slot_of(s, 0, t + k)   # across the wrap
        assert s.ret[slot] == pytest.approx(sum(GAMMA ** i * (t + i) for i in range(k)))
        terminal = e % 2 == 0 and ep_t + k == final
        assert s.discount[slot] == (0.0 if terminal else pytest.approx(GAMMA ** k))


def _alive_by_brute_force(s, stream, f):
    """Transitions that must be sampleable: published, start frame and its stack not lapped."""
    m = s.stream_capacity
    cursor, published = s.counters[stream, CURSOR], s.counters[stream, PUBLISHED]
    alive = set()
    for t in range(max(0, published - m), published):
        slot = slot_of(s, stream, t)
        if s.boot_off[slot] > 0 and t - (f - 1) >= cursor - m:
            alive.add(int(slot))
    return alive


@pytest.mark.parametrize("f", [1, 2])
def test_overwriting_a_slot_kills_only_the_transition_starting_there(make_storage, f):
    m = 12
    s = make_storage(stream_capacity=m, frame_stack=f, num_streams=2)
    replay = PrioritizedReplay(s, zeta=1.0, eta=0.0)
    w = NStepWriter(s, 1, flush_every=1)
    w.begin_episode(frame(1, 0), 0.0)
    for t in range(40):
        w.append(q_row(t), 1, 1.0, frame(1, t + 1), 0.0)
        replay.ingest()
        live = set(np.flatnonzero(replay.sum_tree.values > 0))
        assert live == _alive_by_brute_force(s, 1, f)
        assert len(replay) == len(live)
        if t + 1 >= m:
            # frame t+1 just overwrote frame t+1-m: its transition (and, stacked, the f-1 after
            # it) died; the newest lapped transition is exactly that one
            dead = {slot_of(s, 1, t + 1 - m + j) for j in range(f)}
            assert not live & dead
            oldest = t + 2 - m + f - 1          # the next one is still alive once published
            assert slot_of(s, 1, oldest) in live or oldest >= s.counters[1, PUBLISHED]


def test_sample_gathers_the_right_frames_and_stacks(make_storage):
    s = make_storage(stream_capacity=32, frame_stack=3, n_step=2, num_streams=2)
    for k in range(2):
        w = NStepWriter(s, k, flush_every=3)
        play(w, k, 0, [1.0] * 6, end="term")
        play(w, k, 7, [1.0] * 4, end="trunc", next_q=np.zeros(6, np.float32))
    replay = PrioritizedReplay(s, seed=3)
    assert replay.ingest() == 2 * (6 + 4)
    batch = replay.sample(64, beta=0.5)
    assert batch.obs.shape == (64, 3, 8) and batch.history.shape == (64, 3)
    ids = frame_id(batch.obs.reshape(64, 3, 8))                     # [B, f]
    next_ids = frame_id(batch.next_obs.reshape(64, 3, 8))
    for i, slot in enumerate(batch.indices):
        stream, t = divmod(int(slot), 32)
        ep_start = 0 if t < 7 else 7
        want = [stream << 32 | (t - j) if t - j >= ep_start else 0 for j in (2, 1, 0)]
        assert list(ids[i]) == want
        tk = t + int(s.boot_off[slot])
        want = [stream << 32 | (tk - j) if tk - j >= ep_start else 0 for j in (2, 1, 0)]
        assert list(next_ids[i]) == want
        assert batch.carrying[i] == s.carrying[slot] and batch.next_carrying[i] == tk
        np.testing.assert_array_equal(batch.next_history[i], s.history[s.slot(stream, tk)])
    assert batch.action.dtype == np.int64 and (batch.action == batch.indices % 32 % 6).all()


def test_a_new_writer_recovers_a_stream_whose_writer_died(make_storage):
    s = make_storage()
    w = NStepWriter(s, 0, flush_every=64)
    w.begin_episode(frame(0, 0), 0.0)
    for t in range(10):                          # nothing published: the writer "dies"
        w.append(q_row(t), 0, 1.0, frame(0, t + 1), 0.0)
    assert s.counters[0, PUBLISHED] == 0
    w2 = NStepWriter(s, 0)
    assert s.counters[0, PUBLISHED] == s.counters[0, CURSOR] == 11
    assert (s.boot_off[:11] == 0).all()
    play(w2, 0, 11, [1.0, 1.0], end="term")
    assert s.counters[0, PUBLISHED] == 14 and s.boot_off[11] == 2


def test_begin_episode_mid_episode_drops_the_unfinished_tail(make_storage):
    s = make_storage()
    w = NStepWriter(s, 0, flush_every=1)
    w.begin_episode(frame(0, 0), 0.0)
    for t in range(6):
        w.append(q_row(t), 0, 1.0, frame(0, t + 1), 0.0)
    assert w.history().tolist() == [0, 0, 0]
    play(w, 0, 7, [2.0], end="term")
    assert list(s.boot_off[:9]) == [3, 3, 3, 0, 0, 0, 0, 1, 0]
    assert s.counters[0, PUBLISHED] == 9


def test_writer_history_matches_what_it_stores(make_storage):
    s = make_storage(history_len=4)
    w = NStepWriter(s, 0, flush_every=2)
    w.begin_episode(frame(0, 0), 0.0)
    for t in range(9):
        assert w.history().tolist() == [(j % 6) if j >= 0 else -1 for j in range(t - 4, t)]
        w.append(q_row(t), t % 6, 0.0, frame(0, t + 1), 0.0)
    w.flush()
    for t in range(9 - 3):                        # published frames carry the same history
        np.testing.assert_array_equal(s.history[t], [(j % 6) if j >= 0 else -1
                                                     for j in range(t - 4, t)])


def test_layout_sizes_and_lazy_frames():
    layout = ReplayLayout(num_streams=8, stream_capacity=2 ** 17)
    assert layout.capacity == 2 ** 20
    specs = {b.name: b for b in layout.block_specs()}
    assert specs["frames"].fill is None                            # never pre-touched
    assert specs["frames"].nbytes == 2 ** 20 * 10032
    assert layout.nbytes < 11 * 10 ** 9 + 2 ** 20 * 64              # frames stored once
    with pytest.raises(ValueError):
        ReplayLayout(num_streams=1, stream_capacity=4, n_step=6)
    assert ReplayLayout.from_capacity(2 ** 20, 7, n_step=3).stream_capacity == 2 ** 20 // 7


@pytest.mark.parametrize("end", ["term", "trunc"])
def test_writer_matches_the_reference_nstep_return(make_storage, end):
    """Every stored window against ``learning.nstep_return``, the rule written down once."""
    from dqn_mine.agent.learning import nstep_return

    s = make_storage(n_step=4)
    w = NStepWriter(s, 0, eta=0.0, flush_every=3)
    rewards = list(np.random.default_rng(1).integers(0, 3, 11).astype(float))
    play(w, 0, 0, rewards, end=end, next_q=np.zeros(6, np.float32))
    for t in range(len(rewards)):
        window = rewards[t:t + 4]
        stop = len(window) - 1 if end == "term" and t + len(window) == len(rewards) else None
        ret, discount = nstep_return(window, GAMMA, terminated_at=stop)
        assert s.ret[t] == pytest.approx(ret) and s.discount[t] == pytest.approx(discount)
