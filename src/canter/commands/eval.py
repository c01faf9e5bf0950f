"""`canter eval`: evaluate the newest checkpoint of run folders with frozen normalizer statistics."""

from __future__ import annotations

import argparse
import json

from canter.commands import add_common, write_output


def register(sub: argparse._SubParsersAction) -> None:
    e = sub.add_parser("eval", help="evaluate run folders", description="Evaluate the newest checkpoint of runs.")
    e.add_argument("runs", nargs="+", help="run folders")
    e.add_argument("--episodes", type=int, default=10)
    e.add_argument("--stochastic", action="store_true", help="sample actions instead of the mean")
    e.add_argument("--env", default=None, help="evaluate on another env with the same observation/action sizes")
    e.add_argument("--json", default=None, metavar="PATH", help="also write the results as JSON")
    add_common(e)
    e.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from canter.evaluate import evaluate
    from canter.policy import load

    rows = []
    for run_dir in args.runs:
        policy = load(run_dir)
        result = evaluate(policy, episodes=args.episodes, deterministic=not args.stochastic,
                          seed=args.seed if args.seed is not None else 0, env_id=args.env)
        rows.append({"run": str(run_dir), "env": args.env or policy.facts.env_id, "episodes": int(result.returns.size),
                     "deterministic": not args.stochastic, "return_mean": result.mean, "return_std": result.std,
                     "length_mean": float(result.lengths.mean()), "length_std": float(result.lengths.std()),
                     "eval_seconds": result.wall_seconds, "global_step": policy.facts.global_step,
                     "returns": [float(r) for r in result.returns]})
    print(f"{'run':<60} {'steps':>10} {'return':>20} {'length':>16} {'time':>7}")
    for r in rows:
        name = r["run"] if len(r["run"]) <= 60 else "..." + r["run"][-57:]
        print(f"{name:<60} {r['global_step']:>10,} {r['return_mean']:>11.1f} ± {r['return_std']:<7.1f}"
              f" {r['length_mean']:>7.1f} ± {r['length_std']:<6.1f} {r['eval_seconds']:>6.1f}s")
    if len(rows) > 1:
        means = np.array([r["return_mean"] for r in rows])
        print(f"{'all runs (mean of run means)':<60} {'':>10} {means.mean():>11.1f} ± {means.std():<7.1f}")
    if args.json:
        write_output(args.json, json.dumps(rows, indent=2).encode())
    return 0
