"""The replay on disk: a saved and restored replay samples what the original would have."""

import numpy as np
import pytest

from dqn_mine.replay import NStepWriter, PrioritizedReplay, ReplayLayout, ReplayStorage, snapshot
from dqn_mine.replay.storage import BLOCK_NAMES, CURSOR
from dqn_mine.shared import SharedBlocks

LAYOUT = ReplayLayout(num_streams=2, stream_capacity=64, frame_shape=(3, 4, 5), history_len=3,
                      n_step=3, gamma=0.9)


def fill(storage, steps, seed=0):
    """Two streams of random episodes, long enough to lap each ring (so some slots died)."""
    rng = np.random.default_rng(seed)
    for stream in range(storage.layout.num_streams):
        w = NStepWriter(storage, stream, flush_every=8)
        w.begin_episode(rng.integers(0, 255, (3, 4, 5), np.uint8), 0.0)
        for _t in range(steps):
            end = rng.random() < 0.05
            w.append(rng.normal(size=6).astype(np.float32), int(rng.integers(6)),
                     float(end), rng.integers(0, 255, (3, 4, 5), np.uint8),
                     float(rng.random() < 0.5), terminated=end)
            if end:
                w.begin_episode(rng.integers(0, 255, (3, 4, 5), np.uint8), 0.0)
        w.flush()


@pytest.fixture
def original():
    with SharedBlocks.create(LAYOUT.block_specs()) as blocks:
        storage = ReplayStorage(LAYOUT, blocks)
        fill(storage, 150)
        replay = PrioritizedReplay(storage, zeta=0.6, seed=3)
        replay.ingest()
        batch = replay.sample(16, 0.5)
        replay.update_priorities(batch.indices, np.arange(16) * 0.1, batch.stamps)  # queued
        yield storage, replay
        del storage


def test_restored_replay_samples_the_same_transitions(original, tmp_path):
    storage, replay = original
    path = snapshot.save(tmp_path / "replay", storage, replay)
    assert not (tmp_path / "replay.tmp").exists()
    expected = [replay.sample(32, 0.7) for _ in range(3)]    # after the save: same rng state
    with SharedBlocks.create(LAYOUT.block_specs()) as blocks:
        fresh = ReplayStorage(LAYOUT, blocks)
        restored = PrioritizedReplay(fresh, zeta=0.6, seed=99)   # another seed: state wins
        assert snapshot.load(path, fresh, restored) == len(replay) > 0
        for name in BLOCK_NAMES:
            assert np.array_equal(getattr(fresh, name), getattr(storage, name), equal_nan=True)
        np.testing.assert_array_equal(restored.sum_tree.values, replay.sum_tree.values)
        assert restored.min_tree.min() == replay.min_tree.min()
        for want in expected:
            got = restored.sample(32, 0.7)
            for field in want._fields:
                np.testing.assert_array_equal(getattr(got, field), getattr(want, field),
                                              err_msg=field)
        # writers carry on after the saved cursors: the next frames land in the right slots
        before = fresh.counters[:, CURSOR].copy()
        fill(fresh, 20, seed=1)
        assert (fresh.counters[:, CURSOR] >= before + 21).all()
        assert restored.ingest() > 0
        del fresh


def test_a_replay_saved_again_replaces_the_old_one(original, tmp_path):
    storage, replay = original
    snapshot.save(tmp_path / "replay", storage, replay)
    storage.frames[0] = 7
    snapshot.save(tmp_path / "replay", storage, replay)
    assert (np.load(tmp_path / "replay" / "frames.npy")[0] == 7).all()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["replay"]
    assert snapshot.nbytes(storage) == sum(
        (tmp_path / "replay" / f"{n}.npy").stat().st_size - 128 for n in BLOCK_NAMES) \
        + 8 * storage.capacity


def test_wrong_layout_and_damage_give_one_line(original, tmp_path):
    storage, replay = original
    path = snapshot.save(tmp_path / "replay", storage, replay)
    other = ReplayLayout(num_streams=2, stream_capacity=32, frame_shape=(3, 4, 5), history_len=3,
                         n_step=3, gamma=0.9)
    with pytest.raises(snapshot.SnapshotError, match="stream_capacity") as info:
        snapshot.check(path, other)
    assert "\n" not in str(info.value)
    (path / "frames.npy").write_bytes(b"\x93NUMPY garbage")
    with SharedBlocks.create(LAYOUT.block_specs()) as blocks:
        fresh = ReplayStorage(LAYOUT, blocks)
        with pytest.raises(snapshot.SnapshotError, match="unreadable") as info:
            snapshot.load(path, fresh, PrioritizedReplay(fresh))
        assert "\n" not in str(info.value)
        del fresh
    with pytest.raises(snapshot.SnapshotError, match="no saved replay"):
        snapshot.check(tmp_path / "nothing", LAYOUT)
