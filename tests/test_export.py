"""canter export: the ONNX file and the documented numpy forward pass compute canter's own policy."""

import inspect
import itertools
import re
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest

from canter.algos import ExportedActor
from canter.cli.main import main
from canter.errors import CanterError
from canter.use.export import format_for, npz_arrays, numpy_forward, onnx_bytes

DOC = Path(__file__).resolve().parents[1] / "docs" / "see-plots-export-report.md"


def doc_forward():
    """The numpy forward pass exactly as the docs show it, executed."""
    text = DOC.read_text()
    block = re.search(r"<!-- numpy-forward -->\n```python\n(.*?)```", text, re.S).group(1)
    namespace: dict = {}
    exec(block, namespace)
    return block, namespace["numpy_forward"]


def run_onnx(data: bytes, obs: np.ndarray) -> np.ndarray:
    session = ort.InferenceSession(data, providers=["CPUExecutionProvider"])
    return session.run(["action"], {"obs": obs.astype(np.float32)})[0]


def reference_actor(actor: ExportedActor, obs: np.ndarray) -> np.ndarray:
    """The ExportedActor contract, one observation at a time, in float64."""
    act = {"tanh": np.tanh, "relu": lambda v: max(v, 0.0), "elu": lambda v: v if v > 0 else np.exp(v) - 1}
    out = []
    for row in obs.astype(np.float64):
        x = list(row)
        if actor.normalize:
            x = [
                min(max((v - m) / np.sqrt(var + actor.obs_eps), -actor.clip_obs), actor.clip_obs)
                for v, m, var in zip(x, actor.obs_mean, actor.obs_var)
            ]
        for i, (w, b) in enumerate(zip(actor.weights, actor.biases)):
            x = [sum(x[k] * w[k, j] for k in range(len(x))) + b[j] for j in range(w.shape[1])]
            if i < len(actor.weights) - 1:
                x = [act[actor.activation](v) for v in x]
        x = x[: actor.output_slice]
        lo, hi = actor.action_low, actor.action_high
        if actor.squash:
            x = [lo[j] + (np.tanh(v) + 1) / 2 * (hi[j] - lo[j]) for j, v in enumerate(x)]
        out.append([min(max(v, lo[j]), hi[j]) for j, v in enumerate(x)])
    return np.array(out)


def hand_actor(seed, activation, squash, normalize, output_slice, sizes=(5, 8, 6, 4)):
    rng = np.random.default_rng(seed)
    return ExportedActor(
        weights=[rng.normal(size=(a, b)).astype(np.float32) for a, b in itertools.pairwise(sizes)],
        biases=[rng.normal(size=b).astype(np.float32) for b in sizes[1:]],
        activation=activation,
        squash=squash,
        normalize=normalize,
        obs_mean=rng.normal(size=sizes[0]).astype(np.float32),
        obs_var=rng.uniform(0.1, 4.0, size=sizes[0]).astype(np.float32),
        obs_eps=1e-8,
        clip_obs=2.5,
        action_low=np.array([-1.0, -0.5], np.float32)[:output_slice],
        action_high=np.array([1.0, 2.0], np.float32)[:output_slice],
        output_slice=output_slice,
    )


@pytest.mark.parametrize(
    "activation,squash,normalize",
    [("tanh", False, True), ("relu", True, True), ("elu", True, False), ("tanh", True, True)],
)
def test_hand_built_actor_onnx_and_numpy_match_the_contract(activation, squash, normalize):
    actor = hand_actor(1, activation, squash, normalize, output_slice=2)  # head has 4 outputs, 2 are actions
    obs = (np.random.default_rng(2).normal(size=(50, 5)) * 4).astype(np.float32)
    expected = reference_actor(actor, obs)
    got_onnx = run_onnx(onnx_bytes(actor), obs)
    _, forward = doc_forward()
    got_numpy = forward(npz_arrays(actor), obs)
    assert got_onnx.shape == got_numpy.shape == (50, 2)
    assert np.abs(got_onnx - expected).max() <= 1e-5
    assert np.abs(got_numpy - expected).max() <= 1e-5
    if not squash:
        # Both bounds are reached, so the final clip is exercised.
        assert (expected == actor.action_low).any() and (expected == actor.action_high).any()


def test_docs_quote_the_forward_pass_verbatim():
    block, _ = doc_forward()
    assert block == inspect.getsource(numpy_forward)


@pytest.mark.slow
def test_exported_run_matches_canter_load(tiny_run, tmp_path, capsys):
    import canter

    onnx_path, npz_path = tmp_path / "policy.onnx", tmp_path / "policy.npz"
    assert main(["export", str(tiny_run.run_dir), "--out", str(onnx_path)]) == 0
    assert main(["export", str(tiny_run.run_dir), "--format", "npz", "--out", str(npz_path)]) == 0
    assert "wrote" in capsys.readouterr().out

    policy = canter.load(tiny_run.run_dir)
    stats = policy.obs_stats
    rng = np.random.default_rng(0)
    # Around the normalizer's mean, and far outside it so that the observation clip is exercised too.
    obs = (
        np.asarray(stats.mean)
        + rng.normal(size=(256, policy.obs_dim))
        * np.sqrt(np.asarray(stats.var))
        * np.repeat([[1.0], [30.0]], 128, axis=0)
    ).astype(np.float32)
    expected = policy(obs)
    got = run_onnx(onnx_path.read_bytes(), obs)
    assert got.shape == expected.shape and np.abs(got - expected).max() <= 1e-5

    _, forward = doc_forward()
    with np.load(npz_path) as arrays:
        assert str(arrays["meta_env_id"]) == "Pendulum-v1"
        assert np.abs(forward(arrays, obs) - expected).max() <= 1e-5

    import onnx

    model = onnx.load(onnx_path)
    assert model.opset_import[0].version == 17
    assert {p.key: p.value for p in model.metadata_props}["env_id"] == "Pendulum-v1"


@pytest.mark.slow
def test_export_bad_input(tiny_run, tmp_path, capsys):
    empty = tmp_path / "run_without_checkpoint"
    empty.mkdir()
    assert main(["export", str(empty), "--out", str(tmp_path / "p.onnx")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no checkpoint" in err

    assert main(["export", str(tiny_run.run_dir), "--out", str(tmp_path / "p.bin")]) == 2
    assert "--format" in capsys.readouterr().err

    blocker = tmp_path / "a_file"
    blocker.write_text("")
    assert main(["export", str(tiny_run.run_dir), "--out", str(blocker / "p.onnx")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot write" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "run_without_checkpoint"]


@pytest.mark.slow
def test_export_of_a_run_state_with_large_actions_matches_the_policy(tiny_run):
    """The trained tiny actor's outputs are near zero; with larger weights the policy's action clip is reached,
    and the export must clip the same way."""
    import jax

    from canter.algos import get_algorithm
    from canter.training.restore import load_state
    from canter.use.policy import Policy

    config, facts, state, _ = load_state(tiny_run.run_dir)
    rng = np.random.default_rng(3)
    actor = [
        {
            "w": (rng.normal(size=np.shape(layer["w"])) * 2).astype(np.float32),
            "b": rng.normal(size=np.shape(layer["b"])).astype(np.float32),
        }
        for layer in state.params["actor"]
    ]
    state = state._replace(params=dict(state.params, actor=actor))
    algorithm = get_algorithm(config.run.algo)
    policy = Policy(
        config, facts, jax.device_put(algorithm.policy_params(state)), jax.device_put(state.obs_stats), tiny_run.run_dir
    )
    obs = (rng.normal(size=(300, facts.obs_dim)) * 3).astype(np.float32)
    expected = policy(obs)
    assert (expected == facts.action_low).any() and (expected == facts.action_high).any()
    assert ((expected > facts.action_low) & (expected < facts.action_high)).any()
    exported = algorithm.export_actor(config, state, facts)
    assert np.abs(run_onnx(onnx_bytes(exported), obs) - expected).max() <= 1e-5
    _, forward = doc_forward()
    assert np.abs(forward(npz_arrays(exported), obs) - expected).max() <= 1e-5


def test_the_format_and_the_file_name_must_agree():
    assert format_for("p.onnx", None) == "onnx" and format_for("p.NPZ", None) == "npz"
    assert format_for("policy", "npz") == "npz" and format_for("p.npz", "npz") == "npz"
    with pytest.raises(
        CanterError, match=re.escape("--format npz would write p2.onnx, whose name says onnx; name it .npz")
    ):
        format_for("p2.onnx", "npz")
    with pytest.raises(CanterError, match=re.escape("cannot tell the export format of p.bin")):
        format_for("p.bin", None)
