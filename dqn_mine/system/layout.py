"""Every shared block of a run, in one list: replay storage, control state, weights."""

from __future__ import annotations

from dqn_mine.config import Config
from dqn_mine.shared import BlockSpec


def replay_layout(cfg: Config):
    from dqn_mine.replay import ReplayLayout

    return ReplayLayout.from_capacity(cfg.replay_capacity, cfg.num_streams,
                                      history_len=cfg.history_len, n_step=cfg.n_step,
                                      gamma=cfg.gamma, frame_stack=cfg.frame_stack)


def run_block_specs(cfg: Config, net) -> list[BlockSpec]:
    from dqn_mine.system.control import Control
    from dqn_mine.system.weights import WeightBroadcast

    return (replay_layout(cfg).block_specs() + Control.specs(cfg.acting_processes)
            + WeightBroadcast.specs(net))
