"""Prioritised replay: the priority exponent zeta from 0 (uniform) to 1."""

from experiments.scales import PAPER_NOTE, QUICK, QUICK_NOTE, SMOKE, SMOKE_NOTE

TITLE = "Prioritised replay: priority exponent zeta 0, 0.2, ..., 1.0 (two-room)"
CONFIGS = {f"zeta-{z:.1f}": {"zeta": z} for z in (0.0, 0.2, 0.4, 0.6, 0.8, 1.0)}
BASE = {"task": "two-room"}
SCALES = {
    "paper": {"base": {"updates": 300_000}, "seeds": 5, "note": PAPER_NOTE},
    "quick": {"base": {**QUICK, "task": "one-room", "updates": 7000}, "seeds": 1,
              "note": QUICK_NOTE},
    "smoke": {"base": {**SMOKE, "task": "one-room"}, "configs": ["zeta-0.0", "zeta-0.6"],
              "seeds": 1, "note": SMOKE_NOTE},
}
FINDING = ("Higher zeta samples rewarding transitions far more often; zeta 0 ends near 0.1 while "
           "zeta 0.6 ends near 1.0.")
CLAIMS = [
    ("zeta 0.6 ahead of zeta 0 at the end", "final_return_mean", "zeta-0.6", ">", "zeta-0.0"),
    ("zeta 1.0 samples more reward than zeta 0", "sampled_reward_mean",
     "zeta-1.0", ">", "zeta-0.0"),
]
EXTRA_PLOTS = ("sampled_reward",)
