"""The brax backend: Brax's own envs behind canter's `VecEnv` protocol, its names, its episode semantics on a real Brax
env, and the rule that a run trained on it evaluates on it only."""

import dataclasses
import re
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from canter.envs.functional import FunctionalVecEnv, initial_keys
from canter.envs.registry import get_backend, resolve_backend
from canter.errors import CanterError
from canter.training.restore import PolicyFacts
from canter.use.evaluate import check_eval_env

BRAX = get_backend("brax")
needs_brax = pytest.mark.skipif(not BRAX.available(), reason="brax is not installed here")


def test_importing_the_backend_imports_no_brax():
    """The config reference and --backend's choices import every backend package; that must stay cheap."""
    script = (
        "import sys\n"
        "from canter.envs.registry import get_backend\n"
        "backend = get_backend('brax')\n"
        "print(backend.label, backend.jax_native, backend.own_observations)\n"
        "print(sorted(m for m in ('brax', 'mujoco', 'jax') if m in sys.modules))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split("\n")[:2] == ["Brax True True", "[]"]


@needs_brax
def test_names_are_brax_own_and_only_those_on_mjx():
    from canter.envs.brax.env import LEFT_OUT, brax_envs

    ids = BRAX.supported_ids()
    assert {"ant", "humanoid", "hopper", "halfcheetah", "walker2d", "humanoidstandup"} <= set(ids)
    assert set(ids) | set(LEFT_OUT) == set(brax_envs()._envs)
    assert not set(ids) & set(LEFT_OUT)
    assert resolve_backend("ant", "brax") == "brax"
    # The names known without brax, which the error where it is missing names its extra for.
    assert BRAX.installable_ids == tuple(ids)


@needs_brax
@pytest.mark.parametrize("env_id", ["Ant-v5", "antt", "swimmer"])
def test_an_unknown_brax_name_lists_brax_names(env_id):
    with pytest.raises(CanterError) as caught:
        resolve_backend(env_id, "brax")
    message = str(caught.value)
    assert "\n" not in message and env_id in message
    assert all(name in message for name in BRAX.supported_ids())


def _facts(env_id: str, backend: str) -> PolicyFacts:
    return PolicyFacts(env_id, backend, 27, 8, -np.ones(8, np.float32), np.ones(8, np.float32), 1000)


def test_a_brax_run_evaluates_on_brax_and_its_own_env_only():
    facts = _facts("ant", "brax")
    for env_id, backend in [(None, None), ("ant", None), (None, "brax"), ("ant", "brax")]:
        check_eval_env(facts, env_id, backend)
    for env_id, backend, varied, flags in [
        (None, "mjx", False, "--backend mjx (backend=)"),
        (None, "auto", False, "--backend auto (backend=)"),
        ("Ant-v5", None, False, "--env Ant-v5 (env_id=)"),
        ("Ant-v5", "envpool", False, "--env Ant-v5 (env_id=) and --backend envpool (backend=)"),
        (None, None, True, "--vary"),
    ]:
        expected = f"Brax observations differ from Gymnasium's.*; drop {re.escape(flags)}$"
        with pytest.raises(CanterError, match=expected):
            check_eval_env(facts, env_id, backend, varied)


def test_runs_of_other_backends_evaluate_anywhere_but_on_brax():
    check_eval_env(_facts("Ant-v5", "envpool"), "Ant-v4", "gymnasium", varied=True)
    for trained_on in ("envpool", "mjx"):
        refused = (
            f"Brax observations differ from Gymnasium's, so a run trained on {trained_on} (Ant-v5) does not evaluate "
            f"on brax; drop --backend brax (backend= for evaluate)"
        )
        with pytest.raises(CanterError, match=f"^{re.escape(refused)}$"):
            check_eval_env(_facts("Ant-v5", trained_on), None, "brax")


@pytest.fixture
def float32_jax():
    """JAX set up as for a Brax run (float32), then back as the rest of the suite has it."""
    from canter.core.runtime import setup_jax

    setup_jax("brax")
    yield
    setup_jax()


@pytest.mark.slow
@needs_brax
@pytest.mark.usefixtures("float32_jax")
def test_a_real_brax_env_steps_as_brax_with_envpool_episode_semantics():
    """InvertedPendulum (the cheapest Brax model to compile) with a short step limit: env 0 pushes hard and falls
    (termination), env 1 stays up until the limit (truncation). Until its episode ends each env gives exactly what
    Brax's own env gives; the step after an end is an autoreset step."""
    from canter.envs.brax.env import functional_env, load_env

    limit, steps = 8, 12
    env = dataclasses.replace(functional_env("inverted_pendulum"), max_episode_steps=limit)
    vec = FunctionalVecEnv(env, "inverted_pendulum", "brax", 2, [3, 4])
    assert (vec.spec.obs_dim, vec.spec.act_dim, vec.spec.info_keys) == (4, 1, ())
    actions = jnp.array([[1.0], [0.0]], jnp.float32)

    @jax.jit
    def run(state):
        return jax.lax.scan(lambda s, _: vec.jax_step(s, actions), state, None, length=steps)

    _, out = run(vec.initial_state())
    out = jax.tree.map(np.asarray, out)
    assert out.obs.shape == (steps, 2, 4) and out.obs.dtype == np.float32 and out.reward.dtype == np.float32

    # Brax's own env, from the same reset keys, with the same actions, in one compiled program.
    brax_env = load_env("inverted_pendulum")

    @jax.jit
    def brax_run(keys):
        first = jax.vmap(brax_env.reset)(keys)

        def body(state, _):
            state = jax.vmap(brax_env.step)(state, actions)
            return state, (state.obs, state.reward, state.done > 0.5)

        return first.obs, jax.lax.scan(body, first, None, length=limit)[1]

    first_obs, (brax_obs, brax_reward, brax_done) = jax.tree.map(
        np.asarray, brax_run(jax.vmap(jax.random.split)(initial_keys([3, 4]))[:, 1])
    )
    assert np.array_equal(first_obs, vec.reset())

    fell = int(np.argmax(brax_done[:, 0]))
    assert brax_done[fell, 0] and 0 < fell < limit - 2, "env 0 must fall well before the limit"
    assert not brax_done[:, 1].any(), "env 1 must stay up until the limit"
    for env_index, last in [(0, fell), (1, limit - 1)]:
        for t in range(last + 1):
            np.testing.assert_allclose(out.obs[t, env_index], brax_obs[t, env_index], rtol=1e-5, atol=1e-6)
            np.testing.assert_allclose(out.reward[t, env_index], brax_reward[t, env_index], rtol=1e-5, atol=1e-6)
        ended = out.terminated[: last + 1, env_index] | out.truncated[: last + 1, env_index]
        assert ended.tolist() == [False] * last + [True]
        assert out.terminated[last, env_index] == (env_index == 0)
        assert out.truncated[last, env_index] == (env_index == 1)
        # The autoreset step: action ignored, reward 0, flags false, a fresh observation near the upright pose.
        assert out.reward[last + 1, env_index] == 0.0
        assert not out.terminated[last + 1, env_index] and not out.truncated[last + 1, env_index]
        assert np.abs(out.obs[last + 1, env_index]).max() < 0.02 < np.abs(out.obs[last, env_index]).max()
        # Then the new episode steps: InvertedPendulum's reward is 1 per step alive.
        assert out.reward[last + 2, env_index] == 1.0 and not out.terminated[last + 2, env_index]
