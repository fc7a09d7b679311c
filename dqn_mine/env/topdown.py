"""The top-down map of the whole mine, for people (videos, debugging); never shown to the agent.

Drawn with pillow: floors, walls, doorways (timber-coloured gaps), boulders (grey discs), the kit
(red square with a white cross), the miner (orange disc with a yellow helmet dot) and the agent
(a blue disc with a heading line, holding a small marker of what it carries).
"""

from __future__ import annotations

import numpy as np

from dqn_mine.env.entities import BOULDER, KINDS, KIT, MINER

BACKGROUND = (18, 16, 14)
FLOOR = (92, 80, 68)
WALL = (200, 160, 120)
DOOR = (240, 150, 40)
AGENT = (40, 120, 255)


def draw_map(env, size: int = 256) -> np.ndarray:
    """The map of ``env`` (a MineEnv after reset) as uint8 (size, size, 3)."""
    from PIL import Image, ImageDraw

    size = int(size)
    x0, z0, x1, z1 = env.layout.bounds
    pad = 0.6
    scale = (size - 1) / (max(x1 - x0, z1 - z0) + 2 * pad)
    ox = (size - (x1 - x0) * scale) / 2 - x0 * scale
    oz = (size - (z1 - z0) * scale) / 2 - z0 * scale

    def px(x, z):
        return x * scale + ox, z * scale + oz

    img = Image.new("RGB", (size, size), BACKGROUND)
    draw = ImageDraw.Draw(img)
    for room in env.layout.rooms:
        draw.rectangle([px(room.x0, room.z0), px(room.x1, room.z1)], fill=FLOOR)
    wall_w = max(1, round(scale * 0.18))
    for vertical, wall, lo, hi in env.layout.walls:
        a, b = (px(wall, lo), px(wall, hi)) if vertical else (px(lo, wall), px(hi, wall))
        draw.line([a, b], fill=WALL, width=wall_w)
    for d in env.layout.doors:  # the opening as a thin orange line between two posts
        a, b = ((px(d.wall, d.lo), px(d.wall, d.hi)) if d.vertical
                else (px(d.lo, d.wall), px(d.hi, d.wall)))
        draw.line([a, b], fill=DOOR, width=max(1, wall_w // 2))
        r = max(2.0, scale * 0.3)
        for c in (a, b):
            draw.rectangle([c[0] - r, c[1] - r, c[0] + r, c[1] + r], fill=DOOR)

    # Icons are drawn larger than life (at least a few pixels) so that small maps stay legible.
    grow = 1.5
    for e in env.world_entities():
        _draw_entity(draw, e.kind, *px(e.x, e.z), max(e.radius * scale * grow, 4.0))

    ax, az = px(env.agent_x, env.agent_z)
    r = max(0.4 * scale * grow, 4.0)
    c, s = env.direction
    draw.ellipse([ax - r, az - r, ax + r, az + r], fill=AGENT, outline=(255, 255, 255))
    draw.line([(ax, az), (ax + c * r * 2.2, az + s * r * 2.2)], fill=(255, 255, 255),
              width=max(1, round(r / 3)))
    if env.carrying is not None:
        _draw_entity(draw, env.carrying.kind, ax, az, r * 0.55)
    return np.asarray(img)


LEGEND = (("agent", "agent"), (KIT, "kit"), (MINER, "miner"), (BOULDER, "boulder"),
          ("door", "doorway"))


def draw_legend(width: int, height: int = 16) -> np.ndarray:
    """A strip naming the map's symbols (agent, kit, miner, boulder, doorway): uint8 (h, w, 3)."""
    from PIL import Image, ImageDraw

    img = Image.new("RGB", (int(width), int(height)), BACKGROUND)
    draw = ImageDraw.Draw(img)
    r, y = height * 0.3, height / 2
    x = 6.0
    for symbol, label in LEGEND:
        if symbol == "agent":
            draw.ellipse([x - r, y - r, x + r, y + r], fill=AGENT, outline=(255, 255, 255))
        elif symbol == "door":
            draw.line([(x - r, y), (x + r, y)], fill=DOOR, width=2)
        else:
            _draw_entity(draw, symbol, x, y, r)
        draw.text((x + r + 3, y), label, fill=(230, 230, 230), anchor="lm")
        x += r + 3 + draw.textlength(label) + 12
    return np.asarray(img)


def _draw_entity(draw, kind: str, x: float, y: float, r: float) -> None:
    box = [x - r, y - r, x + r, y + r]
    if kind == KIT:
        k = r * 0.9
        draw.rectangle([x - k, y - k, x + k, y + k], fill=KINDS[KIT].map_colour)
        w = k * 0.18
        draw.rectangle([x - k * 0.65, y - w, x + k * 0.65, y + w], fill=(255, 255, 255))
        draw.rectangle([x - w, y - k * 0.65, x + w, y + k * 0.65], fill=(255, 255, 255))
    elif kind == BOULDER:
        draw.ellipse(box, fill=KINDS[BOULDER].map_colour, outline=(90, 90, 95))
    elif kind == MINER:
        draw.ellipse(box, fill=(255, 115, 0), outline=(255, 255, 255))
        h = r * 0.5
        draw.ellipse([x - h, y - h, x + h, y + h], fill=KINDS[MINER].map_colour)
