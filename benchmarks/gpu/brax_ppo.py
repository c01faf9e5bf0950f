"""Brax's own PPO (`brax.training.agents.ppo.train`) on one of Brax's envs, with Brax's published settings: the
reference side of run.sh's `ppo-brax` part. Writes one JSON record of what it measured.

    python benchmarks/gpu/brax_ppo.py ant --timesteps 10_000_000 --out brax_ant.json

The settings are Brax's training notebook's (google/brax, notebooks/training.ipynb, `train_fn`), as canter's `brax`
preset maps them (src/canter/presets/brax.toml). `--smoke` shrinks them so that the script runs on a CPU in a
minute or two: it checks the script, not Brax.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import time
import warnings
from typing import Any

PUBLISHED = {
    "ant": dict(
        num_evals=10,
        reward_scaling=10,
        episode_length=1000,
        normalize_observations=True,
        action_repeat=1,
        unroll_length=5,
        num_minibatches=32,
        num_updates_per_batch=4,
        discounting=0.97,
        learning_rate=3e-4,
        entropy_cost=1e-2,
        num_envs=4096,
        batch_size=2048,
        seed=1,
    ),
    "humanoid": dict(
        num_evals=10,
        reward_scaling=0.1,
        episode_length=1000,
        normalize_observations=True,
        action_repeat=1,
        unroll_length=10,
        num_minibatches=32,
        num_updates_per_batch=8,
        discounting=0.97,
        learning_rate=3e-4,
        entropy_cost=1e-3,
        num_envs=2048,
        batch_size=1024,
        seed=1,
    ),
}
# --smoke: a handful of envs and short episodes, so that a CPU runs it.
SMOKE = dict(num_envs=8, batch_size=4, num_minibatches=2, episode_length=20, num_eval_envs=4)


def restore_device_put_replicated(jax: Any) -> None:
    """Brax 0.14.2 (the newest release) builds its trainer's state with `jax.device_put_replicated`, which JAX 0.10
    removed. This puts it back as JAX's pmap migration guide replaces it: the value stacked once per device, one
    slice on each."""
    import jax.numpy as jnp
    import numpy as np
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    def device_put_replicated(value: Any, devices: list) -> Any:
        sharding = NamedSharding(Mesh(np.array(devices), ("devices",)), PartitionSpec("devices"))
        return jax.tree.map(lambda x: jax.device_put(jnp.stack([jnp.asarray(x)] * len(devices)), sharding), value)

    try:
        jax.device_put_replicated  # noqa: B018 (an AttributeError where JAX removed it)
    except AttributeError:
        jax.device_put_replicated = device_put_replicated


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("env", choices=sorted(PUBLISHED))
    parser.add_argument("--timesteps", type=int, required=True, help="Brax's num_timesteps (it rounds up)")
    parser.add_argument("--num-evals", type=int, default=3, help="evaluations, the one at step 0 included")
    parser.add_argument("--out", required=True, help="JSON file to write")
    parser.add_argument("--smoke", action="store_true", help="tiny settings, to check the script on a CPU")
    args = parser.parse_args()

    started = time.time()
    with contextlib.redirect_stdout(io.StringIO()):  # MJX prints a line per optional GPU library it lacks
        import jax
        from brax import envs
        from brax.training.agents.ppo import train as ppo

    restore_device_put_replicated(jax)
    # Deterministic evaluations, as canter's: Brax's default samples actions, and on ant a near-still deterministic
    # policy already earns the survive reward, so the two final returns would not measure one thing.
    settings = dict(PUBLISHED[args.env], num_evals=args.num_evals, deterministic_eval=True)
    if args.smoke:
        settings.update(SMOKE)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Brax System, piplines and environments")
        env = envs.get_environment(args.env, backend="mjx")

    evals: list[dict] = []

    def progress(step: int, metrics: dict) -> None:
        evals.append(
            dict(
                step=int(step),
                wall=time.time() - started,
                eval_return=float(metrics["eval/episode_reward"]),
                training_sps=float(metrics.get("training/sps", float("nan"))),
                # Brax's own clocks: its training epochs so far (the first includes its compile), and this evaluation.
                training_walltime=float(metrics.get("training/walltime", float("nan"))),
                eval_walltime=float(metrics.get("eval/walltime", float("nan"))),
            )
        )
        print(f"brax {args.env}: step {step:,} eval return {evals[-1]['eval_return']:.1f} at {evals[-1]['wall']:.1f} s")

    ppo.train(environment=env, num_timesteps=args.timesteps, progress_fn=progress, **settings)
    wall = time.time() - started
    steps = evals[-1]["step"]
    record = dict(
        env=args.env,
        device=str(jax.devices()[0].device_kind),
        settings=settings,
        steps=steps,
        wall_seconds=wall,  # from before the imports of JAX and Brax to the end of training
        steps_per_second=steps / wall,
        training_walltime=evals[-1]["training_walltime"],
        # Brax's own figure: env steps per second of its last training epoch (the first includes the compile).
        training_sps=evals[-1]["training_sps"],
        final_eval_return=evals[-1]["eval_return"],
        eval_episodes=settings.get("num_eval_envs", 128),
        evals=evals,
    )
    with open(args.out, "w") as f:
        json.dump(record, f, indent=2)
    print(
        f"brax {args.env} on {record['device']}: {steps:,} steps in {wall:.1f} s "
        f"({record['steps_per_second']:,.0f} steps/s whole run, {record['training_sps']:,.0f} training), "
        f"final eval return {record['final_eval_return']:.1f}"
    )


if __name__ == "__main__":
    main()
