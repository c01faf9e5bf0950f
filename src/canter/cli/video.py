"""`canter video`: render deterministic episodes of a run's checkpoint (the newest by default) to an MP4 or GIF,
headless."""

from __future__ import annotations

import argparse
import time

from canter.cli.args import add_checkpoint_arg, seed_arg, whole_arg


def register(sub: argparse._SubParsersAction) -> None:
    from canter.use.video import DEFAULT_FPS, DEFAULT_HEIGHT, DEFAULT_WIDTH, FPS_LIMITS

    v = sub.add_parser(
        "video",
        help="render a run's policy to an MP4 or GIF",
        description="Render episodes of a checkpoint (the newest by default) with MuJoCo's offscreen renderer (EGL or "
        "OSMesa; MUJOCO_GL picks one), Box2D's for BipedalWalker, dm_control's for DM "
        "Control runs. EnvPool runs replay in the equivalent Gymnasium env.",
    )
    v.add_argument("run", help="run folder")
    v.add_argument("--out", required=True, help="output file: .mp4 (H.264) or .gif")
    v.add_argument("--episodes", type=whole_arg, default=1, help="episodes, one after another (default 1)")
    v.add_argument(
        "--width", type=whole_arg, default=DEFAULT_WIDTH, help=f"frame width, 16 to 4096 (default {DEFAULT_WIDTH})"
    )
    v.add_argument(
        "--height", type=whole_arg, default=DEFAULT_HEIGHT, help=f"frame height, 16 to 4096 (default {DEFAULT_HEIGHT})"
    )
    fps_limits = ", ".join(f"{limit} for {suffix}" for suffix, (limit, _) in FPS_LIMITS.items())
    v.add_argument(
        "--fps",
        type=whole_arg,
        default=DEFAULT_FPS,
        help=f"frames per second (default {DEFAULT_FPS}; at most {fps_limits})",
    )
    v.add_argument(
        "--camera",
        default=None,
        help="MuJoCo camera name or index, -1 for the free camera (default: the env's own view)",
    )
    v.add_argument("--max-steps", type=whole_arg, default=0, help="cut each episode after this many steps (0: no cut)")
    add_checkpoint_arg(v)
    v.add_argument("--seed", type=seed_arg, default=0, help="env seed of the first episode (default 0)")
    v.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from canter.use.video import record_video

    started = time.perf_counter()
    last = [started]

    def episode_done(index: int, value: float) -> None:
        now = time.perf_counter()
        print(f"episode {index + 1}/{args.episodes}: return {value:.1f} ({now - last[0]:.1f} s)", flush=True)
        last[0] = now

    def starting() -> None:
        cut = f", at most {args.max_steps} steps each" if args.max_steps else ""
        print(f"rendering {args.episodes} episode(s) of {args.run} to {args.out}{cut}", flush=True)
        last[0] = time.perf_counter()

    returns = record_video(
        args.run,
        args.out,
        episodes=args.episodes,
        width=args.width,
        height=args.height,
        fps=args.fps,
        camera=args.camera,
        seed=args.seed,
        checkpoint=args.checkpoint,
        max_steps=args.max_steps,
        on_start=starting,
        on_episode=episode_done,
    )
    print(f"wrote {args.out} ({len(returns)} episodes) in {time.perf_counter() - started:.1f} s")
    return 0
