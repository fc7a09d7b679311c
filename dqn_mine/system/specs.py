"""What each acting process is told: its role, environments, exploration rates and seed.

Training actors come first (actor ``i`` writes replay streams ``i*E .. (i+1)*E - 1``), then the
evaluation actor when ``--eval-every`` is on; its row in the control block is ``cfg.actors``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dqn_mine.config import Config
from dqn_mine.env.mine import VIEWS

# The evaluation actor plays near-greedily, as Ape-X's and the study's did: a learned policy
# should not need held or unstick random actions to deliver.
EVAL_EPSILON = 0.01


@dataclass(frozen=True)
class ActorSpec:
    """What one acting process needs besides the config and the shared blocks."""

    index: int                   # row in the control block
    streams: tuple               # replay streams written, one per env (empty: evaluation actor)
    epsilon: object              # one rate for every env, or a tuple with one per env
    seed: int
    env_kwargs: dict
    num_envs: int = 1

    @property
    def evaluates(self) -> bool:
        """The evaluation actor writes no replay stream."""
        return not self.streams


def env_kwargs(cfg: Config, **override) -> dict:
    """Environment keyword arguments of a config (the trainer's envs and the eval env)."""
    kwargs = dict(task=cfg.task, room_size=cfg.room_size,
                  max_episode_steps=cfg.max_episode_steps, placement=cfg.placement)
    kwargs.update(override)
    kwargs.update(VIEWS[cfg.view])
    if kwargs["task"] == "rooms":  # the other tasks have a fixed room count
        kwargs.setdefault("num_rooms", cfg.num_rooms)
    return kwargs


def eval_env_kwargs(cfg: Config) -> dict:
    """The target task: the full problem, fixed placement, ``eval_num_rooms`` or the schedule's
    last room count."""
    override: dict = {"placement": "fixed"}
    if cfg.curriculum == "schedule":
        override["num_rooms"] = int(cfg.rooms_schedule[-1])
    if cfg.eval_num_rooms is not None:
        override["num_rooms"] = cfg.eval_num_rooms
    return env_kwargs(cfg, **override)


def actor_specs(cfg: Config, generation: int = 0) -> list[ActorSpec]:
    """One spec per training actor (streams numbered actor-major), then the evaluation actor.

    ``generation`` counts the starts of a run (0, then +1 per resume): each draws new seeds."""
    specs = [_training_spec(cfg, i, generation) for i in range(cfg.actors)]
    if cfg.eval_every:
        specs.append(ActorSpec(index=cfg.actors, streams=(), epsilon=EVAL_EPSILON,
                               seed=actor_seed(cfg.seed, 7000 + cfg.actors, generation),
                               env_kwargs=eval_env_kwargs(cfg)))
    return specs


def _training_spec(cfg: Config, i: int, generation: int) -> ActorSpec:
    from dqn_mine.agent.learning import epsilon_for_actor

    e = cfg.envs_per_actor
    # Ape-X gives every environment instance its own rate: with several envs per actor the
    # schedule runs over all of them, or 2 actors x 16 envs would have only two rates.
    eps = cfg.epsilon if cfg.epsilon_schedule == "fixed" else \
        tuple(epsilon_for_actor(i * e + j, cfg.num_streams) for j in range(e))
    return ActorSpec(index=i, streams=tuple(range(i * e, (i + 1) * e)), epsilon=eps,
                     seed=actor_seed(cfg.seed, i, generation), env_kwargs=env_kwargs(cfg),
                     num_envs=e)


def actor_seed(seed: int, index: int, generation: int = 0) -> int:
    """Seed of acting process ``index``; a resumed run (generation > 0) draws fresh ones."""
    if generation == 0:
        return seed * 7919 + index
    return int(np.random.SeedSequence([seed, index, generation]).generate_state(1)[0])
