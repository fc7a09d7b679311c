"""Across seeds: load each run's metrics.csv, align seeds on a common grid, summarise configs.

Definitions (the tests check them by hand):

- a seed's **final** value of a column is its last non-empty value (``episode_return`` is already
  the rolling mean of the last finished episodes, so this is "the mean return at the end");
- a configuration's ``final_<x>_mean`` / ``_std`` / ``_min`` / ``_max`` are over its seeds'
  final values; std is the sample standard deviation (ddof = 1; empty for one seed);
- ``early_return_mean`` is the mean over seeds of each seed's ``episode_return`` at the first
  logged row at or after a quarter of its last update (for "learns faster early" findings);
- ``best_eval_return_mean`` is the mean over seeds of each seed's highest evaluation return
  (a task learned for a while and forgotten, or learned only at the end, still shows);
  ``hardest_phase_mean`` the mean over seeds of the hardest curriculum phase each seed reached
  (the lowest phase number above 0; under the room schedule the most rooms; empty without
  either);
- rate columns (``updates_per_s``, ``env_steps_per_s``) and ``sampled_reward_mean`` are the
  mean over seeds of each seed's mean over its rows; ``updates``, ``wall_time_s`` and
  ``replay_ratio`` are the mean over seeds of each seed's last value;
- curves: each seed is linearly interpolated onto ``points`` evenly spaced x values spanning the
  range every seed covers (from the latest first value to the earliest last value), then mean,
  std, min and max are taken per x.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dqn_mine.metrics import read_metrics

SUMMARY_COLUMNS = (
    "config", "settings", "seeds", "finished", "updates", "wall_time_s", "updates_per_s",
    "env_steps_per_s", "replay_ratio",
    "final_return_mean", "final_return_std", "final_return_min", "final_return_max",
    "final_length_mean", "final_eval_return_mean", "final_eval_return_std",
    "early_return_mean", "sampled_reward_mean", "best_eval_return_mean", "hardest_phase_mean",
)
FINALS = {"return": "episode_return", "length": "episode_length", "eval_return": "eval_return"}


@dataclass
class SeedRun:
    """One run folder's table (columns as float arrays sorted by update), summary.json and
    the run's --curriculum (from config.json)."""

    config: str
    seed: int
    columns: dict[str, np.ndarray]
    summary: dict
    curriculum: str = "none"

    @property
    def finished(self) -> bool:
        return self.summary.get("exit_code") == 0


@dataclass
class Curve:
    """A configuration's metric on a common x grid: per-x statistics over ``n`` seeds."""

    x: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    min: np.ndarray
    max: np.ndarray
    n: int


def load_run(run_dir: Path, config: str, seed: int) -> SeedRun | None:
    """The run's metrics (None if it has no rows yet). A resumed run may repeat updates that
    were logged after its last checkpoint: the later row wins."""
    path = Path(run_dir) / "metrics.csv"
    if not path.exists():
        return None
    rows = read_metrics(path)
    if not rows:
        return None
    by_update = {row["update"]: row for row in rows}
    ordered = [by_update[u] for u in sorted(by_update)]
    columns = {k: np.array([r[k] for r in ordered], dtype=float) for k in ordered[0]}
    summary = _read_json(Path(run_dir) / "summary.json")
    curriculum = str(_read_json(Path(run_dir) / "config.json").get("curriculum", "none"))
    return SeedRun(config, seed, columns, summary, curriculum)


def _read_json(path: Path) -> dict:
    """A run folder's JSON file, or {} while it is missing or half written."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def load_runs(out: Path, configs: Sequence[str], seeds: Sequence[int]) -> dict[str, list[SeedRun]]:
    """``{config: [SeedRun, ...]}`` for the runs under ``out/<config>/seed<k>`` that have data."""
    found: dict[str, list[SeedRun]] = {}
    for name in configs:
        runs = [load_run(Path(out) / name / f"seed{s}", name, s) for s in seeds]
        found[name] = [r for r in runs if r is not None]
    return found


def last_finite(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(finite[-1]) if finite.size else math.nan


def early_value(run: SeedRun, col: str = "episode_return", share: float = 0.25) -> float:
    """``col`` at the first row at or after ``share`` of the run's last update."""
    updates, values = run.columns["update"], run.columns[col]
    ok = np.isfinite(updates) & np.isfinite(values)
    if not ok.any():
        return math.nan
    updates, values = updates[ok], values[ok]
    return float(values[np.argmax(updates >= share * updates[-1])])


def max_finite(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(finite.max()) if finite.size else math.nan


def hardest_phase(run: SeedRun) -> float:
    """The lowest curriculum phase above 0 the run logged, or under the room schedule (whose
    ``phase`` column is the room count) the most rooms; NaN without either."""
    phases = run.columns.get("phase", np.array([]))
    phases = phases[np.isfinite(phases) & (phases > 0)]
    if not phases.size:
        return math.nan
    return float(phases.max() if run.curriculum == "schedule" else phases.min())


def mean_finite(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if finite.size else math.nan


def _mean(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return sum(finite) / len(finite) if finite else math.nan


def _stats(values: Sequence[float]) -> dict[str, float]:
    v = np.array([x for x in values if math.isfinite(x)], dtype=float)
    if not v.size:
        return {"mean": math.nan, "std": math.nan, "min": math.nan, "max": math.nan}
    return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if v.size > 1 else math.nan,
            "min": float(v.min()), "max": float(v.max())}


def align(xs: Sequence[np.ndarray], ys: Sequence[np.ndarray], points: int = 100) -> Curve:
    """Seeds' (x, y) series -> statistics on a common grid (see the module docstring)."""
    pairs = []
    for x, y in zip(xs, ys):
        ok = np.isfinite(x) & np.isfinite(y)
        if ok.any():
            pairs.append((x[ok], y[ok]))
    empty = np.array([])
    if not pairs:
        return Curve(empty, empty, empty, empty, empty, 0)
    lo, hi = max(x[0] for x, _ in pairs), min(x[-1] for x, _ in pairs)
    if lo > hi:  # the seeds share no x range (e.g. one is far behind): nothing to compare
        return Curve(empty, empty, empty, empty, empty, len(pairs))
    grid = np.linspace(lo, hi, points) if hi > lo else np.array([lo])
    table = np.stack([np.interp(grid, x, y) for x, y in pairs])  # [seeds, points]
    std = table.std(axis=0, ddof=1) if len(pairs) > 1 else np.full(grid.shape, math.nan)
    return Curve(grid, table.mean(axis=0), std, table.min(axis=0), table.max(axis=0), len(pairs))


def curve(runs: Sequence[SeedRun], x: str, y: str, points: int = 100) -> Curve:
    return align([r.columns[x] for r in runs], [r.columns[y] for r in runs], points)


def summarize_config(name: str, settings: str, runs: Sequence[SeedRun]) -> dict[str, object]:
    """One summary.csv row (see the module docstring for each definition)."""
    row: dict[str, object] = {"config": name, "settings": settings, "seeds": len(runs),
                              "finished": sum(r.finished for r in runs)}
    row["updates"] = _mean([last_finite(r.columns["update"]) for r in runs])
    row["wall_time_s"] = _mean([last_finite(r.columns["wall_time"]) for r in runs])
    for col in ("updates_per_s", "env_steps_per_s"):
        row[col] = _mean([mean_finite(r.columns[col]) for r in runs])
    row["replay_ratio"] = _mean([last_finite(r.columns["replay_ratio"]) for r in runs])
    for short, col in FINALS.items():
        stats = _stats([last_finite(r.columns[col]) for r in runs])
        for k, v in stats.items():
            key = f"final_{short}_{k}"
            if key in SUMMARY_COLUMNS:
                row[key] = v
    row["early_return_mean"] = _mean([early_value(r) for r in runs])
    row["sampled_reward_mean"] = _mean([mean_finite(r.columns["sampled_reward"]) for r in runs])
    row["best_eval_return_mean"] = _mean([max_finite(r.columns["eval_return"]) for r in runs])
    row["hardest_phase_mean"] = _mean([hardest_phase(r) for r in runs])
    return row


def write_summary(rows: Sequence[dict[str, object]], path: Path) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=SUMMARY_COLUMNS)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _cell(row.get(k)) for k in SUMMARY_COLUMNS})


def _cell(value) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)
