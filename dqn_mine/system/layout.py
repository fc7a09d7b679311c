"""Every shared block of a run, in one list: replay storage, control state, weights."""

from __future__ import annotations

from dqn_mine.config import Config
from dqn_mine.system.shared import BlockSpec

FRAME_SHAPE = (3, 44, 76)


def num_streams(cfg: Config) -> int:
    """One replay stream (ring) per training environment."""
    return cfg.actors * cfg.envs_per_actor


def replay_layout(cfg: Config):
    from dqn_mine.replay import ReplayLayout

    streams = num_streams(cfg)
    return ReplayLayout(num_streams=streams, stream_capacity=cfg.replay_capacity // streams,
                        frame_shape=FRAME_SHAPE, history_len=cfg.history_len,
                        n_step=cfg.n_step, gamma=cfg.gamma, frame_stack=cfg.frame_stack)


def acting_processes(cfg: Config) -> int:
    """Training actors plus the evaluation actor (when evaluation is on)."""
    return cfg.actors + (1 if getattr(cfg, "eval_every", 0) else 0)


def run_block_specs(cfg: Config, net) -> list[BlockSpec]:
    from dqn_mine.system.control import Control
    from dqn_mine.system.weights import WeightBroadcast

    return (replay_layout(cfg).block_specs() + Control.specs(acting_processes(cfg))
            + WeightBroadcast.specs(net))
