"""Run a sweep: each run a ``python -m dqn_mine.train`` subprocess, skipped when complete,
resumed when interrupted, a few at a time without oversubscribing the cores.

State lives only in the run folders, so re-running the same command continues a sweep:

==========================================================  ==================================
run folder                                                  action
==========================================================  ==================================
missing, or no ``config.json``                              start it
``summary.json`` says exit code 0 and the updates reached   skip it (complete)
``checkpoint.pt`` present                                   ``--resume DIR --updates N``
``config.json`` but no checkpoint (killed during start-up)  delete the folder, start it again
saved config differs from the grid's (not just ``updates``) refuse: another ``OUT`` or delete it
==========================================================  ==================================

Settings the configuration never reads (``dqn_mine.config.inert_settings``) do not count as a
difference, so a default changed since the run was made does not strand it.

Ctrl-C (or SIGTERM) is forwarded once to every running trainer, which stops cleanly and leaves a
checkpoint; the launcher waits for them, starts nothing new and exits 130. Trainers run in their
own process group so a terminal's Ctrl-C reaches them only through the launcher.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from dqn_mine.config import Config, ConfigError, inert_settings
from dqn_mine.exitcodes import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK
from experiments.grid import RunSpec

LOG = "train.log"
# Settings a resume may change without making it another run.
RESUMABLE = {"updates", "resume", "run_dir"}


def run_state(spec: RunSpec) -> str:
    """``complete`` | ``resume`` | ``restart`` | ``fresh`` | ``conflict: <why>`` for a run."""
    d = spec.run_dir
    summary = _read_json(d / "summary.json")
    finished = summary and summary.get("exit_code") == 0 and _budget_spent(summary, spec.cfg)
    if not finished and not (d / "config.json").exists():
        return "fresh"
    why = _differs(spec)  # reads and compares config.json once
    if why:
        return f"conflict: {why}"
    if finished:
        return "complete"
    return "resume" if (d / "checkpoint.pt").exists() else "restart"


def _budget_spent(summary: dict, cfg: Config) -> bool:
    """Whether a finished run used its update budget or, bounded by minutes, its time."""
    if summary.get("updates", -1) >= cfg.updates:
        return True
    return cfg.minutes is not None and summary.get("wall_time", 0.0) >= 60 * cfg.minutes


def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _differs(spec: RunSpec) -> str:
    """The settings where the saved config.json differs from the grid's ('' if none)."""
    try:
        saved = Config.from_json(spec.run_dir / "config.json")
    except ConfigError as exc:
        return str(exc)
    ignored = RESUMABLE | (inert_settings(saved) & inert_settings(spec.cfg))
    names = [f.name for f in dataclasses.fields(Config) if f.name not in ignored
             and getattr(saved, f.name) != getattr(spec.cfg, f.name)]
    if not names:
        return ""
    shown = ", ".join(f"{n} {getattr(saved, n)!r} != {getattr(spec.cfg, n)!r}" for n in names[:3])
    return f"{spec.run_dir} holds another configuration ({shown}); use another OUT or delete it"


def train_command(spec: RunSpec, state: str) -> list[str]:
    base = [sys.executable, "-m", "dqn_mine.train"]
    if state == "resume":
        return base + ["--resume", str(spec.run_dir), "--updates", str(spec.cfg.updates)]
    return base + spec.argv()


@dataclass
class Outcome:
    spec: RunSpec
    state: str  # what the launcher found (see run_state)
    exit_code: int | None = None  # None: not run (complete, conflict, or never started)
    seconds: float = 0.0


@dataclass
class _Running:
    spec: RunSpec
    state: str
    proc: subprocess.Popen
    log: object
    index: int
    started: float = field(default_factory=time.monotonic)


class Sweep:
    """Runs ``specs`` (``jobs`` at a time, at most ``cores`` busy processes unless a single run
    alone needs more) and returns one :class:`Outcome` per spec."""

    def __init__(self, specs: Sequence[RunSpec], jobs: int = 1, cores: int | None = None,
                 progress: bool = True, echo=print):
        self.specs, self.jobs = list(specs), max(1, jobs)
        self.cores = cores or os.cpu_count() or 1
        self.progress, self.echo = progress, echo
        self.stop_signal: int | None = None
        self.running: list[_Running] = []

    # -- signals -----------------------------------------------------------------------------
    def _on_signal(self, signum, frame) -> None:
        first = self.stop_signal is None
        self.stop_signal = signum
        for r in self.running:  # a second Ctrl-C reaches the trainers as their second one
            _send(r.proc, signal.SIGINT)
        if first:
            self.echo(f"\n{signal.Signals(signum).name}: stopping the running trainers "
                      "(they write a checkpoint); run the same command again to continue")

    def run(self) -> list[Outcome]:
        from tqdm import tqdm

        outcomes: dict[int, Outcome] = {}
        pending = []
        for i, spec in enumerate(self.specs):
            state = run_state(spec)
            if state == "complete" or state.startswith("conflict"):
                outcomes[i] = Outcome(spec, state)
                if state != "complete":
                    self.echo(f"{spec.label}: {state}")
            else:
                pending.append((i, spec, state))
        old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        bar = tqdm(total=len(self.specs), initial=len(outcomes), unit="run", desc="sweep",
                   disable=not self.progress, dynamic_ncols=True)
        self.echo = bar.write if self.progress else self.echo
        try:
            while (pending and self.stop_signal is None) or self.running:
                while pending and self.stop_signal is None and self._fits(pending[0][1]):
                    i, spec, state = pending.pop(0)
                    self.running.append(self._start(i, spec, state))
                    bar.set_postfix_str(", ".join(r.spec.label for r in self.running))
                time.sleep(0.2)
                for r in [r for r in self.running if r.proc.poll() is not None]:
                    self.running.remove(r)
                    r.log.close()
                    outcomes[r.index] = self._finish(r)
                    bar.update(1)
        finally:
            for r in self.running:  # only reached on an exception in the launcher itself
                _send(r.proc, signal.SIGINT)
                r.proc.wait()
            bar.close()
            for s, handler in old.items():
                signal.signal(s, handler)
        for i, spec, state in pending:
            outcomes[i] = Outcome(spec, state)
        return [outcomes[i] for i in range(len(self.specs))]

    def _fits(self, spec: RunSpec) -> bool:
        if not self.running:
            return True
        busy = sum(r.spec.processes() for r in self.running)
        return len(self.running) < self.jobs and busy + spec.processes() <= self.cores

    def _start(self, index: int, spec: RunSpec, state: str) -> _Running:
        if state == "restart":
            shutil.rmtree(spec.run_dir)
        spec.run_dir.mkdir(parents=True, exist_ok=True)
        cmd = train_command(spec, state)
        log = open(spec.run_dir / LOG, "a")
        log.write(f"$ {' '.join(cmd)}\n")
        log.flush()
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True)
        return _Running(spec, state, proc, log, index)

    def _finish(self, r: _Running) -> Outcome:
        code, seconds = r.proc.returncode, time.monotonic() - r.started
        summary = _read_json(r.spec.run_dir / "summary.json") or {}
        what = {EXIT_OK: "finished", EXIT_INTERRUPTED: "interrupted",
                EXIT_BAD_INPUT: "bad input"}.get(code, "FAILED")
        ret = summary.get("episode_return")
        ret_text = f", mean return {ret:.3f}" if isinstance(ret, float) and ret == ret else ""
        self.echo(f"{r.spec.label}: {what} (exit {code}) after {summary.get('updates', '?')} "
                  f"updates in {seconds:.0f} s{ret_text}"
                  + ("" if code in (EXIT_OK, EXIT_INTERRUPTED)
                     else f"; see {r.spec.run_dir / LOG}"))
        return Outcome(r.spec, r.state, code, seconds)


def _send(proc: subprocess.Popen, sig: int) -> None:
    if proc.poll() is None:
        try:
            proc.send_signal(sig)
        except ProcessLookupError:
            pass


def sweep_exit_code(outcomes: Sequence[Outcome], interrupted: bool) -> int:
    if interrupted:
        return EXIT_INTERRUPTED
    bad = [o for o in outcomes
           if o.state.startswith("conflict") or (o.exit_code not in (None, 0))]
    return EXIT_FAILED if bad else EXIT_OK
