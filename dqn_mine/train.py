"""`python -m dqn_mine.train`: train an Ape-X style DQN agent on the mine.

Examples::

    python -m dqn_mine.train --preset smoke          # a short CPU run on a small one-room task
    python -m dqn_mine.train --actors 7 --n-step 6   # the study's configuration on two-room
    python -m dqn_mine.train --resume runs/<run>     # continue a stopped run

Exit codes: 0 finished, 1 an actor or the learner failed, 2 bad input, 130 stopped by a signal
(a resumable checkpoint is written in every case but bad input).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from dqn_mine import checkpoint as ckpt
from dqn_mine import machine
from dqn_mine.checkpoint import CheckpointError
from dqn_mine.config import Config, ConfigError, parse_args, resolve_device
from dqn_mine.exitcodes import EXIT_BAD_INPUT, EXIT_INTERRUPTED
from dqn_mine.shared import SharedMemoryError, check_free_space

PROG = "dqn_mine.train"


def check_shared_memory(cfg: Config) -> None:
    """Fail before anything is written if the replay cannot fit in /dev/shm."""
    from dqn_mine.system.layout import replay_layout

    check_free_space(replay_layout(cfg).nbytes)


def check_env_settings(cfg: Config) -> None:
    """Let the environment judge its own arguments (it creates no GL context until it renders)."""
    from dqn_mine.env import MineRescueEnv
    from dqn_mine.system.specs import actor_specs

    for spec in actor_specs(cfg)[-1:] + actor_specs(cfg)[:1]:
        try:
            MineRescueEnv(**spec.env_kwargs).close()
        except ValueError as exc:
            raise ConfigError(str(exc)) from None


def check_saved_replay(cfg: Config) -> None:
    """A resumed run's saved replay must fit the replay it will be read into."""
    from dqn_mine.replay import snapshot
    from dqn_mine.system.layout import replay_layout
    from dqn_mine.system.runner import saved_replay

    path = saved_replay(cfg)
    if path is not None:
        try:
            snapshot.check(path, replay_layout(cfg, snapshot.demo_streams(path)))
        except snapshot.SnapshotError as exc:
            raise ConfigError(str(exc)) from None


def check_demos(cfg: Config) -> None:
    """A --demos-from folder must hold readable episodes that fit the replay's rings."""
    from dqn_mine.demos import DemoError, episode_files, pack, read_lengths
    from dqn_mine.system.layout import demo_ring_frames

    if cfg.demos_from:
        try:
            pack(read_lengths(episode_files(cfg.demos_from)), demo_ring_frames(cfg))
        except DemoError as exc:
            raise ConfigError(f"--demos-from: {exc}") from None


def open_run(cfg: Config) -> tuple[Config, Path, dict | None]:
    """Validate everything that can fail, then create (or reuse) the run folder."""
    # parse_args already rebuilt a resumed run's config from its config.json.
    state = ckpt.load(cfg.resume) if cfg.resume else None
    resolve_device(cfg.device)
    check_env_settings(cfg)
    check_shared_memory(cfg)
    check_saved_replay(cfg)
    check_demos(cfg)
    cfg = cfg.with_run_dir()
    run_dir = Path(cfg.run_dir)
    if state is None:
        if (run_dir / "config.json").exists():
            raise ConfigError(f"{run_dir} already holds a run: use --resume {run_dir} "
                              "or another --run-dir")
        run_dir.mkdir(parents=True, exist_ok=True)
    cfg.to_json(run_dir / "config.json")  # on resume: with the flags that overrode it
    machine.record(cfg, run_dir)          # one line per start: minutes differ by machine
    return cfg, run_dir, state


def discard_fresh_run(run_dir: Path) -> None:
    """Remove what open_run wrote for a new run, and the folder if nothing else is in it."""
    for name in ("config.json", "machine.jsonl"):
        (run_dir / name).unlink(missing_ok=True)
    with contextlib.suppress(OSError):
        run_dir.rmdir()


def report(summary) -> None:
    s = summary
    print(f"\n{PROG}: {s.reason} after {s.updates} updates, {s.env_steps} env steps, "
          f"{s.episodes} episodes ({s.rewarded_episodes} rewarded) in {s.wall_time:.0f} s")
    print(f"  mean return (last {s.return_episodes} episodes of this process) "
          f"{s.episode_return:.3f} | {s.updates_per_s:.1f} upd/s while training | "
          f"{s.env_steps_per_s:.0f} steps/s | replay ratio {s.replay_ratio:.3f}")
    print(f"  run folder {s.run_dir} (config.json, metrics.csv, checkpoint.pt)")
    if s.exit_code == EXIT_INTERRUPTED:
        print(f"  resume with: python -m {PROG} --resume {s.run_dir}")


def main(argv: Sequence[str] | None = None) -> int:
    from dqn_mine.demos import DemoError
    from dqn_mine.system.runner import NothingTrained, Run

    try:
        cfg = parse_args(argv)
        cfg, run_dir, state = open_run(cfg)
    except (ConfigError, CheckpointError, SharedMemoryError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        # a bar on a terminal; in a log file (nohup, a sweep) a line per metrics row instead
        summary = Run(cfg, run_dir, state, serial=cfg.serial,
                      progress=sys.stderr.isatty()).execute()
    except (DemoError, NothingTrained) as exc:   # before anything was trained
        if state is None:   # the same command can start it again
            discard_fresh_run(run_dir)
        print(f"{PROG}: {'' if isinstance(exc, NothingTrained) else 'error: '}{exc}",
              file=sys.stderr)
        return EXIT_INTERRUPTED if isinstance(exc, NothingTrained) else EXIT_BAD_INPUT
    except KeyboardInterrupt:  # a second Ctrl-C during the shutdown itself
        print(f"\n{PROG}: stopped at once by a second SIGINT during the shutdown; resume from "
              f"the last checkpoint with: python -m {PROG} --resume {run_dir}", file=sys.stderr)
        return EXIT_INTERRUPTED
    (run_dir / "summary.json").write_text(json.dumps(dataclasses.asdict(summary), indent=2))
    report(summary)
    return summary.exit_code


if __name__ == "__main__":
    sys.exit(main())
