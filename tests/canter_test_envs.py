"""Small custom Gymnasium envs for tests, importable as `canter_test_envs:<Id>`."""

import gymnasium as gym
import numpy as np


class NaNAfter(gym.Env):
    """Returns a NaN observation after `after` steps."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (3,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def __init__(self, after=300):
        self.after, self.t = after, 0
        self.total = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(3, np.float32), {}

    def step(self, action):
        self.t += 1
        self.total += 1
        obs = np.full(3, np.nan if self.total > self.after else 0.1, np.float32)
        return obs, 1.0, False, self.t >= 50, {}


class DiscreteObs(gym.Env):
    observation_space = gym.spaces.Discrete(4)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        return 0, {}

    def step(self, action):
        return 0, 0.0, False, False, {}


class DictObs(gym.Env):
    """Dict observation; counts steps so episode lengths are known (terminates at 7, truncated by 10)."""

    observation_space = gym.spaces.Dict(
        {"b": gym.spaces.Box(-1, 1, (2,), np.float32), "a": gym.spaces.Box(-1, 1, (1,), np.float32)}
    )
    action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return {"a": np.zeros(1, np.float32), "b": np.zeros(2, np.float32)}, {}

    def step(self, action):
        self.t += 1
        obs = {"a": np.full(1, self.t / 10, np.float32), "b": np.full(2, -self.t / 10, np.float32)}
        return obs, float(self.t), self.t >= 7, False, {"reward_step": float(self.t)}


class RefusesOutOfBounds(gym.Env):
    """Accepts only actions within its bounds, [1, 2], which exclude 0."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float32)
    action_space = gym.spaces.Box(1.0, 2.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(1, np.float32), {}

    def step(self, action):
        if not self.action_space.contains(np.asarray(action, np.float32)):
            raise ValueError(f"action {action} is outside [1, 2]")
        return np.zeros(1, np.float32), 0.0, False, False, {"speed": 1.0}


gym.register("NaNAfter-v0", entry_point=NaNAfter, max_episode_steps=50)
gym.register("NaNAtOnce-v0", entry_point=NaNAfter, kwargs={"after": 5}, max_episode_steps=50)  # in the 1st iteration
gym.register("RefusesOutOfBounds-v0", entry_point=RefusesOutOfBounds, max_episode_steps=10)
gym.register("DiscreteObs-v0", entry_point=DiscreteObs)
gym.register("DictObs-v0", entry_point=DictObs, max_episode_steps=10)
