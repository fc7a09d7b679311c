"""Solvability (the scripted expert), curriculum phase starts and any-room coverage."""

from __future__ import annotations

import math
import statistics

import pytest

from dqn_mine.env import MineRescueEnv
from dqn_mine.env.entities import BOULDER
from dqn_mine.env.tasks import PHASES, phase_table
from tests.env_configs import TASK_CONFIGS, ids

SOLVE_CONFIGS = TASK_CONFIGS + [
    dict(task="rooms", num_rooms=5, placement="any-room"),
    dict(task="one-room", room_size=8.0, max_episode_steps=200),  # the smoke preset's task
    # the smallest rooms with two doorways each: little space to put a boulder aside
    dict(task="three-room", room_size=8.0),
    dict(task="rooms", num_rooms=5, room_size=8.0, placement="any-room"),
    dict(task="rooms", num_rooms=12),                # the most rooms the env accepts
]
IDS = ids(SOLVE_CONFIGS)


def expert_episode(env: MineRescueEnv, seed: int) -> tuple:
    """(return, steps) of one expert episode."""
    env.reset(seed=seed)
    total, steps = 0.0, 0
    while True:
        _, reward, terminated, truncated, _ = env.step(env.expert_action())
        total += reward
        steps += 1
        if terminated or truncated:
            return total, steps


def open_doorways(env: MineRescueEnv) -> list:
    """Per door in chain order: is no boulder standing in its opening?"""
    boulders = [e for e in env.world_entities() if e.kind == BOULDER]
    return [all(math.dist((b.x, b.z), door.center) > door.width / 2 for b in boulders)
            for door in env.layout.doors]


def solve_rate(config: dict, seeds: range) -> tuple:
    env = MineRescueEnv(**config)
    results = [expert_episode(env, s) for s in seeds]
    env.close()
    solved = [steps for ret, steps in results if ret == 1.0]
    return len(solved) / len(results), solved, env.max_episode_steps


@pytest.mark.parametrize("config", SOLVE_CONFIGS, ids=IDS)
def test_expert_solves_every_task_within_the_step_limit(config):
    # seeds 31 and 48 of three-room at room size 8 once left the expert no spot for a boulder
    rate, steps, limit = solve_rate(config, [*range(10), 31, 48])
    assert rate >= 11 / 12, f"expert solved only {rate:.0%}"
    assert max(steps) < limit


@pytest.mark.slow
@pytest.mark.parametrize("config", SOLVE_CONFIGS, ids=IDS)
def test_expert_solves_nearly_all_of_100_episodes(config):
    rate, _, _ = solve_rate(config, range(1000, 1100))
    assert rate >= 0.97, f"expert solved only {rate:.0%}"


@pytest.mark.parametrize("phase", sorted(PHASES))
def test_phase_starts_as_specified(phase):
    env = MineRescueEnv(task="three-room", phase=phase)
    want = phase_table("three-room")[phase]
    for seed in range(5):
        _, info = env.reset(seed=seed)
        doors = len(env.layout.doors)
        assert info["agent_room"] == want.agent_room
        assert info["miner_room"] == 0
        assert info["carrying_kit"] == info["carrying"] == want.carrying_kit
        if not want.carrying_kit:
            assert info["kit_room"] == 2
        # Boulders moved aside leave their doorways open: the chain's first k are clear.
        cleared = want.boulders_aside
        assert open_doorways(env) == [True] * cleared + [False] * (doors - cleared)
    env.close()


def test_harder_phases_need_more_expert_steps():
    """The easiest phase (carrying the kit next to the miner) is first, phase 1 the full task."""
    means = {}
    for phase in sorted(PHASES):
        env = MineRescueEnv(task="three-room", phase=phase)
        means[phase] = statistics.mean(expert_episode(env, s)[1] for s in range(8))
        env.close()
    order = [means[p] for p in sorted(PHASES, reverse=True)]
    assert order == sorted(order), means
    assert order[0] < order[-1] / 5, means


@pytest.mark.parametrize("config", [dict(task="two-room"), dict(task="three-room"),
                                    dict(task="rooms", num_rooms=4)])
def test_any_room_placement_covers_every_room(config):
    env = MineRescueEnv(placement="any-room", **config)
    seen = {"agent_room": set(), "kit_room": set(), "miner_room": set()}
    for seed in range(120):
        _, info = env.reset(seed=seed)
        for key in seen:
            seen[key].add(info[key])
    rooms = set(range(info["num_rooms"]))
    assert all(found == rooms for found in seen.values()), seen
    env.close()
