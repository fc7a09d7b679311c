"""`python -m dqn_mine.bench [--quick] [--only env,replay,...] --out FILE`: run every benchmark."""

import argparse
import importlib
import platform
import sys
import time
from pathlib import Path

SECTIONS = ["env", "replay", "learner", "system", "explore", "starts"]


def machine_line() -> str:
    import os
    return (f"{platform.node()} · {os.cpu_count()} cores · Python {platform.python_version()} · "
            f"{time.strftime('%Y-%m-%d %H:%M')}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="results/bench.md", help="markdown file to write")
    ap.add_argument("--quick", action="store_true", help="shorter runs (noisier figures)")
    ap.add_argument("--only", default=",".join(SECTIONS), help="comma-separated sections")
    args = ap.parse_args(argv)
    parts = [f"# dqn_mine benchmarks\n\nMachine: {machine_line()}\n"]
    for name in args.only.split(","):
        try:
            mod = importlib.import_module(f"dqn_mine.bench.{name}")
        except ModuleNotFoundError as exc:
            print(f"skipping {name}: {exc}", file=sys.stderr)
            continue
        print(f"== {name}", file=sys.stderr, flush=True)
        parts.append(mod.run(quick=args.quick))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(parts))
    print(out.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
