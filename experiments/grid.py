"""Grids: named configurations x seeds, at a scale, expanded into concrete runs.

A grid file (``experiments/grids/<name>.py``) is data: module-level constants, no logic.

``TITLE``      one line naming the experiment.
``CONFIGS``    ``{name: {Config field: value}}``, the configurations compared, in plot order.
``BASE``       overrides every configuration shares (optional).
``SCALES``     ``{"paper" | "quick" | "smoke" | "cpu": {...}}`` (cpu optional) with keys
               (all optional):
               ``base`` overrides for every configuration at this scale, ``override``
               ``{name: {...}}`` per configuration, ``configs`` the names run at this scale
               (default all), ``seeds`` the default number of seeds, ``note`` a sentence for the
               report (what the scale reduces).
``METRIC``     the column compared and plotted (default ``episode_return``).
``FINDING``    what the study found, in words.
``CLAIMS``     ``[(text, summary column, config a, op, config b)]``, op one of ``>``, ``<``,
               ``~`` (within 0.1): the finding as checks of this run's summary.
``EXTRA_PLOTS`` metric columns plotted against updates besides the standard set.

Precedence (later wins): the preset (``base`` may name one) < ``BASE`` < scale ``base`` <
``CONFIGS[name]`` < scale ``override[name]`` < seed and run folder.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import pkgutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dqn_mine.config import PRESETS, Config, ConfigError, to_argv

SCALES = ("paper", "quick", "smoke", "cpu")
# Scales a grid may leave out (``paper`` falls back to the defaults; every grid has quick and
# smoke): cpu runs the study's own tasks at full size within a few hours on 2 CPU cores, which
# only some experiments can.
OPTIONAL_SCALES = ("cpu",)
OPS = (">", "<", "~")
CLOSE = 0.1  # what "~" tolerates: the study's "the same" at returns in [0, 1]


@dataclass(frozen=True)
class Claim:
    """One checkable sentence of the study's finding."""

    text: str
    column: str  # a summary.csv column, e.g. final_episode_return_mean
    a: str
    op: str
    b: str


@dataclass(frozen=True)
class RunSpec:
    """One run of a sweep: a configuration at one seed, with its folder."""

    config_name: str
    seed: int
    cfg: Config

    @property
    def run_dir(self) -> Path:
        return Path(self.cfg.run_dir)

    @property
    def label(self) -> str:
        return f"{self.config_name}/seed{self.seed}"

    def argv(self) -> list[str]:
        """Flags of ``python -m dqn_mine.train`` for a fresh start."""
        return to_argv(self.cfg)

    def processes(self) -> int:
        """Busy processes while it runs: actors, the evaluation actor, the learner."""
        return self.cfg.acting_processes + 1


@dataclass(frozen=True)
class Grid:
    """An experiment: see the module docstring for the fields of a grid file."""

    name: str
    title: str
    configs: dict[str, dict[str, Any]]
    base: dict[str, Any]
    scales: dict[str, dict[str, Any]]
    metric: str = "episode_return"
    finding: str = ""
    claims: tuple[Claim, ...] = ()
    extra_plots: tuple[str, ...] = ()

    def scale(self, scale: str) -> dict[str, Any]:
        if scale not in SCALES:
            raise ConfigError(f"unknown scale {scale!r} (choose from {', '.join(SCALES)})")
        if not self.has_scale(scale):
            raise ConfigError(f"grid {self.name} has no {scale} scale (it has: "
                              f"{', '.join(s for s in SCALES if self.has_scale(s))})")
        return self.scales.get(scale, {})

    def has_scale(self, scale: str) -> bool:
        return scale not in OPTIONAL_SCALES or scale in self.scales

    def config_names(self, scale: str) -> list[str]:
        return list(self.scale(scale).get("configs", self.configs))

    def default_seeds(self, scale: str) -> int:
        return int(self.scale(scale).get("seeds", 1))

    def overrides(self, name: str, scale: str) -> dict[str, Any]:
        """The Config fields of configuration ``name`` at ``scale`` (precedence as documented)."""
        s = self.scale(scale)
        return {**self.base, **s.get("base", {}), **self.configs[name],
                **s.get("override", {}).get(name, {})}

    def config(self, name: str, scale: str, seed: int, run_dir: Path) -> Config:
        values = self.overrides(name, scale)
        preset = values.pop("preset", "paper")
        if preset not in PRESETS:
            raise ConfigError(f"grid {self.name}: unknown preset {preset!r}")
        try:
            cfg = Config(**{**PRESETS[preset], "preset": preset, **values})
        except TypeError as exc:
            raise ConfigError(f"grid {self.name}, {name}: {exc}") from None
        cfg = dataclasses.replace(cfg, seed=seed, run_dir=str(run_dir))
        try:
            return cfg.validate()
        except ConfigError as exc:
            raise ConfigError(f"grid {self.name}, {name} at scale {scale}: {exc}") from None

    def expand(self, scale: str, out: Path, seeds: Sequence[int] | None = None) -> list[RunSpec]:
        """Every run, configuration-major: ``OUT/<config>/seed<k>``."""
        seeds = list(range(self.default_seeds(scale))) if seeds is None else list(seeds)
        return [RunSpec(name, s, self.config(name, scale, s, Path(out) / name / f"seed{s}"))
                for name in self.config_names(scale) for s in seeds]


def grid_names() -> list[str]:
    from experiments import grids

    return sorted(m.name for m in pkgutil.iter_modules(grids.__path__) if not m.ispkg)


def load_grid(name: str) -> Grid:
    """The grid file ``experiments/grids/<name>.py``, or a grid file at a path ending in
    ``.py``, as a :class:`Grid` (checked)."""
    if name.endswith(".py"):
        mod = _module_from_path(Path(name))
        name = Path(name).stem
    elif name in grid_names():
        mod = importlib.import_module(f"experiments.grids.{name}")
    else:
        raise ConfigError(f"unknown grid {name!r} (choose from {', '.join(grid_names())}, "
                          "or give a path to a grid file)")
    if not isinstance(getattr(mod, "CONFIGS", None), dict) or not mod.CONFIGS:
        raise ConfigError(f"grid {name}: CONFIGS must be a non-empty dict of name -> overrides")
    grid = Grid(name=name, title=getattr(mod, "TITLE", name), configs=dict(mod.CONFIGS),
                base=dict(getattr(mod, "BASE", {})), scales=dict(getattr(mod, "SCALES", {})),
                metric=getattr(mod, "METRIC", "episode_return"),
                finding=getattr(mod, "FINDING", ""),
                claims=tuple(Claim(*c) for c in getattr(mod, "CLAIMS", ())),
                extra_plots=tuple(getattr(mod, "EXTRA_PLOTS", ())))
    check_grid(grid)
    return grid


def _module_from_path(path: Path):
    if not path.is_file():
        raise ConfigError(f"no grid file at {path}")
    spec = importlib.util.spec_from_file_location(f"_grid_{path.stem}", path)
    mod = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(mod)
    except Exception as exc:
        raise ConfigError(f"grid file {path}: {type(exc).__name__}: {exc}") from None
    return mod


def check_grid(grid: Grid) -> None:
    """Names that must exist do: scales, configurations named by scales and claims, ops."""
    for scale, s in grid.scales.items():
        if scale not in SCALES:
            raise ConfigError(f"grid {grid.name}: unknown scale {scale!r}")
        for name in [*s.get("configs", ()), *s.get("override", {})]:
            if name not in grid.configs:
                raise ConfigError(f"grid {grid.name}, scale {scale}: unknown config {name!r}")
    for c in grid.claims:
        if c.op not in OPS or c.a not in grid.configs or c.b not in grid.configs:
            raise ConfigError(f"grid {grid.name}: bad claim {c}")
