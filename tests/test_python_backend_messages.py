"""The refusals that canter.train, build_config and evaluate share with the CLI name the Python form of each fix
beside the flag: a config's env.backend and evaluate's backend=, env_id= and physics=, which a Python caller passes
instead of --backend, --env or --set. Each is refused before any env steps."""

import pytest

import canter
from canter.envs.registry import get_backend
from canter.errors import CanterError


@pytest.fixture(scope="module")
def policy():
    """The archived InvertedPendulum-v4 run, trained on `auto` (EnvPool)."""
    from conftest import ARCHIVED_RUN

    return canter.load(ARCHIVED_RUN)


def _refusal(call, *python_names: str) -> str:
    with pytest.raises(CanterError) as refused:
        call()
    message = str(refused.value)
    assert "\n" not in message, message
    for name in python_names:
        assert name in message, message
    return message


def _need(*backends: str) -> None:
    if not all(get_backend(name).available() for name in backends):
        pytest.skip(f"needs {' and '.join(backends)}")


def _train(env_id: str, *sets: str):
    return lambda: canter.train(canter.build_config(env_id, sets=["run.tensorboard=false", *sets]))


def test_train_on_a_backend_without_the_id_names_env_backend(tmp_path):
    _need("mjx", "brax")
    message = _refusal(_train("Hopper-v5", "env.backend=brax"), "env.backend")
    assert message.endswith(
        "pass --backend mjx, drop --backend to run it on the CPU, or use hopper with --backend brax (env.backend from "
        "Python; backend= for evaluate)"
    ), message
    message = _refusal(_train("Pendulum-v1", "env.backend=mjx"), "env.backend")
    assert message.endswith("; drop --backend to run it on the CPU (env.backend from Python; backend= for evaluate)")
    assert not (tmp_path / "runs").exists()


def test_train_an_id_of_a_jax_backend_on_auto_names_env_backend():
    _need("brax")
    message = _refusal(_train("hopper"), "env.backend")
    assert message == (
        "'hopper' is an env id of Brax; pass --backend brax (env.backend from Python; backend= for evaluate)"
    )


def test_a_mujoco_py_id_names_env_backend_for_the_backend_with_its_own_port():
    if "Walker2d-v3" not in get_backend("envpool").supported_ids():
        pytest.skip("EnvPool does not run Walker2d-v3")
    message = _refusal(lambda: canter.build_config("Walker2d-v3", sets=["env.backend=gymnasium"]), "env.backend")
    assert "pass --backend envpool (env.backend from Python), which runs its own Walker2d-v3" in message, message


def test_a_physics_setting_on_a_cpu_backend_names_env_backend_in_a_config():
    _need("mjx")
    message = _refusal(lambda: canter.build_config("Hopper-v5", sets=["env.solver_iterations=4"]), "env.backend")
    assert message.endswith(
        "add --backend mjx or drop env.solver_iterations (env.backend from Python; backend= and physics= for evaluate)"
    ), message


def test_evaluate_on_a_backend_without_the_id_names_backend(policy):
    _need("brax")
    message = _refusal(lambda: canter.evaluate(policy, episodes=1, backend="brax"), "backend= for evaluate")
    assert message.startswith("Brax observations differ from Gymnasium's, so a run trained on envpool"), message


def test_evaluate_an_id_of_a_jax_backend_names_backend(policy):
    _need("brax")
    _refusal(lambda: canter.evaluate(policy, episodes=1, env_id="hopper"), "backend= for evaluate")


def test_evaluate_a_custom_env_on_another_backend_names_backend(policy):
    message = _refusal(
        lambda: canter.evaluate(policy, episodes=1, env_id="canter_test_envs:Anything-v0", backend="envpool"),
        "backend= for evaluate",
    )
    assert message.startswith("custom env 'canter_test_envs:Anything-v0' needs the gymnasium backend; drop --backend")


def test_evaluate_physics_on_a_cpu_backend_names_backend_and_physics(policy):
    _need("mjx")
    message = _refusal(
        lambda: canter.evaluate(policy, episodes=1, env_id="Hopper-v5", physics={"solver_iterations": 4}),
        "backend=",
        "physics=",
    )
    assert message.startswith("env.solver_iterations applies to the mjx backend only; add --backend mjx"), message


def test_evaluate_physics_on_an_env_without_a_port_names_physics(policy):
    _need("mjx")
    message = _refusal(lambda: canter.evaluate(policy, episodes=1, physics={"contacts": "floor"}), "physics=")
    assert message == (
        "env.contacts applies to the mjx backend only; InvertedPendulum-v4 has no mjx version: drop env.contacts "
        "(physics= for evaluate)"
    )


def test_evaluate_on_an_env_of_other_sizes_names_env_id(policy):
    message = _refusal(lambda: canter.evaluate(policy, episodes=1, env_id="Hopper-v5"), "env_id=")
    assert message.endswith("the policy expects 4/1; pick a matching --env (env_id= for evaluate)"), message


def test_an_uninstalled_backend_names_its_extra_and_the_backends_that_run_the_env(monkeypatch, policy):
    """The extra to install, then the installed backends with a version of the env, named for Python too; a
    backend of its own envs (Brax) has none such, so another --backend would only be refused in its turn."""
    monkeypatch.setattr(type(get_backend("mjx")), "available", lambda self: False)
    for call in (
        _train("InvertedPendulum-v5", "env.backend=mjx"),
        lambda: canter.evaluate(policy, episodes=1, backend="mjx", env_id="InvertedPendulum-v5"),
    ):
        message = _refusal(call, "env.backend from Python; backend= for evaluate")
        assert message == (
            "MJX is not installed here; pip install 'canter[mjx]', or use --backend envpool or gymnasium "
            "(env.backend from Python; backend= for evaluate)"
        )
    monkeypatch.setattr(type(get_backend("brax")), "available", lambda self: False)
    for call in (_train("ant", "env.backend=brax"), lambda: canter.evaluate(policy, episodes=1, backend="brax")):
        with pytest.raises(CanterError) as refused:
            call()
        assert str(refused.value) == "Brax is not installed here; pip install 'canter[brax]'"


@pytest.mark.parametrize("backend", ["auto", "envpool", "mjx"])
def test_an_id_of_an_uninstalled_backend_names_its_extra_rather_than_calling_it_unknown(monkeypatch, backend):
    """`canter train ant` without brax: Brax's env names are known without it, so the error names the extra."""
    if backend != "auto":
        _need(backend)  # else its own absence is said first
    monkeypatch.setattr(type(get_backend("brax")), "available", lambda self: False)
    message = _refusal(_train("ant", f"env.backend={backend}"), "env.backend from Python")
    fix = "pip install 'canter[brax]' and pass --backend brax"
    if backend == "mjx":
        assert message.endswith(
            f"; {fix}, or use Ant-v5 with --backend mjx (env.backend from Python; backend= for evaluate)"
        ), message
    else:
        assert message == (
            f"'ant' is an env id of Brax, which is not installed here; {fix} (env.backend from Python; backend= for "
            "evaluate)"
        )
