"""Random multi-room layouts: square rooms placed against each other and joined by doorways.

Coordinates: the floor is the x-z plane (y is up). On the top-down map x grows to the right and z
grows downwards, which is the true view from above for a right-handed frame.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

# Free space the walkability test adds across a doorway's wall line so the doorway corridor
# overlaps the (shrunken) interiors of both rooms it joins.
_EPS = 1e-3


@dataclass(frozen=True)
class Room:
    """An axis-aligned room: x in [x0, x1], z in [z0, z1]."""

    x0: float
    z0: float
    x1: float
    z1: float

    @property
    def center(self) -> tuple[float, float]:
        return (self.x0 + self.x1) / 2, (self.z0 + self.z1) / 2

    def contains(self, x: float, z: float, margin: float = 0.0) -> bool:
        return ((self.x0 + margin <= x <= self.x1 - margin)
                and (self.z0 + margin <= z <= self.z1 - margin))

    def overlaps(self, other: Room) -> bool:
        """True when the interiors intersect (sharing a wall is fine)."""
        return (self.x0 < other.x1 - _EPS and other.x0 < self.x1 - _EPS
                and self.z0 < other.z1 - _EPS and other.z0 < self.z1 - _EPS)


@dataclass(frozen=True)
class Door:
    """A doorway in the wall shared by rooms ``a`` and ``b``.

    ``vertical``: the wall is the line x = ``wall`` and the opening spans z in [lo, hi]; otherwise
    the wall is z = ``wall`` and the opening spans x in [lo, hi]. ``sign`` is +1 when room ``b``
    lies on the positive side of the wall.
    """

    a: int
    b: int
    vertical: bool
    wall: float
    lo: float
    hi: float
    sign: int

    @property
    def center(self) -> tuple[float, float]:
        mid = (self.lo + self.hi) / 2
        return (self.wall, mid) if self.vertical else (mid, self.wall)

    @property
    def width(self) -> float:
        return self.hi - self.lo

    def other(self, room: int) -> int:
        return self.b if room == self.a else self.a

    def normal_from(self, room: int) -> tuple[float, float]:
        """Unit vector pointing out of ``room`` through this doorway."""
        s = self.sign if room == self.a else -self.sign
        return (float(s), 0.0) if self.vertical else (0.0, float(s))


class Layout:
    """Rooms, doorways and the walkability test that collision uses."""

    def __init__(self, rooms: list[Room], doors: list[Door]):
        self.rooms = rooms
        self.doors = doors
        self.neighbours: list[list[tuple[Door, int]]] = [[] for _ in rooms]
        for d in doors:
            self.neighbours[d.a].append((d, d.b))
            self.neighbours[d.b].append((d, d.a))
        self._rects: dict[float, list[tuple[float, float, float, float]]] = {}
        self.walls = self._solid_walls()

    def _solid_walls(self) -> list[tuple[bool, float, float, float]]:
        """Solid wall pieces (vertical?, wall coordinate, lo, hi): room sides minus doorways.

        A wall two rooms share appears once per room; the copies coincide, which is harmless.
        """
        pieces = []
        for i, room in enumerate(self.rooms):
            sides = [(True, room.x0, room.z0, room.z1), (True, room.x1, room.z0, room.z1),
                     (False, room.z0, room.x0, room.x1), (False, room.z1, room.x0, room.x1)]
            for vertical, wall, lo, hi in sides:
                gaps = sorted((d.lo, d.hi) for d, _ in self.neighbours[i]
                              if d.vertical == vertical and d.wall == wall)
                cursor = lo
                for g0, g1 in gaps + [(hi, hi)]:
                    if g0 > cursor:
                        pieces.append((vertical, wall, cursor, g0))
                    cursor = g1
        return pieces

    def crosses_wall(self, x0: float, z0: float, x1: float, z1: float) -> bool:
        """True when the straight segment (x0, z0)-(x1, z1) passes through a solid wall."""
        for vertical, wall, lo, hi in self.walls:
            a, b = (x0, x1) if vertical else (z0, z1)
            if (a - wall) * (b - wall) < 0:
                t = (wall - a) / (b - a)
                c = (z0 + t * (z1 - z0)) if vertical else (x0 + t * (x1 - x0))
                if lo <= c <= hi:
                    return True
        return False

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return (min(r.x0 for r in self.rooms), min(r.z0 for r in self.rooms),
                max(r.x1 for r in self.rooms), max(r.z1 for r in self.rooms))

    def rects(self, radius: float) -> list[tuple[float, float, float, float]]:
        """Rectangles whose union holds every centre where a disc of ``radius`` touches no wall.

        Room interiors shrunk by the radius, plus one corridor per doorway. Slightly conservative
        at door jambs (a square corner instead of a rounded one), which is harmless.
        """
        rects = self._rects.get(radius)
        if rects is None:
            r = radius
            rects = [(m.x0 + r, m.z0 + r, m.x1 - r, m.z1 - r) for m in self.rooms]
            for d in self.doors:
                if d.vertical:
                    rects.append((d.wall - r - _EPS, d.lo + r, d.wall + r + _EPS, d.hi - r))
                else:
                    rects.append((d.lo + r, d.wall - r - _EPS, d.hi - r, d.wall + r + _EPS))
            rects = [q for q in rects if q[0] <= q[2] and q[1] <= q[3]]
            self._rects[radius] = rects
        return rects

    def fits(self, x: float, z: float, radius: float) -> bool:
        """True when a disc of ``radius`` centred at (x, z) touches no wall."""
        for x0, z0, x1, z1 in self.rects(radius):
            if x0 <= x <= x1 and z0 <= z <= z1:
                return True
        return False

    def room_at(self, x: float, z: float) -> int:
        """Index of the room holding (x, z), or -1 outside every room."""
        for i, m in enumerate(self.rooms):
            if m.x0 <= x <= m.x1 and m.z0 <= z <= m.z1:
                return i
        return -1

    def room_path(self, start: int, goal: int) -> list[Door]:
        """Doorways to pass, in order, to get from room ``start`` to room ``goal`` (BFS)."""
        prev: dict[int, tuple[int, Door] | None] = {start: None}
        frontier = [start]
        while frontier and goal not in prev:
            nxt = []
            for room in frontier:
                for door, other in self.neighbours[room]:
                    if other not in prev:
                        prev[other] = (room, door)
                        nxt.append(other)
            frontier = nxt
        if goal not in prev:
            raise RuntimeError(f"room {goal} is unreachable from room {start}")
        path = []
        room = goal
        while prev[room] is not None:
            room, door = prev[room]
            path.append(door)
        return path[::-1]


def generate_layout(rng: random.Random, num_rooms: int, size: float, door_width: float,
                    chain: bool) -> Layout:
    """Place ``num_rooms`` square rooms of side ``size``, each against a wall of an earlier room.

    ``chain``: room i attaches to room i-1 (three-room); otherwise to a random earlier room.
    Each new room gets one doorway to the room it attaches to, at a random position along the
    shared stretch of wall, so the room graph is a tree and every room is reachable.
    """
    # Doorways keep this much wall on both sides so door frames and approach paths stay clear.
    jamb = 1.0
    min_overlap = door_width + 2 * jamb
    rooms = [Room(0.0, 0.0, size, size)]
    doors: list[Door] = []
    for i in range(1, num_rooms):
        for _ in range(200):
            j = i - 1 if chain else rng.randrange(i)
            base = rooms[j]
            side = rng.randrange(4)  # 0: +x, 1: -x, 2: +z, 3: -z
            shift = rng.uniform(-(size - min_overlap), size - min_overlap)
            if side < 2:
                # The shared coordinate is copied, never recomputed, so both rooms' walls (and
                # the doorway in them) lie on exactly the same line.
                x0, x1 = (base.x1, base.x1 + size) if side == 0 else (base.x0 - size, base.x0)
                z0 = base.z0 + shift
                room = Room(x0, z0, x1, z0 + size)
                lo, hi = max(base.z0, room.z0), min(base.z1, room.z1)
                wall, vertical = (base.x1 if side == 0 else base.x0), True
            else:
                z0, z1 = (base.z1, base.z1 + size) if side == 2 else (base.z0 - size, base.z0)
                x0 = base.x0 + shift
                room = Room(x0, z0, x0 + size, z1)
                lo, hi = max(base.x0, room.x0), min(base.x1, room.x1)
                wall, vertical = (base.z1 if side == 2 else base.z0), False
            if any(room.overlaps(r) for r in rooms):
                continue
            start = rng.uniform(lo + jamb, hi - jamb - door_width)
            doors.append(Door(j, i, vertical, wall, start, start + door_width,
                              1 if side in (0, 2) else -1))
            rooms.append(room)
            break
        else:  # pragma: no cover - 200 failures in a row do not happen for sane sizes
            raise RuntimeError("could not place a room; try fewer rooms")
    return Layout(rooms, doors)
