"""`python -m dqn_mine.plot`: learning-curve PNGs of run folders."""

import json
import math

import numpy as np
import pytest

from dqn_mine.metrics import MetricsTable
from dqn_mine.plot import main

pytest.importorskip("matplotlib")


def fake_run(run_dir, phases):
    run_dir.mkdir()
    table = MetricsTable(run_dir / "metrics.csv")
    for i, phase in enumerate(phases):
        table.write({"update": 100 * (i + 1), "wall_time": 10.0 * (i + 1),
                     "episode_return": min(1.0, 0.1 * i),
                     "eval_return": 0.5 if i % 3 == 0 else math.nan, "phase": phase})
    table.close()
    return run_dir


def write_metrics(run_dir, rows):
    """A run folder whose metrics.csv holds ``rows``."""
    run_dir.mkdir()
    metrics = MetricsTable(run_dir / "metrics.csv")
    for row in rows:
        metrics.write(row)
    metrics.close()
    return run_dir


def png_size(path):
    from PIL import Image

    with Image.open(path) as img:
        return img.size, np.asarray(img.convert("L")).std()


def test_plot_writes_curves_and_a_phase_panel_for_curricula(tmp_path):
    plain = fake_run(tmp_path / "plain", [0] * 8)
    stepped = fake_run(tmp_path / "curriculum", [6, 6, 5, 5, 4, 3, 3, 3])
    assert main([str(plain)]) == 0
    assert main([str(stepped), str(plain), "--out", str(tmp_path / "both.png")]) == 0
    (w2, h2), ink2 = png_size(plain / "curves.png")
    (w3, h3), ink3 = png_size(tmp_path / "both.png")
    assert h2 == h3 and w3 > 1.3 * w2          # the curriculum adds a third panel
    assert ink2 > 5 and ink3 > 5               # not a blank image


def test_plot_of_a_folder_without_metrics_is_one_line(tmp_path, capsys):
    assert main([str(tmp_path / "missing")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: no metrics.csv") and "\n" not in err


def test_milestones_count_full_task_windows_only(tmp_path, capsys):
    """Phase 1's rolling return counts once a full window of phase-1 episodes has ended; a high
    return of an easier phase, or of a half-filled window after the switch, does not."""

    from dqn_mine.config import parse_args
    from dqn_mine.plot import milestones

    cfg = parse_args(["--task", "three-room", "--curriculum", "adaptive",
                      "--curriculum-window", "10", "--curriculum-review", "0.5"])
    # (phase, episodes so far, phase_return): phase 2 at 0.95; phase 1 from 100 episodes on,
    # its window full from 120 (20 episodes x 0.5 share)
    table = [(2, 50, 0.95), (1, 100, 0.0), (1, 110, 1.0), (1, 120, 0.55), (1, 140, 0.7),
             (1, 160, 0.92), (1, 180, 0.85)]
    rows = [{"update": 100.0 * (i + 1), "wall_time": 60.0 * (i + 1), "phase": float(p),
             "episodes": float(e), "phase_return": r, "episode_return": r}
            for i, (p, e, r) in enumerate(table)]
    reached = milestones(rows, cfg, (0.5, 0.9, 0.99))
    assert reached == {0.5: (400.0, 4.0), 0.9: (600.0, 6.0), 0.99: None}
    # without a curriculum: the actors' return once RETURN_WINDOW episodes have ended
    plain = parse_args([])
    assert milestones(rows, plain, (0.9,)) == {0.9: (300.0, 3.0)}
    # the command line reads each run's config.json
    run_dir = write_metrics(tmp_path / "run", rows)
    (run_dir / "config.json").write_text(json.dumps(
        {"task": "three-room", "curriculum": "adaptive", "curriculum_window": 10,
         "curriculum_review": 0.5}))
    assert main([str(run_dir), "--milestones", "0.5", "0.9"]) == 0
    out = capsys.readouterr().out
    assert "| run | 400, 4.0 | 600, 6.0 | 0.85 |" in out
    # a run that logs the near-greedy envs' means gets their last full-task value as well
    with_low = write_metrics(tmp_path / "low", [
        {**row, "low_eps_return": 0.5, "phase_low_eps_return": 0.4 * row["phase_return"]}
        for row in rows])
    (with_low / "config.json").write_text((run_dir / "config.json").read_text())
    assert main([str(run_dir), str(with_low), "--milestones", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "| last full-task return | last at epsilon <= 0.01 |" in out
    assert "| run | 400, 4.0 | 0.85 | - |" in out and "| low | 400, 4.0 | 0.85 | 0.34 |" in out
    # a run with an evaluation actor: when its return first reached each level, and its last
    evals = [math.nan, 0.2, 0.6, math.nan, 0.4, 0.9, 0.8]
    evaluated = write_metrics(tmp_path / "eval", [{**row, "eval_return": e}
                                                  for row, e in zip(rows, evals)])
    (evaluated / "config.json").write_text((run_dir / "config.json").read_text())
    assert main([str(evaluated), "--milestones", "0.5", "0.9"]) == 0
    out = capsys.readouterr().out
    assert "| evaluation 0.5: updates, minutes | evaluation 0.9: updates, minutes |" in out
    assert "| eval | 400, 4.0 | 600, 6.0 | 0.85 | 300, 3.0 | 600, 6.0 | 0.80 |" in out
    assert main([str(run_dir), "--phases"]) == 0
    assert "| run | 100, 1.0 | 200, 2.0 |" in capsys.readouterr().out   # phase 2, then 1


def test_band_takes_each_runs_last_value_zero_before_its_start_and_none_after_its_end():
    from dqn_mine.plot import band

    a = [(10.0, 0.2), (20.0, 0.8)]             # reaches the full task at x = 10, stops at 20
    b = [(0.0, 0.5), (30.0, 1.0)]
    lo, mid, hi = band([a, b], [5.0, 15.0, 25.0, 40.0])
    assert lo[:3] == [0.0, 0.2, 0.5] and hi[:3] == [0.5, 0.5, 0.5]
    assert mid[:3] == [0.25, 0.35, 0.5]        # at 25 only b is still running
    assert all(math.isnan(v[3]) for v in (lo, mid, hi))   # no run goes on to 40


def test_band_plot_of_seeds_writes_a_png(tmp_path):
    runs = []
    for seed, phases in enumerate(([3, 2, 1, 1, 1, 1, 1, 1], [2, 2, 2, 1, 1, 1, 1, 1])):
        run = fake_run(tmp_path / f"seed{seed}", phases)
        (run / "config.json").write_text(json.dumps({"task": "three-room",
                                                     "curriculum": "adaptive",
                                                     "curriculum_window": 1}))
        runs.append(str(run))
    assert main([*runs, "--band", "--out", str(tmp_path / "band.png")]) == 0
    (w, h), ink = png_size(tmp_path / "band.png")
    assert w > h and ink > 5


def test_phase_stays_by_hand(tmp_path, capsys):
    """Each stay in a phase: when it began, how long until the next phase's first row (or the
    last row), and its mean rolling returns, NaN rows left out."""
    from dqn_mine.plot import phase_stays

    nan = math.nan
    # (minutes, phase, phase_return, phase_low_eps_return)
    table = [(1, 3, 0.2, nan), (2, 3, 0.4, 0.5), (3, 2, nan, nan), (5, 2, 0.1, 0.3),
             (6, 2, 0.3, 0.1), (7, 1, 0.9, 1.0), (10, 1, 0.7, nan)]
    rows = [{"update": 100.0 * m, "wall_time": 60.0 * m, "phase": float(p),
             "phase_return": r, "phase_low_eps_return": low} for m, p, r, low in table]
    stays = phase_stays(rows)
    assert [s[:3] for s in stays] == [(3, 1.0, 2.0), (2, 3.0, 4.0), (1, 7.0, 3.0)]
    assert [s[3] for s in stays] == pytest.approx([0.3, 0.2, 0.8])
    assert [s[4] for s in stays] == pytest.approx([0.5, 0.2, 1.0])
    run_dir = write_metrics(tmp_path / "run", rows)
    assert main([str(run_dir), "--phases"]) == 0
    out = capsys.readouterr().out
    assert "| run | 2 | 3.0 | 4.0 | 0.20 | 0.20 |" in out


def test_a_run_this_version_cannot_continue_is_still_read_for_its_figures(tmp_path):
    """A version 2 run with a look that is neither view: it cannot resume (one-line error), yet
    the plot reads the settings its figures need."""
    from dqn_mine.config import Config, ConfigError
    from dqn_mine.plot import run_config

    path = tmp_path / "config.json"
    path.write_text(json.dumps({"config_version": 2, "curriculum": "adaptive",
                                "curriculum_window": 7, "camera_pitch": 15.0,
                                "room_colours": False}))
    with pytest.raises(ConfigError, match="version 2"):
        Config.from_json(path)
    cfg = run_config(path)
    assert (cfg.curriculum, cfg.curriculum_window) == ("adaptive", 7)
