"""`python -m dqn_mine.evaluate` and `dqn_mine.load_agent` on a real (tiny) trained checkpoint."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import dqn_mine
from dqn_mine.env import MineRescueEnv
from dqn_mine.env.expert import Expert
from dqn_mine.evaluate import OUTCOMES, _outcome
from dqn_mine.evaluate import evaluate as evaluate_episodes

ROOT = Path(__file__).resolve().parents[1]
FIELDS = {"episodes", "success_rate", "mean_return", "std_return", "mean_length", "task", "seed"}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("eval") / "run"
    res = subprocess.run(
        [sys.executable, "-m", "dqn_mine.train", "--preset", "smoke", "--serial", "--actors", "1",
         "--updates", "20", "--prefill", "100", "--replay-capacity", "2048",
         "--unstick", "2", "--run-dir", str(run)],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    return run


def evaluate(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dqn_mine.evaluate", "--quiet", *args],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)


def test_evaluate_writes_eval_json_and_is_reproducible(run_dir, tmp_path):
    res = evaluate(str(run_dir), "--episodes", "3", "--max-steps", "25")
    assert res.returncode == 0, res.stderr
    scores = json.loads((run_dir / "eval.json").read_text())
    assert FIELDS <= set(scores)
    assert scores["episodes"] == 3 and scores["task"] == "one-room"   # the checkpoint's task
    assert 0.0 <= scores["success_rate"] <= 1.0
    assert 1 <= scores["mean_length"] <= 25
    assert "success" in res.stdout and "one-room, 3 episodes" in res.stdout
    assert set(scores["outcomes"]) == set(OUTCOMES) and sum(scores["outcomes"].values()) == 3
    assert scores["outcomes"]["delivered"] == round(3 * scores["success_rate"])
    again = evaluate(str(run_dir / "checkpoint.pt"), "--episodes", "3", "--max-steps", "25",
                     "--out", str(tmp_path / "again.json"), "--video", str(tmp_path / "e.gif"))
    assert again.returncode == 0, again.stderr
    same = json.loads((tmp_path / "again.json").read_text())
    assert {k: same[k] for k in FIELDS} == {k: scores[k] for k in FIELDS}   # same seeds, same play
    assert (tmp_path / "e.gif").stat().st_size > 0
    assert scores["unstick"] is False
    assert scores["held"] is False
    assert scores["epsilon"] == 0.01     # as the run's evaluation actor
    unstuck = evaluate(str(run_dir), "--episodes", "1", "--max-steps", "25", "--unstick",
                       "--held", "--out", str(tmp_path / "unstuck.json"))
    assert unstuck.returncode == 0, unstuck.stderr
    unstuck_scores = json.loads((tmp_path / "unstuck.json").read_text())
    assert unstuck_scores["unstick"] is True and unstuck_scores["held"] is True


def test_evaluate_plays_by_default_what_the_runs_evaluation_actor_plays(run_dir, tmp_path):
    """Near-greedy (epsilon 0.01, no unstick or held actions, whatever the training actors
    did) on the run's task with a fixed placement (a DR run's evaluation actor plays the fixed
    task); explicit flags still win."""
    from dqn_mine import checkpoint as ckpt
    from dqn_mine.config import Config

    saved = ckpt.load(run_dir)
    cfg = Config.from_dict({**saved["config"], "exploration": "ez", "unstick": 1,
                            "placement": "any-room", "task": "two-room"})
    ckpt.save(tmp_path, saved["updater"], saved["counters"], cfg)
    res = evaluate(str(tmp_path), "--episodes", "1", "--max-steps", "20")
    assert res.returncode == 0, res.stderr
    scores = json.loads((tmp_path / "eval.json").read_text())
    assert (scores["epsilon"], scores["unstick"], scores["held"]) == (0.01, False, False)
    assert (scores["task"], scores["placement"]) == ("two-room", "fixed")
    held = evaluate(str(tmp_path), "--episodes", "1", "--max-steps", "20", "--epsilon", "0.05",
                    "--unstick", "--held", "--out", str(tmp_path / "held.json"))
    assert held.returncode == 0, held.stderr
    scores = json.loads((tmp_path / "held.json").read_text())
    assert (scores["epsilon"], scores["unstick"], scores["held"]) == (0.05, True, True)


def test_a_checkpoint_of_config_version_1_evaluates_or_fails_in_one_line(run_dir, tmp_path):
    """A checkpoint saved before config versions: its settings migrate (no prefill_explorer:
    the agent's; per off: zeta 0; removed settings at their neutral values dropped); one that
    used a removed setting fails in one line that names its version."""
    import torch

    from dqn_mine import checkpoint as ckpt

    saved = ckpt.load(run_dir)
    old = {k: v for k, v in saved["config"].items() if k != "prefill_explorer"}
    old.update(per=False, episode_order="ended", init_priority="actor",
               target_update_early_phase=17)
    (tmp_path / "v1").mkdir()
    torch.save({**saved, "config": old}, tmp_path / "v1" / "checkpoint.pt")
    config = ckpt.load(tmp_path / "v1")["config"]
    assert (config["zeta"], config["prefill_explorer"]) == (0.0, "agent") and "per" not in config
    res = evaluate(str(tmp_path / "v1"), "--episodes", "1", "--max-steps", "20")
    assert res.returncode == 0, res.stderr
    (tmp_path / "started").mkdir()
    torch.save({**saved, "config": {**old, "episode_order": "started"}},
               tmp_path / "started" / "checkpoint.pt")
    res = evaluate(str(tmp_path / "started"), "--episodes", "1")
    assert res.returncode == 2 and res.stderr.strip().count("\n") == 0
    assert "version 1" in res.stderr and "episode_order" in res.stderr


def test_load_agent_plays_an_episode_like_the_readme(run_dir):
    agent = dqn_mine.load_agent(run_dir)
    env = MineRescueEnv(task="one-room", room_size=8.0, max_episode_steps=30)
    actions = []
    for _ in range(2):                      # two episodes: reset clears the action history
        obs, info = env.reset(seed=0)
        agent.reset()
        done, episode = False, []
        while not done:
            action = agent.predict(obs, info)
            assert 0 <= action < env.action_space.n
            obs, reward, terminated, truncated, info = env.step(action)
            episode.append(action)
            done = terminated or truncated
        actions.append(episode)
    env.close()
    assert actions[0] == actions[1]          # greedy, same seed: the same episode
    history = agent.core.histories[0]           # what the network was fed last
    assert history.dtype == np.int8 and len(history) == 20


def test_an_unsticking_agent_keeps_the_runs_cycle(run_dir):
    """The run was configured with --unstick 2: its agent counts the same loops as stuck."""
    assert dqn_mine.load_agent(run_dir, unstick=True).core.recent.shape[1] == 2
    assert dqn_mine.load_agent(run_dir).core.recent.shape[1] == 0   # not unsticking: no frames


def test_a_holding_agent_holds_for_the_runs_durations(run_dir):
    """held=True: random actions held as the run's ez training actors hold them."""
    explorer = dqn_mine.load_agent(run_dir, epsilon=0.5, held=True).core.explorer
    assert explorer.durations
    assert (explorer.mu, explorer.max_duration) == (2.0, 100)
    assert not dqn_mine.load_agent(run_dir).core.explorer.durations


def test_outcomes_say_what_the_agent_held_at_the_end():
    from dqn_mine.env.entities import BOULDER

    env = MineRescueEnv(task="two-room")
    env.reset(seed=0)
    boulder = next(e for e in env.entities if e.kind == BOULDER)
    assert _outcome(env, True, True) == "delivered"
    assert _outcome(env, False, False) == "kit never taken"
    assert _outcome(env, False, True) == "kit dropped"
    assert _outcome(env, False, False, entered_kit_room=False) == "kit's room never entered"
    assert _outcome(env, False, False, False, left_start_room=False) == "start room never left"
    env.carrying = boulder
    assert _outcome(env, False, True) == "holding a boulder"
    env.carrying = env.kit
    assert _outcome(env, False, True) == "holding the kit"
    env.close()


@pytest.mark.parametrize("argv,fragment", [
    (["--episodes", "0"], "--episodes must be at least 1"),
    (["--epsilon", "2"], "--epsilon must be in [0, 1]"),
    (["--video", "x.avi"], "--video must name a .gif or .mp4"),
    (["--video-stride", "0"], "--video-stride must be at least 1"),
])
def test_bad_evaluate_flags_are_one_line(run_dir, argv, fragment):
    res = evaluate(str(run_dir), *argv)
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and fragment in res.stderr


def test_missing_or_corrupt_checkpoint_is_one_line(tmp_path):
    bad = tmp_path / "checkpoint.pt"
    bad.write_bytes(b"not a checkpoint")
    for target in (bad, tmp_path / "nowhere"):
        res = evaluate(str(target), "--episodes", "2")
        assert res.returncode == 2
        assert res.stderr.startswith("error:") and res.stderr.strip().count("\n") == 0
    with pytest.raises(ValueError):
        dqn_mine.load_agent(bad)


class _ExpertEverySecondEpisode:
    """Only turns in its first, third, ... episode and plays the scripted expert in the others:
    some episodes deliver, some do not."""

    def __init__(self, env):
        self.env, self.expert, self.episodes = env, None, 0

    def reset(self):
        self.episodes += 1
        self.expert = Expert(self.env) if self.episodes % 2 == 0 else None

    def predict(self, obs, info):
        return self.expert.act() if self.expert else 0


def test_video_of_delivered_films_the_first_delivered_episode_and_keeps_the_scores():
    env = MineRescueEnv(task="one-room", room_size=8.0, max_episode_steps=60,
                        render_mode="rgb_array")
    agent = _ExpertEverySecondEpisode(env)
    plain, none = evaluate_episodes(env, agent, 4, seed=10, progress=False)
    first, first_frames = evaluate_episodes(env, _ExpertEverySecondEpisode(env), 4, seed=10,
                                            progress=False, video_of="first")
    scores, frames = evaluate_episodes(env, _ExpertEverySecondEpisode(env), 4, seed=10,
                                       progress=False, video_of="delivered")
    env.close()
    assert none == [] and plain["video_seed"] is None
    assert plain["outcomes"]["delivered"] == 2 and plain["outcomes"]["kit never taken"] == 2
    assert {k: v for k, v in scores.items() if k != "video_seed"} == \
        {k: v for k, v in plain.items() if k != "video_seed"}
    assert first["video_seed"] == 10 and len(first_frames) == 61      # 60 steps, undelivered
    assert scores["video_seed"] == 11 and 2 < len(frames) < 61          # delivered sooner
    assert frames[0].ndim == 3 and frames[0].shape[2] == 3
    assert not np.array_equal(frames[0], frames[-1])


@pytest.mark.parametrize("count,n,kept", [(10, 1, list(range(10))), (10, 3, [0, 3, 6, 9]),
                                          (11, 3, [0, 3, 6, 9, 10]), (1, 4, [0])])
def test_video_stride_keeps_every_nth_frame_and_the_last(count, n, kept):
    from dqn_mine.evaluate import every_nth

    assert every_nth(list(range(count)), n) == kept


def test_an_agent_that_never_leaves_its_room_is_told_apart():
    env = MineRescueEnv(task="two-room", max_episode_steps=400)     # the kit in room 1
    turner = _ExpertEverySecondEpisode(env)             # episode 1 only turns, 2 is the expert
    scores, _ = evaluate_episodes(env, turner, 2, seed=4, progress=False)
    env.close()
    assert scores["outcomes"]["start room never left"] == 1
    assert scores["outcomes"]["kit's room never entered"] == 0
    assert scores["outcomes"]["delivered"] == 1


def test_evaluate_plays_on_one_torch_thread(run_dir, tmp_path):
    """A batch-1 forward pass on two threads crawls beside a training run; evaluate uses one."""
    import torch

    from dqn_mine.evaluate import main

    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        code = main([str(run_dir), "--episodes", "1", "--max-steps", "5", "--quiet",
                     "--out", str(tmp_path / "one.json")])
        assert code == 0 and torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(threads)
