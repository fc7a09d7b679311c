"""MineRescue-v0 over every task: API, determinism, layouts, spawning, physics, actions, errors.

Real EGL rendering throughout (llvmpipe on CPU machines).
"""

import math
import os
import random
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import dqn_mine  # noqa: F401  (registers the environment)
from dqn_mine.env import ENV_ID, MineRescueEnv
from dqn_mine.env.entities import BOULDER, KIT, MINER
from dqn_mine.env.mine import AGENT_RADIUS, HEADINGS
from tests.env_configs import TASK_CONFIGS, ids

IDS = ids(TASK_CONFIGS)
FORWARD, BACKWARD, RIGHT, LEFT, INTERACT, NOOP = range(6)


@pytest.fixture(scope="module")
def envs():
    made = {}
    yield made
    for env in made.values():
        env.close()


def get(envs, config):
    key = tuple(sorted(config.items()))
    if key not in envs:
        envs[key] = MineRescueEnv(**config)
    return envs[key]


def face(env, x, z, target_x, target_z):
    """Put the agent at (x, z) looking (to within one heading) at the target."""
    env.agent_x, env.agent_z = x, z
    env.heading = (round(math.atan2(target_z - z, target_x - x) / (2 * math.pi / HEADINGS))
                   % HEADINGS)


def hold(env, item):
    """Put ``item`` in the agent's hand, wherever it lay (as a start holding it would)."""
    env.carrying = item
    env._entities_changed()


def stand_before(env, entity, gap=0.3, angle=None):
    """Stand ``gap`` in front of ``entity`` on the agent's side (or at ``angle``), facing it."""
    dist = AGENT_RADIUS + entity.radius + gap
    angles = [angle] if angle is not None else [2 * math.pi * k / 16 for k in range(16)]
    for a in angles:
        x, z = entity.x - dist * math.cos(a), entity.z - dist * math.sin(a)
        if env.agent_fits(x, z) and not env.layout.crosses_wall(x, z, entity.x, entity.z):
            face(env, x, z, entity.x, entity.z)
            return
    raise AssertionError(f"no free spot in front of {entity}")


# --- API ---------------------------------------------------------------------------------------


def test_registered_without_time_limit():
    spec = gym.spec(ENV_ID)
    assert spec.max_episode_steps is None
    assert isinstance(spec.entry_point, str)
    env = gym.make(ENV_ID, task="one-room", max_episode_steps=7)
    env.reset(seed=0)
    for t in range(1, 8):
        *_, terminated, truncated, _ = env.step(NOOP)
        assert truncated == (t == 7) and not terminated
    env.close()


@pytest.mark.parametrize("config", TASK_CONFIGS, ids=IDS)
def test_gymnasium_env_checker(config):
    env = MineRescueEnv(**config)
    check_env(env, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("config", TASK_CONFIGS, ids=IDS)
def test_observation_and_info(envs, config):
    env = get(envs, config)
    obs, info = env.reset(seed=1)
    assert obs.shape == (3, 44, 76) and obs.dtype == np.uint8
    assert env.observation_space.contains(obs)
    assert env.action_space.n == 6
    assert set(info) >= {"carrying", "carrying_kit", "agent_room", "kit_room", "miner_room"}
    assert info["carrying"] is False
    assert obs.std() > 5, "the first-person view should not be a flat colour"
    for a in range(6):
        obs, reward, terminated, truncated, info = env.step(a)
        assert obs.shape == (3, 44, 76) and obs.dtype == np.uint8
        assert isinstance(info["carrying"], bool) and reward in (0.0, 1.0)


def test_start_rooms_follow_the_task(envs):
    for seed in range(10):
        _, info = get(envs, dict(task="two-room")).reset(seed=seed)
        assert (info["agent_room"], info["kit_room"], info["miner_room"]) == (0, 1, 1)
        _, info = get(envs, dict(task="three-room")).reset(seed=seed)
        assert (info["agent_room"], info["kit_room"], info["miner_room"]) == (0, 2, 0)
    seen = set()
    for seed in range(30):  # domain randomisation reaches other start rooms
        _, info = get(envs, dict(task="three-room", placement="any-room")).reset(seed=seed)
        seen.add((info["agent_room"], info["kit_room"], info["miner_room"]))
    assert len(seen) > 5


@pytest.mark.parametrize("config", TASK_CONFIGS, ids=IDS)
def test_same_seed_same_frames(envs, config):
    env = get(envs, config)
    other = MineRescueEnv(**config)  # a second env in the same process shares the GL context
    actions = random.Random(0).choices(range(6), k=60)
    for e in (env, other):
        e.reset(seed=123)
    for a in actions:
        r1, r2 = env.step(a), other.step(a)
        np.testing.assert_array_equal(r1[0], r2[0])
        assert r1[1:] == r2[1:]
    other.close()


def _fingerprint(env):
    lay = env.layout
    return (tuple(lay.rooms), tuple(lay.doors), round(env.agent_x, 6), round(env.agent_z, 6),
            env.heading, tuple((e.kind, round(e.x, 6), round(e.z, 6)) for e in env.entities))


@pytest.mark.parametrize("config", TASK_CONFIGS, ids=IDS)
def test_different_seeds_different_layouts(envs, config):
    env = get(envs, config)
    prints = set()
    for seed in range(10):
        env.reset(seed=seed)
        prints.add(_fingerprint(env))
    assert len(prints) == 10


@pytest.mark.parametrize("config", TASK_CONFIGS, ids=IDS)
def test_rooms_never_overlap_and_all_reachable(envs, config):
    env = get(envs, config)
    for seed in range(20):
        _, info = env.reset(seed=seed)
        rooms, doors = env.layout.rooms, env.layout.doors
        assert len(rooms) == info["num_rooms"] == config.get("num_rooms", len(rooms))
        for i, a in enumerate(rooms):
            assert (math.isclose(a.x1 - a.x0, env.room_size)
                    and math.isclose(a.z1 - a.z0, env.room_size))
            for b in rooms[i + 1:]:
                inter_x = min(a.x1, b.x1) - max(a.x0, b.x0)
                inter_z = min(a.z1, b.z1) - max(a.z0, b.z0)
                assert inter_x <= 1e-9 or inter_z <= 1e-9, f"seed {seed}: rooms overlap"
        for d in doors:  # each doorway sits in the wall the two rooms share, inside both sides
            for r in (rooms[d.a], rooms[d.b]):
                if d.vertical:
                    assert d.wall in (r.x0, r.x1) and r.z0 < d.lo < d.hi < r.z1
                else:
                    assert d.wall in (r.z0, r.z1) and r.x0 < d.lo < d.hi < r.x1
        reached, frontier = {0}, [0]
        while frontier:
            room = frontier.pop()
            for d in doors:
                if room in (d.a, d.b) and d.other(room) not in reached:
                    reached.add(d.other(room))
                    frontier.append(d.other(room))
        assert reached == set(range(len(rooms)))


@pytest.mark.parametrize("config", TASK_CONFIGS, ids=IDS)
def test_nothing_spawns_inside_anything(envs, config):
    env = get(envs, config)
    for seed in range(30):
        _, info = env.reset(seed=seed)
        world = env.world_entities()
        for e in world:
            assert env.layout.fits(e.x, e.z, e.radius), f"seed {seed}: {e} inside a wall"
        for i, a in enumerate(world):
            for b in world[i + 1:]:
                gap = math.hypot(a.x - b.x, a.z - b.z)
                assert gap >= a.radius + b.radius, f"seed {seed}: {a} in {b}"
        assert env.agent_fits(env.agent_x, env.agent_z), f"seed {seed}: agent inside something"
        assert env.room_of(env.kit) == info["kit_room"]
        assert env.room_of(env.miner) == info["miner_room"]
        assert env.agent_room == info["agent_room"]
        boulders = [e for e in world if e.kind == BOULDER]
        if config["task"] != "one-room":  # every doorway starts blocked by a boulder at its centre
            assert (sorted((b.x, b.z) for b in boulders)
                    == sorted(d.center for d in env.layout.doors))


# --- physics -----------------------------------------------------------------------------------


@pytest.mark.parametrize("config", TASK_CONFIGS, ids=IDS)
def test_random_walk_never_passes_walls_or_entities(envs, config):
    env = get(envs, config)
    rng = random.Random(1)
    env.reset(seed=5)
    for _ in range(600):
        x, z = env.agent_x, env.agent_z
        action = rng.choice([FORWARD] * 4 + [BACKWARD, RIGHT, LEFT])
        env.step(action)
        assert env.agent_room >= 0
        assert not env.layout.crosses_wall(x, z, env.agent_x, env.agent_z)
        assert env.agent_fits(env.agent_x, env.agent_z)
        moved = math.hypot(env.agent_x - x, env.agent_z - z)
        assert (moved == pytest.approx(0.5) if action in (FORWARD, BACKWARD) and moved
                else moved == 0)


def test_walls_stop_the_agent(envs):
    env = get(envs, dict(task="one-room"))
    env.reset(seed=0)
    room = env.layout.rooms[0]
    env.entities.clear()
    env._entities_changed()
    env.agent_x, env.agent_z, env.heading = room.x1 - 3.0, (room.z0 + room.z1) / 2, 0  # facing +x
    for _ in range(20):
        env.step(FORWARD)
    assert env.agent_x == pytest.approx(room.x1 - 3.0 + 2.5)  # 5 steps fit, the 6th would touch
    assert room.x1 - env.agent_x >= AGENT_RADIUS


def test_boulder_blocks_doorway_and_the_agent(envs):
    env = get(envs, dict(task="two-room"))
    rng = random.Random(2)
    for seed in range(3):
        env.reset(seed=seed)
        boulder = next(e for e in env.entities if e.kind == BOULDER)
        stand_before(env, boulder, gap=1.0)
        for _ in range(10):
            env.step(FORWARD)
        assert (math.hypot(env.agent_x - boulder.x, env.agent_z - boulder.z)
                >= AGENT_RADIUS + boulder.radius)
        for _ in range(1500):  # without action 4 nobody leaves room 0
            env.step(rng.choice([FORWARD] * 3 + [BACKWARD, RIGHT, LEFT, NOOP]))
            assert env.agent_room == 0


# --- actions -----------------------------------------------------------------------------------


def test_turns_are_nine_degrees_and_steps_half_a_unit(envs):
    env = get(envs, dict(task="one-room"))
    env.reset(seed=0)
    env.entities.clear()
    env._entities_changed()
    room = env.layout.rooms[0]
    env.agent_x, env.agent_z, env.heading = room.center[0], room.center[1], 0
    env.step(RIGHT)
    assert env.heading == 1
    assert env.direction == pytest.approx((math.cos(math.radians(9)), math.sin(math.radians(9))))
    env.step(LEFT)
    env.step(LEFT)
    assert env.heading == HEADINGS - 1
    env.step(RIGHT)
    x, z = env.agent_x, env.agent_z
    env.step(FORWARD)
    assert (env.agent_x - x, env.agent_z - z) == pytest.approx((0.5, 0.0))
    env.step(BACKWARD)
    assert (env.agent_x, env.agent_z) == pytest.approx((x, z))


def test_pick_up_and_drop(envs):
    env = get(envs, dict(task="one-room"))
    env.reset(seed=3)
    kit = env.kit
    stand_before(env, kit)
    before = env._last_obs.copy()
    red_before = _red_pixels(before)
    assert red_before > 0, "the kit should be in view"
    obs, reward, terminated, _, info = env.step(INTERACT)
    assert info["carrying"] and info["carrying_kit"] and reward == 0.0 and not terminated
    assert env.carrying is kit and kit not in env.world_entities()
    held = _red_mask(obs)
    h, w = held.shape
    assert held[h // 2:, w // 3: 2 * w // 3].sum() > 20 and held.sum() == held[h // 2:].sum(), \
        "a carried kit is drawn in hand: at the bottom centre of the view"
    for _ in range(3):
        obs, *_ = env.step(RIGHT)
        assert (_red_mask(obs) == held).all(), "the held kit turns with the agent"
    obs, _, _, _, info = env.step(INTERACT)
    assert not info["carrying"] and env.carrying is None
    c, s = env.direction
    ahead = AGENT_RADIUS + kit.radius + 0.1
    assert (kit.x, kit.z) == pytest.approx((env.agent_x + ahead * c, env.agent_z + ahead * s))
    # Dropped right at the agent's feet it is below the camera's view; a step back shows it
    # drawn at its new place.
    for _ in range(3):
        obs, *_ = env.step(BACKWARD)
    assert _red_pixels(obs) > 0


def test_a_held_boulder_leaves_the_kit_ahead_in_view(envs):
    """Carrying the boulder out of the doorway, the agent must still see the kit it walks to:
    the held item fills only the bottom rows, so a kit 3-8 units straight ahead shows."""
    env = get(envs, dict(task="three-room", phase=3))   # in the kit's room, both doorways cleared
    env.reset(seed=0)
    hold(env, [e for e in env.entities if e.kind == BOULDER][1])   # doorway 1-2's
    kit = env.kit
    for angle in [2 * math.pi * k / 16 for k in range(16)]:
        spots = [(kit.x - d * math.cos(angle), kit.z - d * math.sin(angle)) for d in (3, 5, 8)]
        if all(env.agent_fits(x, z) and not env.layout.crosses_wall(x, z, kit.x, kit.z)
               for x, z in spots):
            break
    else:
        pytest.fail("no clear line to the kit")
    for x, z in spots:
        face(env, x, z, kit.x, kit.z)
        env.step(NOOP)
        assert _red_pixels(env._last_obs) > 0, f"the kit {math.hypot(x - kit.x, z - kit.z):.0f} " \
            "units ahead is hidden by the held boulder"
    held = _grey_mask(env._last_obs)
    h, w = held.shape
    assert held[h - 3:, w // 3: 2 * w // 3].any(), "the boulder is still drawn in hand"


@pytest.mark.parametrize("on_top", [False, True])
def test_a_boulder_held_before_another_shows_only_when_drawn_on_top(envs, on_top):
    """Holding a boulder and facing another within reach: drawn where it is held, the carried
    boulder lies behind the faced one and the view is the one of an empty hand, pixel for pixel
    (action 4 would swap two boulders there, not clear the doorway); drawn on top it shows."""
    env = get(envs, dict(task="three-room", phase=2, camera_pitch=15.0, held_on_top=on_top))
    env.reset(seed=1)      # in room 1, doorway 0-1 cleared: its boulder in hand, 1-2's ahead
    held, other = [e for e in env.entities if e.kind == BOULDER]
    hold(env, held)
    env.place_agent_facing(1, other)
    holding, *_ = env.step(NOOP)
    for _ in range(HEADINGS // 2):
        env.step(LEFT)
    _, _, _, _, info = env.step(INTERACT)          # put down behind, out of view
    assert not info["carrying"]
    for _ in range(HEADINGS // 2):
        env.step(RIGHT)
    empty, *_ = env.step(NOOP)
    assert env.facing() is other
    differ = (holding != empty).any(axis=0)
    h, w = differ.shape
    if on_top:
        assert differ[h - 8:, w // 3: 2 * w // 3].sum() >= 30, "the held boulder is not drawn"
        assert not differ[: h - 8].any(), "only the bottom rows show the held item"
    else:
        assert not differ.any()


def test_a_pitched_camera_shows_an_item_in_reach(envs):
    """Level (MiniWorld's camera) a kit within action 4's reach lies below the view; pitched 15
    degrees down it shows at every reachable distance, and the world is unchanged."""
    level = get(envs, dict(task="one-room"))
    pitched = get(envs, dict(task="one-room", camera_pitch=15.0))
    for gap in (0.0, 0.3, 0.6):           # kit centre 0.85-1.45 ahead: all within reach
        seen = []
        for env in (level, pitched):
            env.reset(seed=3)
            stand_before(env, env.kit, gap=gap)
            obs, _, _, _, info = env.step(NOOP)
            seen.append((_red_pixels(obs), info, (env.agent_x, env.agent_z, env.heading)))
        (red_level, info_level, pose_level), (red_pitched, info_pitched, pose_pitched) = seen
        assert red_level == 0 and red_pitched >= 25, (gap, red_level, red_pitched)
        assert info_level == info_pitched and pose_level == pose_pitched
    _, _, _, _, info = pitched.step(INTERACT)
    assert info["carrying_kit"]
    held = _red_mask(pitched._last_obs)
    h, w = held.shape
    rows = np.nonzero(held.any(axis=1))[0]
    assert rows.min() >= h - 10 and held[:, w // 3: 2 * w // 3].sum() > 20, \
        "the held kit stays in the bottom rows under a pitched camera"


def test_drop_needs_room(envs):
    env = get(envs, dict(task="one-room"))
    env.reset(seed=4)
    stand_before(env, env.kit)
    env.step(INTERACT)
    room = env.layout.rooms[0]
    # nose to a wall
    env.agent_x, env.agent_z, env.heading = room.x1 - AGENT_RADIUS - 0.05, room.center[1], 0
    if not env.agent_fits(env.agent_x, env.agent_z):
        env.agent_z = room.z0 + 1.0
    _, _, _, _, info = env.step(INTERACT)
    assert info["carrying"], "no room in front: the kit stays in hand"


def test_miner_cannot_be_picked_up(envs):
    env = get(envs, dict(task="one-room"))
    env.reset(seed=5)
    stand_before(env, env.miner)
    assert env.facing() is env.miner
    _, reward, terminated, _, info = env.step(INTERACT)
    assert not info["carrying"] and reward == 0.0 and not terminated


def test_exchange_swaps_held_and_faced_items(envs):
    env = get(envs, dict(task="two-room"))
    env.reset(seed=6)
    kit = env.kit
    boulder = next(e for e in env.entities if e.kind == BOULDER)
    stand_before(env, kit)
    env.step(INTERACT)
    assert env.carrying is kit
    bx, bz = boulder.x, boulder.z
    stand_before(env, boulder)
    _, _, _, _, info = env.step(INTERACT)
    assert env.carrying is boulder and info["carrying"] and not info["carrying_kit"]
    assert (kit.x, kit.z) == (bx, bz)
    h, w = env._last_obs.shape[1:]
    hand = env._last_obs[:, -h // 4:, w // 2 - 4: w // 2 + 4].reshape(3, -1).mean(axis=1)
    assert hand.min() > 60 and hand.max() - hand.min() < 25, \
        f"the agent sees it now holds a grey boulder, not the red kit: {hand}"
    assert kit in env.world_entities() and boulder not in env.world_entities()


def test_exchange_from_where_the_agent_stops_at_the_kit(envs):
    """Carrying the boulder, the agent walks into the kit and takes it: the boulder goes down
    beyond the kit's place (it would overlap the agent at it), clear of the agent."""
    env = get(envs, dict(task="two-room"))
    env.reset(seed=6)
    kit = env.kit
    boulder = next(e for e in env.entities if e.kind == BOULDER)
    room = env.layout.rooms[env.room_of(kit)]
    kit.x, kit.z = room.center             # in the open, where there is room for the boulder
    assert env.item_fits(kit, kit.x, kit.z)
    env.carrying = boulder
    env._entities_changed()
    stand_before(env, kit, gap=0.3)
    kx, kz = kit.x, kit.z
    for _ in range(3):                     # walk into the kit: blocked where the bodies touch
        env.step(FORWARD)
    assert math.hypot(kx - env.agent_x, kz - env.agent_z) < AGENT_RADIUS + boulder.radius
    _, _, _, _, info = env.step(INTERACT)
    assert env.carrying is kit and info["carrying_kit"]
    gap = math.hypot(boulder.x - env.agent_x, boulder.z - env.agent_z)
    assert gap >= AGENT_RADIUS + boulder.radius, "the boulder is put down clear of the agent"
    # on the line from the agent through the kit's old place, no further than needed
    ux, uz = (kx - env.agent_x), (kz - env.agent_z)
    cross = ux * (boulder.z - env.agent_z) - uz * (boulder.x - env.agent_x)
    assert abs(cross) < 1e-6 and gap == pytest.approx(AGENT_RADIUS + boulder.radius + 0.1)
    assert env.item_fits(boulder, boulder.x, boulder.z)


def test_exchange_refused_when_the_held_item_has_no_room(envs):
    env = get(envs, dict(task="two-room"))
    env.reset(seed=6)
    kit = env.kit
    boulder = next(e for e in env.entities if e.kind == BOULDER)
    room = env.layout.rooms[env.room_of(kit)]
    # the kit against a wall, the agent facing it from the room: no room there for the boulder
    kit.x, kit.z = room.x1 - kit.radius - 0.05, (room.z0 + room.z1) / 2
    env.carrying = boulder
    env._entities_changed()
    stand_before(env, kit, gap=0.05, angle=0.0)
    _, _, _, _, info = env.step(INTERACT)
    assert env.carrying is boulder and not info["carrying_kit"]
    assert (kit.x, kit.z) == (room.x1 - kit.radius - 0.05, (room.z0 + room.z1) / 2)


def test_clearing_the_doorway_opens_it(envs):
    env = get(envs, dict(task="two-room"))
    env.reset(seed=7)
    boulder = next(e for e in env.entities if e.kind == BOULDER)
    door = env.layout.doors[0]
    nx, nz = door.normal_from(0)
    stand_before(env, boulder, angle=math.atan2(nz, nx))
    env.step(INTERACT)
    assert env.carrying is boulder
    for _ in range(8):
        env.step(FORWARD)
    assert env.agent_room == 1, "with the boulder in hand the agent walks through the doorway"


def test_reward_only_on_delivery(envs):
    env = get(envs, dict(task="one-room"))
    env.reset(seed=8)
    rng = random.Random(0)
    for _ in range(300):  # random play without the kit never earns anything
        _, reward, terminated, _, _ = env.step(rng.choice([FORWARD, BACKWARD, RIGHT, LEFT, NOOP]))
        assert reward == 0.0 and not terminated
    env.reset(seed=8)
    stand_before(env, env.kit)
    env.step(INTERACT)
    stand_before(env, env.miner)
    assert env.facing() is env.miner
    obs, reward, terminated, truncated, info = env.step(INTERACT)
    assert reward == 1.0 and terminated and not truncated and obs.shape == (3, 44, 76)


def test_boulder_is_not_a_delivery(envs):
    env = get(envs, dict(task="two-room"))
    env.reset(seed=9)
    boulder = next(e for e in env.entities if e.kind == BOULDER)
    stand_before(env, boulder)
    env.step(INTERACT)
    env.entities.remove(boulder)  # hold it while facing the miner, wherever it is
    env.entities.append(boulder)
    stand_before(env, env.miner)
    _, reward, terminated, _, info = env.step(INTERACT)
    assert reward == 0.0 and not terminated and info["carrying"]


def test_truncation_at_the_step_limit():
    env = MineRescueEnv(task="two-room", max_episode_steps=25)
    env.reset(seed=0)
    for t in range(1, 26):
        _, _, terminated, truncated, _ = env.step(NOOP)
        assert not terminated and truncated == (t == 25)
    env.close()
    assert MineRescueEnv(task="one-room").max_episode_steps == 1000
    assert MineRescueEnv(task="two-room").max_episode_steps == 1000
    assert MineRescueEnv(task="three-room").max_episode_steps == 2000
    assert MineRescueEnv(task="rooms").max_episode_steps == 2000


# --- bad input ---------------------------------------------------------------------------------


@pytest.mark.parametrize("kwargs, match", [
    (dict(task="four-room"), "unknown task"),
    (dict(task="two-room", num_rooms=3), "exactly 2"),
    (dict(task="one-room", num_rooms=2), "exactly 1"),
    (dict(task="rooms", num_rooms=1), "num_rooms"),
    (dict(task="rooms", num_rooms=2.5), "num_rooms"),
    (dict(task="rooms", num_rooms=100), "num_rooms"),
    (dict(room_size=0), "positive"),
    (dict(room_size=-4.0), "positive"),
    (dict(room_size=float("inf")), "finite"),
    (dict(room_size=3.0), "at least"),
    (dict(max_episode_steps=0), "positive integer"),
    (dict(max_episode_steps=-5), "positive integer"),
    (dict(max_episode_steps=10.5), "positive integer"),
    (dict(placement="anywhere"), "placement"),
    (dict(task="three-room", phase=0), "phase"),
    (dict(task="three-room", phase=7), "phase"),
    (dict(task="one-room", phase=2), "three-room"),
    (dict(task="two-room", phase=2), "three-room"),
    (dict(task="three-room", phase=2, placement="any-room"), "fixed"),
    (dict(render_mode="human"), "render_mode"),
    (dict(camera_pitch=-5.0), "camera_pitch"),
    (dict(camera_pitch=45.0), "camera_pitch"),
    (dict(camera_pitch=float("nan")), "camera_pitch"),
])
def test_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MineRescueEnv(**kwargs)


@pytest.mark.parametrize("action", [6, -1, 2.5, "1", None, np.int64(9)])
def test_bad_actions(envs, action):
    env = get(envs, dict(task="one-room"))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(action)


def test_numpy_actions_accepted(envs):
    env = get(envs, dict(task="one-room"))
    env.reset(seed=0)
    for a in (np.int64(2), np.array(3), np.int32(5)):
        env.step(a)


def test_missing_egl_is_one_clear_line(tmp_path):
    # libglvnd looks for EGL vendors only where this says; pointing it at nothing removes EGL.
    env = dict(os.environ, __EGL_VENDOR_LIBRARY_FILENAMES=str(tmp_path / "none.json"),
               __EGL_VENDOR_LIBRARY_DIRS=str(tmp_path))
    code = "from dqn_mine.env import MineRescueEnv; MineRescueEnv(task='one-room').reset(seed=0)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode != 0
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith("RuntimeError: cannot initialise headless EGL") and "Mesa" in last


def test_env_does_not_import_torch():
    code = ("import sys, dqn_mine.env.tasks as t; e = t.MineRescueEnv(task='rooms'); "
            "e.reset(seed=0); "
            "e.step(0); e.expert_action(); e.render_top_down(64); print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "False", out.stderr


# --- rendering for people ----------------------------------------------------------------------


def _red_mask(obs):
    r, g, b = (obs[i].astype(int) for i in range(3))
    return (r > 120) & (g < 60) & (b < 60)


def _grey_mask(obs):
    r, g, b = (obs[i].astype(int) for i in range(3))
    return (abs(r - g) < 12) & (abs(g - b) < 12) & (r > 90)


def _red_pixels(obs):
    return int(_red_mask(obs).sum())


def test_render_and_map():
    env = MineRescueEnv(task="two-room", render_mode="rgb_array")
    obs, _ = env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert frame.shape[0] == 44 * 6 and frame.shape[1] > 76 * 6 + frame.shape[0]
    np.testing.assert_array_equal(frame[:264:6, :456:6], obs.transpose(1, 2, 0))
    top = env.render_top_down(size=128)
    assert top.shape == (128, 128, 3) and top.dtype == np.uint8
    colours = {tuple(c) for c in env.render_top_down(size=256).reshape(-1, 3)}
    from dqn_mine.env.entities import KINDS
    for kind in (KIT, BOULDER, MINER):
        assert KINDS[kind].map_colour in colours, f"{kind} missing from the map"
    assert MineRescueEnv(task="one-room").render() is None
    env.close()


def test_entities_are_visible_in_first_person(envs):
    env = get(envs, dict(task="two-room"))
    env.reset(seed=1)
    stand_before(env, env.kit, gap=2.0)
    assert _red_pixels(env.step(NOOP)[0]) > 10
    stand_before(env, env.miner, gap=2.0)
    r, g, b = (env.step(NOOP)[0][i].astype(int) for i in range(3))
    assert ((r > 150) & (g > 60) & (b < 40)).sum() > 10, "orange vest / yellow helmet in view"


def test_visual_randomisation_changes_look_not_layout():
    """Same seed: the same mine and entities, but a different light, tint and field of view per
    episode; the same seed with randomisation still reproduces its frames."""
    plain = MineRescueEnv(task="two-room")
    varied = MineRescueEnv(task="two-room", randomise_visuals=True)
    again = MineRescueEnv(task="two-room", randomise_visuals=True)
    try:
        looks = []
        for seed in range(4):
            obs_p, info_p = plain.reset(seed=seed)
            obs_v, info_v = varied.reset(seed=seed)
            assert info_p == info_v
            assert plain.layout.rooms == varied.layout.rooms
            assert [(e.kind, e.x, e.z) for e in plain.entities] == \
                [(e.kind, e.x, e.z) for e in varied.entities]
            assert not np.array_equal(obs_p, obs_v)
            np.testing.assert_array_equal(again.reset(seed=seed)[0], obs_v)
            looks.append((varied.light, *varied.tint, varied.fov_y))
        assert plain.light == 1.0 and plain.fov_y == 60.0
        assert len(set(looks)) == 4                              # drawn anew each episode
        for light, r, g, b, fov in looks:
            assert 0.6 <= light <= 1.3 and 50.0 <= fov <= 70.0
            assert all(0.85 <= c <= 1.15 for c in (r, g, b))
    finally:
        for env in (plain, varied, again):
            env.close()


def test_dimmer_light_gives_darker_frames():
    env = MineRescueEnv(task="one-room", randomise_visuals=True)
    try:
        means = {}
        for seed in range(12):
            obs, _ = env.reset(seed=seed)
            means[env.light] = obs.mean()
        dim, bright = min(means), max(means)
        assert bright - dim > 0.2
        assert means[dim] < means[bright]
    finally:
        env.close()


def _floor_colours(env: MineRescueEnv, seed: int) -> list[np.ndarray]:
    """Median colour of the bottom rows of the view from each room's centre."""
    env.reset(seed=seed)
    colours = []
    for room in env.layout.rooms:
        env.agent_x, env.agent_z = (room.x0 + room.x1) / 2, (room.z0 + room.z1) / 2
        for heading in (0, HEADINGS // 4, HEADINGS // 2, 3 * HEADINGS // 4):
            env.heading = heading
            bottom = env.step(NOOP)[0][:, -4:, :].reshape(3, -1)
            colours.append(np.median(bottom, axis=1))
    return colours


def test_room_colours_tell_the_rooms_apart_and_change_nothing_else():
    plain = MineRescueEnv(task="three-room")
    coloured = MineRescueEnv(task="three-room", room_colours=True)
    try:
        for seed in range(3):
            assert plain.reset(seed=seed)[1] == coloured.reset(seed=seed)[1]
            assert [(e.kind, e.x, e.z) for e in plain.entities] == \
                [(e.kind, e.x, e.z) for e in coloured.entities]
            # four views from each room's centre: rooms differ, views within a room agree
            for env, apart in ((coloured, True), (plain, False)):
                views = np.array(_floor_colours(env, seed)).reshape(3, 4, 3)
                within = np.abs(views - views[:, :1]).sum(-1).max()
                between = min(np.abs(views[a, 0] - views[b, 0]).sum()
                              for a, b in ((0, 1), (0, 2), (1, 2)))
                assert within <= 20, views                   # texture and light
                assert (between > 45) if apart else (between <= 5), views
    finally:
        plain.close()
        coloured.close()
