"""`canter eval`: evaluate a checkpoint of run folders (the newest, the best, or a file) with frozen normalizer
statistics, optionally across scaled physical parameters (`--vary`)."""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from typing import Any

from canter.cli.args import add_checkpoint_arg, check_distinct_runs, check_one_run_for_a_file, seed_arg, whole_arg
from canter.cli.export import check_output_path
from canter.errors import CanterError
from canter.files import check_writable, write_output


def register(sub: argparse._SubParsersAction) -> None:
    from canter.envs.registry import backend_choices, solver_backends

    e = sub.add_parser(
        "eval",
        help="evaluate run folders (and robustness sweeps with --vary)",
        description="Evaluate a checkpoint of runs (the newest by default). Runs that differ only in run.seed "
        "are also summarised as a group. A best checkpoint plays held-out env seeds, which the evaluations that "
        "chose it never played.",
    )
    e.add_argument("runs", nargs="+", help="run folders")
    add_checkpoint_arg(e)
    e.add_argument("--episodes", type=whole_arg, default=10, help="episodes per run (and per --vary value; default 10)")
    e.add_argument("--stochastic", action="store_true", help="sample actions instead of the mean")
    e.add_argument("--env", default=None, help="evaluate on another env with the same observation/action sizes")
    e.add_argument(
        "--backend",
        choices=backend_choices(),
        default=None,
        help="env backend (default: the run's own for its env, else auto)",
    )
    e.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="env.KEY=VALUE",
        help=f"physics of the eval envs on {' and '.join(solver_backends())}: env.solver_iterations, "
        "env.solver_ls_iterations or env.contacts (default: the run's own)",
    )
    e.add_argument("--json", default=None, metavar="PATH", help="also write the results as JSON")
    e.add_argument(
        "--vary",
        default=None,
        action="append",
        metavar="PARAM[:NAME]=S1,S2,...",
        help="robustness sweep on the Gymnasium env: scale body_mass:BODY, geom_friction:GEOM, "
        "actuator_gear:ACTUATOR (omit :NAME for all) or gravity, e.g. body_mass:torso=0.5,1,1.5",
    )
    e.add_argument(
        "--out",
        default=None,
        metavar="PATH.png",
        help="--vary plot (JSON beside it); default RUN/robustness/<param>_<name>.png (<param>.png without a name; "
        "<env>_<param>... with an --env other than the run's) in each run",
    )
    e.add_argument("--seed", type=seed_arg, default=0, help="seed of the evaluation envs (default 0)")
    e.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from canter.config.overrides import parse_set_args
    from canter.envs.registry import AUTO, single_env_backend
    from canter.use.evaluate import check_eval_ends, check_eval_env, eval_physics, eval_target, parse_physics
    from canter.use.policy import load

    if args.episodes < 1:
        raise CanterError(f"--episodes must be >= 1, got {args.episodes}")
    if args.env == "":  # it would read as not given
        raise CanterError("--env is empty; give an env id, or drop --env for the run's own")
    if args.vary is None and args.out is not None:
        raise CanterError("--out names the --vary plot; without --vary use --json")
    if args.json is not None:
        check_output_path(args.json, "--json", "results.json")
        check_writable(args.json)
    spec = None
    if args.vary is not None:
        from canter.use.vary import parse_spec

        if len(args.vary) > 1:
            # One sweep per command: argparse would let a second --vary silently replace the first.
            raise CanterError(
                f"--vary is given {len(args.vary)} times; sweep one parameter per command "
                f"(run canter eval once per --vary)"
            )
        spec = parse_spec(args.vary[0])
        if args.out is not None:
            check_output_path(args.out, "--out", "robustness.png")
        if args.out is not None and Path(args.out).suffix.lower() != ".png":
            raise CanterError(f"--out {args.out}: the robustness plot is a PNG; name it *.png")
    physics = parse_physics(parse_set_args(args.set, flag="--set"))
    if physics and spec is not None:
        raise CanterError("--vary sweeps the Gymnasium env, which takes no --set; run the sweep and --set apart")
    if spec is not None and args.backend not in (None, AUTO, single_env_backend().name):
        raise CanterError(
            f"--vary sweeps the {single_env_backend().label} env, whose MuJoCo model it edits; drop --backend "
            f"{args.backend}"
        )
    check_distinct_runs(args.runs)
    check_one_run_for_a_file(args.checkpoint, args.runs)
    plays_on = single_env_backend().name if spec is not None else args.backend
    policies = [load(run_dir, args.checkpoint, plays_on) for run_dir in args.runs]
    for policy in policies:  # before any sweep is set up or any env is built
        check_eval_env(policy.facts, args.env, args.backend, varied=spec is not None)
        check_eval_ends(policy, args.env, args.backend if spec is None else single_env_backend().name)
        if physics:
            eval_physics(policy, *eval_target(policy, args.env, args.backend), physics)
    if spec is not None:
        return _vary(args, spec, policies, args.seed)
    return _evaluate(args, policies, args.seed, physics)


def _evaluate(args: argparse.Namespace, policies: list, seed: int, physics: dict[str, Any]) -> int:
    from canter.config.experiment import group_by_experiment, repeated_seed_note
    from canter.use.evaluate import evaluate, seed_stream

    rows = []
    failed: list[tuple[Any, CanterError]] = []
    for policy in policies:
        try:
            result = evaluate(
                policy,
                episodes=args.episodes,
                deterministic=not args.stochastic,
                seed=seed,
                env_id=args.env,
                backend=args.backend,
                physics=physics,
            )
        except CanterError as exc:  # the other runs' evaluations are kept, and this one named at the end
            failed.append((policy, exc))
            continue
        rows.append(
            dict(
                run=str(policy.source),
                env=args.env or policy.facts.env_id,
                algo=policy.config.run.algo,
                seed=policy.config.run.seed,
                deterministic=not args.stochastic,
                checkpoint=policy.checkpoint,
                seed_stream=seed_stream(policy),
                eval_seed=seed,
                global_step=policy.facts.global_step,
                total_steps=policy.config.run.total_steps,
                **result.summary(),
            )
        )
    evaluated = [p for p in policies if all(p is not f for f, _ in failed)]
    note = repeated_seed_note([p.config for p in evaluated], [str(p.source) for p in evaluated])
    if note is not None:
        print(f"canter: note: {note}", file=sys.stderr)
    groups = [
        _group_row(rows, members) for members in group_by_experiment([p.config for p in evaluated]) if len(members) > 1
    ]
    # The file before the table: a closed stdout (`| head -1`) ends the command at the table.
    if args.json and rows:
        write_output(args.json, json.dumps({"runs": rows, "groups": groups}, indent=2).encode())
    if rows:
        _print_table(rows, groups)
    if failed:
        first, reason = failed[0]
        kept = (f"; the other {len(rows)} are above" + (f" and in {args.json}" if args.json else "")) if rows else ""
        raise CanterError(
            f"{len(failed)} of {len(policies)} runs could not be evaluated ({first.source}: {reason}){kept}"
        )
    return 0


def _group_row(rows: list[dict[str, Any]], members: list[int]) -> dict[str, Any]:
    """Across-seed summary: mean ± std of the run means (the spread that matters when comparing configs)."""
    import numpy as np

    chosen = [rows[i] for i in members]
    means = np.array([r["return_mean"] for r in chosen])
    lengths = np.array([r["length_mean"] for r in chosen])
    first = chosen[0]
    return {
        "label": (
            f"{first['env']} {first['algo']}, budget {first['total_steps']:,}, "
            f"seeds {','.join(str(r['seed']) for r in chosen)}"
        ),
        "runs": [r["run"] for r in chosen],
        "checkpoint": first["checkpoint"],
        "seeds": [r["seed"] for r in chosen],
        "return_mean": float(means.mean()),
        "return_std": float(means.std()),
        "length_mean": float(lengths.mean()),
        "length_std": float(lengths.std()),
        "eval_seconds": float(sum(r["eval_seconds"] for r in chosen)),
        "episodes": int(sum(r["episodes"] for r in chosen)),
    }


def _short(text: str, width: int) -> str:
    return text if len(text) <= width else "..." + text[-(width - 3) :]


def _checkpoint_label(checkpoint: str) -> str:
    # checkpoint imports JAX, which parsing must not; here the policies have loaded it already.
    from canter.training.checkpoint import BEST, LAST

    return checkpoint if checkpoint in (LAST, BEST) else "file"


def _print_table(rows: list[dict[str, Any]], groups: list[dict[str, Any]]) -> None:
    print(f"{'run':<56} {'ckpt':<4} {'steps':>10} {'return (mean ± std)':>21} {'length':>15} {'time':>7}")
    for r in rows:
        print(
            f"{_short(r['run'], 56):<56} {_checkpoint_label(r['checkpoint']):<4} {r['global_step']:>10,} "
            f"{r['return_mean']:>11.1f} ± {r['return_std']:<7.1f}"
            f" {r['length_mean']:>6.1f} ± {r['length_std']:<6.1f} {r['eval_seconds']:>6.1f}s"
        )
    for g in groups:
        print(
            f"{_short('group: ' + g['label'], 56):<56} {_checkpoint_label(g['checkpoint']):<4} {'':>10} "
            f"{g['return_mean']:>11.1f} ± {g['return_std']:<7.1f}"
            f" {g['length_mean']:>6.1f} ± {g['length_std']:<6.1f} {g['eval_seconds']:>6.1f}s"
        )
    if groups:
        print("group rows: mean ± std across the runs' mean returns and lengths")
    _print_physics(rows)
    if any(r["seed_stream"] == "held-out" for r in rows):
        print("best checkpoints played held-out env seeds, apart from the evaluations that chose them")


def _physics_text(physics: dict[str, Any]) -> str:
    return ", ".join(f"env.{key}={value}" for key, value in physics.items())


def _print_physics(rows: list[dict[str, Any]]) -> None:
    """Which rows played other physics than their model's own (a run's solver settings on mjx, or --set)."""
    changed = [r for r in rows if r["physics"]]
    texts = {_physics_text(r["physics"]) for r in changed}
    if len(changed) == len(rows) and len(texts) == 1:
        print(f"physics: {texts.pop()}; the rest the model's own")
        return
    for r in changed:
        print(f"physics of {_short(r['run'], 56)}: {_physics_text(r['physics'])}; the rest the model's own")


def _labels(policies: list) -> list[str]:
    """Short plot labels (algo, preset, seed), falling back to the folder name where two would collide."""
    labels = [f"{p.config.run.algo}/{p.config.run.preset} s{p.config.run.seed}" for p in policies]
    return [label if labels.count(label) == 1 else p.source.name for label, p in zip(labels, policies)]


def _sweep_plot(policy: Any, spec: Any, env_id: str) -> Path:
    """RUN/robustness/<sweep>.png; a sweep on another env than the run's own (--env) is named after that env too, so
    that it does not replace the sweep of the run's own env."""
    other = "" if env_id == policy.facts.env_id else re.sub(r"[^A-Za-z0-9_.-]+", "-", env_id) + "_"
    return policy.source / "robustness" / f"{other}{spec.slug}.png"


def _vary(args: argparse.Namespace, spec: Any, policies: list, seed: int) -> int:
    from canter.use.vary import check_spec, is_unstable, plot, sweep

    env_ids = {args.env or p.facts.env_id for p in policies}
    if len(env_ids) > 1:
        raise CanterError(f"--vary compares runs on one env, got {', '.join(sorted(env_ids))}; pass --env")
    env_id = env_ids.pop()
    original = check_spec(env_id, spec)  # bad names fail here, before any evaluation
    outputs = [Path(args.out)] if args.out else [_sweep_plot(p, spec, env_id) for p in policies]
    for path in outputs:
        check_output_path(str(path), "--out", "robustness.png")
        check_writable(path)
        check_writable(path.with_suffix(".json"))
    series = []
    print(
        f"{env_id}: {spec.text} ({args.episodes} episodes per value, "
        f"{'stochastic' if args.stochastic else 'deterministic'})"
    )
    print(f"{'run':<40} {'scale':>6} {'return (mean ± std)':>21} {'length':>15} {'time':>7}")
    for policy, label in zip(policies, _labels(policies)):
        points = sweep(policy, spec, args.episodes, not args.stochastic, seed, env_id)
        series.append((label, points))
        for p in points:
            if is_unstable(p):
                print(
                    f"{_short(label, 40):<40} {p['scale']:>6.3g} unstable: MuJoCo warned of diverged physics "
                    f"{p['unstable_warnings']} times, so these episodes have no meaningful return"
                )
                continue
            print(
                f"{_short(label, 40):<40} {p['scale']:>6.3g} {p['return_mean']:>11.1f} ± {p['return_std']:<7.1f}"
                f" {p['length_mean']:>6.1f} ± {p['length_std']:<6.1f} {p['eval_seconds']:>6.1f}s"
            )
    report = {
        "env": env_id,
        "vary": spec.text,
        "param": spec.param,
        "name": spec.name,
        "original": original.tolist(),
        "episodes": args.episodes,
        "deterministic": not args.stochastic,
        "seed": seed,
        "runs": [
            {
                "run": str(p.source),
                "label": label,
                "checkpoint": p.checkpoint,
                "global_step": p.facts.global_step,
                "points": points,
            }
            for p, (label, points) in zip(policies, series)
        ],
    }
    data = json.dumps(report, indent=2).encode()
    image = plot(series, spec, original, env_id)
    for path in outputs:
        write_output(path.with_suffix(".json"), data)
        write_output(path, image)
        print(f"wrote {path} and {path.with_suffix('.json')}")
    if args.json:
        write_output(args.json, data)
    return 0
