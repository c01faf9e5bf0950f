"""The env backend registry: every registered backend works behind the protocol, `auto` follows registry order, and
backend names are spelled only in the registry and the backends' own packages."""

import ast
import functools
import re
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from canter.core.runtime import setup_jax
from canter.envs import registry
from canter.envs.registry import (
    backend_choices,
    backend_names,
    backends,
    describe_backend_choices,
    get_backend,
    make_vec_env,
    resolve_backend,
    single_env_backend,
)
from canter.errors import CanterError

SRC = Path(registry.__file__).resolve().parents[1]


# The cheapest id to compile of each backend that has one (JAX-native backends compile their physics).
CHEAP_IDS = ("Pendulum-v1", "InvertedPendulum-v5", "inverted_pendulum")


def _smoke_id(backend) -> str:
    ids = backend.supported_ids()
    return next((env_id for env_id in CHEAP_IDS if env_id in ids), sorted(ids)[0])


@pytest.fixture
def jax_as_a_run_sets_it(name):
    """JAX in the precision a run on the backend has (float32 for a JAX-native one), then back as the rest of the
    suite has it. The JAX-native envs then compile the programs that their own tests compile for 2 envs, which the
    session's compile cache (conftest.py) keeps for them."""
    setup_jax(name)
    yield
    setup_jax()


# Every registered backend; a JAX-native one compiles its physics twice (reset, host step): slow on the CPU.
EVERY_BACKEND = [
    pytest.param(name, marks=pytest.mark.slow) if get_backend(name).jax_native else name for name in backend_names()
]


@pytest.mark.parametrize("name", EVERY_BACKEND)
@pytest.mark.usefixtures("jax_as_a_run_sets_it")
def test_every_backend_makes_resets_steps_and_closes(name):
    backend = get_backend(name)
    if not backend.available():
        pytest.skip(f"{backend.label} is not installed here")
    env = make_vec_env(_smoke_id(backend), name, 2, [1, 2])
    try:
        spec = env.spec
        assert spec.backend == name and spec.num_envs == 2 and spec.obs_dim > 0 and spec.act_dim > 0
        assert len(spec.action_low) == len(spec.action_high) == spec.act_dim
        obs = env.reset()
        assert obs.shape == (2, spec.obs_dim) and obs.dtype == np.float32
        for _ in range(3):
            out = env.host_step(np.zeros((2, spec.act_dim), np.float32))
            assert out.obs.shape == (2, spec.obs_dim) and out.reward.shape == (2,)
            assert set(out.info) == set(spec.info_keys)

        def run(state):
            def body(state, _):
                return env.jax_step(state, jnp.zeros((2, spec.act_dim), jnp.float32))

            return jax.lax.scan(body, state, None, length=3)

        # A JAX-native env's host_step is its jax_step, compiled and run above: in a scan, what is new is that its
        # state carries from step to step (the same types), which tracing checks without compiling the physics again.
        # EnvPool's jax_step is a custom call of its own, so it is compiled and run.
        scan = functools.partial(jax.eval_shape, run) if backend.jax_native else jax.jit(run)
        _, out = scan(env.initial_state())
        assert out.obs.shape == (3, 2, spec.obs_dim) and out.terminated.dtype == jnp.bool_
    finally:
        env.close()


@pytest.mark.parametrize("name", EVERY_BACKEND)
@pytest.mark.usefixtures("jax_as_a_run_sets_it")
def test_every_backend_autoresets_as_envpool_does(name):
    """The step after an episode ends, by termination or by its step limit, is the reset: the new episode's first
    observation, reward 0 and both flags false (the protocol's EnvPool semantics, which returns and GAE rely on)."""
    backend = get_backend(name)
    if not backend.available():
        pytest.skip(f"{backend.label} is not installed here")
    env = make_vec_env(_smoke_id(backend), name, 1, [5])
    try:
        spec = env.spec
        action = np.asarray(spec.action_high, np.float32)[None]  # topples what can fall; Pendulum runs to its limit
        env.reset()
        for _ in range(spec.max_episode_steps or 1000):
            last = env.host_step(action)
            if last.terminated[0] or last.truncated[0]:
                break
        else:
            pytest.fail(f"no episode of {spec.id} ended within {spec.max_episode_steps or 1000} steps")
        reset = env.host_step(action)
        assert reset.reward[0] == 0.0 and not reset.terminated[0] and not reset.truncated[0]
        assert not np.allclose(reset.obs[0], last.obs[0])
    finally:
        env.close()


def test_registry_lines_name_their_backends(monkeypatch):
    """The names come from the registry's lines alone, so a backend added there is named without a change here."""
    assert backend_choices() == ("auto", *backend_names())
    for name in backend_names():
        assert get_backend(name).name == name and get_backend(name).label
    assert sum(backend.custom_ids for backend in backends()) >= 1
    assert single_env_backend().single_envs
    monkeypatch.setattr(registry, "_BACKENDS", {"envpool": "canter.envs.envpool", "gymnasium": "canter.envs.gymnasium"})
    assert describe_backend_choices() == "auto, envpool or gymnasium"
    with pytest.raises(CanterError, match="unknown env backend 'envpol'; use auto, envpool or gymnasium"):
        resolve_backend("Hopper-v5", "envpol")


def test_auto_takes_the_first_backend_in_registry_order(monkeypatch):
    host_stepped = [backend for backend in backends() if not backend.jax_native]  # `auto` never picks mjx or brax
    for env_id in {i for backend in host_stepped for i in backend.supported_ids()}:
        first = next(backend.name for backend in host_stepped if env_id in backend.supported_ids())
        assert resolve_backend(env_id, "auto") == first, env_id
    assert resolve_backend("Hopper-v5", "auto") == "envpool"  # both have it; EnvPool comes first
    gymnasium_only = sorted(set(get_backend("gymnasium").supported_ids()) - set(get_backend("envpool").supported_ids()))
    assert resolve_backend(gymnasium_only[0], "auto") == "gymnasium"
    assert resolve_backend("canter_test_envs:DictObs-v0", "auto") == "gymnasium"  # the one that takes module:EnvId
    monkeypatch.setattr(registry, "_BACKENDS", dict(reversed(registry._BACKENDS.items())))
    assert resolve_backend("Hopper-v5", "auto") == "gymnasium"


def test_config_and_registry_import_no_env_library():
    """Config validation and the CLI's --backend choices read the registry, which imports every backend package;
    that must stay cheap. Any library beyond canter, the standard library and numpy (the config's own) would be a
    backend's env library, whichever the backend."""
    script = (
        "import sys\n"
        "before = set(sys.modules)\n"
        "import canter.config\n"
        "from canter.envs import registry\n"
        "registry.backends(), registry.backend_doc()\n"
        "added = {name.split('.')[0] for name in set(sys.modules) - before}\n"
        "print(sorted(added - set(sys.stdlib_module_names) - {'canter', 'numpy'}))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def _backend_name_uses(path: Path, names: tuple[str, ...]) -> list[str]:
    """String literals outside docstrings that spell a backend name as a word. Allowed: a library's dotted module
    path (envpool.registration), longer names (envpool_shards) and package metadata lookups, `version("envpool")`
    and its `"envpool":` dict key."""
    word = re.compile(rf"(?<![\w.\-])({'|'.join(names)})(?![\w.\[])")
    tree = ast.parse(path.read_text())
    allowed = set()
    for node in ast.walk(tree):
        if (
            isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
            and node.body
            and isinstance(node.body[0], ast.Expr)
            and isinstance(node.body[0].value, ast.Constant)
        ):
            allowed.add(id(node.body[0].value))
        if _is_version_call(node):
            allowed.update(id(arg) for arg in node.args)
        if isinstance(node, ast.Dict):
            allowed.update(id(key) for key, value in zip(node.keys, node.values) if _is_version_call(value))
    return [
        f"{path.name}:{node.lineno}: {node.value!r}"
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant)
        and isinstance(node.value, str)
        and id(node) not in allowed
        and word.search(node.value)
    ]


def _is_version_call(node) -> bool:
    return isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None)) == "version"


def test_backend_names_are_spelled_only_in_the_registry_and_the_backends():
    envs = SRC / "envs"
    uses = [
        use
        for path in sorted(SRC.rglob("*.py"))
        if envs not in path.parents
        for use in _backend_name_uses(path, backend_names())
    ]
    assert uses == [], "ask canter.envs.registry instead of naming a backend:\n" + "\n".join(uses)


def test_the_name_scan_flags_names_and_spares_library_references(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text('''"""Runs on "envpool" or gymnasium."""
import importlib
from importlib.metadata import version

versions = {"envpool": version("envpool")}
importlib.import_module("envpool.registration")
shards = "env.envpool_shards"
extra = "gymnasium[mujoco]"
backend = "gymnasium"
hint = f"use --backend envpool for {shards}"
''')
    assert _backend_name_uses(sample, ("envpool", "gymnasium")) == [
        "sample.py:9: 'gymnasium'",
        "sample.py:10: 'use --backend envpool for '",
    ]


@pytest.mark.parametrize(
    "env_id, backend, message",
    [
        ("ant", "auto", "'ant' is an env id of Brax; pass --backend brax"),
        ("CarRacing-v3", "envpool", "EnvPool does not run CarRacing-v3; pass --backend gymnasium, or drop --backend"),
        (":Hopper-v5", "auto", "custom env ':Hopper-v5' needs a module and an id, as in my_package.envs:MyEnv-v0"),
        (".envs:Env-v0", "auto", "custom env '.envs:Env-v0' needs a module and an id"),
        ("canter_test_envs:", "auto", "custom env 'canter_test_envs:' needs a module and an id"),
    ],
)
def test_an_id_of_another_backend_or_a_malformed_custom_id_names_the_fix(env_id, backend, message):
    if "brax" in message and not registry.get_backend("brax").available():
        pytest.skip("brax is not installed")
    with pytest.raises(CanterError) as refused:
        resolve_backend(env_id, backend)
    assert str(refused.value).startswith(message), str(refused.value)


# The Python names of --backend that each error advising it ends with, for a caller of canter.train or evaluate.
PYTHON = "(env.backend from Python; backend= for evaluate)"


@pytest.mark.parametrize(
    "env_id, backend, message",
    [
        ("antt", "brax", "unknown env id 'antt' for Brax; did you mean ant? (RUNS)"),
        ("Hoper-v5", "mjx", "unknown env id 'Hoper-v5' for MJX; did you mean Hopper-v5? (RUNS)"),
        (
            "hopper",
            "mjx",
            "MJX does not run hopper (RUNS); pass --backend brax, or use Hopper-v5 with --backend mjx PYTHON",
        ),
        (
            "Hopper-v5",
            "brax",
            "Brax does not run Hopper-v5 (RUNS); pass --backend mjx, drop --backend to run it on the CPU, or use "
            "hopper with --backend brax PYTHON",
        ),
        ("Pendulum-v1", "mjx", "MJX does not run Pendulum-v1 (RUNS); drop --backend to run it on the CPU PYTHON"),
    ],
)
def test_an_id_a_jax_native_backend_lacks_names_the_backends_that_run_it_and_its_own_spelling(env_id, backend, message):
    """Dropping --backend runs an id on the CPU only where a host backend has it, and the JAX-native backends spell
    one task differently (hopper, Hopper-v5): the advice follows both."""
    if not (get_backend("mjx").available() and get_backend("brax").available()):
        pytest.skip("MJX and Brax are not both installed")
    from canter.envs.registry import _or

    with pytest.raises(CanterError) as refused:
        resolve_backend(env_id, backend)
    # Every such error lists what the backend runs, as the issue asks of an unported id.
    runs = f"--backend {backend} runs {_or(sorted(get_backend(backend).supported_ids()))}"
    assert str(refused.value) == message.replace("RUNS", runs).replace("PYTHON", PYTHON)
