"""Export a run's deterministic policy as a standalone file: ONNX, or plain numpy arrays (npz).

Both are built from the algorithm record's `export_actor(config, state, spec) -> ExportedActor`, so they compute
exactly what `canter.load(run)(obs)` computes: frozen observation normalization, the actor MLP, the optional tanh
squash onto the action bounds, and the final clip to the bounds. Everything is float32.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from canter.algos import ExportedActor
from canter.errors import CanterError

# Opset 17 (IR version 8) is read by every onnxruntime since 1.13 and by most other ONNX consumers.
ONNX_OPSET = 17
ONNX_IR_VERSION = 8
# Keyed by netconfig.ACTIVATIONS, as is the table inside numpy_forward, which must stand alone for the docs.
ONNX_ACTIVATIONS = {"tanh": "Tanh", "relu": "Relu", "elu": "Elu"}


def load_actor(run_dir: str | Path, checkpoint: str | Path) -> tuple[ExportedActor, dict[str, str]]:
    """The exported actor of a run's checkpoint (`last`, `best` or a file), and facts about it for the file's
    metadata."""
    from canter import __version__
    from canter.algos import get_algorithm
    from canter.training.checkpoint import BEST, LAST
    from canter.training.restore import load_state

    config, facts, state, _ = load_state(Path(run_dir), checkpoint, policy_only=True)
    actor = get_algorithm(config.run.algo).export_actor(config, state, facts)
    meta = {
        "producer": f"canter {__version__}",
        "env_id": facts.env_id,
        "algo": config.run.algo,
        "checkpoint": checkpoint if checkpoint in (LAST, BEST) else Path(checkpoint).name,
        "global_step": str(facts.global_step),
        "obs_dim": str(facts.obs_dim),
        "act_dim": str(facts.act_dim),
    }
    return actor, meta


def format_for(path: str | Path, requested: str | None) -> str:
    suffix = Path(path).suffix.lower().lstrip(".")
    if requested:
        if requested not in FORMATS:
            raise CanterError(f"--format must be one of {', '.join(FORMATS)}, got {requested!r}")
        if suffix in FORMATS and suffix != requested:
            raise CanterError(
                f"--format {requested} would write {path}, whose name says {suffix}; name it .{requested}, or drop "
                f"--format"
            )
        return requested
    if suffix not in FORMATS:
        passes = " or ".join(f"--format {name}" for name in FORMATS)
        raise CanterError(f"cannot tell the export format of {path}; pass {passes}")
    return suffix


# ---------------------------------------------------------------------------------------------------------- npz


def npz_arrays(actor: ExportedActor, meta: Mapping[str, str] | None = None) -> dict[str, np.ndarray]:
    """The flat arrays of an npz export: w0, b0, w1, b1, ... (w is [inputs, outputs]), the normalizer, the bounds
    and the switches; `meta_<name>` strings describe where the policy came from."""
    arrays: dict[str, np.ndarray] = {}
    for i, (w, b) in enumerate(zip(actor.weights, actor.biases)):
        arrays[f"w{i}"] = np.asarray(w, np.float32)
        arrays[f"b{i}"] = np.asarray(b, np.float32)
    arrays.update(
        num_layers=np.asarray(len(actor.weights)),
        activation=np.asarray(actor.activation),
        normalize=np.asarray(actor.normalize),
        obs_mean=np.asarray(actor.obs_mean, np.float32),
        obs_var=np.asarray(actor.obs_var, np.float32),
        obs_eps=np.asarray(actor.obs_eps, np.float32),
        clip_obs=np.asarray(actor.clip_obs, np.float32),
        output_slice=np.asarray(actor.output_slice),
        squash=np.asarray(actor.squash),
        action_low=np.asarray(actor.action_low, np.float32),
        action_high=np.asarray(actor.action_high, np.float32),
    )
    for key, value in (meta or {}).items():
        arrays[f"meta_{key}"] = np.asarray(value)
    return arrays


def npz_bytes(actor: ExportedActor, meta: Mapping[str, str] | None = None) -> bytes:
    buffer = io.BytesIO()
    # numpy's stub lets **kwds of arrays also fill its `allow_pickle: bool`, so any dict of arrays is refused.
    np.savez(buffer, **npz_arrays(actor, meta))  # type: ignore[arg-type]
    return buffer.getvalue()


# The docs quote this function verbatim (tests/test_export.py checks that they match and runs the quoted code).
def numpy_forward(p, obs):
    """Deterministic action for a batch of observations, from the arrays of `np.load("policy.npz")`."""
    import numpy as np

    x = np.asarray(obs, np.float32)
    if p["normalize"]:
        std = np.sqrt(p["obs_var"] + p["obs_eps"])
        x = np.clip((x - p["obs_mean"]) / std, -p["clip_obs"], p["clip_obs"])
    activation = {
        "tanh": lambda v: np.tanh(v),
        "relu": lambda v: np.maximum(v, 0),
        "elu": lambda v: np.where(v > 0, v, np.expm1(v)),
    }[str(p["activation"])]
    n = int(p["num_layers"])
    for i in range(n):
        x = x @ p[f"w{i}"] + p[f"b{i}"]
        if i < n - 1:
            x = activation(x)
    x = x[..., : int(p["output_slice"])]
    low, high = p["action_low"], p["action_high"]
    if p["squash"]:
        x = (high + low) / 2 + (high - low) / 2 * np.tanh(x)
    return np.clip(x, low, high)


# --------------------------------------------------------------------------------------------------------- onnx


def onnx_model(actor: ExportedActor, meta: Mapping[str, str] | None = None) -> Any:
    """An ONNX model with input `obs` [batch, obs_dim] float32 and output `action` [batch, act_dim] float32."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    if actor.activation not in ONNX_ACTIVATIONS:
        raise CanterError(
            f"cannot export activation '{actor.activation}' to ONNX; supported: {', '.join(ONNX_ACTIVATIONS)}"
        )
    obs_dim = int(np.shape(actor.weights[0])[0])
    act_dim = int(actor.output_slice)
    nodes, inits = [], []

    def const(name: str, value: Any) -> str:
        inits.append(numpy_helper.from_array(np.asarray(value, np.float32), name))
        return name

    def node(op: str, inputs: list[str], output: str, **attrs: Any) -> str:
        nodes.append(helper.make_node(op, inputs, [output], name=output, **attrs))
        return output

    x = "obs"
    if actor.normalize:
        # Divide by the same float32 sqrt(var + eps) that canter computes, rather than multiply by a reciprocal.
        std = np.sqrt(np.asarray(actor.obs_var, np.float32) + np.float32(actor.obs_eps))
        x = node("Sub", [x, const("obs_mean", actor.obs_mean)], "obs_centered")
        x = node("Div", [x, const("obs_std", std)], "obs_scaled")
        x = node(
            "Clip",
            [x, const("clip_obs_low", -actor.clip_obs), const("clip_obs_high", actor.clip_obs)],
            "obs_normalized",
        )
    last = len(actor.weights) - 1
    for i, (w, b) in enumerate(zip(actor.weights, actor.biases)):
        x = node("MatMul", [x, const(f"w{i}", w)], f"matmul{i}")
        x = node("Add", [x, const(f"b{i}", b)], f"dense{i}")
        if i < last:
            x = node(ONNX_ACTIVATIONS[actor.activation], [x], f"hidden{i}")
    if act_dim != int(np.shape(actor.weights[-1])[1]):
        inits += [
            numpy_helper.from_array(np.array([0], np.int64), "slice_start"),
            numpy_helper.from_array(np.array([act_dim], np.int64), "slice_end"),
            numpy_helper.from_array(np.array([1], np.int64), "slice_axis"),
        ]
        x = node("Slice", [x, "slice_start", "slice_end", "slice_axis"], "action_mean")
    low = np.asarray(actor.action_low, np.float32)
    high = np.asarray(actor.action_high, np.float32)
    if actor.squash:
        x = node("Tanh", [x], "squashed")
        x = node("Mul", [x, const("action_half_range", (high - low) / 2)], "squashed_scaled")
        x = node("Add", [x, const("action_center", (high + low) / 2)], "squashed_action")
    # Clip takes scalar bounds only; per-dimension bounds need Max then Min.
    x = node("Max", [x, const("action_low", low)], "action_above_low")
    node("Min", [x, const("action_high", high)], "action")

    graph = helper.make_graph(
        nodes,
        "canter_policy",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", obs_dim])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", act_dim])],
        initializer=inits,
    )
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", ONNX_OPSET)],
        producer_name="canter",
        doc_string="Deterministic policy: obs -> action",
    )
    model.ir_version = ONNX_IR_VERSION
    helper.set_model_props(model, dict(meta or {}))
    onnx.checker.check_model(model, full_check=True)
    return model


def onnx_bytes(actor: ExportedActor, meta: Mapping[str, str] | None = None) -> bytes:
    return onnx_model(actor, meta).SerializeToString()


# Each format's writer, keyed by the name that --format and the file's extension give.
FORMATS: dict[str, Callable[[ExportedActor, Mapping[str, str] | None], bytes]] = {"onnx": onnx_bytes, "npz": npz_bytes}


def export_bytes(run_dir: str | Path, fmt: str, checkpoint: str | Path) -> bytes:
    actor, meta = load_actor(run_dir, checkpoint)
    return FORMATS[fmt](actor, meta)
