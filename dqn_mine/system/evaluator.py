"""The evaluation actor: the near-greedy policy on the full target task, now and then.

Every ``eval_every`` training env steps it plays ``eval_episodes`` episodes with the latest
weights (one version for a whole evaluation), records them with ``is_eval`` so the runner logs
``eval_return``, and saves a GIF of the first one every ``VIDEO_EVERY`` evaluations. Being
paced by the training actors' steps, it does not steal cores from them in between.
"""

from __future__ import annotations

import time
from pathlib import Path

from dqn_mine.config import Config
from dqn_mine.system.actor import ActorBase
from dqn_mine.system.specs import ActorSpec

VIDEO_EVERY = 10   # evaluations between GIFs of an evaluation episode


class EvalActor(ActorBase):
    """Plain epsilon 0.01, no held or unstick actions; writes no replay."""

    def __init__(self, cfg: Config, spec: ActorSpec, control, weights,
                 parent_pid: int | None = None):
        super().__init__(cfg, spec, control, weights, training=False, parent_pid=parent_pid,
                         render_mode="rgb_array")
        self.evaluations = 0
        self.next_at = cfg.eval_every            # training env steps of the next evaluation
        self.recording: list | None = None       # frames of an episode being recorded
        self.start_envs()

    def evaluate_if_due(self) -> bool:
        """Evaluate when the training actors have stepped past the next mark."""
        if self.control.total_actor_steps() < self.next_at:
            return False
        self.evaluate(self.cfg.eval_episodes)
        # From now, not from the missed mark: a long evaluation (many actors stepping meanwhile)
        # must not leave a backlog that keeps the evaluator busy for good.
        self.next_at = max(self.next_at, self.control.total_actor_steps()) + self.cfg.eval_every
        return True

    def evaluate(self, episodes: int) -> None:
        """Run ``episodes`` episodes; now and then record the first one as a GIF."""
        self.pull_weights()
        self.evaluations += 1
        if self.cfg.run_dir and (self.evaluations - 1) % VIDEO_EVERY == 0:
            self.recording = [self.envs[0].render()]
        target = self.episodes + episodes
        while self.episodes < target and not self.should_stop():
            self.step()
            if self.recording is not None:
                self.recording.append(self.envs[0].render())

    def _end_episode(self, j: int) -> None:
        if j == 0 and self.recording is not None:
            self._save_recording()  # before reset: the last frame shows how it ended
        super()._end_episode(j)

    def _save_recording(self) -> None:
        from dqn_mine.video import save_gif

        frames, self.recording = self.recording, None
        name = f"eval_{self.control.total_actor_steps():010d}.gif"
        save_gif(frames, Path(self.cfg.run_dir) / "videos" / name, fps=15)

    # -- loop ----------------------------------------------------------------------------------
    def advance(self) -> None:
        """Serial mode: evaluate when due."""
        self.evaluate_if_due()

    def run(self) -> None:
        while not self.should_stop():
            if not self.evaluate_if_due():
                time.sleep(0.05)
        self.close()
