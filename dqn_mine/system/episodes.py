"""Rolling statistics of the finished episodes the runner drains from the actors."""

from __future__ import annotations

from dqn_mine.config import Config
from dqn_mine.metrics import LOW_EPSILON, RETURN_WINDOW, Rolling
from dqn_mine.system.control import Episode


class EpisodeStats:
    """Training episodes (count, rewarded count, rolling return and length; the rolling return
    of those played at epsilon <= LOW_EPSILON) and evaluation episodes apart."""

    def __init__(self, cfg: Config, episodes: int = 0, rewarded: int = 0):
        self.episodes = episodes           # training episodes, over every start of the run
        self.rewarded = rewarded           # of those, the ones with a reward (a delivery)
        self.returns = Rolling(RETURN_WINDOW)
        self.lengths = Rolling(RETURN_WINDOW)
        self.low_eps_returns = Rolling(RETURN_WINDOW)
        self.full_returns = Rolling(RETURN_WINDOW)      # those begun at the real start
        self.full_episodes = 0                              # ... how many, in this process
        self.eval_returns = Rolling(cfg.eval_episodes)
        self.eval_lengths = Rolling(cfg.eval_episodes)

    def add(self, ep: Episode) -> bool:
        """Count one finished episode; True for a training episode."""
        if ep.is_eval:
            self.eval_returns.extend([ep.ret])
            self.eval_lengths.extend([ep.length])
            return False
        self.episodes += 1
        self.rewarded += ep.ret > 0
        self.returns.extend([ep.ret])
        self.lengths.extend([ep.length])
        if ep.full_task:
            self.full_returns.extend([ep.ret])
            self.full_episodes += 1
        if ep.epsilon <= LOW_EPSILON:
            self.low_eps_returns.extend([ep.ret])
        return True
