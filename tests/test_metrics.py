"""The metrics table: rows under the header, and a resumed run's older file kept whole."""

from __future__ import annotations

import csv

from dqn_mine.metrics import COLUMNS, MetricsTable, read_metrics


def test_new_table_has_every_column_and_empty_cells_read_as_nan(tmp_path):
    table = MetricsTable(tmp_path / "metrics.csv")
    table.write({"update": 10, "episode_return": 0.25, "low_eps_return": float("nan")})
    table.close()
    (row,) = read_metrics(tmp_path / "metrics.csv")
    assert list(row) == list(COLUMNS)
    assert row["update"] == 10 and row["episode_return"] == 0.25
    assert row["low_eps_return"] != row["low_eps_return"]      # NaN


def test_resumed_table_keeps_an_older_header_and_its_columns_aligned(tmp_path):
    path = tmp_path / "metrics.csv"
    old = ["update", "wall_time", "episode_return", "phase_return"]  # a file without new columns
    path.write_text(",".join(old) + "\n1000,60,0.5,0.25\n")
    table = MetricsTable(path)
    table.write({"update": 2000, "wall_time": 120, "episode_return": 0.75, "phase_return": 0.5,
                 "low_eps_return": 0.9})
    table.close()
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == old and rows[2] == ["2000", "120", "0.75", "0.5"]
