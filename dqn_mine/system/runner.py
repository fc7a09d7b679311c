"""The run's lifecycle: build its parts, pre-fill, train, stop cleanly.

The learner runs in the runner's own process (it owns the GPU and the progress bar); actors are
spawned processes, or plain objects stepped inline in serial mode (tests, debugging). Whatever
happens (finished, Ctrl-C, SIGTERM, a dead actor, an exception), the ``finally`` path stops every
actor, writes a resumable checkpoint and unlinks every shared segment.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

from dqn_mine import checkpoint as ckpt
from dqn_mine.config import Config, learner_threads
from dqn_mine.demos import DemoSet
from dqn_mine.exitcodes import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK
from dqn_mine.metrics import MetricsTable, RateMeter, log_line, progress_line, progress_postfix
from dqn_mine.replay.snapshot import SnapshotError, demo_streams
from dqn_mine.system.context import RunContext
from dqn_mine.system.curriculum import Curriculum
from dqn_mine.system.episodes import EpisodeStats
from dqn_mine.system.layout import run_demos
from dqn_mine.system.pacing import learner_may_update, prefill_target
from dqn_mine.system.pool import ActorFailure


def saved_replay(cfg: Config) -> str | None:
    """``--save-replay``'s folder when a resumed run has a replay saved there, else None."""
    from dqn_mine.replay import snapshot

    if cfg.resume and cfg.save_replay and snapshot.exists(cfg.save_replay):
        return cfg.save_replay
    return None


@dataclass
class Summary:
    """What a run reports at its end (also written to ``summary.json``)."""

    run_dir: str
    exit_code: int
    reason: str
    updates: int
    env_steps: int
    episodes: int
    wall_time: float
    episode_return: float
    updates_per_s: float
    env_steps_per_s: float
    replay_ratio: float
    return_episodes: int = 0      # finished episodes (this process) behind episode_return
    rewarded_episodes: int = 0    # training episodes with a reward, over every start of the run


class NothingTrained(Exception):
    """The run stopped before anything was allocated or trained (a signal while the expert
    planned the demonstrations); the message is one line."""


class StopSignals:
    """SIGINT/SIGTERM set a flag the loops poll, so shutdown always runs the same clean path."""

    def __init__(self):
        self.received: str | None = None
        self.insisted = False      # a second Ctrl-C came
        self.deferring = False     # then only note it (see deferred)
        self._old = {}

    def __enter__(self) -> StopSignals:
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame) -> None:
        if self.received is not None and signum == signal.SIGINT:
            self.insisted = True
            if not self.deferring:
                raise KeyboardInterrupt  # a second Ctrl-C: the user insists
            return
        self.received = signal.Signals(signum).name

    @contextlib.contextmanager
    def deferred(self):
        """Installed, but a second Ctrl-C is only noted: stopping the processes and writing the
        checkpoint take seconds, and cutting them short would leave no resumable run."""
        with self:
            self.deferring = True
            try:
                yield self
            finally:
                self.deferring = False

    def __exit__(self, *exc) -> None:
        for sig, handler in self._old.items():
            signal.signal(sig, handler)


# Sums over the log interval of what each update reports.
UPDATE_STATS = ("loss", "mean_q", "td_abs", "sampled_reward", "demo_share", "margin_loss")


def _mean(values: list) -> float:
    """Mean of the numbers that are not NaN (a batch without demonstrations has no margin)."""
    kept = [v for v in values if v == v]
    return sum(kept) / len(kept) if kept else math.nan


class Run:
    """One training run; ``execute()`` returns its :class:`Summary`."""

    def __init__(self, cfg: Config, run_dir: Path, state: dict | None = None,
                 serial: bool = False, progress: bool = True):
        # cfg is what this process runs with (a restored replay sets its pre-fill to 0, see
        # RunContext.start); saved_cfg is what checkpoints record.
        self.cfg = self.saved_cfg = cfg
        self.run_dir, self.state = Path(run_dir), state
        self.serial, self.progress = serial, progress
        counters = (state or {}).get("counters", {})
        # Each start of a run (0, then one more per resume) gives the actors new seeds, so a
        # resumed run does not replay the episodes it has already seen.
        self.generation = int(counters.get("generation", -1)) + 1 if state else 0
        self.steps_offset = int(counters.get("env_steps", 0))
        self.time_offset = float(counters.get("wall_time", 0.0))
        self.stats = EpisodeStats(cfg, episodes=int(counters.get("episodes", 0)),
                                  rewarded=int(counters.get("rewarded_episodes", 0)))
        self.curriculum = Curriculum(cfg, phase=counters.get("phase"),
                                     updates=int(counters.get("updates", 0)))
        self.ctx: RunContext | None = None
        self.metrics: MetricsTable | None = None
        self.signals = StopSignals()
        self.started = time.monotonic()
        self.train_started: float | None = None   # monotonic time the update loop began
        self.train_start_steps = 0
        self.reason = "finished"
        self.keep_checkpoint = False

    # -- counters ----------------------------------------------------------------------------
    def wall_time(self) -> float:
        return self.time_offset + time.monotonic() - self.started

    def actor_steps(self) -> int:
        """Env steps the training actors of this process have taken."""
        return self.ctx.control.total_actor_steps() if self.ctx else 0

    def env_steps(self) -> int:
        return self.steps_offset + self.actor_steps()

    def updates(self) -> int:
        learner = self.ctx.learner if self.ctx else None
        return learner.updates if learner else 0

    def counters(self) -> dict:
        return {"updates": self.updates(), "env_steps": self.env_steps(),
                "episodes": self.stats.episodes, "rewarded_episodes": self.stats.rewarded,
                "wall_time": self.wall_time(),
                "phase": self.curriculum.phase, "num_rooms": self.curriculum.num_rooms,
                "generation": self.generation}

    def drain_episodes(self) -> None:
        """Take in the finished episodes; the curriculum follows, the actors read it back."""
        for ep in self.ctx.control.drain_episodes():
            if self.stats.add(ep):
                self.curriculum.record(ep.phase, ep.ret, ep.epsilon, ep.start_share, ep.scripted)
        self.curriculum.advance(self.updates())
        self.ctx.control.show_curriculum(self.curriculum)

    # -- phases of the run -------------------------------------------------------------------
    def execute(self) -> Summary:
        import torch

        torch.set_num_threads(learner_threads(self.cfg))
        snapshot = self.replay_to_restore()
        demos = None if snapshot else self.plan_demos()   # a saved replay holds them already
        self.ctx = RunContext(self.cfg, demo_streams(snapshot) if snapshot else
                              demos.streams if demos else 0)
        code = EXIT_OK
        try:
            with self.signals:
                torch.manual_seed(self.cfg.seed)
                self.ctx.control.show_curriculum(self.curriculum)
                self.ctx.start_learner(self.state, snapshot, self.serial)
                self.cfg = self.ctx.cfg
                if demos is not None:
                    self.add_demos(demos)
                self.ctx.start_actors(self.generation, self.serial)
                self.prefill_and_train()
                if self.signals.received:
                    code, self.reason = EXIT_INTERRUPTED, f"stopped by {self.signals.received}"
        except ActorFailure as exc:
            code, self.reason = EXIT_FAILED, str(exc)
        except SnapshotError as exc:  # a damaged saved replay: keep it and the checkpoint
            code, self.reason = EXIT_FAILED, str(exc)
            self.keep_checkpoint = True
        except KeyboardInterrupt:  # a second Ctrl-C: the checkpoint is still saved, not the replay
            code = EXIT_INTERRUPTED
        except Exception as exc:  # the learner failed: keep the last good checkpoint
            traceback.print_exc()
            code, self.reason = EXIT_FAILED, f"learner failed: {type(exc).__name__}: {exc}"
            self.keep_checkpoint = True
        finally:
            try:
                self.shutdown()
            finally:  # even when a Ctrl-C cuts the replay's saving short: no segment outlives it
                self.ctx.close()
        return self.summary(code)

    def plan_demos(self) -> DemoSet | None:
        """The run's demonstrations, planned before anything is allocated: a signal meanwhile
        stops the run at once, with nothing to clean up or save."""
        def stop(signum, frame):
            raise NothingTrained(f"stopped by {signal.Signals(signum).name} while the expert "
                                 "planned the demonstrations; nothing was trained")

        old = {sig: signal.signal(sig, stop) for sig in (signal.SIGINT, signal.SIGTERM)}
        if self.cfg.demos and not self.progress:    # none to plan without, or from a folder
            print("demos: planning the expert's episodes", file=sys.stderr, flush=True)
        try:
            return run_demos(self.cfg, self.progress)
        finally:
            for sig, handler in old.items():
                signal.signal(sig, handler)

    def replay_to_restore(self) -> str | None:
        """The saved replay a resumed run reads back, if it has one."""
        path = saved_replay(self.cfg)
        if self.cfg.resume and self.cfg.save_replay and path is None:
            print(f"no saved replay in {self.cfg.save_replay}: pre-filling anew", flush=True)
        return path

    def add_demos(self, demos: DemoSet) -> None:
        """The demonstrations into the replay; a fresh run then pre-trains on them alone."""
        demos.write(self.ctx.storage, self.progress)
        print(f"{len(demos.lengths):,} demonstrations from {demos.source} ({demos.steps:,} "
              f"steps) are in the replay", flush=True)
        if self.state is None and self.cfg.demo_pretrain:
            if demos.steps < self.cfg.batch_size:   # no batch could ever be sampled
                print(f"no pre-training: {demos.steps} demonstration steps do not fill a batch "
                      f"of {self.cfg.batch_size}", flush=True)
                return
            self.pretrain()

    def pretrain(self) -> None:
        """``--demo-pretrain`` updates on the demonstrations, before any actor acts (they are
        not counted as the run's updates: the budget and the replay ratio are the actors')."""
        import torch

        threads = torch.get_num_threads()
        torch.set_num_threads(os.cpu_count() or 1)   # no actor runs yet: every core is free
        try:
            self._pretrain_updates(self.cfg.demo_pretrain)
        finally:
            torch.set_num_threads(threads)

    def _pretrain_updates(self, total: int) -> None:
        learner = self.ctx.learner
        bar = self._bar(total=total, desc="demo pre-train", unit="upd")
        done, last = 0, {}
        while done < total and not self._should_stop():
            stats = learner.pretrain_step()
            if stats is None:
                continue
            done += 1
            bar.update(1)
            last = stats
            logged = not self.progress and done % max(1, total // 10) == 0  # a log file: 10 lines
            if done % 100 == 0 or logged:
                figures = {"loss": f"{stats['loss']:.3g}", "margin": f"{stats['margin_loss']:.3g}"}
                bar.set_postfix(figures, refresh=False)
                if logged:   # where the bar would be, as the training's lines
                    print(log_line("demo pre-train", done, total, self.wall_time() / 60,
                                   figures), file=sys.stderr, flush=True)
        bar.close()
        if last:
            print(f"pre-trained on the demonstrations for {done:,} updates: loss "
                  f"{last['loss']:.4f}, margin loss {last['margin_loss']:.4f}", flush=True)

    def prefill_and_train(self) -> None:
        self.metrics = MetricsTable(
            self.run_dir / "metrics.csv",
            self.run_dir / "tb" if self.cfg.tensorboard else None,
            # indented: TensorBoard's text tab shows it as a code block
            "\n".join("    " + line for line in
                      json.dumps(self.cfg.to_dict(), indent=1).splitlines()))
        try:
            self.prefill()
            self.train()
        finally:
            self.metrics.close()

    def _should_stop(self) -> bool:
        return self.signals.received is not None

    def prefill(self) -> None:
        target = prefill_target(self.cfg)
        bar = self._bar(total=target, desc="pre-fill", unit="step")
        while not self._should_stop():
            self.ctx.actors.advance()
            self.ctx.learner.ingest()
            done = self.actor_steps()
            bar.update(min(done, target) - bar.n)
            if done >= target:
                break
            if not self.serial:
                time.sleep(0.05)
        bar.close()
        self.drain_episodes()
        self.train_start_steps = self.actor_steps()

    def out_of_time(self) -> bool:
        """Whether the run's wall-time budget (``--minutes``) is spent; the run then finishes
        as if its updates were done."""
        if self.cfg.minutes is None or self.wall_time() < 60 * self.cfg.minutes:
            return False
        self.reason = f"finished (time budget of {self.cfg.minutes:g} min)"
        return True

    def learner_may_update(self) -> bool:
        """Under a fixed replay ratio the learner waits for enough new transitions."""
        return learner_may_update(self.cfg, self.ctx.learner.new_updates, self.actor_steps())

    def train(self) -> None:
        cfg, learner = self.cfg, self.ctx.learner
        self.train_started = time.monotonic()
        bar = self._bar(total=cfg.updates, initial=learner.updates, desc="train", unit="upd")
        rates = RateMeter(learner.updates), RateMeter(self.actor_steps())
        agg = {key: [] for key in UPDATE_STATS}
        while learner.updates < cfg.updates and not self._should_stop() \
                and not self.out_of_time():
            self.ctx.actors.advance()
            if not self.learner_may_update():
                if not self.serial:
                    time.sleep(0.001)
                continue
            stats = learner.step()
            if stats is None:
                continue
            bar.update(1)
            # Every update, not only at log rows: the curriculum reacts at once and the actors'
            # episode rings (4,096 records each) can never lap an unread record.
            self.drain_episodes()
            for key in agg:
                agg[key].append(float(stats[key]))
            if learner.updates % cfg.log_interval == 0 or learner.updates == cfg.updates:
                row = self.log_row(agg, *rates)
                bar.set_postfix(progress_postfix(row), refresh=False)
                if not self.progress:
                    print(progress_line(row, cfg.updates), file=sys.stderr, flush=True)
                agg = {key: [] for key in UPDATE_STATS}
            if learner.updates % cfg.checkpoint_interval == 0:
                self.save_checkpoint()
        if agg["loss"]:  # stopped between log rows (Ctrl-C): the updates since get a row too
            self.log_row(agg, *rates)
        bar.close()

    def log_row(self, agg: dict, upd_rate: RateMeter, step_rate: RateMeter) -> dict:
        self.drain_episodes()
        learner, stats = self.ctx.learner, self.stats
        row = {"update": learner.updates, "wall_time": round(self.wall_time(), 3),
               "env_steps": self.env_steps(), "episodes": stats.episodes,
               "episode_return": stats.returns.mean, "episode_length": stats.lengths.mean,
               "eval_return": stats.eval_returns.mean, "eval_length": stats.eval_lengths.mean,
               "updates_per_s": upd_rate.rate(learner.updates),
               "env_steps_per_s": step_rate.rate(self.actor_steps()),
               "replay_ratio": self.replay_ratio(), "phase": self.curriculum.logged_phase,
               "beta": learner.beta(), "replay_size": learner.replay_size(),
               "phase_return": self.curriculum.phase_return,
               "start_share": self.curriculum.start_share,
               "full_task_return": stats.full_returns.mean,
               "full_task_episodes": stats.full_episodes,
               "low_eps_return": stats.low_eps_returns.mean,
               "phase_low_eps_return": self.curriculum.phase_low_eps_return,
               "rewarded_episodes": stats.rewarded}
        row.update({k: _mean(v) for k, v in agg.items()})
        self.metrics.write(row)
        return row

    def replay_ratio(self) -> float:
        """Updates per transition generated since the learner started."""
        new = self.actor_steps() - self.train_start_steps
        return self.ctx.learner.new_updates / new if new > 0 else math.nan

    # -- end ---------------------------------------------------------------------------------
    def save_checkpoint(self) -> None:
        ckpt.save(self.run_dir, self.ctx.learner.state_dict(), self.counters(), self.saved_cfg)

    def shutdown(self) -> None:
        """Stop the actors and the learner; keep what the run learned (checkpoint, replay). A
        second Ctrl-C skips the replay, or cuts its saving short (it is written to a temporary
        folder first, so an older snapshot stays whole)."""
        with self.signals.deferred():
            self.ctx.stop()
            if self.ctx.learner is not None:
                self.drain_episodes()
            keep = self.ctx.learner is not None and not self.keep_checkpoint
            if keep:
                self.save_checkpoint()
        if self.signals.insisted:
            self.reason = "stopped at once by a second SIGINT" + (
                " (the replay was not saved)" if self.cfg.save_replay else "")
        elif keep and self.cfg.save_replay:
            self.ctx.learner.save_replay(self.cfg.save_replay)

    def summary(self, code: int) -> Summary:
        learner = self.ctx.learner
        run_time = max(1e-9, time.monotonic() - self.started)
        # updates/s over the training phase only, as the bar and metrics.csv measure it (start-up
        # and pre-fill excluded; a resumed run counts only its own updates)
        learn_time = 0.0 if self.train_started is None else time.monotonic() - self.train_started
        new_updates = learner.new_updates if learner else 0
        steps = self.env_steps()
        return Summary(run_dir=str(self.run_dir), exit_code=code, reason=self.reason,
                       updates=self.updates(), env_steps=steps, episodes=self.stats.episodes,
                       wall_time=self.wall_time(), episode_return=self.stats.returns.mean,
                       updates_per_s=new_updates / learn_time if learn_time > 0 else 0.0,
                       env_steps_per_s=(steps - self.steps_offset) / run_time,
                       replay_ratio=self.replay_ratio() if learner else math.nan,
                       return_episodes=len(self.stats.returns),
                       rewarded_episodes=self.stats.rewarded)

    def _bar(self, **kwargs):
        from tqdm import tqdm

        return tqdm(disable=not self.progress, dynamic_ncols=True, **kwargs)
