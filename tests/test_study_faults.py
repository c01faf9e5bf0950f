"""Studies that bench and tune must not take for their own: another command's study, and a database made by
another Optuna version."""

import sqlite3

import optuna
import pytest

from canter.errors import CanterError
from canter.orchestrate.bench_distributed import JOB_ATTR
from canter.orchestrate.study import COMMAND_ATTR, SETTINGS_ATTR, StorageSettings, claim_study, open_storage
from canter.orchestrate.tune import PRESET_ATTR, check_study_settings


def _study(tmp_path, name="S"):
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    return optuna.create_study(storage=f"sqlite:///{tmp_path / 'study.db'}", study_name=name, load_if_exists=True)


def test_a_study_is_claimed_by_the_first_command_and_refused_to_the_other(tmp_path):
    study = _study(tmp_path)
    claim_study(study, "bench")
    claim_study(study, "bench")  # a rerun, or another worker of the same bench
    assert study.user_attrs[COMMAND_ATTR] == "bench"
    with pytest.raises(CanterError, match="study 'S' holds a canter bench's jobs; give this tune another --study"):
        check_study_settings(study, {"env": "Pendulum-v1"}, tmp_path / "trials")
    other = _study(tmp_path, "T")
    check_study_settings(other, {"env": "Pendulum-v1"}, tmp_path / "trials")
    with pytest.raises(CanterError, match="study 'T' holds a canter tune's trials; give this bench another --study"):
        claim_study(other, "bench")


def test_studies_from_before_the_mark_are_told_apart_by_what_their_trials_hold(tmp_path):
    """A tune study from before tune kept its settings has trials and no settings, as a bench's has: what its trials
    hold tells them apart, so that tune resumes it and a bench refuses it."""
    bench_made = _study(tmp_path, "old-bench")
    bench_made.enqueue_trial({}, user_attrs={JOB_ATTR: "cell|seeds=0"})  # a bench's queued job
    with pytest.raises(CanterError, match="holds a canter bench's jobs"):
        check_study_settings(bench_made, {"env": "Pendulum-v1"}, tmp_path / "trials")
    claim_study(bench_made, "bench")
    assert bench_made.user_attrs[COMMAND_ATTR] == "bench"

    tune_made = _study(tmp_path, "old-tune")  # trials with their preset, and no settings yet
    tune_made.add_trial(optuna.trial.create_trial(value=1.0, user_attrs={PRESET_ATTR: "[run]\n"}))
    with pytest.raises(CanterError, match="holds a canter tune's trials"):
        claim_study(tune_made, "bench")
    check_study_settings(tune_made, {"env": "Pendulum-v1"}, tmp_path / "trials")
    assert tune_made.user_attrs[COMMAND_ATTR] == "tune"

    settings_kept = _study(tmp_path, "tune-with-settings")  # from before the command was marked
    settings_kept.set_user_attr(SETTINGS_ATTR, {"env": "Pendulum-v1"})
    with pytest.raises(CanterError, match="holds a canter tune's trials"):
        claim_study(settings_kept, "bench")


@pytest.mark.parametrize(
    ("version", "message"),
    [
        ("v3.0.0.d", r"made by an older Optuna .*optuna storage upgrade --storage URL"),
        ("v99.0.0.a", r"made by a newer Optuna .*upgrade canter here\), or give another --storage"),
    ],
    ids=["older", "newer"],
)
def test_a_database_of_another_optuna_is_one_line_naming_its_fix(tmp_path, version, message):
    """An older schema names Optuna's upgrade of the database, a newer one the canter to run instead: Optuna's advice
    for a schema it does not know (pip install -U optuna) came out as a traceback."""
    _study(tmp_path)
    with sqlite3.connect(tmp_path / "study.db") as connection:
        connection.execute("update alembic_version set version_num=?", (version,))
    with pytest.raises(CanterError, match=message):
        open_storage(StorageSettings(f"sqlite:///{tmp_path / 'study.db'}"))


def test_a_tune_refused_a_benchs_study_leaves_no_study_folder(tmp_path, capsys):
    from canter.cli.main import main

    claim_study(_study(tmp_path), "bench")
    out = tmp_path / "tune"
    argv = ["tune", "Pendulum-v1", "--storage", f"sqlite:///{tmp_path / 'study.db'}", "--study", "S"]
    assert main([*argv, "--out-dir", str(out), "--trials", "1", "--total-steps", "2048"]) == 2
    assert "study 'S' holds a canter bench's jobs; give this tune another --study" in capsys.readouterr().err
    assert not (out / "S").exists()


@pytest.mark.parametrize(
    "url, hint",
    [
        (
            "postgresql+asyncpg://u:p@127.0.0.1:5432/db",
            "install the asyncpg driver, or use postgresql:// (psycopg2, from pip install 'canter[distributed]')",
        ),
        (
            "postgresql+psycopg://u:p@127.0.0.1:5432/db",
            "install the psycopg driver, or use postgresql:// (psycopg2, from pip install 'canter[distributed]')",
        ),
    ],
)
def test_a_storage_naming_a_driver_the_extra_lacks_is_told_to_install_that_driver(url, hint):
    """The `distributed` extra brings psycopg2 only: a URL naming another PostgreSQL driver is not sent to it."""
    with pytest.raises(CanterError) as refused:
        open_storage(StorageSettings(url=url))
    driver = url.split("://")[0]
    assert str(refused.value) == (
        f"cannot use the {driver} storage at 127.0.0.1:5432: its database driver is not installed; {hint}"
    )


def test_the_distributed_extra_is_the_fix_for_psycopg2_only():
    from canter.orchestrate.study import driver_hint

    assert driver_hint("postgresql+psycopg2") == "pip install 'canter[distributed]'"
    assert driver_hint("mysql+pymysql").startswith("install a Python driver for mysql+pymysql")
