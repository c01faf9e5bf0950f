"""The public API's evaluate and Policy refuse what is not theirs in one line, and show what they hold."""

import numpy as np
import pytest

import canter
from canter.errors import CanterError


@pytest.fixture(scope="module")
def policy():
    from conftest import ARCHIVED_RUN

    return canter.load(ARCHIVED_RUN)


@pytest.mark.parametrize(
    ("given", "message"),
    [
        (
            "runs/a",
            "evaluate takes a Policy, got the path 'runs/a'; load it first: canter.evaluate(canter.load('runs/a'))",
        ),
        (None, "evaluate takes a Policy (canter.load(RUN)), got NoneType"),
        (3, "evaluate takes a Policy (canter.load(RUN)), got int"),
    ],
)
def test_evaluate_refuses_what_is_not_a_policy(given, message):
    with pytest.raises(CanterError) as refused:
        canter.evaluate(given)
    assert str(refused.value) == message


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"deterministic": "no"}, "deterministic must be True or False, got 'no'"),
        ({"deterministic": None}, "deterministic must be True or False, got None"),
        ({"env_id": 5}, "env_id must be a name (a string) or None for the run's own, got 5"),
        ({"backend": ["envpool"]}, "backend must be a name (a string) or None for the run's own, got ['envpool']"),
        ({"physics": {1: 2}}, "physics takes setting names such as 'solver_iterations' as its keys, got 1"),
    ],
)
def test_evaluate_refuses_arguments_of_the_wrong_kind(policy, kwargs, message):
    with pytest.raises(CanterError) as refused:
        canter.evaluate(policy, episodes=1, **kwargs)
    assert str(refused.value) == message


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"deterministic": "no"}, "deterministic must be True or False, got 'no'"),
        ({"deterministic": True, "seed": -5}, "seed"),
    ],
)
def test_a_policy_call_refuses_arguments_of_the_wrong_kind(policy, kwargs, message):
    with pytest.raises(CanterError, match=message):
        policy(np.zeros(policy.obs_dim, np.float32), **kwargs)


def test_a_policy_takes_numpy_bools_and_a_seed(policy):
    obs = np.zeros(policy.obs_dim, np.float32)
    mean = policy(obs, deterministic=np.bool_(True))
    first, again = policy(obs, deterministic=False, seed=3), policy(obs, deterministic=False, seed=3)
    assert mean.shape == (policy.act_dim,) and np.array_equal(first, again)


def test_a_sampled_evaluation_leaves_the_policys_own_stream_as_it_was(policy):
    obs = np.zeros(policy.obs_dim, np.float32)
    policy(obs, deterministic=False, seed=5)
    expected = policy(obs, deterministic=False)
    policy(obs, deterministic=False, seed=5)
    first = canter.evaluate(policy, episodes=1, deterministic=False, seed=9)
    assert np.array_equal(policy(obs, deterministic=False), expected)
    again = canter.evaluate(policy, episodes=1, deterministic=False, seed=9)
    assert np.array_equal(first.returns, again.returns)


def test_a_policy_and_an_evaluation_show_what_they_are(policy):
    shown = repr(policy)
    assert shown.startswith(f"Policy({policy.facts.env_id}, {policy.config.run.algo}, step ")
    assert f"obs_dim={policy.obs_dim}, act_dim={policy.act_dim}" in shown
    result = canter.evaluate(policy, episodes=2)
    assert repr(result).startswith(f"EvalResult(episodes=2, return {result.mean:.1f} ± {result.std:.1f}, length ")


def test_the_exported_classes_are_listed_and_reachable():
    assert {"EvalResult", "Policy", "RunResult"} <= set(dir(canter)) and "EvalResult" in canter.__all__
    from canter.training.evaluation import EvalResult

    assert canter.EvalResult is EvalResult
    with pytest.raises(AttributeError, match="module 'canter' has no attribute 'Nope'"):
        canter.Nope  # noqa: B018


@pytest.mark.parametrize("backend", ["cuda", 3, ""])
def test_load_refuses_a_backend_that_is_not_one(backend):
    from canter.envs.registry import describe_backend_choices
    from conftest import ARCHIVED_RUN

    with pytest.raises(CanterError) as refused:
        canter.load(ARCHIVED_RUN, backend=backend)
    choices = describe_backend_choices()
    assert str(refused.value) == f"backend must be a backend name ({choices}) or None for its own, got {backend!r}"
