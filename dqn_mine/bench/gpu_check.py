"""`make gpu-check` (`python -m dqn_mine.bench.gpu_check --out DIR`): the CUDA path, checked in
one command on a GPU machine, in about 8 minutes, with every figure in one folder.

1. the learner on CUDA: updates/s at batch 32, 256 and 512 for each precision;
2. NVIDIA EGL rendering in spawned processes: the renderer's name, and steps/s of the study's
   task with 1, 7 and 15 processes at once;
3. the whole system with the learner on CUDA: transitions/s and updates/s with 7 and 15 actors;
4. a 5-minute `two-room` learning run (`--preset cpu` with 15 actors): its metrics, a
   plot and its summary.

DIR gets `summary.md` (the tables), `gpu_check.json` (the same figures), `learning.csv`,
`learning.png` and `learning_summary.json`. A step that fails records its one-line error and the
check goes on. Without CUDA it says so in one line and exits 0.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

LEARNING_SECONDS = 300
RENDER_PROCESSES = (1, 7, 15)
SYSTEM_ACTORS = (7, 15)
STUDY_TASK = dict(task="two-room", room_size=16.0, max_episode_steps=None)


def learner_figures() -> dict:
    import torch

    from dqn_mine.bench.learner import learner_rates

    precisions = ["float32"] + (["bfloat16"] if torch.cuda.is_bf16_supported() else [])
    out = {"device": torch.cuda.get_device_name(), "rows": []}
    for b in (32, 256, 512):
        rates = learner_rates(precisions, b, "cuda", seconds=0.5, rounds=3)
        out["rows"] += [{"batch": b, "precision": p, "updates_per_s": r} for p, r in rates.items()]
    return out


def renderer_name() -> str:
    code = ("from dqn_mine.env.render import gl; import json; "
            "print(json.dumps(gl(76, 44).ctx.info['GL_RENDERER']))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    if res.returncode != 0:
        raise RuntimeError((res.stderr.strip().splitlines() or ["no output"])[-1])
    return json.loads(res.stdout.strip().splitlines()[-1])


def render_figures() -> dict:
    from dqn_mine.bench.env import measure

    out = {"renderer": renderer_name(), "rows": []}
    for n in RENDER_PROCESSES:
        specs = [{"kind": "mine", "env": STUDY_TASK, "seconds": 10.0, "seed": i}
                 for i in range(n)]
        results = measure(*specs)
        per = [r["steps_per_s"] for r in results]
        out["rows"].append({"processes": n, "steps_per_s_total": sum(per),
                            "steps_per_s_per_process": sum(per) / n})
    return out


def system_figures() -> dict:
    from dqn_mine.bench.system import pipeline

    rows = []
    for actors in SYSTEM_ACTORS:
        fig = pipeline(STUDY_TASK, actors, 16, "auto", updates=1500)
        rows.append({"actors": actors, "envs_per_actor": 16, **fig})
    return {"rows": rows}


def learning_run(out_dir: Path, seconds: float = LEARNING_SECONDS) -> dict:
    """A two-room run stopped by SIGINT (a clean, resumable stop) after ``seconds``."""
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(tmp) / "two-room"
        cmd = [sys.executable, "-m", "dqn_mine.train", "--preset", "cpu", "--actors", "15",
               "--updates", "1000000", "--run-dir", str(run_dir)]
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                text=True)
        try:
            proc.wait(timeout=seconds)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=120)
        err = proc.stderr.read() if proc.stderr else ""
        if not (run_dir / "metrics.csv").exists():
            raise RuntimeError((err.strip().splitlines() or ["no metrics written"])[-1])
        shutil.copy(run_dir / "metrics.csv", out_dir / "learning.csv")
        summary = {}
        if (run_dir / "summary.json").exists():
            summary = json.loads((run_dir / "summary.json").read_text())
            shutil.copy(run_dir / "summary.json", out_dir / "learning_summary.json")
        subprocess.run([sys.executable, "-m", "dqn_mine.plot", str(run_dir), "--out",
                        str(out_dir / "learning.png")], capture_output=True, text=True)
    from dqn_mine.metrics import read_metrics

    rows = read_metrics(out_dir / "learning.csv")
    last = rows[-1] if rows else {}
    return {"seconds": seconds, "exit_code": proc.returncode, "rows": len(rows),
            "last": {k: last.get(k) for k in ("update", "wall_time", "env_steps", "episodes",
                                              "episode_return", "updates_per_s",
                                              "env_steps_per_s", "replay_ratio", "phase")},
            "summary": summary}


def step(name: str, fn: Callable[[], dict], figures: dict[str, dict]) -> None:
    start = time.perf_counter()
    print(f"gpu-check: {name} ...", file=sys.stderr, flush=True)
    try:
        figures[name] = fn()
    except Exception as exc:  # record and go on: one broken part must not hide the others
        figures[name] = {"error": f"{type(exc).__name__}: {exc}".splitlines()[0]}
    figures[name]["seconds_taken"] = round(time.perf_counter() - start, 1)


def summary_markdown(figures: dict[str, dict]) -> str:
    lines: list[str] = ["# gpu-check", "", f"Machine: {figures['machine']}", ""]
    learner = figures.get("learner", {})
    lines += ["## Learner on CUDA", ""]
    if "rows" in learner:
        lines += [f"{learner['device']}", "", "| batch | precision | updates/s |", "|---|---|---|"]
        lines += [f"| {r['batch']} | {r['precision']} | {r['updates_per_s']:.0f} |"
                  for r in learner["rows"]]
    render = figures.get("render", {})
    lines += ["", "## EGL rendering in spawned processes (two-room)", ""]
    if "rows" in render:
        lines += [f"GL_RENDERER: {render['renderer']}", "",
                  "| processes | steps/s total | steps/s per process |", "|---|---|---|"]
        lines += [f"| {r['processes']} | {r['steps_per_s_total']:,.0f} | "
                  f"{r['steps_per_s_per_process']:,.0f} |" for r in render["rows"]]
    system = figures.get("system", {})
    lines += ["", "## Whole system (two-room, learner on CUDA)", ""]
    if "rows" in system:
        lines += ["| actors x envs | transitions/s | updates/s | replay ratio |",
                  "|---|---|---|---|"]
        lines += [f"| {r['actors']} x {r['envs_per_actor']} | {r['steps_per_s']:,.0f} | "
                  f"{r['updates_per_s']:.0f} | {r['replay_ratio']:.4f} |"
                  for r in system["rows"]]
    learning = figures.get("learning", {})
    lines += ["", f"## {LEARNING_SECONDS // 60}-minute two-room run (--preset cpu, 15 actors)",
              ""]
    if "last" in learning:
        lines += ["Last metrics row: " + ", ".join(f"{k} {v}" for k, v in
                                                   learning["last"].items()),
                  "", "Curves: learning.png; table: learning.csv."]
    for name in ("learner", "render", "system", "learning"):
        if "error" in figures.get(name, {}):
            lines += ["", f"**{name} failed**: {figures[name]['error']}"]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m dqn_mine.bench.gpu_check",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="results/gpu-check", help="folder for the figures")
    ap.add_argument("--learning-seconds", type=float, default=LEARNING_SECONDS,
                    help="length of the learning run")
    args = ap.parse_args(argv)
    import torch

    if not torch.cuda.is_available():
        print("gpu-check: no CUDA device on this machine; nothing to check (run it on a GPU "
              "machine)")
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from dqn_mine.bench.__main__ import machine_line

    figures: dict[str, dict] = {"machine": machine_line(), "cores": os.cpu_count()}
    step("learner", learner_figures, figures)
    step("render", render_figures, figures)
    step("system", system_figures, figures)
    step("learning", lambda: learning_run(out, args.learning_seconds), figures)
    (out / "gpu_check.json").write_text(json.dumps(figures, indent=1, default=str))
    (out / "summary.md").write_text(summary_markdown(figures))
    print((out / "summary.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
