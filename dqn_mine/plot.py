"""Learning curves of one or more runs: `python -m dqn_mine.plot RUN_DIR [RUN_DIR ...]`.

Writes one PNG (default ``<first run>/curves.png``) with the mean episode return of the training
actors (and, dotted, of those of their envs that play at epsilon <= 0.01) and, where logged, of
the evaluation actor, against network updates and against wall time;
a curriculum run gets its phase (or room count) in a third panel. Needs matplotlib (the ``plot``
extra). ``--milestones 0.5 0.9`` prints instead when each run's full-task rolling return first
reached each level (updates and minutes), as a markdown table; ``--phases`` when each run
entered each curriculum phase, how long it stayed and its mean rolling return there.
``--band`` treats the runs as seeds of one configuration and draws their full-task rolling
return as a median with a min-max band (0 until a curriculum run reaches the full task). Sweeps
over many runs and seeds have their own plots: ``python -m experiments report``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from dqn_mine.config import Config, ConfigError
from dqn_mine.exitcodes import EXIT_BAD_INPUT
from dqn_mine.metrics import LOW_EPSILON, RETURN_WINDOW, read_metrics


def load_run(run_dir: Path) -> list[dict]:
    """The metrics rows of a run folder; a one-line ValueError when there are none."""
    path = Path(run_dir) / "metrics.csv"
    if not path.is_file():
        raise ValueError(f"no metrics.csv in {run_dir}")
    rows = read_metrics(path)
    if not rows:
        raise ValueError(f"{path} has no rows yet")
    return rows


def column(rows: list[dict], name: str) -> list[float]:
    return [r.get(name, math.nan) for r in rows]


def has_values(rows: list[dict], name: str) -> bool:
    return any(not math.isnan(v) for v in column(rows, name))


# The settings the figures read: a run that this version can no longer continue (it used a
# setting since removed) is still plotted from them.
PLOT_SETTINGS = ("curriculum", "curriculum_window", "curriculum_review")
# Curricula that start episodes in phases; "boulders" (three-room's 23-phase table) is gone, but
# docs/run_data keeps its runs.
PHASED = ("adaptive", "boulders")


def run_config(path: Path) -> Config:
    """A run's config.json, or, for a run of a removed setting, the settings the plot reads."""
    import json

    try:
        return Config.from_json(path)
    except ConfigError:
        saved = json.loads(path.read_text())
        return Config(**{name: saved[name] for name in PLOT_SETTINGS if name in saved})


def full_task_returns(rows: list[dict], cfg, low_eps: bool = False) -> list[tuple]:
    """(update, minutes, return) of the rows whose return is the full task's over a full window.

    With the adaptive curriculum that is phase 1's ``phase_return`` (its own episodes only, no
    reviewed ones) from the row by which about ``curriculum_window`` phase-1 episodes have ended
    (estimated from the episode count since the switch and the review share, since the table
    does not count them); without it the actors' ``episode_return`` once ``RETURN_WINDOW``
    episodes have ended. ``low_eps``: the same rows' means over the episodes played at epsilon
    <= 0.01 (``phase_low_eps_return``, ``low_eps_return``)."""
    if cfg.curriculum == "backward":   # its own column, over episodes begun at the real start
        return [(r["update"], r["wall_time"] / 60, r["full_task_return"]) for r in rows
                if r.get("full_task_episodes", 0) >= RETURN_WINDOW and not low_eps]
    if cfg.curriculum not in PHASED:
        key = "low_eps_return" if low_eps else "episode_return"
        return [(r["update"], r["wall_time"] / 60, r.get(key, math.nan)) for r in rows
                if r["episodes"] >= RETURN_WINDOW]
    key = "phase_low_eps_return" if low_eps else "phase_return"
    full = [r for r in rows if r["phase"] == 1]
    if not full:
        return []
    start = full[0]["episodes"]
    share = 1.0 - cfg.curriculum_review
    return [(r["update"], r["wall_time"] / 60, r.get(key, math.nan)) for r in full
            if (r["episodes"] - start) * share >= cfg.curriculum_window]


def milestones(rows: list[dict], cfg, levels) -> dict:
    """level -> (updates, minutes) when the full-task rolling return first reached it, or None."""
    return first_reached(full_task_returns(rows, cfg), levels)


def first_reached(points: list[tuple[float, float, float]], levels) -> dict:
    return {level: next(((u, m) for u, m, ret in points if ret >= level), None)
            for level in levels}


def milestone_table(runs: dict, configs: dict, levels) -> str:
    """Markdown: one row per run, updates and minutes to each level (- when never reached), the
    last full-task return, and (where logged) that of the envs at epsilon <= 0.01."""
    low_eps = any(has_values(rows, "low_eps_return") for rows in runs.values())
    evaluated = any(has_values(rows, "eval_return") for rows in runs.values())
    head = " | ".join(f"return {lv:g}: updates, minutes" for lv in levels)
    extra = f" | last at epsilon <= {LOW_EPSILON:g}" if low_eps else ""
    if evaluated:
        extra += "".join(f" | evaluation {lv:g}: updates, minutes" for lv in levels)
        extra += " | last evaluation"
    columns = len(levels) * (1 + evaluated) + 2 + low_eps + evaluated
    lines = [f"| run | {head} | last full-task return{extra} |", "|---" * columns + "|"]
    for label, rows in runs.items():
        points = full_task_returns(rows, configs[label])
        cells = _reached_cells(points, levels) + [_last(points)]
        if low_eps:
            cells.append(_last(full_task_returns(rows, configs[label], low_eps=True)))
        if evaluated:
            evals = [(r["update"], r["wall_time"] / 60, r["eval_return"]) for r in rows
                     if not math.isnan(r.get("eval_return", math.nan))]
            cells += _reached_cells(evals, levels) + [_last(evals)]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _reached_cells(points: list[tuple], levels) -> list[str]:
    """"updates, minutes" of the first point at or above each level ("-" when never)."""
    return [f"{int(v[0]):,}, {v[1]:.1f}" if v else "-"
            for v in first_reached(points, levels).values()]


def phase_starts(rows: list[dict]) -> dict:
    """phase -> (update, minutes) of the first row logged in it (its start, to a log row)."""
    starts: dict = {}
    for r in rows:
        phase = r.get("phase", math.nan)
        if not math.isnan(phase) and int(phase) not in starts:
            starts[int(phase)] = (r["update"], r["wall_time"] / 60)
    return starts


def phase_table(runs: dict) -> str:
    """Markdown: one row per run, the updates and minutes at which it entered each phase."""
    starts = {label: phase_starts(rows) for label, rows in runs.items()}
    phases = sorted({p for s in starts.values() for p in s}, reverse=True)
    lines = ["| run | " + " | ".join(f"phase {p}: updates, minutes" for p in phases) + " |",
             "|---" * (len(phases) + 1) + "|"]
    for label, s in starts.items():
        cells = [f"{int(s[p][0]):,}, {s[p][1]:.1f}" if p in s else "-" for p in phases]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def phase_stays(rows: list[dict]) -> list[tuple]:
    """(phase, minutes entered, minutes there, mean rolling return there, the same at epsilon <=
    0.01) for each stay in a phase, in order: the mean over the log rows while in it, which
    varies far less between runs than when a phase is passed (a lucky window decides that)."""
    stays: list[list] = []
    for r in rows:
        phase = r.get("phase", math.nan)
        if math.isnan(phase):
            continue
        if not stays or stays[-1][0] != int(phase):
            stays.append([int(phase), r["wall_time"] / 60, []])
        stays[-1][2].append(r)
    ends = [s[1] for s in stays[1:]] + [rows[-1]["wall_time"] / 60] if stays else []
    return [(phase, start, end - start, _mean(column(there, "phase_return")),
             _mean(column(there, "phase_low_eps_return")))
            for (phase, start, there), end in zip(stays, ends)]


def _mean(values: list[float]) -> float:
    kept = [v for v in values if not math.isnan(v)]
    return sum(kept) / len(kept) if kept else math.nan


def stay_table(runs: dict) -> str:
    """Markdown: one row per stay of each run in a phase (``phase_stays``)."""
    lines = ["| run | phase | entered (min) | minutes there | mean rolling return there | "
             f"the same at epsilon <= {LOW_EPSILON} |", "|---|---:|---:|---:|---:|---:|"]
    for label, rows in runs.items():
        for phase, start, there, mean, low in phase_stays(rows):
            lines.append(f"| {label} | {phase} | {start:.1f} | {there:.1f} | "
                         f"{_num(mean)} | {_num(low)} |")
    return "\n".join(lines)


def _num(value: float) -> str:
    return "-" if math.isnan(value) else f"{value:.2f}"


def _last(points: list[tuple]) -> str:
    """The last point's return, 2 decimals ("-" with none or NaN)."""
    return _num(points[-1][2]) if points else "-"


def band(curves: list[list[tuple[float, float]]], grid) -> tuple[list, list, list]:
    """Min, median and max over runs of step curves [(x, value), ...] at each ``grid`` x.

    A run's value at x is its last point at or before x, 0 before its first point (it had not
    reached the full task) and absent after its last (it had stopped); x where no run has a
    value gets NaN."""
    import numpy as np

    lo, mid, hi = [], [], []
    for x in grid:
        values = [next((v for px, v in reversed(c) if px <= x), 0.0) for c in curves
                  if c and x <= c[-1][0]]
        values = [v for v in values if not math.isnan(v)]
        lo.append(min(values) if values else math.nan)
        mid.append(float(np.median(values)) if values else math.nan)
        hi.append(max(values) if values else math.nan)
    return lo, mid, hi


def plot_band(runs: dict, configs: dict, out: Path, levels=(0.5, 0.9)) -> Path:
    """Seeds of one configuration: each run's full-task rolling return (thin), their median
    and min-max band, against updates and minutes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, axes = plt.subplots(1, 2, figsize=(10.4, 3.8), dpi=110)
    for ax, index, xlabel in ((axes[0], 0, "network updates"), (axes[1], 1, "wall time (minutes)")):
        curves = {}
        for label, rows in runs.items():
            ends = rows[-1]["update"] if index == 0 else rows[-1]["wall_time"] / 60
            points = [(p[index], p[2]) for p in full_task_returns(rows, configs[label])]
            start = [(0.0, 0.0), (points[0][0], 0.0)] if points else [(0.0, 0.0)]
            curves[label] = start + points + [(ends, points[-1][1] if points else 0.0)]
            ax.plot(*zip(*curves[label]), lw=0.8, alpha=0.6, label=label)
        grid = np.linspace(0, max(c[-1][0] for c in curves.values()), 400)
        lo, mid, hi = band(list(curves.values()), grid)
        # grey band and black median so neither is mistaken for a seed's own colour
        ax.fill_between(grid, lo, hi, color="grey", alpha=0.2, lw=0,
                        label=f"min-max of {len(runs)} runs")
        ax.plot(grid, mid, color="black", lw=2.0, label="median")
        for level in levels:
            ax.axhline(level, color="grey", lw=0.8, ls=":")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("full-task rolling return")
        ax.set_ylim(-0.03, 1.03)
        ax.grid(alpha=0.3)
    _label_updates(axes[0])
    return _save(fig, axes[0], out, legend_size=7)


def _label_updates(ax) -> None:
    """Update counts as 50k, 100k, ...: six-digit tick labels run into each other."""
    import matplotlib.ticker

    ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(
        lambda value, _: f"{value / 1000:g}k" if value else "0"))


def _save(fig, legend_axis, out: Path, legend_size: int, handles=None) -> Path:
    """Legend on ``legend_axis`` (or ``handles`` below the panels), tight layout, write
    ``out`` (folders made) and close."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    if handles is None:
        legend_axis.legend(fontsize=legend_size)
        fig.savefig(_out_path(out))
    else:   # below the panels: with several runs a legend inside one hides its curves
        legend = fig.legend(handles=handles, fontsize=legend_size, loc="upper center",
                            bbox_to_anchor=(0.5, 0.0), ncol=min(4, len(handles)),
                            frameon=False)
        fig.savefig(_out_path(out), bbox_extra_artists=(legend,), bbox_inches="tight")
    plt.close(fig)
    return out


def _out_path(out: Path) -> Path:
    out.parent.mkdir(parents=True, exist_ok=True)
    return out


def _backward(rows: list[dict]) -> bool:
    """Whether a run started episodes on the expert's path (its starts' share below 1)."""
    return any(v < 1 for v in column(rows, "start_share"))


def _phased(rows: list[dict]) -> bool:
    """Whether a run's curriculum has phases or room counts (not backward, not none)."""
    return not _backward(rows) and any(column(rows, "phase"))


def _plot_progress(ax, rows: list[dict], color, label: str) -> None:
    """A run's curriculum in the third panel: the phase or room count, or for the backward
    curriculum its starts' share of the solution (1: the full task) on a right-hand axis, as
    its frontier counts expert steps, not phases."""
    if _phased(rows):
        ax.step(column(rows, "update"), column(rows, "phase"), where="post", color=color, lw=2,
                label=label)
        return
    if not _backward(rows):   # no curriculum: nothing to draw here
        return
    if not hasattr(ax, "share_axis"):
        ax.share_axis = ax.twinx()
        ax.share_axis.set_ylabel("backward: start, share of the solution")
        ax.share_axis.set_ylim(-0.03, 1.03)
    ax.share_axis.plot(column(rows, "update"), column(rows, "start_share"), color=color, lw=2,
                       label=f"{label} (start share)")


def plot_runs(runs: dict, out: Path) -> Path:
    """runs: label -> metrics rows. One figure, return panels side by side (+ phase panel)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.lines
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    curriculum = any(has_values(rows, "phase") and len(set(column(rows, "phase"))) > 1
                     for rows in runs.values())
    panels = 3 if curriculum else 2
    fig, axes = plt.subplots(1, panels, figsize=(5.2 * panels, 3.8), dpi=110)
    handles, styles_used = [], set()
    for i, (label, rows) in enumerate(runs.items()):
        color = plt.get_cmap("tab10")(i % 10)
        handles.append(matplotlib.lines.Line2D([], [], color=color, lw=2, label=label))
        for ax, x, scale in ((axes[0], "update", 1.0), (axes[1], "wall_time", 60.0)):
            xs = [v / scale for v in column(rows, x)]
            for name, style in _curves(rows).items():
                ax.plot(xs, column(rows, name), color=color, **style)
                styles_used.add(name)
        if curriculum:
            _plot_progress(axes[2], rows, color, label)
    handles += [matplotlib.lines.Line2D([], [], color="black", label=CURVES[name][0],
                                        **CURVES[name][1])
                for name in CURVES if name in styles_used]
    for ax, xlabel in zip(axes, ("network updates", "wall time (minutes)")):
        ax.set_xlabel(xlabel)
        ax.set_ylabel("mean episode return")
        ax.set_ylim(-0.03, 1.03)
    if curriculum:
        axes[2].set_xlabel("network updates")
        if not any(_phased(rows) for rows in runs.values()):   # only the right axis
            axes[2].set_yticks([])
        else:
            axes[2].set_ylabel("curriculum phase / room count")
            axes[2].yaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
        _label_updates(axes[2])
    _label_updates(axes[0])
    for ax in axes:
        ax.grid(alpha=0.3)
    return _save(fig, axes[0], out, legend_size=8, handles=handles)


# A run's curves in the return panels: the run's colour, one line style each.
CURVES = {
    "episode_return": ("training episodes", {"lw": 2}),
    "low_eps_return": (f"envs at epsilon <= {LOW_EPSILON:g}", {"lw": 1.2, "ls": ":"}),
    "full_task_return": ("training episodes begun at the real start", {"lw": 1.2, "ls": "-."}),
    "eval_return": ("evaluation, full task", {"lw": 1.5, "ls": "--"}),
}


def _curves(rows: list[dict]) -> dict[str, dict]:
    """The curves a run has: older runs lack ``low_eps_return``; only backward runs start
    episodes elsewhere than at the real start."""
    has = {"episode_return": True, "low_eps_return": has_values(rows, "low_eps_return"),
           "full_task_return": _backward(rows), "eval_return": has_values(rows, "eval_return")}
    return {name: CURVES[name][1] for name in CURVES if has[name]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m dqn_mine.plot",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="run folders (each with metrics.csv)")
    ap.add_argument("--out", default=None, help="PNG to write (default <first run>/curves.png)")
    ap.add_argument("--milestones", type=float, nargs="+", metavar="RETURN", default=None,
                    help="print when the full-task rolling return first reached each level "
                         "instead of plotting")
    ap.add_argument("--phases", action="store_true",
                    help="print when each run entered each curriculum phase, how long it "
                         "stayed and its mean rolling return there, instead of plotting")
    ap.add_argument("--band", action="store_true",
                    help="the runs are seeds of one configuration: plot their full-task "
                         "rolling return as median and min-max band")
    args = ap.parse_args(argv)
    try:
        runs = {Path(d).name: load_run(Path(d)) for d in args.runs}
        configs = {}
        if args.milestones or args.band:
            configs = {Path(d).name: run_config(Path(d) / "config.json") for d in args.runs}
        if args.milestones:
            print(milestone_table(runs, configs, args.milestones))
            return 0
        if args.phases:
            print(phase_table(runs) + "\n\n" + stay_table(runs))
            return 0
        import matplotlib  # noqa: F401
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except ImportError:
        print("error: plotting needs matplotlib: pip install -e .[plot]", file=sys.stderr)
        return EXIT_BAD_INPUT
    out = Path(args.out) if args.out else Path(args.runs[0]) / "curves.png"
    out = plot_band(runs, configs, out) if args.band else plot_runs(runs, out)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
