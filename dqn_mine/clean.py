"""Remove the shared memory that dead runs left in /dev/shm.

A run unlinks its segments when it stops, crashes or is killed on its own (its resource tracker
does it). Only a SIGKILL of the whole process group, tracker included, leaves them behind, and
they hold their memory until removed. A segment's name carries its creator's pid; those whose
process is gone are removed, a live run's are never touched.

    python -m dqn_mine.clean            # remove them
    python -m dqn_mine.clean --dry-run  # only list them
"""

from __future__ import annotations

import argparse
import os

from dqn_mine.exitcodes import EXIT_OK
from dqn_mine.shared import SHM_DIR, file_size, human_bytes, stale_segments


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m dqn_mine.clean",
                                 description="Remove shared memory left in /dev/shm by dead runs.")
    ap.add_argument("--dry-run", action="store_true", help="list the segments, remove nothing")
    return ap


def clean(path: str = SHM_DIR, dry_run: bool = False) -> tuple[list, int]:
    """Remove (or with ``dry_run`` only find) the stale segments; returns them and their bytes."""
    names = stale_segments(path)
    total = 0
    for name in names:
        file = os.path.join(path, name)
        total += file_size(file)
        if not dry_run:
            try:
                os.unlink(file)
            except FileNotFoundError:
                pass
    return names, total


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    names, total = clean(dry_run=args.dry_run)
    for name in names:
        print(name)
    verb = "would free" if args.dry_run else "freed"
    print(f"{len(names)} segments of dead runs, {verb} {human_bytes(total)}")
    return EXIT_OK


if __name__ == "__main__":
    raise SystemExit(main())
