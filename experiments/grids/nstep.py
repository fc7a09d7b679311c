"""n-step returns: n from 1 to 7."""

from experiments.scales import PAPER_NOTE, QUICK, QUICK_NOTE, SMOKE, SMOKE_NOTE

TITLE = "n-step returns: n = 1 .. 7 (two-room)"
CONFIGS = {f"n-{n}": {"n_step": n} for n in range(1, 8)}
BASE = {"task": "two-room"}
SCALES = {
    "paper": {"base": {"updates": 300_000}, "seeds": 5, "note": PAPER_NOTE},
    "quick": {"base": {**QUICK, "task": "one-room", "updates": 6000}, "seeds": 1,
              "note": QUICK_NOTE},
    "smoke": {"base": {**SMOKE, "task": "one-room"}, "configs": ["n-1", "n-6"], "seeds": 1,
              "note": SMOKE_NOTE},
}
FINDING = "n = 1 ends near 0.1; returns improve up to n = 6; n = 7 is slightly worse."
CLAIMS = [
    ("n = 6 ahead of n = 1 at the end", "final_return_mean", "n-6", ">", "n-1"),
    ("n = 6 ahead of n = 3", "final_return_mean", "n-6", ">", "n-3"),
    ("n = 7 not better than n = 6", "final_return_mean", "n-7", "<", "n-6"),
]
