"""Triangle meshes for the mine, as flat float32 vertex arrays ready for one draw call.

A vertex is 7 floats: position (x, y, z), colour (r, g, b) with the lighting already baked in,
and a material id the fragment shader uses for a cheap procedural texture. Baking light into
vertices keeps the shader (and so llvmpipe's per-pixel cost) tiny, and lets every entity and
wall share one vertex buffer and one draw call.
"""

from __future__ import annotations

import colorsys

import numpy as np

from dqn_mine.env.layout import Layout

VERTEX_FLOATS = 7
VERTEX_FORMAT = "3f 3f 1f"

# Material ids (the fragment shader's texture switch).
PLAIN, ROCK, FLOOR, CEILING, WOOD = 0.0, 1.0, 2.0, 3.0, 4.0

ROCK_COLOUR = (0.50, 0.36, 0.24)
FLOOR_COLOUR = (0.24, 0.21, 0.18)
CEILING_COLOUR = (0.20, 0.17, 0.14)
# With room colours each room's floor has a hue of its own, dim and half-saturated like the rock
# (the kit's red and the miner's orange and yellow stay the brightest colours in view); hues step
# by the golden ratio so that neighbouring room indices differ most.
ROOM_FLOOR_VALUE, ROOM_FLOOR_SATURATION, ROOM_FLOOR_HUE0 = 0.34, 0.55, 0.08
WOOD_COLOUR = (0.62, 0.42, 0.20)
KIT_RED = (0.86, 0.07, 0.07)
WHITE = (0.95, 0.95, 0.95)
BOULDER_GREY = (0.58, 0.58, 0.60)
VEST_ORANGE = (1.00, 0.45, 0.02)
HELMET_YELLOW = (1.00, 0.86, 0.05)
TROUSER_BLUE = (0.12, 0.18, 0.50)
SKIN = (0.86, 0.64, 0.48)

_LIGHT = np.array([0.35, 1.0, 0.25]) / np.linalg.norm([0.35, 1.0, 0.25])
_QUAD_TRIS = np.array([0, 1, 2, 0, 2, 3])


def _lambert(normals: np.ndarray) -> np.ndarray:
    """Ambient plus diffuse shade for unit normals (..., 3) -> (...)."""
    return 0.55 + 0.45 * np.clip(normals @ _LIGHT, 0.0, 1.0)


def quads(corners: np.ndarray, colours: np.ndarray, material: float) -> np.ndarray:
    """corners (Q, 4, 3) counter-clockwise, colours (Q, 4, 3) -> vertices (6Q, 7)."""
    q = corners.shape[0]
    out = np.empty((q, 6, VERTEX_FLOATS), np.float32)
    out[:, :, 0:3] = corners[:, _QUAD_TRIS]
    out[:, :, 3:6] = colours[:, _QUAD_TRIS]
    out[:, :, 6] = material
    return out.reshape(-1, VERTEX_FLOATS)


def triangles(corners: np.ndarray, colours: np.ndarray, material: float) -> np.ndarray:
    """corners (T, 3, 3), colours (T, 3) -> vertices (3T, 7)."""
    t = corners.shape[0]
    out = np.empty((t, 3, VERTEX_FLOATS), np.float32)
    out[:, :, 0:3] = corners
    out[:, :, 3:6] = colours[:, None, :]
    out[:, :, 6] = material
    return out.reshape(-1, VERTEX_FLOATS)


# Unit-cube faces: (normal, four corners in [-0.5, 0.5]^3).
_CUBE_FACES = np.array([
    [[0.5, -.5, -.5], [0.5, 0.5, -.5], [0.5, 0.5, 0.5], [0.5, -.5, 0.5]],   # +x
    [[-.5, -.5, 0.5], [-.5, 0.5, 0.5], [-.5, 0.5, -.5], [-.5, -.5, -.5]],   # -x
    [[-.5, 0.5, -.5], [-.5, 0.5, 0.5], [0.5, 0.5, 0.5], [0.5, 0.5, -.5]],   # +y
    [[-.5, -.5, -.5], [0.5, -.5, -.5], [0.5, -.5, 0.5], [-.5, -.5, 0.5]],   # -y
    [[-.5, -.5, 0.5], [0.5, -.5, 0.5], [0.5, 0.5, 0.5], [-.5, 0.5, 0.5]],   # +z
    [[0.5, -.5, -.5], [-.5, -.5, -.5], [-.5, 0.5, -.5], [0.5, 0.5, -.5]],   # -z
])
_CUBE_NORMALS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                         float)


def boxes(centers, sizes, colours, material: float = PLAIN) -> np.ndarray:
    """Axis-aligned boxes, centers/sizes/colours (B, 3) -> vertices (36B, 7), faces lit."""
    centers, sizes, colours = (np.asarray(a, float).reshape(-1, 3)
                               for a in (centers, sizes, colours))
    # [B, 6, 4, 3]
    corners = centers[:, None, None, :] + _CUBE_FACES[None] * sizes[:, None, None, :]
    shade = _lambert(_CUBE_NORMALS)  # [6]
    cols = colours[:, None, None, :] * shade[None, :, None, None]  # [B, 6, 1, 3]
    cols = np.broadcast_to(cols, corners.shape)
    return quads(corners.reshape(-1, 4, 3), cols.reshape(-1, 4, 3), material)


def room_floor_colours(count: int) -> np.ndarray:
    """(count, 3): room i's floor colour when rooms are told apart by colour."""
    hues = (ROOM_FLOOR_HUE0 + 0.618034 * np.arange(count)) % 1.0
    return np.array([colorsys.hsv_to_rgb(h, ROOM_FLOOR_SATURATION, ROOM_FLOOR_VALUE)
                     for h in hues])


def static_scene(layout: Layout, wall_height: float, door_height: float,
                 room_colours: bool = False) -> np.ndarray:
    """Walls with doorway gaps, lintels, timber door frames, floors and ceilings of a layout;
    ``room_colours``: each room's floor in a colour of its own (``room_floor_colours``)."""
    segs = [_seg(v, w, lo, hi, 0.0, wall_height) for v, w, lo, hi in layout.walls]
    segs += [_seg(d.vertical, d.wall, d.lo, d.hi, door_height, wall_height) for d in layout.doors]
    segs = np.array(segs, float)
    parts = [_walls(segs, wall_height)]
    rooms = np.array([[r.x0, r.z0, r.x1, r.z1] for r in layout.rooms], float)
    floors = room_floor_colours(len(rooms)) if room_colours else FLOOR_COLOUR
    parts.append(_horizontal(rooms, 0.0, floors, FLOOR))
    parts.append(_horizontal(rooms, wall_height, CEILING_COLOUR, CEILING))
    if layout.doors:
        parts.append(_door_frames(layout, door_height))
    return np.concatenate(parts)


def _seg(vertical, wall, a, b, y0, y1):
    shade = 0.9 if vertical else 0.75  # walls facing two ways get two tones, like a lit room
    return (wall, a, wall, b, y0, y1, shade) if vertical else (a, wall, b, wall, y0, y1, shade)


def _walls(segs: np.ndarray, height: float) -> np.ndarray:
    x0, z0, x1, z1, y0, y1, shade = segs.T
    corners = np.stack([np.stack([x0, y0, z0], -1), np.stack([x1, y0, z1], -1),
                        np.stack([x1, y1, z1], -1), np.stack([x0, y1, z0], -1)], 1)  # [S, 4, 3]
    # Darker towards the floor: a cheap stand-in for ambient occlusion that reads as depth.
    gradient = 0.55 + 0.45 * corners[:, :, 1] / height  # [S, 4]
    colours = np.array(ROCK_COLOUR) * (shade[:, None] * gradient)[:, :, None]
    return quads(corners, colours, ROCK)


def _horizontal(rooms: np.ndarray, y: float, colour, material: float) -> np.ndarray:
    """Floors or ceilings at height ``y``: ``colour`` (3,) for all rooms or (rooms, 3)."""
    x0, z0, x1, z1 = rooms.T
    ys = np.full_like(x0, y)
    corners = np.stack([np.stack([x0, ys, z0], -1), np.stack([x1, ys, z0], -1),
                        np.stack([x1, ys, z1], -1), np.stack([x0, ys, z1], -1)], 1)
    colours = np.broadcast_to(np.array(colour, float), (len(rooms), 3))
    return quads(corners, np.broadcast_to(colours[:, None, :], corners.shape), material)


def _door_frames(layout: Layout, door_height: float) -> np.ndarray:
    """Two timber posts and a beam per doorway, set into the wall beside the opening."""
    post, depth, beam = 0.22, 0.30, 0.22
    centers, sizes = [], []
    for d in layout.doors:
        along = [(d.lo - post / 2, post), (d.hi + post / 2, post),
                 ((d.lo + d.hi) / 2, d.width + 2 * post)]
        for k, (c, length) in enumerate(along):
            y, h = ((door_height / 2, door_height) if k < 2 else (door_height + beam / 2, beam))
            if d.vertical:
                centers.append((d.wall, y, c))
                sizes.append((depth, h, length))
            else:
                centers.append((c, y, d.wall))
                sizes.append((length, h, depth))
    return boxes(centers, sizes, [WOOD_COLOUR] * len(centers), WOOD)


# --- entity meshes (built once, in the entity's own frame: floor at y=0, facing +x) -------------

def kit_mesh() -> np.ndarray:
    """A red first-aid case with white crosses on the lid and the sides."""
    w, h, d = 0.72, 0.46, 0.52
    parts = [boxes([(0, h / 2, 0)], [(w, h, d)], [KIT_RED])]
    t, arm = 0.02, 0.13
    crosses = [  # (center, size) of the two bars of each cross
        ((0, h + t / 2, 0), (0.40, t, arm)), ((0, h + t / 2, 0), (arm, t, 0.40)),
        ((0, h / 2, d / 2 + t / 2), (0.34, arm, t)), ((0, h / 2, d / 2 + t / 2), (arm, 0.34, t)),
        ((0, h / 2, -d / 2 - t / 2), (0.34, arm, t)), ((0, h / 2, -d / 2 - t / 2), (arm, 0.34, t)),
        ((w / 2 + t / 2, h / 2, 0), (t, arm, 0.34)), ((w / 2 + t / 2, h / 2, 0), (t, 0.34, arm)),
        ((-w / 2 - t / 2, h / 2, 0), (t, arm, 0.34)), ((-w / 2 - t / 2, h / 2, 0), (t, 0.34, arm)),
    ]
    c, s = zip(*crosses)
    parts.append(boxes(c, s, [WHITE] * len(c)))
    return np.concatenate(parts)


def boulder_mesh(radius: float, height: float) -> np.ndarray:
    """A jittered, once-subdivided icosahedron: a faceted grey rock."""
    verts, faces = _icosphere()
    rng = np.random.default_rng(7)  # fixed: every boulder is the same rock, rotated
    verts = verts * rng.uniform(0.85, 1.08, (len(verts), 1))
    verts = verts * np.array([radius, height / 2, radius])
    verts[:, 1] += height / 2 - 0.05  # sits slightly sunk into the floor
    tri = verts[faces]  # [T, 3, 3]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    tint = rng.uniform(0.88, 1.05, (len(faces), 1))
    colours = np.array(BOULDER_GREY) * tint * _lambert(normals)[:, None]
    return triangles(tri, colours, ROCK)


def miner_mesh() -> np.ndarray:
    """An injured miner sitting on the floor: blue legs, orange vest, yellow helmet with a lamp."""
    items = [
        ((0.40, 0.13, 0.0), (0.80, 0.26, 0.50), TROUSER_BLUE),    # legs stretched out
        ((-0.05, 0.60, 0.0), (0.40, 0.70, 0.58), VEST_ORANGE),    # torso
        ((-0.05, 0.66, 0.0), (0.42, 0.08, 0.60), WHITE),          # reflective stripe
        ((0.20, 0.55, 0.36), (0.55, 0.14, 0.14), VEST_ORANGE),    # arms
        ((0.20, 0.55, -0.36), (0.55, 0.14, 0.14), VEST_ORANGE),
        ((-0.05, 1.12, 0.0), (0.30, 0.30, 0.30), SKIN),           # head
        ((-0.05, 1.30, 0.0), (0.44, 0.10, 0.44), HELMET_YELLOW),  # helmet brim
        ((-0.05, 1.39, 0.0), (0.32, 0.12, 0.32), HELMET_YELLOW),  # helmet crown
        ((0.14, 1.35, 0.0), (0.08, 0.10, 0.12), WHITE),           # lamp
    ]
    c, s, col = zip(*items)
    return boxes(c, s, col)


def _icosphere():
    p = (1 + 5 ** 0.5) / 2
    v = np.array([[-1, p, 0], [1, p, 0], [-1, -p, 0], [1, -p, 0], [0, -1, p], [0, 1, p],
                  [0, -1, -p], [0, 1, -p], [p, 0, -1], [p, 0, 1], [-p, 0, -1], [-p, 0, 1]], float)
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = list(v / np.linalg.norm(v, axis=1, keepdims=True))
    mids: dict[tuple[int, int], int] = {}

    def mid(a, b):
        key = (min(a, b), max(a, b))
        if key not in mids:
            m = verts[a] + verts[b]
            verts.append(m / np.linalg.norm(m))
            mids[key] = len(verts) - 1
        return mids[key]

    faces = []
    for a, b, c in f:
        ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
        faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
    return np.array(verts), np.array(faces)


def place(local: np.ndarray, x: float, z: float, yaw_cos: float, yaw_sin: float) -> np.ndarray:
    """Rotate an entity mesh about y by its yaw and move it to (x, z)."""
    out = local.copy()
    lx, lz = local[:, 0], local[:, 2]
    out[:, 0] = yaw_cos * lx - yaw_sin * lz + x
    out[:, 2] = yaw_sin * lx + yaw_cos * lz + z
    return out
