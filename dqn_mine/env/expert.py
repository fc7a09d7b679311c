"""A scripted expert that solves the rescue with privileged state.

Plan, re-derived from the state at every step (so it recovers when something unexpected happens):

1. Holding a boulder: put it down aside (far from every doorway).
2. Work out the route the rescue needs: the doorways from the agent to the kit and from the kit to
   the miner (from the agent to the miner once it holds the kit). The first doorway on that route
   that something blocks gets cleared: go to it on the near side and pick the blocker up. (Holding
   the kit then means putting the kit down aside first.)
3. Nothing blocks the route: fetch the kit, then hand it to the miner.

Moving between rooms goes through doorways: walk to a point in front of the opening, turn to face
straight through it, walk until well inside the next room. Inside a room the expert follows a
breadth-first distance field on a 0.5-unit grid that treats walls and entities (inflated by the
agent's radius) as obstacles, steering at the farthest path cell it can reach in a straight line.
"""

from __future__ import annotations

import math
import random
from collections import deque

from dqn_mine.env.entities import KIT, Entity
from dqn_mine.env.interface import BACKWARD, FORWARD, INTERACT, TURN_LEFT, TURN_RIGHT
from dqn_mine.env.layout import Door
from dqn_mine.env.mine import AGENT_RADIUS, ASIDE_CLEARANCE, DROP_GAP, HEADINGS, MineEnv

CELL = 0.5              # grid resolution inside a room
MARGIN = 0.2            # extra clearance the planner keeps from walls and entities
ARRIVE = 0.4            # a waypoint counts as reached within this distance
DOOR_APPROACH = 1.3     # stand this far in front of a doorway before walking through it
STAND_GAP = 0.35        # gap between the agent and an item it walks up to
LOOKAHEAD = 8           # path cells considered when steering
_STEP = 2 * math.pi / HEADINGS


class Expert:
    def __init__(self, env: MineEnv):
        self.env = env
        self.rng = random.Random(hash((env.agent_x, env.agent_z, env.heading)))
        self.traverse: tuple[Door, int] | None = None   # doorway being walked through, target room
        self.recovery: list[int] = []
        self.room = env.agent_room
        self._fields: dict = {}
        self._last_pose = None
        self._last_action = None

    # --- top level ---------------------------------------------------------------------------

    def act(self) -> int:
        env = self.env
        pose = (env.agent_x, env.agent_z, env.heading)
        if self._last_action == FORWARD and pose == self._last_pose and not self.recovery:
            # The move was refused (a corner or an entity): back off and turn a little at random.
            turn = self.rng.choice((TURN_LEFT, TURN_RIGHT))
            self.recovery = [BACKWARD] + [turn] * self.rng.randint(1, 4) + [FORWARD]
            self.traverse = None
        if self.recovery:
            action = self.recovery.pop(0)
        else:
            action = self._decide()
        self._last_pose, self._last_action = pose, action
        return action

    def _decide(self) -> int:
        env = self.env
        room = env.agent_room
        if room >= 0 and self.traverse is None:
            self.room = room
        if self.traverse is not None:
            return self._walk_through()
        held = env.carrying
        if held is not None and held.kind != KIT:
            return self._put_aside(held)
        for door, near in self._route():
            blocker = self._blocker(door)
            if blocker is not None:
                if held is not None:  # hands full: put the kit down first, fetch it again later
                    return self._put_aside(held)
                if near != self.room:
                    return self._go_to_room(near)
                return self._reach(blocker)
        target = env.miner if held is not None else env.kit
        target_room = env.room_of(target)
        if target_room != self.room:
            return self._go_to_room(target_room)
        return self._reach(target)

    def _route(self) -> list[tuple[Door, int]]:
        """Doorways (with the room they are entered from) that the rescue passes, in order."""
        env, layout = self.env, self.env.layout
        stops = [self.room]
        if env.carrying is None or env.carrying.kind != KIT:
            stops.append(env.room_of(env.kit))
        stops.append(env.room_of(env.miner))
        route = []
        for a, b in zip(stops, stops[1:]):
            room = a
            for door in layout.room_path(a, b):
                route.append((door, room))
                room = door.other(room)
        return route

    def _blocker(self, door: Door) -> Entity | None:
        """An entity that stops the agent walking straight through ``door``."""
        (cx, cz), (nx, nz) = door.center, door.normal_from(door.a)
        ax, az = cx - nx * DOOR_APPROACH, cz - nz * DOOR_APPROACH
        bx, bz = cx + nx * DOOR_APPROACH, cz + nz * DOOR_APPROACH
        for e in self.env.world_entities():
            if _segment_distance(e.x, e.z, ax, az, bx, bz) < AGENT_RADIUS + e.radius + 0.05:
                return e
        return None

    # --- behaviours ----------------------------------------------------------------------------

    def _go_to_room(self, goal: int) -> int:
        """Head for the first doorway on the way to room ``goal``."""
        door = self.env.layout.room_path(self.room, goal)[0]
        (cx, cz), (nx, nz) = door.center, door.normal_from(self.room)
        px, pz = cx - nx * DOOR_APPROACH, cz - nz * DOOR_APPROACH
        env = self.env
        if math.hypot(env.agent_x - px, env.agent_z - pz) < ARRIVE:
            self.traverse = (door, door.other(self.room))
            return self._walk_through()
        return self._navigate((px, pz))

    def _walk_through(self) -> int:
        door, target = self.traverse
        env = self.env
        (cx, cz), (nx, nz) = door.center, door.normal_from(door.other(target))
        if (env.agent_x - cx) * nx + (env.agent_z - cz) * nz >= DOOR_APPROACH:
            self.traverse = None
            self.room = target
            return self._decide()
        want = round(math.atan2(nz, nx) / _STEP) % HEADINGS
        return self._turn_to(want) if env.heading != want else FORWARD

    def _reach(self, target: Entity) -> int:
        """Walk up to ``target`` (in this room or in one of its doorways), face it, press 4."""
        env = self.env
        if env.facing() is target:
            return INTERACT
        stand = self._stand_point(target)
        if math.hypot(env.agent_x - stand[0], env.agent_z - stand[1]) >= ARRIVE:
            return self._navigate(stand)
        want = self._heading_to(target.x, target.z)
        if env.heading != want:
            return self._turn_to(want)
        return FORWARD

    def _put_aside(self, item: Entity) -> int:
        """Put the held item down where it blocks no doorway."""
        env = self.env
        ahead = AGENT_RADIUS + item.radius + DROP_GAP
        for delta in sorted(range(-HEADINGS // 2, HEADINGS // 2), key=abs):
            k = (env.heading + delta) % HEADINGS
            x = env.agent_x + ahead * math.cos(k * _STEP)
            z = env.agent_z + ahead * math.sin(k * _STEP)
            if self._aside_ok(item, x, z):
                return INTERACT if delta == 0 else self._turn_to(k)
        return self._navigate(self._aside_spot())

    def _aside_ok(self, item: Entity, x: float, z: float) -> bool:
        env = self.env
        far = all(math.hypot(x - d.center[0], z - d.center[1]) >= ASIDE_CLEARANCE
                  for d in env.layout.doors)
        return far and env.can_put_down(item, x, z)

    def _aside_spot(self) -> tuple[float, float]:
        """The free cell of this room nearest to the agent that lies far from every doorway:
        2 units beyond the drop clearance if the room has such a cell, else closer (small rooms
        with two doorways may not), never nearer than the clearance itself."""
        env = self.env
        grid = self._grid(self.room)
        cells = [grid.center(i, j) for (i, j) in grid.free]
        for margin in (2.0, 1.0, 0.0):
            far = [(x, z) for x, z in cells
                   if all(math.hypot(x - d.center[0], z - d.center[1]) >= ASIDE_CLEARANCE + margin
                          for d in env.layout.doors)]
            if far:
                return min(far, key=lambda c: math.hypot(c[0] - env.agent_x, c[1] - env.agent_z))
        raise RuntimeError("no room to put a boulder aside")

    def _stand_point(self, target: Entity) -> tuple[float, float]:
        """A free spot in this room from which the agent faces ``target`` within reach."""
        env = self.env
        key = ("stand", id(target), target.x, target.z, env.entity_moves, self.room)
        if key in self._fields:
            return self._fields[key]
        grid = self._grid(self.room)
        dist = AGENT_RADIUS + target.radius + STAND_GAP
        best, best_d = None, math.inf
        for k in range(16):
            a = 2 * math.pi * k / 16
            x, z = target.x - dist * math.cos(a), target.z - dist * math.sin(a)
            if grid.clear(x, z) and not env.layout.crosses_wall(x, z, target.x, target.z):
                d = math.hypot(x - env.agent_x, z - env.agent_z)
                if d < best_d:
                    best, best_d = (x, z), d
        if best is None:  # crowded: settle for the nearest free cell
            best = min((grid.center(i, j) for i, j in grid.free),
                       key=lambda c: math.hypot(c[0] - target.x, c[1] - target.z))
        self._fields[key] = best
        return best

    # --- low-level motion ----------------------------------------------------------------------

    def _navigate(self, goal: tuple[float, float]) -> int:
        """One step along the shortest grid path to ``goal`` in the current room."""
        env = self.env
        grid = self._grid(self.room)
        field = self._field(grid, goal)
        cell = grid.nearest_in(field, env.agent_x, env.agent_z)
        path = [cell]
        for _ in range(LOOKAHEAD):
            i, j = path[-1]
            nxt = min(grid.neighbours(i, j, field), key=lambda c: field[c], default=None)
            if nxt is None or field[nxt] >= field[path[-1]]:
                break
            path.append(nxt)
        points = [grid.center(*c) for c in path]
        if field[path[-1]] == 0:
            points[-1] = goal
        aim = points[0]
        for p in reversed(points):
            if self._line_clear(env.agent_x, env.agent_z, p[0], p[1], grid):
                aim = p
                break
        if math.hypot(aim[0] - env.agent_x, aim[1] - env.agent_z) < 1e-6:
            return FORWARD
        want = self._heading_to(*aim)
        return self._turn_to(want) if env.heading != want else FORWARD

    def _line_clear(self, x0, z0, x1, z1, grid) -> bool:
        n = max(1, int(math.hypot(x1 - x0, z1 - z0) / 0.25))
        return all(grid.clear(x0 + (x1 - x0) * t / n, z0 + (z1 - z0) * t / n, MARGIN / 2)
                   for t in range(1, n + 1))

    def _heading_to(self, x: float, z: float) -> int:
        env = self.env
        return round(math.atan2(z - env.agent_z, x - env.agent_x) / _STEP) % HEADINGS

    def _turn_to(self, want: int) -> int:
        return TURN_RIGHT if (want - self.env.heading) % HEADINGS <= HEADINGS // 2 else TURN_LEFT

    def _grid(self, room: int) -> _Grid:
        key = ("grid", room, self.env.entity_moves)
        if key not in self._fields:
            self._fields[key] = _Grid(self.env, room)
        return self._fields[key]

    def _field(self, grid: _Grid, goal: tuple[float, float]) -> dict:
        key = ("field", grid.room, self.env.entity_moves, goal)
        if key not in self._fields:
            if len(self._fields) > 64:
                self._fields.clear()
                self._fields[("grid", grid.room, self.env.entity_moves)] = grid
            self._fields[key] = grid.distances(goal)
        return self._fields[key]


class _Grid:
    """Free cells of one room for an agent that keeps MARGIN from walls and entities."""

    def __init__(self, env: MineEnv, room: int):
        self.env = env
        self.room = room
        m = env.layout.rooms[room]
        self.x0, self.z0 = m.x0, m.z0
        self.nx, self.nz = int((m.x1 - m.x0) / CELL), int((m.z1 - m.z0) / CELL)
        self.obstacles = [(e.x, e.z, e.radius) for e in env.world_entities()]
        self.free = {(i, j) for i in range(self.nx) for j in range(self.nz)
                     if self.clear(*self.center(i, j))}

    def center(self, i: int, j: int) -> tuple[float, float]:
        return self.x0 + (i + 0.5) * CELL, self.z0 + (j + 0.5) * CELL

    def clear(self, x: float, z: float, margin: float = MARGIN) -> bool:
        r = AGENT_RADIUS + margin
        if not self.env.layout.fits(x, z, r):
            return False
        return all((x - ex) ** 2 + (z - ez) ** 2 >= (r + er) ** 2 for ex, ez, er in self.obstacles)

    def cell_of(self, x: float, z: float) -> tuple[int, int]:
        i = min(max(int((x - self.x0) / CELL), 0), self.nx - 1)
        j = min(max(int((z - self.z0) / CELL), 0), self.nz - 1)
        return i, j

    def neighbours(self, i: int, j: int, cells) -> list[tuple[int, int]]:
        out = []
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                if (di or dj) and (i + di, j + dj) in cells:
                    # Diagonal moves only when both orthogonal cells are free (no corner cutting).
                    if di and dj and ((i + di, j) not in cells or (i, j + dj) not in cells):
                        continue
                    out.append((i + di, j + dj))
        return out

    def distances(self, goal: tuple[float, float]) -> dict:
        """Breadth-first steps from every free cell to the goal's cell."""
        start = self.cell_of(*goal)
        cells = self.free | {start}
        dist = {start: 0}
        queue = deque([start])
        while queue:
            c = queue.popleft()
            for n in self.neighbours(*c, cells):
                if n not in dist:
                    dist[n] = dist[c] + 1
                    queue.append(n)
        return dist

    def nearest_in(self, field: dict, x: float, z: float) -> tuple[int, int]:
        """The agent's cell, or the closest cell that has a path when the agent's cell has none."""
        c = self.cell_of(x, z)
        if c in field:
            return c
        return min(field, key=lambda k: (k[0] - c[0]) ** 2 + (k[1] - c[1]) ** 2 + 0.01 * field[k])


def _segment_distance(px, pz, ax, az, bx, bz) -> float:
    dx, dz = bx - ax, bz - az
    t = max(0.0, min(1.0, ((px - ax) * dx + (pz - az) * dz) / (dx * dx + dz * dz)))
    return math.hypot(px - ax - t * dx, pz - az - t * dz)




def solve(env: MineEnv, seed: int, step_limit: int) -> list[int]:
    """The expert's actions from the start of the episode ``env.reset(seed=seed)`` to the
    delivery, planned on the unrendered world (``MineEnv.advance``); the env is left wherever
    the plan ended, so reset it before playing. Raises if the expert needs more than
    ``step_limit`` steps (every task's episodes are solvable within its limit: tested)."""
    env.reset(seed=seed)
    expert = Expert(env)
    actions = []
    for _ in range(step_limit):
        action = expert.act()
        actions.append(action)
        if env.advance(action):
            return actions
    raise Unsolved(f"the expert did not deliver within {step_limit} steps (seed {seed})")


class Unsolved(RuntimeError):
    """The expert's plan did not deliver within the step limit it was given."""
