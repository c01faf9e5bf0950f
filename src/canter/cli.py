"""The `canter` command. Every user error is one line on stderr with a non-zero exit and no traceback."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Sequence

from canter.errors import CanterError


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # argparse would print usage over several lines
        raise CanterError(f"{self.prog}: {message} (see --help)")


def _steps(text: str) -> int:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a step count such as 1000000 or 1e6, got {text!r}") from None
    if not value.is_integer() or value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole step count, got {text!r}")
    return int(value)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seed", type=int, default=None, help="run seed")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="canter", description="Fast, correct PPO for MuJoCo continuous control.")
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", parser_class=_Parser, metavar="COMMAND")

    t = sub.add_parser("train", help="train a policy; writes a run folder",
                       description="Train a policy. Precedence: defaults < --preset < --config < --set < flags.")
    t.add_argument("env", nargs="?", help="env id (Hopper-v5) or module:EnvId for a custom Gymnasium env")
    t.add_argument("--preset", default=None, help="preset overlay: fast (default) or cleanrl")
    t.add_argument("--config", default=None, help="TOML file with [section] key = value")
    t.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="override one key")
    t.add_argument("--total-steps", type=_steps, default=None, help="env steps (1e6 works)")
    t.add_argument("--backend", choices=("auto", "envpool", "gymnasium"), default=None)
    t.add_argument("--stop-at-return", type=float, default=None,
                   help="stop once the mean of the last 20 training episodes reaches this")
    t.add_argument("--max-minutes", type=float, default=None, help="stop cleanly, with a checkpoint, after M minutes")
    t.add_argument("--out-dir", default=None, help="folder for run folders (default runs/)")
    t.add_argument("--resume", default=None, metavar="RUN_DIR", help="continue a run from its newest checkpoint")
    _common(t)

    e = sub.add_parser("eval", help="evaluate run folders", description="Evaluate the newest checkpoint of runs.")
    e.add_argument("runs", nargs="+", help="run folders")
    e.add_argument("--episodes", type=int, default=10)
    e.add_argument("--stochastic", action="store_true", help="sample actions instead of the mean")
    e.add_argument("--env", default=None, help="evaluate on another env with the same observation/action sizes")
    e.add_argument("--json", default=None, metavar="PATH", help="also write the results as JSON")
    _common(e)
    return parser


def _version() -> str:
    from canter import __version__

    return f"canter {__version__}"


def cmd_train(args: argparse.Namespace) -> int:
    from canter.config import build_config
    from canter.trainer import resume_config, train

    if args.resume:
        changed = [flag for flag, value in (("env", args.env), ("--preset", args.preset), ("--config", args.config),
                                             ("--set", args.set), ("--seed", args.seed), ("--backend", args.backend),
                                             ("--stop-at-return", args.stop_at_return),
                                             ("--max-minutes", args.max_minutes), ("--out-dir", args.out_dir))
                   if value]
        if changed:
            raise CanterError(f"--resume uses the saved config; only --total-steps and --quiet may be given "
                              f"(got {', '.join(changed)})")
        config = resume_config(Path(args.resume), args.total_steps)
        result = train(config, resume=args.resume, quiet=args.quiet)
    else:
        extra = {}
        if args.backend:
            extra["env.backend"] = args.backend
        if args.stop_at_return is not None:
            extra["run.stop_at_return"] = args.stop_at_return
        if args.max_minutes is not None:
            extra["run.max_minutes"] = args.max_minutes
        if args.out_dir:
            extra["run.out_dir"] = args.out_dir
        sets = list(args.set) + [f"{k}={v}" for k, v in extra.items()]
        config = build_config(args.env, preset=args.preset or "fast", config_file=args.config, sets=sets,
                              seed=args.seed, total_steps=args.total_steps)
        result = train(config, quiet=args.quiet)
    recent = "n/a" if result.recent_return is None else f"{result.recent_return:.1f}"
    print(f"run: {result.run_dir}")
    print(f"steps {result.global_step:,} | {result.sps:,.0f} SPS (compile {result.compile_seconds:.1f} s apart) | "
          f"wall {result.wall_seconds:.1f} s | return (last 20 episodes) {recent} | stopped: {result.stop_reason}")
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    import numpy as np

    from canter.evaluate import evaluate
    from canter.policy import load

    rows = []
    for run in args.runs:
        policy = load(run)
        result = evaluate(policy, episodes=args.episodes, deterministic=not args.stochastic,
                          seed=args.seed if args.seed is not None else 0, env_id=args.env)
        rows.append({"run": str(run), "env": args.env or policy.facts.env_id, "episodes": int(result.returns.size),
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
        from canter.checkpoint import atomic_write_bytes

        try:
            atomic_write_bytes(Path(args.json), lambda f: f.write(json.dumps(rows, indent=2).encode()))
        except OSError as exc:
            raise CanterError(f"cannot write {args.json}: {exc.strerror or exc}; pick a writable path") from None
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return 2
        return {"train": cmd_train, "eval": cmd_eval}[args.command](args)
    except CanterError as exc:
        print(f"canter: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("canter: interrupted", file=sys.stderr)
        return 130


def entry() -> None:
    sys.exit(main())


if __name__ == "__main__":
    entry()
