"""Stable-Baselines3 PPO on HalfCheetah-v4 with CleanRL's ppo_continuous_action.py hyperparameters (canter's
`cleanrl` preset), as the baseline of benchmarks/ppo_speed. Runs in its own venv (requirements-sb3.txt):

    benchmarks/.sb3-venv/bin/python benchmarks/ppo_speed/sb3_ppo.py --total-steps 1e6 --seed 0

Prints exactly one JSON line on stdout (everything else goes to stderr):
    {"tool": "sb3", "steps", "wall_seconds", "train_seconds", "sps", "final_train_return", "train_episodes",
     "eval_mean", "eval_std", "eval_returns", "eval_seconds", "seed", "hyperparameters", "versions"}

wall_seconds counts, like canter's summary.json, from after the imports to the end of training (env and model
construction plus learn()); sps = steps / the time inside learn() (SB3 has no compile step to leave out).
final_train_return is the mean raw return of the last 20 training episodes (Monitor under VecNormalize).

run.py splits the two halves into separate processes, so that the training process's wall time leaves the
evaluation out, as canter's does:
    sb3_ppo.py --total-steps N --seed S --save DIR --eval-episodes 0   (train, save model.zip + vecnormalize.pkl)
    sb3_ppo.py --eval-from DIR --eval-episodes 10                        (one JSON line with eval_* fields)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings


def _steps(text: str) -> int:
    value = float(text)
    if not value.is_integer() or value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole step count, got {text!r}")
    return int(value)


def _clip_vf(text: str) -> float | None:
    return None if text.lower() in ("none", "off", "0") else float(text)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--total-steps", type=_steps, default=1_000_000, help="env steps (1e6 works)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--env", default="HalfCheetah-v4")
    p.add_argument("--threads", type=int, default=2, help="torch.set_num_threads")
    p.add_argument("--eval-episodes", type=int, default=10, help="0: no evaluation")
    p.add_argument("--save", default=None, metavar="DIR", help="save model.zip and vecnormalize.pkl after training")
    p.add_argument("--eval-from", default=None, metavar="DIR", help="only evaluate a model saved with --save")
    p.add_argument(
        "--clip-range-vf",
        type=_clip_vf,
        default=0.2,
        help="value clipping (CleanRL clip_vloss with clip 0.2); 'none' turns it off",
    )
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    import gymnasium  # noqa: F401  (registers the MuJoCo envs)
    import numpy as np
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    # gymnasium: "HalfCheetah-v4 is out of date" (after the imports: gymnasium sets its own filter on import)
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    if args.eval_from:
        return eval_only(args)
    torch.set_num_threads(args.threads)
    started = time.perf_counter()

    gamma = 0.99
    lr = 3e-4
    env = VecNormalize(
        DummyVecEnv([lambda: make_env(args.env)]),
        norm_obs=True,
        norm_reward=True,
        clip_obs=10.0,
        clip_reward=10.0,
        gamma=gamma,
    )
    hyper = dict(
        n_steps=2048,
        batch_size=64,
        n_epochs=10,
        gamma=gamma,
        gae_lambda=0.95,
        clip_range=0.2,
        clip_range_vf=args.clip_range_vf,
        normalize_advantage=True,
        ent_coef=0.0,
        vf_coef=0.5,
        max_grad_norm=0.5,
    )
    policy_kwargs = dict(
        net_arch=dict(pi=[64, 64], vf=[64, 64]), activation_fn=torch.nn.Tanh, log_std_init=0.0, ortho_init=True
    )  # SB3 sets Adam eps=1e-5 itself, as CleanRL does
    model = PPO(
        "MlpPolicy",
        env,
        learning_rate=lambda progress_remaining: lr * progress_remaining,
        policy_kwargs=policy_kwargs,
        seed=args.seed,
        device="cpu",
        verbose=0,
        stats_window_size=20,
        **hyper,
    )

    learn_start = time.perf_counter()
    model.learn(total_timesteps=args.total_steps, progress_bar=False)
    train_seconds = time.perf_counter() - learn_start
    if args.save:  # inside wall_seconds, as canter's final checkpoint is
        from pathlib import Path

        Path(args.save).mkdir(parents=True, exist_ok=True)
        model.save(Path(args.save) / "model.zip")
        env.save(str(Path(args.save) / "vecnormalize.pkl"))
    wall_seconds = time.perf_counter() - started
    steps = int(model.num_timesteps)
    recent = [float(info["r"]) for info in list(model.ep_info_buffer)[-20:]]

    env.close()
    row = {
        "tool": "sb3",
        "env": args.env,
        "seed": args.seed,
        "steps": steps,
        "wall_seconds": wall_seconds,
        "train_seconds": train_seconds,
        "sps": steps / train_seconds,
        "final_train_return": float(np.mean(recent)) if recent else None,
        "train_episodes": len(recent),
        **evaluate(args, model, env.obs_rms),
        "hyperparameters": dict(
            hyper,
            learning_rate=f"{lr} linearly annealed",
            net_arch="pi=[64,64] vf=[64,64]",
            activation="tanh",
            log_std_init=0.0,
            ortho_init=True,
            num_envs=1,
            vec_normalize="obs+reward, clip 10",
            torch_threads=args.threads,
        ),
        "versions": versions(),
        "python": sys.version.split()[0],
    }
    print(json.dumps(row), flush=True)
    return 0


def make_env(env_id: str):
    import gymnasium as gym
    from stable_baselines3.common.monitor import Monitor

    return Monitor(gym.make(env_id))


def evaluate(args: argparse.Namespace, model, obs_rms) -> dict:
    """Deterministic episodes on a fresh env with the training normalizer frozen and raw rewards."""
    import numpy as np
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    if args.eval_episodes < 1:
        return {"eval_mean": None, "eval_std": None, "eval_returns": [], "eval_seconds": 0.0}
    start = time.perf_counter()
    eval_env = VecNormalize(
        DummyVecEnv([lambda: make_env(args.env)]), training=False, norm_obs=True, norm_reward=False, clip_obs=10.0
    )
    eval_env.obs_rms = obs_rms.copy()
    eval_env.seed(args.seed + 1_000_003)
    returns, _lengths = evaluate_policy(
        model, eval_env, n_eval_episodes=args.eval_episodes, deterministic=True, return_episode_rewards=True
    )
    eval_env.close()
    returns = np.asarray(returns, dtype=float)
    return {
        "eval_mean": float(returns.mean()),
        "eval_std": float(returns.std()),
        "eval_returns": [float(r) for r in returns],
        "eval_seconds": time.perf_counter() - start,
    }


def eval_only(args: argparse.Namespace) -> int:
    import pickle
    from pathlib import Path

    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(args.threads)
    folder = Path(args.eval_from)
    model = PPO.load(folder / "model.zip", device="cpu")
    with open(folder / "vecnormalize.pkl", "rb") as f:
        obs_rms = pickle.load(f).obs_rms
    row = {
        "tool": "sb3",
        "env": args.env,
        "seed": args.seed,
        "steps": int(model.num_timesteps),
        **evaluate(args, model, obs_rms),
        "versions": versions(),
    }
    print(json.dumps(row), flush=True)
    return 0


def versions() -> dict:
    from importlib import metadata

    def version(name: str) -> str | None:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return None

    return {name: version(name) for name in ("stable_baselines3", "torch", "gymnasium", "mujoco", "numpy")}


if __name__ == "__main__":
    sys.exit(main())
