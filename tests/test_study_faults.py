"""Studies that bench and tune must not take for their own: another command's study, and a database made by
another Optuna version."""

import sqlite3

import optuna
import pytest

from canter.errors import CanterError
from canter.orchestrate.study import COMMAND_ATTR, StorageSettings, claim_study, open_storage
from canter.orchestrate.tune import SETTINGS_ATTR, check_study_settings


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


def test_studies_from_before_the_mark_are_told_apart_by_what_they_hold(tmp_path):
    bench_made = _study(tmp_path, "old-bench")
    bench_made.enqueue_trial({})  # a bench's queued job: a trial, and no tune settings
    with pytest.raises(CanterError, match="holds a canter bench's jobs"):
        check_study_settings(bench_made, {"env": "Pendulum-v1"}, tmp_path / "trials")
    tune_made = _study(tmp_path, "old-tune")
    tune_made.set_user_attr(SETTINGS_ATTR, {"env": "Pendulum-v1"})
    with pytest.raises(CanterError, match="holds a canter tune's trials"):
        claim_study(tune_made, "bench", other_made_it=SETTINGS_ATTR in tune_made.user_attrs)


def test_a_database_of_another_optuna_version_is_one_line_naming_the_upgrade(tmp_path):
    _study(tmp_path)
    with sqlite3.connect(tmp_path / "study.db") as connection:
        connection.execute("update alembic_version set version_num='v3.0.0.d'")
    with pytest.raises(CanterError, match=r"made by another Optuna version .*optuna storage upgrade --storage URL"):
        open_storage(StorageSettings(f"sqlite:///{tmp_path / 'study.db'}"))
