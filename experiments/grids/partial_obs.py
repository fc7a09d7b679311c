"""Partial observability: frame stacking vs action history on one-room."""

from experiments.scales import PAPER_NOTE, QUICK, QUICK_NOTE, SMOKE, SMOKE_NOTE

TITLE = "Partial observability: frame stack 4 vs action history 20 (one-room)"
CONFIGS = {
    "history-20": {"frame_stack": 1, "history_len": 20},
    "stack-4": {"frame_stack": 4, "history_len": 0},
    "both": {"frame_stack": 4, "history_len": 20},
    "neither": {"frame_stack": 1, "history_len": 0},
}
BASE = {"task": "one-room"}
SCALES = {
    "paper": {"base": {"updates": 200_000}, "seeds": 5, "note": PAPER_NOTE},
    "quick": {"base": QUICK, "seeds": 1, "note": QUICK_NOTE},
    "smoke": {"base": SMOKE, "seeds": 1, "note": SMOKE_NOTE},
}
FINDING = ("Frame stacking or action history learn faster early than neither; both end similar; "
           "combining them adds nothing.")
CLAIMS = [
    ("action history ahead of neither early", "early_return_mean", "history-20", ">", "neither"),
    ("frame stack ahead of neither early", "early_return_mean", "stack-4", ">", "neither"),
    ("action history and frame stack end similar", "final_return_mean",
     "history-20", "~", "stack-4"),
    ("both ends similar to action history alone", "final_return_mean", "both", "~", "history-20"),
]
