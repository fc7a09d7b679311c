"""PNG figures of a sweep (matplotlib, the ``plot`` extra): learning curves with a min-max band
across seeds, and a bar chart of updates per second."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from experiments.aggregate import SeedRun, curve

LABELS = {
    "episode_return": "mean episode return (training actors)",
    "eval_return": "mean evaluation return (full task)",
    "episode_length": "mean episode length (steps)",
    "sampled_reward": "mean reward of sampled batches",
    "phase": "curriculum phase / room count",
    "update": "network updates",
    "wall_time": "wall time (minutes)",
}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def curves_png(runs: dict[str, list[SeedRun]], x: str, y: str, title: str, path: Path) -> bool:
    """One line per configuration (mean over seeds) with its min-max band; False if no data."""
    curves = {name: curve(rs, x, y) for name, rs in runs.items() if rs}
    curves = {k: c for k, c in curves.items() if c.x.size}
    if not curves:
        return False
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.8), dpi=110)
    scale = 60.0 if x == "wall_time" else 1.0
    for i, (name, c) in enumerate(curves.items()):
        color = plt.get_cmap("tab10")(i % 10)
        seeds = f" ({c.n} seeds)" if c.n != 1 else ""
        ax.plot(c.x / scale, c.mean, color=color, lw=2, label=f"{name}{seeds}",
                marker="o" if c.x.size == 1 else None)
        if c.n > 1:
            ax.fill_between(c.x / scale, c.min, c.max, color=color, alpha=0.18, lw=0)
    ax.set_xlabel(LABELS.get(x, x))
    ax.set_ylabel(LABELS.get(y, y))
    seeds = max(c.n for c in curves.values())
    band = "line: mean, band: min-max over seeds" if seeds > 1 else "one seed per line"
    ax.set_title(f"{title}\n{band}", fontsize=10)
    if y in ("episode_return", "eval_return"):
        ax.set_ylim(-0.03, 1.03)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


def bar_png(names: Sequence[str], values: Sequence[float], ylabel: str, title: str,
            path: Path) -> bool:
    keep = [(n, v) for n, v in zip(names, values) if math.isfinite(v)]
    if not keep:
        return False
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(max(5, 1.1 * len(keep) + 2), 4.2), dpi=110)
    colors = [plt.get_cmap("tab10")(names.index(n) % 10) for n, _ in keep]
    bars = ax.bar([n for n, _ in keep], [v for _, v in keep], color=colors)
    ax.bar_label(bars, fmt="%.3g", fontsize=8)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.tick_params(axis="x", labelrotation=20, labelsize=8)
    ax.grid(axis="y", alpha=0.3)
    ax.margins(y=0.12)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True
