"""The backward curriculum: starts on the expert's path, the frontier's rule, full-task records,
and a real run that reaches the full task."""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dqn_mine.config import ConfigError, parse_args
from dqn_mine.env import MineRescueEnv
from dqn_mine.env.expert import Expert, Unsolved, solve
from dqn_mine.system.backward import (
    BUDGET_BASE,
    BUDGET_PER_STEP,
    SOLUTION_REUSE,
    PathStarts,
    start_budget,
)
from dqn_mine.system.control import Episode
from dqn_mine.system.curriculum import REVIEW, Curriculum
from dqn_mine.system.episodes import EpisodeStats

ROOT = Path(__file__).resolve().parents[1]


def expert_frames(task: str, seed: int, **kw) -> tuple[list, list]:
    """Every frame the expert sees playing episode ``seed`` rendered, step by step, and its
    actions."""
    env = MineRescueEnv(task=task, **kw)
    obs, _ = env.reset(seed=seed)
    expert, frames, actions = Expert(env), [obs], []
    while True:
        action = expert.act()
        obs, _, terminated, truncated, _ = env.step(action)
        actions.append(action)
        if terminated or truncated:
            env.close()
            return frames, actions
        frames.append(obs)


@pytest.mark.parametrize("task,kw", [("two-room", {}), ("three-room", {}),
                                     ("rooms", {"num_rooms": 4, "placement": "any-room"})])
def test_a_start_is_the_frame_the_expert_saw_at_that_step(task, kw):
    env = MineRescueEnv(task=task, **kw)
    starts = PathStarts(np.random.default_rng(3), env.max_episode_steps)
    obs, info, full, share = starts.reset(env, to_go=7)
    frames, actions = expert_frames(task, starts.seed, **kw)
    assert actions == starts.solution          # the unrendered plan is the rendered expert's
    length = len(actions)
    assert not full and share == pytest.approx(7 / length)
    assert np.array_equal(obs, frames[length - 7])
    assert env.steps == 0 and env.max_episode_steps == start_budget(7, 2000 if task != "two-room"
                                                                    else 1000)
    # the agent plays on from there: the expert's last seven actions deliver
    for action in actions[-7:]:
        _, reward, terminated, _, _ = env.step(action)
    assert terminated and reward == 1.0
    env.close()


def test_a_start_beyond_the_solution_is_the_full_task_with_the_tasks_limit():
    env = MineRescueEnv(task="two-room")
    starts = PathStarts(np.random.default_rng(0), env.max_episode_steps)
    obs, info, full, share = starts.reset(env, to_go=5000)
    first, _ = MineRescueEnv(task="two-room").reset(seed=starts.seed)
    assert full and share == 1.0 and env.max_episode_steps == 1000
    assert np.array_equal(obs, first) and info["agent_room"] == 0
    env.close()


def test_a_solved_seed_serves_several_episodes_then_a_new_one_is_drawn():
    env = MineRescueEnv(task="two-room")
    starts = PathStarts(np.random.default_rng(1), env.max_episode_steps)
    seeds = []
    for to_go in range(1, 2 * SOLUTION_REUSE + 1):
        starts.reset(env, to_go)
        seeds.append(starts.seed)
    assert seeds[:SOLUTION_REUSE] == [seeds[0]] * SOLUTION_REUSE
    assert seeds[SOLUTION_REUSE:] == [seeds[-1]] * SOLUTION_REUSE and seeds[0] != seeds[-1]
    env.close()


def test_seeds_the_expert_cannot_solve_within_the_limit_are_passed_over():
    env = MineRescueEnv(task="two-room", max_episode_steps=130)   # solutions: ~110-200 steps
    starts = PathStarts(np.random.default_rng(2), env.max_episode_steps)
    for _ in range(3):
        starts.uses_left = 0
        starts.reset(env, to_go=5)
        assert len(starts.solution) <= 130
    short = PathStarts(np.random.default_rng(2), 5)
    with pytest.raises(Unsolved, match="step limit is too short"):
        short.reset(env, to_go=1)
    env.close()


def test_start_budget_grows_with_the_steps_to_go_up_to_the_tasks_limit():
    assert start_budget(1, 1000) == BUDGET_PER_STEP + BUDGET_BASE
    assert start_budget(50, 1000) == 50 * BUDGET_PER_STEP + BUDGET_BASE
    assert start_budget(900, 1000) == 1000


def test_fast_forward_refuses_actions_that_deliver():
    env = MineRescueEnv(task="one-room", room_size=8.0)
    actions = solve(env, 4, 1000)
    env.reset(seed=4)
    with pytest.raises(ValueError, match="deliver"):
        env.fast_forward(actions)
    env.close()


# -- the frontier's rule ------------------------------------------------------------------------
def backward(*flags: str) -> Curriculum:
    return Curriculum(parse_args(["--curriculum", "backward", "--curriculum-window", "4",
                                  "--curriculum-threshold", "0.5", "--backward-step", "10",
                                  *flags]))


def test_frontier_moves_back_one_step_per_full_window_above_the_threshold():
    cur = backward()
    assert cur.phase == 10 and cur.logged_phase == 10
    for ret in (1.0, 1.0, 1.0):
        cur.record(10, ret, share=0.1)
    cur.advance(updates=1)
    assert cur.phase == 10, "the window is not full yet"
    cur.record(REVIEW, 1.0)          # review episodes do not count
    cur.record(20, 1.0)              # nor episodes of another frontier
    cur.advance(updates=2)
    assert cur.phase == 10 and len(cur.returns) == 3
    for ret in (1.0, 1.0, 1.0, 1.0, 1.0):   # a batch: one move at most
        cur.record(10, ret, share=0.1)
    cur.advance(updates=3)
    assert cur.phase == 20 and len(cur.returns) == 0 and math.isnan(cur.start_share)
    for ret in (1.0, 0.0, 1.0, 0.0):         # the mean must exceed the threshold
        cur.record(20, ret, share=0.25)
    cur.advance(updates=4)
    assert cur.phase == 20 and cur.phase_return == 0.5 and cur.start_share == 0.25


def test_frontier_stops_at_the_tasks_step_limit_and_resumes_where_it_was():
    cur = backward("--max-episode-steps", "25")
    for _ in range(3):
        for _ in range(4):
            cur.record(cur.phase, 1.0, share=0.5)
        cur.advance(updates=1)
    assert cur.phase == 25
    resumed = Curriculum(parse_args(["--curriculum", "backward"]), phase=25)
    assert resumed.phase == 25


def test_frontier_stays_once_all_its_starts_are_the_full_task():
    cur = backward()
    for shares in ((0.5, 1.0, 1.0, 1.0), (1.0, 1.0, 1.0, 1.0)):
        for share in shares:
            cur.record(cur.phase, 1.0, share=share)
        cur.advance(updates=1)
    assert cur.phase == 20, "moved once (a start on the path), then stayed"


def test_starts_lie_in_the_frontier_and_review_starts_nearer():
    rng = np.random.default_rng(0)
    cur = backward("--curriculum-review", "0.3")
    cur.phase = 40
    draws = [cur.backward_start(40, rng) for _ in range(4000)]
    frontier = [to_go for phase, to_go in draws if phase == 40]
    review = [to_go for phase, to_go in draws if phase == REVIEW]
    assert set(frontier) == set(range(31, 41))
    assert set(review) == set(range(1, 31))
    assert len(review) / len(draws) == pytest.approx(0.3, abs=0.03)
    # the first frontier has nothing nearer to review
    assert {cur.backward_start(10, rng)[0] for _ in range(200)} == {10}


def test_backward_starts_every_task_and_placement():
    for flags in (["--task", "three-room"], ["--task", "rooms", "--num-rooms", "5"],
                  ["--task", "two-room", "--placement", "any-room"]):
        assert parse_args(["--curriculum", "backward", *flags]).curriculum == "backward"
    with pytest.raises(ConfigError, match="--backward-step must be at least 1"):
        parse_args(["--curriculum", "backward", "--backward-step", "0"])


def test_full_task_return_counts_only_episodes_begun_at_the_real_start():
    stats = EpisodeStats(parse_args([]))
    stats.add(Episode(0, 1.0, 30, 10, False, full_task=False, start_share=0.1))
    stats.add(Episode(0, 0.0, 1000, 150, False, full_task=True, start_share=1.0))
    stats.add(Episode(1, 1.0, 400, 0, True))                        # evaluation: apart
    assert stats.returns.mean == 0.5 and stats.full_returns.mean == 0.0


def test_episode_records_keep_the_start_through_shared_memory():
    from dqn_mine.shared import SharedBlocks
    from dqn_mine.system.control import Control

    with SharedBlocks.create(Control.specs(2)) as blocks:
        control = Control(blocks)
        sent = [Episode(1, 1.0, 12, 30, False, 0.01, False, 0.25),
                Episode(0, 0.0, 900, 0, True, float("nan"), True, float("nan"))]
        for ep in sent:
            control.record_episode(ep)
        got = sorted(control.drain_episodes(), key=lambda e: e.actor)
        assert got[1] == sent[0]
        assert got[0][:4] == sent[1][:4] and got[0].full_task and math.isnan(got[0].start_share)


# -- a real run ---------------------------------------------------------------------------------
def test_a_backward_run_reaches_the_full_task_and_records_it(tmp_path):
    """Serial, one-room 8 x 8 (the expert's solutions: 11-58 steps, most 20-45): the frontier
    moves back past most solutions' length within minutes, and the episodes that then begin at
    the real start are recorded as the full task."""
    run_dir = tmp_path / "run"
    res = subprocess.run(
        [sys.executable, "-m", "dqn_mine.train", "--preset", "smoke", "--serial",
         "--curriculum", "backward", "--backward-step", "20", "--curriculum-window", "20",
         "--curriculum-threshold", "0.3", "--replay-ratio", "0.1", "--updates", "600",
         "--prefill", "500", "--run-dir", str(run_dir), "--log-interval", "100",
         "--seed", "1"],
        cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    with open(run_dir / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    phases = [int(r["phase"]) for r in rows]
    assert phases[0] == 20 and phases == sorted(phases) and phases[-1] >= 40
    assert int(rows[-1]["full_task_episodes"]) > 0, "no episode began at the task's real start"
    assert rows[-1]["full_task_return"] != ""


def test_progress_bar_shows_the_frontier_its_success_and_the_full_task_return():
    from dqn_mine.metrics import progress_postfix

    shown = progress_postfix({"phase": 40, "phase_return": 0.5, "start_share": 0.25,
                              "full_task_return": 0.125})
    assert (shown["phase"], shown["phase_ret"], shown["share"], shown["full"]) == \
        ("40", "0.5", "0.25", "0.125")


def test_an_actor_records_its_starts_on_the_path_and_the_full_task_as_such():
    """A real actor in this process: with the frontier at 3 steps to go its episodes start
    there (recorded under that frontier, not as the full task); with the
    frontier beyond every solution they are the full task."""
    import dataclasses

    import torch

    from dqn_mine.agent.network import DuelingQNetwork
    from dqn_mine.config import PRESETS, Config
    from tests.test_actor import in_process_actor

    cfg = dataclasses.replace(Config(**PRESETS["smoke"], preset="smoke"), actors=1,
                              envs_per_actor=2, replay_capacity=4096, eval_every=0,
                              curriculum="backward", backward_step=3, epsilon_schedule="fixed",
                              epsilon=0.0).validate()
    torch.manual_seed(0)
    net = DuelingQNetwork(frame_stack=cfg.frame_stack, history_len=cfg.history_len)
    for frontier, full in ((3, False), (cfg.max_episode_steps, True)):
        with in_process_actor(cfg, net, phase=frontier) as actor:
            assert (actor.phases == frontier).all() and (actor.full == full).all()
            assert ((actor.to_go >= 1) & (actor.to_go <= frontier)).all()
            while actor.episodes < 4:
                actor.step()
            records = actor.control.drain_episodes()
            assert len(records) >= 4
            assert {(r.phase, r.full_task) for r in records} == {(frontier, full)}
            assert all(0 < r.start_share <= 1 for r in records)
