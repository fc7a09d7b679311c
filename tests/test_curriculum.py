"""The curriculum on its own, then its state, the room-count schedule and the evaluation actor
through real runs."""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path

import pytest

from dqn_mine.config import parse_args
from dqn_mine.system.curriculum import Curriculum
from dqn_mine.system.specs import actor_specs, eval_env_kwargs

ROOT = Path(__file__).resolve().parents[1]
# The agent pre-fills: the scripted walker's episodes would not count towards the switches.
FAST = ["--actors", "2", "--prefill", "100", "--replay-capacity", "4096", "--log-interval", "10",
        "--max-episode-steps", "30", "--room-size", "8",
        "--prefill-explorer", "agent"]


def run(*args: str) -> list:
    res = subprocess.run([sys.executable, "-m", "dqn_mine.train", *args], cwd=ROOT,
                         capture_output=True, text=True, timeout=400)
    assert res.returncode == 0, res.stderr[-3000:]
    run_dir = Path(args[args.index("--run-dir") + 1])
    with open(run_dir / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


# -- the Curriculum object alone --------------------------------------------------------------
def test_adaptive_curriculum_starts_easiest_and_advances_one_phase_per_full_window():
    cfg = parse_args(["--task", "three-room", "--curriculum", "adaptive",
                      "--curriculum-window", "3", "--curriculum-threshold", "0.5"])
    cur = Curriculum(cfg)
    assert (cur.phase, cur.num_rooms, cur.logged_phase) == (6, None, 6)
    for ret in (1.0, 1.0):
        cur.record(6, ret)
    cur.advance(updates=10)
    assert cur.phase == 6, "the window is not full yet"
    cur.record(5, 1.0)             # a reviewed (easier) phase's episode does not count
    cur.advance(updates=20)
    assert cur.phase == 6 and len(cur.returns) == 2
    for ret in (1.0, 1.0, 1.0, 1.0):   # a batch of episodes: one advance at most
        cur.record(6, ret)
    cur.advance(updates=30)
    assert cur.phase == 5 and len(cur.returns) == 0 and cur.logged_phase == 5
    for _ in range(3):
        cur.record(5, 0.5)         # the mean must exceed the threshold, not reach it
    cur.advance(updates=40)
    assert cur.phase == 5 and cur.phase_return == 0.5


def test_three_room_preset_is_cpu_with_the_clear_view_and_the_adaptive_one_starts_at_6():
    cfg = parse_args(["--preset", "cpu-three-room"])
    cpu = parse_args(["--preset", "cpu"])                       # two-room's results keep theirs
    assert (cfg.task, cfg.view, cfg.unstick, cfg.updates) == ("three-room", "clear", 2, 600_000)
    assert (cpu.unstick, cpu.view) == (1, "study")
    same = ("curriculum", "curriculum_review", "demos", "backward_step", "lr", "replay_ratio")
    assert {k: getattr(cfg, k) for k in same} == {k: getattr(cpu, k) for k in same}
    assert cfg.curriculum == "backward" and cfg.demos > 0
    assert Curriculum(parse_args(["--task", "three-room", "--curriculum", "adaptive"])).phase == 6


def test_the_view_reaches_the_training_and_the_evaluation_envs():
    """clear: the camera pitched 15 down, room colours, the held item on top, for training and
    scoring alike; study: none of them passed, so the environment keeps its own defaults."""
    clear = parse_args(["--preset", "cpu-three-room"])
    look = {"room_colours": True, "camera_pitch": 15.0, "held_on_top": True}
    for kwargs in (actor_specs(clear)[0].env_kwargs, eval_env_kwargs(clear)):
        assert {name: kwargs[name] for name in look} == look
    for argv in (["--preset", "cpu"], ["--preset", "cpu-three-room", "--view", "study"]):
        study = parse_args(argv)
        for kwargs in (actor_specs(study)[0].env_kwargs, eval_env_kwargs(study)):
            assert not set(look) & set(kwargs)


def test_low_epsilon_return_counts_only_the_near_greedy_episodes_of_the_phase():
    cfg = parse_args(["--task", "three-room", "--curriculum", "adaptive",
                      "--curriculum-window", "4", "--curriculum-threshold", "0.4"])   # at 6
    cur = Curriculum(cfg)
    assert math.isnan(cur.phase_low_eps_return)
    cur.record(6, 1.0, epsilon=0.4)      # an exploring env's success
    cur.record(6, 0.0, epsilon=0.01)     # at the study's rate: counted
    cur.record(5, 1.0, epsilon=0.001)    # a reviewed phase: neither mean
    cur.record(6, 1.0, epsilon=0.002)
    assert cur.phase_return == pytest.approx(2 / 3) and cur.phase_low_eps_return == 0.5
    cur.record(6, 0.0, epsilon=0.2)
    cur.advance(updates=0)               # mean 0.5 > 0.4 over all four: the rule ignores epsilon
    assert cur.phase == 5 and math.isnan(cur.phase_low_eps_return)


def test_the_scripted_prefill_walkers_episodes_do_not_advance_the_curriculum():
    cfg = parse_args(["--task", "three-room", "--curriculum", "adaptive",
                      "--curriculum-window", "2", "--curriculum-threshold", "0.4"])   # at 6
    cur = Curriculum(cfg)
    for _ in range(4):
        cur.record(6, 1.0, epsilon=1.0, scripted=True)   # the walker delivers: not the agent
    cur.advance(updates=0)
    assert cur.phase == 6 and math.isnan(cur.phase_return)
    cur.record(6, 1.0, epsilon=0.01)
    cur.record(6, 1.0, epsilon=0.01)
    cur.advance(updates=0)
    assert cur.phase == 5


def test_adaptive_curriculum_stops_at_the_full_task_and_resumes_where_it_was():
    cfg = parse_args(["--task", "three-room", "--curriculum", "adaptive",
                      "--curriculum-window", "1", "--curriculum-threshold", "-1"])   # 6..1
    cur = Curriculum(cfg)
    seen = []
    for _ in range(8):
        cur.record(cur.phase, 0.0)
        cur.advance(updates=0)
        seen.append(cur.phase)
    assert seen == [5, 4, 3, 2, 1, 1, 1, 1]
    assert Curriculum(cfg, phase=3).phase == 3


def test_room_schedule_follows_the_share_of_updates():
    cfg = parse_args(["--task", "rooms", "--curriculum", "schedule", "--rooms-schedule", "2", "3",
                      "4", "--updates", "90"])
    cur = Curriculum(cfg)
    assert (cur.num_rooms, cur.phase, cur.logged_phase) == (2, 0, 2)
    rooms = []
    for updates in (10, 29, 30, 59, 60, 90, 500):
        cur.advance(updates)
        rooms.append(cur.num_rooms)
    assert rooms == [2, 2, 3, 3, 4, 4, 4]
    assert Curriculum(cfg, updates=45).num_rooms == 3        # a resumed run's position
    assert math.isnan(cur.phase_return)


def test_episode_start_tells_the_environment_what_to_set():
    import numpy as np

    rng = np.random.default_rng(0)
    adaptive = Curriculum(parse_args(["--task", "three-room", "--curriculum", "adaptive"]))
    assert adaptive.episode_start(3, 0, rng) == (3, {"phase": 3})
    rooms = Curriculum(parse_args(["--task", "rooms", "--curriculum", "schedule"]))
    assert rooms.episode_start(0, 4, rng) == (0, {"num_rooms": 4})
    plain = Curriculum(parse_args([]))
    assert plain.episode_start(0, 0, rng) == (0, {}) and plain.phase == 0
    assert plain.num_rooms is None


def test_two_room_has_no_curriculum_phases():
    """Its six-phase table was removed (the backward curriculum beat it): a phase other than 1
    (its full task) and the adaptive curriculum on it are one-line errors."""
    import numpy as np

    from dqn_mine.config import ConfigError
    from dqn_mine.env import MineRescueEnv

    full, one = MineRescueEnv(task="two-room"), MineRescueEnv(task="two-room", phase=1)
    try:
        (obs, info), (obs1, info1) = full.reset(seed=4), one.reset(seed=4)
        assert np.array_equal(obs, obs1) and info == info1 and info["agent_room"] == 0
    finally:
        full.close()
        one.close()

    with pytest.raises(ValueError) as env_error:
        MineRescueEnv(task="two-room", phase=3)
    with pytest.raises(ConfigError) as config_error:
        parse_args(["--task", "two-room", "--curriculum", "adaptive"])
    for error in (env_error, config_error):
        message = str(error.value)
        assert "three-room" in message and "two-room" in message and "\n" not in message


# -- through real runs -------------------------------------------------------------------------
def test_phases_advance_through_shared_state(tmp_path):
    """A threshold every episode beats moves the phase from 6 to 1; the actors follow it
    (each phase gets its own window of episodes, all started in that phase)."""
    rows = run("--task", "three-room", "--curriculum", "adaptive", "--curriculum-window", "2",
               "--curriculum-threshold", "-1", "--updates", "400", "--serial",
               "--run-dir", str(tmp_path / "cl"), *FAST)
    phases = [int(r["phase"]) for r in rows]
    assert phases == sorted(phases, reverse=True), phases
    assert phases[-1] == 1 and phases[0] < 6


def test_review_starts_a_share_of_episodes_in_easier_phases():
    import numpy as np

    cfg = parse_args(["--task", "three-room", "--curriculum", "adaptive",
                      "--curriculum-review", "0.3"])
    rng = np.random.default_rng(0)
    drawn = np.array([Curriculum(cfg).review_phase(4, rng) for _ in range(20_000)])
    shares = [np.mean(drawn == p) for p in (1, 2, 3, 4, 5, 6)]
    assert shares[0] == shares[1] == shares[2] == 0 and abs(shares[3] - 0.7) < 0.015
    assert abs(shares[4] - 0.15) < 0.01 and abs(shares[5] - 0.15) < 0.01
    # nothing easier to review
    assert {Curriculum(cfg).review_phase(6, rng) for _ in range(100)} == {6}
    study = parse_args(["--task", "three-room", "--curriculum", "adaptive"])
    state = rng.bit_generator.state
    assert {Curriculum(study).review_phase(2, rng) for _ in range(100)} == {2}
    assert rng.bit_generator.state == state, "without review no random number is drawn"


def test_review_starts_that_share_of_the_episodes_in_passed_phases():
    """In phase 2 of three-room with --curriculum-review 0.5, about half of the episodes start
    in an easier phase already passed (3..6, uniformly)."""
    import numpy as np

    cfg = parse_args(["--task", "three-room", "--curriculum", "adaptive",
                      "--curriculum-review", "0.5"])
    cur, rng = Curriculum(cfg), np.random.default_rng(0)
    phases = []
    for _ in range(2_000):
        phase, settings = cur.episode_start(2, 0, rng)
        assert settings["phase"] == phase
        phases.append(phase)
    phases = np.array(phases)
    assert abs(np.mean(phases > 2) - 0.5) < 0.04
    assert set(phases) == {2, 3, 4, 5, 6}


def test_phase_holds_when_returns_stay_below_threshold(tmp_path):
    rows = run("--task", "three-room", "--curriculum", "adaptive", "--curriculum-window", "2",
               "--curriculum-threshold", "1.0", "--updates", "40",
               "--run-dir", str(tmp_path / "hold"), *FAST)
    assert {int(r["phase"]) for r in rows} == {6}


def test_room_schedule_switches_at_the_right_update(tmp_path):
    rows = run("--task", "rooms", "--curriculum", "schedule", "--rooms-schedule", "2", "3", "4",
               "--updates", "90", "--serial", "--run-dir", str(tmp_path / "rooms"), *FAST)
    by_update = {int(r["update"]): int(r["phase"]) for r in rows}
    assert [by_update[u] for u in (10, 20, 30, 40, 60, 70, 80)] == [2, 2, 3, 3, 4, 4, 4]


def test_evaluation_results_arrive_in_the_metrics(tmp_path):
    rows = run("--task", "one-room", "--eval-every", "200", "--eval-episodes", "2",
               "--updates", "200",
               "--run-dir", str(tmp_path / "eval"), *FAST)
    evaluated = [r for r in rows if r["eval_return"] != ""]
    assert evaluated, "no evaluation result reached metrics.csv"
    assert all(0.0 <= float(r["eval_return"]) <= 1.0 for r in evaluated)
    assert all(1 <= float(r["eval_length"]) <= 30 for r in evaluated)
    videos = sorted((tmp_path / "eval" / "videos").glob("eval_*.gif"))
    assert videos, "no evaluation video was saved"
    from PIL import Image

    with Image.open(videos[0]) as gif:
        assert gif.n_frames >= 2


def test_evaluation_actor_runs_the_full_target_task():
    cfg = parse_args(["--task", "three-room", "--placement", "any-room", "--eval-every", "1000"])
    specs = actor_specs(cfg)
    evaluator = specs[-1]
    assert len(specs) == cfg.actors + 1 and evaluator.streams == ()
    assert evaluator.evaluates and not any(s.evaluates for s in specs[:-1])
    assert evaluator.env_kwargs["placement"] == "fixed" and evaluator.env_kwargs["task"] == \
        "three-room"
    assert all(s.env_kwargs["placement"] == "any-room" for s in specs[:-1])
    adaptive = parse_args(["--task", "three-room", "--curriculum", "adaptive",
                           "--eval-every", "1000"])
    assert Curriculum(adaptive).phase == 6 and actor_specs(adaptive)[-1].evaluates
    assert eval_env_kwargs(adaptive)["task"] == "three-room" and "phase" not in \
        eval_env_kwargs(adaptive)
    rooms = parse_args(["--task", "rooms", "--curriculum", "schedule", "--rooms-schedule", "3", "4",
                        "5", "--eval-every", "1000"])
    assert eval_env_kwargs(rooms)["num_rooms"] == 5 and Curriculum(rooms).num_rooms == 3
    three = parse_args(["--task", "rooms", "--num-rooms", "3", "--placement", "any-room",
                        "--eval-num-rooms", "5", "--eval-every", "1000"])
    assert actor_specs(three)[0].env_kwargs["num_rooms"] == 3
    assert eval_env_kwargs(three)["num_rooms"] == 5 and eval_env_kwargs(three)["placement"] == \
        "fixed"


@pytest.mark.parametrize("value", [math.nan])
def test_metrics_nan_cells_are_empty(tmp_path, value):
    from dqn_mine.metrics import MetricsTable, read_metrics

    table = MetricsTable(tmp_path / "m.csv")
    table.write({"update": 1, "eval_return": value, "loss": 0.5})
    table.close()
    row = read_metrics(tmp_path / "m.csv")[0]
    assert row["update"] == 1 and row["loss"] == 0.5 and math.isnan(row["eval_return"])


def test_curriculum_dr_starts_a_share_of_episodes_as_the_randomised_full_task():
    import numpy as np

    from dqn_mine.env import MineRescueEnv
    from dqn_mine.system.curriculum import DR_PHASE

    cfg = parse_args(["--task", "three-room", "--curriculum", "adaptive", "--curriculum-dr", "0.3"])
    cur, rng = Curriculum(cfg), np.random.default_rng(0)
    starts = [cur.episode_start(3, 0, rng) for _ in range(4_000)]
    dr = [settings for phase, settings in starts if phase == DR_PHASE]
    assert abs(len(dr) / len(starts) - 0.3) < 0.025
    assert all(s == {"phase": None, "placement": "any-room"} for s in dr)
    assert all(s == {"phase": 3, "placement": "fixed"} for p, s in starts if p != DR_PHASE)
    # an actor's env built for the fixed task takes both kinds of start, episode by episode
    env = MineRescueEnv(task="three-room")
    rooms = set()
    for seed, (phase, settings) in enumerate(starts[:40]):
        for name, value in settings.items():
            setattr(env, name, value)
        _, info = env.reset(seed=seed)
        if phase == DR_PHASE:
            rooms.add((info["agent_room"], info["kit_room"], info["miner_room"]))
            assert not info["carrying"]
        else:
            assert info["agent_room"] == 2 and info["miner_room"] == 0   # phase 3: room 2
    env.close()
    assert len(rooms) >= 4 and rooms != {(0, 2, 0)}
