"""Stable-Baselines3 TD3 on HalfCheetah-v4 with the hyperparameters of canter's td3 defaults (CleanRL's
td3_continuous_action.py), as the baseline of benchmarks/td3_speed. Runs in the SB3 venv (benchmarks/.sb3-venv):

    benchmarks/.sb3-venv/bin/python benchmarks/td3_speed/sb3_td3.py --total-steps 1e6 --seed 0

Prints exactly one JSON line on stdout: {"tool": "sb3", "steps", "wall_seconds", "sps", "steady_sps",
"final_train_return", "seed", "learning_starts", "hyperparameters", "versions"}. `sps` counts every step inside
learn(); `steady_sps` only the steps after learning_starts (one gradient step per env step), which is what a
1M-step run is made of.
"""

from __future__ import annotations

import argparse
import json
import sys
import time


def _steps(text: str) -> int:
    value = float(text)
    if not value.is_integer() or value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole step count, got {text!r}")
    return int(value)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--total-steps", type=_steps, default=1_000_000)
    p.add_argument("--learning-starts", type=int, default=25_000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--env", default="HalfCheetah-v4")
    p.add_argument("--threads", type=int, default=2, help="torch.set_num_threads")
    args = p.parse_args(argv)

    started = time.perf_counter()
    import gymnasium as gym
    import numpy as np
    import torch
    from stable_baselines3 import TD3
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.noise import NormalActionNoise

    torch.set_num_threads(args.threads)
    after_imports = time.perf_counter()
    env = Monitor(gym.make(args.env))
    act_dim = env.action_space.shape[0]
    hyper = dict(
        learning_rate=3e-4,
        buffer_size=1_000_000,
        learning_starts=args.learning_starts,
        batch_size=256,
        tau=0.005,
        gamma=0.99,
        train_freq=1,
        gradient_steps=1,
        policy_delay=2,
        target_policy_noise=0.2,
        target_noise_clip=0.5,
    )
    model = TD3(
        "MlpPolicy",
        env,
        action_noise=NormalActionNoise(np.zeros(act_dim), 0.1 * np.ones(act_dim)),
        policy_kwargs=dict(net_arch=[256, 256]),
        seed=args.seed,
        device="cpu",
        verbose=0,
        **hyper,
    )

    class Clock(BaseCallback):
        """The time at which learning starts, for the steady-state rate."""

        def __init__(self) -> None:
            super().__init__()
            self.mark: tuple[float, int] | None = None

        def _on_step(self) -> bool:
            if self.mark is None and self.num_timesteps >= args.learning_starts:
                self.mark = (time.perf_counter(), self.num_timesteps)
            return True

    clock = Clock()
    learn_start = time.perf_counter()
    model.learn(total_timesteps=args.total_steps, callback=clock)
    end = time.perf_counter()
    returns = env.get_episode_rewards()[-20:]
    steady = None
    if clock.mark is not None and args.total_steps > clock.mark[1]:
        steady = (args.total_steps - clock.mark[1]) / (end - clock.mark[0])
    import gymnasium
    import mujoco
    import stable_baselines3

    print(
        json.dumps(
            {
                "tool": "sb3",
                "steps": args.total_steps,
                "wall_seconds": end - after_imports,
                "process_seconds_in_python": end - started,
                "sps": args.total_steps / (end - learn_start),
                "steady_sps": steady,
                "final_train_return": float(np.mean(returns)) if returns else None,
                "seed": args.seed,
                "learning_starts": args.learning_starts,
                "hyperparameters": dict(hyper, net_arch=[256, 256]),
                "versions": {
                    "stable_baselines3": stable_baselines3.__version__,
                    "torch": torch.__version__,
                    "gymnasium": gymnasium.__version__,
                    "mujoco": mujoco.__version__,
                    "python": sys.version.split()[0],
                },
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
