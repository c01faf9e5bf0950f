import jax
import jax.numpy as jnp
import numpy as np
import pytest

from canter.core.seeding import EVAL, RESUME, TRAIN, env_seeds
from canter.envs import make_vec_env, resolve_backend
from canter.errors import CanterError


@pytest.mark.parametrize(
    "env_id, backend, obs_dim, act_dim",
    [
        ("Hopper-v5", "envpool", 11, 3),
        ("Hopper-v5", "gymnasium", 11, 3),
        ("Pendulum-v1", "envpool", 3, 1),
        ("WalkerWalk-v1", "envpool", 24, 6),
        ("canter_test_envs:DictObs-v0", "gymnasium", 3, 2),
    ],
)
def test_protocol_shapes_and_dtypes(env_id, backend, obs_dim, act_dim):
    env = make_vec_env(env_id, backend if ":" not in env_id else "auto", 3, [1, 2, 3])
    try:
        spec = env.spec
        assert (spec.backend, spec.obs_dim, spec.act_dim) == (backend, obs_dim, act_dim)
        obs = env.reset()
        assert obs.shape == (3, obs_dim) and obs.dtype == np.float32

        def run(state):
            def body(state, _):
                state, out = env.jax_step(state, jnp.zeros((3, act_dim), jnp.float32))
                return state, out

            return jax.lax.scan(body, state, None, length=4)

        _, out = jax.jit(run)(env.initial_state())
        assert out.obs.shape == (4, 3, obs_dim) and out.obs.dtype == jnp.float32
        assert out.reward.shape == (4, 3) and out.reward.dtype == jnp.float32
        assert out.terminated.dtype == jnp.bool_ and out.truncated.dtype == jnp.bool_
        assert all(v.dtype == jnp.float32 for v in out.info.values())
        host = env.host_step(np.zeros((3, act_dim), np.float32))
        assert host.obs.dtype == np.float32 and host.obs.shape == (3, obs_dim)
    finally:
        env.close()


def test_envpool_spaces_build_without_gymnasium_cast_warnings():
    """EnvPool declares Pendulum's and BipedalWalker's float32 Boxes with float64 bounds and rebuilds them on every
    reset and host step; the user should not see Gymnasium's warning about it. A fresh process, as a user gets."""
    import subprocess
    import sys

    script = (
        "import numpy as np\n"
        "from canter.envs import make_vec_env\n"
        "for env_id in ('Pendulum-v1', 'BipedalWalker-v3'):\n"
        "    for num_envs in (1, 2):\n"
        "        env = make_vec_env(env_id, 'envpool', num_envs, list(range(num_envs)))\n"
        "        env.host_step(np.zeros((num_envs, env.spec.act_dim), np.float32))\n"
        "        env.close()\n"
        "print('stepped')\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "stepped" in done.stdout, done.stderr
    assert "precision lowered" not in done.stderr and "Warning" not in done.stderr, done.stderr


def test_dict_observations_are_flattened_in_key_order():
    env = make_vec_env("canter_test_envs:DictObs-v0", "auto", 1, [0])
    out = env.host_step(np.zeros((1, 2), np.float32))
    np.testing.assert_allclose(out.obs[0], [0.1, -0.1, -0.1])  # "a" then "b"
    assert out.info["reward_step"][0] == 1.0


def _roll(env, actions):
    outs = [env.host_step(a) for a in actions]
    return (
        np.stack([o.obs for o in outs]),
        np.stack([o.reward for o in outs]),
        np.stack([o.terminated for o in outs]),
        np.stack([o.truncated for o in outs]),
    )


@pytest.mark.parametrize(
    ("env_id", "differs"), [("Humanoid-v4", True), ("HumanoidStandup-v4", True), ("Humanoid-v5", False)]
)
def test_the_ids_whose_envpool_env_is_not_gymnasiums_are_named_where_a_run_is_replayed(env_id, differs):
    """EnvPool's v4 humanoids keep their 84 contact-force entries at 0, where Gymnasium's move: a run of one that is
    played in Gymnasium (a video, a robustness sweep, eval --backend gymnasium) gets a note saying so."""
    from canter.envs.registry import replay_note

    rng = np.random.default_rng(0)
    a = make_vec_env(env_id, "envpool", 1, [0])
    b = make_vec_env(env_id, "gymnasium", 1, [0])
    a.reset(), b.reset()
    actions = rng.uniform(-0.4, 0.4, size=(100, 1, a.spec.act_dim)).astype(np.float32)
    contacts = slice(-84, None) if env_id.endswith("v4") else slice(-78, None)
    largest = [np.abs(_roll(env, actions)[0][..., contacts]).max() for env in (a, b)]
    assert bool(largest[0] == 0.0 and largest[1] > 10.0) == differs, largest
    note = replay_note(env_id, "envpool", "gymnasium")
    assert (note is not None) is differs
    # Either way round: a Gymnasium run evaluated on EnvPool sees the zeros instead.
    assert (replay_note(env_id, "gymnasium", "envpool") is not None) is differs
    if differs:
        assert note.startswith(f"canter: note: {env_id} trained on EnvPool and played on Gymnasium here")
        assert "contact-force" in note
    assert replay_note(env_id, "envpool", "envpool") is None and replay_note(env_id, "envpool", "mjx") is None


def test_a_replay_note_is_printed_once_per_env_and_pair_of_backends(capsys):
    from canter.envs import registry

    for _ in range(3):  # a robustness sweep evaluates once per scale
        registry.note_replay("HumanoidStandup-v4", "envpool", "gymnasium")
    registry.note_replay("HalfCheetah-v5", "envpool", "gymnasium")
    assert capsys.readouterr().err.count("canter: note: HumanoidStandup-v4") == 1


@pytest.mark.parametrize("env_id", ["HalfCheetah-v5", "Hopper-v5"])
def test_envpool_and_gymnasium_simulate_identically(env_id):
    """Same MuJoCo (pinned), zero reset noise, same actions: same observations and rewards, resets included."""
    rng = np.random.default_rng(0)
    a = make_vec_env(env_id, "envpool", 1, [0], reset_noise_scale=0.0)
    b = make_vec_env(env_id, "gymnasium", 1, [0], reset_noise_scale=0.0)
    np.testing.assert_allclose(a.reset(), b.reset(), atol=1e-6)
    actions = rng.uniform(-1, 1, size=(300, 1, a.spec.act_dim)).astype(np.float32)
    obs_a, rew_a, term_a, trunc_a = _roll(a, actions)
    obs_b, rew_b, term_b, trunc_b = _roll(b, actions)
    np.testing.assert_array_equal(term_a, term_b)
    np.testing.assert_array_equal(trunc_a, trunc_b)
    np.testing.assert_allclose(obs_a, obs_b, atol=1e-5, rtol=1e-5)
    np.testing.assert_allclose(rew_a, rew_b, atol=1e-5)
    if env_id == "Hopper-v5":
        assert term_a.any(), "random actions should topple the hopper, exercising the autoreset"


@pytest.mark.parametrize("backend", ["envpool", "gymnasium"])
def test_autoreset_step_semantics(backend):
    """Pendulum truncates at 200; step 201 returns the reset observation, reward 0 and both flags false."""
    env = make_vec_env("Pendulum-v1", backend, 1, [5])
    outs = [env.host_step(np.ones((1, 1), np.float32)) for _ in range(201)]
    assert not any(o.truncated[0] for o in outs[:199])
    assert outs[199].truncated[0] and not outs[199].terminated[0]
    reset = outs[200]
    assert reset.reward[0] == 0.0 and not reset.truncated[0] and not reset.terminated[0]
    cos, sin, velocity = reset.obs[0]  # a fresh reset: an angle, and a velocity drawn from [-1, 1]
    assert cos**2 + sin**2 == pytest.approx(1.0, abs=1e-5) and abs(velocity) <= 1.0
    assert not np.allclose(reset.obs[0], outs[199].obs[0])


def test_two_run_seeds_share_no_env_seed():
    seen = {}
    for run_seed in range(10):
        for purpose in (TRAIN, EVAL):
            for seed in env_seeds(run_seed, 256, purpose):
                assert seed not in seen, (run_seed, purpose, seen.get(seed))
                seen[seed] = (run_seed, purpose)
                assert 0 <= seed < 2**31
    assert env_seeds(0, 4) == env_seeds(0, 4)
    assert env_seeds(0, 4, RESUME, 100) != env_seeds(0, 4, RESUME, 200)


def test_unknown_ids_and_spaces_are_clear_errors():
    with pytest.raises(CanterError, match=r"unknown env id 'Hoper-v5'.*Hopper-v5"):
        resolve_backend("Hoper-v5", "auto")
    with pytest.raises(CanterError, match="cannot import module 'no_such_module'"):
        resolve_backend("no_such_module:Env-v0", "auto")
    with pytest.raises(CanterError, match="not supported; canter needs a Box or a Dict of Boxes"):
        make_vec_env("canter_test_envs:DiscreteObs-v0", "auto", 1, [0])
    with pytest.raises(CanterError, match=r"custom env .* needs the gymnasium backend"):
        resolve_backend("canter_test_envs:DictObs-v0", "envpool")
    assert resolve_backend("Hopper-v5", "auto") == "envpool"


def test_a_custom_module_whose_dependency_is_missing_names_the_dependency(tmp_path, monkeypatch):
    """The module is found: what is missing is what it imports, and its traceback shows where."""
    (tmp_path / "needs_a_dependency.py").write_text("import no_such_dependency\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(CanterError) as refused:
        resolve_backend("needs_a_dependency:Env-v0", "auto")
    assert str(refused.value) == (
        "module 'needs_a_dependency' for env 'needs_a_dependency:Env-v0' imports 'no_such_dependency', which is "
        "missing (No module named 'no_such_dependency'); install it, or see the full traceback with: python -c "
        '"import needs_a_dependency"'
    )


def test_sharded_pools_step_like_one_pool():
    """Splitting the envs over concurrent single-threaded pools, evenly or not (5 envs: 3 + 2, 2 + 2 + 1), changes
    nothing but speed: every env gets its own action and seed whatever pool it lands in (each env's actions differ)."""
    seeds = env_seeds(7, 5)
    envs = [make_vec_env("Hopper-v5", "envpool", 5, seeds, shards=k) for k in (1, 2, 3)]
    assert [len(e._pools) for e in envs] == [1, 2, 3]
    for other in envs[1:]:
        np.testing.assert_array_equal(envs[0].reset(), other.reset())
    actions = np.random.default_rng(0).uniform(-1, 1, size=(50, 5, 3)).astype(np.float32)

    def run(env):
        def body(state, action):
            return env.jax_step(state, action)

        return jax.jit(lambda s, a: jax.lax.scan(body, s, a))(env.initial_state(), jnp.asarray(actions))[1]

    reference = jax.tree_util.tree_leaves(run(envs[0]))
    for other in envs[1:]:
        for x, y in zip(reference, jax.tree_util.tree_leaves(run(other))):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    with pytest.raises(CanterError, match="cannot split 3 envs"):
        make_vec_env("Hopper-v5", "envpool", 3, [1, 2, 3], shards=4)


def test_shard_sizes_split_as_evenly_as_possible():
    from canter.envs.envpool.shards import shard_sizes

    assert shard_sizes(5, 2) == [3, 2]
    assert shard_sizes(16, 2) == [8, 8]
    assert shard_sizes(7, 3) == [3, 2, 2]
    assert shard_sizes(1, 1) == [1]
    for bad in (0, 6):
        with pytest.raises(ValueError, match="cannot split 5 envs"):
            shard_sizes(5, bad)


def test_default_shards_follow_the_cores_this_process_may_use(monkeypatch):
    from canter.envs.envpool import shards

    monkeypatch.setattr(shards.os, "sched_getaffinity", lambda pid: {3}, raising=False)  # a job pinned to one core
    monkeypatch.setattr(shards.os, "cpu_count", lambda: 16)
    assert shards.default_shards(8) == 1
    monkeypatch.setattr(shards.os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    assert shards.default_shards(8) == 4 and shards.default_shards(2) == 2


def test_a_custom_env_whose_bounds_exclude_zero_is_probed_within_them():
    env = make_vec_env("canter_test_envs:RefusesOutOfBounds-v0", "auto", 1, [0])
    assert env.spec.info_keys == ("speed",)
    env.close()


def test_reading_a_dm_control_tasks_observation_prints_nothing_on_a_headless_machine():
    """The EnvPool backend asks dm_control for a task's own observation keys, which imports its renderer: with no
    display GLFW warned on every DM Control run and evaluation."""
    import os
    import subprocess
    import sys

    code = (
        "from canter.envs.dm_control_tasks import observation_keys; print(sorted(observation_keys('walker', 'walk')))"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "MUJOCO_GL", "PYOPENGL_PLATFORM")}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert done.stdout.strip() == "['height', 'orientations', 'velocity']" and done.stderr == "", done.stderr
