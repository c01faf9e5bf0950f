"""One ported task as a `FunctionalEnv`: Gymnasium's XML loaded by C MuJoCo, moved to MJX, stepped `frame_skip`
times per action."""

from __future__ import annotations

import functools
import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from canter.envs.functional import FunctionalEnv, x64_enabled
from canter.envs.mjx.collisions import c_mujoco_collisions
from canter.envs.mjx.library import import_mjx
from canter.envs.mjx.tasks import NORMAL, TASKS, Task
from canter.errors import CanterError


def assets_dir() -> Path:
    import gymnasium.envs.mujoco

    return Path(gymnasium.envs.mujoco.__file__).parent / "assets"


def load_model(task: Task, env_id: str) -> Any:
    """The task's MjModel, with the one change MJX needs: it has no PGS solver, so a model that asks for PGS
    (Humanoid, HumanoidStandup) solves its constraints with Newton instead, and says so each time an env definition
    is built (once per process, physics setting and precision)."""
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(assets_dir() / task.xml))
    if model.opt.solver == mujoco.mjtSolver.mjSOL_PGS:
        model.opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
        print(
            f"canter: {env_id} on mjx solves contacts with Newton: MJX has no PGS solver, which its XML asks for, "
            f"so its physics differ slightly from CPU MuJoCo's",
            file=sys.stderr,
        )
    return model


def collide_with_floor_only(model: Any) -> None:
    """Let the model's body geoms collide with the floor (its planes) and not with each other (env.contacts=floor),
    as Brax and MuJoCo Playground limit their models' contacts. MuJoCo collides two geoms when either one's contype
    meets the other's conaffinity, so the colliding body geoms get contype 0 and conaffinity 1 and the planes the
    opposite; geoms that collided with nothing still do not."""
    import mujoco

    colliding = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    planes = model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE
    if not (colliding & planes).any():
        raise CanterError("env.contacts=floor needs a model with a floor (a plane geom); this one has none")
    model.geom_contype[colliding] = planes[colliding].astype(model.geom_contype.dtype)
    model.geom_conaffinity[colliding] = (~planes[colliding]).astype(model.geom_conaffinity.dtype)


# C MuJoCo's mj_step resets the data to the model's rest pose (mj_resetData, then mj_forward) when an entry of qpos or
# qvel is NaN, infinite or beyond mjMAXVAL as it starts, or of qacc once forward has computed it, so Gymnasium's and
# EnvPool's physics never compute from a diverged state. MJX has no such check; the port makes it, so that one
# diverging env of thousands goes on as it would on the CPU backends instead of ending the run.
MAX_VALUE = 1e10  # mjMAXVAL
# What mjx.step reads of its Data (forward recomputes everything else), so a substep's reset replaces only these.
STEP_INPUTS = ("time", "qpos", "qvel", "act", "ctrl", "qacc_warmstart")


def physics_diverged(*arrays: jnp.ndarray) -> jnp.ndarray:
    """Whether any entry is NaN, infinite or beyond C MuJoCo's mjMAXVAL (its mju_isBad)."""
    return ~jnp.all(jnp.stack([jnp.all(jnp.abs(a) <= MAX_VALUE) for a in arrays]))


def _reset_where(diverged: jnp.ndarray, rest: Any, data: Any, fields: tuple[str, ...] | None = None) -> Any:
    if fields is None:
        return jax.tree.map(lambda r, d: jnp.where(diverged, r, d), rest, data)
    return data.replace(**{f: jnp.where(diverged, getattr(rest, f), getattr(data, f)) for f in fields})


def rest_data(mj_model: Any) -> Any:
    """The MjData that C MuJoCo's divergence reset leaves: mj_resetData, then mj_forward."""
    import mujoco

    data = mujoco.MjData(mj_model)
    mujoco.mj_forward(mj_model, data)
    return data


def _same_types(new: Any, old: Any) -> Any:
    # With 64-bit types on, MJX's step returns a few int32 index fields of its Data as int64.
    return jax.tree.map(lambda a, b: a.astype(b.dtype), new, old)


class MjxTaskEnv:
    """One env of a ported task: pure functions of an `mjx.Data`."""

    def __init__(
        self, env_id: str, solver_iterations: int = 0, solver_ls_iterations: int = 0, contacts: str = "all"
    ) -> None:
        """Nonzero solver settings replace the XML's (env.solver_iterations, env.solver_ls_iterations), and
        contacts `floor` keeps only the collisions with the floor (env.contacts)."""
        mjx = import_mjx()

        self.task = task = TASKS[env_id]
        self.mj_model = load_model(task, env_id)
        if solver_iterations:
            self.mj_model.opt.iterations = solver_iterations
        if solver_ls_iterations:
            self.mj_model.opt.ls_iterations = solver_ls_iterations
        if contacts == "floor":
            collide_with_floor_only(self.mj_model)
        self.model = mjx.put_model(self.mj_model, impl="jax")  # the port reads its internals
        self.dt = float(self.mj_model.opt.timestep) * task.frame_skip
        self._template = mjx.make_data(self.model, impl="jax")
        self._rest = _same_types(mjx.put_data(self.mj_model, rest_data(self.mj_model), impl="jax"), self._template)

    def from_state(self, qpos: jnp.ndarray, qvel: jnp.ndarray) -> tuple[Any, jnp.ndarray]:
        """The env set to (qpos, qvel) as Gymnasium's `set_state` does, and its observation. `mj_forward` there
        gives the observation and the next step's starting position body frames and com quantities; the step itself
        recomputes everything else."""
        mjx = import_mjx()

        model, dtype = self.model, self.model.qpos0.dtype
        qpos = jnp.asarray(qpos, dtype)
        data = self._template.replace(qpos=qpos, qvel=jnp.asarray(qvel, dtype))
        data = mjx.com_vel(model, mjx.com_pos(model, mjx.kinematics(model, data)))
        # MJX's kinematics writes free joints' quaternions back normalized; C MuJoCo leaves qpos as it was set, and
        # Gymnasium's first observation shows it so (its reset noise denormalizes them).
        data = data.replace(qpos=qpos)
        return data, self.task.observe(model, data).astype(jnp.float32)

    def reset(self, key: jax.Array) -> tuple[Any, jnp.ndarray]:
        """Gymnasium's reset noise around the model's initial pose."""
        model, scale = self.model, self.task.reset_noise_scale
        pos_key, vel_key = jax.random.split(key)
        dtype = model.qpos0.dtype
        qpos = model.qpos0 + jax.random.uniform(pos_key, (model.nq,), dtype, -scale, scale)
        if self.task.velocity_noise == NORMAL:
            qvel = scale * jax.random.normal(vel_key, (model.nv,), dtype)
        else:
            qvel = jax.random.uniform(vel_key, (model.nv,), dtype, -scale, scale)
        return self.from_state(qpos, qvel)

    def step(self, data: Any, action: jnp.ndarray) -> tuple[Any, jnp.ndarray, jnp.ndarray, jnp.ndarray, dict]:
        mjx = import_mjx()

        model, task = self.model, self.task
        action = action.astype(data.ctrl.dtype)
        before = task.progress(model, data)
        data = data.replace(ctrl=action)

        def substep(_: int, d: Any) -> Any:  # C MuJoCo checks qpos and qvel as each mj_step starts...
            d = _reset_where(physics_diverged(d.qpos, d.qvel), self._rest, d, STEP_INPUTS)
            d = _same_types(mjx.step(model, d), d)
            # ...and qacc before it integrates, which MJX's step does not stop for: the state it integrated from a bad
            # qacc is replaced, one substep later than C MuJoCo's reset (C integrates that substep from the rest pose)
            return _reset_where(physics_diverged(d.qacc), self._rest, d, STEP_INPUTS)

        with c_mujoco_collisions():
            data = jax.lax.fori_loop(0, task.frame_skip, substep, data)
        # The last substep's qacc reset, whole, since the observation reads the derived quantities. A qpos or qvel that
        # went bad in the last integration stays, as C MuJoCo returns it (Hopper then terminates), until the next step.
        data = _reset_where(physics_diverged(data.qacc), self._rest, data)
        if task.contact_forces:
            data = mjx.rne_postconstraint(model, data)
        velocity = (task.progress(model, data) - before) / self.dt
        reward, terminated, info = task.reward(model, data, action, velocity, self.dt)
        obs = task.observe(model, data).astype(jnp.float32)
        info = {k: jnp.asarray(info[k], jnp.float32) for k in task.info_keys}
        return data, obs, jnp.asarray(reward, jnp.float32), jnp.asarray(terminated, bool), info

    def functional(self) -> FunctionalEnv:
        low, high = self.mj_model.actuator_ctrlrange.T
        return FunctionalEnv(
            obs_dim=int(jax.eval_shape(self.reset, jax.random.PRNGKey(0))[1].shape[0]),
            act_dim=int(self.mj_model.nu),
            action_low=tuple(float(x) for x in low),
            action_high=tuple(float(x) for x in high),
            max_episode_steps=self.task.max_episode_steps,
            info_keys=self.task.info_keys,
            reset=self.reset,
            step=self.step,
        )


def functional_env(
    env_id: str, solver_iterations: int = 0, solver_ls_iterations: int = 0, contacts: str = "all"
) -> FunctionalEnv:
    """The task's env, built once per process, physics setting and precision: every env made for it (training, each
    evaluation) shares its model and compiled programs."""
    return _functional_env(env_id, solver_iterations, solver_ls_iterations, contacts, x64_enabled())


@functools.cache
def _functional_env(
    env_id: str, solver_iterations: int, solver_ls_iterations: int, contacts: str, x64: bool
) -> FunctionalEnv:
    return MjxTaskEnv(env_id, solver_iterations, solver_ls_iterations, contacts).functional()
