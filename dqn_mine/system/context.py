"""What a run is made of, built in one place: shared blocks, control, replay storage, weights,
learner and actors (see docs/design.md for how they talk)."""

from __future__ import annotations

import dataclasses

from dqn_mine.config import Config, network_shape, resolve_device
from dqn_mine.system.layout import replay_layout, run_block_specs


def attach_views(cfg: Config, handle: tuple):
    """In an acting process: attach the run's blocks and build the views it needs."""
    from dqn_mine.replay import ReplayStorage
    from dqn_mine.shared import SharedBlocks
    from dqn_mine.system.control import Control
    from dqn_mine.system.weights import WeightBroadcast

    blocks = SharedBlocks.attach(handle)
    demo_streams = blocks["counters"].shape[0] - cfg.num_streams   # rings beyond the actors'
    return blocks, ReplayStorage(replay_layout(cfg, demo_streams), blocks), Control(blocks), \
        WeightBroadcast(blocks)


class RunContext:
    """The runner's parts. Created with the shared memory and its views; :meth:`start` adds the
    learner and the actors; :meth:`stop` and :meth:`close` take them down again."""

    def __init__(self, cfg: Config, demo_streams: int = 0):
        from dqn_mine.agent.network import DuelingQNetwork
        from dqn_mine.replay import ReplayStorage
        from dqn_mine.shared import SharedBlocks
        from dqn_mine.system.control import Control
        from dqn_mine.system.learner import Learner
        from dqn_mine.system.pool import InlineActors, ProcessActors
        from dqn_mine.system.weights import WeightBroadcast

        # What this process runs with: a restored replay sets the pre-fill to 0.
        self.cfg = cfg
        template = DuelingQNetwork(**network_shape(cfg))
        self.blocks = SharedBlocks.create(run_block_specs(cfg, template, demo_streams))
        self.control = Control(self.blocks)
        self.storage = ReplayStorage(replay_layout(cfg, demo_streams), self.blocks)
        self.weights = WeightBroadcast(self.blocks)
        self.learner: Learner | None = None
        self.actors: ProcessActors | InlineActors | None = None

    def start_learner(self, state: dict | None, replay_snapshot: str | None,
                      serial: bool) -> None:
        """The learner, restored from ``state`` and ``replay_snapshot`` when given."""
        from dqn_mine.system.learner import Learner

        self.learner = Learner(self.cfg, self.storage, self.control, self.weights,
                               resolve_device(self.cfg.device), threaded=not serial,
                               replay_snapshot=replay_snapshot)
        if self.learner.restored:
            print(f"read {self.learner.restored:,} transitions back from "
                  f"{self.cfg.save_replay}: no pre-fill", flush=True)
            self.cfg = dataclasses.replace(self.cfg, prefill=0)
        if state:
            self.learner.load_state(state)

    def start_actors(self, generation: int, serial: bool) -> None:
        """The learner's weights broadcast, then the actors, which start from them."""
        from dqn_mine.system.pool import InlineActors, ProcessActors

        self.learner.publish()
        self.actors = (
            InlineActors(self.cfg, self.storage, self.control, self.weights, generation)
            if serial else ProcessActors(self.cfg, self.blocks.handle(), generation))

    def stop(self) -> None:
        """Tell every actor to stop and wait for them; stop the learner's sampling thread."""
        self.control.request_stop()
        if self.actors is not None:
            self.actors.stop()
        if self.learner is not None:
            self.learner.close()

    def close(self) -> None:
        """Release the shared memory (after :meth:`stop`)."""
        self.blocks.close()
