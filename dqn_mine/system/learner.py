"""Learner: prioritised n-step double-DQN updates fed by a background batch prefetcher.

The prefetch thread is the single owner of the replay's trees: it ingests what actors published,
samples and moves batches to the device; priority feedback from the update loop is queued by
the replay itself and applied in that thread. The update loop only ever touches ready batches, so
sampling overlaps the forward/backward pass.
"""

from __future__ import annotations

import queue
import threading
from typing import Callable

import numpy as np

from dqn_mine.config import Config, network_shape, resolve_learner_precision

# Ape-X's clip of the global gradient norm (the study states none). With Huber loss and IS
# weights <= 1 it rarely binds; it guards against rare spikes, e.g. right after a target sync.
MAX_GRAD_NORM = 40.0


class BatchSource:
    """Ready batches on the device; threaded (parallel runs) or inline (serial mode, tests)."""

    def __init__(self, replay, batch_size: int, beta: Callable[[], float], to_device: Callable,
                 queue_size: int = 4, threaded: bool = True):
        self.replay, self.batch_size, self.beta, self.to_device = replay, batch_size, beta, \
            to_device
        self.ready: queue.Queue = queue.Queue(maxsize=queue_size)
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = None
        if threaded:
            self._thread = threading.Thread(target=self._loop, name="batch-prefetch", daemon=True)
            self._thread.start()

    def _make_batch(self):
        """One sampled batch on the device, or None while the replay is too small."""
        self.replay.ingest()
        if len(self.replay) < self.batch_size:
            return None
        batch = self.replay.sample(self.batch_size, self.beta())
        return batch, self.to_device(batch)

    def _loop(self) -> None:
        try:
            while not self._stop.is_set():
                item = self._make_batch()
                if item is None:
                    self._stop.wait(0.01)
                    continue
                while not self._stop.is_set():
                    try:
                        self.ready.put(item, timeout=0.1)
                        break
                    except queue.Full:
                        self.replay.apply_priority_updates()
        except BaseException as exc:  # surfaced by get() in the learner's thread
            self.error = exc

    def get(self, timeout: float = 0.5):
        """(numpy batch, device batch) or None if none became ready within ``timeout``."""
        if self._thread is None:
            return self._make_batch()
        if self.error is not None:
            raise RuntimeError(f"batch prefetch thread failed: {self.error!r}") from self.error
        try:
            return self.ready.get(timeout=timeout)
        except queue.Empty:
            return None

    def ingest(self) -> int:
        """Used before the learner starts (pre-fill), when no thread samples yet."""
        return 0 if self._thread is not None else self.replay.ingest()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)


class Learner:
    """The update loop: network updater, batch source, weight publishing, and the update count.

    The runner talks to it through :meth:`ingest` (pre-fill), :meth:`step`, :meth:`publish`,
    :meth:`state_dict` / :meth:`load_state` (checkpoints), :meth:`save_replay` and the counters
    ``updates`` and ``new_updates``; ``control.updates`` mirrors ``updates`` for the actors.
    """

    def __init__(self, cfg: Config, storage, control, weights, device: str,
                 threaded: bool = True, replay_snapshot: str | None = None):
        """``replay_snapshot``: a saved replay to read back (before the prefetch thread starts
        sampling); ``restored`` then holds its live transitions."""
        from dqn_mine.agent.learning import DQNUpdater, batch_to_device
        from dqn_mine.agent.network import DuelingQNetwork
        from dqn_mine.replay import PrioritizedReplay

        self.cfg, self.control, self.weights, self.device = cfg, control, weights, device
        net = DuelingQNetwork(**network_shape(cfg))
        demos = storage.layout.demo_streams > 0
        self.updater = DQNUpdater(net, lr=cfg.lr, target_update_interval=cfg.target_update_interval,
                                  device=device, max_grad_norm=MAX_GRAD_NORM,
                                  precision=resolve_learner_precision(cfg.precision, device),
                                  demo_margin=cfg.demo_margin,
                                  demo_weight=cfg.demo_loss_weight if demos else 0.0)
        self.replay = PrioritizedReplay(storage, zeta=cfg.zeta, seed=cfg.seed,
                                        demo_bonus=cfg.demo_bonus if demos else 0.0)
        self.restored = 0
        if replay_snapshot is not None:
            from dqn_mine.replay import snapshot

            self.restored = snapshot.load(replay_snapshot, storage, self.replay)
        self.updates = 0            # of the whole run, resumes included
        self.first_update = 0       # ``updates`` when this process started (0, or a checkpoint's)
        self.source = BatchSource(
            self.replay, cfg.batch_size, beta=self.beta,
            to_device=lambda b: batch_to_device(b, device), threaded=threaded)

    @property
    def new_updates(self) -> int:
        """Updates made by this process (a resumed run's budget and rates count only these)."""
        return self.updates - self.first_update

    def replay_size(self) -> int:
        """Live transitions in the replay."""
        return len(self.replay)

    def ingest(self) -> int:
        """Take in what the actors published, before the sampling thread starts (pre-fill)."""
        return self.source.ingest()

    def beta(self) -> float:
        from dqn_mine.replay import beta_at

        return beta_at(self.updates, self.cfg.updates)

    def load_state(self, state: dict) -> None:
        self.updater.load_state_dict(state["updater"])
        # The optimiser's state carries the old learning rate; a resumed run's --lr wins.
        for group in self.updater.optimizer.param_groups:
            group["lr"] = self.cfg.lr
        self.updates = self.first_update = int(state["counters"]["updates"])
        self.control.updates = self.updates

    def state_dict(self) -> dict:
        """Network, target and optimiser (what a checkpoint keeps of the learner)."""
        return self.updater.state_dict()

    def publish(self) -> None:
        self.weights.publish(self.updater.online)

    def step(self) -> dict | None:
        """One network update; None if no batch was ready."""
        stats = self.pretrain_step()
        if stats is None:
            return None
        self.updates += 1
        self.control.updates = self.updates
        if self.updates % self.cfg.publish_interval == 0:
            self.publish()
        return stats

    def pretrain_step(self) -> dict | None:
        """One network update that the run's update count leaves out (``--demo-pretrain``: on
        the demonstrations, before the actors start); None if no batch was ready."""
        item = self.source.get()
        if item is None:
            return None
        batch, device_batch = item
        stats = self.updater.update(device_batch)
        # queued, thread-safe; the stamps keep it off slots refilled since the sample
        self.replay.update_priorities(batch.indices, stats["td_abs"], batch.stamps)
        stats["td_abs"] = float(np.mean(stats["td_abs"]))
        return stats

    def save_replay(self, path: str) -> None:
        """Write the replay to ``path`` (after :meth:`close`: nothing samples meanwhile)."""
        from dqn_mine.replay import snapshot

        size = snapshot.nbytes(self.replay.storage)
        print(f"saving the replay ({len(self.replay):,} transitions, {size / 1e9:.2f} GB) to "
              f"{path} ...", flush=True)
        snapshot.save(path, self.replay.storage, self.replay)

    def close(self) -> None:
        self.source.close()
