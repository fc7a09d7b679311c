"""Every shared block of a run, in one list: replay storage, control state, weights."""

from __future__ import annotations

from dqn_mine.config import Config
from dqn_mine.shared import BlockSpec


def replay_layout(cfg: Config, demo_streams: int = 0):
    """One ring per training environment (``--replay-capacity`` split evenly), then
    ``demo_streams`` rings of the same size for the demonstrations (``dqn_mine.demos``)."""
    from dqn_mine.replay import ReplayLayout

    return ReplayLayout(num_streams=cfg.num_streams + demo_streams,
                        stream_capacity=cfg.replay_capacity // cfg.num_streams,
                        history_len=cfg.history_len, n_step=cfg.n_step, gamma=cfg.gamma,
                        frame_stack=cfg.frame_stack, demo_streams=demo_streams)


def run_block_specs(cfg: Config, net, demo_streams: int = 0) -> list[BlockSpec]:
    from dqn_mine.system.control import Control
    from dqn_mine.system.weights import WeightBroadcast

    return (replay_layout(cfg, demo_streams).block_specs()
            + Control.specs(cfg.acting_processes) + WeightBroadcast.specs(net))


def demo_ring_frames(cfg: Config) -> int:
    """Frames a demonstration ring holds without ever overwriting one (stacking looks back)."""
    return replay_layout(cfg).stream_capacity - (cfg.frame_stack - 1)


def run_demos(cfg: Config, progress: bool = False):
    """The demonstrations ``cfg`` asks for (``dqn_mine.demos.DemoSet``), None without any."""
    from dqn_mine.demos import DemoSet

    frames = demo_ring_frames(cfg)
    if cfg.demos_from:
        return DemoSet.from_folder(cfg.demos_from, frames)
    if not cfg.demos:
        return None
    from dqn_mine.env import MineRescueEnv
    from dqn_mine.system.specs import env_kwargs

    return DemoSet.from_expert(MineRescueEnv(**env_kwargs(cfg)), cfg.demos, cfg.seed, frames,
                               progress)
