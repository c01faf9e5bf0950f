"""`canter train`: train a policy into a run folder, or resume one."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from canter.cli.args import (
    add_backend_arg,
    add_track_args,
    limit_arg,
    seed_arg,
    seeds_arg,
    steps_arg,
    track_spec,
    whole_arg,
)
from canter.config.values import unlimited_as_none
from canter.errors import CanterError
from canter.signals import stops_dropped_after_the_work


def register(sub: argparse._SubParsersAction) -> None:
    from canter.algos import algorithm_names
    from canter.config.presets import preset_names

    t = sub.add_parser(
        "train",
        help="train a policy; writes a run folder",
        description="Train a policy. Precedence: defaults < --preset < --config < --set < flags.",
    )
    t.add_argument("env", nargs="?", help="env id (Hopper-v5) or module:EnvId for a custom Gymnasium env")
    t.add_argument("--algo", default=None, help=f"algorithm: {', '.join(algorithm_names())} (default ppo)")
    t.add_argument(
        "--preset",
        default=None,
        help=f"preset overlay: {', '.join(preset_names())} (default: the one a --config file's run.preset names, "
        f"else fast)",
    )
    t.add_argument("--config", default=None, help="TOML file with [section] key = value")
    t.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="override one key")
    t.add_argument("--total-steps", type=steps_arg, default=None, help="env steps (1e6 works)")
    add_backend_arg(t)
    t.add_argument(
        "--stop-at-return",
        type=limit_arg,
        default=None,
        help="stop once the mean of the last 20 training episodes reaches this (inf: no target, which lifts a resumed "
        "run's)",
    )
    t.add_argument(
        "--max-minutes",
        type=limit_arg,
        default=None,
        help="stop cleanly, with a checkpoint, after M minutes (with --resume: replaces the saved limit; inf lifts it)",
    )
    t.add_argument("--out-dir", default=None, help="folder for run folders (default runs/)")
    t.add_argument(
        "--video-every",
        type=steps_arg,
        default=None,
        metavar="N",
        help="render an episode to RUN/videos/step_<step>.mp4 every N env steps (run.video_every)",
    )
    t.add_argument(
        "--eval-every",
        type=steps_arg,
        default=None,
        metavar="N",
        help="evaluate as `canter eval` does every N env steps and at the end, into metrics.csv's eval/* "
        "columns, keeping the best state as checkpoints/best.npz (run.eval_every; default: never)",
    )
    t.add_argument(
        "--eval-episodes",
        type=whole_arg,
        default=None,
        metavar="K",
        help="episodes of each evaluation during training (run.eval_episodes, default 10)",
    )
    t.add_argument(
        "--seeds",
        type=seeds_arg,
        default=None,
        metavar="S1,S2,...",
        help="train one run per seed together in one vmapped program (instead of --seed)",
    )
    t.add_argument(
        "--resume",
        nargs="+",
        default=None,
        metavar="RUN_DIR",
        help="continue a run from its newest checkpoint; several run folders that differ only in "
        "run.seed resume together as one group",
    )
    add_track_args(t, "one tracker run per seed; a resume continues the tracker runs recorded in RUN/trackers.json")
    t.add_argument("--seed", type=seed_arg, default=None, help="run seed")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from canter.training.trackers import tracking

    # Once training's StopFlag ends, the run is saved and summarized: a stop signal as the trackers close or the
    # report prints is dropped, and the run ends as it finished (exit 0), not as a killed one (143).
    with stops_dropped_after_the_work():
        with tracking(track_spec(args, [Path(d) for d in args.resume or ()])):
            results = _train(args)
        _report(results)
    return 0


# The flags that set a run.* key of a new run; --resume refuses them (it keeps the run's settings) but for the budget.
_RUN_KEY_FLAGS = {
    "out_dir": "run.out_dir",
    "video_every": "run.video_every",
    "eval_every": "run.eval_every",
    "eval_episodes": "run.eval_episodes",
}
# What each setting of the evaluations during training sets; each needs run.eval_every.
_EVALUATION_SETTINGS = {
    "--eval-episodes": "the episodes of each evaluation",
    "--set run.eval_episodes": "the episodes of each evaluation",
    "--set run.eval_backend": "where the evaluations play",
}
# What --resume may be given besides run folders: the budget and how the run is shown and tracked.
_RESUME_FLAGS = "--total-steps, --max-minutes, --stop-at-return, --quiet, --track and --mlflow-uri"


def _train(args: argparse.Namespace) -> list[Any]:
    if args.seed is not None and args.seeds is not None:
        raise CanterError("--seed and --seeds exclude each other; give one seed with --seed or a group with --seeds")
    return _resume(args) if args.resume else _train_new(args)


def _resume(args: argparse.Namespace) -> list[Any]:
    given = {"env": args.env, "--algo": args.algo, "--preset": args.preset, "--config": args.config}
    given |= {"--set": args.set, "--seed": args.seed, "--seeds": args.seeds, "--backend": args.backend}
    given |= {f"--{name.replace('_', '-')}": getattr(args, name) for name in _RUN_KEY_FLAGS}
    changed = [flag for flag, value in given.items() if value is not None and value != []]  # 0 is given too
    if changed:
        raise CanterError(
            f"--resume uses the saved config; only {_RESUME_FLAGS} may be given (got {', '.join(changed)})"
        )
    _check_the_renderer(_renders_videos_when_resumed(args.resume))
    # The trainer imports JAX, so it comes after the checks that need only the config.
    from canter.training.loop import resume_seeds, train
    from canter.training.resume import Saved, resume_config

    target = Saved.KEEP if args.stop_at_return is None else unlimited_as_none(args.stop_at_return)
    if len(args.resume) > 1:
        return resume_seeds(
            [Path(d) for d in args.resume],
            args.total_steps,
            max_minutes=args.max_minutes,
            stop_at_return=target,
            quiet=args.quiet,
        )
    config = resume_config(Path(args.resume[0]), args.total_steps, args.max_minutes, target)
    return [train(config, resume=args.resume[0], quiet=args.quiet)]


def _train_new(args: argparse.Namespace) -> list[Any]:
    from canter.algos import seeds_train_apart
    from canter.config.build import build_config
    from canter.config.overrides import parse_set_args

    if args.out_dir == "":  # it would read as not given, and the run would go to runs/
        raise CanterError("--out-dir is empty; give a folder for the run folders, or drop --out-dir")
    extra: dict[str, Any] = {key: getattr(args, flag) for flag, key in _RUN_KEY_FLAGS.items()}
    extra = {key: value for key, value in extra.items() if value is not None}
    if args.backend:
        extra["env.backend"] = args.backend
    if args.stop_at_return is not None:
        extra["run.stop_at_return"] = unlimited_as_none(args.stop_at_return)
    if args.max_minutes is not None:  # inf is no limit, which the config holds as none
        extra["run.max_minutes"] = unlimited_as_none(args.max_minutes)
    config = build_config(
        args.env,
        preset=args.preset,
        config_file=args.config,
        sets=list(args.set),
        # A group replaces the seed by each of its own; given here, it refuses a --set run.seed all the same.
        seed=args.seeds[0] if args.seeds else args.seed,
        total_steps=args.total_steps,
        algo=args.algo,
        flags=extra,
    )
    if not config.run.eval_every:  # the settings of evaluations during training would change nothing without them
        set_keys = parse_set_args(list(args.set))
        given = {"--eval-episodes": args.eval_episodes is not None}
        given |= {f"--set {key}": key in set_keys for key in ("run.eval_episodes", "run.eval_backend")}
        for flag in (flag for flag, present in given.items() if present):
            raise CanterError(f"{flag} sets {_EVALUATION_SETTINGS[flag]} during training; also pass --eval-every N")
    _check_the_renderer(bool(config.run.video_every))
    from canter.training.loop import train, train_seeds

    if args.seeds is None:
        return [train(config, quiet=args.quiet)]
    if len(args.seeds) > 1 and seeds_train_apart(config.run.algo):
        print(
            f"canter: note: {config.run.algo} seeds train faster one per process than in a group "
            f"(docs/multiseed.md); `canter bench --algos {config.run.algo} --seeds ... --jobs 2` does that",
            file=sys.stderr,
        )
    return train_seeds(config, args.seeds, quiet=args.quiet)


def _renders_videos_when_resumed(run_dirs: list[str]) -> bool:
    """Whether any of these runs renders videos as it trains; a config.toml that cannot be read says nothing here,
    and the resume itself names what is wrong with it."""
    from canter.training.run_folder import read_config

    for run_dir in run_dirs:
        try:
            if read_config(Path(run_dir)).run.video_every:
                return True
        except CanterError:
            continue
    return False


def _check_the_renderer(renders: bool) -> None:
    """A MUJOCO_GL that names no renderer, or cannot render here, is refused before a run that renders videos
    starts; a renderer that fails later costs only its videos."""
    if renders:
        from canter.use.renderer import check_renderer

        check_renderer()


def _report(results: list[Any]) -> None:
    for result in results:
        recent = "n/a" if result.recent_return is None else f"{result.recent_return:.1f}"
        print(f"run: {result.run_dir}")
        print(
            f"steps {result.global_step:,} | {result.sps:,.0f} SPS (compile {result.compile_seconds:.1f} s apart) "
            f"| wall {result.wall_seconds:.1f} s | return (last 20 episodes) {recent} | "
            f"stopped: {result.stop_reason}"
        )
