"""Replay benchmark: our shared-memory prioritised replay beside cpprb's PrioritizedReplayBuffer.

``python -m dqn_mine.bench.replay [--quick]`` prints a markdown section (``run()`` returns it).

1. Tree round at capacity 2^20: "sample B + update B priorities" (B = 512 and 32), small obs. Both
   libraries alternate in short repetitions within one run (the median of each is reported), so
   machine noise hits both alike.
2. With 10,032-byte frames: add rate (first lap = fresh shared pages, then a lap over warm
   pages), sample rate for batches of 32 and 512 with the frames gathered into a ready batch, and
   the priority-update rate. cpprb stores frames once too (``next_of=("obs",)``). The two run one
   after the other, each freeing its memory before the other starts; the capacity is lowered if
   memory forces it (the table says so).

cpprb is a benchmark-only dependency (``pip install -e .[bench]``); without it only our figures
are printed.
"""

from __future__ import annotations

import argparse
import gc
import statistics
import sys
import time
from typing import Callable

import numpy as np

from dqn_mine.replay import (
    Batch,
    MinTree,
    NStepWriter,
    PrioritizedReplay,
    ReplayLayout,
    ReplayStorage,
    SumTree,
)
from dqn_mine.shared import SharedBlocks

try:
    import cpprb
except ImportError:           # the benchmark still reports our side
    cpprb = None

FRAME = (3, 44, 76)
EPISODE = 500                  # steps per synthetic episode
ZETA, BETA = 0.6, 0.4


def _rate(fn: Callable[[], None], seconds: float) -> float:
    """Calls per second of ``fn`` over about ``seconds`` (after one warm-up call)."""
    fn()
    n, t0 = 0, time.perf_counter()
    while True:
        fn()
        n += 1
        dt = time.perf_counter() - t0
        if dt >= seconds:
            return n / dt


def _alternate(fns: dict[str, Callable[[], None]], seconds: float, reps: int) -> dict[str, float]:
    """Median rate of each fn, measured in alternation so noise hits them alike."""
    rates: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(reps):
        for k, fn in fns.items():
            rates[k].append(_rate(fn, seconds / reps))
    return {k: statistics.median(v) for k, v in rates.items()}


def _mem_available() -> int:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 1 << 62


# -- 1. tree round ------------------------------------------------------------------------------
def _tree_round(quick: bool) -> list[str]:
    cap = 2 ** 20
    rng = np.random.default_rng(0)
    prio = rng.random(cap) + 0.01

    sum_tree, min_tree = SumTree(cap), MinTree(cap)
    sum_tree.update(np.arange(cap), prio ** ZETA)
    min_tree.update(np.arange(cap), prio ** ZETA)

    def trees_only(b=512):
        u = (np.arange(b) + rng.random(b)) * (sum_tree.total() / b)
        idx, p = sum_tree.find_with_values(u)
        (p / min_tree.min()) ** -BETA
        p = (rng.random(b) + 0.01) ** ZETA
        sum_tree.update(idx, p)
        min_tree.update(idx, p)

    layout = ReplayLayout(num_streams=1, stream_capacity=cap, frame_shape=(1,), n_step=1,
                          history_len=0)
    with SharedBlocks.create(layout.block_specs()) as blocks:
        rows = _tree_rates(ReplayStorage(layout, blocks), prio, trees_only, quick)
    ref = rows.get("cpprb: sample + update_priorities")
    lines = ["### Tree round: sample B + update B priorities, capacity 2^20, small obs", "",
             "| implementation | B = 512, rounds/s | vs cpprb | B = 32, rounds/s | vs cpprb |",
             "|---|---:|---:|---:|---:|"]
    for k, r in rows.items():
        cells = [f"{r[b]:,.0f} | " + (f"{r[b] / ref[b]:.2f}x" if ref else "") for b in (512, 32)]
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    return lines


def _tree_rates(storage: ReplayStorage, prio: np.ndarray, trees_only, quick: bool):
    """Rounds/s of ours, trees only and cpprb for B = 512 and 32 (the views of ``storage`` die
    with this call, before the caller unlinks the blocks)."""
    cap, rng = storage.capacity, np.random.default_rng(1)
    _fill_small(storage, rng)
    replay = PrioritizedReplay(storage, zeta=ZETA)
    replay.ingest()
    rb = None
    if cpprb is not None:
        rb = cpprb.PrioritizedReplayBuffer(cap, {"obs": {"shape": 1}, "act": {}, "rew": {},
                                                 "next_obs": {"shape": 1}, "done": {}},
                                           alpha=ZETA)
        for lo in range(0, cap, 1 << 16):
            n = 1 << 16
            rb.add(obs=np.zeros((n, 1)), act=np.zeros(n), rew=np.zeros(n),
                   next_obs=np.zeros((n, 1)), done=np.zeros(n), priorities=prio[lo:lo + n])
    rows: dict[str, dict[int, float]] = {}
    for b in (512, 32):
        out = Batch.empty(storage.layout, b)

        def ours(b=b, out=out):
            batch = replay.sample(b, BETA, out=out)
            replay.update_priorities(batch.indices, rng.random(b))

        fns = {"ours: PrioritizedReplay.sample + update_priorities": ours,
               "ours: trees only (find, weights, sum and min updates)":
                   lambda b=b: trees_only(b)}
        if rb is not None:
            def theirs(b=b):
                s = rb.sample(b, beta=BETA)
                rb.update_priorities(s["indexes"], rng.random(b) + 0.01)

            fns["cpprb: sample + update_priorities"] = theirs
        seconds = (4.0 if quick else 12.0) * (1.0 if b == 512 else 0.5)
        for k, r in _alternate(fns, seconds, reps=4 if quick else 6).items():
            rows.setdefault(k, {})[b] = r
    return rows


def _fill_small(storage: ReplayStorage, rng) -> None:
    """Fill every slot of a tiny-frame layout (n_step 1) directly: one published transition each."""
    cap = storage.capacity
    storage.frames[:] = 0
    storage.carrying[:] = 0
    storage.ep_step[:] = np.arange(cap) % EPISODE
    storage.action[:] = 0
    storage.ret[:] = 0
    storage.discount[:] = 0.99
    storage.boot_off[:] = 1
    storage.boot[:] = (np.arange(cap) + 1) % cap
    storage.priority[:] = rng.random(cap) + 0.01
    storage.counters[0, :2] = cap + 1   # cursor = published = cap + 1: slot 0 (frame 0) lapped
    storage.counters[0, 1] = cap        # transitions 1 .. cap-1 published and alive


# -- 2. with frames -----------------------------------------------------------------------------
class _Frames:
    """Synthetic episodes: a pool of random frames, Q vectors, actions."""

    def __init__(self, rng):
        self.frames = rng.integers(0, 256, (256, *FRAME), dtype=np.uint8)
        self.q = rng.random((256, 6)).astype(np.float32)
        self.act = rng.integers(0, 6, 256)


def _ours_frames(cap: int, warm: int, streams: int, seconds: float) -> dict[str, float]:
    layout = ReplayLayout(num_streams=streams, stream_capacity=cap // streams)
    t0 = time.perf_counter()
    blocks = SharedBlocks.create(layout.block_specs())
    res = {"create": time.perf_counter() - t0}
    try:
        res.update(_ours_frames_rates(ReplayStorage(layout, blocks), warm, seconds))
    finally:
        blocks.close()            # the views died with the call: the 10 GB go back now
    return res


def _ours_frames_rates(storage: ReplayStorage, warm: int, seconds: float) -> dict[str, float]:
    layout, cap = storage.layout, storage.capacity
    data = _Frames(np.random.default_rng(1))
    writers = [NStepWriter(storage, k) for k in range(layout.num_streams)]
    res: dict[str, float] = {}

    def write(w: NStepWriter, steps: int):
        f, q, a = data.frames, data.q, data.act
        w.begin_episode(f[0], 0.0)
        for i in range(steps):
            j = i & 255
            end = i % EPISODE == EPISODE - 1
            w.append(q[j], a[j], 0.0, f[j], 0.0, end, False)
            if end and i + 1 < steps:
                w.begin_episode(f[j], 0.0)
        w.flush()

    t0 = time.perf_counter()
    for w in writers:                                   # first lap: fresh pages
        write(w, layout.stream_capacity)
    res["first lap s"] = time.perf_counter() - t0
    res["add fresh"] = cap / res["first lap s"]
    t0 = time.perf_counter()
    write(writers[0], warm)                             # stream 0 laps over its own slots
    res["add warm"] = warm / (time.perf_counter() - t0)

    replay = PrioritizedReplay(storage, zeta=ZETA)
    t0 = time.perf_counter()
    replay.ingest()
    res["ingest all"] = time.perf_counter() - t0
    rng = np.random.default_rng(2)
    for b in (32, 512):
        out = Batch.empty(layout, b)
        res[f"sample {b}"] = _rate(lambda b=b, out=out: replay.sample(b, BETA, out=out), seconds)
        res[f"sample {b} new arrays"] = _rate(lambda b=b: replay.sample(b, BETA), seconds)
    idx = replay.sample(512, BETA).indices

    def update():                                       # queue + apply (as the next sample does)
        replay.update_priorities(idx, rng.random(512))
        replay.apply_priority_updates()

    res["update 512"] = _rate(update, seconds)
    return res


def _cpprb_frames(cap: int, warm: int, seconds: float) -> dict[str, float]:
    data = _Frames(np.random.default_rng(1))
    res: dict[str, float] = {}
    t0 = time.perf_counter()
    rb = cpprb.PrioritizedReplayBuffer(
        cap, {"obs": {"shape": FRAME, "dtype": np.uint8}, "act": {}, "rew": {}, "done": {}},
        next_of=("obs",), alpha=ZETA)
    res["create"] = time.perf_counter() - t0            # cpprb zero-fills: pages touched here
    block = 64
    rng = np.random.default_rng(2)
    # ready blocks of 64 transitions (cpprb's best case: no per-step Python call)
    blocks = []
    for s in range(0, 256, block):
        blocks.append(dict(obs=data.frames[s:s + block],
                           next_obs=data.frames[(np.arange(s, s + block) + 1) % 256],
                           act=data.act[s:s + block], rew=np.zeros(block), done=np.zeros(block),
                           priorities=rng.random(block) + 0.01))

    def add(steps: int):
        for i in range(0, steps, block):
            rb.add(**blocks[(i // block) % len(blocks)])
            if (i + block) % EPISODE < block:
                rb.on_episode_end()

    t0 = time.perf_counter()
    add(cap)
    res["first lap s"] = time.perf_counter() - t0
    res["add fresh"] = cap / res["first lap s"]
    t0 = time.perf_counter()
    add(warm)
    res["add warm"] = warm / (time.perf_counter() - t0)
    for b in (32, 512):
        res[f"sample {b}"] = _rate(lambda b=b: rb.sample(b, beta=BETA), seconds)
    idx = rb.sample(512, beta=BETA)["indexes"]
    res["update 512"] = _rate(lambda: rb.update_priorities(idx, rng.random(512) + 0.01), seconds)
    return res                    # rb goes with the call; the caller collects


def _frames_section(quick: bool) -> list[str]:
    streams = 8
    want = 2 ** 16 if quick else 2 ** 20
    need = want * int(np.prod(FRAME)) * 1.15
    cap = want
    while cap > 2 ** 14 and need > 0.8 * _mem_available():
        cap //= 2
        need /= 2
    warm = min(cap, 2 ** 14 if quick else 2 ** 17)
    seconds = 1.0 if quick else 4.0
    ours = _ours_frames(cap, warm, streams, seconds)
    gc.collect()
    theirs = _cpprb_frames(cap, warm, seconds) if cpprb is not None else {}
    gc.collect()
    note = "" if cap == want else f" (lowered from 2^{int(np.log2(want))}: not enough memory)"
    lines = [f"### With 10,032-byte frames, capacity 2^{int(np.log2(cap))}{note}", "",
             f"Ours: {ReplayLayout(streams, cap // streams).nbytes / 2**30:.2f} GiB of shared "
             f"memory in {streams} stream rings, frames not pre-touched (pages commit as the ring "
             f"fills); a fresh learner ingests all {cap:,} transitions in "
             f"{ours['ingest all']:.2f} s.", "",
             "| operation | ours | cpprb | ours / cpprb |", "|---|---:|---:|---:|"]
    t_ours = ours["create"] + ours["first lap s"]
    t_theirs = theirs["create"] + theirs["first lap s"] if theirs else None
    lines.append(f"| create buffer, s | {ours['create']:.2f} | "
                 + (f"{theirs['create']:.2f} |  |" if theirs else "n/a | |"))
    lines.append(f"| create + fill {cap:,} transitions, s | {t_ours:.1f} | "
                 + (f"{t_theirs:.1f} | {t_theirs / t_ours:.2f}x |" if theirs else "n/a | |"))
    rows = [("add, first lap (fresh pages), transitions/s", "add fresh", "add fresh"),
            (f"add, warm lap ({warm:,}), transitions/s", "add warm", "add warm"),
            ("sample 32 + gather frames, batches/s", "sample 32", "sample 32"),
            ("sample 32, new arrays per batch", "sample 32 new arrays", "sample 32"),
            ("sample 512 + gather frames, batches/s", "sample 512", "sample 512"),
            ("sample 512, new arrays per batch", "sample 512 new arrays", "sample 512"),
            ("update 512 priorities, calls/s", "update 512", "update 512")]
    for label, ko, kt in rows:
        o, t = ours[ko], theirs.get(kt)
        lines.append(f"| {label} | {o:,.0f} | {t:,.0f} | {o / t:.2f}x |" if t
                     else f"| {label} | {o:,.0f} | n/a | |")
    lines += ["", "Ours adds through `NStepWriter.append`, one call per environment step (n-step "
              "return and Ape-X priority included); cpprb gets ready blocks of 64 one-step "
              "transitions. Ours samples into a preallocated `Batch` (`out=`) unless the row "
              "says new arrays; cpprb allocates its batch every call. Sampling draws from the "
              "whole filled ring."]
    return lines


def run(quick: bool = False) -> str:
    lines = ["## Replay", ""]
    if cpprb is None:
        lines += ["cpprb is not installed (`pip install -e .[bench]`): our figures only.", ""]
    t0 = time.perf_counter()
    lines += _tree_round(quick) + [""]
    gc.collect()
    lines += _frames_section(quick)
    lines += ["", f"({'quick' if quick else 'full'} run, {time.perf_counter() - t0:.0f} s)", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short run (< 1 minute), small frame ring")
    args = ap.parse_args(argv)
    print(run(quick=args.quick))
    return 0


if __name__ == "__main__":
    sys.exit(main())
