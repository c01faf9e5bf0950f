import jax.numpy as jnp
import numpy as np
import pytest

from canter.algos.ppo.symmetry import (
    MirrorPair,
    check_action_range,
    parse_groups,
    symmetric_loss,
)
from canter.errors import CanterError


def test_parse_groups_and_negate():
    pairs = parse_groups("3:7=7:11, 11:14=14:17", negate=(14, 15))
    assert pairs == (
        MirrorPair((3, 4, 5, 6), (7, 8, 9, 10), (1.0,) * 4),
        MirrorPair((11, 12, 13), (14, 15, 16), (-1.0, -1.0, 1.0)),
    )
    assert parse_groups("0=1") == (MirrorPair((0,), (1,), (1.0,)),)
    assert parse_groups("") == ()


@pytest.mark.parametrize(
    "text, negate, message",
    [
        ("3:7=7:10", (), "pairs 4 with 3 dimensions"),
        ("3:7", (), "is not a pair"),
        ("a:b=1:2", (), "cannot read range"),
        ("5:3=1:3", (), "0 <= start < stop"),
        ("0:2=2:4", (1,), "sym.negate: indices [1]"),
    ],
)
def test_bad_groups_are_one_line_errors(text, negate, message):
    with pytest.raises(CanterError) as info:
        parse_groups(text, negate)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_action_range_check_names_the_algorithm():
    pairs = parse_groups("3:7=7:11,11:14=14:17")
    check_action_range(pairs, 17, "rpo")
    with pytest.raises(CanterError, match=r"index 16 is out of the action range 0..5 of this env \(rpo\)"):
        check_action_range(pairs, 6, "rpo")


def test_zero_for_mirrored_inputs_and_positive_otherwise():
    pairs = parse_groups("0:2=2:4", negate=(3,))
    mask = jnp.ones(3)
    mirrored = jnp.array([[0.5, -1.0, 0.5, 1.0], [2.0, 3.0, 2.0, -3.0], [0.0, 0.1, 0.0, -0.1]])
    assert float(symmetric_loss(mirrored, pairs, mask, use_signs=True)) == 0.0
    assert float(symmetric_loss(mirrored, pairs, mask, use_signs=False)) > 0.0  # the signs matter for means
    assert float(symmetric_loss(mirrored.at[1, 0].add(1.0), pairs, mask, use_signs=True)) > 0.0


def test_hand_computed_value_mean_over_pairs_and_masked_rows():
    # Pair A compares columns 0,1 with 2,3; pair B column 4 with 5. Row 2 is masked out.
    values = jnp.array(
        [[1.0, 2.0, 3.0, 4.0, 0.0, 1.0], [0.0, 0.0, 1.0, 1.0, 2.0, 0.0], [9.0, 9.0, -9.0, -9.0, 9.0, -9.0]]
    )
    pairs = parse_groups("0:2=2:4,4=5")
    mask = jnp.array([1.0, 1.0, 0.0])
    pair_a = np.mean([((1 - 3) ** 2 + (2 - 4) ** 2) / 2, ((0 - 1) ** 2 + (0 - 1) ** 2) / 2])  # (4 + 1) / 2
    pair_b = np.mean([(0 - 1) ** 2, (2 - 0) ** 2])  # (1 + 4) / 2
    expected = (pair_a + pair_b) / 2
    assert float(symmetric_loss(values, pairs, mask, use_signs=True)) == pytest.approx(expected)
