"""The mjx backend: Gymnasium's v5 tasks ported to MJX, checked against the Gymnasium backend (C MuJoCo), its episode
semantics, exact resume with episodes in flight, vmapped seeds, a policy moved between backends, and bad input.

Equivalence is measured two ways, with uniform random actions:
- each step from the same state: before every step the MJX state is set to C MuJoCo's full `MjData`
  (`mjx.put_data`), both take the same action, and observation, reward, info and termination are compared. This
  checks the port (observations, rewards, terminations) on every step of a trajectory.
- free-running: both start from the same state and run on their own. Random actions make HalfCheetah and Ant
  chaotic: C MuJoCo against itself, one copy moved by 1e-9 in qpos, differs by 0.5% (HalfCheetah) and 2e-5 (Ant)
  after 50 steps and by 10-20% after 100. So free-running is tested on the two tasks that `make test` keeps,
  InvertedPendulum and Hopper, which stay close (measured on this machine in float32 over 200 steps: relative
  error 2.6e-7 and 3.3e-6; Walker2d 4.7e-8 in float64).

Tolerances are relative to 1 + |value|: 1e-4 on observations, rewards and info; on observations, 4 to 7 times the
float32 error measured on this machine (benchmarks/mjx_equivalence/results.md) for HalfCheetah (9.6e-5), Humanoid
(5.0e-4), HumanoidStandup (2.8e-4) and Ant (5.2e-3), whose observations hold contact forces (cfrc_ext, up to
thousands) from a Newton solve. Rewards and info keep 1e-4 (Ant 2e-4: measured 2.4e-5 and 4.0e-5), tight enough that
a dropped or misweighted cost term fails: Ant's whole contact cost moves its reward by up to 6e-3 on this trajectory.
MJX compiles take about 25 s per task on this CPU, so `make test` runs InvertedPendulum and Hopper only;
`pytest --run-heavy -m heavy tests/test_mjx_backend.py` runs every task.
"""

import csv
import json
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from canter.config.build import build_config
from canter.core.runtime import setup_jax
from canter.envs.functional import FunctionalVecEnv, x64_enabled
from canter.envs.registry import resolve_backend
from canter.errors import CanterError
from conftest import TINY, error_line

pytestmark = pytest.mark.slow

TESTED = ("InvertedPendulum-v5", "Hopper-v5")
OTHERS = ("HalfCheetah-v5", "Walker2d-v5", "Ant-v5", "Humanoid-v5", "HumanoidStandup-v5")
LOOSE = {"HalfCheetah-v5": 5e-4, "Ant-v5": 3e-2, "Humanoid-v5": 2e-3, "HumanoidStandup-v5": 2e-3}  # observations
REWARD_LOOSE = {"Ant-v5": 2e-4}  # rewards and info


@pytest.fixture(autouse=True)
def _float32_jax():
    setup_jax("mjx")


def _rel(a, b):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.max(np.abs(a - b) / (1.0 + np.abs(b))))


def _pair(env_id):
    import gymnasium as gym

    from canter.envs.mjx.env import MjxTaskEnv

    ported = MjxTaskEnv(env_id)
    reference = gym.make(env_id)
    reference.unwrapped.model.opt.solver = ported.mj_model.opt.solver  # Newton where the XML asks for PGS
    reference.reset(seed=3)
    return ported, reference


def _put_data(model, data):
    """C MuJoCo's `MjData` as an MJX state, in host arrays: the device arrays `mjx.put_data` makes are committed to
    their device, which the compiled step's signature records, so their step would be another program than the one
    that steps the states `from_state` returns (test_free_running_...)."""
    from mujoco import mjx

    return jax.tree.map(np.asarray, mjx.put_data(model, data))


def _each_step_from_the_same_state(env_id, steps=100):
    ported, reference = _pair(env_id)
    model, data = reference.unwrapped.model, reference.unwrapped.data
    step = jax.jit(ported.step)
    rng = np.random.default_rng(0)
    tolerance, reward_tolerance = LOOSE.get(env_id, 1e-4), REWARD_LOOSE.get(env_id, 1e-4)
    terminations = 0
    for i in range(steps):
        state = _put_data(model, data)
        action = rng.uniform(reference.action_space.low, reference.action_space.high).astype(np.float32)
        obs, reward, terminated, _, info = reference.step(action)
        _, p_obs, p_reward, p_terminated, p_info = step(state, jnp.asarray(action))
        assert _rel(p_obs, obs) < tolerance, (i, _rel(p_obs, obs))
        assert _rel(p_reward, reward) < reward_tolerance, (i, float(p_reward), reward)
        for key in p_info:
            assert _rel(p_info[key], info[key]) < reward_tolerance, (i, key, float(p_info[key]), info[key])
        assert bool(p_terminated) == terminated, i
        if terminated:
            terminations += 1
            reference.reset()
    # A diverged state: C MuJoCo resets to the rest pose at the next step's start and steps on with zero controls,
    # whatever the action (which still sets the control cost, except of Humanoid and HumanoidStandup: Gymnasium costs
    # their controls after the step, which the reset zeroed).
    data.qvel[:] = 1e20
    state = _put_data(model, data)
    action = reference.action_space.high.astype(np.float32)
    obs, reward, terminated, _, _ = reference.step(action)
    _, p_obs, p_reward, p_terminated, _ = step(state, jnp.asarray(action))
    assert np.isfinite(obs).all() and _rel(p_obs, obs) < tolerance, _rel(p_obs, obs)
    assert _rel(p_reward, reward) < reward_tolerance and bool(p_terminated) == terminated, (float(p_reward), reward)
    return terminations


@pytest.mark.parametrize("env_id", TESTED)
def test_each_step_matches_gymnasium_from_the_same_state(env_id):
    terminations = _each_step_from_the_same_state(env_id)
    # Random actions topple both, so the terminating step (no healthy reward) and resets are covered.
    assert terminations > (5 if env_id == "InvertedPendulum-v5" else 0)


@pytest.mark.heavy
@pytest.mark.parametrize("env_id", OTHERS)
def test_every_port_matches_gymnasium_from_the_same_state(env_id):
    _each_step_from_the_same_state(env_id)


@pytest.mark.heavy
@pytest.mark.parametrize("height", [1.1, 1.5])
def test_ant_terminates_above_its_healthy_heights_without_the_healthy_reward(height):
    """Random actions never topple the Ant in the trajectory above, so its termination is set up here: lifted above
    1.0, it falls for one step and ends there (below 0.2 the torso would sit in the floor, which pushes it out)."""
    ported, reference = _pair("Ant-v5")
    model, data = reference.unwrapped.model, reference.unwrapped.data
    data.qpos[2] = height
    state, action = _put_data(model, data), np.zeros(model.nu, np.float32)
    _, reward, terminated, _, info = reference.step(action)
    _, _, p_reward, p_terminated, p_info = jax.jit(ported.step)(state, jnp.asarray(action))
    assert terminated and bool(p_terminated) and float(p_info["reward_survive"]) == info["reward_survive"] == 0.0
    assert _rel(p_reward, reward) < REWARD_LOOSE["Ant-v5"]


# Hopper free-running (21 s) is heavy: its per-step check above runs in `make test`.
@pytest.mark.parametrize("env_id", ["InvertedPendulum-v5", pytest.param("Hopper-v5", marks=pytest.mark.heavy)])
def test_free_running_stays_with_gymnasium_for_200_steps(env_id):
    ported, reference = _pair(env_id)
    data = reference.unwrapped.data
    sync = jax.jit(ported.from_state)
    step = jax.jit(ported.step)
    state, obs = sync(data.qpos.copy(), data.qvel.copy())
    rng = np.random.default_rng(1)
    for i in range(200):
        action = rng.uniform(reference.action_space.low, reference.action_space.high).astype(np.float32)
        ref_obs, ref_reward, ref_terminated, _, _ = reference.step(action)
        state, obs, reward, terminated, _ = step(state, jnp.asarray(action))
        assert _rel(obs, ref_obs) < 1e-4, (i, _rel(obs, ref_obs))
        assert _rel(reward, ref_reward) < 1e-4, i
        assert bool(terminated) == ref_terminated, i
        if ref_terminated:  # both restart from Gymnasium's next reset state
            reference.reset()
            state, obs = sync(data.qpos.copy(), data.qvel.copy())


def test_reset_noise_is_gymnasiums_distribution():
    from canter.envs.mjx.env import MjxTaskEnv

    env = MjxTaskEnv("Hopper-v5")
    states, _ = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 500))  # one compile, not per op
    noise = np.asarray(states.qpos) - np.asarray(env.mj_model.qpos0)
    assert np.all(np.abs(noise) <= 5e-3 + 1e-7)
    assert abs(noise.std() - 5e-3 / np.sqrt(3)) < 1.5e-4  # U(-0.005, 0.005): std 2.9e-3, 3000 draws
    velocity = np.asarray(states.qvel)  # from rest, so the noise itself
    assert np.all(np.abs(velocity) <= 5e-3 + 1e-7) and abs(velocity.std() - 5e-3 / np.sqrt(3)) < 1.5e-4
    # HalfCheetah's velocities get normal noise, 0.1 * N(0, 1); its positions uniform, U(-0.1, 0.1).
    cheetah = MjxTaskEnv("HalfCheetah-v5")
    states, _ = jax.jit(jax.vmap(cheetah.reset))(jax.random.split(jax.random.PRNGKey(1), 500))
    velocity = np.asarray(states.qvel)
    assert abs(velocity.std() - 0.1) < 4e-3 and np.abs(velocity).max() > 0.25  # 4500 draws: beyond 2.5 std
    positions = np.asarray(states.qpos) - np.asarray(cheetah.mj_model.qpos0)
    assert np.all(np.abs(positions) <= 0.1 + 1e-6) and abs(positions.std() - 0.1 / np.sqrt(3)) < 3e-3


def _pendulum(num_envs, seeds):
    from canter.envs.mjx.env import MjxTaskEnv

    return FunctionalVecEnv(
        MjxTaskEnv("InvertedPendulum-v5").functional(), "InvertedPendulum-v5", "mjx", num_envs, seeds
    )


def test_episode_semantics_are_envpools():
    """The step that ends an episode reports it; the next one ignores its action and returns a fresh reset, reward 0
    and both flags false. Truncation at the step limit works the same way."""
    env = _pendulum(2, [5, 6])
    first = env.reset()
    assert abs(first[0, 1]) < 0.011  # within the reset noise
    # Four steps before the 1000-step limit: the limit stays the task's, so this steps with the program that the
    # evaluation tests below compile for 2 envs (the limit is a constant of the program).
    state, first_obs = env._started
    env._started = (state._replace(elapsed=state.elapsed + env.spec.max_episode_steps - 4), first_obs)
    hold = np.zeros((2, 1), np.float32)
    for _ in range(3):
        out = env.host_step(hold)
        assert not out.truncated.any() and not out.terminated.any()
    out = env.host_step(hold)
    assert out.truncated.all() and not out.terminated.any()
    out = env.host_step(np.full((2, 1), 3.0, np.float32))  # ignored: an autoreset step
    assert not out.truncated.any() and not out.terminated.any() and np.all(out.reward == 0)
    assert np.all(np.abs(out.obs[:, :2]) <= 0.0101)
    # Push one env over: it terminates, with reward 0 (InvertedPendulum pays 1 per upright step).
    for _ in range(50):
        out = env.host_step(np.array([[3.0], [0.0]], np.float32))
        if out.terminated[0]:
            break
    assert out.terminated[0] and out.reward[0] == 0
    after = env.host_step(np.zeros((2, 1), np.float32))
    assert not after.terminated[0] and after.reward[0] == 0 and abs(after.obs[0, 1]) < 0.011


def test_env_seeds_choose_the_reset_states():
    a = _pendulum(2, [1, 2]).reset()
    b = _pendulum(2, [1, 2]).reset()
    c = _pendulum(2, [3, 2]).reset()
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a[0], c[0])
    np.testing.assert_array_equal(a[1], c[1])  # each env's stream depends on its own seed only


def test_an_env_without_a_port_lists_the_ported_ones():
    with pytest.raises(CanterError) as error:
        resolve_backend("Swimmer-v5", "mjx")
    message = str(error.value)
    assert "Swimmer-v5" in message and "Hopper-v5" in message and "HumanoidStandup-v5" in message
    assert resolve_backend("Hopper-v5", "auto") != "mjx"  # `auto` never picks a JAX-native backend


# The tests below share compiled programs through the session's compile cache (conftest.py), each compiled once:
# - the training tests train with this config, so their runs compile one iteration program. The learning rate stays
#   constant so that a stop and a resume (two budgets) follow the same schedule as one straight run;
# - the evaluation tests play EVAL_EPISODES on 2 envs (one plays 3 episodes, the other 2) with a policy of this
#   config's sizes: one evaluation program, and the host loop's reset and step of test_env_registry's mjx case.
PENDULUM = TINY + [
    "env.num_envs=16",
    "env.backend=mjx",
    "ppo.n_steps=64",
    "ppo.minibatch_size=128",
    "ppo.anneal_lr=false",
    "net.hidden=32,32",
    "run.checkpoint_every=512",
]
ITERATION = 16 * 64  # env steps: env.num_envs x ppo.n_steps
TOTAL = 32 * ITERATION  # PPO balances InvertedPendulum by then (seeds 0-5 by 24 iterations on this CPU)
EVAL_EPISODES = 5


def _evaluate_on_two_envs(monkeypatch):
    import canter.training.evaluation

    monkeypatch.setattr(canter.training.evaluation, "MAX_EVAL_ENVS", 2)
    monkeypatch.setattr(canter.training.evaluation, "MAX_JAX_EVAL_ENVS", 2)


def _rows(run_dir):
    with open(run_dir / "metrics.csv") as f:
        return [{k: v for k, v in row.items() if k not in ("wall_time", "sps")} for row in csv.DictReader(f)]


def test_a_resumed_run_continues_its_episodes_exactly(tmp_path):
    """Three iterations straight, against two, a stop and a resume for the third (an iteration counts fewer env
    steps than ITERATION, as reset steps do not count: the budgets of ITERATION and 2 x ITERATION steps end after
    two and three): every metrics row and every parameter are the same, so the episodes in flight at the stop (their
    state, step counts, running returns and reset keys) were restored, not restarted."""
    from canter.training.loop import train
    from canter.training.restore import load_state

    def config(total, folder):
        sets = PENDULUM + [f"run.out_dir={tmp_path / folder}"]
        return build_config("InvertedPendulum-v5", seed=0, total_steps=total, sets=sets)

    straight = train(config(2 * ITERATION, "straight"))
    first = train(config(ITERATION, "parts"))
    resumed = train(config(2 * ITERATION, "parts"), resume=first.run_dir)
    assert _rows(straight.run_dir) == _rows(resumed.run_dir)
    a, b = load_state(straight.run_dir)[2], load_state(resumed.run_dir)[2]
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(x, y)


def test_a_diverged_mjx_run_stops_with_its_last_good_state_and_env_carry(tmp_path, capsys):
    """A learning rate of 100 takes InvertedPendulum's policy to NaN in its second iteration. The run stops with one
    line naming the last good step; the newest checkpoint is that step's, whose parameters and episodes in flight
    (the env carry that a resume continues) are finite; and a resume diverges again, with the same line."""
    from canter.training import checkpoint
    from canter.training.restore import load_state

    sets = ["ppo.lr=100", "env.num_envs=4", "ppo.n_steps=16", "ppo.minibatch_size=32", "run.checkpoint_every=64"]
    sets += TINY + [f"run.out_dir={tmp_path / 'runs'}"]
    argv = ["train", "InvertedPendulum-v5", "--backend", "mjx", "--total-steps", "3000"]
    stopped = error_line(capsys, argv + [arg for item in sets for arg in ("--set", item)])
    found = re.match(r"non-finite .* after step (\d+); stopped, last good state saved in ", stopped)
    assert found, stopped
    (run_dir,) = (tmp_path / "runs").iterdir()
    arrays, header = checkpoint.read(checkpoint.resolve(run_dir))
    assert header["global_step"] == int(found.group(1)) > 0
    params = load_state(run_dir)[2].params
    assert all(np.isfinite(leaf).all() for leaf in jax.tree.leaves(params))
    carry = {name: arrays[name] for name in header["env_carry_leaves"]}
    assert "env_carry/obs" in carry and "env_carry/env_state/physics/qpos" in carry
    assert [name for name, leaf in carry.items() if leaf.dtype.kind == "f" and not np.isfinite(leaf).all()] == []
    assert error_line(capsys, ["train", "--resume", str(run_dir)]) == stopped


def test_ppo_learns_on_mjx_and_the_policy_moves_to_cpu_mujoco(tmp_path, monkeypatch, capsys):
    """A policy trained on MJX physics, with its normalizer statistics, balances the same task stepped by C MuJoCo
    (the Gymnasium backend): the ports keep observations and actions identical, so policies move between backends.
    Its evaluation during training, asked of C MuJoCo (run.eval_backend=auto), is `canter eval --backend envpool`."""
    from canter.training import checkpoint
    from canter.training.loop import train
    from canter.use.evaluate import evaluate
    from canter.use.policy import load

    sets = PENDULUM + [f"run.out_dir={tmp_path}", f"run.eval_every={TOTAL}", "run.eval_episodes=4"]
    sets.append("run.eval_backend=auto")
    result = train(build_config("InvertedPendulum-v5", seed=0, total_steps=TOTAL, sets=sets))
    policy = load(result.run_dir)
    with monkeypatch.context() as patch:
        _evaluate_on_two_envs(patch)
        on_mjx = evaluate(policy, episodes=EVAL_EPISODES, seed=0)
        _eval_with_other_physics(patch, result.run_dir, capsys)
    on_cpu = evaluate(policy, episodes=8, seed=0, backend="gymnasium")
    assert on_mjx.mean >= 900, on_mjx.returns
    assert on_cpu.mean >= 900, on_cpu.returns
    # The user's commands: evaluated on EnvPool's C MuJoCo, and rendered through the CPU backends.
    from canter.cli.main import main
    from canter.core import runtime

    monkeypatch.setattr(runtime, "_cpu_notice_given", False)
    capsys.readouterr()
    assert main(["eval", str(result.run_dir), "--backend", "envpool", "--episodes", "4", "--json", "e.json"]) == 0
    assert "no GPU found" not in capsys.readouterr().err  # nothing steps on mjx here
    on_envpool = json.loads(Path("e.json").read_text())["runs"][0]
    assert on_envpool["return_mean"] >= 900
    during = checkpoint.read_header(checkpoint.best_path(result.run_dir))["evaluation"]
    assert during["backend"] == "envpool" and during["returns"] == on_envpool["returns"]
    assert main(["video", str(result.run_dir), "--episodes", "1", "--max-steps", "100", "--out", "v.mp4"]) == 0
    assert Path("v.mp4").stat().st_size > 0


def test_the_cpu_notice_comes_where_mjx_steps_not_where_its_policy_loads(monkeypatch, capsys):
    import jax

    from canter.core import runtime

    monkeypatch.setattr(runtime, "_cpu_notice_given", False)
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")  # as on a machine without a GPU, where it is said
    monkeypatch.setattr(runtime, "_cpu_fixed_for", None)  # as in a process whose first setup was for mjx
    runtime.setup_jax("mjx", announce=False)  # as loading an mjx run's checkpoint does
    for backend in ("envpool", "gymnasium", "auto", None):
        runtime.announce_physics(backend)
    assert capsys.readouterr().err == ""
    runtime.announce_physics("mjx")
    runtime.announce_physics("mjx")
    assert capsys.readouterr().err == "canter: no GPU found, so mjx steps its physics on the CPU (correct, but slow)\n"


def test_an_envpool_policy_evaluated_on_mjx_steps_mjx_in_float32_and_says_why_it_is_on_the_cpu(monkeypatch, capsys):
    """Loading an EnvPool run sets JAX up for it (float64, the CPU); its evaluation on mjx switches to float32
    physics, and its notice names the EnvPool setup, not a missing GPU, as what keeps MJX on the CPU."""
    from canter.core import runtime
    from canter.envs import registry
    from canter.use.evaluate import evaluate
    from canter.use.policy import load
    from conftest import ARCHIVED_RUN

    states = []

    def making(*args, **kwargs):
        env = make_vec_env(*args, **kwargs)
        states.append(env.state_shapes())  # traced in the precision it plays in, nothing computed
        return env

    make_vec_env = registry.make_vec_env
    monkeypatch.setattr(registry, "make_vec_env", making)
    monkeypatch.setattr(runtime, "_cpu_notice_given", False)
    monkeypatch.setattr(runtime, "_cpu_fixed_for", "envpool")  # as in a process that loaded it first
    policy = load(ARCHIVED_RUN)
    assert policy.facts.backend == "envpool" and x64_enabled()
    capsys.readouterr()
    result = evaluate(policy, episodes=2, env_id="InvertedPendulum-v5", backend="mjx")
    assert len(result.returns) == 2 and result.backend == "mjx"
    floats = {leaf.dtype for leaf in jax.tree.leaves(states) if jnp.issubdtype(leaf.dtype, jnp.floating)}
    assert floats == {jnp.dtype("float32")}
    assert capsys.readouterr().err == (
        "canter: mjx steps its physics on the CPU since this process set JAX up for envpool first, whose step runs "
        "only there (correct, but slow)\n"
    )


def test_an_envpool_run_evaluating_on_mjx_during_training_says_its_physics_is_float64(monkeypatch, capsys):
    from canter.core import runtime

    monkeypatch.setattr(runtime, "_cpu_notice_given", False)
    monkeypatch.setattr(runtime, "_cpu_fixed_for", "envpool")
    setup_jax("envpool", announce=False)  # the training program's precision, which its evaluations share
    runtime.announce_physics("mjx")
    assert capsys.readouterr().err == (
        "canter: mjx steps its physics on the CPU, in float64, since this process set JAX up for envpool first, "
        "whose step runs only there (correct, but slow)\n"
    )


def test_canter_eval_on_mjx_sets_jax_up_for_mjx_before_it_loads_an_envpool_run(tmp_path):
    """In a fresh process, `canter eval <EnvPool run> --backend mjx` chooses JAX's platform for MJX (the GPU where
    there is one), so on a machine without one its notice is the missing GPU's."""
    import subprocess
    import sys

    from conftest import ARCHIVED_RUN

    argv = ["eval", str(ARCHIVED_RUN), "--env", "InvertedPendulum-v5", "--backend", "mjx", "--episodes", "2"]
    argv += ["--json", str(tmp_path / "e.json")]
    done = subprocess.run([sys.executable, "-m", "canter.cli", *argv], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    notices = [line for line in done.stderr.splitlines() if line.startswith("canter: ")]
    assert notices == ["canter: no GPU found, so mjx steps its physics on the CPU (correct, but slow)"], done.stderr
    assert json.loads((tmp_path / "e.json").read_text())["runs"][0]["backend"] == "mjx"


def test_an_mjx_run_refused_on_its_settings_is_one_line_without_the_cpu_notice(monkeypatch, tmp_path, capsys):
    from canter.core import runtime

    monkeypatch.setattr(runtime, "_cpu_notice_given", False)
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    argv = ["train", "InvertedPendulum-v5", "--backend", "mjx", "--set", "env.num_envs=100000000"]
    line = error_line(capsys, [*argv, "--out-dir", str(tmp_path / "runs")])
    assert line.startswith("env.num_envs=100000000 needs about "), line
    assert not (tmp_path / "runs").exists()


def _eval_with_other_physics(monkeypatch, run_dir, capsys):
    """`canter eval --set` makes the eval envs with the physics settings asked for, and records them."""
    import canter.envs.mjx.env
    from canter.cli.main import main

    made = []
    real = canter.envs.mjx.env.functional_env

    def spy(env_id, **options):
        made.append(options)
        return real(env_id, **options)

    monkeypatch.setattr(canter.envs.mjx.env, "functional_env", spy)
    sets = ["--set", "env.solver_iterations=2", "--set", "env.solver_ls_iterations=3"]
    assert main(["eval", str(run_dir), *sets, "--episodes", "2", "--json", "physics.json"]) == 0
    assert made == [{"solver_iterations": 2, "solver_ls_iterations": 3}]
    row = json.loads(Path("physics.json").read_text())["runs"][0]
    assert row["backend"] == "mjx" and row["physics"] == made[0]
    assert (
        "physics: env.solver_iterations=2, env.solver_ls_iterations=3; the rest the model's own"
        in capsys.readouterr().out
    )


def test_solver_settings_reach_the_mjx_model_and_nothing_else():
    from canter.envs.mjx.env import MjxTaskEnv

    env = MjxTaskEnv("Hopper-v5", solver_iterations=4, solver_ls_iterations=6)
    assert (env.mj_model.opt.iterations, env.mj_model.opt.ls_iterations) == (4, 6)
    assert MjxTaskEnv("Hopper-v5").mj_model.opt.iterations == 100  # 0 keeps the XML's
    config = build_config("Hopper-v5", sets=["env.backend=mjx", "env.solver_iterations=4"])
    assert config.env.solver_iterations == 4
    with pytest.raises(CanterError, match=r"env.solver_iterations applies to the mjx backend only; add --backend mjx"):
        build_config("Hopper-v5", sets=["env.solver_iterations=4"])
    with pytest.raises(CanterError, match=r"env.solver_ls_iterations must be >= 0"):
        build_config("Hopper-v5", sets=["env.backend=mjx", "env.solver_ls_iterations=-1"])


def _contact_pairs(model, qpos) -> set[tuple[int, int]]:
    """The geom pairs in contact after C MuJoCo's mj_forward at `qpos`."""
    import mujoco

    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    return {tuple(sorted(pair)) for pair in data.contact.geom[: data.ncon].tolist()}


def test_floor_contacts_keep_the_floors_and_drop_the_rest():
    """env.contacts=floor: in a pose where the humanoid lies on the floor with its limbs crossed, C MuJoCo finds the
    same floor contacts with the changed model and no contact between body parts, which the XML's model has."""
    import mujoco

    from canter.envs.mjx.env import MjxTaskEnv, collide_with_floor_only, load_model
    from canter.envs.mjx.tasks import TASKS

    full = load_model(TASKS["Humanoid-v5"], "Humanoid-v5")
    floor_only = load_model(TASKS["Humanoid-v5"], "Humanoid-v5")
    collide_with_floor_only(floor_only)
    qpos = full.qpos0.copy()
    qpos[2] = 0.15  # the torso down on the floor
    qpos[7:] = np.random.default_rng(0).uniform(-1.2, 1.2, full.nq - 7)  # limbs bent into each other
    plane = {int(i) for i in np.flatnonzero(full.geom_type == mujoco.mjtGeom.mjGEOM_PLANE)}
    before, after = _contact_pairs(full, qpos), _contact_pairs(floor_only, qpos)
    on_floor = {pair for pair in before if plane & set(pair)}
    assert on_floor and before - on_floor  # the pose has both kinds, so the test can fail
    assert after == on_floor

    # Through the env: MJX sizes its contact arrays for the pairs that can collide.
    from canter.envs.mjx.library import import_mjx

    mjx = import_mjx()
    envs = {contacts: MjxTaskEnv("Humanoid-v5", contacts=contacts) for contacts in ("all", "floor")}
    assert envs["floor"].mj_model.geom_contype.tolist() == floor_only.geom_contype.tolist()
    datas = {name: mjx.make_data(env.model) for name, env in envs.items()}
    slots = {name: getattr(data, "_impl", data).contact.geom.shape[0] for name, data in datas.items()}
    assert slots == {"all": 138, "floor": 29}  # the figures that env.contacts' help gives
    with pytest.raises(CanterError, match=r"env.contacts=floor needs a model with a floor"):
        MjxTaskEnv("InvertedPendulum-v5", contacts="floor")


def test_contacts_setting_is_checked_and_reaches_the_mjx_env_only():
    from canter.envs.registry import env_options

    config = build_config("Humanoid-v5", sets=["env.backend=mjx", "env.contacts=floor"])
    assert env_options(config.env, "mjx") == {"contacts": "floor"}
    assert env_options(config.env, "envpool") == {}  # a CPU evaluation steps the XML's own model
    assert env_options(build_config("Humanoid-v5", sets=["env.backend=mjx"]).env, "mjx") == {}
    with pytest.raises(CanterError, match=r"env.contacts applies to the mjx backend only; add --backend mjx"):
        build_config("Humanoid-v5", sets=["env.contacts=floor"])
    with pytest.raises(CanterError, match=r"env.contacts must be all or floor, got 'none'"):
        build_config("Humanoid-v5", sets=["env.backend=mjx", "env.contacts=none"])


def test_evaluation_in_one_program_plays_the_host_loops_episodes(monkeypatch):
    """A JAX env plays an evaluation's episodes inside one jitted program (`play_episodes`); it keeps the host loop's
    bookkeeping: the same episodes, returns and lengths, each env its quota."""
    from canter.algos import get_algorithm
    from canter.envs.registry import make_vec_env
    from canter.training.evaluation import CompiledAct, run_episodes

    _evaluate_on_two_envs(monkeypatch)
    config = build_config("InvertedPendulum-v5", sets=PENDULUM)
    env = make_vec_env("InvertedPendulum-v5", "mjx", 2, [0, 1])
    algorithm = get_algorithm("ppo")
    state = algorithm.init_state(config, env.spec, 0)
    params, obs_stats = algorithm.policy_params(state), state.obs_stats
    act = CompiledAct(config, env.spec)

    def host_act(obs):
        return act(params, obs_stats, obs)

    host = run_episodes(host_act, "InvertedPendulum-v5", "mjx", EVAL_EPISODES, seed=3)
    traced = act.traced(params, obs_stats)
    jitted = run_episodes(host_act, "InvertedPendulum-v5", "mjx", EVAL_EPISODES, seed=3, traced_act=traced)
    assert jitted.returns.size == host.returns.size == EVAL_EPISODES
    np.testing.assert_allclose(np.sort(jitted.returns), np.sort(host.returns), rtol=1e-5)
    np.testing.assert_array_equal(np.sort(jitted.lengths), np.sort(host.lengths))


def test_a_jax_env_plays_every_evaluation_episode_on_its_own_env():
    """Host-stepped backends share up to MAX_EVAL_ENVS envs between the episodes; a JAX-native one gives each
    episode its own env, so the episodes play side by side instead of one after another."""
    from canter.training.evaluation import MAX_EVAL_ENVS, eval_env_count

    assert eval_env_count("mjx", 128) == 128
    assert eval_env_count("gymnasium", 128) == MAX_EVAL_ENVS == 32
    assert eval_env_count("envpool", 5) == 5
