"""Ablation (``make ablation``): remove n-step, distribution or PER from the system."""

from experiments.scales import PAPER_NOTE, QUICK, QUICK_NOTE, SMOKE, SMOKE_NOTE

TITLE = "Ablation: n-step returns, distributed actors and prioritised replay (two-room)"
CONFIGS = {
    "all-included": {"actors": 7, "n_step": 6},
    "no-n-step": {"actors": 7, "n_step": 1},
    "no-distribution": {"actors": 1, "n_step": 6},
    "no-per": {"actors": 7, "zeta": 0.0, "n_step": 6},      # zeta 0: uniform replay
    "none-included": {"actors": 1, "zeta": 0.0, "n_step": 1},
}
BASE = {"task": "two-room"}
MANY = {"actors": 2}  # "distributed" on 2 cores
SCALES = {
    "paper": {"base": {"updates": 300_000}, "seeds": 5, "note": PAPER_NOTE},
    "quick": {"base": {**QUICK, "task": "one-room", "updates": 14_000},
              "override": {"all-included": MANY, "no-n-step": MANY, "no-per": MANY},
              "seeds": 1, "note": QUICK_NOTE + "; 2 actors stand for 7"},
    "smoke": {"base": {**SMOKE, "task": "one-room"},
              "override": {"all-included": MANY, "no-n-step": MANY, "no-per": MANY},
              "seeds": 1, "note": SMOKE_NOTE},
}
FINDING = ("All included (7 actors, PER, n = 6) reaches a near-perfect mean return (about 1.0); "
           "removing any one of n-step, distribution (1 actor) or PER drops performance a lot; "
           "with none of them it never improves.")
CLAIMS = [
    ("all included ahead of none included at the end", "final_return_mean",
     "all-included", ">", "none-included"),
    ("all included ahead of no n-step", "final_return_mean", "all-included", ">", "no-n-step"),
    ("all included ahead of no distribution", "final_return_mean",
     "all-included", ">", "no-distribution"),
    ("all included ahead of no PER", "final_return_mean", "all-included", ">", "no-per"),
]
EXTRA_PLOTS = ("sampled_reward",)
