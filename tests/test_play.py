"""`python -m dqn_mine.play`: GIFs of the expert, a random policy and a trained checkpoint."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]


def play(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dqn_mine.play", "--quiet", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)


def gif_frames(path: Path) -> tuple:
    with Image.open(path) as gif:
        return gif.n_frames, gif.size


def test_expert_gif_shows_first_person_and_map(tmp_path):
    out = tmp_path / "expert.gif"
    res = play("--policy", "expert", "--task", "two-room", "--seed", "1", "--out", str(out))
    assert res.returncode == 0, res.stderr
    assert "return 1.0" in res.stdout
    frames, (width, height) = gif_frames(out)
    assert frames > 10 and width > 2 * height   # first-person view and map side by side


def test_video_frames_carry_the_map_legend(tmp_path):
    import numpy as np

    from dqn_mine.env import MineRescueEnv
    from dqn_mine.env.topdown import draw_legend

    env = MineRescueEnv(task="two-room", render_mode="rgb_array")
    env.reset(seed=1)
    view = env.render()
    env.close()
    out = tmp_path / "expert.gif"
    res = play("--policy", "expert", "--task", "two-room", "--seed", "1", "--max-steps", "3",
               "--out", str(out))
    assert res.returncode == 0, res.stderr
    with Image.open(out) as gif:
        first = np.asarray(gif.convert("RGB"))
    legend = draw_legend(view.shape[1])
    assert first.shape == (view.shape[0] + legend.shape[0], view.shape[1], 3)
    # the legend strip holds the symbols' colours: agent blue, kit red
    assert (np.abs(legend.astype(int) - (40, 120, 255)).sum(-1) < 30).any()
    assert (np.abs(legend.astype(int) - (225, 20, 20)).sum(-1) < 30).any()
    assert np.abs(first[view.shape[0]:].astype(int) - legend).mean() < 8   # GIF palette error


@pytest.mark.skipif(not __import__("dqn_mine.play").play.mp4_available(),
                    reason="MP4 needs imageio-ffmpeg (pip install -e .[video])")
def test_mp4_is_written_and_much_smaller_than_the_gif(tmp_path):
    gif, mp4 = tmp_path / "a.gif", tmp_path / "a.mp4"
    for out in (gif, mp4):
        res = play("--policy", "random", "--task", "one-room", "--max-steps", "60",
                   "--out", str(out))
        assert res.returncode == 0, res.stderr
    import imageio.v2 as imageio

    with imageio.get_reader(mp4) as reader:
        assert sum(1 for _ in reader) == 61
    assert mp4.stat().st_size < gif.stat().st_size / 3


def test_random_policy_respects_step_limit(tmp_path):
    out = tmp_path / "random.gif"
    res = play("--policy", "random", "--task", "one-room", "--max-steps", "25", "--out", str(out))
    assert res.returncode == 0, res.stderr
    assert gif_frames(out)[0] <= 26


def test_bump_and_press_walker_presses_action_4_where_it_is_blocked():
    """The default pre-fill's walker, played alone: it acts only on what it sees and, in one
    room, takes the kit up at some wall or entity it bumps into."""
    from dqn_mine.play import POLICIES, build_parser, fill_env_settings, make_env

    args = build_parser().parse_args(["--policy", "bump-and-press", "--task", "one-room",
                                      "--seed", "3"])
    fill_env_settings(args)
    env = make_env(args)
    policy = POLICIES["bump-and-press"](args)
    obs, info = env.reset(seed=args.seed)
    actions, carried = [], False
    try:
        for _ in range(1000):
            actions.append(policy(env, obs, info))
            obs, reward, terminated, truncated, info = env.step(actions[-1])
            carried |= bool(info["carrying"])
            if terminated or truncated:
                break
    finally:
        env.close()
    assert actions.count(0) > len(actions) / 2 and 4 in actions   # mostly straight ahead
    assert carried                                                # and it took something up


def test_max_steps_above_the_task_default_is_honoured():
    # In-process and without the GIF: writing ~1000 frames takes far longer than playing them.
    from dqn_mine.env import TASKS
    from dqn_mine.play import POLICIES, build_parser, fill_env_settings, make_env, record

    default = TASKS["one-room"].step_limit
    args = build_parser().parse_args(["--policy", "random", "--task", "one-room", "--seed", "0",
                                      "--max-steps", str(default + 5)])
    fill_env_settings(args)
    env = make_env(args)
    try:
        frames, total, steps = record(env, POLICIES["random"](args), args.seed, progress=False)
    finally:
        env.close()
    assert total == 0.0                  # seed 0's random walk never delivers the kit ...
    assert steps == default + 5          # ... so the episode runs to the requested limit
    assert len(frames) == steps + 1


def test_checkpoint_agent_plays_its_training_task(tmp_path):
    run_dir = tmp_path / "run"
    train = subprocess.run(
        [sys.executable, "-m", "dqn_mine.train", "--preset", "smoke", "--serial", "--actors", "1",
         "--updates", "20", "--prefill", "100", "--replay-capacity", "2048",
         "--run-dir", str(run_dir)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert train.returncode == 0, train.stderr[-2000:]
    out = tmp_path / "agent.gif"
    res = play("--checkpoint", str(run_dir), "--max-steps", "30", "--out", str(out))
    assert res.returncode == 0, res.stderr
    assert "agent on one-room" in res.stdout     # the task came from the checkpoint's config
    assert gif_frames(out)[0] >= 2


def test_corrupt_checkpoint_is_one_line(tmp_path):
    bad = tmp_path / "checkpoint.pt"
    bad.write_bytes(b"not a checkpoint")
    res = play("--checkpoint", str(bad), "--out", str(tmp_path / "x.gif"))
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and "checkpoint" in res.stderr
    assert not (tmp_path / "x.gif").exists()


BAD_PLAY = [
    (["--seed", "-1"], "--seed"),
    (["--fps", "0"], "--fps"),
    (["--epsilon", "2"], "--epsilon"),
    (["--out", "NAME"], ".gif"),
    (["--task", "cave"], "task"),
]


@pytest.mark.parametrize("argv,fragment", BAD_PLAY, ids=[" ".join(a) for a, _ in BAD_PLAY])
def test_bad_play_flags_are_one_line_before_recording(tmp_path, argv, fragment):
    argv = [a.replace("NAME", str(tmp_path / "no_extension")) for a in argv]
    if "--out" not in argv:
        argv += ["--out", str(tmp_path / "x.gif")]
    res = play("--policy", "random", *argv)
    assert res.returncode == 2, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and fragment in res.stderr
    assert not list(tmp_path.iterdir())          # nothing written


@pytest.mark.parametrize("content", [
    {"format": 1, "updater": {"online": {}}},                               # no config
    {"format": 1, "updater": {"online": {}}, "config": {"task": "one-room"}},
    {"format": 1, "updater": {"online": {}},                                # weights missing
     "config": {"task": "one-room", "frame_stack": 1, "history_len": 20}},
])
def test_checkpoint_with_missing_parts_is_one_line(tmp_path, content):
    import torch

    bad = tmp_path / "checkpoint.pt"
    torch.save(content, bad)
    res = play("--checkpoint", str(bad), "--out", str(tmp_path / "x.gif"))
    assert res.returncode == 2, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and "checkpoint" in res.stderr
    assert not (tmp_path / "x.gif").exists()


@pytest.mark.parametrize("flag,name,value", [
    ([], "camera_pitch", 0.0), (["--camera-pitch", "12.5"], "camera_pitch", 12.5),
    ([], "held_on_top", False), (["--held-on-top"], "held_on_top", True),
    ([], "room_colours", False), (["--room-colours"], "room_colours", True),
])
def test_look_flags_build_the_env(flag, name, value):
    """Each flag of how the mine looks reaches the env play builds (else the default look)."""
    from dqn_mine.play import build_parser, fill_env_settings, make_env

    args = build_parser().parse_args(["--policy", "random", "--task", "three-room", *flag])
    fill_env_settings(args)
    env = make_env(args)
    try:
        assert getattr(env, name) == value and type(getattr(env, name)) is type(value)
    finally:
        env.close()
