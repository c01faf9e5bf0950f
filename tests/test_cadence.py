"""The cadence of checkpoints, evaluations and videos (canter.training.cadence) against a step-by-step reference."""

import random

import pytest

from canter.training.cadence import Cadence, next_due


def reference_fired(start: int, steps: list[int], every: int) -> list[int]:
    """Walk every env step from `start`: a multiple of `every` passed makes the work pending, and the next visited
    step does it, once however many multiples it passed."""
    fired, pending, position = [], False, start
    for step in steps:
        for passed in range(position + 1, step + 1):
            if every and passed % every == 0:
                pending = True
        position = step
        if pending:
            fired.append(step)
            pending = False
    return fired


def cadence_fired(start: int, steps: list[int], every: int) -> list[int]:
    cadence, fired = Cadence(every, start), []
    for step in steps:
        if cadence.due(step):
            fired.append(step)
            cadence = cadence.advance(step)
    return fired


@pytest.mark.parametrize(
    ("step", "every", "expected"),
    [(0, 10, 10), (1, 10, 10), (9, 10, 10), (10, 10, 20), (25, 10, 30), (0, 1, 1), (7, 1, 8), (4096, 2048, 6144)],
)
def test_next_due_by_hand(step, every, expected):
    assert next_due(step, every) == expected


def test_due_by_hand():
    fresh = Cadence(10, 0)
    assert [fresh.due(s) for s in (0, 9, 10, 11, 35)] == [False, False, True, True, True]
    after = fresh.advance(35)  # one step past three multiples: done once, next due at 40
    assert [after.due(s) for s in (35, 39, 40)] == [False, False, True]
    resumed = Cadence(10, 20)  # a run resumed at an exact multiple has done that one's work already
    assert [resumed.due(s) for s in (20, 29, 30)] == [False, False, True]


def test_every_zero_is_never_due():
    assert not any(Cadence(0, 0).due(s) for s in (0, 1, 10**12))


def test_negative_every_is_refused():
    with pytest.raises(ValueError, match="every >= 0"):
        Cadence(-1, 0)


def test_steps_that_jump_past_several_multiples():
    steps = [3, 7, 12, 13, 19, 20, 47, 48, 50, 51]
    assert cadence_fired(0, steps, 10) == reference_fired(0, steps, 10) == [12, 20, 47, 50]


def test_matches_the_reference_on_random_runs():
    rng = random.Random(0)
    for _ in range(500):
        every = rng.choice([0, 1, 2, 5, 7, 10, 64])
        start = rng.choice([0, rng.randrange(200)])
        steps, step = [], start
        for _ in range(rng.randrange(1, 30)):
            step += rng.choice([1, 2, 3, rng.randrange(1, 40)])
            steps.append(step)
        assert cadence_fired(start, steps, every) == reference_fired(start, steps, every), (start, steps, every)
