"""The curriculum: which phase, or how many rooms, the training episodes start with.

The kinds (``--curriculum``):

- ``adaptive`` (three-room): ``phase`` runs from the task's easiest phase down to 1,
  the full task. It moves one phase harder once the mean return of the last ``window`` episodes,
  all started in the current phase, exceeds ``threshold``. With ``review`` > 0 a share of the
  episodes starts in an easier phase already passed (see :meth:`Curriculum.review_phase`);
  with ``curriculum_dr`` > 0 a share starts as the full task with random rooms (domain
  randomisation; recorded as phase 0).
- ``schedule`` (the rooms task): ``num_rooms`` follows the room counts of the schedule, each for
  an equal share of the updates.
- ``backward`` (every task): episodes start on the scripted expert's solution of the episode,
  ``phase`` = d expert steps before its delivery (``dqn_mine.system.backward``). Each start is
  drawn in the frontier (d - step, d]; d moves ``backward_step`` further back once the mean return
  of the last ``window`` frontier episodes exceeds ``threshold``, unless all of them were the full
  task (a start at least the solution's length). With ``review`` > 0 that share of the episodes
  starts nearer the reward, in [1, d - step] (recorded as phase ``REVIEW``).

The object holds no processes and no shared memory: the runner feeds it finished episodes and the
update count and copies ``phase`` and ``num_rooms`` to the shared control block; every actor
builds its own copy from the config and asks it how to start an episode.
"""

from __future__ import annotations

import numpy as np

from dqn_mine.config import Config
from dqn_mine.env.tasks import TASKS, phase_table
from dqn_mine.metrics import LOW_EPSILON, Rolling

DR_PHASE = 0    # what a domain-randomised episode of the adaptive curriculum is recorded under
REVIEW = -1     # what a backward curriculum's review episode is recorded under


class Curriculum:
    """State of a run's curriculum; ``kind`` is one of ``CURRICULA``."""

    def __init__(self, cfg: Config, phase: int | None = None, updates: int = 0):
        """``phase``: a resumed run's adaptive phase (None: start at the easiest); ``updates``:
        the updates already made (the schedule's position)."""
        self.kind = cfg.curriculum
        self.threshold, self.review = cfg.curriculum_threshold, cfg.curriculum_review
        self.dr_share = cfg.curriculum_dr
        self.rooms_schedule = tuple(cfg.rooms_schedule)
        self.total_updates = cfg.updates
        self.phased = self.kind == "adaptive"
        self.backward = self.kind == "backward"
        self.step = cfg.backward_step
        self.easiest = max(phase_table(cfg.task)) if self.phased else 0
        # adaptive: the current phase (1 = the full task); 0 without phases
        self.phase = self._start_phase(phase)
        # schedule: the current room count; None without the schedule
        self.num_rooms: int | None = None
        self.window = cfg.curriculum_window
        self.full_steps = cfg.max_episode_steps or TASKS[cfg.task].step_limit
        self.returns = Rolling(self.window)             # current phase's episodes only
        self.shares = Rolling(self.window)      # backward: their starts' shares of the solution
        self.low_eps_returns = Rolling(self.window)     # those of them at epsilon <= LOW_EPSILON
        self._follow_schedule(updates)

    def _start_phase(self, resumed: int | None) -> int:
        if self.backward:
            return self.step if resumed is None else int(resumed)
        if not self.phased or resumed is None:
            return self.easiest
        return int(resumed)

    # -- the runner's side ---------------------------------------------------------------------
    def record(self, phase: int, ret: float, epsilon: float = float("nan"),
               share: float = float("nan"), scripted: bool = False) -> None:
        """A training episode that started in ``phase``, played at exploration rate ``epsilon``,
        ended with return ``ret``. Every one of the phase counts towards the switch (the
        study's rule) except the scripted pre-fill walker's, which are not the agent's; the
        low-epsilon mean is only shown (an unknown rate, NaN, is not low)."""
        if phase == self.phase and not scripted:
            self.returns.extend([ret])
            self.shares.extend([share])
            if epsilon <= LOW_EPSILON:
                self.low_eps_returns.extend([ret])

    def advance(self, updates: int) -> None:
        """After a batch of recorded episodes: one phase harder when the rolling mean of the
        last ``window`` episodes of the current phase exceeds the threshold; the schedule's room
        count for ``updates`` updates."""
        if self.phased and self.phase > 1 and self._passed():
            self.phase -= 1
            self._clear()
        if self.backward and self.phase < self.full_steps and self._passed() \
                and self.shares.mean < 1.0:     # all full-task starts: nowhere further back
            self.phase = min(self.full_steps, self.phase + self.step)
            self._clear()
        self._follow_schedule(updates)

    def _passed(self) -> bool:
        return len(self.returns) == self.window and self.returns.mean > self.threshold

    def _clear(self) -> None:
        for rolling in (self.returns, self.low_eps_returns, self.shares):
            rolling.clear()

    def _follow_schedule(self, updates: int) -> None:
        if self.kind != "schedule":
            return
        stages = self.rooms_schedule
        stage = min(len(stages) - 1, updates * len(stages) // max(1, self.total_updates))
        self.num_rooms = int(stages[stage])

    @property
    def starts_phases(self) -> bool:
        """Whether this curriculum sets where episodes start (tables or the expert's path)."""
        return self.phased or self.backward

    @property
    def phase_return(self) -> float:
        """Rolling mean return of the current phase's (backward: frontier's) episodes; NaN
        when episodes start as the task does."""
        return self.returns.mean if self.starts_phases else float("nan")

    @property
    def phase_low_eps_return(self) -> float:
        """The same over the current phase's episodes at epsilon <= LOW_EPSILON (NaN if none)."""
        return self.low_eps_returns.mean if self.starts_phases else float("nan")

    @property
    def start_share(self) -> float:
        """Backward: the frontier episodes' starts as a mean share of their solutions (1: the
        full task); 1 when every episode starts as the task does."""
        if self.backward:
            return self.shares.mean
        return float("nan") if self.phased else 1.0

    def is_full_task(self, phase: int) -> bool:
        """Whether an episode recorded under ``phase`` (not backward) began at the task's
        real start."""
        return not self.phased or phase == 1

    @property
    def logged_phase(self) -> int:
        """What metrics.csv's ``phase`` column shows: the phase, or the scheduled room count."""
        return self.num_rooms if self.kind == "schedule" else self.phase

    # -- an actor's side -----------------------------------------------------------------------
    def backward_start(self, d: int, rng: np.random.Generator) -> tuple[int, int]:
        """(phase recorded with the episode, expert steps to go at its start) while the shared
        state says frontier ``d``: in the frontier (d - step, d], or with probability
        ``review`` (once d has moved) nearer, in [1, d - step]."""
        low = max(1, d - self.step + 1)
        if low > 1 and self.review and self._reviews(rng):
            return REVIEW, int(rng.integers(1, low))
        return d, int(rng.integers(low, d + 1))

    def episode_start(self, phase: int, num_rooms: int, rng: np.random.Generator) -> tuple:
        """(phase recorded with the episode, environment settings) for an episode that starts
        while the shared state says ``phase`` and ``num_rooms``."""
        if self.phased:
            if self.dr_share and self._randomises(rng):
                return DR_PHASE, self.dr_settings()
            phase = self.review_phase(phase, rng)
            return phase, self.phase_settings(phase)
        if self.kind == "schedule":
            return phase, {"num_rooms": num_rooms}
        return phase, {}

    def phase_settings(self, phase: int) -> dict:
        """The environment settings of an episode that starts in ``phase``."""
        return {"phase": phase, "placement": "fixed"} if self.dr_share else {"phase": phase}

    def dr_settings(self) -> dict:
        """A domain-randomised episode: the full task's boulders, agent, kit and miner each in
        a random room (which includes every phase's rooms, but no boulder moved aside or kit
        in hand)."""
        return {"phase": None, "placement": "any-room"}

    def review_phase(self, phase: int, rng: np.random.Generator) -> int:
        """The phase an episode starts in: with probability ``review`` an easier one already
        passed (uniformly), else ``phase``. Reviewed episodes keep the rewards of the skills the
        current phase builds on flowing into the replay after a switch; only episodes of the
        current phase count towards the next switch. No random number is drawn without review,
        so the study's rule draws the same episodes as before review existed."""
        if phase >= self.easiest or self.review == 0 or not self._reviews(rng):
            return phase
        return int(rng.integers(phase + 1, self.easiest + 1))

    def _randomises(self, rng: np.random.Generator) -> bool:
        """Whether the next episode is domain-randomised (a draw per episode)."""
        return rng.random() < self.dr_share

    def _reviews(self, rng: np.random.Generator) -> bool:
        """Whether the next episode reviews (a draw per episode)."""
        return rng.random() < self.review
