"""The trainer end to end: real spawned actors, real shared memory, real signals."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dqn_mine.shared import leftover_segments

ROOT = Path(__file__).resolve().parents[1]
# A tiny fast configuration on top of the smoke preset.
TINY = ["--preset", "smoke", "--actors", "2", "--prefill", "200", "--replay-capacity", "4096",
        "--log-interval", "20", "--checkpoint-interval", "1000"]


def train_cmd(*args: str) -> list:
    return [sys.executable, "-m", "dqn_mine.train", *args]


def run_train(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(train_cmd(*args), cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout)


def metrics_rows(run_dir: Path) -> list:
    with open(run_dir / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


def children_of(pid: int) -> list:
    out = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout
    return [int(p) for p in out.split()]


def alive(pids: list) -> list:
    out = []
    for pid in pids:
        try:
            with open(f"/proc/{pid}/status") as f:
                if "zombie" not in f.read().lower():
                    out.append(pid)
        except FileNotFoundError:
            pass
    return out


def wait_for(predicate, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture(autouse=True)
def no_leftovers():
    before = set(leftover_segments())
    yield
    assert set(leftover_segments()) - before == set(), "shared memory segments leaked"


# -- bad input -------------------------------------------------------------------------------
@pytest.mark.parametrize("flags, phrase", [
    (["--actors", "0"], "actors"),
    (["--n-step", "0"], "n-step"),
    (["--task", "four-room"], "task"),
    (["--replay-capacity", "16", "--batch-size", "32"], "capacity"),
    (["--resume", "no/such/run"], "no/such/run"),
])
def test_bad_flags_give_one_line_and_touch_nothing(tmp_path, flags, phrase):
    run_dir = tmp_path / "run"
    res = run_train(*flags, "--run-dir", str(run_dir), timeout=60)
    assert res.returncode == 2
    lines = [ln for ln in res.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, res.stderr
    assert phrase.replace("-", "") in lines[0].replace("-", "").replace("_", "").lower()
    assert not run_dir.exists()


def test_resume_of_corrupt_run_is_one_line(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text("{not json")
    res = run_train("--resume", str(run_dir), timeout=60)
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert sorted(p.name for p in run_dir.iterdir()) == ["config.json"]


# -- serial wiring ---------------------------------------------------------------------------
def test_serial_run_writes_the_run_folder(tmp_path):
    run_dir = tmp_path / "serial"
    res = run_train(*TINY, "--serial", "--updates", "60", "--run-dir", str(run_dir))
    assert res.returncode == 0, res.stderr[-3000:]
    cfg = json.loads((run_dir / "config.json").read_text())
    assert cfg["actors"] == 2 and cfg["serial"] is True
    rows = metrics_rows(run_dir)
    assert [int(r["update"]) for r in rows] == [20, 40, 60]
    assert int(rows[-1]["env_steps"]) >= 400          # the pre-fill at least
    assert float(rows[-1]["loss"]) >= 0
    assert (run_dir / "checkpoint.pt").exists()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["updates"] == 60 and summary["exit_code"] == 0
    # updates/s over training only, as the CSV measures it (start-up and pre-fill excluded)
    csv_rate = sorted(float(r["updates_per_s"]) for r in rows)[1]
    assert 0.5 * csv_rate < summary["updates_per_s"] < 2 * csv_rate
    assert summary["return_episodes"] == min(summary["episodes"], 100)
    machine = [json.loads(line) for line in (run_dir / "machine.jsonl").read_text().splitlines()]
    assert len(machine) == 1 and machine[0]["device"] == "cpu"
    assert machine[0]["learner_precision"] in ("float32", "bfloat16")
    assert machine[0]["gemm_float32_gflops_1_thread"] > 0


def test_minutes_end_a_run_as_finished_with_a_checkpoint(tmp_path):
    run_dir = tmp_path / "timed"
    res = run_train(*TINY, "--serial", "--updates", "1000000", "--minutes", "0.25",
                    "--run-dir", str(run_dir))
    assert res.returncode == 0, res.stderr[-3000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["reason"] == "finished (time budget of 0.25 min)"
    assert 0 < summary["updates"] < 1_000_000 and 15 <= summary["wall_time"] < 60
    assert (run_dir / "checkpoint.pt").exists()


def test_saved_replay_is_read_back_on_resume_without_a_prefill(tmp_path):
    from dqn_mine import checkpoint as ckpt

    run_dir, replay_dir = tmp_path / "run", tmp_path / "replay"
    res = run_train(*TINY, "--serial", "--updates", "40", "--run-dir", str(run_dir),
                    "--save-replay", str(replay_dir))
    assert res.returncode == 0, res.stderr[-3000:]
    assert "saving the replay (" in res.stdout and "GB) to" in res.stdout
    first = ckpt.load(run_dir)["counters"]
    assert first["generation"] == 0 and (replay_dir / "frames.npy").exists()
    res = run_train("--resume", str(run_dir), "--updates", "60")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "transitions back from" in res.stdout and "no pre-fill" in res.stdout
    again = ckpt.load(run_dir)["counters"]
    # 20 updates stepped inline take a few dozen env steps; a new pre-fill alone would be 400
    assert 0 < again["env_steps"] - first["env_steps"] < 400
    assert again["generation"] == 1 and again["updates"] == 60
    assert json.loads((run_dir / "config.json").read_text())["prefill"] == 200
    assert len((run_dir / "machine.jsonl").read_text().splitlines()) == 2   # one per start
    # a replay of another size is refused in one line before anything starts
    res = run_train("--resume", str(run_dir), "--updates", "80", "--replay-capacity", "2048")
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert "replay layout" in res.stderr


def test_resumed_actors_draw_new_seeds():
    from dqn_mine.config import parse_args
    from dqn_mine.system.specs import actor_specs

    cfg = parse_args(["--actors", "3", "--eval-every", "100"])
    seeds = [[s.seed for s in actor_specs(cfg, g)] for g in range(3)]
    assert seeds[0] == [0, 1, 2, 7003]            # a new run keeps its documented seeds
    assert len({s for gen in seeds for s in gen}) == 12


def test_resume_takes_the_new_learning_rate(tmp_path):
    """Flags given on resume win, the optimiser's saved learning rate included."""
    from dqn_mine import checkpoint as ckpt

    run_dir = tmp_path / "resumed"
    res = run_train(*TINY, "--serial", "--updates", "40", "--run-dir", str(run_dir))
    assert res.returncode == 0, res.stderr[-3000:]
    res = run_train("--resume", str(run_dir), "--updates", "60", "--lr", "1e-5")
    assert res.returncode == 0, res.stderr[-3000:]
    state = ckpt.load(run_dir / "checkpoint.pt")
    assert {g["lr"] for g in state["updater"]["optimizer"]["param_groups"]} == {1e-5}
    assert json.loads((run_dir / "config.json").read_text())["lr"] == 1e-5


# -- parallel runs ---------------------------------------------------------------------------
def test_parallel_run_with_two_actors(tmp_path):
    run_dir = tmp_path / "par"
    res = run_train(*TINY, "--updates", "100", "--run-dir", str(run_dir))
    assert res.returncode == 0, res.stderr[-3000:]
    rows = metrics_rows(run_dir)
    assert int(rows[-1]["update"]) == 100
    assert float(rows[-1]["replay_ratio"]) > 0
    assert float(rows[-1]["env_steps_per_s"]) > 0


@pytest.mark.parametrize("save_replay", [False, True], ids=["plain", "save-replay"])
def test_sigint_stops_cleanly_and_resume_continues(tmp_path, save_replay):
    run_dir = tmp_path / "int"
    extra = ["--save-replay", str(tmp_path / "replay")] if save_replay else []
    proc = subprocess.Popen(train_cmd(*TINY, "--updates", "100000", "--run-dir", str(run_dir),
                                      *extra),
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: (run_dir / "metrics.csv").exists() and len(metrics_rows(run_dir)) >= 2,
                 240, "training to log")
        kids = children_of(proc.pid)
        assert len([k for k in kids]) >= 2
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        assert time.monotonic() - t0 < 30
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err[-3000:]
    assert "--resume" in out
    wait_for(lambda: not alive(kids), 10, "every child process to exit")
    stopped_at = int(metrics_rows(run_dir)[-1]["update"])
    from dqn_mine import checkpoint as ckpt

    # the last metrics row is the stop itself, not the last log interval before it
    assert int(ckpt.load(run_dir)["counters"]["updates"]) == stopped_at
    stopped_size = int(metrics_rows(run_dir)[-1]["replay_size"])
    res = run_train("--resume", str(run_dir), "--updates", str(stopped_at + 40))
    assert res.returncode == 0, res.stderr[-3000:]
    updates = [int(r["update"]) for r in metrics_rows(run_dir)]
    assert updates[-1] == stopped_at + 40
    assert updates == sorted(updates)
    assert ("saving the replay" in out) == save_replay
    assert ("no pre-fill" in res.stdout) == save_replay
    if save_replay:   # the resumed learner starts from the replay it stopped with
        resumed = [r for r in metrics_rows(run_dir) if int(r["update"]) > stopped_at]
        assert int(resumed[0]["replay_size"]) >= 0.95 * stopped_size


def test_second_sigint_stops_at_once_in_one_line_and_leaves_a_resumable_run(tmp_path):
    """The user insists (Ctrl-C twice): no traceback, no replay save to wait for, no process or
    segment left (the fixture checks /dev/shm), and the checkpoint still loads."""
    run_dir = tmp_path / "twice"
    proc = subprocess.Popen(train_cmd(*TINY, "--updates", "100000", "--run-dir", str(run_dir),
                                      "--save-replay", str(tmp_path / "replay")),
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: (run_dir / "metrics.csv").exists() and len(metrics_rows(run_dir)) >= 2,
                 240, "training to log")
        kids = children_of(proc.pid)
        proc.send_signal(signal.SIGINT)
        time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err[-3000:]
    assert "Traceback" not in err and "second SIGINT" in out + err
    assert "--resume" in out + err
    wait_for(lambda: not alive(kids), 10, "every child process to exit")
    from dqn_mine import checkpoint as ckpt

    assert int(ckpt.load(run_dir)["counters"]["updates"]) > 0
    assert not (tmp_path / "replay").exists() or not any((tmp_path / "replay").iterdir())


def test_sigint_while_the_expert_plans_demonstrations_stops_in_one_line(tmp_path):
    """Nothing exists yet: the run stops at once, says so in one line, and leaves no run folder
    in the way of the same command (nor a process or a segment)."""
    run_dir = tmp_path / "plan"
    argv = [a for a in TINY if a != "--no-progress"]      # the planning bar says when it plans
    proc = subprocess.Popen(train_cmd(*argv, "--demos", "5000", "--run-dir", str(run_dir)),
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        seen = ""
        while "planning" not in seen:
            char = proc.stderr.read(1)
            assert char, f"exited before planning: {seen[-2000:]}"
            seen += char
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err[-3000:]
    last = err.strip().splitlines()[-1]
    assert "Traceback" not in err and "while the expert planned" in last
    assert not run_dir.exists()


def test_killed_actor_stops_the_run_with_an_error(tmp_path):
    run_dir = tmp_path / "kill"
    proc = subprocess.Popen(train_cmd(*TINY, "--updates", "100000", "--run-dir", str(run_dir)),
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: (run_dir / "metrics.csv").exists(), 240, "the run to start")
        kids = children_of(proc.pid)
        actors = [k for k in kids
                  if "spawn_main" in open(f"/proc/{k}/cmdline").read().replace("\0", " ")]
        assert actors, "no actor process found"
        os.kill(actors[0], signal.SIGKILL)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1
    assert "actor 0 died (killed by SIGKILL)" in out + err
    assert (run_dir / "checkpoint.pt").exists()
    wait_for(lambda: not alive(kids), 10, "every child process to exit")


def test_killed_runner_takes_its_actors_and_shared_memory_with_it(tmp_path):
    """kill -9 of the runner: nobody sets the stop flag, so the actors notice their parent is
    gone, exit, and the resource tracker then unlinks the run's segments."""
    run_dir = tmp_path / "orphans"
    proc = subprocess.Popen(train_cmd(*TINY, "--updates", "100000", "--run-dir", str(run_dir)),
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for(lambda: (run_dir / "metrics.csv").exists(), 240, "the run to start")
        kids = children_of(proc.pid)
        assert len(kids) >= 2
        segments = [s for s in leftover_segments() if f"_{proc.pid}_" in s]
        assert segments, "the run's shared memory was not found"
        proc.kill()
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    wait_for(lambda: not alive(kids), 20, "the orphaned actors to exit")
    wait_for(lambda: not set(segments) & set(leftover_segments()), 20,
             "the resource tracker to unlink the segments")


# -- learning --------------------------------------------------------------------------------
@pytest.mark.slow
def test_smoke_preset_learns_one_room(tmp_path):
    """The whole system learns a small task on CPU (the README's main job)."""
    run_dir = tmp_path / "learn"
    res = run_train("--preset", "smoke", "--run-dir", str(run_dir),
                    timeout=1500)
    assert res.returncode == 0, res.stderr[-3000:]
    rows = metrics_rows(run_dir)
    # Means of the last eight rows (the last 2,000 updates): one row's rolling return swings by
    # +-0.1 between log intervals. The learned policy is judged by the near-greedy environment
    # (epsilon 0.0007; the other plays at 0.4), the all-env return mixes in the exploring one.
    # Untrained, both are 0.03-0.1. Locally the runs end at 0.93-0.96 near-greedy and 0.85-0.91
    # overall; two CI runs ended lower, one at 0.77 overall, one at 0.78 near-greedy (the run
    # and its timing differ from machine to machine), so the bars sit below those, still far
    # above an untrained agent.
    def last_rows_mean(key):
        return sum(float(r[key]) for r in rows[-8:]) / 8
    greedy, overall = last_rows_mean("low_eps_return"), last_rows_mean("episode_return")
    assert greedy >= 0.7, f"smoke preset's near-greedy env ended at return {greedy:.2f}"
    assert overall >= 0.55, f"smoke preset ended at mean return {overall:.2f} over all envs"


def test_cpu_preset_finds_rewards_on_two_room_within_its_prefill(tmp_path):
    """The cpu preset's exploration (its curriculum's first phase, Ape-X rates, ez, unstick)
    records rewarded two-room episodes within one pre-fill of 20,000 steps per actor."""
    run_dir = tmp_path / "cpu"
    res = run_train("--preset", "cpu", "--serial", "--updates", "40", "--replay-capacity",
                    "65536", "--eval-every", "0", "--log-interval", "20",
                    "--run-dir", str(run_dir), timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    rows = metrics_rows(run_dir)
    assert int(rows[-1]["env_steps"]) < 45_000
    assert int(rows[-1]["episodes"]) >= 32
    assert max(float(r["episode_return"]) for r in rows) > 0.05


def test_bump_and_press_prefill_records_more_rewards_than_the_agents_own(tmp_path):
    """With --prefill-explorer bump-and-press the scripted walker fills the replay: on the full
    16 x 16 one-room task its pre-fill records rewarded episodes, more than the same pre-fill
    played by the fresh agent at epsilon 0.01."""
    common = ["--task", "one-room", "--serial", "--actors", "2", "--envs-per-actor", "8",
              "--prefill", "8000", "--updates", "20", "--replay-capacity", "32768",
              "--log-interval", "20"]
    rows = {}
    for explorer in ("bump-and-press", "agent"):
        run_dir = tmp_path / explorer
        res = run_train(*common, "--prefill-explorer", explorer, "--run-dir", str(run_dir),
                        timeout=600)
        assert res.returncode == 0, res.stderr[-3000:]
        rows[explorer] = metrics_rows(run_dir)[-1]
    scripted, agent = rows["bump-and-press"], rows["agent"]
    assert int(scripted["episodes"]) >= 16 and float(scripted["episode_return"]) > 0.05
    assert int(agent["rewarded_episodes"]) < int(scripted["rewarded_episodes"])
    summary = json.loads((tmp_path / "bump-and-press" / "summary.json").read_text())
    assert summary["rewarded_episodes"] == int(scripted["rewarded_episodes"])
    assert float(scripted["sampled_reward"]) > 0          # the learner trains on those rewards


def test_tensorboard_event_files_hold_every_metrics_row(tmp_path):
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    run_dir = tmp_path / "tb"
    res = run_train(*TINY, "--serial", "--updates", "40", "--tensorboard",
                    "--run-dir", str(run_dir))
    assert res.returncode == 0, res.stderr[-3000:]
    events = EventAccumulator(str(run_dir / "tb"))
    events.Reload()
    rows = metrics_rows(run_dir)
    loss = events.Scalars("loss")
    assert [e.step for e in loss] == [int(r["update"]) for r in rows] == [20, 40]
    assert loss[-1].value == pytest.approx(float(rows[-1]["loss"]), rel=1e-4)
    assert any(tag.startswith("config") for tag in events.Tags()["tensors"])   # the config text


def test_serial_runs_are_deterministic_from_their_seed(tmp_path):
    """--serial (actors and learner in one process, no sampling thread): the same seed gives the
    same metrics row for row, timings aside; a parallel run is not reproducible (its processes
    interleave as the OS schedules them)."""
    timing = {"wall_time", "updates_per_s", "env_steps_per_s"}
    tables = []
    for name in ("a", "b"):
        res = run_train(*TINY, "--serial", "--updates", "40", "--seed", "3",
                        "--run-dir", str(tmp_path / name))
        assert res.returncode == 0, res.stderr[-3000:]
        tables.append([{k: v for k, v in r.items() if k not in timing}
                       for r in metrics_rows(tmp_path / name)])
    assert len(tables[0]) == 2 and tables[0] == tables[1]
    assert float(tables[0][-1]["loss"]) > 0
