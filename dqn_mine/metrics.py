"""The run folder's metrics table, rolling episode statistics and the live progress line."""

from __future__ import annotations

import csv
import math
import time
from collections import deque
from collections.abc import Iterable
from pathlib import Path

# What every run records; one row every `log_interval` updates (and at the end).
COLUMNS = (
    "update", "wall_time", "env_steps", "episodes", "episode_return", "episode_length",
    "eval_return", "eval_length", "updates_per_s", "env_steps_per_s", "replay_ratio",
    "sampled_reward", "loss", "td_abs", "mean_q", "phase", "beta", "replay_size",
    "phase_return",   # adaptive curriculum: the rolling mean that advances it (current phase only)
    "start_share",    # backward curriculum: the frontier's starts as a share of the solution
    "full_task_return",   # rolling mean return of the training episodes begun at the real start
    "full_task_episodes",   # how many such episodes this process has seen (fills that window)
    # The same two means over the episodes played at an exploration rate of at most LOW_EPSILON:
    # under the Ape-X rates they show what the near-greedy policy does, apart from the envs
    # that mostly explore.
    "low_eps_return", "phase_low_eps_return",
    "rewarded_episodes",   # training episodes with a reward so far (the pre-fill's included)
    "demo_share",     # --demos: the share of demonstrations in the sampled batches
    "margin_loss",    # --demos: the large-margin loss, mean over the sampled demonstrations
)
LOW_EPSILON = 0.01   # the study's rate: an env at or below it plays (almost) its greedy policy
RETURN_WINDOW = 100   # finished episodes in the rolling mean return and length


class MetricsTable:
    """Append-only CSV: a resumed run continues the same file under the same header.

    With ``tensorboard_dir`` every row also goes to TensorBoard event files there (one scalar per
    column against the update count, ``config`` as text); the CSV stays the source of truth.
    """

    def __init__(self, path: Path, tensorboard_dir: Path | None = None,
                 config_text: str = ""):
        self._tb = None
        if tensorboard_dir is not None:
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(log_dir=str(tensorboard_dir))
            if config_text:
                self._tb.add_text("config", config_text, 0)
        self.path = Path(path)
        fresh = not self.path.exists() or self.path.stat().st_size == 0
        # A resumed run keeps its file's own header (an older version may have fewer columns).
        columns = COLUMNS if fresh else _header(self.path)
        self._file = open(self.path, "a", newline="")
        self._writer = csv.DictWriter(self._file, fieldnames=columns, extrasaction="ignore")
        if fresh:
            self._writer.writeheader()
            self._file.flush()

    def write(self, row: dict[str, float]) -> None:
        self._writer.writerow({k: _fmt(row.get(k)) for k in self._writer.fieldnames})
        self._file.flush()
        if self._tb is not None:
            step = int(row.get("update", 0))
            for key in COLUMNS[1:]:
                value = row.get(key)
                if isinstance(value, (int, float)) and not math.isnan(value):
                    self._tb.add_scalar(key, value, step)
            self._tb.flush()

    def close(self) -> None:
        self._file.close()
        if self._tb is not None:
            self._tb.close()


def _fmt(value) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def _header(path: Path) -> list[str]:
    with open(path, newline="") as f:
        return next(csv.reader(f), list(COLUMNS))


def read_metrics(path: Path) -> list:
    """The table as a list of dicts of floats (empty cells become NaN)."""
    with open(path, newline="") as f:
        return [{k: (float(v) if v != "" else math.nan) for k, v in row.items()}
                for row in csv.DictReader(f)]


class Rolling:
    """Mean of the last ``window`` values (NaN while empty)."""

    def __init__(self, window: int):
        self.values: deque = deque(maxlen=window)

    def extend(self, values: Iterable[float]) -> None:
        self.values.extend(values)

    def clear(self) -> None:
        self.values.clear()

    @property
    def mean(self) -> float:
        return sum(self.values) / len(self.values) if self.values else math.nan

    def __len__(self) -> int:
        return len(self.values)


class RateMeter:
    """Rate of a growing counter between successive calls."""

    def __init__(self, start: int = 0):
        self.last_value = start
        self.last_time = time.perf_counter()

    def rate(self, value: int) -> float:
        now = time.perf_counter()
        dt = now - self.last_time
        r = (value - self.last_value) / dt if dt > 0 else math.nan
        self.last_value, self.last_time = value, now
        return r


def progress_line(row: dict[str, float], total_updates: int) -> str:
    """The training bar's figures as one line, for a log file."""
    return log_line("train", int(row["update"]), total_updates, row["wall_time"] / 60,
                    progress_postfix(row))


def log_line(label: str, done: int, total: int, minutes: float, figures: dict[str, str]) -> str:
    """A progress bar as one line, where stderr is a log file and no bar is drawn."""
    shown = " ".join(f"{k}={v}" for k, v in figures.items())
    return f"{label}: {done:,}/{total:,} updates, {minutes:.1f} min | {shown}"


def progress_postfix(row: dict[str, float]) -> dict[str, str]:
    """The few figures worth watching live in the tqdm bar."""
    keys = {"episode_return": "ret", "eval_return": "eval", "updates_per_s": "upd/s",
            "rewarded_episodes": "rewarded", "env_steps_per_s": "steps/s",
            "replay_ratio": "ratio", "loss": "loss", "phase": "phase",
            "phase_return": "phase_ret", "start_share": "share", "full_task_return": "full"}
    out = {}
    for key, short in keys.items():
        value: float | None = row.get(key)
        if value is None or (isinstance(value, float) and math.isnan(value)):
            continue
        if key == "phase" and not value:  # 0 = no curriculum: nothing to watch
            continue
        out[short] = str(value) if isinstance(value, int) else f"{value:.3g}"
    return out
