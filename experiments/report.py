"""A sweep's ``summary.csv``, PNG plots and ``report.md`` (table, the study's finding, and
whether this run agrees)."""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from pathlib import Path

from experiments.aggregate import (
    SUMMARY_COLUMNS,
    SeedRun,
    load_runs,
    summarize_config,
    write_summary,
)
from experiments.grid import CLOSE, Claim, Grid

CURVES = (  # (file, x, y or None for the grid's metric, what it shows)
    ("return_vs_updates.png", "update", None, "against network updates"),
    ("return_vs_wall_time.png", "wall_time", None, "against wall time"),
    ("episode_length.png", "update", "episode_length", "against network updates"),
)


def settings_text(grid: Grid, name: str, scale: str) -> str:
    """What distinguishes a configuration: its own overrides at this scale."""
    s = grid.scale(scale)
    own = {**grid.configs[name], **s.get("override", {}).get(name, {})}
    return " ".join(f"{k}={_value(v)}" for k, v in own.items()) or "(base)"


def _value(v) -> str:
    return " ".join(map(str, v)) if isinstance(v, tuple) else str(v)


def check_claim(claim: Claim, rows: dict[str, dict]) -> tuple[bool | None, float, float]:
    """(agrees?, value of a, value of b); agrees is None when either value is missing."""
    a = rows.get(claim.a, {}).get(claim.column, math.nan)
    b = rows.get(claim.b, {}).get(claim.column, math.nan)
    if not (isinstance(a, float) and isinstance(b, float)) or math.isnan(a) or math.isnan(b):
        return None, a, b
    ok = {">": a > b, "<": a < b, "~": abs(a - b) <= CLOSE}[claim.op]
    return ok, a, b


def build_report(grid: Grid, scale: str, out: Path, seeds: Sequence[int],
                 command: str = "") -> Path:
    """Write summary.csv, the PNGs and report.md under ``out``; return the report's path."""
    out = Path(out)
    names = grid.config_names(scale)
    runs = load_runs(out, names, seeds)
    rows = [summarize_config(n, settings_text(grid, n, scale), runs[n]) for n in names]
    write_summary(rows, out / "summary.csv")
    pngs = make_plots(grid, runs, rows, out)
    text = render(grid, scale, seeds, rows, pngs, command)
    (out / "report.md").write_text(text)
    return out / "report.md"


def make_plots(grid: Grid, runs: dict[str, list[SeedRun]], rows: list[dict],
               out: Path) -> list[tuple[str, str]]:
    """(file, caption) of every PNG written; none if matplotlib is missing."""
    try:
        from experiments import plots
    except ImportError:
        return []
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return []
    made = []
    for fname, x, y, what in CURVES:
        y = y or grid.metric
        title = f"{grid.name}: {plots.LABELS.get(y, y)}, {what}"
        if plots.curves_png(runs, x, y, title, out / fname):
            made.append((fname, title))
    for y in grid.extra_plots:
        fname = f"{y}.png"
        title = f"{grid.name}: {plots.LABELS.get(y, y)}"
        if plots.curves_png(runs, "update", y, title, out / fname):
            made.append((fname, title))
    title = f"{grid.name}: network updates per second (mean over seeds)"
    if plots.bar_png([r["config"] for r in rows], [r["updates_per_s"] for r in rows],
                     "updates / s", title, out / "updates_per_s.png"):
        made.append(("updates_per_s.png", title))
    return made


def _num(v, fmt="{:.3f}") -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v)


def _final_cell(row: dict, key: str) -> str:
    mean, std = row.get(f"final_{key}_mean"), row.get(f"final_{key}_std", math.nan)
    if mean is None or math.isnan(mean):
        return "–"
    text = _num(mean)
    if std is not None and not math.isnan(std):
        text += f" ± {std:.3f}"
    if f"final_{key}_min" in row and row["seeds"] > 1:
        text += f" [{row[f'final_{key}_min']:.3f}, {row[f'final_{key}_max']:.3f}]"
    return text


def render(grid: Grid, scale: str, seeds: Sequence[int], rows: list[dict],
           pngs: list[tuple[str, str]], command: str) -> str:
    note = grid.scale(scale).get("note", "")
    eval_col = grid.metric == "eval_return"
    lines = [f"# {grid.title}", "",
             f"- grid: `{grid.name}`, scale: **{scale}**" + (f" ({note})" if note else ""),
             f"- seeds: {', '.join(map(str, seeds))}",
             f"- generated: {time.strftime('%Y-%m-%d %H:%M')}"]
    if command:
        lines.append(f"- reproduce / continue: `{command}`")
    lines += ["", "## Results", "",
              "Final = each seed's last logged rolling mean (last 100 finished episodes), then "
              "mean ± sample std [min, max] over seeds.", ""]
    phase_col = any(math.isfinite(r.get("hardest_phase_mean", math.nan)) for r in rows)
    head = ["config", "settings", "seeds (finished)", "final return"]
    if eval_col:
        head += ["final eval return", "best eval return"]
    if phase_col:
        head.append("hardest phase reached (schedule: rooms)")
    head += ["final ep. length", "updates", "wall time", "updates/s", "replay ratio",
             "sampled reward"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [f"`{r['config']}`", r["settings"], f"{r['seeds']} ({r['finished']})",
                 _final_cell(r, "return")]
        if eval_col:
            cells += [_final_cell(r, "eval_return"), _num(r["best_eval_return_mean"])]
        if phase_col:
            cells.append(_num(r["hardest_phase_mean"], "{:.1f}"))
        cells += [_num(r["final_length_mean"], "{:.0f}"), _num(r["updates"], "{:.0f}"),
                  _num(r["wall_time_s"] / 60 if r["seeds"] else math.nan, "{:.1f} min"),
                  _num(r["updates_per_s"], "{:.1f}"), _num(r["replay_ratio"]),
                  _num(r["sampled_reward_mean"], "{:.4f}")]
        lines.append("| " + " | ".join(map(str, cells)) + " |")
    incomplete = [r["config"] for r in rows if r["finished"] < len(seeds)]
    lines += ["", "## What the study found", "", grid.finding, "",
              "## Does this run agree?", ""]
    by_name = {r["config"]: r for r in rows}
    for claim in grid.claims:
        if claim.a not in by_name or claim.b not in by_name:
            lines.append(f"- {claim.text}: **n/a** (not run at scale {scale})")
            continue
        ok, a, b = check_claim(claim, by_name)
        verdict = {True: "**yes**", False: "**no**", None: "**n/a** (no data)"}[ok]
        within = f", claim: within {CLOSE}" if claim.op == "~" else ""
        lines.append(f"- {claim.text}: {verdict} ({claim.a} {_num(a)} vs "
                     f"{claim.b} {_num(b)}; `{claim.column}`{within})")
    if incomplete:
        lines += ["", f"Not all runs finished ({', '.join(incomplete)}): the verdicts use what "
                  "was logged so far."]
    if scale != "paper":
        lines += ["", f"At scale `{scale}` the verdicts are indicative only; the study's "
                  "numbers come from its settings (`SCALE=paper`) averaged over 20-30 seeds."]
    if pngs:
        lines += ["", "## Plots", ""]
        for fname, title in pngs:
            lines += [f"![{title}]({fname})", ""]
    else:
        lines += ["", "(No plots: install the `plot` extra, `pip install -e .[plot]`.)"]
    return "\n".join(lines).rstrip() + "\n"


__all__ = ["build_report", "check_claim", "SUMMARY_COLUMNS"]
