"""`canter bench`: run a grid of algorithms x envs x hyperparameters x seeds and tabulate it."""

from __future__ import annotations

import argparse

from canter.cli.args import (
    add_backend_arg,
    add_track_args,
    check_storage_arg,
    comma_entries,
    seeds_arg,
    sets_with_backend,
    steps_arg,
    track_spec,
    whole_arg,
)


def _names(text: str) -> tuple[str, ...]:
    names = tuple(name for name in comma_entries(text) if name)
    if not names:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {text!r}")
    if len(set(names)) != len(names):  # a repeat would be a second cell counting the same runs again
        raise argparse.ArgumentTypeError(f"each name may appear once, got {text!r}")
    return names


def register(sub: argparse._SubParsersAction) -> None:
    from canter.config.presets import preset_names

    b = sub.add_parser(
        "bench",
        help="run a benchmark grid; writes results.md/.csv and plots",
        description="Run every (algo, env, grid values) cell for every seed, each seed a run folder "
        "under --out with a deterministic name; re-running skips finished runs and "
        "resumes interrupted ones. Writes results.md (with IQM, mean, median and optimality gap and their 95% "
        "bootstrap intervals), results.csv, statistics.json and plot_ENV.png.",
    )
    b.add_argument("--algos", type=_names, default=None, help="comma-separated algorithms (default ppo)")
    b.add_argument("--envs", type=_names, default=None, help="comma-separated env ids, e.g. Hopper-v5,Walker2d-v5")
    b.add_argument("--seeds", type=seeds_arg, default=(0, 1, 2, 3, 4), help="comma-separated seeds (default 0,1,2,3,4)")
    b.add_argument(
        "--total-steps", type=steps_arg, default=1_000_000, help="env steps per run (1e6 works; default 1e6)"
    )
    b.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="KEY=V1,V2,...",
        help="a hyperparameter axis, repeatable: ppo.ent_coef=0.01,1e-4,0 or net.hidden=64-64,128-64",
    )
    b.add_argument(
        "--jobs",
        type=whole_arg,
        default=1,
        help="jobs trained at once, one process each (a cell's seeds, or one td3/ddpg/sac seed; default 1)",
    )
    b.add_argument("--out", default="bench", help="bench folder (default bench/)")
    b.add_argument(
        "--preset",
        default=None,
        help=f"preset under the grid values: {', '.join(preset_names())} (default: the one a --config file's "
        "run.preset names, else fast)",
    )
    b.add_argument("--config", default=None, help="TOML file under the grid values")
    b.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="fixed override")
    add_backend_arg(b)
    b.add_argument(
        "--episodes",
        type=whole_arg,
        default=10,
        help="deterministic episodes of each run's final evaluation, as in canter eval (default 10)",
    )
    # `--eval-episodes` means episodes per evaluation during training (train, tune), not bench's final evaluation,
    # so bench refuses it and names `--episodes`.
    b.add_argument("--eval-episodes", type=whole_arg, default=None, help=argparse.SUPPRESS)
    b.add_argument(
        "--storage",
        default=None,
        metavar="URL",
        help="share the grid through this Optuna storage (e.g. postgresql://user:pw@host/db)",
    )
    b.add_argument("--study", default=None, metavar="NAME", help="study name with --storage (default: --out name)")
    b.add_argument(
        "--heartbeat",
        type=whole_arg,
        default=None,
        metavar="SECONDS",
        help="with --storage: heartbeat interval (default 60)",
    )
    add_track_args(b, "one tracker run per seed, a cell's seeds in one group; a re-run continues those it resumes")
    b.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from canter.errors import CanterError
    from canter.orchestrate.bench import bench
    from canter.orchestrate.bench_grid import BenchSettings, parse_grid_arg

    if args.eval_episodes is not None:
        raise CanterError(
            f"bench sets the episodes of each run's final evaluation with --episodes (--eval-episodes is train's "
            f"and tune's count per evaluation during training); pass --episodes {args.eval_episodes}"
        )

    # Without a storage the bench runs on this machine alone, with no study to name and no trials to heartbeat: the
    # flags would do nothing, and a user who gave them most likely meant to share the grid.
    alone = [f"--{name}" for name in ("study", "heartbeat") if getattr(args, name) is not None]
    if alone and not args.storage:
        flags = " and ".join(alone)
        raise CanterError(
            f"{flags} {'go' if len(alone) > 1 else 'goes'} with --storage only (without it the bench runs on this "
            f"machine alone, with no study); add --storage URL to share the grid, or leave out {flags}"
        )
    check_storage_arg(args.storage, "the bench on this machine alone")

    grid = tuple(parse_grid_arg(g) for g in args.grid)
    grid_keys = {key for key, _ in grid}
    for key, flag in (("run.algo", "--algos"), ("env.id", "--envs"), ("env.backend", "--backend")):
        if key in grid_keys and getattr(args, flag[2:]) is not None:
            raise CanterError(f"give the {key} values either with {flag} or with --grid {key}=..., not both")
    if args.envs is None and "env.id" not in grid_keys:
        raise CanterError("no environments given; pass --envs Hopper-v5,Walker2d-v5")
    settings = BenchSettings(
        algos=args.algos or ("ppo",),
        envs=args.envs or (),
        seeds=args.seeds,
        total_steps=args.total_steps,
        grid=grid,
        jobs=args.jobs,
        out_dir=args.out,
        preset=args.preset,
        config_file=args.config,
        sets=sets_with_backend(args),
        eval_episodes=args.episodes,
        storage_url=args.storage,
        study_name=args.study,
        **({"heartbeat_seconds": args.heartbeat} if args.heartbeat is not None else {}),
        track=track_spec(args),
    )
    from canter.orchestrate.jobs import sigterm_interrupts

    with sigterm_interrupts():  # a scheduler's SIGTERM stops the jobs and records their trials, as Ctrl-C does
        bench(settings)
    return 0
