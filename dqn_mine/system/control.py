"""Run-wide control state shared by the runner, the learner and the actors.

Every field has exactly one writer, so no lock is needed: the runner's process writes ``stop``,
``updates`` (the learner) and the curriculum's ``phase`` and ``num_rooms``; actor ``i`` writes its
own row of ``actor_steps`` and of the episode ring. Episode records go through shared memory
rather than a ``multiprocessing.Queue`` because a queue's pipe can be left half-written (and its
lock held) by an actor killed mid-``put``; a ring of plain numbers cannot.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from dqn_mine.shared import BlockSpec, SharedBlocks

EPISODE_RING = 4096  # per actor; the learner drains far more often than actors finish this many


class Episode(NamedTuple):
    actor: int
    ret: float
    length: int
    phase: int
    is_eval: bool
    epsilon: float = float("nan")   # the rate of the env that played it (NaN: unknown)
    full_task: bool = True          # it began at the task's real start (no curriculum start)
    start_share: float = float("nan")   # backward: its start's expert steps to go / solution
    scripted: bool = False          # played by the scripted pre-fill walker, not the agent


class Control:
    """Views over the control blocks; construct in any process from attached blocks."""

    def __init__(self, blocks: SharedBlocks):
        self.stop_flag = blocks["ctl_stop"]            # [1] 0 run, 1 stop
        self.update_count = blocks["ctl_updates"]      # [1] learner updates done
        self.phase_cell = blocks["ctl_phase"]          # [1] adaptive curriculum phase (0: none)
        self.rooms_cell = blocks["ctl_rooms"]          # [1] scheduled room count (0: none)
        self.actor_steps = blocks["ctl_actor_steps"]   # [A] env steps per actor
        # [A, K, 8] ret, length, phase, is_eval, eps, full_task, start_share, scripted
        self.ep_ring = blocks["ctl_ep_ring"]
        self.ep_written = blocks["ctl_ep_written"]     # [A] records written per actor
        self._ep_read = np.zeros(len(self.ep_written), dtype=np.int64)  # reader-local cursor

    @staticmethod
    def specs(num_actors: int) -> list[BlockSpec]:
        """``num_actors`` counts every acting process, the evaluation actor included."""
        a = max(1, num_actors)
        return [
            BlockSpec("ctl_stop", (1,), "i8", fill=0),
            BlockSpec("ctl_updates", (1,), "i8", fill=0),
            BlockSpec("ctl_phase", (1,), "i8", fill=0),
            BlockSpec("ctl_rooms", (1,), "i8", fill=0),
            BlockSpec("ctl_actor_steps", (a,), "i8", fill=0),
            BlockSpec("ctl_ep_ring", (a, EPISODE_RING, len(Episode._fields) - 1), "f8",
                      fill=np.nan),
            BlockSpec("ctl_ep_written", (a,), "i8", fill=0),
        ]

    # -- flags and counters ------------------------------------------------------------------
    def request_stop(self) -> None:
        self.stop_flag[0] = 1

    @property
    def stopping(self) -> bool:
        return bool(self.stop_flag[0])

    @property
    def updates(self) -> int:
        return int(self.update_count[0])

    @updates.setter
    def updates(self, value: int) -> None:
        self.update_count[0] = value

    @property
    def phase(self) -> int:
        return int(self.phase_cell[0])

    @property
    def num_rooms(self) -> int:
        return int(self.rooms_cell[0])

    def show_curriculum(self, curriculum) -> None:
        """Publish a :class:`~dqn_mine.system.curriculum.Curriculum`'s state to the actors."""
        self.phase_cell[0] = curriculum.phase
        self.rooms_cell[0] = curriculum.num_rooms or 0

    def total_actor_steps(self) -> int:
        return int(self.actor_steps.sum())

    # -- episode records ---------------------------------------------------------------------
    def record_episode(self, ep: Episode) -> None:
        """Writer side (actor ``ep.actor`` only): fill the slot, then publish by bumping the
        count."""
        n = int(self.ep_written[ep.actor])
        self.ep_ring[ep.actor, n % EPISODE_RING] = tuple(map(float, ep[1:]))
        self.ep_written[ep.actor] = n + 1

    def drain_episodes(self) -> list[Episode]:
        """Reader side (the learner): every record published since the last call."""
        out: list[Episode] = []
        for actor, written in enumerate(self.ep_written.copy()):
            start = max(int(self._ep_read[actor]), int(written) - EPISODE_RING)
            for n in range(start, int(written)):
                ret, length, phase, is_eval, eps, full, share, scripted = self.ep_ring[
                    actor, n % EPISODE_RING]
                out.append(Episode(actor, float(ret), int(length), int(phase), bool(is_eval),
                                   float(eps), bool(full), float(share), bool(scripted)))
            self._ep_read[actor] = written
        return out
