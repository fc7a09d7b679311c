"""Exploration: plain epsilon-greedy vs adaptive curriculum vs any-room placement (domain
randomisation) vs both on three-room, compared through the evaluation actor on the full task."""

from experiments.scales import PAPER_NOTE, QUICK, SMOKE, SMOKE_NOTE

TITLE = ("Exploration: baseline vs curriculum (phases) vs domain randomisation vs both "
         "(three-room)")
CONFIGS = {
    "baseline": {},
    "curriculum": {"curriculum": "adaptive"},
    "any-room": {"placement": "any-room"},
    # both: 30% of the episodes start as the full task in random rooms, the rest follow the
    # phases (the rule counts only those)
    "curriculum+dr": {"curriculum": "adaptive", "curriculum_dr": 0.3},
}
NO_PHASES = {"curriculum": "none"}
BACKWARD = {"curriculum": "backward"}
CPU_MINUTES = {"baseline": 15, "curriculum": 90, "any-room": 35, "curriculum+dr": 35}
BASE = {"task": "three-room", "eval_every": 10_000, "eval_episodes": 10}
SCALES = {
    "paper": {"base": {"updates": 1_000_000}, "seeds": 5, "note": PAPER_NOTE},
    "quick": {"base": {**QUICK, "task": "three-room", "updates": 12_000, "actors": 1,
                       "max_episode_steps": 400, "eval_every": 4000, "eval_episodes": 5},
              "seeds": 1,
              "note": "reduced for 2 CPU cores: three-room of 8x8 rooms, 400-step episodes, "
                      "12,000 updates, 1 actor and the evaluation actor, one seed; the full "
                      "task is far out of reach at this budget, watch the curriculum phase"},
    # The cpu-three-room preset for all four without its demonstrations (its actors, learner and
    # clear view), so that they differ only in how episodes start: the study's six phases need
    # far more updates than 2 cores give, so both curricula are the backward one (the expert's
    # path), in fixed or random rooms. Each for the minutes it needs to show its result (the
    # baseline finds no reward in 90).
    "cpu": {"base": {"preset": "cpu-three-room", "task": "three-room", "demos": 0,
                     "eval_every": 500_000},
            "override": {"baseline": {**NO_PHASES, "minutes": CPU_MINUTES["baseline"]},
                         "curriculum": {**BACKWARD, "minutes": CPU_MINUTES["curriculum"]},
                         "any-room": {**NO_PHASES, "minutes": CPU_MINUTES["any-room"]},
                         "curriculum+dr": {**BACKWARD, "placement": "any-room",
                                           "curriculum_dr": 0.0,
                                           "minutes": CPU_MINUTES["curriculum+dr"]}},
            "seeds": 1,
            "note": "full-size three-room (16 x 16 rooms, 2,000 steps) on 2 CPU cores: the "
                    "cpu-three-room preset without demonstrations, the backward curriculum as "
                    "the curriculum, minutes a run "
                    + ", ".join(f"{k} {v}" for k, v in CPU_MINUTES.items()) + ", one seed"},
    "smoke": {"base": {**SMOKE, "task": "three-room", "eval_every": 500, "eval_episodes": 1},
              "seeds": 1, "note": SMOKE_NOTE},
}
METRIC = "eval_return"
FINDING = ("Plain epsilon-greedy never finds the reward; curriculum learning and domain "
           "randomisation both learn to solve the full task (evaluation actor on three-room).")
CLAIMS = [
    ("curriculum ahead of baseline on the full task", "final_eval_return_mean",
     "curriculum", ">", "baseline"),
    ("any-room ahead of baseline on the full task", "final_eval_return_mean",
     "any-room", ">", "baseline"),
    ("curriculum+dr ahead of baseline on the full task", "final_eval_return_mean",
     "curriculum+dr", ">", "baseline"),
]
EXTRA_PLOTS = ("episode_return", "phase")
