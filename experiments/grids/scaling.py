"""Scaling: 3, 4 and 5 rooms with any-room placement; a 3 -> 4 -> 5 schedule."""

from experiments.scales import CPU, PAPER_NOTE, QUICK, SMOKE, SMOKE_NOTE

TITLE = "Scaling: 3, 4, 5 rooms with domain randomisation; the 3 -> 4 -> 5 room schedule"
CONFIGS = {
    "rooms-3": {"num_rooms": 3},
    "rooms-4": {"num_rooms": 4},
    "rooms-5": {"num_rooms": 5},
    "schedule-3-4-5": {"num_rooms": 5, "curriculum": "schedule", "rooms_schedule": (3, 4, 5)},
}
# Every configuration is scored by the evaluation actor on the 5-room task, the hardest.
BASE = {"task": "rooms", "placement": "any-room", "eval_every": 10_000, "eval_episodes": 10,
        "eval_num_rooms": 5}
SCALES = {
    "paper": {"base": {"updates": 10_000_000}, "seeds": 3, "note": PAPER_NOTE},
    "quick": {"base": {**QUICK, "task": "rooms", "updates": 8000, "max_episode_steps": 400},
              "seeds": 1,
              "note": "reduced for 2 CPU cores: rooms of 8x8, 400-step episodes, 8,000 "
                      "updates, one seed"},
    # 16 x 16 rooms, 2,000 steps. A budget in updates, not minutes: the schedule splits the
    # updates into thirds. 160,000 updates take 27 minutes at 100 updates/s and 37 at 72 (the
    # slowest VM measured), so the four runs end within 3 hours on either. The evaluation actor
    # plays the 5-room task in every configuration, so all four are compared on one problem.
    "cpu": {"base": {**CPU, "task": "rooms", "curriculum": "none", "updates": 160_000},
            "override": {"schedule-3-4-5": {"curriculum": "schedule"}},
            "seeds": 1,
            "note": "full-size rooms (16 x 16, 2,000 steps) on 2 CPU cores: the cpu preset's "
                    "actors and learner, 160,000 updates a run, one seed; evaluation on 5 rooms"},
    "smoke": {"base": {**SMOKE, "task": "rooms", "eval_every": 500, "eval_episodes": 1},
              "configs": ["rooms-3", "schedule-3-4-5"],
              "seeds": 1, "note": SMOKE_NOTE},
}
METRIC = "eval_return"
FINDING = ("3 and 4 rooms learn well, 5 rooms much worse; a 3 -> 4 -> 5 scheduled curriculum "
           "improves the 5-room result.")
CLAIMS = [
    ("3 rooms ahead of 5 rooms on 5 rooms", "final_eval_return_mean", "rooms-3", ">", "rooms-5"),
    ("the 3 -> 4 -> 5 schedule ahead of 5 rooms from the start", "final_eval_return_mean",
     "schedule-3-4-5", ">", "rooms-5"),
]
EXTRA_PLOTS = ("episode_return", "phase")
