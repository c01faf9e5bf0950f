"""`canter tune`: Optuna hyperparameter search (TPE + median pruner) on one machine or many."""

from __future__ import annotations

import argparse

from canter.cli.args import (
    add_backend_arg,
    add_track_args,
    check_storage_arg,
    seed_arg,
    sets_with_backend,
    steps_arg,
    track_spec,
    whole_arg,
)
from canter.core.seeding import SEED_LIMIT
from canter.errors import CanterError


def register(sub: argparse._SubParsersAction) -> None:
    from canter.config.presets import preset_names

    t = sub.add_parser(
        "tune",
        help="tune hyperparameters with Optuna",
        description="Optuna search (TPE sampler, median pruner on intermediate deterministic "
        "evaluations). The study lives in OUT_DIR/STUDY (SQLite) unless --storage is "
        "given; with a shared --storage and --study, run the same command on any number "
        "of machines. Writes best.toml (for canter train --config) and summary.md.",
    )
    t.add_argument("env", nargs="?", help="env id, e.g. Hopper-v5")
    t.add_argument("--algo", default="ppo", help="algorithm to tune (default ppo)")
    t.add_argument(
        "--trials",
        type=whole_arg,
        default=50,
        help="finished (complete + pruned) trials of the whole study (default 50)",
    )
    t.add_argument("--jobs", type=whole_arg, default=1, help="parallel worker processes on this machine (default 1)")
    t.add_argument(
        "--total-steps",
        type=steps_arg,
        default=1_000_000,
        help="env steps per trial (default 1e6: the defaults train 50M steps in all)",
    )
    t.add_argument(
        "--seeds-per-trial", type=whole_arg, default=1, help="average the objective over K seeds (default 1)"
    )
    t.add_argument(
        "--seed", type=seed_arg, default=0, help="first seed of every trial (seeds SEED..SEED+K-1; default 0)"
    )
    t.add_argument(
        "--startup-trials", type=whole_arg, default=10, help="random trials before TPE models the space (default 10)"
    )
    t.add_argument(
        "--evaluations",
        type=whole_arg,
        default=20,
        help="evaluations during training per trial, for pruning (default 20)",
    )
    t.add_argument(
        "--eval-episodes", type=whole_arg, default=5, help="episodes per evaluation during training (default 5)"
    )
    t.add_argument("--trial-minutes", type=float, default=None, help="wall-clock limit of one trial")
    t.add_argument("--study-hours", type=float, default=None, help="stop starting trials after this many hours")
    t.add_argument("--space", default=None, metavar="FILE", help="search space TOML (default: the shipped one)")
    t.add_argument("--print-space", action="store_true", help="print the shipped search space of --algo and exit")
    t.add_argument(
        "--preset",
        default=None,
        help=f"preset under the sampled values: {', '.join(preset_names())} (default: the one a --config file's "
        "run.preset names, else fast)",
    )
    t.add_argument("--config", default=None, help="TOML file under the sampled values")
    t.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="fixed override")
    add_backend_arg(t)
    t.add_argument("--out-dir", default="tune", help="folder of study folders (default tune/)")
    t.add_argument("--study", default=None, metavar="NAME", help="study name (default ENV__ALGO)")
    t.add_argument(
        "--storage",
        default=None,
        metavar="URL",
        help="Optuna RDB URL, e.g. postgresql://user:pw@host/db (default: SQLite in the study folder)",
    )
    t.add_argument(
        "--heartbeat",
        type=whole_arg,
        default=60,
        metavar="SECONDS",
        help="trial heartbeat interval (default %(default)s); a trial silent for 3x this, or whose worker on this "
        "machine is gone, is failed and retried",
    )
    t.add_argument(
        "--sampler-seed",
        type=seed_arg,
        default=None,
        help="seed of the TPE sampler (job 0 of --jobs uses SEED, job J one drawn from SEED and J; give each "
        "machine its own; default: none, so a random one)",
    )
    add_track_args(t, "one tracker run per seed of each trial, named trial_NNNNN-sSEED, every trial in one group")
    t.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from canter.algos import check_algorithm_name

    check_algorithm_name(args.algo)
    if args.print_space:
        from canter.orchestrate.search_space import default_space_text

        print(default_space_text(args.algo), end="")
        return 0
    if not args.env:
        raise CanterError("no environment given; pass an env id, e.g. `canter tune Hopper-v5`")
    check_storage_arg(args.storage, "the SQLite database in the study folder")
    if args.seeds_per_trial < 1:  # TuneSettings sees the seeds, none at all for a count below 1
        raise CanterError(f"--seeds-per-trial must be >= 1, got {args.seeds_per_trial}")
    if args.seed + args.seeds_per_trial > SEED_LIMIT:
        raise CanterError(f"--seed {args.seed} with {args.seeds_per_trial} seeds per trial passes {SEED_LIMIT - 1}")
    from canter.orchestrate.tune import TuneSettings, tune

    settings = TuneSettings(
        env_id=args.env,
        algo=args.algo,
        trials=args.trials,
        jobs=args.jobs,
        total_steps=args.total_steps,
        seeds=tuple(range(args.seed, args.seed + args.seeds_per_trial)),
        startup_trials=args.startup_trials,
        evaluations=args.evaluations,
        eval_episodes=args.eval_episodes,
        trial_minutes=args.trial_minutes,
        study_hours=args.study_hours,
        preset=args.preset,
        config_file=args.config,
        sets=sets_with_backend(args),
        space_file=args.space,
        out_dir=args.out_dir,
        study_name=args.study,
        storage_url=args.storage,
        heartbeat_seconds=args.heartbeat,
        sampler_seed=args.sampler_seed,
        track=track_spec(args),
    )
    from canter.orchestrate.jobs import sigterm_interrupts

    with sigterm_interrupts():  # a scheduler's SIGTERM stops the jobs and records their trials, as Ctrl-C does
        tune(settings)
    return 0
