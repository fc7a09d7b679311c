"""Environment throughput: steps/s, reset time and memory of one process and of two at once.

- every task (random actions, resets included, the task's own step limit): steps/s of one
  process, mean reset time, resident memory (``VmRSS`` after creating the env, stepping and
  resetting), and steps/s of two processes stepping at the same time (each, and the sum);
- our ``rooms`` task with 4 rooms against Farama MiniWorld's ``MiniWorld-FourRooms-v0`` at 76x44
  (``PYGLET_HEADLESS=1``; with llvmpipe's default threads and with ``LP_NUM_THREADS=0``),
  alternating repeats in the same run, with the ratios the bar asks for (>= 4x steps/s per
  process against the faster MiniWorld variant, reset < 2 ms, < 150 MB); skipped with a note if
  ``miniworld`` is not importable (``pip install -e ".[bench]"``);
- llvmpipe's ``LP_NUM_THREADS`` 0 / 1 / 2 for one and two processes, the evidence behind the
  default in ``dqn_mine/env/render.py``.

Besides steps/s (wall time) each worker reports steps per CPU-second of its own process (all
threads), which a loaded machine disturbs much less, and the cores it used.

Every figure comes from a fresh subprocess (``python -m dqn_mine.bench.env --worker SPEC``), so
one GL context per process and memory not inflated by the benchmark's own imports. Processes of
one measurement are set up first (imports, env, warm-up) and then released together, so the
timed windows of a pair overlap. The machine may be shared: the load average is printed, and
comparisons are side by side in one run.

`python -m dqn_mine.bench --only env [--quick]`, or `python -m dqn_mine.bench.env [--quick]`.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time

TASKS = [
    ("one-room", {"task": "one-room"}),
    ("two-room", {"task": "two-room"}),
    ("three-room", {"task": "three-room"}),
    ("rooms, 4 rooms", {"task": "rooms", "num_rooms": 4}),
    ("rooms, 4 rooms, any-room", {"task": "rooms", "num_rooms": 4, "placement": "any-room"}),
]
ROOMS4 = {"task": "rooms", "num_rooms": 4}
MINIWORLD_ID = "MiniWorld-FourRooms-v0"
BAR_RATIO, BAR_RESET_MS, BAR_RSS_MB = 4.0, 2.0, 150.0
_RESULT = "RESULT "


# --------------------------------------------------------------------------- the worker process

def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def _cpu_s() -> float:
    """CPU seconds of this process, all threads (llvmpipe's render threads included)."""
    import resource

    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def _make(spec: dict):
    """The environment and its number of actions (imports happen here, in the worker)."""
    if spec["kind"] == "miniworld":
        import gymnasium
        import miniworld  # noqa: F401  (registers the MiniWorld-* ids)

        env = gymnasium.make(MINIWORLD_ID, obs_width=76, obs_height=44)
        return env, int(env.action_space.n)
    from dqn_mine.env import MineRescueEnv

    env = MineRescueEnv(**spec["env"])
    return env, int(env.action_space.n)


def _worker(spec: dict) -> None:
    import numpy as np

    env, n_actions = _make(spec)
    rng = np.random.default_rng(spec.get("seed", 0))
    env.reset(seed=spec.get("seed", 0))
    for a in rng.integers(0, n_actions, 50):  # warm-up: GL context, shaders, first uploads
        _, _, terminated, truncated, _ = env.step(int(a))
        if terminated or truncated:
            env.reset()
    print("ready", flush=True)
    sys.stdin.readline()  # the parent releases every process of a measurement at once

    seconds, block = spec["seconds"], 64
    steps = episodes = 0
    cpu0 = _cpu_s()
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        for a in rng.integers(0, n_actions, block):
            _, _, terminated, truncated, _ = env.step(int(a))
            if terminated or truncated:
                env.reset()
                episodes += 1
        steps += block
    elapsed = time.perf_counter() - start
    cpu = _cpu_s() - cpu0

    reset_ms = float("nan")
    if spec.get("resets", 0):
        t0 = time.perf_counter()
        for _ in range(spec["resets"]):
            env.reset()
        reset_ms = (time.perf_counter() - t0) / spec["resets"] * 1000
    out = {"steps_per_s": steps / elapsed, "steps_per_cpu_s": steps / max(cpu, 1e-9),
           "cpu_share": cpu / elapsed, "steps": steps, "episodes": episodes,
           "reset_ms": reset_ms, "rss_mb": _rss_mb()}
    env.close()
    print(_RESULT + json.dumps(out), flush=True)


# --------------------------------------------------------------------------- the parent side

def _child_env(spec: dict) -> dict:
    env = dict(os.environ)
    env.pop("LP_NUM_THREADS", None)  # each side's own default unless a measurement sets it
    if spec.get("lp_threads") is not None:
        env["LP_NUM_THREADS"] = str(spec["lp_threads"])
    if spec["kind"] == "miniworld":
        env["PYGLET_HEADLESS"] = "1"
    return env


def _read_until(proc: subprocess.Popen, marker: str) -> str:
    lines = []
    for line in proc.stdout:
        if line.startswith(marker):
            return line
        lines.append(line)
    err = proc.stderr.read() if proc.stderr else ""
    tail = (err.strip().splitlines() or lines or ["(no output)"])[-1].strip()
    raise RuntimeError(f"benchmark worker failed: {tail}")


def measure(*specs: dict) -> list[dict]:
    """Run one worker per spec, all released at the same moment; their results in order."""
    procs = [subprocess.Popen([sys.executable, "-m", "dqn_mine.bench.env", "--worker",
                               json.dumps(s)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, env=_child_env(s))
             for s in specs]
    try:
        for p in procs:
            _read_until(p, "ready")
        for p in procs:
            p.stdin.write("go\n")
            p.stdin.flush()
        results = [json.loads(_read_until(p, _RESULT)[len(_RESULT):]) for p in procs]
        for p in procs:
            p.wait(timeout=60)
        return results
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()


def miniworld_available() -> str | None:
    """None if MiniWorld can be imported headless here, else the reason."""
    res = subprocess.run([sys.executable, "-c", "import miniworld"], capture_output=True,
                         text=True, env={**os.environ, "PYGLET_HEADLESS": "1"}, timeout=120)
    if res.returncode == 0:
        return None
    lines = res.stderr.strip().splitlines()
    return lines[-1] if lines else f"exit code {res.returncode}"


def _load() -> str:
    return " / ".join(f"{x:.2f}" for x in os.getloadavg())


def _spread(values: list[float], fmt: str = ",.0f") -> str:
    med = statistics.median(values)
    if len(values) < 2:
        return format(med, fmt)
    return f"{format(med, fmt)} ({format(min(values), fmt)}-{format(max(values), fmt)})"


def run(quick: bool = False) -> str:
    t_start = time.perf_counter()
    load_start = _load()
    secs = 1.5 if quick else 4.0              # timed stepping per measurement
    resets = 100 if quick else 300            # timed resets (ours)
    mw_resets = 20 if quick else 60           # timed resets (MiniWorld: 10-17 ms each)
    repeats = 2 if quick else 3               # rotating ours / MiniWorld x2
    lp_rounds = 1 if quick else 2             # rounds over the LP_NUM_THREADS grid
    pair_tasks = [TASKS[0], TASKS[3]] if quick else TASKS

    def ours(env, **kw):
        return {"kind": "ours", "env": env, "seconds": secs, **kw}

    # Every task: one process, then two at once.
    rows = []
    for name, env in TASKS:
        one = measure(ours(env, resets=resets))[0]
        pair = (measure(ours(env, seed=1), ours(env, seed=2))
                if (name, env) in pair_tasks else None)
        rows.append((name, one, pair))

    # rooms 4 against MiniWorld, alternating.
    mw_missing = miniworld_available()
    cmp: dict = {"ours": [], "mw": [], "mw0": []}
    specs = {"ours": lambda r: ours(ROOMS4, seed=10 + r, resets=resets),
             "mw": lambda r: {"kind": "miniworld", "seconds": secs, "seed": 10 + r,
                              "resets": mw_resets},
             "mw0": lambda r: {"kind": "miniworld", "seconds": secs, "seed": 10 + r,
                               "resets": mw_resets, "lp_threads": 0}}
    who_all = ["ours", "mw", "mw0"] if mw_missing is None else ["ours"]
    for r in range(repeats):
        for who in who_all[r % len(who_all):] + who_all[:r % len(who_all)]:
            cmp[who].append(measure(specs[who](r))[0])

    # LP_NUM_THREADS grid on rooms 4, the order rotated each round.
    grid = [(lp, n) for n in (1, 2) for lp in (0, 1, 2)]
    lp_figs: dict = {cfg: [] for cfg in grid}
    for rnd in range(lp_rounds):
        shift = rnd * 2 % len(grid)
        for lp, n in grid[shift:] + grid[:shift]:
            lp_figs[(lp, n)].append(
                measure(*[ours(ROOMS4, seed=20 + i, lp_threads=lp) for i in range(n)]))

    # ------------------------------------------------------------------ the section
    lines = [
        "## Environment: steps/s, reset time, memory (CPU rendering, llvmpipe)",
        "",
        f"Random actions, resets included, each task's own step limit; every figure from a fresh "
        f"process, {secs:g} s of stepping each; reset time is the mean of {resets} resets; RSS is "
        f"`VmRSS` after creating the env, stepping and resetting. Two processes are released "
        f"together and step at the same time. *Steps per CPU-s* divides by the process's own CPU "
        f"time (all its threads), which other jobs on the machine disturb much less than wall "
        f"time. {os.cpu_count()} cores; load average (1/5/15 min) {load_start} at the start of "
        f"this section: with other jobs running every absolute figure is noisy, so compare "
        f"within this run.",
        "",
        "| task | steps/s, 1 process | steps per CPU-s | reset ms | RSS MB | "
        "steps/s, 2 processes (each) | 2 processes (sum) | sum / 1 process |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, one, pair in rows:
        if pair:
            each = " / ".join(f"{x['steps_per_s']:,.0f}" for x in pair)
            total = sum(x["steps_per_s"] for x in pair)
            pair_cols = f"{each} | {total:,.0f} | {total / one['steps_per_s']:.2f}x"
        else:
            pair_cols = "- | - | -"
        lines.append(f"| {name} | {one['steps_per_s']:,.0f} | {one['steps_per_cpu_s']:,.0f} | "
                     f"{one['reset_ms']:.2f} | {one['rss_mb']:.0f} | {pair_cols} |")
    if len(pair_tasks) < len(TASKS):
        lines += ["", "(`--quick` runs the two-process measurement for two tasks only.)"]

    lines += ["", f"### Against MiniWorld `{MINIWORLD_ID}` (76x44, `PYGLET_HEADLESS=1`)", ""]
    col = lambda res, key: [x[key] for x in res]  # noqa: E731
    med = statistics.median
    o_rate, o_reset, o_rss = (col(cmp["ours"], k) for k in ("steps_per_s", "reset_ms", "rss_mb"))
    if mw_missing is not None:
        lines += [f"MiniWorld is not importable here ({mw_missing}); install it with "
                  f"`pip install -e \".[bench]\"`. Skipped; our `rooms` task with 4 rooms alone: "
                  f"{_spread(o_rate)} steps/s, reset {_spread(o_reset, '.2f')} ms, "
                  f"{_spread(o_rss, '.0f')} MB."]
        bar_rate = None
    else:
        # The bar is judged against the faster MiniWorld variant (the stricter comparison).
        fast = max(("mw", "mw0"), key=lambda k: med(col(cmp[k], "steps_per_s")))
        ratios = [a / b for a, b in zip(o_rate, col(cmp[fast], "steps_per_s"))]
        bar_rate = med(ratios)
        lines += [
            f"{repeats} repeats, one process at a time, the order rotated each repeat; median "
            f"(min-max). Ours renders with its default `LP_NUM_THREADS=0`; MiniWorld runs with "
            f"llvmpipe's default thread count and, as a second reference, with "
            f"`LP_NUM_THREADS=0` too. MiniWorld has 3 actions and a 250-step limit (so more "
            f"resets within its stepping), ours 6 actions and 2000 steps; MiniWorld's reset time "
            f"is the mean of {mw_resets}. Ratios are against the faster MiniWorld row.",
            "",
            "| | steps/s, 1 process | steps per CPU-s | reset ms | RSS MB |",
            "|---|---:|---:|---:|---:|",
        ]
        for who, label in (("ours", "ours, `rooms` 4 rooms"),
                           ("mw", "MiniWorld FourRooms (default threads)"),
                           ("mw0", "MiniWorld FourRooms, `LP_NUM_THREADS=0`")):
            res = cmp[who]
            lines.append(f"| {label} | {_spread(col(res, 'steps_per_s'))} | "
                         f"{_spread(col(res, 'steps_per_cpu_s'))} | "
                         f"{_spread(col(res, 'reset_ms'), '.2f')} | "
                         f"{_spread(col(res, 'rss_mb'), '.0f')} |")
        ratio = lambda key: med(col(cmp["ours"], key)) / med(col(cmp[fast], key))  # noqa: E731
        lines.append(f"| ours / MiniWorld | **{bar_rate:.1f}x** (per repeat: "
                     f"{', '.join(f'{r:.1f}x' for r in ratios)}) | "
                     f"{ratio('steps_per_cpu_s'):.1f}x | {ratio('reset_ms'):.3f}x | "
                     f"{ratio('rss_mb'):.2f}x |")
    ok = lambda c: "met" if c else "**missed**"  # noqa: E731
    bar = [f"reset {med(o_reset):.2f} ms < {BAR_RESET_MS:g} ms: {ok(med(o_reset) < BAR_RESET_MS)}",
           f"RSS {med(o_rss):.0f} MB < {BAR_RSS_MB:g} MB: {ok(med(o_rss) < BAR_RSS_MB)}"]
    if bar_rate is not None:
        bar.insert(0, f"steps/s {bar_rate:.1f}x MiniWorld's >= {BAR_RATIO:g}x: "
                      f"{ok(bar_rate >= BAR_RATIO)}")
    lines += ["", "Bar: " + "; ".join(bar) + "."]

    def lp_cell(lp: int, n: int, fn) -> float:
        return med(fn(res) for res in lp_figs[(lp, n)])

    wall = lambda res: sum(x["steps_per_s"] for x in res)  # noqa: E731
    eff = lambda res: statistics.fmean(x["steps_per_cpu_s"] for x in res)  # noqa: E731
    cores = lambda res: sum(x["cpu_share"] for x in res)  # noqa: E731
    lines += [
        "",
        "### llvmpipe render threads (`LP_NUM_THREADS`), `rooms` 4 rooms",
        "",
        f"Set in each process's environment before import; {lp_rounds} round(s) over the grid, "
        f"the order rotated each round, median per cell. *Cores used* is the CPU time of the "
        f"process(es) over wall time: extra render threads can take CPU from other jobs on a "
        f"loaded machine, which raises steps/s without making rendering cheaper; steps per CPU-s "
        f"shows the cost.",
        "",
        "| LP_NUM_THREADS | 1 process: steps/s | steps per CPU-s | cores used | "
        "2 processes: steps/s (each) | sum | steps per CPU-s | cores used |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for lp in (0, 1, 2):
        each = " / ".join(f"{lp_cell(lp, 2, lambda r, i=i: r[i]['steps_per_s']):,.0f}"
                          for i in (0, 1))
        lines.append(
            f"| {lp}{' (default)' if lp == 0 else ''} | {lp_cell(lp, 1, wall):,.0f} | "
            f"{lp_cell(lp, 1, eff):,.0f} | {lp_cell(lp, 1, cores):.2f} | {each} | "
            f"{lp_cell(lp, 2, wall):,.0f} | {lp_cell(lp, 2, eff):,.0f} | "
            f"{lp_cell(lp, 2, cores):.2f} |")
    best = {key: max((0, 1, 2), key=lambda lp: lp_cell(lp, n, fn))
            for key, n, fn in (("w1", 1, wall), ("w2", 2, wall), ("e1", 1, eff), ("e2", 2, eff))}
    lines += ["", f"Highest steps/s here: {best['w1']} for one process, {best['w2']} for two; "
                  f"cheapest per CPU-s: {best['e1']} for one, {best['e2']} for two. Load average "
                  f"{_load()} at the end; this section took {time.perf_counter() - t_start:.0f} s."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--worker":
        _worker(json.loads(sys.argv[2]))
    else:
        print(run(quick="--quick" in sys.argv))
