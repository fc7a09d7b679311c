"""Episode videos: GIFs (pillow), or MP4s with the `video` extra (imageio-ffmpeg).

Shared by ``play``, ``evaluate`` and the evaluation actor, which saves a GIF now and then.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def save_gif(frames: list[np.ndarray], path: Path, fps: float) -> None:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:],
                   duration=max(1, round(1000 / fps)), loop=0)


def save_video(frames: list[np.ndarray], path: Path, fps: float) -> None:
    """Frames with the map's legend below them, as a GIF or (with imageio-ffmpeg) an MP4."""
    from dqn_mine.env.topdown import draw_legend

    legend = draw_legend(frames[0].shape[1])
    frames = [np.concatenate([f, legend]) for f in frames]
    if path.suffix.lower() != ".mp4":
        save_gif(frames, path, fps)
        return
    import imageio.v2 as imageio

    path.parent.mkdir(parents=True, exist_ok=True)
    # H.264 wants even sides: repeat the last row/column when a side is odd.
    h, w = frames[0].shape[:2]
    pad = ((0, h % 2), (0, w % 2), (0, 0))
    with imageio.get_writer(path, fps=fps, macro_block_size=1) as writer:
        for f in frames:
            writer.append_data(np.pad(f, pad, mode="edge"))


def mp4_available() -> bool:
    import importlib.util

    return all(importlib.util.find_spec(m) is not None for m in ("imageio", "imageio_ffmpeg"))
