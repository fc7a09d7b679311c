"""Checkpoints: network, target, optimiser, counters and config in one ``checkpoint.pt``.

Written to a temporary file and renamed, so a run killed mid-write keeps its previous checkpoint.
"""

from __future__ import annotations

import os
from pathlib import Path

from dqn_mine.config import NETWORK_SHAPE, Config, ConfigError

FILENAME = "checkpoint.pt"
FORMAT = 1


class CheckpointError(ValueError):
    """A checkpoint is missing, unreadable or not one of ours (the message is one line)."""


def save(run_dir: Path, updater_state: dict, counters: dict, cfg) -> Path:
    import torch

    path = Path(run_dir) / FILENAME
    tmp = path.with_suffix(".pt.tmp")
    torch.save({"format": FORMAT, "updater": updater_state, "counters": dict(counters),
                "config": cfg.saved_dict()}, tmp)
    os.replace(tmp, path)
    return path


def load(path: Path, map_location: str = "cpu") -> dict:
    """The checkpoint dict; ``path`` may be a run folder or a ``.pt`` file."""
    import torch

    path = Path(path)
    if path.is_dir():
        path = path / FILENAME
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        state = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as exc:
        raise CheckpointError(f"checkpoint {path} is unreadable ({type(exc).__name__}); "
                              "it may be truncated or corrupt") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT \
            or not isinstance(state.get("updater"), dict) or "online" not in state["updater"] \
            or not isinstance(state.get("config"), dict) \
            or not set(NETWORK_SHAPE) <= set(state["config"]):
        raise CheckpointError(f"{path} is not a dqn_mine checkpoint")
    try:   # every reader sees this version's settings, an older run's migrated
        state["config"] = Config.from_dict(state["config"], where=str(path)).to_dict()
    except ConfigError as exc:
        raise CheckpointError(str(exc)) from None
    return state
