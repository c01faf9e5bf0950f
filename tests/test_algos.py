import pytest

from canter.algos import algorithm_names, check_algorithm_name, get_algorithm
from canter.cli import main
from canter.config import build_config
from canter.errors import CanterError


def test_every_registered_algorithm_has_a_complete_record():
    for name in algorithm_names():
        algorithm = get_algorithm(name)
        assert algorithm.name == name and algorithm.metric_names


def test_unknown_algorithm_lists_the_valid_ones(capsys):
    with pytest.raises(CanterError, match="choose one of: ppo"):
        check_algorithm_name("ppx")
    with pytest.raises(CanterError, match="unknown algorithm 'nope'"):
        build_config("Hopper-v5", algo="nope")
    assert main(["train", "Hopper-v5", "--algo", "nope", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown algorithm 'nope'" in err
