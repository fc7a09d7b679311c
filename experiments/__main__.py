"""``python -m experiments``: run a grid sweep and write its report.

Examples::

    python -m experiments list
    python -m experiments run ablation --scale quick            # results/ablation/
    python -m experiments run nstep --scale paper --seeds 20 --jobs 2 --out results/nstep-paper
    python -m experiments run ablation --scale quick --dry-run  # the commands, nothing run
    python -m experiments report ablation --scale quick         # re-aggregate and re-plot

Exit codes: 0 every run complete, 1 a run failed or conflicts with its folder, 2 bad input,
130 interrupted (run the same command again to continue).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path

from dqn_mine.config import ConfigError
from dqn_mine.exitcodes import EXIT_BAD_INPUT
from experiments.grid import SCALES, grid_names, load_grid
from experiments.launcher import EXIT_INTERRUPTED, Sweep, run_state, sweep_exit_code, train_command
from experiments.report import build_report

PROG = "python -m experiments"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="the grids and their configurations")
    for name, text in (("run", "run a sweep (skipping complete runs), then write its report"),
                       ("report", "aggregate and plot what a sweep has logged so far")):
        p = sub.add_parser(name, help=text)
        p.add_argument("grid", help="grid file under experiments/grids/ (see `list`)")
        p.add_argument("--scale", default="auto", choices=("auto",) + SCALES,
                       help="paper: the study's settings; quick: about an hour on 2 CPU cores; "
                            "smoke: minutes; auto: paper with CUDA, else quick (default: auto)")
        p.add_argument("--seeds", type=int, default=None,
                       help="number of seeds, 0..N-1 (default: the grid's for the scale)")
        p.add_argument("--seed-list", type=int, nargs="+", default=None, metavar="SEED",
                       help="explicit seeds instead of --seeds")
        p.add_argument("--out", default=None, help="output folder (default: results/<grid>/)")
        if name == "run":
            p.add_argument("--configs", nargs="+", default=None, metavar="NAME",
                           help="run only these configurations (default: all of the grid's; "
                                "the report still lists every one)")
            p.add_argument("--jobs", type=int, default=1,
                           help="runs at a time, never more busy processes than cores unless a "
                                "run alone needs more (default: 1)")
            p.add_argument("--cores", type=int, default=None,
                           help="cores to fill (default: all of this machine's)")
            p.add_argument("--dry-run", action="store_true",
                           help="print each run's state and command, run nothing")
            p.add_argument("--no-progress", dest="progress", action="store_false",
                           help="no progress bar over runs")
    return parser


def resolve_scale(scale: str) -> str:
    """``auto``: the study's settings where a GPU can carry them, else the 2-core reduction."""
    if scale != "auto":
        return scale
    import torch

    return "paper" if torch.cuda.is_available() else "quick"


def seeds_of(args, grid) -> list[int]:
    if args.seed_list is not None:
        return list(dict.fromkeys(args.seed_list))   # a seed given twice is one run
    n = grid.default_seeds(args.scale) if args.seeds is None else args.seeds
    if n < 1:
        raise ConfigError(f"--seeds must be at least 1, got {n}")
    return list(range(n))


def only_configs(specs: list, names: Sequence[str], known: Sequence[str]) -> list:
    """The runs of the named configurations, in the order named (a sweep split over sessions
    or machines, the most telling first)."""
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ConfigError(f"--configs: unknown configuration {unknown[0]!r} "
                          f"(choose from {', '.join(known)})")
    return [spec for name in dict.fromkeys(names) for spec in specs if spec.config_name == name]


def cmd_list() -> int:
    for name in grid_names():
        grid = load_grid(name)
        print(f"{name}: {grid.title}")
        for scale in filter(grid.has_scale, SCALES):
            print(f"  {scale:<6} {grid.default_seeds(scale)} seed(s) x "
                  f"{', '.join(grid.config_names(scale))}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
        if args.command == "list":
            return cmd_list()
        grid = load_grid(args.grid)
        args.scale = resolve_scale(args.scale)
        seeds = seeds_of(args, grid)
        out = Path(args.out or f"results/{grid.name}")
        specs = grid.expand(args.scale, out, seeds)
        if args.command == "run" and args.configs:
            specs = only_configs(specs, args.configs, grid.config_names(args.scale))
    except ConfigError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    command = f"{PROG} run {grid.name} --scale {args.scale} --seed-list " \
              f"{' '.join(map(str, seeds))} --out {shlex.quote(str(out))}"
    if args.command == "run" and args.configs:
        command += " --configs " + " ".join(map(shlex.quote, dict.fromkeys(args.configs)))
    conflicts = [f"{spec.label}: {state}" for spec in specs
                 if (state := run_state(spec)).startswith("conflict")]
    if conflicts and (args.command == "report" or len(conflicts) == len(specs)):
        # Most often another scale's sweep in the same folder: a report would mislabel it.
        print(f"{PROG}: error: {out} holds runs with other settings than {grid.name} at scale "
              f"{args.scale} ({conflicts[0]}); give --scale or --out", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.command == "report":
        if not out.is_dir():
            print(f"{PROG}: error: no sweep at {out} (run it first, or give --out)",
                  file=sys.stderr)
            return EXIT_BAD_INPUT
        print(f"{PROG}: wrote {build_report(grid, args.scale, out, seeds, command)}")
        return 0
    if args.dry_run:
        for spec in specs:
            state = run_state(spec)
            print(f"{spec.label}: {state}")
            if state not in ("complete",) and not state.startswith("conflict"):
                print("  " + shlex.join(train_command(spec, state)))
        return 0
    out.mkdir(parents=True, exist_ok=True)
    print(f"{PROG}: {grid.name} at scale {args.scale}: {len(specs)} runs "
          f"({len(specs) // len(seeds)} configurations x {len(seeds)} seeds) -> {out}/")
    sweep = Sweep(specs, jobs=args.jobs, cores=args.cores, progress=args.progress)
    outcomes = sweep.run()
    report = build_report(grid, args.scale, out, seeds, command)
    code = sweep_exit_code(outcomes, interrupted=sweep.stop_signal is not None)
    done = sum(o.state == "complete" or o.exit_code == 0 for o in outcomes)
    print(f"{PROG}: {done}/{len(outcomes)} runs complete; report {report}")
    if code == EXIT_INTERRUPTED:
        print(f"{PROG}: interrupted; continue with: {command}")
    return code


if __name__ == "__main__":
    sys.exit(main())
