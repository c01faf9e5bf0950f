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
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

PAGE = Path(__file__).resolve().parent
sys.path.insert(0, str(PAGE.parents[1]))  # archive.py
from archive import ROOT  # noqa: E402

from canter.algos.ppo.symmetry import effort_asymmetry, mirror_mismatch, parse_groups  # noqa: E402

if TYPE_CHECKING:
    from canter.use.policy import Policy

EPISODES = 5
LIMBS = parse_groups("3:7=7:11,11:14=14:17", negate=(14, 15))  # the preset's groups: legs, arms
ARCHIVE = PAGE / "runs" / "limbs.json"
SEED0 = ROOT / "benchmarks" / "results" / "humanoidstandup-5m" / "run-folders"
WORK = ROOT / "runs" / "report000"
# label, seed, where the run folder is (the first match of the glob), in the order of the table
RUNS = (
    ("ppo", 0, SEED0 / "ppo"),
    ("rpo", 0, SEED0 / "rpo"),
    ("rpo + sym 0.02", 0, SEED0 / "rposym"),
    ("ppo, ent_coef 0", 100, WORK / "hs-ent" / "*ent_coef=0.0__s100"),
    ("ppo, ent_coef 0.01", 100, WORK / "hs-ent" / "*ent_coef=0.01__s100"),
    ("rpo + sym 0", 100, WORK / "hs-sym" / "*sym.coef=0.0__s100"),
    ("rpo + sym 0.01", 100, WORK / "hs-sym" / "*sym.coef=0.01__s100"),
    ("rpo + sym 0.02", 100, WORK / "hs-rpo-sym" / "*__s100"),
    ("rpo + sym 0.02", 101, WORK / "hs-rpo-sym" / "*__s101"),
    ("rpo + sym 0.02", 102, WORK / "hs-rpo-sym" / "*__s102"),
    ("rpo + sym 0.05", 100, WORK / "hs-sym" / "*sym.coef=0.05__s100"),
)


def find_run(pattern: Path) -> Path | None:
    """The finished run folder that `pattern` names (a folder holding one run, or a glob), or None."""
    folders = sorted(pattern.parent.glob(pattern.name)) if "*" in pattern.name else [pattern]
    runs = [f for f in folders if f.is_dir()]
    runs = [r for f in runs for r in ([f] if (f / "summary.json").is_file() else f.iterdir()) if r.is_dir()]
    finished = [r for r in runs if (r / "summary.json").is_file() and _finished(r)]
    return finished[0] if finished else None


def _finished(run: Path) -> bool:
    summary = json.loads((run / "summary.json").read_text())
    return bool(summary.get("stop_reason") == "budget")


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


def main() -> int:
    from canter.use.policy import load

    archive = json.loads(ARCHIVE.read_text()) if ARCHIVE.is_file() else []
    done = {(entry["label"], entry["seed"]) for entry in archive}
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    for text, seed, pattern in RUNS:
        if (text, seed) in done:
            continue
        run = find_run(pattern)
        if run is None:
            print(f"{text}, seed {seed}: no finished run at {pattern}; skipped", flush=True)
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
    sys.exit(main())
