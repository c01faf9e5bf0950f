"""canter.use.statistics against rliable called directly and against hand computations; the scoreboard of bench,
plot and report; the shipped random and reference scores."""

import json
import subprocess
import sys
import tomllib
from importlib import resources

import numpy as np
import pytest
from rliable import library, metrics

from canter.use import statistics
from canter.use.reference_scores import normalizer_for, random_command, reference_score
from canter.use.scoreboard import TRAINING_SOURCE, RunScore, build_scoreboard, run_score

REPS = 200  # few resamples: these tests check the plumbing, not the coverage


def test_aggregates_are_rliables_interval_estimates():
    scores = np.array([[1.0, 10.0], [2.0, 20.0], [3.0, 30.0], [4.0, 40.0]])
    found = statistics.aggregates(scores, gamma=5.0, reps=REPS, seed=3)
    # By hand: IQM of the middle half of all eight values, mean and median of the per-env means, gap below 5.
    assert found.iqm.estimate == pytest.approx((3 + 4 + 10 + 20) / 4)
    assert found.mean.estimate == pytest.approx((2.5 + 25) / 2)
    assert found.median.estimate == pytest.approx((2.5 + 25) / 2)
    assert found.optimality_gap.estimate == pytest.approx(5 - (1 + 2 + 3 + 4 + 5 * 4) / 8)
    assert (found.runs, found.tasks, found.gamma) == (4, 2, 5.0)

    def rliable_four(s):
        return np.array(
            [
                metrics.aggregate_iqm(s),
                metrics.aggregate_mean(s),
                metrics.aggregate_median(s),
                metrics.aggregate_optimality_gap(s, 5.0),
            ]
        )

    np.random.seed(3)
    points, intervals = library.get_interval_estimates({"a": scores}, rliable_four, reps=REPS)
    for i, name in enumerate(("iqm", "mean", "median", "optimality_gap")):
        interval = getattr(found, name)
        assert interval.estimate == pytest.approx(points["a"][i])
        assert (interval.low, interval.high) == pytest.approx((intervals["a"][0][i], intervals["a"][1][i]))
        assert interval.low <= interval.estimate <= interval.high
    # Without a threshold there is no gap; one run gives an interval of width zero.
    assert statistics.aggregates(scores, reps=REPS).optimality_gap is None
    single = statistics.aggregates(np.array([[7.0]]), reps=REPS)
    assert single.iqm.low == single.iqm.high == single.iqm.estimate == 7.0


def _score_matrices():
    """Random matrices of many shapes, some with ties, some with a single run or task."""
    rng = np.random.default_rng(7)
    for runs, tasks in [(1, 1), (1, 3), (2, 1), (3, 2), (4, 5), (5, 3), (7, 1), (10, 4), (13, 6)]:
        yield rng.normal(size=(runs, tasks)) * 1000
        yield rng.integers(0, 4, size=(runs, tasks)).astype(float)  # many ties


def test_each_statistic_equals_rliables_to_the_last_bit():
    for scores in _score_matrices():
        assert statistics.interquartile_mean(scores) == metrics.aggregate_iqm(scores)
        assert statistics.task_mean(scores) == metrics.aggregate_mean(scores)
        assert statistics.task_median(scores) == metrics.aggregate_median(scores)
        for gamma in (0.0, 1.5, 1e4):
            assert statistics.optimality_gap(scores, gamma) == metrics.aggregate_optimality_gap(scores, gamma)
    matrices = list(_score_matrices())
    for x in matrices:
        for y in matrices:
            if x.shape[1] == y.shape[1]:
                assert statistics.improvement_probability(x, y) == metrics.probability_of_improvement(x, y)
    same = matrices[5]
    assert statistics.improvement_probability(same, same) == 0.5


def test_the_same_seed_gives_the_same_interval_and_the_global_generator_is_left_alone():
    scores = np.random.default_rng(0).normal(size=(5, 3))
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    a = statistics.aggregates(scores, reps=REPS, seed=1)
    assert (np.random.get_state()[1] == before).all()
    assert statistics.aggregates(scores, reps=REPS, seed=1) == a
    assert statistics.aggregates(scores, reps=REPS, seed=2).iqm.low != a.iqm.low
    with pytest.raises(ValueError, match="finite matrix"):
        statistics.aggregates(np.array([[1.0, np.nan]]))


def test_probability_of_improvement_and_profiles_match_rliable():
    x = np.array([[3.0, 1.0], [4.0, 2.0], [5.0, 2.0]])
    y = np.array([[1.0, 2.0], [5.0, 2.0]])
    found = statistics.probability_of_improvement(x, y, reps=REPS, seed=4)
    # Env 1: 3>1, 3<5, 4>1, 4<5, 5>1, 5=5 -> 3.5/6; env 2: 1<2 twice, 2=2 four times -> 2/6.
    assert found.estimate == pytest.approx((3.5 / 6 + 2 / 6) / 2)
    np.random.seed(4)
    points, intervals = library.get_interval_estimates(
        {"p": [x, y]}, lambda a, b: np.array([metrics.probability_of_improvement(a, b)]), reps=REPS
    )
    assert found.estimate == pytest.approx(points["p"][0])
    assert (found.low, found.high) == pytest.approx((intervals["p"][0][0], intervals["p"][1][0]))
    with pytest.raises(ValueError, match="same tasks"):
        statistics.probability_of_improvement(x, y[:, :1])

    scores = {"a": np.array([[0.2, 0.6], [1.1, 1.4]]), "b": np.array([[0.0], [2.0]])}
    taus = [0.0, 0.5, 1.0, 1.5]
    profiles = statistics.performance_profiles(scores, taus, reps=REPS, seed=5)
    assert profiles["a"].fraction == pytest.approx((1.0, 0.75, 0.5, 0.0))
    assert profiles["b"].fraction == pytest.approx((0.5, 0.5, 0.5, 0.5))
    np.random.seed(5)
    fractions, intervals = library.create_performance_profile(scores, np.array(taus), reps=REPS)
    for name in scores:
        assert profiles[name].fraction == pytest.approx(tuple(fractions[name]))
        assert profiles[name].low == pytest.approx(tuple(intervals[name][0]))
        assert profiles[name].high == pytest.approx(tuple(intervals[name][1]))
    np.testing.assert_allclose(statistics.normalized([10.0, 55.0], 10.0, 100.0), [0.0, 0.5])


def test_aggregates_are_rliables_to_the_last_bit_from_every_resample_at_once():
    # The plain reference: rliable's bootstrap, one resample after another, each scored by rliable's own metrics
    # (the median of a single task is of its runs, canter's definition).
    for scores in _score_matrices():
        for gamma in (None, 0.5):
            found = statistics.aggregates(scores, gamma, reps=REPS, seed=8)

            def rliables(s, gamma=gamma):
                median = statistics.run_median(s) if s.shape[1] == 1 else metrics.aggregate_median(s)
                values = [metrics.aggregate_iqm(s), metrics.aggregate_mean(s), median]
                return np.array(values + ([] if gamma is None else [metrics.aggregate_optimality_gap(s, gamma)]))

            np.random.seed(8)
            points, intervals = library.get_interval_estimates({"s": scores}, rliables, reps=REPS)
            low, high = intervals["s"]
            names = ["iqm", "mean", "median"] + ([] if gamma is None else ["optimality_gap"])
            for i, name in enumerate(names):
                interval = getattr(found, name)
                assert (interval.estimate, interval.low, interval.high) == (points["s"][i], low[i], high[i])


def test_profiles_are_rliables_to_the_last_bit_from_every_resample_at_once():
    # Methods of different shapes, drawn in turn from one seeding, as rliable draws them; ties on the thresholds.
    rng = np.random.default_rng(9)
    shapes = [(5, 5), (3, 1), (5, 5), (1, 2), (10, 4), (7, 9)]
    scores = {f"m{i}": np.round(rng.normal(1.0, 0.6, size=shape), 1) for i, shape in enumerate(shapes)}
    taus = np.linspace(0.0, 2.0, 41)
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    profiles = statistics.performance_profiles(scores, taus, reps=REPS, seed=10)
    assert (np.random.get_state()[1] == before).all()
    np.random.seed(10)
    fractions, intervals = library.create_performance_profile(scores, taus, reps=REPS)
    for name in scores:
        assert profiles[name].fraction == tuple(fractions[name])
        assert (profiles[name].low, profiles[name].high) == (tuple(intervals[name][0]), tuple(intervals[name][1]))


def test_a_scoreboard_is_built_without_rliables_loop_over_resamples(monkeypatch):
    # rliable scores resamples one at a time: 600 aggregates and 100 profiles of a grid of 100 methods took minutes.
    def refuse(*args, **kwargs):
        raise AssertionError("rliable's bootstrap loop was called")

    monkeypatch.setattr(library, "get_interval_estimates", refuse)
    monkeypatch.setattr(library, "create_performance_profile", refuse)
    scores = [
        RunScore(method, env, "ppo", 1000.0 + 100 * s + (method == "b"), f"{method}{env}{s}")
        for method in ("a", "b")
        for env in ("Hopper-v4", "Walker2d-v4")
        for s in range(5)
    ]
    board = build_scoreboard(scores, TRAINING_SOURCE, reps=REPS)
    assert set(board.profiles) == {"a", "b"} and len(board.cells) == 4


def _rliables_probability_of_improvement(x, y, reps, seed):
    """The plain reference: rliable's bootstrap, one resample after another, each scored by improvement_probability
    (equal to rliable's own to the last bit, above)."""
    np.random.seed(seed)
    points, intervals = library.get_interval_estimates(
        {"p": [x, y]}, lambda a, b: np.array([statistics.improvement_probability(a, b)]), reps=reps
    )
    return statistics.Interval(float(points["p"][0]), float(intervals["p"][0][0]), float(intervals["p"][1][0]))


def test_probabilities_of_improvement_are_rliables_to_the_last_bit_for_every_pair_at_once():
    # Shapes that share draws (the same runs and tasks) and shapes that do not: unequal runs, one run, one task,
    # more tasks than numpy's pairwise sum takes in one block of 8, and ties.
    rng = np.random.default_rng(11)
    shapes = [(5, 5, 5), (5, 5, 5), (3, 3, 1), (1, 4, 2), (6, 2, 3), (5, 5, 5), (4, 7, 12), (2, 2, 20)]
    pairs = []
    for runs_x, runs_y, tasks in shapes:
        for draw in (rng.normal, lambda size: rng.integers(0, 3, size).astype(float)):
            pairs.append((draw(size=(runs_x, tasks)) * 100, draw(size=(runs_y, tasks)) * 100))
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    found = statistics.probabilities_of_improvement(pairs, reps=REPS, seed=6)
    assert (np.random.get_state()[1] == before).all()
    assert found == [_rliables_probability_of_improvement(x, y, REPS, 6) for x, y in pairs]
    assert statistics.probability_of_improvement(*pairs[0], reps=REPS, seed=6) == found[0]
    with pytest.raises(ValueError, match="same tasks"):
        statistics.probabilities_of_improvement([pairs[0], (pairs[0][0], pairs[0][1][:, :1])])


def test_shipped_random_scores_carry_their_command_and_cover_the_published_envs():
    data = tomllib.loads(resources.files("canter.data").joinpath("random.toml").read_text())
    assert data["command"].startswith("python -m canter.use.random_score --episodes 100")
    assert random_command() == data["command"]
    published = tomllib.loads(resources.files("canter.data").joinpath("published.toml").read_text())
    for base in {s["env"] for s in published["score"]}:
        for version in (4, 5):
            entry = data["env"][f"{base}-v{version}"]
            assert entry["episodes"] >= 100 and np.isfinite(entry["mean"])
    # Tianshou where it has a 1M figure, else CleanRL; none for rpo at 1M.
    assert reference_score("ppo", "Hopper-v5") == (2609.3, "Tianshou", "Hopper-v3")
    assert reference_score("ppo", "Pusher-v4") == (-40.38, "CleanRL", "Pusher-v4")
    assert reference_score("ppo", "InvertedPendulum-v5") == (1000.0, "Tianshou", "InvertedPendulum-v2")
    assert reference_score("rpo", "Hopper-v5") is None
    assert reference_score("td3", "Humanoid-v5") == (5189.5, "Tianshou", "Humanoid-v3")  # Tianshou's where it has one
    hopper = normalizer_for("ppo", "Hopper-v5")
    assert hopper.random == data["env"]["Hopper-v5"]["mean"] and hopper.reference == 2609.3
    assert normalizer_for("ppo", "Pendulum-v1") is None


def test_random_returns_of_a_short_env(tmp_path):
    from canter.use.random_score import main, random_returns

    returns, backend = random_returns("InvertedPendulum-v4", episodes=5, seed=0)
    # Random actions topple the pole within a few dozen steps; reward is 1 per step.
    assert returns.shape == (5,) and (returns >= 1).all() and (returns < 100).all()
    assert backend in ("envpool", "gymnasium")
    again, _ = random_returns("InvertedPendulum-v4", episodes=5, seed=0)
    np.testing.assert_array_equal(returns, again)
    out = tmp_path / "random.toml"
    assert main(["InvertedPendulum-v4", "--episodes", "5", "--out", str(out)]) == 0
    written = tomllib.loads(out.read_text())
    assert (
        written["command"] == f"python -m canter.use.random_score InvertedPendulum-v4 --episodes 5 --seed 0 --out {out}"
    )
    assert written["env"]["InvertedPendulum-v4"]["mean"] == pytest.approx(returns.mean(), abs=1e-4)


def test_the_random_score_command_refuses_an_unknown_env_in_one_line_of_its_own_name(tmp_path):
    command = [sys.executable, "-m", "canter.use.random_score", "Nope-v1", "--out", str(tmp_path / "random.toml")]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith("python -m canter.use.random_score: error: unknown env id 'Nope-v1'"), done.stderr
    assert not (tmp_path / "random.toml").exists()


@pytest.mark.parametrize("env_id", ["InvertedPendulum-v4", "InvertedPendulum-v5"])
def test_a_shipped_random_score_is_measured_again_to_the_same_value(env_id):
    """The file's own command, re-run for one short env per version: a wrong or swapped entry would show."""
    from canter.use.random_score import random_returns

    data = tomllib.loads(resources.files("canter.data").joinpath("random.toml").read_text())
    entry = data["env"][env_id]
    returns, _ = random_returns(env_id, episodes=entry["episodes"], seed=data["seed"])
    assert returns.mean() == pytest.approx(entry["mean"], abs=1e-3)


def hand_scores():
    rows = []
    for method, algo, hopper, walker in (
        ("ppo", "ppo", [3000.0, 3300.0, 2500.0], [4000.0, 3500.0, 2000.0]),
        ("trpo", "trpo", [2000.0, 2100.0, 2200.0], [3900.0, 4100.0, 3000.0]),
    ):
        for env_id, values in (("Hopper-v5", hopper), ("Walker2d-v5", walker)):
            rows += [RunScore(method, env_id, algo, v, f"{method}-{env_id}-s{i}") for i, v in enumerate(values)]
    return rows


def test_scoreboard_tables_and_json_hold_every_aggregate_with_its_interval():
    board = build_scoreboard(hand_scores(), "final deterministic evaluation", reps=REPS)
    assert [(c.method, c.env_id) for c in board.cells] == [
        ("ppo", "Hopper-v5"),
        ("ppo", "Walker2d-v5"),
        ("trpo", "Hopper-v5"),
        ("trpo", "Walker2d-v5"),
    ]
    hopper_ppo = board.cells[0]
    assert hopper_ppo.returns.mean.estimate == pytest.approx(2933.333, abs=1e-3)
    # One env's median is its runs' (3000), not rliable's median of per-env means, which is their mean.
    assert hopper_ppo.returns.median.estimate == 3000.0
    # Optimality gap below Tianshou's 2609.3: only the 2500 run falls short.
    assert hopper_ppo.returns.optimality_gap.estimate == pytest.approx((2609.3 - 2500.0) / 3)
    ppo = board.methods[0]
    assert ppo.envs == ("Hopper-v5", "Walker2d-v5") and ppo.normalized.tasks == 2
    walker = normalizer_for("ppo", "Walker2d-v5")
    expected = np.array(
        [
            statistics.normalized([3000.0, 3300.0, 2500.0], hopper_ppo.normalizer.random, 2609.3),
            statistics.normalized([4000.0, 3500.0, 2000.0], walker.random, walker.reference),
        ]
    ).T
    assert ppo.normalized.mean.estimate == pytest.approx(expected.mean())
    assert set(board.profiles) == {"ppo", "trpo"}
    [comparison] = board.comparisons
    assert (comparison.x, comparison.y) == ("ppo", "trpo")
    # Hopper: every ppo run beats every trpo run; Walker2d: 4000 beats two, 3500 one, 2000 none -> 3/9.
    assert comparison.probability.estimate == pytest.approx((1.0 + 3 / 9) / 2)

    markdown = board.markdown()
    for text in (
        "### Final return per env",
        "| Hopper-v5 | ppo | 3 | ",
        "2,609.3 (Tianshou, Hopper-v3)",
        "### Across envs, normalized",
        "### Performance profile",
        "### Probability of improvement",
        "| ppo | trpo | Hopper-v5, Walker2d-v5 | 0.67 |",  # 3 runs per env: no interval
        "95% stratified-bootstrap confidence intervals",
        "python -m canter.use.random_score",
    ):
        assert text in markdown, text
    data = json.loads(board.json())
    cell = data["cells"][0]
    assert set(cell["return"]) == {"runs", "tasks", "iqm", "mean", "median", "optimality_gap", "gamma"}
    assert cell["return"]["iqm"]["low"] <= cell["return"]["iqm"]["estimate"] <= cell["return"]["iqm"]["high"]
    assert cell["normalizer"]["reference_source"] == "Tianshou"
    assert cell["normalizer"]["reference_env"] == "Hopper-v3"
    # The normalized scores fall short of 1 (the reference) by this much on average, a score above 1 counting as 1.
    gap = 1.0 - np.mean(np.minimum(expected, 1.0))
    assert gap > max(0.0, 1.0 - expected.mean())  # some runs pass the reference (capped), some fall short
    assert data["across_envs"][0]["normalized"]["optimality_gap"]["estimate"] == pytest.approx(gap)
    assert data["bootstrap"] == {"method": "stratified, percentile", "reps": REPS, "seed": 0}
    assert data["probability_of_improvement"][0]["probability"]["estimate"] == pytest.approx((1.0 + 3 / 9) / 2)


def test_intervals_are_shown_from_five_runs_on():
    three = [RunScore("ppo", "Hopper-v5", "ppo", v, f"s{i}") for i, v in enumerate([3000.0, 3300.0, 2500.0])]
    three += [RunScore("trpo", "Hopper-v5", "trpo", v, f"s{i}") for i, v in enumerate([1000.0, 900.0, 1100.0])]
    board = build_scoreboard(three, "final deterministic evaluation", reps=REPS)
    rows = {row[:2]: row for row in board.tables()[0].rows}
    # With 3 runs the bootstrap interval of the mean is the runs' min and max; it is kept in the JSON only.
    assert rows[("Hopper-v5", "ppo")][3:6] == ("2,933.3", "2,933.3", "3,000.0")  # IQM of 3 runs: all of them
    assert board.cells[0].returns.mean.low == 2500.0 and board.cells[0].returns.mean.high == 3300.0
    assert board.tables()[-1].rows == (("ppo", "trpo", "Hopper-v5", "1.00"),)
    assert json.loads(board.json())["probability_of_improvement"][0]["runs"] == [3, 3]
    five = [RunScore("ppo", "Hopper-v5", "ppo", 3000.0 + 100 * i, f"s{i}") for i in range(5)]
    shown = build_scoreboard(five, "final deterministic evaluation", reps=REPS).tables()[0].rows[0]
    assert shown[4].startswith("3,200.0 [") and shown[4].endswith("]")


def test_scoreboard_without_normalizers_or_a_second_method():
    rows = [RunScore("ppo", "Pendulum-v1", "ppo", v, f"s{i}") for i, v in enumerate([-200.0, -150.0])]
    rows += [RunScore("rpo", "Hopper-v5", "rpo", 100.0, "s0")]
    board = build_scoreboard(rows, "training return", reps=REPS)
    assert board.methods == () and board.profiles == {}
    assert board.comparisons == ()  # the two methods share no env
    markdown = board.markdown()
    assert "none published" in markdown and "Across envs" not in markdown and "Normalizers" not in markdown


def test_run_score_prefers_the_final_evaluation(tmp_path):
    assert run_score(tmp_path) is None
    (tmp_path / "summary.json").write_text(json.dumps({"recent_return": 12.5}))
    assert run_score(tmp_path)[0] == 12.5 and "training return" in run_score(tmp_path)[1]
    (tmp_path / "eval.json").write_text(json.dumps({"mean": 20.0}))
    assert run_score(tmp_path)[0] == 20.0 and "deterministic evaluation" in run_score(tmp_path)[1]
    assert run_score(tmp_path, (TRAINING_SOURCE,))[0] == 12.5
    # With checkpoints, only an evaluation of the newest one counts: one from before a resume is stale.
    (tmp_path / "checkpoints").mkdir()
    for step in (1000, 2000):
        (tmp_path / "checkpoints" / f"ckpt_{step:012d}.npz").write_bytes(b"")
    (tmp_path / "eval.json").write_text(json.dumps({"mean": 20.0, "checkpoint": "ckpt_000000001000.npz"}))
    assert run_score(tmp_path)[0] == 12.5
    (tmp_path / "eval.json").write_text(json.dumps({"mean": 20.0, "checkpoint": "ckpt_000000002000.npz"}))
    assert run_score(tmp_path)[0] == 20.0


def test_a_published_reference_without_a_random_score_still_gives_the_optimality_gap_but_no_normalized_score():
    from canter.use.scoreboard import RunScore, build_scoreboard

    returns = [2000.0, 2500.0, 3000.0, 2200.0, 2800.0]
    scores = [RunScore("ppo", "Hopper-v3", "ppo", r, f"s{i}") for i, r in enumerate(returns)]
    board = build_scoreboard(scores, "test", reps=200)
    cell = board.cells[0]
    assert cell.normalizer is None and cell.reference == (2609.3, "Tianshou", "Hopper-v3")
    expected_gap = np.mean([max(2609.3 - r, 0.0) for r in returns])  # a plain loop over the runs
    assert cell.returns.optimality_gap is not None
    assert cell.returns.optimality_gap.estimate == pytest.approx(expected_gap)
    rows = board.tables()[0].rows
    assert rows[0][-1] == "2,609.3 (Tianshou, Hopper-v3); no random score, not normalized"
    assert not board.methods  # nothing to normalize across envs
