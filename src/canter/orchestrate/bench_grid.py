"""The grid of `canter bench`: its settings, its cells (one algorithm x env x grid values combination each, with
its validated config) and its jobs (the seeds of a cell that one child process trains)."""

from __future__ import annotations

import itertools
import sys
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from canter.config.algorithms import reads_key, unread_key_error
from canter.config.build import build_config
from canter.config.fields import OUTPUT, role_of
from canter.config.overrides import all_keys, unknown_key_error
from canter.config.schema import Config, field_types
from canter.config.values import coerce, is_tuple_field
from canter.errors import CanterError
from canter.orchestrate.env_check import check_continuous
from canter.orchestrate.study import check_at_least
from canter.training.trackers import TrackSpec

# Keys the bench sets itself, each from its own flag (run.algo and env.id as grid axes stand in for --algos and
# --envs).
_FORBIDDEN = {"run.seed": "--seeds", "run.total_steps": "--total-steps", "run.out_dir": "--out"}


@dataclass(frozen=True)
class BenchSettings:
    algos: tuple[str, ...]
    envs: tuple[str, ...]
    seeds: tuple[int, ...]
    total_steps: int
    grid: tuple[tuple[str, tuple[str, ...]], ...] = ()  # (key, raw values) in the order given
    jobs: int = 1
    out_dir: str = "bench"
    preset: str | None = None  # None: the one the config file's run.preset names, else fast
    config_file: str | None = None
    sets: tuple[str, ...] = ()
    eval_episodes: int = 10
    storage_url: str | None = None
    study_name: str | None = None
    heartbeat_seconds: int = 60
    poll_seconds: float = 0.5
    track: TrackSpec = field(default_factory=TrackSpec)  # `--track`: a tracker run per seed, a group per cell

    def __post_init__(self) -> None:
        check_at_least(
            [
                ("--jobs", self.jobs, 1),
                ("--episodes (eval_episodes)", self.eval_episodes, 1),
                ("--heartbeat (heartbeat_seconds)", self.heartbeat_seconds, 1),
            ]
        )
        if not self.out_dir:  # an empty path is the working folder, where the bench would scatter its files
            raise CanterError("--out is empty; give a folder for the bench, or drop --out")


@dataclass(frozen=True)
class Cell:
    algo: str
    env_id: str
    values: tuple[tuple[str, str], ...]  # every grid axis: (key, canonical value)
    config: Config

    @property
    def name(self) -> str:
        parts = [self.env_id.split(":")[-1], self.algo] + [f"{key}={value}" for key, value in self.values]
        return "__".join(safe_name(p) for p in parts)

    def run_dir(self, bench_dir: Path, seed: int) -> Path:
        return bench_dir / f"{self.name}__s{seed}"


@dataclass(frozen=True)
class Job:
    """The seeds of one cell that one child process trains together."""

    cell: Cell
    seeds: tuple[int, ...]
    apart: bool  # one seed of a cell whose seeds train apart: the seed is part of the name

    @property
    def name(self) -> str:
        return f"{self.cell.name}__s{self.seeds[0]}" if self.apart else self.cell.name


def make_jobs(cells: list[Cell], seeds: tuple[int, ...]) -> list[Job]:
    from canter.algos import seeds_train_apart

    jobs = []
    for cell in cells:
        if seeds_train_apart(cell.algo):
            jobs += [Job(cell, (seed,), True) for seed in seeds]
        else:
            jobs.append(Job(cell, tuple(seeds), False))
    return jobs


def safe_name(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_.=," else "-" for c in text)


def canonical(value: Any) -> str:
    """A grid value as it names its cell's run folders (`Cell.name`): `set_text`'s form, but a tuple's entries
    joined by dashes. Kept apart from `set_text` on purpose: archived benches and report pages find their run
    folders by these names, so they must not change when the --set text does."""
    if isinstance(value, tuple):
        return "-".join(map(str, value))
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "none"
    return repr(value) if isinstance(value, float) else str(value)


def parse_grid_arg(text: str) -> tuple[str, tuple[str, ...]]:
    key, sep, values = text.partition("=")
    key = key.strip()
    items = tuple(v.strip() for v in values.split(","))
    if not sep or not key or items == ("",):
        raise CanterError(f"--grid expects KEY=V1,V2,... such as ppo.ent_coef=0.01,1e-4,0; got {text!r}")
    if "" in items:  # a slip, as in --seeds: dropped, it would bench one value fewer than was typed
        raise CanterError(f"--grid {text!r} has an empty value; drop the stray comma or fill in the value")
    return key, items


def repeated_values_error(key: str, raw: tuple[str, ...], values: list[str], tuple_valued: bool) -> str:
    """The one-line refusal of a grid axis that names a value twice (`raw` as typed, `values` in `canonical` form).
    A tuple key's repeat is most often a tuple typed with commas, which the grid split into one value per entry, so
    that case shows the split and how tuples are written."""
    repeats = ", ".join(v for v in dict.fromkeys(values) if values.count(v) > 1)
    if not tuple_valued:
        return f"--grid {key} repeats {repeats}; give each value once"
    example = "16-16,32-32" if key.endswith("hidden") else "0-1,2-3"
    return (
        f"--grid {key} repeats {repeats}: {','.join(raw)} is {len(raw)} values, as values are separated by commas "
        f"and a tuple's entries by '-'; write tuples as --grid {key}={example}"
    )


def make_cells(settings: BenchSettings) -> list[Cell]:
    """Every cell, each with its validated config; refuses an unknown algo, env, key or value before any work."""
    from canter.algos import check_algorithm_name
    from canter.envs import resolve_backend

    algos, envs = list(settings.algos), list(settings.envs)
    axes: list[tuple[str, list[str]]] = []
    seen: set[str] = set()
    known = set(all_keys())
    for key, raw in settings.grid:
        if key in seen:
            raise CanterError(f"--grid {key} is given twice; list all its values in one --grid")
        seen.add(key)
        if key in _FORBIDDEN:
            raise CanterError(f"--grid {key} is not a grid axis; use {_FORBIDDEN[key]}")
        if key == "run.preset":  # it records the preset a config was built from; a cell's value would change nothing
            raise CanterError(
                "--grid run.preset is not a grid axis (a preset sets many keys); run one bench per --preset"
            )
        if key in ("run.algo", "env.id"):
            if len(set(raw)) != len(raw):  # as --algos and --envs refuse: two cells would share run folders
                raise CanterError(repeated_values_error(key, raw, list(raw), False))
            if key == "run.algo":
                algos = list(raw)
            else:
                envs = list(raw)
            continue
        if key not in known:
            raise unknown_key_error(key, "--grid")
        section, _, name = key.partition(".")
        tp = field_types(section)[name]
        values = [canonical(coerce(key, tp, v)) for v in raw]
        if len(set(values)) != len(values):
            raise CanterError(repeated_values_error(key, raw, values, is_tuple_field(tp)))
        axes.append((key, values))
    if not algos or not envs or not settings.seeds:
        raise CanterError("the bench needs at least one algorithm, one env and one seed")
    for algo in algos:
        check_algorithm_name(algo)
    for key, _ in axes:
        for algo in algos:
            if not reads_key(algo, key):
                raise CanterError(f"--grid {key}: {unread_key_error(algo, key)}, or bench {algo} in a bench of its own")
    # A --set applies to the cells whose algorithm reads it, so one bench can carry td3.* and sac.* settings.
    set_keys = {item.partition("=")[0].strip(): item for item in settings.sets}
    for key in set_keys:
        if key in _FORBIDDEN:  # the bench's own value would replace it
            raise CanterError(
                f"{key} is set by the bench's {_FORBIDDEN[key]}; give {_FORBIDDEN[key]} rather than --set {key}"
            )
        if key in known and algos and not any(reads_key(algo, key) for algo in algos):
            raise CanterError(f"--set {unread_key_error(algos[0], key)}")
        if key in seen:  # the grid's value would replace it in every cell
            raise CanterError(f"{key} is given by both --grid and --set; keep --grid {key}=... or --set {key}=...")
    cells = []
    for algo, env_id in itertools.product(algos, envs):
        for combo in itertools.product(*(values for _, values in axes)):
            pairs = tuple(zip((key for key, _ in axes), combo))
            sets = [item for key, item in set_keys.items() if key not in known or reads_key(algo, key)]
            sets += [f"{key}={value}" for key, value in pairs]
            try:
                config = build_config(
                    env_id,
                    preset=settings.preset,
                    config_file=settings.config_file,
                    sets=sets,
                    seed=settings.seeds[0],
                    total_steps=settings.total_steps,
                    algo=algo,
                )
            except CanterError as exc:
                where = ", ".join([algo, env_id] + [f"{k}={v}" for k, v in pairs])
                raise CanterError(f"cell ({where}): {exc}") from None
            cells.append(Cell(algo, env_id, pairs, config))
    _refuse_shared_names(cells)
    for env_id, backend in dict.fromkeys((cell.env_id, cell.config.env.backend) for cell in cells):
        resolve_backend(env_id, backend)  # on the backend the cell runs it on (--backend, --set or a --grid axis)
        check_continuous(env_id, backend)  # last: it makes an env
    for key in [key for key, _ in axes if _writes_only(key)]:
        print(
            f"canter: note: --grid {key} changes how the work is done or written, not what is learned: its cells "
            "learn the same numbers, so compare their speed, not their scores",
            file=sys.stderr,
        )
    return cells


def _refuse_shared_names(cells: list[Cell]) -> None:
    """Two cells whose names agree would train and evaluate the same run folders, and the bench's statistics would
    count each run twice. A folder name keeps only an env id's tail, so `pkg:Env-v0` and `Env-v0` are such a pair."""
    first: dict[str, Cell] = {}
    for cell in cells:
        other = first.setdefault(cell.name, cell)
        if other is not cell:
            raise CanterError(
                f"cells ({_describe(other)}) and ({_describe(cell)}) would share the run folders {cell.name}__s*; "
                "bench them in two benches with their own --out"
            )


def _describe(cell: Cell) -> str:
    return ", ".join([cell.env_id, cell.algo] + [f"{key}={value}" for key, value in cell.values])


def _writes_only(key: str) -> bool:
    """A key whose role is OUTPUT: where and how results are written or the work split up (such as
    env.envpool_shards, a fair speed axis), never the numbers."""
    section, _, name = key.partition(".")
    return any(f.name == name and role_of(f) == OUTPUT for f in fields(Config().section(section)))


def varying_keys(cells: list[Cell]) -> list[str]:
    """The grid keys whose value differs between cells: they label the table rows."""
    keys = [key for key, _ in cells[0].values] if cells else []
    return [k for i, k in enumerate(keys) if len({c.values[i][1] for c in cells}) > 1]
