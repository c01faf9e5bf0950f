"""canter tune: search spaces, the objective on a tiny budget, the best preset, SQLite parallel jobs, and the
distributed mode against a real PostgreSQL server with a worker killed mid-trial."""

import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import optuna
import pytest

from canter.cli.main import main
from canter.config.build import build_config
from canter.config.experiment import experiment_key
from canter.errors import CanterError
from canter.orchestrate.search_space import (
    apply_sample,
    default_space_text,
    load_space,
    parse_space,
)
from canter.orchestrate.study import Outcome, normalize_url
from canter.orchestrate.tune import (
    TuneSettings,
    announced,
    check_settings,
    evaluation_index,
    logged_evaluations,
    logged_steps,
    make_study,
    run_trial,
    sampler_seed,
)
from pg_server import postgres_url  # noqa: F401  (session fixture)

# A tiny space and budget: a trial is one short Pendulum run, so the tests measure the machinery, not learning.
TINY_SPACE = """
[ppo.lr]
low = 1e-4
high = 1e-2
log = true

[ppo.n_steps]
choices = [64, 128]

[ppo.ent_coef]
low = 0.0
high = 0.01
"""
TINY_SETS = ("net.hidden=16,16", "env.num_envs=4", "ppo.minibatch_size=256", "ppo.epochs=2")


def tiny_args(tmp_path: Path) -> list[str]:
    space = tmp_path / "space.toml"
    space.write_text(TINY_SPACE)
    args = [
        "--total-steps",
        "1024",
        "--evaluations",
        "2",
        "--eval-episodes",
        "1",
        "--startup-trials",
        "10",
        "--space",
        str(space),
        "--out-dir",
        str(tmp_path / "tune"),
    ]
    for s in TINY_SETS:
        args += ["--set", s]
    return args


def test_no_more_workers_start_than_the_study_lacks_trials(tmp_path, capsys, monkeypatch):
    import canter.orchestrate.jobs
    import canter.orchestrate.tune

    monkeypatch.setattr(canter.orchestrate.jobs.os, "sched_getaffinity", lambda pid: {0, 1, 2}, raising=False)
    url = f"sqlite:///{tmp_path / 'tune' / 'Pendulum-v1__ppo' / 'study.db'}"
    started = []

    def workers(work, args, name):  # stands in for the processes, which finish 2 of the 3 trials
        started.append(len(args))
        study = optuna.load_study(study_name="Pendulum-v1__ppo", storage=url)
        for _ in range(2):
            study.add_trial(optuna.trial.create_trial(state=optuna.trial.TrialState.PRUNED))
        return []

    monkeypatch.setattr(canter.orchestrate.jobs, "run_workers", workers)
    monkeypatch.setattr(canter.orchestrate.tune, "worker", lambda settings, job, before: started.append(1))
    argv = ["tune", "Pendulum-v1", "--trials", "3", "--jobs", "5", *tiny_args(tmp_path)]
    assert main(argv) == 0, capsys.readouterr().err
    assert main(argv) == 0, capsys.readouterr().err
    # 3 workers for 3 trials, not --jobs 5, so no warning about 5 jobs on 3 cores; then 1 for the trial left.
    assert started == [3, 1]
    assert "warning" not in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------- search spaces


def _registered_algorithms():
    from canter.algos import algorithm_names

    return algorithm_names()


def test_every_algorithm_ships_a_space():
    assert {"ppo", "rpo", "trpo", "td3", "ddpg", "sac"} <= set(_registered_algorithms())
    for algo in _registered_algorithms():
        assert "[" in default_space_text(algo)


@pytest.mark.parametrize("algo", _registered_algorithms())
def test_every_shipped_space_validates_and_samples_valid_configs(algo):
    space = load_space(None, algo)
    assert space.keys
    base = build_config("Hopper-v5", algo=algo)
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    for _ in range(30):
        trial = study.ask()
        config = apply_sample(base, space.suggest(trial))
        for key, value in trial.params.items():
            section, _, name = key.partition(".")
            got = getattr(getattr(config, section), name)
            if "minibatch_size" in name:
                assert got == min(value, config.ppo.n_steps * config.env.num_envs)
            elif isinstance(got, tuple):
                assert "-".join(map(str, got)) == value
            else:
                assert got == value


def test_ppo_space_follows_seed_002_table_1():
    params = {p.key: p for p in load_space(None, "ppo").params}
    assert params["ppo.n_steps"].choices == (8, 16, 32, 64, 128, 256, 512, 1024, 2048)
    assert (params["ppo.lr"].low, params["ppo.lr"].high, params["ppo.lr"].log) == (1e-5, 1.0, True)
    assert params["ppo.epochs"].choices == (1, 5, 10, 20)
    assert params["ppo.minibatch_size"].choices == (8, 16, 32, 64, 128, 256, 512)
    assert params["ppo.gamma"].choices == (0.9, 0.95, 0.98, 0.99, 0.995, 0.999, 0.9999)
    assert params["ppo.gae_lambda"].choices == (0.8, 0.9, 0.92, 0.95, 0.98, 0.99, 1.0)
    assert (params["ppo.ent_coef"].low, params["ppo.ent_coef"].high, params["ppo.ent_coef"].log) == (1e-8, 0.1, True)
    assert params["ppo.clip"].choices == (0.1, 0.2, 0.3, 0.4)
    assert params["ppo.max_grad_norm"].choices == (0.3, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 2.0, 5.0)
    assert (params["ppo.vf_coef"].low, params["ppo.vf_coef"].high, params["ppo.vf_coef"].log) == (0.0, 1.0, False)
    assert (params["ppo.target_kl"].low, params["ppo.target_kl"].high) == (0.001, 0.3)


def test_tied_keys_take_the_sampled_value():
    space = parse_space(
        {"ppo": {"lr": {"low": 1e-5, "high": 1e-3, "log": True}, "critic_lr": {"same_as": "ppo.lr"}}}, "test"
    )
    values = space.suggest(optuna.trial.FixedTrial({"ppo.lr": 3e-4}))
    assert values == {"ppo.lr": 3e-4, "ppo.critic_lr": 3e-4}
    with pytest.raises(CanterError, match="must name a sampled key"):
        parse_space({"ppo": {"critic_lr": {"same_as": "ppo.lr"}}}, "test")
    with pytest.raises(CanterError, match=r"ppo.epochs"):  # the tied values must fit the key's type
        parse_space({"ppo": {"lr": {"low": 1e-5, "high": 1e-3}, "epochs": {"same_as": "ppo.lr"}}}, "test")


def test_space_types_and_tuple_choices():
    space = parse_space(
        {
            "net": {"hidden": {"choices": ["64-64", "128-64"]}},
            "ppo": {"epochs": {"low": 1, "high": 20}, "lr": {"low": 1e-5, "high": 1e-3, "log": True}},
        },
        "test",
    )
    by_key = {p.key: p for p in space.params}
    assert by_key["net.hidden"].choices == ("64-64", "128-64")
    assert by_key["ppo.epochs"].integer and not by_key["ppo.lr"].integer
    values = space.suggest(optuna.trial.FixedTrial({"net.hidden": "128-64", "ppo.epochs": 7, "ppo.lr": 2e-4}))
    config = apply_sample(build_config("Hopper-v5"), values)
    assert config.net.hidden == (128, 64) and config.ppo.epochs == 7 and config.ppo.lr == 2e-4


@pytest.mark.parametrize(
    "data, message",
    [
        ({"ppo": {"learning_rate": {"low": 1e-5, "high": 1.0}}}, "unknown hyperparameter 'ppo.learning_rate'"),
        ({"ppo": {"lr": {"low": 1e-3, "high": 1e-3}}}, "empty range"),
        ({"ppo": {"lr": {"low": 1e-2, "high": 1e-3}}}, "empty range"),
        ({"ppo": {"epochs": {"choices": []}}}, "empty list of choices"),
        ({"ppo": {"ent_coef": {"low": 0.0, "high": 0.1, "log": True}}}, "low must be > 0"),
        ({"ppo": {"gamma": {"choices": [0.99, 1.5]}}}, "ppo.gamma = 1.5 is invalid"),
        ({"ppo": {"epochs": {"choices": [1.5]}}}, "expected an integer"),
        ({"ppo": {"lr": {"low": 1e-5}}}, "needs choices"),
        ({"ppo": {"epochs": {"low": 1, "high": 10, "step": 0.5}}}, "its step must be a whole number, got 0.5"),
        ({"ppo": {"epochs": {"low": 1, "high": 10, "step": 2.5}}}, "its step must be a whole number, got 2.5"),
        ({"ppo": {"epochs": {"low": 1, "high": 3, "step": float("nan")}}}, "step must be a positive finite number"),
        ({"ppo": {"epochs": {"low": 1, "high": 3, "step": float("inf")}}}, "step must be a positive finite number"),
        ({"ppo": {"clip": {"low": 0.1, "high": 0.3, "step": float("nan")}}}, "step must be a positive finite number"),
        ({"ppo": {"clip": {"low": 0.1, "high": 0.3, "step": True}}}, "step must be a positive finite number"),
        # Optuna would cut high down to the last whole step, with a warning, and record the range it was given.
        (
            {"ppo": {"epochs": {"low": 1, "high": 10, "step": 2}}},
            "step 2 does not divide the range 1 to 10; set high = 9, or pick a step that divides high - low = 9",
        ),
        ({"ppo": {"epochs": {"low": 1, "high": 3, "step": 10}}}, "step 10 is larger than the range 1 to 3"),
        ({"ppo": {"clip": {"low": 0.1, "high": 0.3, "step": 0.15}}}, "set high = 0.25"),
        # Optuna refuses any step with log on a float, at every trial; an integer takes step 1.
        ({"ppo": {"lr": {"low": 1e-5, "high": 1e-2, "log": True, "step": 1}}}, "cannot combine with log"),
        ({"ppo": {"epochs": {"low": 1, "high": 16, "log": True, "step": 2}}}, "cannot combine with log"),
        ({}, "empty"),
    ],
)
def test_bad_search_space_is_refused(data, message):
    with pytest.raises(CanterError, match=message.replace("(", r"\(").replace(".", r"\.")):
        parse_space(data, "space.toml")


def test_a_step_that_divides_the_range_is_kept():
    """Within float rounding: 0.2 / 0.1 is 2.0000000000000004."""
    space = parse_space(
        {"ppo": {"clip": {"low": 0.1, "high": 0.3, "step": 0.1}, "epochs": {"low": 2, "high": 10}}}, "t"
    )
    assert [(p.key, p.step) for p in space.params] == [("ppo.clip", 0.1), ("ppo.epochs", None)]


def test_bad_input_is_one_line_and_starts_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[ppo.lr]\nlow = 1.0\nhigh = 0.5\n")
    code = main(["tune", "Pendulum-v1", "--space", str(bad), "--jobs", "64", "--out-dir", str(tmp_path / "t")])
    err = capsys.readouterr().err
    assert code == 2
    # Only the error: the --jobs warning waits until the command has passed its checks.
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith("canter: error:") and "empty range" in err and "Traceback" not in err
    assert not (tmp_path / "t").exists()

    code = main(
        [
            "tune",
            "Pendulum-v1",
            "--storage",
            "postgresql://canter:secret@127.0.0.1:9/nodb",
            "--out-dir",
            str(tmp_path / "t"),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "postgresql+psycopg2 storage at 127.0.0.1:9" in err and "secret" not in err
    assert not (tmp_path / "t").exists()
    code = main(["tune", "Pendulum-v1", "--storage", f"sqlite:///{tmp_path}/missing/dir/study.db"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and f"sqlite storage at {tmp_path}/missing/dir/study.db" in err

    code = main(["tune", "Pendulum-v1", "--algo", "ppoo"])
    assert code == 2 and "unknown algorithm 'ppoo'" in capsys.readouterr().err

    # A shared storage with an --out-dir that cannot hold the trials' folders: refused before any trial is stored.
    shared = f"sqlite:///{tmp_path / 'shared.db'}"
    code = main(["tune", "Pendulum-v1", "--storage", shared, "--study", "s", "--out-dir", "/proc/canter-nope"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "/proc/canter-nope" in err, err
    assert "s" not in optuna.get_all_study_names(storage=shared)  # no study, so no failed trials in it

    for argv, message in [
        (["--sampler-seed", "-1"], "argument --sampler-seed: expected a seed from 0 to 4294967295"),
        (["--seed", "4294967295", "--seeds-per-trial", "2"], "--seed 4294967295 with 2 seeds per trial passes"),
        (["--storage", "postgresql://u@host:abc/db"], "is not a database URL"),
    ]:
        code = main(["tune", "Pendulum-v1", "--out-dir", str(tmp_path / "t"), *argv])
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1 and message in err and "Traceback" not in err, err
    assert not (tmp_path / "t").exists()


# ------------------------------------------------------------------------------------------------- the objective


def tiny_settings(tmp_path: Path, **kwargs) -> TuneSettings:
    space = tmp_path / "space.toml"
    space.write_text(TINY_SPACE)
    defaults = dict(
        env_id="Pendulum-v1",
        total_steps=1024,
        evaluations=2,
        eval_episodes=1,
        sets=TINY_SETS,
        space_file=str(space),
        out_dir=str(tmp_path / "tune"),
        poll_seconds=0.2,
    )
    return TuneSettings(**{**defaults, **kwargs})


@pytest.mark.slow
def test_objective_is_the_mean_deterministic_return_over_seeds(tmp_path, capsys):
    from canter.use.evaluate import evaluate
    from canter.use.policy import load

    settings = tiny_settings(tmp_path, seeds=(3, 4))
    base, space = check_settings(settings)
    study = optuna.create_study(direction="maximize")
    trial = study.ask()
    outcome = run_trial(trial, settings, base, space)
    assert outcome.state == "complete", outcome.reason
    trial_dir = settings.study_dir / "trials" / "trial_00000"
    sampled = ", ".join(f"{key.split('.')[1]} {value:.4g}" for key, value in trial.params.items())
    assert capsys.readouterr().out == f"start trial 0 ({sampled}) in {trial_dir}\n"
    # Recompute independently: load each seed's final policy and evaluate it deterministically.
    returns = []
    for seed in (3, 4):
        run = trial_dir / f"s{seed}"
        assert load(run).config.run.seed == seed
        returns.append(evaluate(load(run), episodes=1, deterministic=True, seed=0).mean)
    assert outcome.value == pytest.approx(np.mean(returns), rel=1e-6)
    # The sampled values were trained, and every checkpoint was reported (the last one is the objective).
    config = load(trial_dir / "s3").config
    assert config.ppo.lr == trial.params["ppo.lr"] and config.ppo.n_steps == trial.params["ppo.n_steps"]
    frozen = study.tell(trial, outcome.value)
    assert sorted(frozen.intermediate_values) == [512, 1024]  # nominal steps: every 1/2 of the budget
    assert frozen.intermediate_values[1024] == outcome.value


def test_a_resumed_study_does_not_replay_its_proposals(tmp_path):
    settings = tiny_settings(tmp_path, sampler_seed=7)
    _, space = check_settings(settings)
    storage = optuna.storages.RDBStorage(f"sqlite:///{tmp_path / 'study.db'}")

    def first_proposal():
        study = make_study(settings, storage)
        trial = study.ask()
        values = space.suggest(trial)
        study.tell(trial, 0.0)
        return values

    # Three sessions of one trial each: a sampler seeded alike every time proposed the same trial three times.
    proposals = [first_proposal() for _ in range(3)]
    assert proposals[0] != proposals[1] != proposals[2] != proposals[0]
    assert sampler_seed(7, 0, 0) == 7 and sampler_seed(None, 0, 5) is None
    # Machines given seeds a step apart, each with several jobs, share no job's seed (seed + job made 0's job 1 and
    # 1's job 0 propose the same trials).
    new_study_seeds = [sampler_seed(machine, job, 0) for machine in range(4) for job in range(4)]
    assert len(set(new_study_seeds)) == len(new_study_seeds)
    assert len({sampler_seed(7, job, trials) for job in range(4) for trials in range(1, 50)}) == 4 * 49
    # The same study state gives the same seed, so a resume is reproducible.
    assert sampler_seed(7, 0, 3) == sampler_seed(7, 0, 3)
    # The workers of one command seed from the count the command made when it started, not from what they see
    # when they start (a sibling's first trial may be there by then): counted as at the start, the first proposal
    # of the first session comes back.
    again = make_study(settings, storage, 0, trials_before=0).ask()
    assert space.suggest(again) == proposals[0]


def test_each_trial_prints_how_it_ended(capsys):
    outcomes = [
        Outcome("complete", value=812.44),
        Outcome("pruned", reason="pruned at step 512 with return -1200.0"),
        Outcome("fail", reason="exceeded --trial-minutes 1 (stopped after 0 steps)"),
        Outcome("fail"),
    ]
    for number, outcome in enumerate(outcomes):
        assert announced(number, lambda outcome=outcome: outcome) is outcome
    assert capsys.readouterr().out.splitlines() == [
        "done  trial 0 in 0.0 min: return 812.4",
        "PRUNE trial 1 in 0.0 min: pruned at step 512 with return -1200.0",
        "FAIL  trial 2 in 0.0 min: exceeded --trial-minutes 1 (stopped after 0 steps)",
        "FAIL  trial 3 in 0.0 min: no reason recorded",
    ]


def test_checkpoints_of_the_seeds_of_a_group_are_matched_by_evaluation_index():
    settings = TuneSettings(env_id="Hopper-v5", total_steps=1000, evaluations=4)  # every 250 steps
    assert settings.eval_interval == 250
    # Seeds count their own steps, so one seed checkpoints at 251 and another at 263 for the same evaluation; an
    # iteration that crosses two points counts for the later one; the final checkpoint is the last evaluation.
    assert [evaluation_index(s, settings) for s in (251, 263, 499, 500, 760, 999, 1000, 1077)] == [
        1,
        1,
        1,
        2,
        3,
        3,
        4,
        4,
    ]
    assert evaluation_index(100, settings) == 1


@pytest.mark.slow
def test_pruned_trial_stops_its_training(tmp_path):
    import json

    settings = tiny_settings(tmp_path, total_steps=1_000_000, evaluations=200)
    base, space = check_settings(settings)
    study = optuna.create_study(direction="maximize", pruner=optuna.pruners.ThresholdPruner(lower=1e9))
    trial = study.ask()
    outcome = run_trial(trial, settings, base, space)
    assert outcome.state == "pruned" and outcome.reason.startswith("pruned at step")
    summary = json.loads((settings.study_dir / "trials" / "trial_00000" / "s0" / "summary.json").read_text())
    assert summary["stop_reason"] == "signal" and summary["global_step"] < 1_000_000


@pytest.mark.slow
def test_trial_over_its_time_limit_fails_with_the_reason(tmp_path):
    settings = tiny_settings(tmp_path, trial_minutes=0.002, total_steps=10**7)
    base, space = check_settings(settings)
    outcome = run_trial(
        optuna.trial.FixedTrial({"ppo.lr": 1e-3, "ppo.n_steps": 64, "ppo.ent_coef": 0.0}), settings, base, space
    )
    assert outcome.state == "fail" and "exceeded --trial-minutes 0.002" in outcome.reason
    # The steps it had trained, as its metrics.csv logged them (it said "about 0" whenever no evaluation had come).
    run = settings.study_dir / "trials" / "trial_00000" / "s0"
    assert outcome.reason.endswith(f"(stopped after {logged_steps(run):,} steps)")


# ------------------------------------------------------------------------------- SQLite jobs and the best preset


@pytest.mark.slow
def test_sqlite_parallel_jobs_and_best_preset_loads_back(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MLflow's artifacts go to ./mlruns
    mlflow_uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    argv = ["tune", "Pendulum-v1", "--trials", "3", "--jobs", "2", "--heartbeat", "2"] + tiny_args(tmp_path)
    code = main(argv + ["--track", "mlflow", "--mlflow-uri", mlflow_uri])
    out, err = capsys.readouterr()
    assert code == 0, err
    study_dir = tmp_path / "tune" / "Pendulum-v1__ppo"
    study = optuna.load_study(study_name="Pendulum-v1__ppo", storage=f"sqlite:///{study_dir / 'study.db'}")
    complete = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    assert len(complete) == 3
    assert len({t.user_attrs["worker"] for t in complete}) == 2  # two spawned processes shared the study
    assert "| trial | return |" in out and "3 complete" in out
    _assert_trials_tracked_under_one_parent_run(complete, mlflow_uri)

    # The best preset trains as it is: it resolves to the best trial's trained config, bookkeeping aside.
    best = max(complete, key=lambda t: t.value)
    preset = study_dir / "best.toml"
    assert f"best trial {best.number}" in preset.read_text()
    assert "canter train --config best.toml --seed 1  (a seed the study did not tune on;" in preset.read_text()
    assert "the best of 3 on the seeds that chose it, so it overstates" in preset.read_text()
    loaded = build_config(None, config_file=str(preset))
    trained = build_config(None, config_file=str(Path(best.user_attrs["trial_dir"]) / "s0" / "config.toml"))
    assert experiment_key(loaded) == experiment_key(trained)
    assert loaded.run.total_steps == trained.run.total_steps
    assert loaded.ppo.lr == best.params["ppo.lr"] and loaded.ppo.n_steps == best.params["ppo.n_steps"]
    # A run trained from it is laid over the trials' preset and named by it; another preset is refused, not misnamed.
    assert loaded.run.preset == trained.run.preset == "fast"
    with pytest.raises(CanterError, match=r"sets run\.preset = 'fast', but the preset is cleanrl"):
        build_config(None, preset="cleanrl", config_file=str(preset))


@pytest.mark.slow
def test_a_worker_that_ended_early_fails_the_command_only_when_trials_are_missing(tmp_path, capsys, monkeypatch):
    from canter.orchestrate import jobs

    def first_runs_all_then_second_is_killed(work, worker_args, name):
        work(*worker_args[0])  # it runs until the study has its trials, so the second finds none left
        return [-9]

    monkeypatch.setattr(jobs, "run_workers", first_runs_all_then_second_is_killed)
    argv = ["tune", "Pendulum-v1", "--trials", "2", "--jobs", "2"] + tiny_args(tmp_path)
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert (
        "canter: note: 1 of 2 tune workers ended early (killed by signal 9 (SIGKILL, probably out of memory)), but the "
        "others finished the study's 2 trials"
    ) in err

    monkeypatch.setattr(jobs, "run_workers", lambda work, worker_args, name: [-9, -9])
    assert main(["tune", "Pendulum-v1", "--trials", "4", "--jobs", "2"] + tiny_args(tmp_path)) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("canter: error: 2 of 2 tune workers ended early (killed by signal 9"), err


# ------------------------------------------------------------------------ PostgreSQL: a worker killed mid-trial


def _worker(args: list[str], log: Path, ignore_sigint: bool = False) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    command = [sys.executable, "-m", "canter.cli.main", "tune"] + args
    if ignore_sigint:  # as a job started with `&` from a script inherits it: its processes ignore SIGINT
        command = ["bash", "-c", 'trap "" INT; exec "$@"', "bash", *command]
    return subprocess.Popen(command, stdout=open(log, "wb"), stderr=subprocess.STDOUT, env=env)


def _wait_gone(pid: int, seconds: float) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            return
        if state == "Z":  # exited, waiting to be reaped by its new parent
            return
        time.sleep(0.2)
    raise AssertionError(f"process {pid} outlived its killed worker")


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::optuna.exceptions.ExperimentalWarning")
def test_postgres_distributed_worker_killed_mid_trial(tmp_path, postgres_url):  # noqa: F811
    trials = 2
    storage = normalize_url(postgres_url)  # what optuna.load_study needs for the psycopg2 driver
    args = [
        "Pendulum-v1",
        "--trials",
        str(trials),
        "--storage",
        postgres_url,
        "--study",
        "killed-worker",
        "--heartbeat",
        "1",
    ] + tiny_args(tmp_path)
    victim = _worker(args + ["--out-dir", str(tmp_path / "a")], tmp_path / "a.log")
    survivor = _worker(args + ["--out-dir", str(tmp_path / "b")], tmp_path / "b.log")
    try:
        deadline = time.monotonic() + 120
        victim_trial = None
        while victim_trial is None:
            assert time.monotonic() < deadline and victim.poll() is None, (tmp_path / "a.log").read_text()
            if "start trial" not in (tmp_path / "a.log").read_text():  # its tables are made: the study can be read
                time.sleep(0.2)
                continue
            study = optuna.load_study(study_name="killed-worker", storage=storage)
            running = [
                t
                for t in study.get_trials(states=(optuna.trial.TrialState.RUNNING,))
                if t.user_attrs.get("worker", "").endswith(f":{victim.pid}")
            ]
            victim_trial = running[0].number if running else None
            time.sleep(0.2)
        time.sleep(1.0)  # inside the trial: its training child is up
        children = Path(f"/proc/{victim.pid}/task/{victim.pid}/children").read_text().split()
        victim.send_signal(signal.SIGKILL)
        assert children  # the trial's training process, which must not outlive its worker
        for pid in map(int, children):
            _wait_gone(pid, 30)
        assert survivor.wait(timeout=180) == 0, (tmp_path / "b.log").read_text()
    finally:
        for p in (victim, survivor):
            if p.poll() is None:
                p.kill()
    study = optuna.load_study(study_name="killed-worker", storage=storage)
    by_state = {s: [t for t in study.trials if t.state == s] for s in optuna.trial.TrialState}
    listing = [
        (t.number, t.state.name, t.user_attrs.get("fail_reason") or t.user_attrs.get("note")) for t in study.trials
    ]
    assert len(by_state[optuna.trial.TrialState.COMPLETE]) == trials, listing
    assert not by_state[optuna.trial.TrialState.RUNNING] and not by_state[optuna.trial.TrialState.WAITING]
    # The killed trial failed by heartbeat and a copy with the same parameters completed.
    killed = study.trials[victim_trial]
    assert killed.state == optuna.trial.TrialState.FAIL
    retries = [
        t
        for t in study.trials
        if optuna.storages.RetryHeartbeatStaleTrialCallback.retried_trial_number(t) == victim_trial
    ]
    assert len(retries) == 1 and retries[0].state == optuna.trial.TrialState.COMPLETE
    assert retries[0].params == killed.params
    # Every other failed trial says why.
    for t in by_state[optuna.trial.TrialState.FAIL]:
        assert t.number == victim_trial or t.user_attrs.get("fail_reason"), t
    assert f"{trials} complete" in (tmp_path / "b.log").read_text()


def _assert_trials_tracked_under_one_parent_run(trials, mlflow_uri: str) -> None:
    """`--track mlflow`: each trial's seed is an MLflow run named after the trial, and every trial of the study is a
    child of one parent run named after the study (the jobs started at once, so each may have made one)."""
    import json

    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=mlflow_uri)
    parents = set()
    for trial in trials:
        run_dir = Path(trial.user_attrs["trial_dir"]) / "s0"
        tracked = client.get_run(json.loads((run_dir / "trackers.json").read_text())["mlflow"]["run_id"])
        assert tracked.info.run_name == f"trial_{trial.number:05d}-s0"
        assert tracked.data.tags["canter.trial"] == str(trial.number) and tracked.info.status == "FINISHED"
        assert float(tracked.data.params["ppo.lr"]) == trial.params["ppo.lr"]
        parents.add(tracked.data.tags["mlflow.parentRunId"])
        # The objective is the seed's evaluation at the end of the budget: the last one the tracker got.
        evaluations = client.get_metric_history(tracked.info.run_id, "eval/return_mean")
        assert max(evaluations, key=lambda m: m.step).value == pytest.approx(trial.value, rel=1e-6)
    [parent_id] = parents
    # The tune process made it before its workers started, and handed it to every trial's job.
    for trial in trials:
        job = json.loads((Path(trial.user_attrs["trial_dir"]) / "job.json").read_text())
        assert job["track"]["group_runs"] == [["mlflow", "tune-Pendulum-v1__ppo", parent_id]]
    parent = client.get_run(parent_id)
    assert parent.info.run_name == parent.data.tags["canter.group"] == "tune-Pendulum-v1__ppo"
    assert len(client.search_runs([parent.info.experiment_id], "tags.`canter.parent` = 'true'")) == 1


def test_a_space_over_keys_the_algorithm_ignores_is_refused(tmp_path):
    space = tmp_path / "space.toml"
    space.write_text("[ppo.lr]\nlow = 1e-5\nhigh = 1e-3\nlog = true\n")
    settings = TuneSettings(env_id="Hopper-v5", total_steps=1000, algo="td3", space_file=str(space))
    with pytest.raises(CanterError, match=r"^search space .*space.toml: ppo.lr has no effect on td3, .*drop it"):
        check_settings(settings)
    for algo in _registered_algorithms():  # the shipped spaces only vary what their algorithm reads
        check_settings(TuneSettings(env_id="Hopper-v5", total_steps=1000, algo=algo))


def test_a_resumed_study_with_other_settings_or_a_new_one_over_old_trial_folders_is_refused(tmp_path):
    from canter.orchestrate.tune import check_study_settings, study_settings

    settings = tiny_settings(tmp_path)
    wanted = study_settings(settings, *check_settings(settings))
    trials = tmp_path / "trials"
    study = optuna.create_study(direction="maximize", study_name="s")
    check_study_settings(study, wanted, trials)  # a new study takes the settings
    check_study_settings(study, wanted, trials)  # and is resumed with the same ones
    study.add_trial(optuna.trial.create_trial(value=1.0))  # a finished trial, which other settings would not match

    longer = replace(settings, total_steps=2048)
    with pytest.raises(CanterError) as refused:
        check_study_settings(study, study_settings(longer, *check_settings(longer)), trials)
    assert str(refused.value) == (
        "study 's' was run with --total-steps 1024, but this command gives 2048; its trials would not compare: "
        "use the same settings, or a new --study"
    )
    other_space = tmp_path / "other.toml"
    other_space.write_text(TINY_SPACE.replace("1e-4", "1e-5"))
    wider = replace(settings, space_file=str(other_space))
    with pytest.raises(CanterError, match=r"was run with the search space's \[ppo.lr\] 0.0001 to"):
        check_study_settings(study, study_settings(wider, *check_settings(wider)), trials)
    with pytest.raises(CanterError, match=r"was run with the base config's ppo.clip 0.2, but this command gives 0.3"):
        clip = replace(settings, sets=(*settings.sets, "ppo.clip=0.3"))
        check_study_settings(study, study_settings(clip, *check_settings(clip)), trials)
    # Not a learning key, but it picks the envs that play every evaluation, which is what the trials are scored on.
    gym = replace(settings, sets=(*settings.sets, "run.eval_backend=gymnasium"))
    with pytest.raises(CanterError) as refused:
        check_study_settings(study, study_settings(gym, *check_settings(gym)), trials)
    assert str(refused.value) == (
        "study 's' was run with the base config's run.eval_backend (not set), but this command gives 'gymnasium'; "
        "its trials would not compare: use the same settings, or a new --study"
    )

    (trials / "trial_00000").mkdir(parents=True)
    with pytest.raises(CanterError, match=r"holds the trials of an earlier study that this database does not know"):
        check_study_settings(optuna.create_study(direction="maximize"), wanted, trials)


def test_a_study_with_no_finished_trial_restarts_with_other_settings(tmp_path, capsys):
    """A worker that gives up says to fix the cause and run again: with nothing finished, nothing compares, so the
    fixed space or config replaces the study's settings, even where Optuna holds the old choices of a parameter."""
    from canter.orchestrate.study import FAIL_REASON, RESTARTED, SETTINGS_ATTR
    from canter.orchestrate.tune import check_study_settings

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    url, trials = f"sqlite:///{tmp_path / 'study.db'}", tmp_path / "trials"
    study = optuna.create_study(storage=url, study_name="s", direction="maximize")
    check_study_settings(study, {"--total-steps": "1024"}, trials)
    failed = study.ask()
    failed.suggest_categorical("trpo.critic_minibatch_size", [100])
    failed.set_user_attr(FAIL_REASON, "invalid sample: 100 does not divide the batch 512")
    study.tell(failed, state=optuna.trial.TrialState.FAIL)
    study.enqueue_trial({"trpo.critic_minibatch_size": 100})  # a stopped trial queued again

    study = check_study_settings(study, {"--total-steps": "2048"}, trials)
    assert capsys.readouterr().err == (
        "canter: note: study 's' had no finished trial, so it now runs with this command's settings\n"
    )
    reloaded = optuna.load_study(storage=url, study_name="s")
    assert reloaded.user_attrs[SETTINGS_ATTR] == {"--total-steps": "2048"}
    kept = reloaded.get_trials()
    assert [(t.number, t.state, t.params) for t in kept] == [(n, optuna.trial.TrialState.FAIL, {}) for n in (0, 1)]
    assert [t.user_attrs[FAIL_REASON] for t in kept] == ["invalid sample: 100 does not divide the batch 512", RESTARTED]
    trial = study.ask()  # the new choices, which Optuna would refuse beside the old ones
    assert trial.number == 2 and trial.suggest_categorical("trpo.critic_minibatch_size", [128]) == 128
    study.tell(trial, 1.0)

    with pytest.raises(CanterError, match=r"was run with --total-steps 2048, but this command gives 1024"):
        check_study_settings(study, {"--total-steps": "1024"}, trials)


def test_a_study_whose_trial_runs_keeps_its_settings(tmp_path):
    """Another worker's running trial trains under the recorded settings: they stay until it ends."""
    from canter.orchestrate.tune import check_study_settings

    study = optuna.create_study(study_name="s", direction="maximize")
    check_study_settings(study, {"--total-steps": "1024"}, tmp_path / "trials")
    study.ask()
    with pytest.raises(CanterError, match=r"was run with --total-steps 1024, but this command gives 2048"):
        check_study_settings(study, {"--total-steps": "2048"}, tmp_path / "trials")


def test_an_invalid_sample_names_the_space_entry_to_change_not_a_set_of_a_sampled_key():
    from canter.orchestrate.tune import space_hint

    space = parse_space({"trpo": {"critic_minibatch_size": {"choices": [100]}}}, "sp.toml")
    refused = "trpo.critic_minibatch_size 100 does not divide the batch 512; pick a divisor, e.g. --set {}=64"
    assert space_hint(refused.format("trpo.critic_minibatch_size"), space) == (
        "trpo.critic_minibatch_size 100 does not divide the batch 512; pick a divisor, e.g. 64 in the search "
        "space's [trpo.critic_minibatch_size]"
    )
    # A key the space does not sample is for --set to fix.
    assert space_hint(refused.format("ppo.minibatch_size"), space) == refused.format("ppo.minibatch_size")


def test_a_trial_trains_its_whole_budget_whatever_the_base_config_stops_at(tmp_path):
    from canter.orchestrate.tune import trial_config

    settings = tiny_settings(tmp_path)
    base, _space = check_settings(settings)
    base = replace(base, run=replace(base.run, stop_at_return=-100, max_minutes=5))  # as a preset may give them
    config = trial_config(base, {"ppo.lr": 1e-3}, tmp_path / "trial", settings)
    assert config.run.stop_at_return is None and config.run.max_minutes is None


@pytest.mark.slow
def test_a_trial_stopped_by_a_signal_after_an_evaluation_fails_rather_than_completes(tmp_path, monkeypatch):
    import threading

    import canter.orchestrate.tune as tune_module

    settings = tiny_settings(tmp_path, total_steps=1_000_000, evaluations=200)
    base, space = check_settings(settings)
    real_start = tune_module.start_job

    def start_then_stop(spec, folder, *args):
        proc = real_start(spec, folder, *args)
        metrics = Path(folder) / "s0" / "metrics.csv"

        def stop_after_first_evaluation():
            while proc.poll() is None:
                if metrics.is_file() and logged_evaluations(metrics.parent, settings):
                    proc.send_signal(signal.SIGTERM)  # as a scheduler stopping the job would
                    return
                time.sleep(0.05)

        threading.Thread(target=stop_after_first_evaluation, daemon=True).start()
        return proc

    monkeypatch.setattr(tune_module, "start_job", start_then_stop)
    trial = optuna.trial.FixedTrial({"ppo.lr": 1e-3, "ppo.n_steps": 64, "ppo.ent_coef": 0.0})
    outcome = run_trial(trial, settings, base, space)
    assert outcome.state == "fail" and outcome.reason.startswith("stopped before its budget, after "), outcome
    assert outcome.reason.endswith(" of 200 evaluations")


@pytest.mark.slow
def test_a_trial_whose_training_ended_before_its_evaluations_were_read_is_not_pruned(tmp_path, monkeypatch):
    import canter.orchestrate.tune as tune_module

    settings = tiny_settings(tmp_path)
    base, space = check_settings(settings)
    real_start = tune_module.start_job

    def start_and_finish(spec, folder, *args):  # a worker that looks only after the training has ended
        proc = real_start(spec, folder, *args)
        proc.wait()
        return proc

    monkeypatch.setattr(tune_module, "start_job", start_and_finish)
    study = optuna.create_study(direction="maximize", pruner=optuna.pruners.ThresholdPruner(lower=1e9))
    outcome = run_trial(study.ask(), settings, base, space)
    assert outcome.state == "complete", outcome


@pytest.mark.slow
def test_a_trial_whose_last_evaluations_are_read_in_one_poll_is_not_pruned(tmp_path, monkeypatch):
    """The final evaluation read in the same poll as the one before it, while the trainer is still closing (poll()
    says running): the trial has trained its whole budget, so it completes; it was once pruned at the earlier one."""
    import canter.orchestrate.tune as tune_module

    settings = tiny_settings(tmp_path)
    base, space = check_settings(settings)
    real_start = tune_module.start_job

    class StillClosing:
        def __init__(self, proc):
            self.proc, self.polls = proc, 0

        def poll(self):
            self.polls += 1
            return None if self.polls == 1 else self.proc.poll()

        def __getattr__(self, name):
            return getattr(self.proc, name)

    def start_and_finish(spec, folder, *args):
        proc = real_start(spec, folder, *args)
        proc.wait()
        return StillClosing(proc)

    monkeypatch.setattr(tune_module, "start_job", start_and_finish)
    monkeypatch.setattr(tune_module, "stop_jobs", lambda procs, **kw: None)
    study = optuna.create_study(direction="maximize", pruner=optuna.pruners.ThresholdPruner(lower=1e9))
    outcome = run_trial(study.ask(), settings, base, space)
    assert outcome.state == "complete", outcome


@pytest.mark.slow
@pytest.mark.parametrize("jobs, ignore_sigint", [(1, False), (2, True)])
def test_sigterm_stops_a_study_as_ctrl_c_does(tmp_path, jobs, ignore_sigint):
    """A scheduler's SIGTERM to `canter tune` alone stops every trial's training and records the trials as
    interrupted; it left them RUNNING, so the next run waited out the heartbeat grace. With --jobs the workers do
    not get the signal: the parent passes it on, as SIGTERM, which a background job's workers do not ignore."""
    args = ["Pendulum-v1", "--trials", "2", "--jobs", str(jobs), "--heartbeat", "60"] + tiny_args(tmp_path)
    args[args.index("--total-steps") + 1] = "200000"  # a trial that outlasts the test
    proc = _worker(args, tmp_path / "tune.log", ignore_sigint)
    storage = f"sqlite:///{tmp_path / 'tune' / 'Pendulum-v1__ppo' / 'study.db'}"
    try:
        deadline = time.monotonic() + 180
        # The log, not the study, says when the trials are up: opening the SQLite file while tune is still making
        # its tables races it for the schema's first row.
        while (tmp_path / "tune.log").read_text().count("start trial") < jobs:
            assert time.monotonic() < deadline and proc.poll() is None, (tmp_path / "tune.log").read_text()
            time.sleep(0.5)
        time.sleep(3.0)  # inside the trials: their training children are up
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=120) == 130, (tmp_path / "tune.log").read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
    trials = optuna.load_study(study_name="Pendulum-v1__ppo", storage=storage).trials
    stopped = [t for t in trials if t.state == optuna.trial.TrialState.FAIL]
    assert len(stopped) == jobs and all(t.user_attrs["fail_reason"] == "interrupted" for t in stopped)
    # Each is queued again with its parameters, for the next run.
    queued = [t for t in trials if t.state == optuna.trial.TrialState.WAITING]
    assert sorted(t.params["ppo.lr"] for t in queued) == sorted(t.params["ppo.lr"] for t in stopped)
    assert len(trials) == 2 * jobs
    assert "canter: interrupted" in (tmp_path / "tune.log").read_text()


def test_a_worker_that_gives_up_still_leaves_the_summary(tmp_path, monkeypatch, capsys):
    import canter.orchestrate.tune as tune_module

    def gives_up(settings, job, trials_before):
        print("start trial 0 (...)")
        raise CanterError("study 'x': 10 trials failed in a row and none finished; the last one: broken")

    written = []
    monkeypatch.setattr(tune_module, "worker", gives_up)
    monkeypatch.setattr(tune_module, "write_results", lambda study, settings: written.append(study.study_name))
    with pytest.raises(CanterError, match="10 trials failed in a row"):
        tune_module.tune(tiny_settings(tmp_path))
    assert written == ["Pendulum-v1__ppo"]  # summary.md and best.toml come from what the study holds


def test_an_interrupted_trial_prints_its_fail_line(capsys):
    def interrupted():
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        announced(5, interrupted)
    assert capsys.readouterr().out == "FAIL  trial 5: interrupted\n"
