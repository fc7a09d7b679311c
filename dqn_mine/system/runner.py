"""The run: allocate shared memory, start the actors, pre-fill, train, stop cleanly.

The learner runs in the runner's own process (it owns the GPU and the progress bar); actors are
spawned processes, or plain objects stepped inline in serial mode (tests, debugging). Whatever
happens (finished, Ctrl-C, SIGTERM, a dead actor, an exception), the `finally` path stops every
actor, writes a resumable checkpoint and unlinks every shared segment.
"""

from __future__ import annotations

import dataclasses
import json
import math
import multiprocessing as mp
import signal
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

from dqn_mine import checkpoint as ckpt
from dqn_mine.config import Config, learner_threads, network_shape, resolve_device
from dqn_mine.exitcodes import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK
from dqn_mine.metrics import MetricsTable, RateMeter, Rolling, progress_postfix
from dqn_mine.replay.snapshot import SnapshotError
from dqn_mine.shared import SharedBlocks
from dqn_mine.system.actor import (
    Actor,
    actor_main,
    actor_specs,
    first_error,
    initial_phase,
    learner_may_update,
    prefill_target,
)
from dqn_mine.system.control import Control
from dqn_mine.system.layout import replay_layout, run_block_specs
from dqn_mine.system.learner import Learner


def saved_replay(cfg: Config) -> str | None:
    """``--save-replay``'s folder when a resumed run has a replay saved there, else None."""
    from dqn_mine.replay import snapshot

    if cfg.resume and cfg.save_replay and snapshot.exists(cfg.save_replay):
        return cfg.save_replay
    return None


class ActorFailure(RuntimeError):
    """An actor process raised or died; the message names it and the cause."""


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


class StopSignals:
    """SIGINT/SIGTERM set a flag the loops poll, so shutdown always runs the same clean path."""

    def __init__(self):
        self.received: str | None = None
        self._old = {}

    def __enter__(self) -> StopSignals:
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame) -> None:
        if self.received is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt  # a second Ctrl-C: the user insists
        self.received = signal.Signals(signum).name

    def __exit__(self, *exc) -> None:
        for sig, handler in self._old.items():
            signal.signal(sig, handler)


class ProcessActors:
    """Training actors as spawned processes (spawn: EGL contexts and CUDA do not survive fork)."""

    def __init__(self, cfg: Config, handle: tuple, generation: int = 0):
        ctx = mp.get_context("spawn")
        # One pipe per actor for its error report: unlike a Queue it has no named semaphore to
        # leak when an actor is killed.
        self.errors = []
        self.procs: list[mp.Process] = []
        for spec in actor_specs(cfg, generation):
            receive, send = ctx.Pipe(duplex=False)
            p = ctx.Process(target=actor_main, args=(cfg, spec, handle, send),
                            name=f"dqn_mine-actor-{spec.index}", daemon=True)
            p.start()
            send.close()
            self.errors.append(receive)
            self.procs.append(p)

    def advance(self) -> None:
        """Processes act on their own; only their health needs checking."""
        self.check()

    def check(self) -> None:
        for i, p in enumerate(self.procs):
            err = first_error(self.errors[i])
            if err is not None:
                index, line, trace = err
                print(trace, file=sys.stderr)
                raise ActorFailure(f"actor {index} failed: {line}")
            if p.exitcode is not None:
                how = (f"killed by {signal.Signals(-p.exitcode).name}" if p.exitcode < 0
                       else f"exit code {p.exitcode}")
                raise ActorFailure(f"actor {i} died ({how})")

    def stop(self, timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        for p in self.procs:
            p.join(max(0.1, deadline - time.monotonic()))
        for p in self.procs:
            if p.is_alive():
                p.terminate()
                p.join(2)
            if p.is_alive():
                p.kill()
                p.join(2)
        for conn in self.errors:
            conn.close()


class InlineActors:
    """Serial mode: the same actors, stepped in this process between learner updates."""

    def __init__(self, cfg: Config, storage, control, weights, generation: int = 0):
        self.cfg, self.control = cfg, control
        self.actors = [Actor(cfg, spec, storage, control, weights)
                       for spec in actor_specs(cfg, generation)]
        self.next_eval = cfg.eval_every

    def advance(self) -> None:
        for actor in self.actors:
            if not actor.spec.streams:
                self._maybe_evaluate(actor)
            elif actor.steps < actor.allowed_steps():
                actor.step()

    def _maybe_evaluate(self, actor: Actor) -> None:
        if self.control.total_actor_steps() >= self.next_eval:
            actor.evaluate(self.cfg.eval_episodes)
            self.next_eval = max(self.next_eval, self.control.total_actor_steps()) \
                + self.cfg.eval_every

    def check(self) -> None:
        pass

    def stop(self, timeout: float = 0.0) -> None:
        for actor in self.actors:
            actor.close()


class Run:
    """One training run; ``execute()`` returns its :class:`Summary`."""

    def __init__(self, cfg: Config, run_dir: Path, state: dict | None = None,
                 serial: bool = False, progress: bool = True):
        # cfg is what this process runs with (a restored replay sets its pre-fill to 0);
        # saved_cfg is what checkpoints record.
        self.cfg = self.saved_cfg = cfg
        self.run_dir, self.state = Path(run_dir), state
        self.serial, self.progress = serial, progress
        counters = (state or {}).get("counters", {})
        # Each start of a run (0, then one more per resume) gives the actors new seeds, so a
        # resumed run does not replay the episodes it has already seen.
        self.generation = int(counters.get("generation", -1)) + 1 if state else 0
        self.steps_offset = int(counters.get("env_steps", 0))
        self.episodes = int(counters.get("episodes", 0))
        self.time_offset = float(counters.get("wall_time", 0.0))
        self.returns = Rolling(cfg.return_window)
        self.lengths = Rolling(cfg.return_window)
        self.eval_returns = Rolling(cfg.eval_episodes)
        self.eval_lengths = Rolling(cfg.eval_episodes)
        self.curriculum_returns = Rolling(cfg.curriculum_window)
        self.phase = int(counters.get("phase", initial_phase(cfg)))
        self.first_update = int(counters.get("updates", 0))
        self.train_started: float | None = None   # monotonic time the update loop began
        self.train_start_steps = 0
        self.started = time.monotonic()
        self.reason = "finished"
        self.keep_checkpoint = False

    # -- counters ----------------------------------------------------------------------------
    def wall_time(self) -> float:
        return self.time_offset + time.monotonic() - self.started

    def env_steps(self) -> int:
        return self.steps_offset + self.control.total_actor_steps()

    def counters(self) -> dict:
        return {"updates": self.learner.updates, "env_steps": self.env_steps(),
                "episodes": self.episodes, "wall_time": self.wall_time(), "phase": self.phase,
                "generation": self.generation}

    def drain_episodes(self) -> None:
        for ep in self.control.drain_episodes():
            if ep.is_eval:
                self.eval_returns.extend([ep.ret])
                self.eval_lengths.extend([ep.length])
                continue
            self.episodes += 1
            self.returns.extend([ep.ret])
            self.lengths.extend([ep.length])
            if ep.phase == self.phase:
                self.curriculum_returns.extend([ep.ret])
        self.advance_curriculum()

    def advance_curriculum(self) -> None:
        """Adaptive phases: one phase harder once the rolling mean return of the last
        ``curriculum_window`` episodes (all of the current phase) exceeds the threshold; the
        scheduled room counts: by the share of updates done."""
        cfg = self.cfg
        if cfg.curriculum == "adaptive" and self.phase > 1 \
                and len(self.curriculum_returns) == cfg.curriculum_window \
                and self.curriculum_returns.mean > cfg.curriculum_threshold:
            self.phase -= 1
            self.curriculum_returns.clear()
        elif cfg.curriculum == "schedule" and hasattr(self, "learner"):
            stages = cfg.rooms_schedule
            stage = min(len(stages) - 1, self.learner.updates * len(stages) // max(1, cfg.updates))
            self.phase = int(stages[stage])
        self.control.phase = self.phase

    # -- phases of the run -------------------------------------------------------------------
    def execute(self) -> Summary:
        import torch

        from dqn_mine.agent.network import DuelingQNetwork
        from dqn_mine.replay import ReplayStorage
        from dqn_mine.system.weights import WeightBroadcast

        device = resolve_device(self.cfg.device)
        torch.set_num_threads(learner_threads(self.cfg))
        template = DuelingQNetwork(**network_shape(self.cfg))
        blocks = SharedBlocks.create(run_block_specs(self.cfg, template))
        self.actors = None
        code = EXIT_OK
        try:
            with StopSignals() as self.signals:
                torch.manual_seed(self.cfg.seed)
                self.control = Control(blocks)
                self.control.phase = self.phase
                storage = ReplayStorage(replay_layout(self.cfg), blocks)
                weights = WeightBroadcast(blocks)
                self.learner = Learner(self.cfg, storage, self.control, weights, device,
                                       threaded=not self.serial,
                                       replay_snapshot=self.replay_to_restore())
                if self.learner.restored:
                    print(f"read {self.learner.restored:,} transitions back from "
                          f"{self.cfg.save_replay}: no pre-fill", flush=True)
                    self.cfg = dataclasses.replace(self.cfg, prefill=0)
                if self.state:
                    self.learner.load_state(self.state)
                self.learner.publish()  # actors start from the learner's weights
                self.actors = (
                    InlineActors(self.cfg, storage, self.control, weights, self.generation)
                    if self.serial else
                    ProcessActors(self.cfg, blocks.handle(), self.generation))
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
                if self.signals.received:
                    code, self.reason = EXIT_INTERRUPTED, f"stopped by {self.signals.received}"
        except ActorFailure as exc:
            code, self.reason = EXIT_FAILED, str(exc)
        except SnapshotError as exc:  # a damaged saved replay: keep it and the checkpoint
            code, self.reason = EXIT_FAILED, str(exc)
            self.keep_checkpoint = True
        except Exception as exc:  # the learner failed: keep the last good checkpoint
            traceback.print_exc()
            code, self.reason = EXIT_FAILED, f"learner failed: {type(exc).__name__}: {exc}"
            self.keep_checkpoint = True
        finally:
            self.shutdown()
            blocks.close()
        return self.summary(code)

    def replay_to_restore(self) -> str | None:
        """The saved replay a resumed run reads back, if it has one."""
        path = saved_replay(self.cfg)
        if self.cfg.resume and self.cfg.save_replay and path is None:
            print(f"no saved replay in {self.cfg.save_replay}: pre-filling anew", flush=True)
        return path

    def _should_stop(self) -> bool:
        return self.signals.received is not None

    def prefill(self) -> None:
        target = prefill_target(self.cfg)
        bar = self._bar(total=target, desc="pre-fill", unit="step")
        while not self._should_stop():
            self.actors.advance()
            self.learner.source.ingest()
            done = self.control.total_actor_steps()
            bar.update(min(done, target) - bar.n)
            if done >= target:
                break
            if not self.serial:
                time.sleep(0.05)
        bar.close()
        self.drain_episodes()
        self.train_start_steps = self.control.total_actor_steps()

    def learner_may_update(self) -> bool:
        """Under a fixed replay ratio the learner waits for enough new transitions."""
        return learner_may_update(self.cfg, self.learner.updates - self.first_update,
                                  self.control.total_actor_steps())

    def train(self) -> None:
        cfg, learner = self.cfg, self.learner
        self.train_started = time.monotonic()
        bar = self._bar(total=cfg.updates, initial=learner.updates, desc="train", unit="upd")
        upd_rate = RateMeter(learner.updates)
        step_rate = RateMeter(self.control.total_actor_steps())
        agg = {"loss": [], "mean_q": [], "td_abs": [], "sampled_reward": []}
        while learner.updates < cfg.updates and not self._should_stop():
            self.actors.advance()
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
                row = self.log_row(agg, upd_rate, step_rate)
                bar.set_postfix(progress_postfix(row), refresh=False)
                agg = {k: [] for k in agg}
            if learner.updates % cfg.checkpoint_interval == 0:
                self.save_checkpoint()
        if agg["loss"]:  # stopped between log rows (Ctrl-C): the updates since get a row too
            self.log_row(agg, upd_rate, step_rate)
        bar.close()

    def log_row(self, agg: dict, upd_rate: RateMeter, step_rate: RateMeter) -> dict:
        self.drain_episodes()
        steps = self.control.total_actor_steps()
        row = {"update": self.learner.updates, "wall_time": round(self.wall_time(), 3),
               "env_steps": self.env_steps(), "episodes": self.episodes,
               "episode_return": self.returns.mean, "episode_length": self.lengths.mean,
               "eval_return": self.eval_returns.mean, "eval_length": self.eval_lengths.mean,
               "updates_per_s": upd_rate.rate(self.learner.updates),
               "env_steps_per_s": step_rate.rate(steps),
               "replay_ratio": self.replay_ratio(), "phase": self.control.phase,
               "beta": self.learner.beta(),
               "replay_size": len(self.learner.replay),
               "phase_return": (self.curriculum_returns.mean if self.cfg.curriculum == "adaptive"
                                else math.nan)}
        row.update({k: (sum(v) / len(v) if v else math.nan) for k, v in agg.items()})
        self.metrics.write(row)
        return row

    def replay_ratio(self) -> float:
        """Updates per transition generated since the learner started."""
        new = self.control.total_actor_steps() - self.train_start_steps
        return (self.learner.updates - self.first_update) / new if new > 0 else math.nan

    # -- end ---------------------------------------------------------------------------------
    def save_checkpoint(self) -> None:
        ckpt.save(self.run_dir, self.learner.updater.state_dict(), self.counters(),
                  self.saved_cfg)

    def shutdown(self) -> None:
        control = getattr(self, "control", None)
        if control is not None:
            control.request_stop()
        if self.actors is not None:
            self.actors.stop()
        learner = getattr(self, "learner", None)
        if learner is not None:
            learner.close()
            self.drain_episodes()
            if not self.keep_checkpoint:
                self.save_checkpoint()
                if self.cfg.save_replay:
                    self.learner.save_replay(self.cfg.save_replay)

    def summary(self, code: int) -> Summary:
        learner = getattr(self, "learner", None)
        updates = learner.updates if learner else 0
        control = getattr(self, "control", None)
        wall = self.wall_time()
        steps = self.env_steps() if control is not None else self.steps_offset
        run_time = max(1e-9, time.monotonic() - self.started)
        # updates/s over the training phase only, as the bar and metrics.csv measure it (start-up
        # and pre-fill excluded; a resumed run counts only its own updates)
        learn_time = 0.0 if self.train_started is None else time.monotonic() - self.train_started
        new_updates = updates - self.first_update
        return Summary(run_dir=str(self.run_dir), exit_code=code, reason=self.reason,
                       updates=updates, env_steps=steps, episodes=self.episodes, wall_time=wall,
                       episode_return=self.returns.mean,
                       updates_per_s=new_updates / learn_time if learn_time > 0 else 0.0,
                       env_steps_per_s=(steps - self.steps_offset) / run_time,
                       replay_ratio=self.replay_ratio() if learner and control is not None
                       else math.nan, return_episodes=len(self.returns))

    def _bar(self, **kwargs):
        from tqdm import tqdm

        return tqdm(disable=not self.progress, dynamic_ncols=True, **kwargs)
