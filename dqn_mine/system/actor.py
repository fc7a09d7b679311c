"""Actor: owns a few environments, acts epsilon-greedily with one batched forward pass for all of
them, and writes n-step transitions (with initial priorities from its own network) into its
streams of the shared replay. Runs as a spawned process (`actor_main`) or inline (serial mode).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dqn_mine.config import Config, network_shape, resolve_actor_precision


@dataclass(frozen=True)
class ActorSpec:
    """What one acting process needs besides the config and the shared blocks."""

    index: int                   # row in the control block
    streams: tuple               # replay streams written, one per env (empty: evaluation actor)
    epsilon: object              # one rate for every env, or a tuple with one per env
    seed: int
    env_kwargs: dict
    num_envs: int = 1
    follows_curriculum: bool = True


def env_kwargs(cfg: Config, **override) -> dict:
    """Environment keyword arguments of a config (the trainer's envs and the eval env)."""
    kwargs = dict(task=cfg.task, room_size=cfg.room_size,
                  max_episode_steps=cfg.max_episode_steps, placement=cfg.placement,
                  randomise_visuals=cfg.visual_randomisation)
    kwargs.update(override)
    if kwargs["task"] == "rooms":  # the other tasks have a fixed room count
        kwargs.setdefault("num_rooms", cfg.num_rooms)
    return kwargs


class Actor:
    """Acting on ``len(spec.streams)`` environments; ``step()`` advances all of them by one step."""

    def __init__(self, cfg: Config, spec: ActorSpec, storage, control, weights,
                 parent_pid: int | None = None):
        import torch

        from dqn_mine.agent.explore import Explorer
        from dqn_mine.agent.network import DuelingQNetwork
        from dqn_mine.env import MineRescueEnv
        from dqn_mine.replay import NStepWriter

        self.cfg, self.spec, self.control, self.weights = cfg, spec, control, weights
        # A runner killed outright (SIGKILL, the OOM killer) never sets the stop flag: a spawned
        # actor watches its parent instead, or it would act forever and pin the shared memory.
        self.parent_pid = parent_pid
        self.next_parent_check = 0.0
        # The replay-ratio budget counts this process's updates only: a resumed run restores the
        # update counter but its actors start from zero steps.
        self.updates_at_start = control.updates
        self.torch = torch
        self.rng = np.random.default_rng(spec.seed)
        # The evaluation actor measures the greedy policy: plain epsilon, never held actions,
        # never unstuck.
        training = bool(spec.streams)
        self.explorer = Explorer(spec.epsilon, spec.num_envs, self.rng,
                                 durations=cfg.exploration == "ez" and training,
                                 mu=cfg.ez_mu, max_duration=cfg.ez_max_duration,
                                 unstick=cfg.unstick and training)
        self.net = DuelingQNetwork(**network_shape(cfg))
        # Pulled float32 weights are converted on load (WeightBroadcast copies into the tensors).
        self.net.to(resolve_actor_precision(cfg.actor_precision, spec.num_envs)).eval()
        self.version = -1
        self.pull_weights()
        render = {} if spec.streams else {"render_mode": "rgb_array"}  # evaluation videos
        self.envs = [MineRescueEnv(**spec.env_kwargs, **render) for _ in range(spec.num_envs)]
        self.writers = ([NStepWriter(storage, stream=s, eta=cfg.eta) for s in spec.streams]
                        if spec.streams else None)
        # Kept here rather than read from the writers so the evaluation actor, which writes no
        # replay, feeds its network exactly the same input.
        self.histories = np.full((len(self.envs), cfg.history_len), -1, dtype=np.int8)  # [E, h]
        self.returns = np.zeros(len(self.envs))
        self.phases = np.zeros(len(self.envs), dtype=np.int64)
        self.lengths = np.zeros(len(self.envs), dtype=np.int64)
        self.steps = 0
        self.episodes = 0
        self.evaluations = 0
        self.recording: list | None = None  # frames of an evaluation episode being recorded
        f, (c, h, w) = cfg.frame_stack, self.envs[0].observation_space.shape
        self.stacks = np.zeros((len(self.envs), f * c, h, w), dtype=np.uint8)  # [E, 3f, H, W]
        self.carrying = np.zeros(len(self.envs), dtype=np.float32)
        self.stuck = np.zeros(len(self.envs), dtype=bool)   # frame unchanged by the last step
        for j, env in enumerate(self.envs):
            self.apply_curriculum(j)
            obs, info = env.reset(seed=spec.seed * 1000 + j)
            self._begin(j, obs, info)

    # -- episode bookkeeping -----------------------------------------------------------------
    def _begin(self, j: int, obs: np.ndarray, info: dict) -> None:
        self.stacks[j] = 0
        self._push_frame(j, obs)
        self.carrying[j] = float(info["carrying"])
        self.returns[j], self.lengths[j] = 0.0, 0
        self.histories[j] = -1
        self.stuck[j] = False
        self.explorer.reset(j)
        if self.writers:
            self.writers[j].begin_episode(obs, bool(info["carrying"]))

    def _push_frame(self, j: int, obs: np.ndarray) -> None:
        c = obs.shape[0]
        self.stacks[j, :-c] = self.stacks[j, c:]   # oldest frame first, newest last
        self.stacks[j, -c:] = obs

    def _end_episode(self, j: int) -> None:
        if j == 0 and self.recording is not None:
            self._save_recording()  # before reset: the last frame shows how it ended
        self.control.record_episode(self.spec.index, float(self.returns[j]),
                                    int(self.lengths[j]), int(self.phases[j]),
                                    is_eval=not self.spec.streams)
        self.episodes += 1
        if self.spec.streams:  # the evaluation actor keeps one version for a whole evaluation
            self.pull_weights()   # actors pick up new weights between episodes
        self.apply_curriculum(j)
        obs, info = self.envs[j].reset()
        self._begin(j, obs, info)

    def apply_curriculum(self, j: int) -> None:
        """Read the shared curriculum state between episodes and set it on environment j (the
        episode is recorded under the phase it started in)."""
        phase = self.phases[j] = self.control.phase
        if not self.spec.follows_curriculum:
            return
        if self.cfg.curriculum == "adaptive":
            phase = self.phases[j] = review_phase(self.cfg, phase, self.rng)
            self.envs[j].phase = phase
        elif self.cfg.curriculum == "schedule":
            self.envs[j].num_rooms = phase

    def pull_weights(self) -> None:
        version = self.weights.pull(self.net, self.version)
        if version is not None:
            self.version = version

    # -- acting ------------------------------------------------------------------------------
    def q_values(self, stacks: np.ndarray, histories: np.ndarray,
                 carrying: np.ndarray) -> np.ndarray:
        torch = self.torch
        with torch.inference_mode():
            q = self.net(torch.from_numpy(stacks), torch.from_numpy(histories),
                         torch.from_numpy(carrying))
        return q.float().numpy()                                    # [E, A], float32

    def step(self) -> int:
        """One step of every environment; returns the number of env steps taken."""
        q = self.q_values(self.stacks, self.histories, self.carrying)  # [E, A]
        actions = self.explorer.act(q.argmax(axis=1), self.stuck)
        for j, env in enumerate(self.envs):
            self._step_env(j, env, int(actions[j]), q[j])
        self.steps += len(self.envs)
        if self.spec.streams:  # evaluation steps are not training experience
            self.control.actor_steps[self.spec.index] = self.steps
        return len(self.envs)

    def _step_env(self, j: int, env, action: int, q: np.ndarray) -> None:
        obs, reward, terminated, truncated, info = env.step(action)
        self.returns[j] += reward
        self.lengths[j] += 1
        if self.explorer.unstick:
            self.stuck[j] = np.array_equal(obs, self.stacks[j, -obs.shape[0]:])
        self._push_frame(j, obs)
        self.carrying[j] = float(info["carrying"])
        if self.cfg.history_len:
            self.histories[j, :-1] = self.histories[j, 1:]   # oldest first, newest last
            self.histories[j, -1] = action
        if self.writers:
            next_q = None
            if truncated and not terminated:
                # A time limit is not a terminal state: the final frame is bootstrapped from,
                # so its value enters the initial priority. Rare enough for a batch-1 forward.
                next_q = self.q_values(self.stacks[j:j + 1], self.histories[j:j + 1],
                                       self.carrying[j:j + 1])[0]
            self.writers[j].append(q, action, float(reward), obs, bool(info["carrying"]),
                                   bool(terminated), bool(truncated), next_q=next_q)
        if terminated or truncated:
            self._end_episode(j)

    # -- loop --------------------------------------------------------------------------------
    def allowed_steps(self) -> float:
        """Step budget under a fixed replay ratio (inf when free-running)."""
        return actor_step_budget(self.cfg, self.control.updates - self.updates_at_start)

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

    def run(self) -> None:
        if not self.spec.streams:
            return self.run_evaluations()
        while not self.should_stop():
            if self.steps >= self.allowed_steps():
                time.sleep(0.002)
                continue
            self.step()
        self.close()

    def run_evaluations(self) -> None:
        """Evaluation actor: ``eval_episodes`` episodes with the latest weights every
        ``eval_every`` training env steps (paced by the training actors so that evaluation
        does not steal cores from them)."""
        next_at = self.cfg.eval_every
        while not self.should_stop():
            if self.control.total_actor_steps() < next_at:
                time.sleep(0.05)
                continue
            self.evaluate(self.cfg.eval_episodes)
            # From now, not from the missed mark: a long evaluation (many actors stepping
            # meanwhile) must not leave a backlog that keeps the evaluator busy for good.
            next_at = max(next_at, self.control.total_actor_steps()) + self.cfg.eval_every
        self.close()

    def evaluate(self, episodes: int) -> None:
        """Run ``episodes`` episodes; now and then record the first one as a GIF."""
        self.pull_weights()
        every = self.cfg.eval_video_every
        self.evaluations += 1
        if every and self.cfg.run_dir and (self.evaluations - 1) % every == 0:
            self.recording = [self.envs[0].render()]
        target = self.episodes + episodes
        while self.episodes < target and not self.should_stop():
            self.step()
            if self.recording is not None:
                self.recording.append(self.envs[0].render())

    def _save_recording(self) -> None:
        from dqn_mine.video import save_gif

        frames, self.recording = self.recording, None
        name = f"eval_{self.control.total_actor_steps():010d}.gif"
        save_gif(frames, Path(self.cfg.run_dir) / "videos" / name, fps=15)

    def close(self) -> None:
        for w in self.writers or ():
            w.flush()
        for env in self.envs:
            env.close()


def actor_main(cfg: Config, spec: ActorSpec, handle: tuple, errors) -> None:
    """Entry point of a spawned actor process."""
    # The runner handles Ctrl-C and tells actors to stop through shared state; an actor that
    # died on SIGINT mid-write would leave a half-published block.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # The runner's pid as the runner gave it: a getppid() here could already read 1 if the
    # runner died while this process was still starting.
    parent = multiprocessing.parent_process().pid
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    blocks = None
    try:
        import torch

        torch.set_num_threads(1)
        blocks, storage, control, weights = attach_all(cfg, handle)
        Actor(cfg, spec, storage, control, weights, parent_pid=parent).run()
    except BaseException as exc:  # report every failure to the runner, then exit non-zero
        errors.send((spec.index, f"{type(exc).__name__}: {exc}", traceback.format_exc()))
        raise SystemExit(1) from None
    finally:
        if blocks is not None:
            blocks.close()


def attach_all(cfg: Config, handle: tuple):
    """Attach the run's blocks and build the views an acting process needs."""
    from dqn_mine.replay import ReplayStorage
    from dqn_mine.shared import SharedBlocks
    from dqn_mine.system.control import Control
    from dqn_mine.system.layout import replay_layout
    from dqn_mine.system.weights import WeightBroadcast

    blocks = SharedBlocks.attach(handle)
    return blocks, ReplayStorage(replay_layout(cfg), blocks), Control(blocks), \
        WeightBroadcast(blocks)


def initial_phase(cfg: Config) -> int:
    """Start of the curriculum: the easiest phase (6 of three-room, 5 of two-room), or the first
    room count."""
    if cfg.curriculum == "adaptive":
        from dqn_mine.env.tasks import TASK_PHASES

        return max(TASK_PHASES[cfg.task])
    if cfg.curriculum == "schedule":
        return int(cfg.rooms_schedule[0])
    return 0


def review_phase(cfg: Config, phase: int, rng: np.random.Generator) -> int:
    """The phase an episode starts in: with probability ``curriculum_review`` an easier one
    already passed (uniformly), else ``phase``. Reviewed episodes keep the rewards of the skills
    the current phase builds on flowing into the replay after a switch (without them the replay
    soon holds only the new phase's failures and what was learned decays); the curriculum's
    rolling mean counts only episodes of the current phase."""
    easiest = initial_phase(cfg)
    review = cfg.curriculum_review
    if phase >= easiest or review == 0 or not rng.random() < review:
        return phase
    return int(rng.integers(phase + 1, easiest + 1))


def actor_specs(cfg: Config, generation: int = 0) -> list[ActorSpec]:
    """One spec per training actor (streams numbered actor-major), then the evaluation actor.

    ``generation`` counts the starts of a run (0, then +1 per resume): each draws new seeds."""
    from dqn_mine.agent.learning import epsilon_for_actor

    e = cfg.envs_per_actor
    specs = []
    for i in range(cfg.actors):
        # Ape-X gives every environment instance its own rate: with several envs per actor the
        # schedule runs over all of them, or 2 actors x 16 envs would have only two rates.
        eps = cfg.epsilon if cfg.epsilon_schedule == "fixed" else \
            tuple(epsilon_for_actor(i * e + j, cfg.actors * e) for j in range(e))
        specs.append(ActorSpec(index=i, streams=tuple(range(i * e, (i + 1) * e)), epsilon=eps,
                               seed=actor_seed(cfg.seed, i, generation),
                               env_kwargs=env_kwargs(cfg), num_envs=e))
    if cfg.eval_every:
        specs.append(ActorSpec(index=cfg.actors, streams=(), epsilon=cfg.eval_epsilon,
                               seed=actor_seed(cfg.seed, 7000 + cfg.actors, generation),
                               env_kwargs=eval_env_kwargs(cfg), follows_curriculum=False))
    return specs


def actor_seed(seed: int, index: int, generation: int = 0) -> int:
    """Seed of acting process ``index``; a resumed run (generation > 0) draws fresh ones."""
    if generation == 0:
        return seed * 7919 + index
    return int(np.random.SeedSequence([seed, index, generation]).generate_state(1)[0])


def eval_env_kwargs(cfg: Config) -> dict:
    """The target task: the full problem, fixed placement and look, the schedule's last room
    count."""
    override = {"placement": "fixed", "randomise_visuals": False}
    if cfg.eval_task and cfg.eval_task != cfg.task:
        override.update(task=cfg.eval_task, max_episode_steps=None)
    if cfg.curriculum == "schedule":
        override["num_rooms"] = int(cfg.rooms_schedule[-1])
    return env_kwargs(cfg, **override)


def prefill_target(cfg: Config) -> int:
    """Env steps all actors together must publish before the learner starts."""
    return cfg.prefill * cfg.actors


# Under --replay-ratio both sides count from the same point, the nominal pre-fill
# (prefill_target): the learner may make ratio * (steps - prefill_target) updates, and each actor
# may step prefill + its share of updates / ratio, plus slack. Counting the learner from the steps
# measured when pre-fill ended instead (which overshoot the nominal pre-fill) deadlocks once every
# actor has reached its cap by then: no new steps, so no updates, so no new budget.

def actor_step_budget(cfg: Config, updates: int) -> float:
    """Env steps one actor may have taken after ``updates`` updates of this run (inf: no limit)."""
    if not cfg.replay_ratio:
        return float("inf")
    actors = max(1, cfg.actors)
    share = updates / cfg.replay_ratio / actors
    slack = 2 * cfg.batch_size / cfg.replay_ratio / actors + 64
    return cfg.prefill + share + slack


def learner_may_update(cfg: Config, updates: int, actor_steps: int) -> bool:
    """Whether the learner, after ``updates`` updates of this run, may make another one while the
    actors have taken ``actor_steps`` env steps in all (always, when free-running)."""
    if not cfg.replay_ratio:
        return True
    return updates < cfg.replay_ratio * (actor_steps - prefill_target(cfg))


def first_error(conn) -> tuple | None:
    """The error an actor reported on its pipe, if any (non-blocking)."""
    try:
        return conn.recv() if conn.poll() else None
    except (EOFError, OSError):  # closed without a report: the exit code tells the rest
        return None
