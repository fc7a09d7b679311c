"""The mine world: layout, entities, collision, the six actions and rendering.

``MineEnv`` owns everything that is the same for every task (physics, actions, rendering, the
builders that place rooms, entities and the agent). A task only decides where things start; see
``dqn_mine/env/tasks.py`` and ``MineRescueEnv``.
"""

from __future__ import annotations

import math
import numbers
import random

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from dqn_mine.env import mesh
from dqn_mine.env.entities import BOULDER, KIT, MINER, Entity, local_mesh
from dqn_mine.env.interface import (
    BACKWARD,
    FORWARD,
    FRAME_SHAPE,
    INTERACT,
    NUM_ACTIONS,
    OBS_HEIGHT,
    OBS_WIDTH,
    TURN_LEFT,
    TURN_RIGHT,
)
from dqn_mine.env.layout import Door, Layout, generate_layout

AGENT_RADIUS = 0.4
FORWARD_STEP = 0.5
HEADINGS = 40                      # 360 / 9 degrees: headings are exact table entries
EYE_HEIGHT = 1.5
FOV_Y = 60.0
WALL_HEIGHT = 3.0
DOOR_HEIGHT = 2.3
DOOR_WIDTH = 2.4
REACH_AHEAD = AGENT_RADIUS + 0.5   # centre of the disc in which action 4 finds an item ...
REACH_RADIUS = 0.6                 # ... and its radius
# Delivery, after MiniWorld's mechanics: a carried item is held in front of the agent, at
# 1.05 x (agent radius + item radius + one forward step) from its centre, and MiniWorld's
# ``near()`` counts two entities as touching within their radii plus 1.1 forward steps. Action 4
# hands the kit over when the held kit is near the miner in that sense (and no wall lies
# between). This reaches further than "the miner in the pick-up reach" (the held kit is 1.42
# ahead, so the miner may be up to 3.0 away), but it changes undirected exploration little:
# one-room, 300 episodes, uniform random 0.3% -> 0.7% delivered, ez-uniform 0.7% both ways
# (docs/exploration.md).
CARRY_AHEAD_FACTOR = 1.05
NEAR_STEPS = 1.1
# The carried item is drawn where it is held, sunk so that its top lies this many degrees below
# the line of sight: it fills only the bottom rows of the view, centred, so the agent sees *what*
# it carries (the carrying flag alone cannot tell the kit from a boulder). Drawn higher (its top
# 0.3 below the eye, as MiniWorld lifts a carried entity), a held boulder covered the lower
# middle of the view, where the floor 2.6-8 units ahead shows, and hid a kit straight ahead at
# every distance the agent walks towards it from: an agent carrying the boulder out of the
# doorway could find the kit only from the side. At 25 degrees a kit on the floor ahead is
# hidden only within about 3 units, where it leaves the view anyway (the floor's nearest
# visible point is 2.6 units ahead).
HELD_TOP_ANGLE = 25.0
# The carried item is held 1.4-1.9 units ahead and passes through what it meets (only the agent
# collides), so anything nearer (a wall, the boulder of a doorway in reach) hides it: holding a
# boulder and facing another within reach, the view is the same pixel for pixel as empty-handed,
# and only the one-value carrying flag tells the state where action 4 swaps two boulders (the
# doorway stays blocked) from the one where it clears the doorway. MiniWorld avoids this by
# making the carried entity collide. ``held_on_top`` draws the item over the world instead.
DROP_GAP = 0.1                     # space between the agent and an item it puts down
DOOR_CLEARANCE = 2.5               # kit, miner and agent start at least this far from doorways
ASIDE_CLEARANCE = 3.5              # boulders moved aside lie at least this far from doorways
MIN_ROOM_SIZE = 8.0
# Visual randomisation (optional): drawn per episode, after the layout, so a seed gives the same
# mine with or without it. Entities keep their hue (only the light level touches them), so the
# kit stays red and the miner stays yellow.
LIGHT_RANGE = (0.6, 1.3)           # overall light level
TINT_RANGE = (0.85, 1.15)          # per-channel colour of walls, floor and ceiling
FOV_RANGE = (50.0, 70.0)           # vertical field of view, degrees
# An optional camera pitched down (degrees). Level (0, MiniWorld's camera) the floor in view
# begins 2.6 units ahead, beyond action 4's reach: the agent must press on a kit it saw a step or
# two before. At 15 degrees the view's bottom edge meets the floor 1.5 units ahead and part of a
# kit anywhere in reach stays in view; the top edge still shows a wall's full height from 5.6
# units away.
MAX_CAMERA_PITCH = 30.0
# Named looks (MineEnv keyword arguments): the study's, and one where the agent sees what it
# reaches (the pitch above), tells rooms apart (floor colours) and sees what it carries.
VIEWS = {"study": {},
         "clear": {"camera_pitch": 15.0, "room_colours": True, "held_on_top": True}}

_COS = [math.cos(2 * math.pi * k / HEADINGS) for k in range(HEADINGS)]
_SIN = [math.sin(2 * math.pi * k / HEADINGS) for k in range(HEADINGS)]


class MineEnv(gym.Env):
    """Base class of the mine tasks; subclasses implement ``_generate()``.

    Headings are indices into 40 directions 9 degrees apart; heading k looks along
    (cos, sin)(2 pi k / 40) in the x-z plane, and turning right increases k.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 15}

    def __init__(self, max_episode_steps: int, room_size: float = 16.0,
                 render_mode: str | None = None, randomise_visuals: bool = False,
                 room_colours: bool = False, camera_pitch: float = 0.0,
                 held_on_top: bool = False):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if (not isinstance(camera_pitch, numbers.Real) or isinstance(camera_pitch, bool)
                or not 0.0 <= camera_pitch <= MAX_CAMERA_PITCH):
            raise ValueError(f"camera_pitch must be in [0, {MAX_CAMERA_PITCH:g}] degrees, "
                             f"got {camera_pitch!r}")
        self.render_mode = render_mode
        self.room_size = float(room_size)
        self.max_episode_steps = int(max_episode_steps)
        self.randomise_visuals = bool(randomise_visuals)
        self.room_colours = bool(room_colours)
        self.camera_pitch = float(camera_pitch)
        self.held_on_top = bool(held_on_top)
        self.light, self.tint, self.fov_y = 1.0, np.ones(3, np.float32), FOV_Y
        self.observation_space = spaces.Box(0, 255, FRAME_SHAPE, np.uint8)
        self.action_space = spaces.Discrete(NUM_ACTIONS)
        self.layout: Layout | None = None
        self.entities: list[Entity] = []   # everything in the world, the carried item included
        self.carrying: Entity | None = None
        self.agent_x = self.agent_z = 0.0
        self.heading = 0
        self.steps = 0
        self._rng = random.Random(0)
        self._scene = None
        self._obstacles: list[tuple[float, float, float]] = []
        self._walk: list[tuple[float, float, float, float]] = []
        self._expert = None
        self._last_obs = None
        self.entity_moves = 0  # bumped whenever an entity moves (the expert caches plans by it)

    # --- gymnasium API --------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        # Python's Random draws scalars ~10x faster than numpy's Generator; seed it from np_random
        # so that gymnasium's seeding rules (seed once, then continue the stream) still hold.
        self._rng.seed(int(self.np_random.integers(2 ** 63)))
        self.entities = []
        self.carrying = None
        self.steps = 0
        self._expert = None
        self._generate()
        self._draw_visuals()
        self._walk = self.layout.rects(AGENT_RADIUS)
        self._entities_changed(static=True)
        return self._observe(), self._info()

    def _info(self) -> dict:
        """What ``reset`` reports about the start."""
        return {"carrying": self.carrying is not None, "carrying_kit": self._carrying_kit(),
                "agent_room": self.agent_room, "kit_room": self.room_of(self.kit),
                "miner_room": self.room_of(self.miner), "num_rooms": len(self.layout.rooms)}

    def step(self, action):
        if action.__class__ is not int:
            action = _as_action(action)
        elif not 0 <= action < NUM_ACTIONS:
            raise ValueError(f"action must be an integer in 0..5, got {action}")
        terminated = self.advance(action)
        self.steps += 1
        truncated = not terminated and self.steps >= self.max_episode_steps
        carrying = self.carrying
        info = {"carrying": carrying is not None,
                "carrying_kit": carrying is not None and carrying.kind == KIT}
        return self._observe(), (1.0 if terminated else 0.0), terminated, truncated, info

    def advance(self, action: int) -> bool:
        """Apply a valid ``action`` to the world without rendering or counting a step; True on
        delivery. ``step`` is this plus the frame; the expert plans and replays with it alone."""
        if action == FORWARD:
            self._move(FORWARD_STEP)
        elif action == BACKWARD:
            self._move(-FORWARD_STEP)
        elif action == TURN_RIGHT:
            self.heading = (self.heading + 1) % HEADINGS
        elif action == TURN_LEFT:
            self.heading = (self.heading - 1) % HEADINGS
        elif action == INTERACT:
            return self._interact()
        return False

    def fast_forward(self, actions) -> tuple[np.ndarray, dict]:
        """Play ``actions`` from the current state unrendered (none may deliver), then start the
        episode's step count afresh there: the observation and info of that state, as
        ``reset`` returns them. A start on the expert's path costs a reset and a replay, not
        the plan (see ``dqn_mine.env.expert.solve``)."""
        for action in actions:
            if self.advance(int(action)):
                raise ValueError("fast_forward: the actions deliver; a start must precede it")
        self.steps = 0
        self._expert = None
        return self._observe(), self._info()

    def render(self):
        """First-person view (upscaled 6x) and the top-down map side by side, uint8 (H, W, 3)."""
        if self.render_mode != "rgb_array":
            return None
        first = self._last_obs.transpose(1, 2, 0).repeat(6, 0).repeat(6, 1)
        side = first.shape[0]
        top = self.render_top_down(side)
        gap = np.full((side, 4, 3), 255, np.uint8)
        return np.concatenate([first, gap, top], axis=1)

    def render_top_down(self, size: int = 256) -> np.ndarray:
        """A map of the whole mine for people (never for the agent): uint8 (size, size, 3)."""
        from dqn_mine.env.topdown import draw_map

        return draw_map(self, size)

    def close(self):
        if self._scene is not None:
            self._scene.release()
            self._scene = None

    def expert_action(self) -> int:
        """The next action of a scripted planner that uses privileged state (see expert.py)."""
        if self._expert is None:
            from dqn_mine.env.expert import Expert

            self._expert = Expert(self)
        return self._expert.act()

    # --- state the expert, the map and tests read ------------------------------------------

    @property
    def direction(self) -> tuple[float, float]:
        return _COS[self.heading], _SIN[self.heading]

    @property
    def kit(self) -> Entity:
        return next(e for e in self.entities if e.kind == KIT)

    @property
    def miner(self) -> Entity:
        return next(e for e in self.entities if e.kind == MINER)

    @property
    def agent_room(self) -> int:
        return self.layout.room_at(self.agent_x, self.agent_z)

    def room_of(self, entity: Entity) -> int:
        if entity is self.carrying:
            return self.agent_room
        return self.layout.room_at(entity.x, entity.z)

    def world_entities(self) -> list[Entity]:
        """Entities lying in the world (everything but the carried item)."""
        return [e for e in self.entities if e is not self.carrying]

    def agent_fits(self, x: float, z: float) -> bool:
        """True when the agent could stand at (x, z) without touching a wall or an entity."""
        for x0, z0, x1, z1 in self._walk:
            if x0 <= x <= x1 and z0 <= z <= z1:
                break
        else:
            return False
        for ex, ez, rr in self._obstacles:
            dx, dz = x - ex, z - ez
            if dx * dx + dz * dz < rr:
                return False
        return True

    def item_fits(self, item: Entity, x: float, z: float, ignore: Entity | None = None) -> bool:
        """True when ``item`` could lie at (x, z): no wall, no other entity, not on the agent."""
        r = item.radius
        if not self.layout.fits(x, z, r):
            return False
        if (x - self.agent_x) ** 2 + (z - self.agent_z) ** 2 < (r + AGENT_RADIUS) ** 2:
            return False
        for e in self.entities:
            if e is not item and e is not ignore and e is not self.carrying:
                if (x - e.x) ** 2 + (z - e.z) ** 2 < (r + e.radius) ** 2:
                    return False
        return True

    def can_put_down(self, item: Entity, x: float, z: float,
                     ignore: Entity | None = None) -> bool:
        """True when the agent could put ``item`` down at (x, z): it fits there and no wall lies
        between the agent and the spot (drop, exchange, and the expert's choice of a spot)."""
        return (self.item_fits(item, x, z, ignore=ignore)
                and not self.layout.crosses_wall(self.agent_x, self.agent_z, x, z))

    def facing(self) -> Entity | None:
        """The entity action 4 acts on: the nearest one in reach in front, not behind a wall."""
        c, s = _COS[self.heading], _SIN[self.heading]
        cx, cz = self.agent_x + REACH_AHEAD * c, self.agent_z + REACH_AHEAD * s
        best, best_d = None, math.inf
        for e in self.entities:
            if e is self.carrying:
                continue
            d = (e.x - cx) ** 2 + (e.z - cz) ** 2
            if d < (e.radius + REACH_RADIUS) ** 2 and d < best_d:
                if not self.layout.crosses_wall(self.agent_x, self.agent_z, e.x, e.z):
                    best, best_d = e, d
        return best

    def carry_position(self, item: Entity) -> tuple[float, float]:
        """Where a carried ``item`` is held: in front of the agent (MiniWorld's carry position)."""
        ahead = _carry_ahead(item)
        return (self.agent_x + ahead * _COS[self.heading],
                self.agent_z + ahead * _SIN[self.heading])

    def delivers(self) -> bool:
        """Whether action 4 now hands the kit to the miner: the held kit is near the miner."""
        held = self.carrying
        if held is None or held.kind != KIT:
            return False
        miner = self.miner
        x, z = self.carry_position(held)
        touch = held.radius + miner.radius + NEAR_STEPS * FORWARD_STEP
        return ((x - miner.x) ** 2 + (z - miner.z) ** 2 < touch * touch
                and not self.layout.crosses_wall(self.agent_x, self.agent_z, miner.x, miner.z))

    # --- actions -----------------------------------------------------------------------------

    def _move(self, dist: float) -> None:
        x = self.agent_x + dist * _COS[self.heading]
        z = self.agent_z + dist * _SIN[self.heading]
        if self.agent_fits(x, z):
            self.agent_x, self.agent_z = x, z

    def _interact(self) -> bool:
        """Deliver, pick up, exchange or drop; True on delivery."""
        if self.delivers():
            return True
        target = self.facing()
        held = self.carrying
        if target is not None and target.movable:
            if held is not None:  # exchange: the held item takes the target's place
                spot = self._exchange_spot(held, target)
                if spot is None:
                    return False
                held.x, held.z, held.yaw = spot[0], spot[1], target.yaw
            self.carrying = target
        elif held is not None:
            c, s = _COS[self.heading], _SIN[self.heading]
            ahead = AGENT_RADIUS + held.radius + DROP_GAP
            x, z = self.agent_x + ahead * c, self.agent_z + ahead * s
            if not self.can_put_down(held, x, z):
                return False
            held.x, held.z, held.yaw = x, z, 2 * math.pi * self.heading / HEADINGS
            self.carrying = None
        else:
            return False
        self._entities_changed()
        return False

    def _exchange_spot(self, held: Entity, target: Entity) -> tuple[float, float] | None:
        """Where an exchange puts the held item down: where ``target`` lay, or, when a larger
        held item would overlap the agent there, just beyond it on the line from the agent.

        Without the push-out a held boulder (radius 0.9) could replace a kit only from 1.3-1.95
        units away, never from where the agent stops when it walks into the kit: an agent that
        carried the boulder through the doorway could then never take the kit.
        """
        dx, dz = target.x - self.agent_x, target.z - self.agent_z
        dist = math.hypot(dx, dz)
        clear = AGENT_RADIUS + held.radius + DROP_GAP
        x, z = target.x, target.z
        if dist < clear:
            x, z = self.agent_x + dx * clear / dist, self.agent_z + dz * clear / dist
        return (x, z) if self.can_put_down(held, x, z, ignore=target) else None

    def _carrying_kit(self) -> bool:
        return self.carrying is not None and self.carrying.kind == KIT

    # --- rendering ----------------------------------------------------------------------------

    def _draw_visuals(self) -> None:
        """This episode's light, wall tint and field of view (the defaults unless randomised)."""
        if not self.randomise_visuals:
            self.light, self.tint, self.fov_y = 1.0, np.ones(3, np.float32), FOV_Y
            return
        u = self._rng.uniform
        self.light = u(*LIGHT_RANGE)
        self.tint = np.array([u(*TINT_RANGE) for _ in range(3)], np.float32)
        self.fov_y = u(*FOV_RANGE)

    def _entities_changed(self, static: bool = False) -> None:
        """Refresh collision discs and the entity geometry after something moved."""
        self.entity_moves += 1
        world = self.world_entities()
        self._obstacles = [(e.x, e.z, (AGENT_RADIUS + e.radius) ** 2) for e in world]
        if self._scene is None:
            from dqn_mine.env.render import Scene

            far = 2.0 * self.room_size * (len(self.layout.rooms) + 1)
            self._scene = Scene(OBS_WIDTH, OBS_HEIGHT, FOV_Y, EYE_HEIGHT, far, self.camera_pitch,
                                self.held_on_top)
        dynamic = (np.concatenate([e.vertices() for e in world]) if world
                   else np.zeros((0, mesh.VERTEX_FLOATS), np.float32))
        held = self._held_mesh()
        if self.randomise_visuals:
            dynamic[:, 3:6] *= self.light   # concatenate and place made copies: the cached
            held[:, 3:6] *= self.light      # meshes stay
        if static:
            static_mesh = mesh.static_scene(self.layout, WALL_HEIGHT, DOOR_HEIGHT,
                                            self.room_colours)
            if self.randomise_visuals:
                static_mesh[:, 3:6] *= self.light * self.tint
            self._scene.set_fov(self.fov_y)
            self._scene.set_static(static_mesh, dynamic, held)
        else:
            self._scene.set_dynamic(dynamic, held)

    def _held_mesh(self) -> np.ndarray:
        """The carried item in the camera's frame (eye at the origin, looking along +x)."""
        item = self.carrying
        if item is None:
            return np.zeros((0, mesh.VERTEX_FLOATS), np.float32)
        local, ahead = local_mesh(item.kind), _carry_ahead(item)
        out = mesh.place(local, ahead, 0.0, 1.0, 0.0)
        # The same rows of the image under a pitched camera.
        below_eye = ahead * math.tan(math.radians(HELD_TOP_ANGLE + self.camera_pitch))
        out[:, 1] += EYE_HEIGHT - below_eye - local[:, 1].max()
        return out

    def _observe(self) -> np.ndarray:
        obs = self._scene.render(self.agent_x, self.agent_z, _COS[self.heading], _SIN[self.heading])
        self._last_obs = obs
        return obs

    # --- builders for tasks (dqn_mine/env/tasks.py composes its starts from these) -------------

    def _generate(self) -> None:
        raise NotImplementedError

    def build_layout(self, num_rooms: int, chain: bool) -> None:
        self.layout = generate_layout(self._rng, num_rooms, self.room_size, DOOR_WIDTH, chain)

    def block_doorways(self) -> list[Entity]:
        """A boulder in the middle of every doorway."""
        boulders = []
        for door in self.layout.doors:
            x, z = door.center
            boulders.append(self.add(Entity(BOULDER, x, z, self._rng.uniform(0, 2 * math.pi))))
        return boulders

    def move_aside(self, boulder: Entity, door: Door) -> None:
        """Put a doorway's boulder somewhere in one of the two rooms it joins, clear of doorways."""
        room = self._rng.choice((door.a, door.b))
        boulder.x, boulder.z = self._random_spot(boulder.radius, room, ASIDE_CLEARANCE, boulder)

    def place(self, kind: str, room: int) -> Entity:
        """A new entity at a random free spot in ``room`` (place entities before the agent)."""
        ent = Entity(kind, yaw=self._rng.uniform(0, 2 * math.pi))
        ent.x, ent.z = self._random_spot(ent.radius, room, DOOR_CLEARANCE, ent)
        return self.add(ent)

    def place_agent(self, room: int) -> None:
        self.agent_x, self.agent_z = self._random_spot(AGENT_RADIUS, room, DOOR_CLEARANCE)
        self.heading = self._rng.randrange(HEADINGS)

    def place_agent_facing(self, room: int, item: Entity, dist: float | None = None) -> None:
        """The agent in ``room``, ``dist`` from ``item``'s centre (default: just clear of it),
        facing it: one press of action 4 takes it. The heading is drawn among those that allow
        this (from a doorway's boulder: the half-circle on ``room``'s side)."""
        dist = AGENT_RADIUS + item.radius + 0.1 if dist is None else dist
        others = [e for e in self.entities if e is not item and e is not self.carrying]
        for heading in self._rng.sample(range(HEADINGS), HEADINGS):
            x, z = item.x - dist * _COS[heading], item.z - dist * _SIN[heading]
            if self.layout.room_at(x, z) != room or not self.layout.fits(x, z, AGENT_RADIUS):
                continue
            if any(math.hypot(x - e.x, z - e.z) < AGENT_RADIUS + e.radius for e in others):
                continue
            self.agent_x, self.agent_z, self.heading = x, z, heading
            if self.facing() is item:
                return
        raise RuntimeError(f"no spot in room {room} facing the {item.kind} within reach")

    def add(self, ent: Entity) -> Entity:
        self.entities.append(ent)
        return ent

    def random_rooms(self, count: int) -> tuple[int, ...]:
        """``count`` rooms drawn uniformly (with repeats) from the episode's stream."""
        n = len(self.layout.rooms)
        return tuple(self._rng.randrange(n) for _ in range(count))

    def _random_spot(self, radius: float, room: int, door_clearance: float,
                     exclude: Entity | None = None) -> tuple[float, float]:
        """A uniformly random spot of ``room`` away from walls, doorways and other entities."""
        m = self.layout.rooms[room]
        margin = radius + 0.3
        doors = [d.center for d in self.layout.doors]
        others = [(e.x, e.z, (radius + e.radius + 0.5) ** 2) for e in self.entities
                  if e is not exclude and e is not self.carrying]
        rand = self._rng.uniform
        for _ in range(1000):
            x = rand(m.x0 + margin, m.x1 - margin)
            z = rand(m.z0 + margin, m.z1 - margin)
            if any((x - dx) ** 2 + (z - dz) ** 2 < door_clearance ** 2 for dx, dz in doors):
                continue
            if any((x - ex) ** 2 + (z - ez) ** 2 < rr for ex, ez, rr in others):
                continue
            return x, z
        raise RuntimeError(f"no free spot in room {room}; is room_size too small?")


def _carry_ahead(item: Entity) -> float:
    return CARRY_AHEAD_FACTOR * (AGENT_RADIUS + item.radius + FORWARD_STEP)


def _as_action(action) -> int:
    try:
        value = int(action)
        ok = value == action and 0 <= value < NUM_ACTIONS
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"action must be an integer in 0..5, got {action!r}")
    return value
