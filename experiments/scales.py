"""Shared scale settings the grid files build on (data only).

``quick`` is sized for 2 CPU cores: the ``smoke`` preset's small one-room (8 x 8 units, 200-step
episodes, Ape-X epsilons, a faster learning rate) where the study used two-room, and a few
thousand updates (about 20 updates/s here, so 8,000 updates take about 7 minutes a run).
``smoke`` only proves the pipeline: a couple of hundred updates on a tiny mine, seconds a run.
"""

QUICK = {"preset": "smoke", "updates": 8000, "log_interval": 200, "checkpoint_interval": 2000}
QUICK_NOTE = ("reduced for 2 CPU cores: one-room 8x8 (smoke preset) instead of the study's task, "
              "a few thousand updates, one seed")

SMOKE = {"preset": "smoke", "updates": 150, "prefill": 200, "replay_capacity": 4096, "actors": 1,
         "room_size": 8.0, "max_episode_steps": 50, "log_interval": 25,
         "checkpoint_interval": 1000}
SMOKE_NOTE = "a pipeline check only (150 updates on a tiny mine): no learning is expected"

PAPER_NOTE = "the study's configuration"

# The study's own tasks at full size on 2 CPU cores: the cpu preset's actors, replay and learner
# (see dqn_mine/config.py); the grid's scale bounds each run by updates or minutes so that the
# grid ends within 3 hours on one 2-core machine. No demonstrations: the grids compare the
# study's methods (the preset's demos came after their runs).
CPU = {"preset": "cpu", "updates": 10_000_000, "eval_every": 500_000, "eval_episodes": 10,
       "demos": 0}
