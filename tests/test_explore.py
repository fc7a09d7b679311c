"""Exploration: the ez-greedy process, the delivery reach, and the exploration measurement."""

import math

import numpy as np
import pytest

from dqn_mine.agent.explore import (
    HELD_ACTIONS,
    BumpAndPress,
    Explorer,
    PrefillFirst,
    zeta_durations,
)
from dqn_mine.bench.explore import POLICIES, SUBGOALS, fresh_network_inputs, measure
from dqn_mine.env import MineRescueEnv
from dqn_mine.env.mine import AGENT_RADIUS, FORWARD_STEP, HEADINGS

INTERACT = 4


# --- the exploration process -------------------------------------------------------------------

def test_zeta_durations_follow_the_power_law():
    rng = np.random.default_rng(0)
    n = zeta_durations(rng, 200_000, mu=2.0, cap=5)
    p = np.arange(1, 6) ** -2.0
    p /= p.sum()
    freq = np.bincount(n, minlength=6)[1:] / len(n)
    assert n.min() == 1 and n.max() == 5
    np.testing.assert_allclose(freq, p, atol=0.005)


def test_epsilon_zero_is_greedy_and_one_is_uniform():
    greedy = np.array([3, 1, 0, 5])
    ex = Explorer(0.0, 4, np.random.default_rng(0), durations=True)
    for _ in range(50):
        assert (ex.act(greedy) == greedy).all()
    ex = Explorer(1.0, 1000, np.random.default_rng(1))
    counts = np.bincount(ex.act(np.zeros(1000, int)), minlength=6)
    assert counts.min() > 120 and counts.max() < 215   # 1000 / 6 = 167 each


def test_held_motion_lasts_its_duration_and_interaction_one_step():
    rng = np.random.default_rng(2)
    ex = Explorer(1.0, 5000, rng, durations=True, max_duration=100)
    greedy = np.zeros(5000, int)
    first = ex.act(greedy)
    # after one step a run still has duration - 1 steps left; interaction and no-op have none
    assert (ex.left[first >= HELD_ACTIONS] == 0).all()
    assert (ex.left[first < HELD_ACTIONS] > 0).mean() > 0.3   # P(n >= 2) = 1 - 1/zeta ~ 0.4
    held = first < HELD_ACTIONS
    left = ex.left.copy()
    for k in range(1, 6):
        now = ex.act(greedy)
        still = held & (left >= k)
        assert (now[still] == first[still]).all(), "a run keeps its action until it is spent"


def test_reset_cancels_a_running_action():
    ex = Explorer([1.0, 0.0], 2, np.random.default_rng(3), durations=True)
    ex.action[:] = 0
    ex.left[:] = 50
    ex.reset(1)
    out = ex.act(np.array([2, 2]))
    assert out[0] == 0 and out[1] == 2     # env 1: run cancelled, epsilon 0 -> greedy


def test_without_durations_nothing_is_held():
    ex = Explorer(1.0, 100, np.random.default_rng(4), durations=False)
    ex.act(np.zeros(100, int))
    assert (ex.left == 0).all()


def test_unstick_replaces_the_greedy_action_only_where_the_frame_did_not_change():
    greedy = np.full(6000, 2)
    stuck = np.zeros(6000, bool)
    stuck[:3000] = True
    ex = Explorer(0.0, 6000, np.random.default_rng(5), unstick=True)
    out = ex.act(greedy, stuck)
    assert (out[3000:] == 2).all(), "epsilon 0 and not stuck: greedy"
    counts = np.bincount(out[:3000], minlength=6)
    assert counts.min() > 400 and counts.max() < 620     # uniform over 6 actions: 500 each
    off = Explorer(0.0, 6000, np.random.default_rng(5), unstick=False)
    assert (off.act(greedy, stuck) == 2).all(), "without unstick the stuck mask is ignored"


def test_unstick_leaves_the_other_envs_random_stream_alone():
    greedy = np.zeros(50, int)
    stuck = np.zeros(50, bool)
    stuck[::7] = True
    plain = Explorer(0.3, 50, np.random.default_rng(6), durations=True)
    unstuck = Explorer(0.3, 50, np.random.default_rng(6), durations=True, unstick=True)
    a, b = plain.act(greedy, stuck), unstuck.act(greedy, stuck)
    fired = a != greedy                     # envs where epsilon started a random action anyway
    same = ~stuck | fired
    assert (a[same] == b[same]).all()
    assert (unstuck.left[stuck & ~fired & (b < HELD_ACTIONS)] > 0).any(), \
        "an unstick action is held like an epsilon one under ez"


# --- delivery reach (hand-placed scenes) -------------------------------------------------------

@pytest.fixture()
def room():
    env = MineRescueEnv(task="one-room")
    env.reset(seed=5)
    r = env.layout.rooms[0]
    cx, cz = (r.x0 + r.x1) / 2, (r.z0 + r.z1) / 2
    miner, kit = env.miner, env.kit
    miner.x, miner.z = cx, cz
    kit.x, kit.z = r.x0 + 1.5, r.z0 + 1.5
    env.carrying = kit                     # hold the kit
    env._entities_changed()
    yield env, cx, cz
    env.close()


def _stand(env, x, z, heading):
    env.agent_x, env.agent_z, env.heading = x, z, heading % HEADINGS


def test_held_kit_near_the_miner_delivers(room):
    env, cx, cz = room
    # 2.2 units west of the miner, looking east: the held kit is 1.42 ahead, 0.78 from the
    # miner, inside MiniWorld's near() distance (0.45 + 0.6 + 0.55 = 1.6) ...
    _stand(env, cx - 2.2, cz, 0)
    assert env.facing() is None, "... while the miner is beyond the pick-up reach"
    _, reward, terminated, _, _ = env.step(INTERACT)
    assert reward == 1.0 and terminated


def test_kit_held_off_to_the_side_or_too_far_does_not_deliver(room):
    env, cx, cz = room
    _stand(env, cx - 3.2, cz, 0)                  # held kit 1.78 from the miner: too far
    assert not env.delivers()
    _stand(env, cx - 1.2, cz, HEADINGS // 2)      # looking away from the miner
    assert not env.delivers()
    _stand(env, cx - 1.2, cz, HEADINGS // 4)      # side-on: kit held 1.42 to the south
    held = env.carry_position(env.kit)
    assert math.dist(held, (cx, cz)) > 0.45 + 0.6 + 1.1 * FORWARD_STEP
    assert not env.delivers()


def test_carrying_something_else_never_delivers(room):
    env, cx, cz = room
    env.carrying = None
    _stand(env, cx - AGENT_RADIUS - env.miner.radius - 0.2, cz, 0)
    assert env.facing() is env.miner and not env.delivers()
    _, reward, terminated, _, _ = env.step(INTERACT)
    assert reward == 0.0 and not terminated


def test_no_delivery_through_a_wall():
    env = MineRescueEnv(task="two-room")
    env.reset(seed=1)
    door = env.layout.doors[0]
    miner = env.miner
    # put the agent right behind the wall opposite the miner, holding the kit, facing it
    (dx, dz), a, b = door.center, env.layout.rooms[door.a], env.layout.rooms[door.b]
    vertical = abs(a.x1 - b.x0) < 1e-6 or abs(b.x1 - a.x0) < 1e-6
    env.carrying = env.kit
    if vertical:
        wall_x = a.x1 if abs(a.x1 - b.x0) < 1e-6 else a.x0
        side = 1 if wall_x == a.x0 else -1     # the agent's room (door.a) side
        miner.x, miner.z = wall_x - side * 0.7, dz + 4.0
        env.agent_x, env.agent_z = wall_x + side * 0.8, dz + 4.0
        env.heading = 0 if side < 0 else HEADINGS // 2
    else:
        wall_z = a.z1 if abs(a.z1 - b.z0) < 1e-6 else a.z0
        side = 1 if wall_z == a.z0 else -1
        miner.x, miner.z = dx + 4.0, wall_z - side * 0.7
        env.agent_x, env.agent_z = dx + 4.0, wall_z + side * 0.8
        env.heading = HEADINGS // 4 if side < 0 else 3 * HEADINGS // 4
    env._entities_changed()
    held = env.carry_position(env.kit)
    assert math.dist(held, (miner.x, miner.z)) < 1.6   # near, but the wall is between
    assert not env.delivers()
    env.close()


# --- the measurement ---------------------------------------------------------------------------

def test_exploration_measurement_is_reproducible_and_consistent():
    kwargs = dict(task="two-room", max_episode_steps=150)
    a = measure(kwargs, POLICIES["ez-uniform"], episodes=8, num_envs=4, seed=3)
    b = measure(kwargs, POLICIES["ez-uniform"], episodes=8, num_envs=4, seed=3)
    assert a["episodes"] == 8
    assert {k: a[k] for k in SUBGOALS} == {k: b[k] for k in SUBGOALS}
    # the doorway is blocked: no room is entered without moving its boulder first
    assert a["room entered"] <= a["boulder moved"]
    assert a["delivered"] <= a["kit picked up"]


def test_fresh_network_policy_runs():
    r = measure(dict(task="one-room", max_episode_steps=100), POLICIES["fresh ez Ape-X"],
                episodes=4, num_envs=4, seed=0)
    assert r["episodes"] == 4 and all(0.0 <= r[k] <= 1.0 for k in SUBGOALS)
    assert r["boulder moved"] == 0.0 and r["room entered"] == 0.0   # one room, no boulders


def test_bump_and_press_presses_at_obstacles_and_seldom_idles():
    """The scripted yardstick takes the doorway's boulder in most episodes (it presses action 4
    at every obstacle) and, unlike a fresh network, is seldom idle."""
    r = measure(dict(task="two-room"), POLICIES["bump-and-press"], episodes=12, num_envs=4,
                seed=0)
    assert r["episodes"] == 12
    assert r["boulder moved"] >= 0.25 and r["idle steps"] < 0.3
    assert r["room entered"] <= r["boulder moved"] and r["delivered"] <= r["kit picked up"]


def test_bump_and_press_walks_until_stuck_then_presses_and_turns_away():
    bp = BumpAndPress(2, np.random.default_rng(0))
    free, stuck = np.zeros(2, bool), np.array([True, False])
    first = bp.act(np.zeros(2, np.int64), stuck)
    assert first[0] == INTERACT                       # pressed where the view stopped changing
    turns = [bp.act(np.zeros(2, np.int64), free)[0] for _ in range(3)]
    assert len(set(turns)) == 1 and turns[0] in (2, 3)  # then one turn held, at least 3 steps
    bp.reset(0)
    assert bp.queued[0] == [] and bp.scripted and (bp.epsilon == 1).all()   # never near-greedy


def test_prefill_first_hands_over_to_the_agent_after_its_steps():
    """The scripted walker acts for exactly the actor's pre-fill steps, then the greedy agent."""
    greedy = np.array([5, 5])                          # no-op: never the walker's straight walk
    explorer = PrefillFirst(BumpAndPress(2, np.random.default_rng(0)),
                            Explorer(0.0, 2, np.random.default_rng(0)), steps=6)
    assert explorer.unstick                            # the acting core must compare frames
    taken = []
    for _ in range(5):                                 # 2 envs: 3 calls are 6 steps
        taken.append((explorer.epsilon.copy(), explorer.scripted))
        actions = explorer.act(greedy, np.zeros(2, bool))
        taken[-1] = (*taken[-1], actions)
    assert all(scripted and (eps == 1).all() for eps, scripted, _ in taken[:3])
    assert all(not scripted and (eps == 0).all() and (a == greedy).all()
               for eps, scripted, a in taken[3:])
    assert not explorer.unstick                        # no frame comparisons after the pre-fill
    assert sum((a == 0).sum() for _, _, a in taken[:3]) >= 4   # mostly straight ahead


# --- configuration -----------------------------------------------------------------------------

@pytest.mark.parametrize("argv, match", [
    (["--exploration", "levy"], "exploration"),
    (["--unstick", "-1"], "unstick"),
    (["--unstick"], "expected one argument"),
])
def test_bad_exploration_flags_are_one_line_errors(argv, match):
    from dqn_mine.config import ConfigError, parse_args

    with pytest.raises(ConfigError, match=match) as err:
        parse_args(argv)
    assert "\n" not in str(err.value)


def test_cpu_preset_is_the_full_two_room_task():
    from dqn_mine.config import parse_args

    cfg = parse_args(["--preset", "cpu"])
    assert (cfg.task, cfg.room_size, cfg.max_episode_steps) == ("two-room", 16.0, None)
    assert (cfg.exploration, cfg.epsilon_schedule, cfg.n_step) == ("ez", "apex", 6)
    assert cfg.curriculum == "backward" and cfg.eval_every > 0   # judged on the full task
    assert cfg.demos == 200 and cfg.demos_from is None
    # a folder of recorded demonstrations replaces the preset's expert episodes
    from_files = parse_args(["--preset", "cpu", "--demos-from", "demos/two-room"])
    assert (from_files.demos, from_files.demos_from) == (0, "demos/two-room")


def test_a_kit_held_from_the_start_counts_as_picked_up_only_when_taken_again():
    from dqn_mine.bench.explore import _Tracker

    env = MineRescueEnv(task="three-room", phase=6)   # starts carrying the kit
    for seed in range(10):
        _, info = env.reset(seed=seed)
        tracker = _Tracker(env, info)
        _, _, _, _, info = env.step(5)                 # no-op: still the kit it started with
        tracker.update(info)
        assert info["carrying_kit"] and not tracker.flags["kit picked up"]
        _, _, term, _, info = env.step(INTERACT)       # drop it in front (unless it delivers)
        tracker.update(info)
        if term or info["carrying"]:
            continue                                   # delivered, or no room to drop: next seed
        assert not tracker.flags["kit picked up"]
        _, _, _, _, info = env.step(INTERACT)          # and take it up again
        tracker.update(info)
        assert info["carrying_kit"] and tracker.flags["kit picked up"]
        break
    else:
        raise AssertionError("no seed let the agent drop the kit")
    env.close()


def test_a_fresh_network_acts_on_its_action_history_not_on_what_it_sees():
    """Why a fresh network gets stuck: with PyTorch's default init the conv features are ~0.02
    against one-hot history inputs of 1, so swapping the image almost never changes the greedy
    action, swapping the history often does."""
    rows = fresh_network_inputs(nets=3, episodes=2, steps=30)
    image = np.mean([r["image"] for r in rows])
    history = np.mean([r["history"] for r in rows])
    assert image < 0.05 and history > image + 0.1
    assert all(1 / 6 <= r["top action"] <= 1 for r in rows)
