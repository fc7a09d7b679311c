"""Entities of the mine: the first-aid kit, boulders and the injured miner.

Each kind knows its collision radius, whether the agent can carry it, its mesh (built once per
process) and its colour on the top-down map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import numpy as np

from dqn_mine.env import mesh

KIT, BOULDER, MINER = "kit", "boulder", "miner"


@dataclass(frozen=True)
class Kind:
    name: str
    radius: float        # collision disc on the floor
    movable: bool        # the agent can pick it up
    map_colour: tuple    # RGB 0-255 on the top-down map


# A boulder is sized to block a doorway: (DOOR_WIDTH / 2) < BOULDER radius + 2 * AGENT radius,
# so with a boulder in the opening no gap is wide enough for the agent (see MineEnv constants).
KINDS = {
    KIT: Kind(KIT, 0.45, True, (225, 20, 20)),
    BOULDER: Kind(BOULDER, 0.9, True, (150, 150, 155)),
    MINER: Kind(MINER, 0.6, False, (255, 200, 0)),
}


class Entity:
    """A thing on the floor at (x, z), turned by ``yaw`` radians about the vertical axis."""

    __slots__ = ("kind", "x", "z", "yaw", "radius", "movable")

    def __init__(self, kind: str, x: float = 0.0, z: float = 0.0, yaw: float = 0.0):
        spec = KINDS[kind]
        self.kind = kind
        self.x = x
        self.z = z
        self.yaw = yaw
        self.radius = spec.radius
        self.movable = spec.movable

    def __repr__(self) -> str:
        return f"Entity({self.kind!r}, x={self.x:.2f}, z={self.z:.2f})"

    def vertices(self) -> np.ndarray:
        """This entity's triangles in world coordinates."""
        return mesh.place(local_mesh(self.kind), self.x, self.z,
                          math.cos(self.yaw), math.sin(self.yaw))


@cache
def local_mesh(kind: str) -> np.ndarray:
    if kind == KIT:
        return mesh.kit_mesh()
    if kind == BOULDER:
        return mesh.boulder_mesh(KINDS[BOULDER].radius, 1.6)
    return mesh.miner_mesh()
