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

from dqn_mine.config import PHASED_CURRICULA, Config
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
        self.review_by_steps = cfg.curriculum_review_unit == "steps"
        self.dr_share = cfg.curriculum_dr
        # an actor's steps since the phase it last saw changed: all, and those of review episodes
        self.seen_phase, self.played_steps, self.review_steps = None, 0, 0
        # an actor's steps over its whole run: all, and those of domain-randomised episodes
        self.all_steps, self.dr_steps = 0, 0
        self.rooms_schedule = tuple(cfg.rooms_schedule)
        self.total_updates = cfg.updates
        self.phased = self.kind in PHASED_CURRICULA
        self.backward = self.kind == "backward"
        self.step = cfg.backward_step
        self.easiest = max(phase_table(cfg.task, self.kind == "boulders")) if self.phased else 0
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
            if phase != self.seen_phase:
                self.seen_phase, self.played_steps, self.review_steps = phase, 0, 0
            if self.dr_share and self._randomises(rng):
                return DR_PHASE, self.dr_settings()
            phase = self.review_phase(phase, rng)
            return phase, self.phase_settings(phase)
        if self.kind == "schedule":
            return phase, {"num_rooms": num_rooms}
        return phase, {}

    def played(self, phase: int, steps: int) -> None:
        """An episode this actor started in ``phase`` ended after ``steps`` steps. Episodes of a
        phase easier than the current one count as review (also those started before a switch:
        they are what the replay gets from passed phases)."""
        self.all_steps += steps
        if self.backward:
            self.played_steps += steps
            self.review_steps += steps if phase == REVIEW else 0
            return
        if phase == DR_PHASE:
            self.dr_steps += steps
            return      # neither the current phase's nor a review: outside that count
        self.played_steps += steps
        if self.seen_phase is not None and phase > self.seen_phase:
            self.review_steps += steps

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
        so the study's rule draws the same episodes as before review existed.

        ``curriculum_review_unit`` "steps" makes ``review`` a share of the actor's steps, not of
        its episodes: a passed phase's successful episode is short and a new phase's failing one
        runs to the step limit (docs/three_room.md)."""
        if phase >= self.easiest or self.review == 0 or not self._reviews(rng):
            return phase
        return int(rng.integers(phase + 1, self.easiest + 1))

    def _randomises(self, rng: np.random.Generator) -> bool:
        """Whether the next episode is domain-randomised: a draw per episode, or while such
        episodes have played less than ``curriculum_dr`` of all the actor's steps (no draw). A
        randomised full task mostly runs to its 2,000-step limit, so on three-room 30% of the
        episodes are a third of the steps while the phase's own episodes fail too, and about half
        once they take 800 steps: by episodes, the share grows as the phase is learned."""
        if self.review_by_steps:
            return self.dr_steps < self.dr_share * self.all_steps
        return rng.random() < self.dr_share

    def _reviews(self, rng: np.random.Generator) -> bool:
        """Whether the next episode reviews: a draw per episode, or while review episodes have
        played less than ``review`` of the steps since the phase switch (no draw)."""
        if self.review_by_steps:
            return self.review_steps < self.review * self.played_steps
        return rng.random() < self.review
