"""Experiments: grid expansion, sweep resume, aggregation against hand computations, and a
smoke-scale ablation end to end (real trainer subprocesses)."""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from dqn_mine.config import ConfigError, inert_settings, parse_args
from dqn_mine.metrics import COLUMNS
from experiments.aggregate import align, load_runs, summarize_config
from experiments.grid import SCALES, Claim, Grid, grid_names, load_grid
from experiments.launcher import Outcome, run_state, sweep_exit_code, train_command
from experiments.report import build_report, check_claim

ROOT = Path(__file__).resolve().parents[1]
PNGS = ("return_vs_updates.png", "return_vs_wall_time.png", "updates_per_s.png",
        "episode_length.png")


def launcher(*args: str, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "experiments", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            **kwargs)


# -- grids ---------------------------------------------------------------------------------------

EXPECTED = {"ablation", "actors", "exploration", "nstep", "partial_obs", "scaling", "zeta"}


def test_every_experiment_of_the_study_has_a_grid():
    assert EXPECTED <= set(grid_names())


@pytest.mark.parametrize("name", sorted(EXPECTED))
@pytest.mark.parametrize("scale", SCALES)
def test_grid_expands_to_valid_runs(name, scale, tmp_path):
    from dqn_mine.train import check_env_settings

    grid = load_grid(name)
    if not grid.has_scale(scale):
        with pytest.raises(ConfigError, match=f"no {scale} scale"):
            grid.expand(scale, tmp_path)
        return
    runs = grid.expand(scale, tmp_path, seeds=[0, 3])
    assert len(runs) == 2 * len(grid.config_names(scale))
    assert len({r.run_dir for r in runs}) == len(runs)
    for r in runs:
        assert r.run_dir == tmp_path / r.config_name / f"seed{r.seed}"
        assert r.cfg.seed == r.seed
        # The flags rebuild the same config (what the trainer subprocess will run).
        assert parse_args(r.argv()) == r.cfg
        if scale != "paper":  # paper settings are the defaults the trainer tests already cover
            check_env_settings(r.cfg)
    assert len({r.cfg for r in runs if r.seed == 0}) == len(grid.config_names(scale))


def test_ablation_settings_are_the_studys_at_paper_scale(tmp_path):
    grid = load_grid("ablation")
    cfgs = {r.config_name: r.cfg for r in grid.expand("paper", tmp_path, seeds=[0])}
    assert {k: (c.actors, c.zeta, c.n_step) for k, c in cfgs.items()} == {
        "all-included": (7, 0.6, 6), "no-n-step": (7, 0.6, 1),
        "no-distribution": (1, 0.6, 6), "no-per": (7, 0.0, 6),
        "none-included": (1, 0.0, 1)}
    assert all(c.task == "two-room" and c.lr == 3e-5 for c in cfgs.values())


def test_precedence_of_overrides(tmp_path):
    grid = Grid(name="t", title="t",
                configs={"a": {"n_step": 3, "actors": 4}, "b": {}},
                base={"task": "one-room", "n_step": 2, "lr": 1e-3},
                scales={"quick": {"base": {"preset": "smoke", "lr": 1e-4, "actors": 3},
                                  "override": {"a": {"actors": 1}}, "configs": ["a"],
                                  "seeds": 2}})
    runs = grid.expand("quick", tmp_path)
    assert [(r.config_name, r.seed) for r in runs] == [("a", 0), ("a", 1)]
    cfg = runs[0].cfg
    assert (cfg.preset, cfg.task, cfg.lr, cfg.n_step, cfg.actors) == \
        ("smoke", "one-room", 1e-4, 3, 1)
    assert cfg.prefill == 2000  # from the smoke preset
    b = grid.expand("paper", tmp_path, seeds=[5])[1].cfg
    assert (b.preset, b.n_step, b.actors, b.seed) == ("paper", 2, 7, 5)


def test_bad_grids_are_refused(tmp_path):
    bad = Grid(name="t", title="t", configs={"a": {"no_such_field": 1}}, base={}, scales={})
    with pytest.raises(ConfigError, match="no_such_field"):
        bad.expand("paper", tmp_path)
    bad = Grid(name="t", title="t", configs={"a": {"actors": 0}}, base={}, scales={})
    with pytest.raises(ConfigError, match="actors"):
        bad.expand("paper", tmp_path)
    with pytest.raises(ConfigError, match="unknown grid"):
        load_grid("no-such-grid")
    path = tmp_path / "g.py"
    path.write_text("CONFIGS = {'a': {}}\nSCALES = {'quick': {'configs': ['zzz']}}\n")
    with pytest.raises(ConfigError, match="zzz"):
        load_grid(str(path))
    with pytest.raises(ConfigError, match="scale"):
        load_grid("ablation").expand("huge", tmp_path)


# -- launcher: states of run folders -------------------------------------------------------------

def _fake_run(spec, summary=None, checkpoint=False, cfg=None):
    spec.run_dir.mkdir(parents=True)
    (cfg or spec.cfg).to_json(spec.run_dir / "config.json")
    if checkpoint:
        (spec.run_dir / "checkpoint.pt").write_bytes(b"x")
    if summary is not None:
        (spec.run_dir / "summary.json").write_text(json.dumps(summary))


def test_run_states_decide_skip_resume_restart(tmp_path):
    import dataclasses

    grid = load_grid("nstep")
    specs = grid.expand("smoke", tmp_path, seeds=[0, 1, 2, 3, 4, 5])
    target = specs[0].cfg.updates
    _fake_run(specs[0], {"exit_code": 0, "updates": target}, checkpoint=True)
    _fake_run(specs[1], {"exit_code": 130, "updates": 40}, checkpoint=True)
    _fake_run(specs[2], {"exit_code": 0, "updates": target - 1}, checkpoint=True)  # extend
    _fake_run(specs[3])  # killed during start-up: config.json, nothing else
    _fake_run(specs[4], checkpoint=True,
              cfg=dataclasses.replace(specs[4].cfg, lr=0.5))  # another configuration
    states = [run_state(s) for s in specs]
    assert states[:4] == ["complete", "resume", "resume", "restart"]
    assert states[4].startswith("conflict") and "lr" in states[4]
    assert states[5] == "fresh"
    cmd = train_command(specs[1], "resume")
    assert cmd[-4:] == ["--resume", str(specs[1].run_dir), "--updates", str(target)]
    assert "--run-dir" in train_command(specs[5], "fresh")
    outcomes = [Outcome(specs[0], "complete"), Outcome(specs[1], "resume", 0)]
    assert sweep_exit_code(outcomes, interrupted=False) == 0
    assert sweep_exit_code(outcomes + [Outcome(specs[4], states[4])], False) == 1
    assert sweep_exit_code(outcomes + [Outcome(specs[2], "resume", 1)], False) == 1
    assert sweep_exit_code(outcomes, interrupted=True) == 130


def test_a_setting_the_run_never_reads_is_no_conflict(tmp_path):
    # A run without the schedule curriculum, made when --rooms-schedule had another value,
    # never read it: still the grid's run. The schedule run read it: a conflict.
    import dataclasses

    specs = load_grid("scaling").expand("cpu", tmp_path, seeds=[0])
    unread = next(s for s in specs if s.cfg.curriculum != "schedule")
    read = next(s for s in specs if s.cfg.curriculum == "schedule")
    for spec in (unread, read):
        done = {"exit_code": 0, "updates": spec.cfg.updates}
        _fake_run(spec, done, cfg=dataclasses.replace(spec.cfg, rooms_schedule=(2, 3)))
    assert run_state(unread) == "complete"
    assert run_state(read).startswith("conflict")
    assert "rooms_schedule" in run_state(read)
    no_schedule = dataclasses.replace(read.cfg, curriculum="none")
    assert "rooms_schedule" in inert_settings(no_schedule)
    assert "rooms_schedule" not in inert_settings(read.cfg)


def test_a_run_that_spent_its_minutes_is_complete(tmp_path):
    # The cpu scale of the exploration grid bounds runs by minutes, not updates: a finished run
    # is skipped, not resumed, by the next sweep; one stopped early is resumed.
    spec, early = load_grid("exploration").expand("cpu", tmp_path, seeds=[9])[1:3]
    assert spec.cfg.minutes == 90 and early.cfg.minutes is not None
    _fake_run(spec, {"exit_code": 0, "updates": 400_000, "wall_time": 90 * 60.0},
              checkpoint=True)
    _fake_run(early, {"exit_code": 0, "updates": 400_000, "wall_time": 60.0}, checkpoint=True)
    assert [run_state(spec), run_state(early)] == ["complete", "resume"]


def test_jobs_never_oversubscribe_cores(tmp_path):
    from experiments.launcher import Sweep, _Running

    grid = Grid(name="t", title="t", configs={"one": {"actors": 1}, "three": {"actors": 3},
                                              "eval": {"actors": 1, "eval_every": 100}},
                base={}, scales={})
    one, three, ev = grid.expand("paper", tmp_path)
    assert (one.processes(), three.processes(), ev.processes()) == (2, 4, 3)
    sweep = Sweep([], jobs=3, cores=6, progress=False)
    assert sweep._fits(three)  # nothing running: a run always starts, even a big one
    sweep.running = [_Running(one, "fresh", None, None, 0)]
    assert sweep._fits(three)  # 2 + 4 busy processes fit 6 cores
    sweep.running.append(_Running(three, "fresh", None, None, 1))
    assert not sweep._fits(one)  # 6 busy of 6 cores
    sweep = Sweep([], jobs=1, cores=64, progress=False)
    sweep.running = [_Running(one, "fresh", None, None, 0)]
    assert not sweep._fits(one)  # jobs = 1: one at a time whatever the cores


# -- aggregation against hand computations -------------------------------------------------------

def _write_metrics(run_dir: Path, rows, exit_code=0):
    run_dir.mkdir(parents=True)
    with open(run_dir / "metrics.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        for row in rows:
            w.writerow({k: ("" if row.get(k) is None else row[k]) for k in COLUMNS})
    (run_dir / "summary.json").write_text(json.dumps({"exit_code": exit_code}))


def _row(update, wall, ret, length=50, ups=10.0, ratio=0.1, sampled=0.0, ev=None, phase=0):
    return {"update": update, "wall_time": wall, "episode_return": ret, "episode_length": length,
            "updates_per_s": ups, "env_steps_per_s": 100.0, "replay_ratio": ratio,
            "sampled_reward": sampled, "eval_return": ev, "phase": phase}


def _synthetic(out: Path):
    """Two configurations; 'a' has two seeds with different logging points and an empty cell."""
    _write_metrics(out / "a" / "seed0", [
        _row(100, 10.0, None, length=None, ups=8.0, ratio=0.20, sampled=0.0, phase=3),
        _row(200, 20.0, 0.2, length=40, ups=12.0, ratio=0.15, sampled=0.1, ev=0.7, phase=2),
        _row(300, 30.0, 0.4, length=30, ups=10.0, ratio=0.10, sampled=0.2, ev=0.5, phase=2)])
    _write_metrics(out / "a" / "seed1", [
        _row(150, 15.0, 0.0, length=50, ups=20.0, ratio=0.30, sampled=0.0, phase=4),
        _row(250, 35.0, 0.6, length=20, ups=20.0, ratio=0.20, sampled=0.3, ev=1.0, phase=3),
        # a resumed run re-logs update 250 after its last checkpoint: the later row wins
        _row(250, 36.0, 0.8, length=10, ups=30.0, ratio=0.25, sampled=0.5, ev=0.9, phase=3)],
        exit_code=130)
    _write_metrics(out / "b" / "seed0", [_row(100, 5.0, 0.1), _row(200, 9.0, 0.3)])


def test_summary_matches_hand_computation(tmp_path):
    _synthetic(tmp_path)
    runs = load_runs(tmp_path, ["a", "b"], [0, 1])
    assert [len(runs["a"]), len(runs["b"])] == [2, 1]
    a = summarize_config("a", "x", runs["a"])
    assert (a["seeds"], a["finished"]) == (2, 1)
    # finals: seed0 0.4 (last row), seed1 0.8 (the repeated update's later row)
    assert a["final_return_mean"] == pytest.approx(0.6)
    assert a["final_return_std"] == pytest.approx(math.sqrt(((0.4 - 0.6) ** 2 +
                                                             (0.8 - 0.6) ** 2) / 1))
    assert (a["final_return_min"], a["final_return_max"]) == pytest.approx((0.4, 0.8))
    assert a["final_length_mean"] == pytest.approx((30 + 10) / 2)
    assert a["final_eval_return_mean"] == pytest.approx((0.5 + 0.9) / 2)
    # best: seed0 0.7 (before its last 0.5), seed1 0.9 (its 1.0 was re-logged as 0.9)
    assert a["best_eval_return_mean"] == pytest.approx((0.7 + 0.9) / 2)
    assert a["hardest_phase_mean"] == pytest.approx((2 + 3) / 2)
    assert a["updates"] == pytest.approx((300 + 250) / 2)
    assert a["wall_time_s"] == pytest.approx((30.0 + 36.0) / 2)
    assert a["updates_per_s"] == pytest.approx(((8 + 12 + 10) / 3 + (20 + 30) / 2) / 2)
    assert a["replay_ratio"] == pytest.approx((0.10 + 0.25) / 2)
    assert a["sampled_reward_mean"] == pytest.approx(((0 + 0.1 + 0.2) / 3 + (0 + 0.5) / 2) / 2)
    # early: first logged return at or after 25% of the last update (seed0 skips its empty cell)
    assert a["early_return_mean"] == pytest.approx((0.2 + 0.0) / 2)
    b = summarize_config("b", "", runs["b"])
    assert b["final_return_mean"] == pytest.approx(0.3)
    assert math.isnan(b["final_return_std"])  # one seed: no sample std
    assert math.isnan(b["final_eval_return_mean"])
    assert math.isnan(b["best_eval_return_mean"]) and math.isnan(b["hardest_phase_mean"])
    assert b["early_return_mean"] == pytest.approx(0.1)


def test_hardest_phase_of_a_room_schedule_is_its_most_rooms(tmp_path):
    """Under --curriculum schedule the phase column holds the room count, which grows."""
    for name, curriculum in (("sched", "schedule"), ("phased", "adaptive")):
        _write_metrics(tmp_path / name / "seed0", [_row(100, 1.0, 0.0, phase=3),
                                                   _row(200, 2.0, 0.0, phase=5)])
        (tmp_path / name / "seed0" / "config.json").write_text(
            json.dumps({"curriculum": curriculum}))
    runs = load_runs(tmp_path, ["sched", "phased"], [0])
    assert summarize_config("sched", "", runs["sched"])["hardest_phase_mean"] == 5
    assert summarize_config("phased", "", runs["phased"])["hardest_phase_mean"] == 3


def test_curves_interpolate_seeds_on_a_common_grid():
    xs = [np.array([100.0, 200.0, 300.0]), np.array([150.0, 250.0, 350.0])]
    ys = [np.array([np.nan, 0.2, 0.4]), np.array([0.0, 0.6, 1.0])]
    c = align(xs, ys, points=3)
    # common range: from the later first valid x (200) to the earlier last x (300)
    assert c.x.tolist() == [200.0, 250.0, 300.0]
    s0 = [0.2, 0.3, 0.4]          # seed 0 at 200, 250, 300
    s1 = [0.3, 0.6, 0.8]          # seed 1: halfway 150->250, at 250, halfway 250->350
    assert c.mean == pytest.approx([(p + q) / 2 for p, q in zip(s0, s1)])
    assert c.min == pytest.approx([min(p, q) for p, q in zip(s0, s1)])
    assert c.max == pytest.approx([max(p, q) for p, q in zip(s0, s1)])
    assert c.std == pytest.approx([abs(p - q) / math.sqrt(2) for p, q in zip(s0, s1)])
    assert c.n == 2
    assert align([np.array([1.0, 2.0]), np.array([3.0, 4.0])],
                 [np.array([0.0, 0.0])] * 2).x.size == 0  # disjoint ranges: nothing shared


def test_claims_and_report_from_synthetic_runs(tmp_path):
    _synthetic(tmp_path)
    rows = {"a": {"final_return_mean": 0.6}, "b": {"final_return_mean": 0.3}}
    assert check_claim(Claim("", "final_return_mean", "a", ">", "b"), rows) == (True, 0.6, 0.3)
    assert check_claim(Claim("", "final_return_mean", "a", "<", "b"), rows)[0] is False
    assert check_claim(Claim("", "final_return_mean", "a", "~", "b"), rows)[0] is False
    assert check_claim(Claim("", "final_return_mean", "a", "~", "a"), rows)[0] is True
    assert check_claim(Claim("", "wall_time_s", "a", ">", "b"), rows)[0] is None
    grid = Grid(name="t", title="Synthetic", configs={"a": {"actors": 2}, "b": {}}, base={},
                scales={}, finding="a beats b.",
                claims=(Claim("a ahead of b", "final_return_mean", "a", ">", "b"),))
    report = build_report(grid, "paper", tmp_path, [0, 1]).read_text()
    assert "a ahead of b: **yes** (a 0.600 vs b 0.300" in report
    assert "| `a` | actors=2 | 2 (1) | 0.600 ± 0.283 [0.400, 0.800] | 2.5 |" in report
    assert "| final return | hardest phase reached (schedule: rooms) |" in report
    with open(tmp_path / "summary.csv", newline="") as f:
        summary = {r["config"]: r for r in csv.DictReader(f)}
    assert float(summary["a"]["final_return_mean"]) == pytest.approx(0.6)
    assert summary["b"]["final_return_std"] == ""
    pytest.importorskip("matplotlib")
    for png in PNGS:
        assert (tmp_path / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# -- real sweeps ---------------------------------------------------------------------------------

TINY = ('{"preset": "smoke", "updates": 60, "prefill": 200, "replay_capacity": 4096, '
        '"actors": 1, "room_size": 8.0, "max_episode_steps": 50, "log_interval": 20, '
        '"checkpoint_interval": 1000}')


def test_interrupted_sweep_resumes_and_skips_complete_runs(tmp_path):
    """Run 'quick' to completion, stop the sweep inside 'long' with SIGINT (forwarded to the
    trainer, which checkpoints), then re-run: 'quick' is skipped, 'long' resumes and finishes."""
    grid = tmp_path / "tiny.py"
    grid.write_text(f"TITLE = 'tiny'\nBASE = {TINY}\n"
                    "CONFIGS = {'quick': {}, 'long': {'updates': 5000}}\n")
    out = tmp_path / "out"
    args = ("run", str(grid), "--scale", "smoke", "--out", str(out), "--no-progress")
    proc = launcher(*args, start_new_session=True)
    metrics = out / "long" / "seed0" / "metrics.csv"
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and proc.poll() is None:
        if metrics.exists() and len(metrics.read_text().splitlines()) >= 3:
            break
        time.sleep(0.5)
    assert proc.poll() is None, proc.communicate()[0]
    os.kill(proc.pid, signal.SIGINT)
    text = proc.communicate(timeout=120)[0]
    assert proc.returncode == 130, text
    long_dir, quick_dir = out / "long" / "seed0", out / "quick" / "seed0"
    assert json.loads((long_dir / "summary.json").read_text())["exit_code"] == 130
    assert (long_dir / "checkpoint.pt").exists()
    assert json.loads((quick_dir / "summary.json").read_text())["exit_code"] == 0
    assert (out / "report.md").exists()  # a report of what there is so far
    stopped_at = json.loads((long_dir / "summary.json").read_text())["updates"]
    quick_mtime = (quick_dir / "summary.json").stat().st_mtime

    # Finish 'long' quickly: the grid now asks for fewer updates than 5000 (a resume extends or
    # keeps the target; only `updates` may change between runs of a sweep).
    grid.write_text(f"TITLE = 'tiny'\nBASE = {TINY}\n"
                    f"CONFIGS = {{'quick': {{}}, 'long': {{'updates': {stopped_at + 40}}}}}\n")
    proc = launcher(*args)
    text = proc.communicate(timeout=240)[0]
    assert proc.returncode == 0, text
    assert (quick_dir / "summary.json").stat().st_mtime == quick_mtime  # skipped
    summary = json.loads((long_dir / "summary.json").read_text())
    assert (summary["exit_code"], summary["updates"]) == (0, stopped_at + 40)
    assert "--resume" in (long_dir / "train.log").read_text()
    updates = [float(r["update"]) for r in csv.DictReader(open(long_dir / "metrics.csv"))]
    assert updates[-1] == stopped_at + 40 and updates[0] == 20
    assert "2/2 runs complete" in text


@pytest.mark.slow
def test_smoke_ablation_end_to_end(tmp_path):
    out = tmp_path / "ablation"
    proc = launcher("run", "ablation", "--scale", "smoke", "--out", str(out), "--no-progress")
    text = proc.communicate(timeout=600)[0]
    assert proc.returncode == 0, text
    names = load_grid("ablation").config_names("smoke")
    for name in names:
        assert json.loads((out / name / "seed0" / "summary.json").read_text())["exit_code"] == 0
    report = (out / "report.md").read_text()
    assert "all included ahead of none included at the end: **" in report
    with open(out / "summary.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["config"] for r in rows] == names
    assert all(float(r["updates"]) == 150 and float(r["updates_per_s"]) > 0 for r in rows)
    pytest.importorskip("matplotlib")
    for png in PNGS + ("sampled_reward.png",):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"]({png})" in report


def test_auto_scale_fits_the_machine():
    import torch

    from experiments.__main__ import resolve_scale

    assert resolve_scale("auto") == ("paper" if torch.cuda.is_available() else "quick")
    assert [resolve_scale(s) for s in SCALES] == list(SCALES)


def test_a_seed_given_twice_is_one_run():
    from experiments.__main__ import build_parser, seeds_of

    args = build_parser().parse_args(["run", "ablation", "--seed-list", "3", "0", "3", "1"])
    assert seeds_of(args, load_grid("ablation")) == [3, 0, 1]


def test_report_refuses_runs_of_another_scale(tmp_path, capsys):
    from experiments.__main__ import main

    for spec in load_grid("ablation").expand("quick", tmp_path, [0]):
        spec.run_dir.mkdir(parents=True)
        spec.cfg.to_json(spec.run_dir / "config.json")
    assert main(["report", "ablation", "--scale", "paper", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "other settings" in err and "\n" not in err
    assert not (tmp_path / "report.md").exists()


def test_configs_runs_a_subset_in_the_order_named(tmp_path, capsys):
    from experiments.__main__ import main

    out = tmp_path / "sweep"
    assert main(["run", "exploration", "--scale", "cpu", "--out", str(out), "--dry-run",
                 "--configs", "any-room", "baseline", "any-room"]) == 0
    printed = capsys.readouterr().out
    labels = [line.split(":")[0] for line in printed.splitlines() if not line.startswith(" ")]
    assert labels == ["any-room/seed0", "baseline/seed0"]
    assert "--placement any-room" in printed and not out.exists()
    assert main(["run", "exploration", "--scale", "cpu", "--out", str(out), "--dry-run",
                 "--configs", "baseline", "bogus"]) == 2
    err = capsys.readouterr().err.strip()
    assert "'bogus'" in err and "any-room" in err and "\n" not in err
