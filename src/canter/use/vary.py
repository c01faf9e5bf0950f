"""Robustness sweeps: scale one physical parameter of a MuJoCo model and evaluate the policy at each scale.

A spec reads `PARAM[:NAME]=S1,S2,...`, e.g. `body_mass:torso=0.5,1,1.5`. Every scale is applied to the value the
freshly built model had (never to an already scaled one), and the model's derived constants are recomputed with
`mj_setConst`, so that, for example, a heavier torso also has a heavier subtree and a new mass matrix at qpos0.

A scale can make the physics diverge (gravity scaled by 1e30). MuJoCo then resets the state in the middle of the
episode and goes on, and the step that diverged can earn a reward of 1e37; such a point is marked unstable, with
the number of MuJoCo's warnings, and left out of the tables' returns and the plot.
"""

from __future__ import annotations

import math
import re
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from canter.errors import CanterError


@dataclass(frozen=True)
class Param:
    field: str  # mjModel array that is scaled
    kind: str | None  # the named MuJoCo object it is indexed by (None: one global value)
    label: str  # for tables and plot axes
    unit: str


PARAMS: dict[str, Param] = {
    "body_mass": Param("body_mass", "body", "mass", "kg"),
    "geom_friction": Param("geom_friction", "geom", "friction (sliding, torsional, rolling)", ""),
    "actuator_gear": Param("actuator_gear", "actuator", "actuator gear", ""),
    "gravity": Param("opt.gravity", None, "gravity", "m/s²"),
}

_OBJ_TYPES = {"body": "mjOBJ_BODY", "geom": "mjOBJ_GEOM", "actuator": "mjOBJ_ACTUATOR"}
_COUNTS = {"body": "nbody", "geom": "ngeom", "actuator": "nu"}


@dataclass(frozen=True)
class VarySpec:
    param: str  # a key of PARAMS
    name: str | None  # body/geom/actuator name; None scales every one of them
    scales: tuple[float, ...]

    @property
    def text(self) -> str:
        target = f":{self.name}" if self.name else ""
        return f"{self.param}{target}=" + ",".join(f"{s:g}" for s in self.scales)

    @property
    def slug(self) -> str:
        """A file name for this sweep: only letters, digits, '-', '_' and '.'."""
        target = f"_{self.name}" if self.name else ""
        return re.sub(r"[^A-Za-z0-9_.-]+", "-", f"{self.param}{target}")

    @property
    def axis_label(self) -> str:
        param = PARAMS[self.param]
        if param.kind is None:
            return f"{param.label} scale"
        return f"{self.name} {param.label} scale" if self.name else f"{param.label} scale (every {param.kind})"


def parse_spec(text: str) -> VarySpec:
    """Parse `PARAM[:NAME]=S1,S2,...`; scales must be finite and > 0 (a zero mass or gear is not a model)."""
    head, eq, values = text.partition("=")
    if not eq or not values.strip():
        raise CanterError(f"--vary {text!r}: expected PARAM[:NAME]=S1,S2,..., e.g. body_mass:torso=0.5,1,1.5")
    param, _, name = head.strip().partition(":")
    if param not in PARAMS:
        raise CanterError(f"--vary: unknown parameter {param!r}; valid: {', '.join(PARAMS)}")
    if name and PARAMS[param].kind is None:
        raise CanterError(f"--vary: {param} takes no name (it scales the whole vector); drop ':{name}'")
    scales = []
    for item in values.split(","):
        try:
            scale = float(item)
        except ValueError:
            raise CanterError(f"--vary {text!r}: {item.strip()!r} is not a number") from None
        if not math.isfinite(scale) or scale <= 0:
            raise CanterError(f"--vary {text!r}: scales must be finite and > 0, got {item.strip()}")
        if scale in scales:  # it would play the same episodes again and show one point twice
            raise CanterError(f"--vary {text!r}: scale {item.strip()} is given twice; give each scale once")
        scales.append(scale)
    return VarySpec(param, name or None, tuple(scales))


def object_names(model: Any, kind: str) -> list[str]:
    """Names by index. Unnamed actuators (Gymnasium's Hopper has them) go by the joint they drive; any other unnamed
    object by `#index`."""
    import mujoco

    obj = getattr(mujoco.mjtObj, _OBJ_TYPES[kind])
    names = []
    for i in range(getattr(model, _COUNTS[kind])):
        name = mujoco.mj_id2name(model, obj, i)
        if not name and kind == "actuator" and model.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_JOINT:
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, int(model.actuator_trnid[i, 0]))
        names.append(name or f"#{i}")
    return names


def target_index(model: Any, spec: VarySpec) -> slice | int:
    """Row(s) of the parameter's array that the spec scales; a one-line error listing valid names if unknown."""
    kind = PARAMS[spec.param].kind
    if kind is None or spec.name is None:
        return slice(None)
    names = object_names(model, kind)
    if spec.name not in names:
        raise CanterError(
            f"--vary: no {kind} named {spec.name!r} in this model; valid {kind} names: {', '.join(names)}"
        )
    return names.index(spec.name)


def _array(model: Any, field: str) -> np.ndarray:
    obj = model
    for part in field.split("."):
        obj = getattr(obj, part)
    return obj


def original_value(model: Any, spec: VarySpec) -> np.ndarray:
    return np.array(_array(model, PARAMS[spec.param].field)[target_index(model, spec)], copy=True)


def apply_scale(model: Any, data: Any, spec: VarySpec, scale: float) -> None:
    """Scale the spec's parameter of a freshly built `model` in place and recompute the derived constants."""
    import mujoco

    index = target_index(model, spec)
    array = _array(model, PARAMS[spec.param].field)
    array[index] = array[index] * scale
    # Masses feed body_subtreemass, the inertia at qpos0 and actuator_acc0; gears feed actuator_length0/acc0.
    mujoco.mj_setConst(model, data)


def mujoco_handles(env: Any, env_id: str) -> tuple[Any, Any]:
    """(model, data) of a Gymnasium MuJoCo env, or a one-line error for other envs."""
    inner = getattr(env, "unwrapped", env)
    model, data = getattr(inner, "model", None), getattr(inner, "data", None)
    if model is None or data is None or not hasattr(model, "body_mass"):
        raise CanterError(f"--vary needs a Gymnasium MuJoCo env with env.unwrapped.model; {env_id} has none")
    return model, data


def check_spec(env_id: str, spec: VarySpec) -> np.ndarray:
    """Build one env, check the names in the spec and return the original value (shown in tables and plots)."""
    env = _make_gymnasium(env_id)
    try:
        model, _ = mujoco_handles(env, env_id)
        original = original_value(model, spec)
    finally:
        env.close()
    check_scaled_values(spec, original)
    return original


def check_scaled_values(spec: VarySpec, original: np.ndarray) -> None:
    """Each scaled value must be a float64: past about 1.8e308 it is inf, which MuJoCo cannot simulate and the
    sweep's JSON cannot hold."""
    for scale in spec.scales:
        with np.errstate(over="ignore"):
            scaled = original * scale
        if not np.all(np.isfinite(scaled)):
            raise CanterError(
                f"--vary {spec.text!r}: scale {scale:g} takes {spec.param} past the largest number a float holds "
                f"(about 1.8e308); give a smaller scale"
            )


def _make_gymnasium(env_id: str) -> Any:
    from canter.envs.registry import held_only_elsewhere, resolve_backend, single_env_backend

    backend = single_env_backend()
    try:
        resolve_backend(env_id, backend.name)
    except CanterError:
        raise CanterError(
            f"--vary edits the MuJoCo model of {env_id} in {backend.label}, which has no such env "
            f"({held_only_elsewhere(env_id)}); drop --vary, which varies only {backend.label}'s envs"
        ) from None
    from canter.use.evaluate import refuse_mujoco_py_sweep

    refuse_mujoco_py_sweep(env_id)
    return backend.make_single(env_id)


# The text of MuJoCo's warnings for a NaN, Inf or huge qpos, qvel or qacc, after which it resets the state.
_UNSTABLE = "The simulation is unstable"
_OUT_OF_SPACE = r".*returned by the `step\(\)` method is not within the observation space"


@contextmanager
def counting_instabilities() -> Iterator[list[str]]:
    """MuJoCo's instability warnings while the block runs, collected (not printed) in the list it yields; any other
    warning goes where it went before. numpy's overflow warnings, and Gymnasium's that an observation is outside
    its space, are silenced meanwhile: the float64 state of a diverging model overflows the float32 observations,
    and the point is marked unstable already."""
    import mujoco

    previous = mujoco.get_mju_user_warning()
    unstable: list[str] = []

    def warn(text: str) -> None:
        if _UNSTABLE in text:
            unstable.append(text)
        elif previous is not None:
            previous(text)
        else:
            print(f"MuJoCo warning: {text}", file=sys.stderr)

    mujoco.set_mju_user_warning(warn)
    try:
        with np.errstate(over="ignore"), warnings.catch_warnings():
            # Gymnasium's env checker's word for the same divergence, seen in the observations it leaves behind
            warnings.filterwarnings("ignore", message=_OUT_OF_SPACE, category=UserWarning)
            yield unstable
    finally:
        mujoco.set_mju_user_warning(previous)


def is_unstable(point: dict[str, Any]) -> bool:
    return bool(point.get("unstable_warnings"))


def sweep(
    policy: Any, spec: VarySpec, episodes: int, deterministic: bool, seed: int, env_id: str | None = None
) -> list[dict[str, Any]]:
    """Evaluate `policy` at every scale on fresh Gymnasium envs; one summary dict per scale, with the number of times
    MuJoCo warned of diverged physics (`unstable_warnings`, at most one per episode and kind until the
    state is reset; a point with any has no meaningful return)."""
    from canter.use.evaluate import evaluate

    env_id = env_id or policy.facts.env_id
    original = check_spec(env_id, spec)
    points = []
    for scale in spec.scales:

        def prepare(env: Any, scale: float = scale) -> None:
            model, data = mujoco_handles(env, env_id)
            apply_scale(model, data, spec, scale)

        with counting_instabilities() as unstable:
            result = evaluate(
                policy, episodes=episodes, deterministic=deterministic, seed=seed, env_id=env_id, prepare_env=prepare
            )
        value = original * scale
        points.append(dict(scale=scale, value=value.tolist(), unstable_warnings=len(unstable), **result.summary()))
    return points


def plot(series: list[tuple[str, list[dict[str, Any]]]], spec: VarySpec, original: np.ndarray, env_id: str) -> bytes:
    """PNG of return mean ± std against the scale, one line per (label, points)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=120)
    try:
        for label, points in series:
            stable = [p for p in points if not is_unstable(p)]
            x = np.array([p["scale"] for p in stable])
            mean = np.array([p["return_mean"] for p in stable])
            std = np.array([p["return_std"] for p in stable])
            left_out = [f"{p['scale']:g}" for p in points if is_unstable(p)]
            if left_out:
                label += f" (unstable physics at {', '.join(left_out)}: not shown)"
            (line,) = ax.plot(x, mean, marker="o", label=label)
            ax.fill_between(x, mean - std, mean + std, color=line.get_color(), alpha=0.2)
        ax.axvline(1.0, color="grey", lw=0.8, ls="--")
        param = PARAMS[spec.param]
        base = ""
        if np.size(original) == 1:
            base = f" (1 = {float(np.ravel(original)[0]):.4g}{' ' + param.unit if param.unit else ''})"
        ax.set_xlabel(spec.axis_label + base)
        ax.set_ylabel(f"episode return (mean ± std, {series[0][1][0]['episodes']} episodes)")
        ax.set_title(f"{env_id}: return against {spec.param}{':' + spec.name if spec.name else ''}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png")
        return buffer.getvalue()
    finally:
        plt.close(fig)
