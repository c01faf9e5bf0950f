"""Does the symmetric loss make the humanoid use both arms and legs? Measured on the final policies of report 000.

    python benchmarks/reports/000-humanoidstandup-halfcheetah-ppo-rpo-sym/limbs.py

The report's reason for the loss is a humanoid that stands up with one arm or leg, and its evidence is videos. This
plays each HumanoidStandup run's final checkpoint for 5 deterministic episodes (canter's evaluation protocol and
env, EnvPool's v4), records the clipped actions, and scores each mirror pair of the preset's `sym.groups` (legs 3:7
against 7:11, arms 11:14 against 14:17) two ways: `effort_asymmetry`, |L - R| / (L + R) of the two sides' mean
squared torques (0 for even use, 1 for one side only), and `mirror_mismatch`, how far the sides are from moving as
mirror images (0 mirrored, 1 independent, 2 opposite), which is what the loss pulls towards.

Checkpoints are not archived (only the seed-0 runs of 2026-11-23 keep theirs), so a run is measured on the machine
that trained it; runs/limbs.json keeps every measurement, and run.py --write draws its table.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

PAGE = Path(__file__).resolve().parent
sys.path.insert(0, str(PAGE.parents[1]))  # archive.py
sys.path.insert(0, str(PAGE.parent))  # grids.py
from archive import ROOT  # noqa: E402
from grids import Grid, finished  # noqa: E402

from canter.algos.ppo.symmetry import MirrorPair, check_action_range, parse_groups  # noqa: E402
from canter.errors import CanterError  # noqa: E402
from canter.orchestrate.run_status import read_json  # noqa: E402

if TYPE_CHECKING:
    from canter.use.policy import Policy

EPISODES = 5
LIMBS = parse_groups("3:7=7:11,11:14=14:17", negate=(14, 15))  # the preset's groups: legs, arms
ARCHIVE = PAGE / "runs" / "limbs.json"
SEED0 = ROOT / "benchmarks" / "results" / "humanoidstandup-5m" / "run-folders"
SEED0_STEPS = 5_000_000
WORK = ROOT / "runs" / "report000"


@dataclass(frozen=True)
class GridRun:
    """One seed of one cell of a page grid, which `canter bench` trained in WORK / grid."""

    grid: str
    values: tuple[tuple[str, str], ...] = ()  # the cell's grid values, as Cell.values gives them


# label, seed, where the run is (a folder of seed-0 runs holding one run folder, or a page grid's cell), in the
# order of the table
RUNS: tuple[tuple[str, int, Path | GridRun], ...] = (
    ("ppo", 0, SEED0 / "ppo"),
    ("rpo", 0, SEED0 / "rpo"),
    ("rpo + sym 0.02", 0, SEED0 / "rposym"),
    ("ppo, ent_coef 0", 100, GridRun("hs-ent", (("ppo.ent_coef", "0.0"),))),
    ("ppo, ent_coef 0.01", 100, GridRun("hs-ent", (("ppo.ent_coef", "0.01"),))),
    ("rpo + sym 0", 100, GridRun("hs-sym", (("sym.coef", "0.0"),))),
    ("rpo + sym 0.01", 100, GridRun("hs-sym", (("sym.coef", "0.01"),))),
    ("rpo + sym 0.02", 100, GridRun("hs-rpo-sym")),
    ("rpo + sym 0.02", 101, GridRun("hs-rpo-sym")),
    ("rpo + sym 0.02", 102, GridRun("hs-rpo-sym")),
    ("rpo + sym 0.05", 100, GridRun("hs-sym", (("sym.coef", "0.05"),))),
)


def run_folder(where: Path | GridRun, seed: int, grids: Mapping[str, Grid]) -> Path | None:
    """The finished run folder that `where` names for `seed`, or None where it has not finished (or is not here)."""
    if isinstance(where, Path):
        folders = sorted(f for f in where.iterdir() if f.is_dir()) if where.is_dir() else []
        # These predate the archive's eval.json, so their summary alone says they ran the whole budget.
        summary = read_json(folders[0] / "summary.json") if len(folders) == 1 else None
        return folders[0] if summary and summary.get("global_step", 0) >= SEED0_STEPS else None
    grid = grids[where.grid]
    (cell,) = [c for c in grid.cells() if c.values == where.values]
    folder = cell.run_dir(WORK / grid.name, seed)
    return folder if finished(folder, grid.total_steps) else None


def effort_asymmetry(actions: np.ndarray, pairs: tuple[MirrorPair, ...]) -> tuple[float, ...]:
    """How unevenly a trajectory's actions [T, act_dim] load each mirror pair: |L - R| / (L + R) per pair, where L
    and R are the mean squared actions of the pair's two groups. 0 is even use, 1 is one side only (0 when both sides
    are still). A behaviour measure, not the loss: it asks whether a humanoid uses both arms or legs."""
    values = _trajectory(actions, pairs, "effort_asymmetry")
    result = []
    for pair in pairs:
        first = float(np.mean(np.square(values[:, list(pair.first)])))
        mirror = float(np.mean(np.square(values[:, list(pair.mirror)])))
        total = first + mirror
        result.append(abs(first - mirror) / total if total > 0 else 0.0)
    return tuple(result)


def mirror_mismatch(actions: np.ndarray, pairs: tuple[MirrorPair, ...]) -> tuple[float, ...]:
    """How far each mirror pair's two sides are from moving as mirror images over a trajectory [T, act_dim]:
    E|L - sR|^2 / (E|L|^2 + E|R|^2) per pair, with the signs `s` of `sym.negate`. 0 is mirrored motion, 1 is sides
    that move independently (uncorrelated), 2 is opposite motion (0 when both sides are still)."""
    values = _trajectory(actions, pairs, "mirror_mismatch")
    result = []
    for pair in pairs:
        first, mirror = values[:, list(pair.first)], values[:, list(pair.mirror)] * np.asarray(pair.signs)
        total = float(np.mean(np.sum(np.square(first), -1)) + np.mean(np.sum(np.square(mirror), -1)))
        gap = float(np.mean(np.sum(np.square(first - mirror), -1)))
        result.append(gap / total if total > 0 else 0.0)
    return tuple(result)


def _trajectory(actions: np.ndarray, pairs: tuple[MirrorPair, ...], name: str) -> np.ndarray:
    values = np.asarray(actions, np.float64)
    if values.ndim != 2:
        raise CanterError(f"{name} needs actions shaped [steps, act_dim], got shape {values.shape}")
    check_action_range(pairs, values.shape[1], name)
    return values


def measure(policy: Policy, episodes: int = EPISODES) -> dict[str, Any]:
    """Play `episodes` deterministic episodes with canter's evaluation protocol, recording the clipped actions."""
    recorded: list[np.ndarray] = []

    def act(obs: np.ndarray) -> np.ndarray:
        actions = policy(obs, deterministic=True)
        recorded.append(actions)
        return actions

    # As `canter eval` does, without the one-program path, which never hands the actions back.
    from canter.core.seeding import EVAL, HELD_OUT
    from canter.training.evaluation import run_episodes
    from canter.use.evaluate import seed_stream

    purpose = HELD_OUT if seed_stream(policy) == "held-out" else EVAL
    sizes = (policy.obs_dim, policy.act_dim)
    result = run_episodes(act, policy.facts.env_id, policy.facts.backend, episodes, 0, purpose, sizes)
    actions = np.concatenate(recorded)
    if len(actions) != int(np.sum(result.lengths)):
        # Every HumanoidStandup episode lasts 1000 steps, so each env plays one episode and no step is extra.
        raise SystemExit(f"recorded {len(actions)} actions for {int(np.sum(result.lengths))} episode steps")
    (legs, arms), (legs_mirror, arms_mirror) = effort_asymmetry(actions, LIMBS), mirror_mismatch(actions, LIMBS)
    return {
        "episodes": episodes,
        "return_mean": round(float(np.mean(result.returns)), 1),
        "effort_asymmetry": {"legs": round(legs, 4), "arms": round(arms, 4)},
        "mirror_mismatch": {"legs": round(legs_mirror, 4), "arms": round(arms_mirror, 4)},
    }


def table() -> str:
    """The measurements of runs/limbs.json in the order of RUNS, one row per run (or a row saying it is missing)."""
    archive = json.loads(ARCHIVE.read_text()) if ARCHIVE.is_file() else []
    found = {(entry["label"], entry["seed"]): entry for entry in archive}
    lines = [
        "| setting | seed | eval return (5 episodes) | effort asymmetry: legs | arms | mirror mismatch: legs | arms |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for text, seed, _ in RUNS:
        entry = found.get((text, seed))
        if entry is None:
            lines.append(f"| {text} | {seed} | not measured yet | | | | |")
            continue
        effort, mirror = entry["effort_asymmetry"], entry["mirror_mismatch"]
        lines.append(
            f"| {text} | {seed} | {entry['return_mean']:,.0f} | {effort['legs']:.2f} | {effort['arms']:.2f} | "
            f"{mirror['legs']:.2f} | {mirror['arms']:.2f} |"
        )
    return "\n".join(lines)


def main(grids: Mapping[str, Grid]) -> int:
    from canter.use.policy import load

    archive = json.loads(ARCHIVE.read_text()) if ARCHIVE.is_file() else []
    done = {(entry["label"], entry["seed"]) for entry in archive}
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    for text, seed, where in RUNS:
        if (text, seed) in done:
            continue
        run = run_folder(where, seed, grids)
        if run is None:
            print(f"{text}, seed {seed}: no finished run ({where}); skipped", flush=True)
            continue
        policy = load(run, "last")
        step = json.loads((run / "summary.json").read_text())["global_step"]
        entry = {"label": text, "seed": seed, "run": run.name, "global_step": step, **measure(policy)}
        entry["commit"] = commit.stdout.strip()
        print(json.dumps(entry), flush=True)
        archive.append(entry)
        ARCHIVE.write_text(json.dumps(archive, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    from run import GRIDS  # the page's grids; run.py draws this file's table, so it is imported only here

    sys.exit(main(GRIDS))
