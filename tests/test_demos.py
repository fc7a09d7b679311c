"""Demonstrations (DQfD): the margin loss by hand, the demonstration rings of the replay (never
overwritten, always sampleable, with their priority bonus), the file format, and runs with them."""

import json

import numpy as np
import pytest
import torch

from dqn_mine import demos
from dqn_mine.agent.learning import TensorBatch, margin_loss, td_loss
from dqn_mine.demos import DemoEpisode, DemoError, pack, write_episode
from dqn_mine.env.interface import FRAME_SHAPE
from dqn_mine.replay import NStepWriter, PrioritizedReplay, ReplayLayout, ReplayStorage
from dqn_mine.shared import SharedBlocks
from tests.test_agent_learning import ONLINE, TARGET, TableQ, table_batch

# -- the large-margin loss ---------------------------------------------------------------------


def test_margin_loss_by_hand():
    q = torch.tensor([[1.0, 2.0, 0.5], [3.0, 0.0, 2.9], [5.0, 1.0, 1.0]])
    got = margin_loss(q, torch.tensor([0, 0, 0]), margin=0.8)
    # max_a Q + l(a_E, a) - Q(a_E): 2.0 + 0.8 - 1.0; 2.9 + 0.8 - 3.0; a_E ahead by >= 0.8: 0
    assert got.tolist() == pytest.approx([1.8, 0.7, 0.0])
    assert margin_loss(q, torch.tensor([1, 2, 1]), 0.0).tolist() == pytest.approx([0.0, 0.1, 4.0])


def test_td_loss_adds_the_weighted_margin_loss_on_demonstrations_only():
    online, target = TableQ(ONLINE), TableQ(TARGET)
    # state 2: Q = [4.0, -1.0, 0.5]; actions 1 and 2 are demonstrated (margins 5.8 and 4.3)
    batch = table_batch([2, 2, 2], [0, 1, 2], [4.5, 1.0, 0.5], [0, 0, 0], [0, 0, 0],
                        [1.0, 0.5, 0.25])
    tb = TensorBatch(**{name: torch.as_tensor(getattr(batch, name))
                        for name in TensorBatch._fields[:-2]},
                     indices=batch.indices, demo=torch.tensor([False, True, True]))
    plain, td_plain, _, none = td_loss(online, target, tb, demo_weight=0.0)
    loss, td_abs, _, summed = td_loss(online, target, tb, demo_margin=0.8, demo_weight=2.0)
    assert none.item() == 0.0
    assert summed.item() == pytest.approx(5.8 + 4.3)
    assert loss.item() == pytest.approx(plain.item() + 2.0 * (0.5 * 5.8 + 0.25 * 4.3) / 3)
    assert td_abs.tolist() == pytest.approx(td_plain.tolist())   # priorities stay TD errors


# -- the demonstration rings -------------------------------------------------------------------

FRAME = (1, 2, 2)
Q0 = np.zeros(6, np.float32)


def fake_episode(steps: int, value: int, delivered: bool = True) -> DemoEpisode:
    frames = np.full((steps + 1, *FRAME), value, np.uint8)
    frames[:, 0, 0, 0] = np.arange(steps + 1)                  # each frame its own
    rewards = np.zeros(steps, np.float32)
    rewards[-1] = float(delivered)
    return DemoEpisode(frames, np.zeros(steps + 1, bool), np.arange(steps) % 6,
                       rewards, delivered, seed=value)


@pytest.fixture
def demo_replay():
    """Two agent rings and one demonstration ring of 40 slots (n = 3) holding two episodes."""
    layout = ReplayLayout(num_streams=3, stream_capacity=40, frame_shape=FRAME, history_len=0,
                          n_step=3, demo_streams=1)
    with SharedBlocks.create(layout.block_specs()) as blocks:
        storage = ReplayStorage(layout, blocks)
        writer = NStepWriter(storage, 2)
        for ep in (fake_episode(12, 100), fake_episode(20, 200)):
            write_episode(writer, ep)
        yield storage
        del storage, writer


def test_pack_keeps_whole_episodes_within_a_ring():
    assert pack([10, 10, 10, 20], 25) == [[0, 1], [2], [3]]
    assert pack([5, 5, 5, 5], 12) == [[0, 1], [2, 3]]   # 6 + 6 frames fill 12
    assert pack([5, 5, 5, 5], 11) == [[0], [1], [2], [3]]
    assert pack([5, 4, 5], 12) == [[0, 1], [2]]
    assert pack([24], 25) == [[0]]
    with pytest.raises(DemoError, match="does not fit"):
        pack([25], 25)


def test_demonstrations_are_never_overwritten_and_stay_sampleable(demo_replay):
    storage = demo_replay
    first = storage.layout.demo_from
    assert first == 80
    before = storage.frames[first:first + 35].copy()
    replay = PrioritizedReplay(storage, zeta=0.6, seed=0, demo_bonus=1.0)
    demo_slots = np.arange(first, first + 33)
    starts = demo_slots[storage.boot_off[demo_slots] > 0]
    assert len(starts) == 12 + 20        # every step of both episodes starts a transition
    for stream in (0, 1):                # the agent's rings lap five times
        w = NStepWriter(storage, stream, flush_every=8)
        w.begin_episode(np.zeros(FRAME, np.uint8), 0.0)
        for t in range(200):
            w.append(Q0, 0, 0.0, np.zeros(FRAME, np.uint8), 0.0)
            if t % 25 == 0:
                replay.ingest()
                batch = replay.sample(16, beta=0.4)
                assert (batch.demo == (batch.indices >= first)).all()
    replay.ingest()
    assert np.array_equal(storage.frames[first:first + 35], before)
    assert (replay.sum_tree[starts] > 0).all()                 # still alive
    seen = set()
    for _ in range(200):
        seen.update(replay.sample(32, beta=0.4).indices.tolist())
    assert set(starts.tolist()) <= seen                         # and all get sampled
    # the n-step return of a demonstration ends at its reward: 3 steps before it, gamma^2
    last = first + 12 - 1
    assert storage.ret[last] == pytest.approx(1.0) and storage.discount[last] == 0.0
    assert storage.ret[last - 2] == pytest.approx(0.99 ** 2)


def test_the_demo_bonus_shows_in_the_priorities(demo_replay):
    storage = demo_replay
    replay = PrioritizedReplay(storage, zeta=0.5, eta=1e-5, seed=0, demo_bonus=1.0)
    w = NStepWriter(storage, 0, flush_every=1)
    w.begin_episode(np.zeros(FRAME, np.uint8), 0.0)
    for _ in range(10):
        w.append(Q0, 0, 0.0, np.zeros(FRAME, np.uint8), 0.0)
    replay.ingest()
    agent, demo = 2, storage.layout.demo_from + 2
    replay.update_priorities([agent, demo], [0.3, 0.3])
    replay.apply_priority_updates()
    assert replay.sum_tree[agent] == pytest.approx((0.3 + 1e-5) ** 0.5)
    assert replay.sum_tree[demo] == pytest.approx((0.3 + 1e-5 + 1.0) ** 0.5)


# -- files -------------------------------------------------------------------------------------

def test_recorded_demonstrations_load_back_identically(tmp_path):
    from dqn_mine.env import MineRescueEnv
    from dqn_mine.env.expert import solve

    env = MineRescueEnv(task="one-room", room_size=8.0)
    plan = solve(env, 5, env.max_episode_steps)
    ep = demos.record_actions(env, 5, plan)
    assert ep.terminated and ep.steps == len(plan) and ep.rewards[-1] == 1.0
    assert ep.frames.shape == (len(plan) + 1, *FRAME_SHAPE)
    again = demos.record_actions(env, 5, plan)     # the same seed renders the same frames
    assert np.array_equal(again.frames, ep.frames)
    path = demos.save_episode(tmp_path, 0, ep)
    back = demos.load_episode(path)
    for name in demos.ARRAYS:
        assert np.array_equal(np.asarray(getattr(back, name)), np.asarray(getattr(ep, name)))
    assert demos.read_lengths([path]) == [len(plan)]
    env.close()


def test_a_damaged_demonstration_is_one_line(tmp_path):
    (tmp_path / "episode_000000.npz").write_bytes(b"not a zip")
    with pytest.raises(DemoError, match="unreadable demonstration"):
        demos.load_episode(tmp_path / "episode_000000.npz")
    with pytest.raises(DemoError, match="no demonstration folder"):
        demos.episode_files(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DemoError, match="holds no episode"):
        demos.episode_files(tmp_path / "empty")


# -- runs with demonstrations ------------------------------------------------------------------

def test_play_records_demonstrations_a_run_keeps_and_saves(tmp_path):
    """play --record writes loadable episodes; a run keeps them in the replay (they show in the
    sampled batches and the margin loss), saves them with --save-replay, and a resumed run
    reads them back from there."""
    from dqn_mine.play import main as play
    from tests.test_train import TINY, metrics_rows, run_train

    folder = tmp_path / "demos"
    assert play(["--policy", "expert", "--task", "one-room", "--room-size", "8", "--episodes",
                 "3", "--record", str(folder), "--quiet"]) == 0
    meta = json.loads((folder / "demos.json").read_text())
    assert meta["episodes"] == 3 and meta["env"]["task"] == "one-room"
    episodes = [demos.load_episode(p) for p in demos.episode_files(folder)]
    assert all(ep.terminated and ep.rewards.sum() == 1.0 for ep in episodes)
    assert meta["steps"] == sum(ep.steps for ep in episodes)
    assert [ep.seed for ep in episodes] == [0, 1, 2]
    # a second recording into the same folder would mix two sets: refused
    assert play(["--episodes", "1", "--record", str(folder), "--quiet"]) == 2

    run_dir, replay_dir = tmp_path / "run", tmp_path / "replay"
    res = run_train(*TINY, "--serial", "--updates", "40", "--demos-from", str(folder),
                    "--run-dir", str(run_dir), "--save-replay", str(replay_dir))
    assert res.returncode == 0, res.stderr[-3000:]
    assert f"3 demonstrations from {folder} ({meta['steps']} steps)" in res.stdout
    rows = metrics_rows(run_dir)
    assert 0 < float(rows[-1]["demo_share"]) < 1 and float(rows[-1]["margin_loss"]) >= 0
    saved = json.loads((replay_dir / "replay.json").read_text())["layout"]
    assert saved["demo_streams"] == 1 and saved["num_streams"] == 3
    res = run_train("--resume", str(run_dir), "--updates", "60")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "transitions back from" in res.stdout and "demonstrations from" not in res.stdout
    assert 0 < float(metrics_rows(run_dir)[-1]["demo_share"]) < 1


@pytest.mark.parametrize("flags, phrase", [
    (["--demos", "-1"], "--demos must be at least 0"),
    (["--demos", "5", "--demos-from", "x"], "two sources"),
    (["--demo-pretrain", "10"], "add --demos"),
    (["--demo-margin", "-0.1"], "--demo-margin must be >= 0"),
    (["--demos-from", "no/such/folder"], "no demonstration folder at no/such/folder"),
])
def test_bad_demonstration_settings_give_one_line(tmp_path, flags, phrase):
    from tests.test_train import TINY, run_train

    res = run_train(*TINY, *flags, "--run-dir", str(tmp_path / "run"), timeout=60)
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and phrase in res.stderr, res.stderr
    assert not (tmp_path / "run").exists()


def test_demonstrations_make_a_greedy_agent_deliver(tmp_path):
    """One-room with no exploration at all (epsilon 0, no unstick): a fresh network repeats
    itself and never delivers, so nothing is learned; with 30 expert episodes and pre-training
    on them the same run delivers from its first episodes."""
    from tests.test_train import run_train

    common = ["--preset", "smoke", "--serial", "--updates", "300", "--prefill", "200",
              "--epsilon-schedule", "fixed", "--epsilon", "0"]
    rewarded = {}
    for name, flags in (("plain", []), ("demos", ["--demos", "30", "--demo-pretrain", "1500"])):
        res = run_train(*common, *flags, "--run-dir", str(tmp_path / name), timeout=900)
        assert res.returncode == 0, res.stderr[-3000:]
        summary = json.loads((tmp_path / name / "summary.json").read_text())
        rewarded[name] = (summary["rewarded_episodes"], summary["episodes"])
        if flags:   # a log file, not a terminal: the pre-training reports in ten lines
            assert res.stderr.count("demo pre-train: ") == 10, res.stderr[-3000:]
            assert "demo pre-train: 1,500/1,500 updates" in res.stderr
    assert rewarded["plain"][0] == 0, rewarded
    assert rewarded["demos"][0] >= 4 and rewarded["demos"][0] >= rewarded["demos"][1] / 2, \
        rewarded


def test_manual_recording_from_scripted_key_presses(tmp_path):
    """play --manual with the keys piped in (no display): the expert's plan typed as keys makes
    the very episode the expert recorded; q ends an episode early, as truncated."""
    import subprocess
    import sys

    from dqn_mine.env import MineRescueEnv
    from dqn_mine.env.expert import solve
    from dqn_mine.manual import KEYS

    env = MineRescueEnv(task="one-room", room_size=8.0)
    plan = solve(env, 3, env.max_episode_steps)
    expert = demos.record_actions(env, 3, plan)
    env.close()
    key_of = {action: key for key, action in KEYS.items() if len(key) == 1 and key != " "}
    typed = "".join(key_of[a] for a in plan) + "\nwwq"          # newlines are skipped
    res = subprocess.run([sys.executable, "-m", "dqn_mine.play", "--manual", "--keys", "-",
                          "--record", str(tmp_path / "rec"), "--task", "one-room",
                          "--room-size", "8", "--seed", "3", "--episodes", "2"],
                         input=typed, capture_output=True, text=True, timeout=120,
                         env={k: v for k, v in __import__("os").environ.items()
                              if k != "DISPLAY"})
    assert res.returncode == 0, res.stderr[-2000:]
    first, second = (demos.load_episode(p) for p in demos.episode_files(tmp_path / "rec"))
    assert first.terminated and np.array_equal(first.actions, expert.actions)
    assert np.array_equal(first.frames, expert.frames)
    assert not second.terminated and second.actions.tolist() == [0, 0] and second.seed == 4


def test_too_few_demonstrations_for_a_batch_skip_the_pretraining(tmp_path):
    from tests.test_train import TINY, run_train

    res = run_train(*TINY, "--serial", "--updates", "20", "--demos", "1", "--demo-pretrain",
                    "50", "--batch-size", "128", "--replay-capacity", "8192",
                    "--run-dir", str(tmp_path / "run"))
    assert res.returncode == 0, res.stderr[-3000:]
    assert "no pre-training:" in res.stdout and "do not fill a batch of 128" in res.stdout
