"""td3, ddpg and sac end to end: what the iteration stores, learning, resume, loading and bad input."""

import shutil
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from canter.algos import get_algorithm
from canter.algos.offpolicy.ddpg import DDPGLearner
from canter.algos.offpolicy.iteration import count_step, init_train_state, make_iteration, next_ou_state, should_train
from canter.algos.offpolicy.sac import SACLearner
from canter.algos.offpolicy.td3 import TD3
from canter.cli.main import main
from canter.config.build import build_config
from canter.envs.base import StepOutput
from canter.envs.episodes import init_env_carry
from canter.errors import CanterError
from canter.run_layout import read_summary
from canter.training import checkpoint, run_folder
from canter.training.disk_room import state_bytes
from canter.training.loop import train
from canter.training.restore import load_state
from canter.training.resume import resume_config
from canter.use.evaluate import evaluate
from canter.use.policy import load
from signals import sigterm_during_setup

# Env 0 terminates when its counter reaches 3; env 1 is truncated (time limit) at 4.
TERMINATE_AT = (3, 100)
TRUNCATE_AT = (100, 4)


def counter_env_step(state, action):
    """A pure-JAX env with EnvPool's semantics: obs = (counter, env index), reward = counter; the step after a done
    is an autoreset step (reward 0, flags false) that returns the reset observation."""
    t, needs_reset = state
    t = jnp.where(needs_reset, 0, t + 1)
    terminated = ~needs_reset & (t >= jnp.array(TERMINATE_AT))
    truncated = ~needs_reset & (t >= jnp.array(TRUNCATE_AT))
    obs = jnp.stack([t.astype(jnp.float32), jnp.arange(2, dtype=jnp.float32)], axis=-1)
    reward = jnp.where(needs_reset, 0.0, t.astype(jnp.float32))
    return (t, terminated | truncated), StepOutput(obs, reward, terminated, truncated, {})


def reference_transitions(vector_steps):
    """(obs counter, env, reward, next counter, terminated) in insertion order, by plain simulation."""
    t, needs_reset, stored = [0, 0], [False, False], []
    for _ in range(vector_steps):
        for env in range(2):
            if needs_reset[env]:
                t[env], needs_reset[env] = 0, False
                continue
            new = t[env] + 1
            term, trunc = new >= TERMINATE_AT[env], new >= TRUNCATE_AT[env]
            stored.append((t[env], env, new, new, float(term)))
            t[env], needs_reset[env] = new, term or trunc
    return stored


def run_counter_iteration(config, learner):
    """One jitted iteration of `learner` on the two-env counter env, from fresh state."""
    spec = SimpleNamespace(obs_dim=2, act_dim=1, action_low=(-2.0,), action_high=(2.0,))
    state = init_train_state(config, learner, 2, 1, config.run.seed)
    carry = init_env_carry((jnp.zeros(2, jnp.int32), jnp.zeros(2, bool)), jnp.array([[0.0, 0.0], [0.0, 1.0]]), ())
    return jax.jit(make_iteration(config, learner, spec, counter_env_step))(state, carry, jnp.float32(1.0))


def test_iteration_stores_valid_transitions_with_true_final_obs_and_terminated_only():
    config = build_config(
        "Pendulum-v1",
        algo="td3",
        sets=[
            "env.num_envs=2",
            "td3.steps_per_call=18",
            "td3.learning_starts=1000000",
            "td3.buffer_size=64",
            "td3.batch_size=4",
            "td3.hidden=4",
            "td3.noise=ou",
        ],
    )
    state, _, metrics = run_counter_iteration(config, TD3(config.td3))

    expected = reference_transitions(9)
    size = int(state.buffer.size)
    assert size == len(expected) == int(metrics["steps"]) == int(state.global_step)
    data = jax.device_get(state.buffer.data)
    got = [
        (
            int(data.obs[i, 0]),
            int(data.obs[i, 1]),
            int(data.reward[i]),
            int(data.next_obs[i, 0]),
            float(data.terminated[i]),
        )
        for i in range(size)
    ]
    assert got == expected
    # The truncated step stores its true final observation (4) and does not stop bootstrapping.
    assert (3, 1, 4, 4, 0.0) in got and (2, 0, 3, 3, 1.0) in got
    assert bool(metrics["finite"]) and int(metrics["gradient_steps"]) == 0
    # An env whose episode ended on the last step restarts its OU noise at zero; the other's keeps running.
    last_done = np.asarray(metrics["finished"])[-1]
    assert last_done.tolist() == [False, True]  # 9 vector steps: env 1's second episode ends on the last one
    ou = np.asarray(state.ou_state)
    for env in range(2):
        assert (ou[env] == 0).all() == bool(last_done[env])


def test_ou_noise_stays_at_zero_through_the_autoreset_step():
    """The autoreset step's action is ignored, so its OU noise must not advance: the next episode's first action
    then carries one increment from 0, as SB3's does, not two."""
    config = build_config(
        "Pendulum-v1",
        algo="td3",
        sets=["env.num_envs=2", "td3.steps_per_call=20", "td3.learning_starts=0", "td3.buffer_size=64"]
        + ["td3.batch_size=4", "td3.hidden=4", "td3.noise=ou", "td3.noise_std=1.0"],
    )
    state, _, metrics = run_counter_iteration(config, TD3(config.td3))
    done = np.asarray(metrics["finished"])
    assert done[-2].tolist() == [False, True] and not done[-1].any()  # env 1's last step was its autoreset step
    ou = np.asarray(state.ou_state)
    assert (ou[1] == 0).all() and (ou[0] != 0).all()


def test_an_autoreset_step_that_stores_nothing_makes_no_update():
    """One env that terminates every 3 steps: of 8 vector steps, 2 are autoresets, so 6 transitions and 6 updates
    at train_freq 1, as in the references, whose envs reset within the step."""

    def one_env_step(state, action):
        t, needs_reset = state
        t = jnp.where(needs_reset, 0, t + 1)
        terminated = ~needs_reset & (t >= 3)
        obs = jnp.stack([t.astype(jnp.float32), jnp.zeros_like(t, jnp.float32)], axis=-1)
        return (t, terminated), StepOutput(
            obs, jnp.where(needs_reset, 0.0, 1.0), terminated, jnp.zeros_like(terminated), {}
        )

    config = build_config(
        "Pendulum-v1",
        algo="td3",
        sets=["env.num_envs=1", "td3.steps_per_call=8", "td3.learning_starts=0", "td3.train_freq=1"]
        + ["td3.gradient_steps=1", "td3.buffer_size=64", "td3.batch_size=2", "td3.hidden=4"],
    )
    spec = SimpleNamespace(obs_dim=2, act_dim=1, action_low=(-2.0,), action_high=(2.0,))
    learner = TD3(config.td3)
    state = init_train_state(config, learner, 2, 1, config.run.seed)
    carry = init_env_carry((jnp.zeros(1, jnp.int32), jnp.zeros(1, bool)), jnp.zeros((1, 2)), ())
    state, _, metrics = jax.jit(make_iteration(config, learner, spec, one_env_step))(state, carry, jnp.float32(1.0))
    assert int(metrics["steps"]) == 6 and int(state.buffer.size) == 6
    assert int(metrics["gradient_steps"]) == 6 and int(state.vector_steps) == 6


class _RewardSpy(TD3):
    """TD3 whose update learns nothing and reports the ratio of the batch's rewards to the raw ones (the counter env's
    reward equals its next observation's counter, which observation normalization, off here, would change)."""

    update_metrics = ("critic_loss", "reward_ratio")

    def update(self, state, batch, key):
        ratio = jnp.mean(batch.reward / batch.next_obs[:, 0])
        return state, {"critic_loss": jnp.float32(0.0), "reward_ratio": ratio}


def test_the_learner_samples_rewards_times_the_fixed_reward_scale_while_the_buffer_keeps_them_raw():
    config = build_config(
        "Pendulum-v1",
        algo="td3",
        sets=[
            "env.num_envs=2",
            "env.normalize_obs=false",
            "env.normalize_reward=false",
            "env.reward_scale=0.1",
            "td3.steps_per_call=20",
            "td3.learning_starts=4",
            "td3.buffer_size=64",
            "td3.batch_size=4",
            "td3.hidden=4",
        ],
    )
    state, _, metrics = run_counter_iteration(config, _RewardSpy(config.td3))
    assert int(metrics["gradient_steps"]) > 0
    assert float(metrics["reward_ratio"]) == pytest.approx(0.1, rel=1e-6)
    size = int(state.buffer.size)
    data = jax.device_get(state.buffer.data)
    np.testing.assert_array_equal(data.reward[:size], data.next_obs[:size, 0])


def acted_counters(vector_steps):
    """Per vector step, the counters of the envs that act on it (the others are in their autoreset step), by plain
    simulation of the counter env."""
    t, needs_reset, steps = [0, 0], [False, False], []
    for _ in range(vector_steps):
        acted = []
        for env in range(2):
            if needs_reset[env]:
                t[env], needs_reset[env] = 0, False
                continue
            acted.append((t[env], env))
            t[env] += 1
            needs_reset[env] = t[env] >= TERMINATE_AT[env] or t[env] >= TRUNCATE_AT[env]
        steps.append(acted)
    return steps


class _CountingSpy(TD3):
    """TD3 whose update only counts: it reports its index as critic_loss, and as actor_loss on the even ones (NaN,
    a delayed actor step, on the odd ones)."""

    def update(self, state, batch, key):
        index = state.updates.astype(jnp.float32)
        actor = jnp.where(state.updates % 2 == 0, index, jnp.nan)
        return state._replace(updates=state.updates + 1), {"critic_loss": index, "actor_loss": actor, "q_mean": index}


@pytest.mark.parametrize(
    "vector_steps, learning_starts, train_freq, gradient_steps",
    [
        # 22 vector steps: learning_starts is reached exactly on step 2 (2 envs act); on step 20 both envs are in
        # their autoreset step, which stores nothing, so it neither trains nor counts for train_freq.
        (11, 4, 1, 1),
        (11, 5, 2, 3),
        (7, 7, 3, 2),  # train_freq 3 across the two calls
        (8, 100, 1, 1),  # never trains: NaN metrics
    ],
)
def test_gradient_steps_follow_a_python_simulation_of_the_schedule(
    vector_steps, learning_starts, train_freq, gradient_steps
):
    """Two calls in a row (the counts carry over between them). The reference, step by step: the env steps taken
    so far count the acting envs; a vector step counts for train_freq only if some env stored a transition; then
    it trains `gradient_steps` times if it stored one, at least learning_starts env steps have been taken and the
    vector steps so far are a multiple of train_freq. The metrics average the update indices of each call's
    steps, the actor's over the even ones only."""
    sets = ["env.num_envs=2", "env.normalize_obs=false", f"td3.steps_per_call={2 * vector_steps}"]
    sets += [f"td3.learning_starts={learning_starts}", f"td3.train_freq={train_freq}"]
    sets += [f"td3.gradient_steps={gradient_steps}", "td3.buffer_size=64", "td3.batch_size=4", "td3.hidden=4"]
    config = build_config("Pendulum-v1", algo="td3", sets=sets)
    learner = _CountingSpy(config.td3)
    spec = SimpleNamespace(obs_dim=2, act_dim=1, action_low=(-2.0,), action_high=(2.0,))
    iteration = jax.jit(make_iteration(config, learner, spec, counter_env_step))
    state = init_train_state(config, learner, 2, 1, config.run.seed)
    carry = init_env_carry((jnp.zeros(2, jnp.int32), jnp.zeros(2, bool)), jnp.array([[0.0, 0.0], [0.0, 1.0]]), ())

    acted = acted_counters(2 * vector_steps)
    assert (vector_steps < 10) or (acted[19] == [] and len(acted[1]) == 2)
    env_steps = stored_steps = updates = 0
    for call in range(2):
        state, carry, metrics = iteration(state, carry, jnp.float32(1.0))
        first = updates
        for step in acted[call * vector_steps : (call + 1) * vector_steps]:
            env_steps += len(step)
            stored_steps += len(step) > 0
            if step and env_steps >= learning_starts and stored_steps % train_freq == 0:
                updates += gradient_steps
        indices = list(range(first, updates))
        assert int(metrics["gradient_steps"]) == len(indices) and int(state.learner.updates) == updates
        assert int(state.vector_steps) == stored_steps and int(state.global_step) == env_steps
        expected = {"critic_loss": indices, "actor_loss": [i for i in indices if i % 2 == 0]}
        for name, values in expected.items():
            got = float(metrics[name])
            assert got == pytest.approx(np.mean(values)) if values else np.isnan(got), (name, call)
    if learning_starts < 100:
        assert updates > 0 and int(metrics["gradient_steps"]) > 0


class _BatchSpy(TD3):
    """TD3 whose update learns nothing and reports the four rows of its batch: the counter and env columns of the
    observation, the counter of the next one, and the reward minus twice the action."""

    update_metrics = (
        "critic_loss",
        *(f"{field}{i}" for i in range(4) for field in ("counter", "env", "next", "action_gap")),
    )

    def update(self, state, batch, key):
        rows = {"critic_loss": jnp.float32(0.0)}
        for i in range(4):
            rows |= {f"counter{i}": batch.obs[i, 0], f"env{i}": batch.obs[i, 1], f"next{i}": batch.next_obs[i, 0]}
            rows[f"action_gap{i}"] = batch.reward[i] - 2.0 * batch.action[i, 0]
        return state, rows


def test_sampled_batches_are_normalized_with_the_running_statistics_of_that_step():
    """Train once, on the last of 9 vector steps: every row of the batch must be a stored transition normalized by
    numpy's mean and variance of all the observations acted on so far, this step's included, pooled with the
    statistics' prior (mean 0, variance 1, weight 1e-4): (x - mean) / sqrt(var + 1e-8). The env here rewards the
    action it received, so the stored action is that one over the half-range 2: the unit-box action."""

    def action_rewarding_env_step(state, action):
        state, out = counter_env_step(state, action)
        return state, out._replace(reward=jnp.where(state[0] == 0, 0.0, action[:, 0]))

    acted = acted_counters(9)
    env_steps = sum(len(step) for step in acted)
    assert acted[-1]  # the last step stores a transition, so it trains
    sets = ["env.num_envs=2", "env.normalize_obs=true", "env.clip_obs=1000", "env.normalize_reward=false"]
    sets += ["td3.steps_per_call=18", f"td3.learning_starts={env_steps}", "td3.train_freq=1", "td3.gradient_steps=1"]
    sets += ["td3.buffer_size=64", "td3.batch_size=4", "td3.hidden=4"]
    config = build_config("Pendulum-v1", algo="td3", sets=sets)
    learner = _BatchSpy(config.td3)
    spec = SimpleNamespace(obs_dim=2, act_dim=1, action_low=(-2.0,), action_high=(2.0,))
    state = init_train_state(config, learner, 2, 1, config.run.seed)
    carry = init_env_carry((jnp.zeros(2, jnp.int32), jnp.zeros(2, bool)), jnp.array([[0.0, 0.0], [0.0, 1.0]]), ())
    state, _, metrics = jax.jit(make_iteration(config, learner, spec, action_rewarding_env_step))(
        state, carry, jnp.float32(1.0)
    )
    assert int(state.global_step) == env_steps and int(metrics["gradient_steps"]) == 1

    seen = np.array([row for step in acted for row in step], np.float64)
    count = len(seen) + 1e-4
    mean = seen.sum(axis=0) / count
    var = (1e-4 * (1.0 + mean**2) + np.sum((seen - mean) ** 2, axis=0)) / count
    scale = np.sqrt(var + 1e-8)
    stored = [
        ((c - mean[0]) / scale[0], (e - mean[1]) / scale[1], (n - mean[0]) / scale[0])
        for c, e, n, *_ in reference_transitions(9)
    ]
    for i in range(4):
        row = tuple(float(metrics[f"{field}{i}"]) for field in ("counter", "env", "next"))
        assert any(np.allclose(row, s, rtol=0, atol=1e-5) for s in stored), (row, stored)
        assert float(metrics[f"action_gap{i}"]) == pytest.approx(0.0, abs=1e-6)
    assert len({float(metrics[f"counter{i}"]) for i in range(4)}) > 1  # not one row drawn four times


FIXTURE_RUNS = Path(__file__).parent / "fixtures" / "runs-v1"


@pytest.mark.parametrize("algo", ["td3", "ddpg", "sac"])
def test_v1_checkpoints_load_into_each_algorithms_own_learner_state(algo):
    """The learner states keep the leaf names that checkpoints store (a field that one algorithm does not use is
    absent rather than None, and None held no leaves), so run folders of format 1 still load and act."""
    _, facts, state, header = load_state(FIXTURE_RUNS / algo)
    assert type(state.learner) is (SACLearner if algo == "sac" else DDPGLearner)
    assert len(jax.tree_util.tree_leaves(state)) == len(header["leaves"])
    assert int(state.global_step) == int(header["global_step"])
    policy = load(FIXTURE_RUNS / algo)
    obs = np.random.default_rng(0).normal(size=(8, facts.obs_dim)).astype(np.float32)
    action = policy(obs)
    assert action.shape == (8, facts.act_dim)
    assert np.all(action >= facts.action_low) and np.all(action <= facts.action_high)
    np.testing.assert_array_equal(action, policy(obs))


def _config(algo, out_dir, total, extra=()):
    sets = [
        f"{algo}.hidden=64,64",
        f"{algo}.learning_starts=1000",
        f"{algo}.steps_per_call=500",
        f"{algo}.buffer_size=20000",
        "run.compress_checkpoints=true",
        "run.tensorboard=false",
        f"run.out_dir={out_dir}",
        "run.checkpoint_every=0",
    ]
    return build_config("Pendulum-v1", algo=algo, seed=0, total_steps=total, sets=sets + list(extra))


# Pendulum-v1 (EnvPool, float32 actions): a random policy scores about -1200; -400 means it swings up and holds.
LEARNING = {"td3": (8000, -400.0), "ddpg": (6000, -400.0), "sac": (6000, -400.0)}


@pytest.fixture(scope="module")
def learned(tmp_path_factory):
    """One short Pendulum run per algorithm, trained on first use and shared by the tests below."""
    runs = {}

    def get(algo):
        if algo not in runs:
            runs[algo] = train(_config(algo, tmp_path_factory.mktemp(algo), LEARNING[algo][0]))
        return runs[algo]

    return get


@pytest.mark.slow
@pytest.mark.parametrize("algo", sorted(LEARNING))
def test_learns_pendulum_and_loads_as_a_deterministic_policy(algo, learned):
    result = learned(algo)
    policy = load(result.run_dir)
    score = evaluate(policy, episodes=10, deterministic=True, seed=0)
    assert score.mean >= LEARNING[algo][1], (algo, score.returns)

    obs = np.random.default_rng(0).normal(size=(16, 3)).astype(np.float32)
    first = policy(obs)
    np.testing.assert_array_equal(first, policy(obs))
    assert first.shape == (16, 1) and np.all(np.abs(first) <= 2.0)
    # The exported actor (dense layers, tanh, affine map onto the bounds) computes the same actions.
    config, facts, state, _ = load_state(result.run_dir)
    exported = get_algorithm(algo).export_actor(config, state, facts)
    assert exported.squash and exported.output_slice == 1 and exported.activation == "relu"
    x = obs
    for i, (w, b) in enumerate(zip(exported.weights, exported.biases)):
        x = x @ w + b
        if i < len(exported.weights) - 1:
            x = np.maximum(x, 0.0)
    x = np.tanh(x[:, : exported.output_slice])
    low, high = exported.action_low, exported.action_high
    np.testing.assert_allclose(first, np.clip(low + (x + 1) / 2 * (high - low), low, high), rtol=1e-4, atol=1e-5)
    if algo == "sac":
        assert not np.allclose(policy(obs, deterministic=False, seed=1), first)


def test_best_checkpoint_holds_the_policy_without_the_replay_buffer(tmp_path):
    """best.npz is read only for its policy: it leaves the buffer out, and loads and acts as the full state of the
    same step does."""
    extra = ["run.eval_every=1000", "run.eval_episodes=1", "run.checkpoint_every=1000", "run.keep_checkpoints=10"]
    extra.append("run.compress_checkpoints=false")
    result = train(_config("td3", tmp_path, 2000, extra))
    best = checkpoint.best_path(result.run_dir)
    arrays, header = checkpoint.read(best)
    assert header["left_out"] and all(name.startswith("buffer/") for name in header["left_out"])
    assert not any(name.startswith("buffer/") for name in arrays)
    full_path = run_folder.checkpoint_path(result.run_dir, header["global_step"])
    full, _ = checkpoint.read(full_path)
    # obs, action, reward and next obs of the filled part: the zero rows after it are not written, nor any of the
    # terminal flags, all zero on Pendulum, which never terminates
    buffer_bytes = int(full["buffer/size"]) * (3 + 1 + 1 + 3) * 4
    assert 1000 < int(full["buffer/size"]) < 20_000 and full["buffer/data/obs"].shape == (20_000, 3)
    assert best.stat().st_size + buffer_bytes <= full_path.stat().st_size
    for name, value in arrays.items():
        np.testing.assert_array_equal(value, full[name])
    # The disk warning counted the rows this 2,000-step run can fill (up to the end of the iteration that reaches
    # it), not the buffer's 20,000: its estimate is the largest checkpoint written, give or take Pendulum's terminal
    # flags, which stay zero, and the rows the run's last iteration left unfilled.
    config, _, state, _ = load_state(result.run_dir)
    estimate = state_bytes(state, get_algorithm("td3").filled_rows(config))
    largest = max(path.stat().st_size for path in run_folder.list_checkpoints(result.run_dir))
    assert largest <= estimate < 1.1 * largest, (largest, estimate)
    assert state_bytes(state) > 2.5 * largest  # the whole buffer: 640 KB of transitions
    obs = np.random.default_rng(0).normal(size=(8, 3)).astype(np.float32)
    np.testing.assert_array_equal(load(result.run_dir, checkpoint="best")(obs), load(result.run_dir, full_path)(obs))
    # A resume reads the newest full checkpoint, never best.npz, and carries on.
    assert train(resume_config(result.run_dir, 3000), resume=result.run_dir).global_step >= 3000


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_onnx_export_of_an_off_policy_run_matches_canter_load(algo, learned, tmp_path):
    ort = pytest.importorskip("onnxruntime")
    run_dir = learned(algo).run_dir
    out = tmp_path / f"{algo}.onnx"
    assert main(["export", str(run_dir), "--out", str(out)]) == 0
    # Far outside the training distribution too, so that the tanh squash and the bounds are exercised.
    obs = (np.random.default_rng(1).normal(size=(64, 3)) * np.repeat([[1.0], [50.0]], 32, axis=0)).astype(np.float32)
    session = ort.InferenceSession(out.read_bytes(), providers=["CPUExecutionProvider"])
    got = session.run(["action"], {"obs": obs})[0]
    np.testing.assert_allclose(got, load(run_dir)(obs), rtol=0, atol=1e-5)


@pytest.mark.slow
def test_resume_restores_the_replay_buffer_and_is_deterministic(learned, tmp_path):
    source = learned("td3").run_dir  # its checkpoint is compressed (run.compress_checkpoints)
    _, _, before, header = load_state(source)
    steps = int(header["global_step"])
    assert int(before.buffer.size) == steps and int(before.learner.updates) > 0
    copies = [tmp_path / "a", tmp_path / "b"]
    for copy in copies:
        shutil.copytree(source, copy)
    results = [train(resume_config(copy, steps + 1000), resume=copy) for copy in copies]
    s1, s2 = (load_state(r.run_dir)[2] for r in results)
    same = [
        np.array_equal(np.asarray(a), np.asarray(b))
        for a, b in zip(jax.tree_util.tree_leaves(s1), jax.tree_util.tree_leaves(s2))
    ]
    assert all(same), "two resumes of one checkpoint must be identical"
    assert int(s1.buffer.size) == results[0].global_step >= steps + 1000
    assert int(s1.learner.updates) > int(before.learner.updates)
    # The transitions stored before the checkpoint are still there after resuming.
    np.testing.assert_array_equal(np.asarray(s1.buffer.data.obs)[:steps], np.asarray(before.buffer.data.obs)[:steps])


@pytest.mark.slow
@pytest.mark.parametrize("checkpoint_every", [0, 1])
def test_non_finite_observation_keeps_the_last_good_state_despite_donation(tmp_path, checkpoint_every):
    """Without checkpoints the state handed back is saved. With a checkpoint after every call, the one before the
    failed call is kept: the state handed back holds that call's finite transitions in its buffer, which its step
    counter does not count, so a resume from it could not be exact."""
    config = build_config(
        "canter_test_envs:NaNAfter-v0",
        algo="td3",
        total_steps=50_000,
        sets=[
            "td3.hidden=8",
            "td3.learning_starts=50",
            "td3.steps_per_call=120",
            "td3.batch_size=16",
            "run.tensorboard=false",
            f"run.checkpoint_every={checkpoint_every}",
            f"run.out_dir={tmp_path}",
        ],
    )
    with pytest.raises(CanterError, match=r"non-finite .* after step \d+"):
        train(config)
    run_dir = next(tmp_path.iterdir())
    _, _, state, header = load_state(run_dir)
    assert int(header["global_step"]) == int(state.global_step) < 300
    leaves = jax.tree_util.tree_leaves(state)
    assert all(np.isfinite(np.asarray(x)).all() for x in leaves if np.issubdtype(np.asarray(x).dtype, np.floating))
    if checkpoint_every:
        assert int(state.buffer.size) == int(state.global_step)  # every stored transition a counted step


class _PoisonsItsActor(TD3):
    """TD3 whose every update leaves a NaN actor, as a diverged gradient step would."""

    def update(self, state, batch, key):
        new, diagnostics = super().update(state, batch, key)
        return new._replace(actor=jax.tree_util.tree_map(lambda x: x * jnp.nan, new.actor)), diagnostics


def test_a_non_finite_action_is_never_stored_even_where_the_env_returns_finite_values():
    """The counter env ignores its action, as MuJoCo ignores a NaN control, so only the action shows the fault."""
    config = build_config(
        "Pendulum-v1",
        algo="td3",
        sets=["env.num_envs=2", "env.normalize_obs=false", "td3.steps_per_call=20", "td3.learning_starts=4"]
        + ["td3.buffer_size=64", "td3.batch_size=4", "td3.hidden=4", "td3.noise=none"],
    )
    state, _, metrics = run_counter_iteration(config, _PoisonsItsActor(config.td3))
    size = int(state.buffer.size)
    assert not bool(metrics["finite"]) and 0 < size < 20
    assert np.isfinite(np.asarray(state.buffer.data.action[:size])).all()


@pytest.mark.parametrize(
    "sets, message",
    [
        (["td3.buffer_size=100", "td3.batch_size=256"], "td3.buffer_size 100 is smaller than td3.batch_size 256"),
        (
            ["sac.buffer_size=8", "sac.batch_size=4", "env.num_envs=16"],
            "sac.buffer_size 8 is smaller than env.num_envs 16, the rows one step inserts; raise sac.buffer_size",
        ),
        (["sac.tau=1.5"], r"sac.tau must be in \(0, 1\]"),
        (["ddpg.tau=0"], r"ddpg.tau must be in \(0, 1\]"),
        (["ddpg.noise=pink"], "ddpg.noise must be gaussian, ou or none"),
        (["sac.noise=gaussian"], "sac.noise must be none"),
        (["td3.policy_delay=0"], "td3.policy_delay must be >= 1"),
        (["sac.alpha=0"], "sac.alpha must be > 0"),
    ],
)
def test_bad_hyperparameters_are_refused_before_any_work(sets, message):
    with pytest.raises(CanterError, match=message):
        build_config("Pendulum-v1", algo=sets[0].partition(".")[0], sets=sets)


def test_cli_refusal_is_one_line(capsys):
    assert main(["train", "Pendulum-v1", "--algo", "td3", "--set", "td3.buffer_size=10", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "td3.buffer_size 10 is smaller than td3.batch_size 256" in err


@pytest.mark.parametrize("algo", ["td3", "ddpg", "sac"])
@pytest.mark.parametrize("low, high", [((-np.inf,), (np.inf,)), ((-1.0,), (np.inf,)), ((0.5,), (0.5,))])
def test_an_action_box_without_finite_width_is_refused_with_the_algorithms_that_train_it(algo, low, high):
    from canter.algos import get_algorithm
    from canter.envs.base import EnvSpec

    spec = EnvSpec("my:Env-v0", "gymnasium", 1, 3, 1, low, high, 10, ())
    config = build_config("Pendulum-v1", algo=algo)
    with pytest.raises(CanterError) as refused:
        get_algorithm(algo).validate(config, spec)
    assert str(refused.value) == (
        f"{algo} needs finite action bounds (it squashes actions with tanh); my:Env-v0 has low={list(low)} "
        f"high={list(high)}; give the env a finite action box with high > low, or train it with --algo ppo, rpo or "
        f"trpo, whose Gaussian policies need no bounds"
    )


def test_presets_give_off_policy_runs_one_env_and_raw_observations():
    for preset in ("fast", "cleanrl"):
        for algo in ("td3", "ddpg", "sac"):
            config = build_config("HalfCheetah-v4", preset=preset, algo=algo)
            assert config.env.num_envs == 1 and not config.env.normalize_obs and not config.env.normalize_reward
    assert build_config("HalfCheetah-v4", preset="fast").env.num_envs == 16  # ppo keeps its own
    seed = build_config("BipedalWalker-v3", preset="report002-ddpg")
    assert seed.run.algo == "ddpg" and seed.env.num_envs == 4 and seed.ddpg.batch_size == 512
    assert seed.ddpg.tau == 0.001 and seed.ddpg.train_freq == 16 and seed.ddpg.noise_std == pytest.approx(0.89066, 1e-4)


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_a_seed_in_a_group_follows_its_single_seed_curve(algo, tmp_path, capsys):
    """`canter train --algo td3 --seeds 0,1` runs the same iteration under jax.vmap. Measured on this tiny run: the
    counts and returns are identical and the losses differ by at most 4e-6 (sac's critic loss, about 3-80); the
    bounds are about 25x that, and far below the difference between two seeds."""
    import csv

    from canter.training.run_folder import read_config

    sets = [
        f"{algo}.hidden=16,16",
        "run.tensorboard=false",
        f"{algo}.learning_starts=100",
        f"{algo}.buffer_size=1000",
        f"{algo}.batch_size=32",
        f"{algo}.steps_per_call=100",
        "run.checkpoint_every=200",
    ]
    config = build_config(
        "Pendulum-v1", total_steps=400, seed=1, sets=sets + [f"run.out_dir={tmp_path / 'alone'}"], algo=algo
    )
    alone = train(config, quiet=True)
    argv = [
        "train",
        "Pendulum-v1",
        "--algo",
        algo,
        "--seeds",
        "0,1",
        "--total-steps",
        "400",
        "--quiet",
        "--out-dir",
        str(tmp_path / "group"),
    ]
    assert main(argv + [arg for s in sets for arg in ("--set", s)]) == 0
    # The CLI points at the faster way to train several off-policy seeds.
    assert f"canter: note: {algo} seeds train faster one per process" in capsys.readouterr().err
    by_seed = {read_config(d).run.seed: d for d in (tmp_path / "group").iterdir()}

    def columns(run_dir):
        with open(run_dir / "metrics.csv") as f:
            rows = list(csv.DictReader(f))
        return {k: np.array([float(r[k]) if r[k] else np.nan for r in rows]) for k in rows[0]}

    a, g, other = columns(alone.run_dir), columns(by_seed[1]), columns(by_seed[0])
    assert len(a["global_step"]) == len(g["global_step"]) >= 4
    for name in ("global_step", "episodes", "episodic_length", "gradient_steps", "buffer_size"):
        np.testing.assert_array_equal(g[name], a[name], err_msg=name)
    np.testing.assert_allclose(g["episodic_return"], a["episodic_return"], rtol=1e-5)
    for name in ("critic_loss", "actor_loss", "q_mean"):
        np.testing.assert_allclose(g[name], a[name], rtol=1e-4, atol=1e-4, err_msg=name)
    assert not np.allclose(other["critic_loss"][1:], a["critic_loss"][1:], rtol=1e-2)  # another seed really differs


@pytest.mark.slow
def test_vmapped_sac_seeds_keep_finite_gradients_however_xla_rounds_their_critics_minimum(tmp_path):
    """With XLA's optimizations off, the vmapped sac group above once diverged at its first update: the gradient of
    `jnp.min` over the critics divided by the count of entries equal to a minimum computed with other rounding, 0.
    The pairwise minimum (`losses.min_over_critics`) keeps it finite, whatever the compiler does."""
    import os
    import subprocess
    import sys

    sets = ["sac.hidden=16,16", "run.tensorboard=false", "sac.learning_starts=100", "sac.buffer_size=1000"]
    sets += ["sac.batch_size=32", "sac.steps_per_call=100"]
    argv = [sys.executable, "-m", "canter.cli", "train", "Pendulum-v1", "--algo", "sac", "--seeds", "0,1"]
    argv += ["--total-steps", "400", "--quiet", "--out-dir", str(tmp_path)]
    argv += [arg for item in sets for arg in ("--set", item)]
    env = {**os.environ, "JAX_DISABLE_MOST_OPTIMIZATIONS": "true"}
    done = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr
    for run_dir in tmp_path.iterdir():
        assert (read_summary(run_dir) or {}).get("stop_reason") == "budget", run_dir


def test_a_signal_during_setup_saves_no_replay_buffer_and_the_run_resumes_as_if_uninterrupted(tmp_path):
    """At step 0 the buffer is all zeros, as reading a left-out field back gives it: a Ctrl-C in setup writes the
    policy's few kilobytes rather than the buffer, and the resumed run is the one that was never stopped."""
    with sigterm_during_setup():
        stopped = train(
            _config("sac", tmp_path / "stopped", 1500, ["sac.buffer_size=1000000", "run.compress_checkpoints=false"])
        )
    saved = checkpoint.latest(stopped.run_dir)
    assert stopped.stop_reason == "signal" and saved.name == "ckpt_000000000000.npz"
    assert saved.stat().st_size < 1_000_000  # a million transitions of Pendulum's would be about 36 MB
    assert any(name.startswith("buffer/") for name in checkpoint.read_header(saved)["left_out"])

    resumed = train(resume_config(stopped.run_dir, 1500), resume=stopped.run_dir)
    uninterrupted = train(_config("sac", tmp_path / "uninterrupted", 1500, ["sac.buffer_size=1000000"]))
    assert resumed.global_step == uninterrupted.global_step
    a, b = load_state(resumed.run_dir)[2], load_state(uninterrupted.run_dir)[2]
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


# ---------------------------------------------------------------------------------- the env loop's pure pieces


def test_count_step_counts_env_steps_and_skips_a_vector_step_that_stored_nothing():
    global_step, vector_steps = jnp.asarray(10, jnp.int32), jnp.asarray(3, jnp.int32)
    for valid, expected in [([True, True, False], (12, 4, True)), ([False, False, False], (10, 3, False))]:
        got = count_step(global_step, vector_steps, jnp.asarray(valid))
        assert (int(got[0]), int(got[1]), bool(got[2])) == expected


def test_should_train_matches_its_rule_on_every_case():
    cfg = SimpleNamespace(learning_starts=100, train_freq=3)
    for stored in (False, True):
        for healthy in (False, True):
            for global_step in (99, 100, 250):
                for vector_steps in range(1, 7):
                    expected = stored and healthy and global_step >= 100 and vector_steps % 3 == 0
                    got = should_train(
                        cfg,
                        jnp.asarray(stored),
                        jnp.asarray(healthy),
                        jnp.asarray(global_step),
                        jnp.asarray(vector_steps),
                    )
                    assert bool(got) == expected, (stored, healthy, global_step, vector_steps)


def test_next_ou_state_holds_on_autoreset_steps_and_restarts_where_episodes_end():
    old = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]], np.float32)
    new = np.array([[7.0, 8.0], [9.0, 10.0], [11.0, 12.0]], np.float32)
    valid = np.array([True, False, True])
    done = np.array([False, False, True])
    got = np.asarray(next_ou_state(jnp.asarray(old), jnp.asarray(new), jnp.asarray(valid), jnp.asarray(done)))
    expected = np.empty_like(old)
    for i in range(3):  # a plain loop over the envs
        expected[i] = (new[i] if valid[i] else old[i]) * (0.0 if done[i] else 1.0)
    np.testing.assert_array_equal(got, expected)
