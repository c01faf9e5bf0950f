"""Gymnasium's v5 MuJoCo locomotion tasks, ported to MJX: the same XML models, observations, rewards, terminations,
reset noise and 1000-step limits as Gymnasium's defaults, written as pure JAX functions of one env.

Each task is a `Task` record in `TASKS`. Its functions read an `mjx.Data` as Gymnasium reads `MjData` after
`mj_step(nstep=frame_skip)` and `mj_rnePostConstraint`: positions and velocities are the final ones, while derived
quantities (body frames, com inertia and velocity, actuator and contact forces) are those the last substep computed
on its way, as in C MuJoCo: the start of the substep with the Euler integrator (HalfCheetah), the last Runge-Kutta
stage with RK4 (the others).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax.numpy as jnp

# How Gymnasium draws the initial velocity: `uniform` as qpos, U(-scale, scale); `normal`: scale * N(0, 1).
UNIFORM, NORMAL = "uniform", "normal"


@dataclass(frozen=True)
class Task:
    xml: str  # file name in gymnasium/envs/mujoco/assets
    frame_skip: int
    reset_noise_scale: float
    velocity_noise: str  # UNIFORM or NORMAL
    # (model, data) -> the position whose change over a step is the task's velocity ([x] or [x, y]).
    progress: Callable[[Any, Any], jnp.ndarray]
    observe: Callable[[Any, Any], jnp.ndarray]
    # (model, data, action, velocity [x] or [x, y], dt) -> (reward, terminated, info)
    reward: Callable[[Any, Any, jnp.ndarray, jnp.ndarray, float], tuple[jnp.ndarray, jnp.ndarray, dict]]
    info_keys: tuple[str, ...]
    contact_forces: bool = False  # reads cfrc_ext, which needs rne_postconstraint after the step
    max_episode_steps: int = 1000


def _x(model: Any, data: Any) -> jnp.ndarray:
    return data.qpos[:1]


def _torso_xy(model: Any, data: Any) -> jnp.ndarray:
    return data.xpos[1, :2]  # Ant's main body is body 1, "torso"


def _mass_center_xy(model: Any, data: Any) -> jnp.ndarray:
    mass = model.body_mass
    return (mass @ data.xipos / mass.sum())[:2]


def _no_progress(model: Any, data: Any) -> jnp.ndarray:
    return jnp.zeros((1,), data.qpos.dtype)


def _contact_wrenches(data: Any) -> jnp.ndarray:
    """Each body's external contact wrench (MuJoCo's cfrc_ext), which MJX 3.6 keeps in its JAX implementation's
    fields."""
    return data._impl.cfrc_ext


def _control_cost(weight: float, action: jnp.ndarray) -> jnp.ndarray:
    return weight * jnp.sum(jnp.square(action))


def _in_open(value: jnp.ndarray, low: float, high: float) -> jnp.ndarray:
    return (low < value) & (value < high)


# --- Hopper and Walker2d: planar walkers that fall over --------------------------------------------------------


def _planar_observe(model: Any, data: Any) -> jnp.ndarray:
    return jnp.concatenate([data.qpos[1:], jnp.clip(data.qvel, -10.0, 10.0)])


def _planar_reward(healthy: Callable[[Any], jnp.ndarray]) -> Callable[..., tuple]:
    def reward(model: Any, data: Any, action: jnp.ndarray, velocity: jnp.ndarray, dt: float) -> tuple:
        is_healthy = healthy(data)
        forward = velocity[0]
        survive = is_healthy.astype(forward.dtype)
        ctrl = _control_cost(1e-3, action)
        info = {
            "x_position": data.qpos[0],
            "z_distance_from_origin": data.qpos[1] - model.qpos0[1],
            "x_velocity": velocity[0],
            "reward_forward": forward,
            "reward_ctrl": -ctrl,
            "reward_survive": survive,
        }
        return forward + survive - ctrl, ~is_healthy, info

    return reward


def _hopper_healthy(data: Any) -> jnp.ndarray:
    z, angle = data.qpos[1], data.qpos[2]
    state = jnp.concatenate([data.qpos, data.qvel])[2:]
    return jnp.all(_in_open(state, -100.0, 100.0)) & _in_open(z, 0.7, jnp.inf) & _in_open(angle, -0.2, 0.2)


def _walker_healthy(data: Any) -> jnp.ndarray:
    return _in_open(data.qpos[1], 0.8, 2.0) & _in_open(data.qpos[2], -1.0, 1.0)


_PLANAR_INFO = ("x_position", "z_distance_from_origin", "x_velocity", "reward_forward", "reward_ctrl", "reward_survive")

# --- HalfCheetah ----------------------------------------------------------------------------------------------


def _cheetah_observe(model: Any, data: Any) -> jnp.ndarray:
    return jnp.concatenate([data.qpos[1:], data.qvel])


def _cheetah_reward(model: Any, data: Any, action: jnp.ndarray, velocity: jnp.ndarray, dt: float) -> tuple:
    forward = velocity[0]
    ctrl = _control_cost(0.1, action)
    info = {"x_position": data.qpos[0], "x_velocity": forward, "reward_forward": forward, "reward_ctrl": -ctrl}
    return forward - ctrl, jnp.zeros((), bool), info


# --- Ant ------------------------------------------------------------------------------------------------------


def _ant_contact_forces(data: Any) -> jnp.ndarray:
    return jnp.clip(_contact_wrenches(data), -1.0, 1.0)


def _ant_observe(model: Any, data: Any) -> jnp.ndarray:
    return jnp.concatenate([data.qpos[2:], data.qvel, _ant_contact_forces(data)[1:].reshape(-1)])


def _ant_reward(model: Any, data: Any, action: jnp.ndarray, velocity: jnp.ndarray, dt: float) -> tuple:
    state = jnp.concatenate([data.qpos, data.qvel])
    z = data.qpos[2]
    is_healthy = jnp.all(jnp.isfinite(state)) & (z >= 0.2) & (z <= 1.0)
    forward = velocity[0]
    survive = is_healthy.astype(forward.dtype)
    ctrl = _control_cost(0.5, action)
    contact = 5e-4 * jnp.sum(jnp.square(_ant_contact_forces(data)))
    info = {
        "x_position": data.qpos[0],
        "y_position": data.qpos[1],
        "distance_from_origin": jnp.linalg.norm(data.qpos[:2]),
        "x_velocity": velocity[0],
        "y_velocity": velocity[1],
        "reward_forward": forward,
        "reward_ctrl": -ctrl,
        "reward_contact": -contact,
        "reward_survive": survive,
    }
    return forward + survive - ctrl - contact, ~is_healthy, info


# --- Humanoid and HumanoidStandup -----------------------------------------------------------------------------


def _humanoid_observe(model: Any, data: Any) -> jnp.ndarray:
    return jnp.concatenate(
        [
            data.qpos[2:],
            data.qvel,
            data._impl.cinert[1:].reshape(-1),  # MJX 3.6 keeps cinert, as cfrc_ext, in its implementation's fields
            data.cvel[1:].reshape(-1),
            data.qfrc_actuator[6:],
            _contact_wrenches(data)[1:].reshape(-1),
        ]
    )


def _humanoid_reward(model: Any, data: Any, action: jnp.ndarray, velocity: jnp.ndarray, dt: float) -> tuple:
    is_healthy = _in_open(data.qpos[2], 1.0, 2.0)
    forward = 1.25 * velocity[0]
    survive = 5.0 * is_healthy.astype(forward.dtype)
    # Gymnasium costs the controls after the step, not the action: a divergence reset zeroes them in between.
    ctrl = _control_cost(0.1, data.ctrl)
    contact = jnp.minimum(5e-7 * jnp.sum(jnp.square(_contact_wrenches(data))), 10.0)
    info = {
        "x_position": data.qpos[0],
        "y_position": data.qpos[1],
        "distance_from_origin": jnp.linalg.norm(data.qpos[:2]),
        "x_velocity": velocity[0],
        "y_velocity": velocity[1],
        "reward_survive": survive,
        "reward_forward": forward,
        "reward_ctrl": -ctrl,
        "reward_contact": -contact,
    }
    return forward + survive - ctrl - contact, ~is_healthy, info


def _standup_reward(model: Any, data: Any, action: jnp.ndarray, velocity: jnp.ndarray, dt: float) -> tuple:
    uph = data.qpos[2] / model.opt.timestep
    ctrl = _control_cost(0.1, data.ctrl)  # the controls after the step, as `_humanoid_reward` costs them
    impact = jnp.minimum(0.5e-6 * jnp.sum(jnp.square(_contact_wrenches(data))), 10.0)
    info = {
        "x_position": data.qpos[0],
        "y_position": data.qpos[1],
        "z_distance_from_origin": data.qpos[2] - model.qpos0[2],
        "reward_linup": uph,
        "reward_quadctrl": -ctrl,
        "reward_impact": -impact,
    }
    return uph - ctrl - impact + 1.0, jnp.zeros((), bool), info


# --- InvertedPendulum -----------------------------------------------------------------------------------------


def _pendulum_observe(model: Any, data: Any) -> jnp.ndarray:
    return jnp.concatenate([data.qpos, data.qvel])


def _pendulum_reward(model: Any, data: Any, action: jnp.ndarray, velocity: jnp.ndarray, dt: float) -> tuple:
    obs = _pendulum_observe(model, data)
    terminated = ~jnp.all(jnp.isfinite(obs)) | (jnp.abs(obs[1]) > 0.2)
    reward = (~terminated).astype(obs.dtype)
    return reward, terminated, {"reward_survive": reward}


_GROUND_INFO = (
    "x_position",
    "y_position",
    "distance_from_origin",
    "x_velocity",
    "y_velocity",
)

TASKS: dict[str, Task] = {
    "InvertedPendulum-v5": Task(
        xml="inverted_pendulum.xml",
        frame_skip=2,
        reset_noise_scale=0.01,
        velocity_noise=UNIFORM,
        progress=_no_progress,
        observe=_pendulum_observe,
        reward=_pendulum_reward,
        info_keys=("reward_survive",),
    ),
    "Hopper-v5": Task(
        xml="hopper.xml",
        frame_skip=4,
        reset_noise_scale=5e-3,
        velocity_noise=UNIFORM,
        progress=_x,
        observe=_planar_observe,
        reward=_planar_reward(_hopper_healthy),
        info_keys=_PLANAR_INFO,
    ),
    "Walker2d-v5": Task(
        xml="walker2d_v5.xml",
        frame_skip=4,
        reset_noise_scale=5e-3,
        velocity_noise=UNIFORM,
        progress=_x,
        observe=_planar_observe,
        reward=_planar_reward(_walker_healthy),
        info_keys=_PLANAR_INFO,
    ),
    "HalfCheetah-v5": Task(
        xml="half_cheetah.xml",
        frame_skip=5,
        reset_noise_scale=0.1,
        velocity_noise=NORMAL,
        progress=_x,
        observe=_cheetah_observe,
        reward=_cheetah_reward,
        info_keys=("x_position", "x_velocity", "reward_forward", "reward_ctrl"),
    ),
    "Ant-v5": Task(
        xml="ant.xml",
        frame_skip=5,
        reset_noise_scale=0.1,
        velocity_noise=NORMAL,
        progress=_torso_xy,
        observe=_ant_observe,
        reward=_ant_reward,
        info_keys=_GROUND_INFO + ("reward_forward", "reward_ctrl", "reward_contact", "reward_survive"),
        contact_forces=True,
    ),
    "Humanoid-v5": Task(
        xml="humanoid.xml",
        frame_skip=5,
        reset_noise_scale=1e-2,
        velocity_noise=UNIFORM,
        progress=_mass_center_xy,
        observe=_humanoid_observe,
        reward=_humanoid_reward,
        info_keys=_GROUND_INFO + ("reward_survive", "reward_forward", "reward_ctrl", "reward_contact"),
        contact_forces=True,
    ),
    "HumanoidStandup-v5": Task(
        xml="humanoidstandup.xml",
        frame_skip=5,
        reset_noise_scale=1e-2,
        velocity_noise=UNIFORM,
        progress=_no_progress,
        observe=_humanoid_observe,
        reward=_standup_reward,
        info_keys=(
            "x_position",
            "y_position",
            "z_distance_from_origin",
            "reward_linup",
            "reward_quadctrl",
            "reward_impact",
        ),
        contact_forces=True,
    ),
}
