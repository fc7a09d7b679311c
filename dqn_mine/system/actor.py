"""Acting processes: a training :class:`Actor` and, in ``evaluator``, the evaluation actor.

Both step a few environments with one batched forward pass through the shared acting core
(``dqn_mine.agent.acting``) and load the weights the learner broadcasts. A training actor also
writes n-step transitions (with initial priorities from its own network) into its streams of the
shared replay, follows the curriculum and keeps to the replay-ratio budget. Each runs as a spawned
process (``dqn_mine.system.pool``) or inline in the runner's process (serial mode).
"""

from __future__ import annotations

import os
import time

import numpy as np

from dqn_mine.config import Config, network_shape, resolve_actor_precision
from dqn_mine.system.backward import PathStarts
from dqn_mine.system.control import Episode
from dqn_mine.system.curriculum import Curriculum
from dqn_mine.system.pacing import ActorPace
from dqn_mine.system.specs import ActorSpec


class ActorBase:
    """What both kinds of actor share: environments, acting core, weights, episode records."""

    def __init__(self, cfg: Config, spec: ActorSpec, control, weights, training: bool,
                 parent_pid: int | None = None, render_mode: str | None = None):
        from dqn_mine.agent.acting import ActingCore
        from dqn_mine.agent.explore import BumpAndPress, Explorer, PrefillFirst
        from dqn_mine.agent.network import DuelingQNetwork, lower_heavy_layers
        from dqn_mine.env import MineRescueEnv

        self.cfg, self.spec, self.control, self.weights = cfg, spec, control, weights
        # A runner killed outright (SIGKILL, the OOM killer) never sets the stop flag: a spawned
        # actor watches its parent instead, or it would act forever and pin the shared memory.
        self.parent_pid = parent_pid
        self.next_parent_check = 0.0
        self.rng = np.random.default_rng(spec.seed)
        # Held and unstick actions are for training: the evaluation actor measures the
        # near-greedy policy with plain epsilon.
        explorer = Explorer(spec.epsilon, spec.num_envs, self.rng,
                            durations=training and cfg.exploration == "ez",
                            unstick=training and cfg.unstick > 0)
        if training and cfg.prefill_explorer == "bump-and-press" and cfg.prefill:
            explorer = PrefillFirst(BumpAndPress(spec.num_envs, self.rng), explorer, cfg.prefill)
        # Pulled float32 weights are converted on load (WeightBroadcast copies into the tensors).
        self.net = lower_heavy_layers(DuelingQNetwork(**network_shape(cfg)),
                                      resolve_actor_precision(cfg.precision,
                                                              spec.num_envs)).eval()
        self.version = -1            # of the weights loaded (WeightBroadcast's publish count)
        self.pull_weights()
        self.envs = [MineRescueEnv(**spec.env_kwargs, render_mode=render_mode)
                     for _ in range(spec.num_envs)]
        self.core = ActingCore(self.net, explorer, spec.num_envs, cfg.frame_stack,
                               cfg.history_len, max(1, cfg.unstick))
        self.returns = np.zeros(spec.num_envs)
        self.lengths = np.zeros(spec.num_envs, dtype=np.int64)
        self.phases = np.zeros(spec.num_envs, dtype=np.int64)   # each episode's start phase
        self.full = np.ones(spec.num_envs, dtype=bool)          # ... whether the real start
        self.shares = np.full(spec.num_envs, np.nan)            # ... backward: its share
        self.steps = 0
        self.episodes = 0

    def start_envs(self) -> None:
        """Reset every environment with its seed (the first episode of each)."""
        for j in range(len(self.envs)):
            self.new_episode(j, seed=self.spec.seed * 1000 + j)

    def new_episode(self, j: int, seed: int | None = None) -> None:
        """Start environment j's next episode where the curriculum says."""
        self.apply_curriculum(j)
        self._begin(j, *self.reset_env(j, seed))

    def reset_env(self, j: int, seed: int | None) -> tuple:
        """(obs, info) of environment j's next episode."""
        return self.envs[j].reset(seed=seed)

    def pull_weights(self) -> None:
        version = self.weights.pull(self.net, self.version)
        if version is not None:
            self.version = version

    def apply_curriculum(self, j: int) -> None:
        """Between episodes: where environment j's next episode starts (the evaluation actor:
        always the full task, recorded as phase 0 and ``full``)."""

    # -- stepping ------------------------------------------------------------------------------
    def step(self) -> int:
        """One step of every environment; returns the number of env steps taken."""
        actions, q = self.core.act()                                   # [E], [E, A]
        for j, env in enumerate(self.envs):
            self._step_env(j, env, int(actions[j]), q[j])
        self.steps += len(self.envs)
        return len(self.envs)

    def _step_env(self, j: int, env, action: int, q: np.ndarray) -> None:
        obs, reward, terminated, truncated, info = env.step(action)
        self.returns[j] += reward
        self.lengths[j] += 1
        self.core.observe(j, action, obs, info["carrying"])
        self.after_step(j, q, action, float(reward), obs, info, terminated, truncated)
        if terminated or truncated:
            self._end_episode(j)

    def after_step(self, j, q, action, reward, obs, info, terminated, truncated) -> None:
        """What a kind of actor does with a step besides acting on it."""

    def _begin(self, j: int, obs: np.ndarray, info: dict) -> None:
        self.core.begin(j, obs, info["carrying"])
        self.returns[j], self.lengths[j] = 0.0, 0

    def _end_episode(self, j: int) -> None:
        record = Episode(self.spec.index, float(self.returns[j]), int(self.lengths[j]),
                         int(self.phases[j]), self.spec.evaluates,
                         float(self.core.explorer.epsilon[j]), bool(self.full[j]),
                         float(self.shares[j]), self.core.explorer.scripted)
        self.episodes += 1
        self.between_episodes(j)
        self.new_episode(j)
        self.control.record_episode(record)

    def between_episodes(self, j: int) -> None:
        """What a kind of actor does after an episode of environment j ended, before the next."""

    # -- stopping ------------------------------------------------------------------------------
    def should_stop(self) -> bool:
        """The runner asked to stop, or it is gone (checked about once a second)."""
        if self.control.stopping:
            return True
        if self.parent_pid is None:
            return False
        now = time.monotonic()
        if now < self.next_parent_check:
            return False
        self.next_parent_check = now + 1.0
        return os.getppid() != self.parent_pid   # re-parented: the runner died

    def close(self) -> None:
        for env in self.envs:
            env.close()


class Actor(ActorBase):
    """A training actor on ``len(spec.streams)`` environments, one replay stream each."""

    def __init__(self, cfg: Config, spec: ActorSpec, storage, control, weights,
                 parent_pid: int | None = None):
        from dqn_mine.replay import NStepWriter

        self.curriculum = Curriculum(cfg)
        self.pace = ActorPace(cfg, control)
        super().__init__(cfg, spec, control, weights, training=True, parent_pid=parent_pid)
        self.to_go = np.zeros(spec.num_envs, dtype=np.int64)   # backward: each start's
        self.paths = [PathStarts(np.random.default_rng([spec.seed, j]), env.max_episode_steps)
                      for j, env in enumerate(self.envs)] if self.curriculum.backward else None
        self.writers = [NStepWriter(storage, stream=s) for s in spec.streams]
        self.start_envs()

    def apply_curriculum(self, j: int) -> None:
        """Read the shared curriculum state and set it on environment j (the episode is recorded
        under the phase it started in)."""
        if self.curriculum.backward:
            self.phases[j], self.to_go[j] = self.curriculum.backward_start(self.control.phase,
                                                                           self.rng)
            return
        phase, settings = self.curriculum.episode_start(self.control.phase,
                                                        self.control.num_rooms, self.rng)
        self.phases[j], self.full[j] = phase, self.curriculum.is_full_task(phase)
        for name, value in settings.items():
            setattr(self.envs[j], name, value)

    def reset_env(self, j: int, seed: int | None) -> tuple:
        """Backward: on the expert's path of a seed of the env's own (``seed`` is for the
        first episode of an env that follows the task's own starts)."""
        if self.paths is None:
            return super().reset_env(j, seed)
        obs, info, self.full[j], self.shares[j] = self.paths[j].reset(self.envs[j],
                                                                      int(self.to_go[j]))
        return obs, info

    def _begin(self, j: int, obs: np.ndarray, info: dict) -> None:
        super()._begin(j, obs, info)
        self.writers[j].begin_episode(obs, bool(info["carrying"]))

    def step(self) -> int:
        taken = super().step()
        self.control.actor_steps[self.spec.index] = self.steps
        return taken

    def after_step(self, j, q, action, reward, obs, info, terminated, truncated) -> None:
        next_q = None
        if truncated and not terminated:
            # A time limit is not a terminal state: the final frame is bootstrapped from, so its
            # value enters the initial priority. Rare enough for a batch-1 forward.
            next_q = self.core.q_values(slice(j, j + 1))[0]
        self.writers[j].append(q, action, reward, obs, bool(info["carrying"]),
                               bool(terminated), bool(truncated), next_q=next_q)

    def between_episodes(self, j: int) -> None:
        self.pull_weights()   # actors pick up new weights between episodes

    # -- loop ----------------------------------------------------------------------------------
    def allowed_steps(self) -> float:
        return self.pace.allowed_steps()

    def advance(self) -> None:
        """Serial mode: one step of every environment, if the budget allows it."""
        if self.steps < self.allowed_steps():
            self.step()

    def run(self) -> None:
        while not self.should_stop():
            if self.steps >= self.allowed_steps():
                time.sleep(0.002)
                continue
            self.step()
        self.close()

    def close(self) -> None:
        for w in self.writers:
            w.flush()
        super().close()
