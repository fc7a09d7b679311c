"""The replay on disk (``--save-replay DIR``): written with the final checkpoint, read on resume.

A snapshot is a folder: one ``.npy`` file per shared array of :class:`ReplayStorage` (frames,
per-slot metadata, the writers' counters), ``sampler.npz`` with the sampler's priorities and
counters, and ``replay.json`` with the layout it was written for. It is written to ``DIR.tmp``
and renamed, so an interrupted write never replaces a good snapshot with half of one. A resumed
run that reads it samples exactly the transitions, priorities and random stream it stopped with,
and its actors' writers carry on after the saved cursors (their unfinished episodes are dropped).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np

from dqn_mine.replay.storage import BLOCK_NAMES, ReplayLayout, ReplayStorage

FORMAT = 1
_INFO, _SAMPLER = "replay.json", "sampler.npz"


class SnapshotError(ValueError):
    """A saved replay is missing parts, corrupt, or was written for another layout (one line)."""


def nbytes(storage: ReplayStorage) -> int:
    """Bytes a snapshot of ``storage`` takes (the arrays; the sampler adds 8 per slot)."""
    return sum(getattr(storage, name).nbytes for name in BLOCK_NAMES) + 8 * storage.capacity


def exists(path) -> bool:
    return (Path(path) / _INFO).is_file()


def save(path, storage: ReplayStorage, replay) -> Path:
    """Write ``storage`` and the sampler ``replay`` (a PrioritizedReplay) to the folder ``path``."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name in BLOCK_NAMES:
        np.save(tmp / f"{name}.npy", getattr(storage, name))
    state = replay.state_dict()
    np.savez(tmp / _SAMPLER, leaves=state["leaves"], seen=state["seen"],
             alive_from=state["alive_from"], live=state["live"], max_p=state["max_p"])
    info = {"format": FORMAT, "layout": _layout_dict(storage.layout), "rng": state["rng"]}
    (tmp / _INFO).write_text(json.dumps(info, indent=1) + "\n")
    old = path.with_name(path.name + ".old")
    if path.exists():
        shutil.rmtree(old, ignore_errors=True)
        path.rename(old)
    tmp.rename(path)
    shutil.rmtree(old, ignore_errors=True)
    return path


def demo_streams(path) -> int:
    """Demonstration rings of the replay saved at ``path`` (SnapshotError if unreadable)."""
    layout = _info(path).get("layout")
    return int(layout.get("demo_streams", 0)) if isinstance(layout, dict) else 0


def check(path, layout: ReplayLayout) -> dict:
    """Raise SnapshotError unless ``path`` holds a snapshot written for ``layout``; returns its
    ``replay.json``."""
    info = _info(path)
    saved = info.get("layout")
    if isinstance(saved, dict):   # saved before replays held demonstrations
        saved = {"demo_streams": 0, **saved}
    if saved != _layout_dict(layout):
        diff = sorted(k for k in _layout_dict(layout)
                      if not isinstance(saved, dict) or saved.get(k) != _layout_dict(layout)[k])
        raise SnapshotError(f"the replay saved in {path} was written for another replay layout "
                            f"(differs in {', '.join(diff)}); resume with the settings it was "
                            f"saved with, or move it away to pre-fill anew")
    return info


def load(path, storage: ReplayStorage, replay) -> int:
    """Fill ``storage`` and ``replay`` from the snapshot at ``path``; returns live transitions."""
    path = Path(path)
    info = check(path, storage.layout)
    try:
        for name in BLOCK_NAMES:
            saved = np.load(path / f"{name}.npy", mmap_mode="r")
            target = getattr(storage, name)
            if saved.shape != target.shape or saved.dtype != target.dtype:
                raise SnapshotError(f"{path / name}.npy has shape {saved.shape} {saved.dtype}, "
                                    f"expected {target.shape} {target.dtype}")
            target[...] = saved
        with np.load(path / _SAMPLER) as z:
            state = {k: z[k] for k in ("leaves", "seen", "alive_from", "live", "max_p")}
        state["rng"] = info["rng"]
        replay.load_state_dict(state)
    except SnapshotError:
        raise
    except (OSError, ValueError, KeyError, EOFError) as exc:
        why = str(exc).splitlines()[0] if str(exc) else ""
        raise SnapshotError(f"the replay saved in {path} is unreadable ({type(exc).__name__}: "
                            f"{why}); move it away to pre-fill anew") from None
    return len(replay)


def _info(path) -> dict:
    path = Path(path)
    try:
        info = json.loads((path / _INFO).read_text())
    except FileNotFoundError:
        raise SnapshotError(f"no saved replay in {path}") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        raise SnapshotError(f"the replay saved in {path} is corrupt ({_INFO} unreadable)") from None
    if not isinstance(info, dict) or info.get("format") != FORMAT:
        raise SnapshotError(f"{path} does not hold a dqn_mine replay of format {FORMAT}")
    return info


def _layout_dict(layout: ReplayLayout) -> dict:
    return json.loads(json.dumps(dataclasses.asdict(layout)))   # tuples as lists, like the file
