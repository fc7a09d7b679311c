"""A run's acting processes: spawned (:class:`ProcessActors`) or inline (:class:`InlineActors`).

Both offer the runner the same three calls: ``advance()`` between learner updates, ``check()``
for a failed actor, ``stop()`` at the end.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import sys
import time
import traceback

from dqn_mine.config import Config
from dqn_mine.system.actor import Actor
from dqn_mine.system.evaluator import EvalActor
from dqn_mine.system.specs import ActorSpec, actor_specs


class ActorFailure(RuntimeError):
    """An actor process raised or died; the message names it and the cause."""


def make_actor(cfg: Config, spec: ActorSpec, storage, control, weights,
               parent_pid: int | None = None):
    """The actor a spec describes: the evaluation actor, or a training actor."""
    if spec.evaluates:
        return EvalActor(cfg, spec, control, weights, parent_pid=parent_pid)
    return Actor(cfg, spec, storage, control, weights, parent_pid=parent_pid)


def actor_main(cfg: Config, spec: ActorSpec, handle: tuple, errors) -> None:
    """Entry point of a spawned actor process."""
    # The runner handles Ctrl-C and tells actors to stop through shared state; an actor that
    # died on SIGINT mid-write would leave a half-published block.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # The runner's pid as the runner gave it: a getppid() here could already read 1 if the
    # runner died while this process was still starting.
    parent = mp.parent_process().pid
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    blocks = None
    try:
        import torch

        from dqn_mine.system.context import attach_views

        torch.set_num_threads(1)
        blocks, storage, control, weights = attach_views(cfg, handle)
        make_actor(cfg, spec, storage, control, weights, parent_pid=parent).run()
    except BaseException as exc:  # report every failure to the runner, then exit non-zero
        errors.send((spec.index, f"{type(exc).__name__}: {exc}", traceback.format_exc()))
        raise SystemExit(1) from None
    finally:
        if blocks is not None:
            blocks.close()


def first_error(conn) -> tuple | None:
    """The error an actor reported on its pipe, if any (non-blocking)."""
    try:
        return conn.recv() if conn.poll() else None
    except (EOFError, OSError):  # closed without a report: the exit code tells the rest
        return None


class ProcessActors:
    """Actors as spawned processes (spawn: EGL contexts and CUDA do not survive fork)."""

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
        self.actors = [make_actor(cfg, spec, storage, control, weights)
                       for spec in actor_specs(cfg, generation)]

    def advance(self) -> None:
        for actor in self.actors:
            actor.advance()

    def check(self) -> None:
        pass

    def stop(self, timeout: float = 0.0) -> None:
        for actor in self.actors:
            actor.close()
