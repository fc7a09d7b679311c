"""`python -m dqn_mine.plot`: learning-curve PNGs of run folders."""

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
