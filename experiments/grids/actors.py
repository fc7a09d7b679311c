"""Actors and replay ratio: 1..9 actors free-running; 1 vs many at a fixed ratio."""

from experiments.scales import PAPER_NOTE, QUICK, QUICK_NOTE, SMOKE, SMOKE_NOTE

TITLE = "Actors and replay ratio: 1/3/5/7/9 actors; 1 vs 9 actors at a fixed replay ratio"
RATIO = 0.017  # 9 actors' own ratio in the study; throttles the 1-actor run to it
CONFIGS = {
    "actors-1": {"actors": 1},
    "actors-3": {"actors": 3},
    "actors-5": {"actors": 5},
    "actors-7": {"actors": 7},
    "actors-9": {"actors": 9},
    "fixed-ratio-1-actor": {"actors": 1, "replay_ratio": RATIO},
    "fixed-ratio-many-actors": {"actors": 9, "replay_ratio": RATIO},
}
BASE = {"task": "two-room"}
QUICK_RATIO = 0.02  # below what 1 actor gives free-running on this machine (about 0.04)
SCALES = {
    "paper": {"base": {"updates": 300_000}, "seeds": 5, "note": PAPER_NOTE},
    "quick": {"base": {**QUICK, "task": "one-room", "updates": 5000},
              "configs": ["actors-1", "actors-3", "fixed-ratio-1-actor",
                          "fixed-ratio-many-actors"],
              "override": {"fixed-ratio-1-actor": {"replay_ratio": QUICK_RATIO},
                           "fixed-ratio-many-actors": {"actors": 3,
                                                       "replay_ratio": QUICK_RATIO}},
              "seeds": 1, "note": QUICK_NOTE + "; 3 actors stand for 9"},
    "smoke": {"base": {**SMOKE, "task": "one-room"},
              "configs": ["actors-1", "fixed-ratio-1-actor", "fixed-ratio-many-actors"],
              "override": {"fixed-ratio-many-actors": {"actors": 2}},
              "seeds": 1, "note": SMOKE_NOTE},
}
FINDING = ("1 actor and 9 actors at the same replay ratio learn the same per update, and 9 actors "
           "finish about 5x sooner. More actors give a lower replay ratio and better returns per "
           "update; on the study's 12-thread machine 7 actors were best per unit of time.")
CLAIMS = [
    ("same replay ratio: 1 and many actors learn the same per update", "final_return_mean",
     "fixed-ratio-1-actor", "~", "fixed-ratio-many-actors"),
    ("same replay ratio: many actors finish sooner", "wall_time_s",
     "fixed-ratio-many-actors", "<", "fixed-ratio-1-actor"),
    ("more actors give a lower replay ratio", "replay_ratio", "actors-3", "<", "actors-1"),
    ("more actors give better returns per update", "final_return_mean",
     "actors-3", ">", "actors-1"),
]
