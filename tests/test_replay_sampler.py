"""Prioritised sampling: frequencies, importance weights, priority updates, racing writers."""

import numpy as np
import pytest

from dqn_mine.replay import (
    Batch,
    NStepWriter,
    PrioritizedReplay,
    ReplayLayout,
    ReplayStorage,
    beta_at,
)
from dqn_mine.replay.storage import CURSOR, PUBLISHED
from dqn_mine.shared import SharedBlocks


@pytest.fixture
def storage():
    """One stream of 1000 slots holding 999 published one-step transitions (slot 999 is the
    bootstrap frame of the last one); priorities are set by each test."""
    layout = ReplayLayout(num_streams=1, stream_capacity=1000, frame_shape=(2,), history_len=2,
                          n_step=1)
    with SharedBlocks.create(layout.block_specs()) as blocks:
        s = ReplayStorage(layout, blocks)
        s.frames[:] = 0
        s.carrying[:] = 0
        s.history[:] = -1
        s.ep_step[:] = np.arange(1000)
        s.action[:] = 1
        s.ret[:] = 0
        s.discount[:] = 0.99
        s.boot_off[:] = 1
        s.boot_off[999] = 0
        s.boot[:] = np.arange(1, 1001) % 1000
        s.counters[0, CURSOR] = 1000
        s.counters[0, PUBLISHED] = 999
        yield s
        del s


def _sample_counts(replay, n_batches, batch_size, beta=0.4):
    counts = np.zeros(replay.storage.capacity)
    for _ in range(n_batches):
        np.add.at(counts, replay.sample(batch_size, beta).indices, 1)
    return counts


def test_zero_priorities_never_sampled_and_frequencies_match(storage):
    rng = np.random.default_rng(0)
    p = rng.random(999) * 3
    p[rng.random(999) < 0.3] = 0.0                 # dead / never-added transitions
    storage.priority[:999] = p
    replay = PrioritizedReplay(storage, zeta=0.6, eta=1e-5, seed=1)
    assert replay.ingest() == 999
    assert len(replay) == int(np.count_nonzero(p ** 0.6))
    counts = _sample_counts(replay, 400, 256)
    assert counts[999] == 0 and counts[:999][p == 0].sum() == 0
    expected = counts.sum() * p ** 0.6 / (p ** 0.6).sum()
    live = expected > 0
    chi2 = ((counts[:999][live] - expected[live]) ** 2 / expected[live]).sum()
    dof = live.sum() - 1
    assert chi2 < dof + 5 * np.sqrt(2 * dof)       # ~5 sigma of a chi-square with dof degrees


def test_zeta_zero_is_uniform(storage):
    storage.priority[:999] = np.linspace(0.01, 100, 999)
    replay = PrioritizedReplay(storage, zeta=0.0, seed=2)
    replay.ingest()
    batch = replay.sample(128, beta=0.7)
    np.testing.assert_allclose(batch.weights, 1.0)
    counts = _sample_counts(replay, 200, 256)
    expected = counts.sum() / 999
    chi2 = ((counts[:999] - expected) ** 2 / expected).sum()
    assert chi2 < 998 + 5 * np.sqrt(2 * 998)


def test_importance_weights_match_the_formula(storage):
    rng = np.random.default_rng(3)
    p = rng.random(999) + 0.05
    storage.priority[:999] = p
    zeta, beta = 0.6, 0.45
    replay = PrioritizedReplay(storage, zeta=zeta, seed=4)
    replay.ingest()
    batch = replay.sample(512, beta)
    prob = p ** zeta / (p ** zeta).sum()                        # P(i)
    n = 999
    w = (n * prob) ** -beta
    want = w[batch.indices] / w.max()                           # max over all, via the min-tree
    np.testing.assert_allclose(batch.weights, want, rtol=1e-5)
    assert batch.weights.dtype == np.float32 and batch.weights.max() <= 1.0


def test_update_priorities_and_writers_without_q_values(storage):
    storage.priority[:1000] = np.nan               # written without Q values: the largest so far
    replay = PrioritizedReplay(storage, zeta=0.5, eta=0.01, seed=5)
    replay.ingest()
    np.testing.assert_allclose(replay.sum_tree.values[:999], 1.0)
    replay.update_priorities(np.array([3, 4, 4]), np.array([-8.99, 1.0, 15.99]))
    replay.apply_priority_updates()
    assert replay.sum_tree[3] == pytest.approx(9.0 ** 0.5)
    assert replay.sum_tree[4] == pytest.approx(16.0 ** 0.5)    # duplicates: the last one wins
    assert replay.min_tree.min() == pytest.approx(1.0)
    # the next published transition gets the largest priority seen so far
    storage.counters[0, CURSOR] = 1001
    storage.counters[0, PUBLISHED] = 1000          # frame 999's transition; frame 0 lapped
    storage.boot_off[999] = 1
    storage.boot[999] = 0
    assert replay.ingest() == 1
    assert replay.sum_tree[999] == pytest.approx(16.0 ** 0.5)
    assert replay.sum_tree[0] == 0 and len(replay) == 999
    replay.update_priorities(np.array([0]), np.array([5.0]))   # dead slots stay dead
    replay.apply_priority_updates()
    assert replay.sum_tree[0] == 0
    with pytest.raises(ValueError, match="finite"):
        replay.update_priorities(np.array([5]), np.array([np.nan]))


def test_sample_into_preallocated_batch(storage):
    storage.priority[:999] = 1.0
    replay = PrioritizedReplay(storage, seed=6)
    replay.ingest()
    out = Batch.empty(storage.layout, 16)
    batch = replay.sample(16, 0.4, out=out)
    assert batch is out and out.obs.shape == (16, 2) and out.history.shape == (16, 2)


@pytest.fixture
def lapped_stream():
    """One 20-slot stream (n = 2) after 30 steps of one episode, ingested: 31 frames written
    (cursor 31), transitions 0 .. 27 published (Q(s_30) bootstraps 28), frames 0 .. 10 lapped:
    transitions 11 .. 27 alive, in slots 11 .. 19 and 0 .. 7."""
    layout = ReplayLayout(num_streams=1, stream_capacity=20, frame_shape=(1,), history_len=0,
                          n_step=2)
    with SharedBlocks.create(layout.block_specs()) as blocks:
        s = ReplayStorage(layout, blocks)
        w = NStepWriter(s, 0, flush_every=1)
        w.begin_episode(np.zeros(1, np.uint8), 0.0)
        for _ in range(30):
            w.append(Q0, 0, 1.0, np.zeros(1, np.uint8), 0.0)
        replay = PrioritizedReplay(s, zeta=0.0, seed=0)
        replay.ingest()
        yield s, w, replay
        del s, w, replay


Q0 = np.zeros(6, np.float32)


def test_a_writer_lapping_a_sampled_window_zeroes_its_weight(lapped_stream):
    s, w, replay = lapped_stream
    assert len(replay) == 17
    for _ in range(30, 35):                        # the writer laps 5 more frames, no ingest
        w.append(Q0, 0, 1.0, np.zeros(1, np.uint8), 0.0)
    batch = replay.sample(200, 1.0)
    t_of = np.where(batch.indices >= 11, batch.indices, batch.indices + 20)
    stale = t_of < 36 - 20                         # cursor 36: frames before 16 overwritten
    assert stale.any() and (~stale).any()
    np.testing.assert_array_equal(batch.weights == 0, stale)
    assert len(replay) == 17 - len(np.unique(batch.indices[stale]))
    assert replay.ingest() == 33 - 28              # the 5 new ones; the lapped already gone
    assert len(replay) == 33 - 16


def test_a_lap_that_ends_an_episode_never_gives_action_minus_one(lapped_stream):
    """A lapped slot may hold an episode's final frame (action -1, starts no transition) by the
    time it is gathered: weight 0 and a valid action index, or the learner's gather crashes."""
    s, w, replay = lapped_stream
    for t in range(30, 35):                        # frame 35 ends the episode in slot 15
        w.append(Q0, 0, 1.0, np.zeros(1, np.uint8), 0.0, t == 34, False)
    assert s.action[15] == -1
    batch = replay.sample(200, 1.0)
    assert (batch.indices == 15).any()
    assert (batch.weights[batch.indices == 15] == 0).all()
    assert ((batch.action >= 0) & (batch.action < 6)).all()


def test_beta_schedule():
    assert beta_at(0, 100, 0.4) == pytest.approx(0.4)
    assert beta_at(50, 100, 0.4) == pytest.approx(0.7)
    assert beta_at(100, 100, 0.4) == 1.0 and beta_at(500, 100, 0.4) == 1.0
    assert beta_at(3, 0, 0.4) == 1.0


@pytest.fixture
def ten_slots():
    """One 10-slot stream of one-step transitions and its writer (eta 0), episode begun."""
    layout = ReplayLayout(num_streams=1, stream_capacity=10, frame_shape=(1,), history_len=0,
                          n_step=1)
    with SharedBlocks.create(layout.block_specs()) as blocks:
        s = ReplayStorage(layout, blocks)
        w = NStepWriter(s, 0, eta=0.0, flush_every=1)
        w.begin_episode(np.zeros(1, np.uint8), 0.0)
        yield layout, s, w
        del s, w


def test_queued_updates_merge_with_ingest_and_never_revive_the_dead(ten_slots):
    layout, s, w = ten_slots
    f = np.zeros(1, np.uint8)
    for _ in range(9):                         # Q(s_t, a) = 0: initial priority |r| = 1
        w.append(np.zeros(6, np.float32), 0, 1.0, f, 0.0)
    replay = PrioritizedReplay(s, zeta=1.0, eta=0.0, seed=0)
    assert replay.ingest() == 8 and len(replay) == 8     # transitions 0 .. 7
    replay.update_priorities([0, 5], [7.0, 3.0])          # queued, e.g. by another thread
    assert replay.sum_tree[0] == 1.0
    for _ in range(9, 12):                     # frames 10, 11, 12 overwrite slots 0, 1, 2
        w.append(np.zeros(6, np.float32), 0, 2.0, f, 0.0)
    assert replay.ingest() == 3                # transitions 8, 9, 10 (slot 0 refilled)
    assert replay.sum_tree[5] == 3.0           # the queued update landed ...
    assert replay.sum_tree[0] == 2.0           # ... but not on slot 0's new transition
    assert replay.sum_tree[1] == 0.0           # transition 1 died, 11 is not complete
    assert replay.sum_tree[2] == 0.0 and len(replay) == 8      # transitions 3 .. 10
    del replay


def test_a_late_update_for_a_refilled_slot_is_dropped(ten_slots):
    """Sampled, then the slot is overwritten and refilled and ingested, and only then does the
    learner report the old transition's TD error: with the batch's stamps the new transition
    keeps its own priority; slots not refilled still take the update."""
    layout, s, w = ten_slots
    f = np.zeros(1, np.uint8)
    for _ in range(9):                         # transitions 0 .. 7, priority |r| = 1
        w.append(np.zeros(6, np.float32), 0, 1.0, f, 0.0)
    replay = PrioritizedReplay(s, zeta=1.0, eta=0.0, seed=0)
    replay.ingest()
    batch = replay.sample(64, 1.0, out=Batch.empty(layout, 64))
    assert {0, 5} <= set(batch.indices.tolist())
    np.testing.assert_array_equal(batch.stamps, batch.indices)   # first lap: t = slot
    for _ in range(9, 12):                     # transitions 8, 9, 10; slot 0 refilled
        w.append(np.zeros(6, np.float32), 0, 2.0, f, 0.0)
    replay.ingest()
    assert replay.sum_tree[0] == 2.0
    pick = np.array([np.flatnonzero(batch.indices == k)[0] for k in (0, 5)])
    replay.update_priorities(batch.indices[pick], [7.0, 3.0], batch.stamps[pick])
    replay.ingest()
    assert replay.sum_tree[0] == 2.0           # the new transition's own priority
    assert replay.sum_tree[5] == 3.0           # the sampled transition is still there
    del replay, batch
