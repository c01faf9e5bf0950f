"""canter plot: smoothing, interpolation, bootstrap band and grouping against plain references; CLI smoke runs."""

import json
import math
import shutil
import warnings
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canter.cli.main import main
from canter.config.build import build_config
from canter.config.experiment import experiment_key, group_by_experiment
from canter.config.overrides import apply_overrides
from canter.config.serialize import to_toml
from canter.errors import CanterError
from canter.use.bands import bootstrap_band, common_grid, experiment_band, interpolate, moving_average, range_band
from canter.use.curves import RunCurves, load_run, read_metrics
from canter.use.experiments import Experiment, experiment_labels, experiments_of, method_labels
from canter.use.plot import choose_metrics, draw, final_score, scoreboard_of, unused_diagnostic
from canter.use.scoreboard import EVAL_SOURCE, TRAINING_SOURCE, RunScore, build_scoreboard
from conftest import ARCHIVED_RUN, error_line


@pytest.mark.parametrize(
    "y",
    [
        [1.0, np.nan, 3.0, 4.0, np.nan, np.nan, np.nan, 8.0, 9.0, 10.0],
        # Infinite rows (a diverged or damaged run) spoil only the windows that hold them.
        [1.0, np.inf, 3.0, 4.0, np.nan, -np.inf, 7.0, 8.0, np.inf, -np.inf, 11.0, 12.0, 13.0],
        # A huge value (a loss that spiked) leaves the windows after it exact.
        [1e17, 1.0, 2.0, np.nan, 3.0, 4.0, 5.0, 6.0, -3e18, 7.0, 8.0, 9.0, 1e-3, 2e-3],
    ],
)
def test_moving_average_matches_a_loop_with_nans(y):
    y = np.array(y)
    for window in (1, 2, 3, 5, 20):
        expected = []
        for i in range(len(y)):
            chunk = [float(v) for v in y[max(0, i - window + 1) : i + 1] if not math.isnan(v)]
            expected.append(sum(chunk) / len(chunk) if chunk else math.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no numpy warning either
            smoothed = moving_average(y, window)
        np.testing.assert_allclose(smoothed, expected, rtol=1e-12, equal_nan=True)
    np.testing.assert_array_equal(moving_average(y, 1), y)
    with pytest.raises(CanterError, match="--smooth"):
        moving_average(y, 0)


def test_bootstrap_band_matches_a_numpy_loop():
    rng = np.random.default_rng(5)
    samples = rng.normal(size=(4, 7))
    samples[1, 2] = np.nan  # one run without a value at one point
    mean, low, high = bootstrap_band(samples, confidence=0.9, resamples=300, seed=11)

    ref_rng = np.random.default_rng(11)
    resampled_means = []
    for _ in range(300):
        rows = samples[ref_rng.integers(0, 4, size=4)]
        kept = [[v for v in rows[:, j] if not np.isnan(v)] for j in range(7)]
        resampled_means.append([np.mean(k) if k else np.nan for k in kept])
    resampled_means = np.array(resampled_means)
    np.testing.assert_allclose(mean, [np.mean([v for v in samples[:, j] if not np.isnan(v)]) for j in range(7)])
    # A resample of only the NaN run has no mean at that point and is left out of the quantiles.
    columns = [c[~np.isnan(c)] for c in resampled_means.T]
    np.testing.assert_allclose(low, [np.quantile(c, 0.05) for c in columns])
    np.testing.assert_allclose(high, [np.quantile(c, 0.95) for c in columns])
    assert (low <= mean).all() and (mean <= high).all()
    # Same seed, same band: the figure does not change between invocations.
    np.testing.assert_array_equal(bootstrap_band(samples, 0.9, 300, 11)[1], low)


def test_bootstrap_band_resamples_in_slices_of_bounded_memory(monkeypatch):
    """The resampled sets are averaged a slice at a time: the same band, and memory that does not grow with the
    number of resamples (whole, 30 runs on a 1,000-point grid took 480 MB at once)."""
    import tracemalloc

    import canter.use.bands

    samples = np.random.default_rng(2).normal(size=(30, 1000))
    samples[3, :40] = np.nan
    tracemalloc.start()
    try:
        whole_slices = bootstrap_band(samples, seed=4)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 3 * canter.use.bands.RESAMPLE_SLICE_BYTES, peak
    monkeypatch.setattr(canter.use.bands, "RESAMPLE_SLICE_BYTES", 7 * 8 * samples.size)  # slices of 7 resamples
    for ours, sliced in zip(whole_slices, bootstrap_band(samples, seed=4)):
        np.testing.assert_array_equal(ours, sliced)


def test_bootstrap_band_width_is_about_the_normal_interval():
    samples = np.random.default_rng(0).normal(size=(40, 200))
    _mean, low, high = bootstrap_band(samples, seed=1)
    expected = 2 * 1.96 * samples.std(axis=0, ddof=1) / math.sqrt(40)
    assert 0.85 < np.median((high - low) / expected) < 1.1


def test_single_run_band_collapses_to_the_run():
    row = np.array([[1.0, 2.0, 3.0]])
    mean, low, high = bootstrap_band(row)
    np.testing.assert_array_equal(mean, row[0])
    np.testing.assert_array_equal(low, row[0])
    np.testing.assert_array_equal(high, row[0])


def test_interpolation_onto_a_common_grid():
    x1 = np.array([0.0, 1000.0, 2000.0, 3000.0])
    x2 = np.array([100.0, 1150.0, 2050.0, 2500.0, 3300.0])
    grid = common_grid([x1, x2])
    # Union of the ranges; the finest median spacing (run 2: 850) gives ceil(3300 / 850) + 1 = 5 points.
    np.testing.assert_allclose(grid, np.linspace(0.0, 3300.0, 5))
    # Runs that barely overlap keep their own resolution rather than share a grid of 3 points.
    np.testing.assert_allclose(common_grid([np.arange(3.0), np.arange(10.0, 13.0)]), np.arange(13.0))
    assert len(common_grid([np.array([0.0, 1e-9, 2e-9, 1e9])])) == 4000  # capped
    np.testing.assert_allclose(interpolate(x1, 2 * x1 + 1, grid), [1.0, 1651.0, 3301.0, 4951.0, np.nan])
    y2 = np.array([1.0, np.nan, 3.0, 5.0, 7.0])  # a NaN row is skipped, not propagated
    np.testing.assert_allclose(interpolate(x2, y2, np.array([0.0, 100.0, 2050.0, 2275.0])), [np.nan, 1.0, 3.0, 4.0])
    assert np.isnan(interpolate(x2, np.full(5, np.nan), grid)).all()
    # Held for up to `hold` past the ends, NaN beyond.
    np.testing.assert_allclose(
        interpolate(x1, 2 * x1 + 1, np.array([-50.0, -150.0, 3050.0, 3150.0]), hold=100.0),
        [1.0, np.nan, 6001.0, np.nan],
    )


def test_seeds_ending_an_iteration_apart_draw_no_spike_at_the_end():
    # Two seeds of one budget log every 1000 steps but stop 900 steps apart; the last grid points must still
    # average both seeds, not show the later seed alone.
    early = fake_run(np.arange(1000.0, 100_001.0, 1000.0), np.full(100, 1000.0), seed=0)
    late = fake_run(np.arange(1000.0, 100_001.0, 1000.0) + 900.0, np.full(100, 5000.0), seed=1)
    band = experiment_band(Experiment("g", (early, late)), "episodic_return")
    assert band.x[-1] == 100_900.0
    np.testing.assert_allclose(band.mean, 3000.0)
    # A run that stops far short of the other still drops out instead of being extended.
    short = fake_run(np.arange(1000.0, 50_001.0, 1000.0), np.full(50, 1000.0), seed=2)
    band = experiment_band(Experiment("g", (short, late)), "episodic_return")
    assert band.mean[-1] == 5000.0
    np.testing.assert_allclose(band.mean[band.x <= 50_000.0], 3000.0)


def fake_run(steps, values, seed=0, **sets) -> RunCurves:
    config = build_config("Pendulum-v1", seed=seed, sets=[f"{k}={v}" for k, v in sets.items()])
    steps = np.asarray(steps, float)
    return RunCurves(
        Path(f"run{seed}"),
        config,
        {"global_step": steps, "wall_time": steps / 100.0, "episodic_return": np.asarray(values, float)},
    )


def test_group_band_averages_runs_with_different_step_grids():
    a = fake_run([0, 1000, 2000, 3000], [0.0, 10.0, 20.0, 30.0], seed=0)  # y = x / 100
    b = fake_run([0, 1500, 3000], [5.0, 20.0, 35.0], seed=1)  # y = x / 100 + 5
    band = experiment_band(Experiment("g", (a, b)), "episodic_return")
    np.testing.assert_allclose(band.x, np.linspace(0, 3000, 4))
    np.testing.assert_allclose(band.mean, band.x / 100 + 2.5)
    assert band.runs == 2 and (band.low <= band.mean).all() and (band.high >= band.mean).all()
    # Where only one run reaches, the mean is that run's value and the band collapses onto it.
    c = fake_run([0, 1500, 4500], [5.0, 20.0, 50.0], seed=2)
    longer = experiment_band(Experiment("g", (a, c)), "episodic_return")
    np.testing.assert_allclose(longer.x, np.linspace(0, 4500, 6))  # run a's spacing of 1000 sets the grid
    # Run a holds its last value (30) for one logging interval (1000) past its end at 3000: x = 3600 averages
    # both runs, x = 4500 is c's alone.
    np.testing.assert_allclose(
        longer.mean, [(0 + 5) / 2, (9 + 14) / 2, (18 + 23) / 2, (27 + 32) / 2, (30 + 41) / 2, 50.0]
    )
    assert longer.low[-1] == longer.high[-1] == 50.0
    wall = experiment_band(Experiment("g", (a, b)), "episodic_return", x_axis="wall")
    np.testing.assert_allclose(wall.mean, wall.x + 2.5)
    smoothed = experiment_band(Experiment("g", (a,)), "episodic_return", smooth=2)
    np.testing.assert_allclose(smoothed.mean, [0.0, 5.0, 15.0, 25.0])
    assert experiment_band(Experiment("g", (a,)), "approx_kl") is None


def test_an_evaluation_curve_starts_at_the_first_evaluation_not_a_metrics_row_before_it():
    """Evaluations land on a few of the metrics rows: the grid and each run's hold come from the rows that hold one,
    so no point shows a seed's first evaluation where none had run (one metrics row before it, at step 800 here)."""
    steps = np.arange(0.0, 6401.0, 800.0)
    runs = []
    for seed, first in enumerate((1600.0, 2400.0)):  # the second seed's first evaluation is a row later
        run = fake_run(steps, steps / 10, seed=seed)
        evaluations = np.where((steps >= first) & (steps % 1600 == first % 1600), 100.0 * seed + steps, np.nan)
        run.columns["eval/return_mean"] = evaluations
        runs.append(run)
    band = experiment_band(Experiment("g", tuple(runs)), "eval/return_mean")
    assert band.x[0] == 1600.0  # seed 0's first evaluation; no point before it
    np.testing.assert_allclose(band.x, [1600.0, 3200.0, 4800.0, 6400.0])  # spaced as the evaluations are
    # Seed 1 (evaluated at 2400, 4000, 5600) holds its ends for one of its evaluation intervals (1600).
    seed1 = np.interp(band.x, [2400.0, 4000.0, 5600.0], [2500.0, 4100.0, 5700.0])
    np.testing.assert_allclose(band.mean, (band.x + seed1) / 2)


def test_groups_of_fewer_than_five_runs_get_the_range_and_larger_ones_a_bootstrap_ci():
    steps = np.arange(0.0, 5000.0, 1000.0)
    runs = [fake_run(steps, steps / 100 + 10 * i, seed=i) for i in range(5)]
    three = experiment_band(Experiment("g", tuple(runs[:3])), "episodic_return")
    assert three.kind == "range" and three.runs == 3
    np.testing.assert_allclose(three.mean, steps / 100 + 10)
    np.testing.assert_allclose(three.low, steps / 100)
    np.testing.assert_allclose(three.high, steps / 100 + 20)
    five = experiment_band(Experiment("g", tuple(runs)), "episodic_return", seed=3)
    assert five.kind == "bootstrap" and five.runs == 5
    samples = np.stack([steps / 100 + 10 * i for i in range(5)])
    for got, expected in zip((five.mean, five.low, five.high), bootstrap_band(samples, seed=3)):
        np.testing.assert_allclose(got, expected)
    assert experiment_band(Experiment("g", runs[:1]), "episodic_return").kind == "single"
    mean, low, high = range_band(np.array([[1.0, np.nan], [3.0, 2.0], [2.0, 4.0]]))
    np.testing.assert_allclose(mean, [2.0, 3.0])
    np.testing.assert_allclose(low, [1.0, 2.0])
    np.testing.assert_allclose(high, [3.0, 4.0])


def test_the_legend_states_each_groups_n_and_band_and_the_statistics_sit_below(tmp_path):
    steps = np.arange(0.0, 5000.0, 1000.0)
    five = Experiment("preset=fast", tuple(fake_run(steps, steps / 100 + i, seed=i) for i in range(5)))
    three = Experiment("preset=cleanrl", tuple(fake_run(steps, steps / 50 + i, seed=i) for i in range(3)))
    single = Experiment("ppo.clip=0.3", (fake_run(steps, steps, seed=9),))
    scores = [RunScore("preset=fast", "Hopper-v5", "ppo", 3000.0 + 10 * i, f"s{i}") for i in range(5)]
    scores += [RunScore("preset=cleanrl", "Hopper-v5", "ppo", 2000.0 + 10 * i, f"s{i}") for i in range(3)]
    board = build_scoreboard(scores, "final deterministic evaluation", reps=50)
    fig = draw([five, three, single], ["episodic_return"], board=board)
    fig.savefig(tmp_path / "c.svg", format="svg")
    svg = (tmp_path / "c.svg").read_text()
    for text in (
        "preset=fast (5 runs), band: 95% CI",
        "preset=cleanrl (3 runs), band: range",
        "ppo.clip=0.3 (1 run), no band",
        "groups of fewer than 5 runs): min to max of the runs",
        "groups of 5 runs or more): percentile bootstrap CI of the mean",
        "Final scores: final deterministic evaluation",
        "preset=fast (n=5)",
        "Performance profile",
        "P(preset=fast &gt; preset=cleanrl)",
        "Normalized score: 0 = uniformly random actions",
        "(Tianshou ppo)",
    ):
        assert text in svg, text
    # Without several runs in any group there is nothing to put intervals on, so no statistics row.
    alone = build_scoreboard(scores[:1], "final deterministic evaluation", reps=50)
    draw([single], ["episodic_return"], board=alone).savefig(tmp_path / "one.svg", format="svg")
    assert "Final scores" not in (tmp_path / "one.svg").read_text()


def test_a_method_keeps_one_colour_across_envs_and_its_statistics_rows_share_it(tmp_path):
    """The statistics aggregate a method over envs, so a method has one colour, its envs a line style each: with a
    colour per curve group, its rows would take colours that no curve of that method has."""
    from matplotlib.colors import to_hex

    from canter.use.plot import group_styles

    steps = np.arange(0.0, 5000.0, 1000.0)

    def runs(env, algo):
        configs = [build_config(env, seed=i, algo=algo, total_steps=5000) for i in range(3)]
        return tuple(RunCurves(Path(f"{env}-{algo}-{i}"), c, {"global_step": steps}) for i, c in enumerate(configs))

    groups = [Experiment(f"{e} {a}", runs(e, a)) for e in ("Hopper-v5", "Walker2d-v5") for a in ("td3", "sac")]
    styles = group_styles(groups)
    assert styles.colors == ("C0", "C1", "C0", "C1") and styles.line_styles == ("-", "-", "--", "--")
    assert styles.method_colors == {"algo=td3": "C0", "algo=sac": "C1"}
    scores = [
        RunScore(m, e, a, float(100 * i + len(m)), f"s{i}")
        for e in ("Hopper-v5", "Walker2d-v5")
        for m, a in (("algo=sac", "sac"), ("algo=td3", "td3"))  # rows in another order than the curves
        for i in range(3)
    ]
    board = build_scoreboard(scores, "final deterministic evaluation", reps=50)
    fig = draw(groups, ["episodic_return"], board=board)
    statistics = fig.subfigs[1].axes[0]
    row_colors = [to_hex(line.get_color()) for line in statistics.lines]
    rows = [label.get_text() for label in statistics.get_yticklabels()]
    expected = {"algo=td3": to_hex("C0"), "algo=sac": to_hex("C1")}
    assert [r.split(" (")[0] for r in rows] == ["algo=sac", "algo=td3"]
    assert row_colors == [expected[r.split(" (")[0]] for r in rows]
    # One method with two groups on one env: a colour per group, the statistics' own palette.
    twice = [groups[0], Experiment("again", groups[0].runs)]
    assert group_styles(twice).colors == ("C0", "C1") and group_styles(twice).method_colors == {}
    # One method on five envs: four line styles cannot tell them apart, so each gets its own colour.
    envs = ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5", "Swimmer-v5")
    five = group_styles([Experiment(e, runs(e, "td3")) for e in envs])
    assert five.colors == ("C0", "C1", "C2", "C3", "C4") and five.method_colors == {}


def test_unused_diagnostics_are_left_out_of_the_default_panels():
    def with_diagnostics(**sets):
        run = fake_run([0, 1, 2], [0.0, 0.0, 0.0], **sets)
        columns = dict(
            run.columns,
            sym_loss=np.zeros(3),
            kl_beta=np.array([1.0, 0.5, 0.25]),
            clip_frac=np.zeros(3),
        )
        return RunCurves(run.run_dir, run.config, columns)

    clipped = with_diagnostics()
    # Without sym.coef and with the clipped objective, the symmetry loss and the KL penalty's beta are off; the
    # clip fraction stays although it never left 0, and so does the return.
    assert choose_metrics([clipped], None) == ["episodic_return", "clip_frac"]
    assert unused_diagnostic([clipped], "sym_loss") and not unused_diagnostic([clipped], "clip_frac")
    assert choose_metrics([clipped], ["sym_loss"]) == ["sym_loss"]  # named, it is drawn
    penalty = with_diagnostics(**{"ppo.objective": "kl_penalty"})
    assert choose_metrics([penalty], None) == ["episodic_return", "kl_beta", "clip_frac"]
    assert choose_metrics([clipped, penalty], None) == ["episodic_return", "kl_beta", "clip_frac"]
    # A run of an algorithm that never logs the column does not bring it back.
    sac = load_run(Path(__file__).parent / "fixtures" / "runs-v1" / "sac")
    assert "sym_loss" not in sac.columns and "sym_loss" not in choose_metrics([clipped, sac], None)


def test_scores_of_one_kind_only(tmp_path, capsys):
    def run(seed, summary, eval_json=None, last_eval=None):
        folder = tmp_path / f"s{seed}"
        folder.mkdir()
        (folder / "summary.json").write_text(json.dumps({"recent_return": summary}))
        if eval_json is not None:
            (folder / "eval.json").write_text(json.dumps({"mean": eval_json}))
        curves = fake_run([0, 1], [0, 1], seed=seed)
        if last_eval is not None:
            curves.columns["eval/return_mean"] = np.array([math.nan, last_eval])
        return replace(curves, run_dir=folder)

    evaluated = [run(0, 10.0, eval_json=100.0), run(1, 20.0, last_eval=200.0)]
    board = scoreboard_of(experiments_of(evaluated))
    assert board.cells[0].scores == (100.0, 200.0) and capsys.readouterr().err == ""
    # A run without an evaluation: a training return (stochastic actions) is not a sample of the same score, so
    # every run is scored by its training return.
    board = scoreboard_of(experiments_of([*evaluated, run(2, 30.0)]))
    assert board.cells[0].scores == (10.0, 20.0, 30.0) and board.source == TRAINING_SOURCE
    assert capsys.readouterr().err == (
        f"canter: note: {tmp_path / 's2'} has no evaluation, so every run is scored by its training return\n"
    )
    # A run with an evaluation but no training return (no summary.json yet) is then left out, and named.
    unfinished = run(3, 40.0, last_eval=400.0)
    (unfinished.run_dir / "summary.json").unlink()
    board = scoreboard_of(experiments_of([*evaluated, run(4, 50.0), unfinished]))
    assert board.cells[0].scores == (10.0, 20.0, 50.0)
    assert f"{tmp_path / 's3'} has no training return" in capsys.readouterr().err


def test_a_diverged_final_evaluation_is_no_score_and_is_named(tmp_path, capsys):
    """A NaN in eval.json is the run's final score: neither its training return nor an evaluation from before it
    diverged may stand in for it. It stays out of the statistics, with a note."""
    from canter.use.scoreboard import run_score

    def run(seed, eval_mean):
        folder = tmp_path / f"s{seed}"
        folder.mkdir()
        (folder / "summary.json").write_text(json.dumps({"recent_return": 50.0}))
        (folder / "eval.json").write_text(json.dumps({"mean": eval_mean}))
        curves = fake_run([0, 1], [0, 1], seed=seed)
        curves.columns["eval/return_mean"] = np.array([900.0, math.nan])
        return replace(curves, run_dir=folder)

    runs = [run(0, 100.0), run(1, 200.0), run(2, math.nan)]
    (tmp_path / "s2" / "eval.json").write_text('{"mean": NaN}')  # as json.dumps writes a NaN
    score, source = run_score(tmp_path / "s2")
    assert math.isnan(score) and source == EVAL_SOURCE
    assert math.isnan(final_score(runs[2])[0])
    board = scoreboard_of(experiments_of(runs))
    assert board.cells[0].scores == (100.0, 200.0)
    assert capsys.readouterr().err == (
        f"canter: note: {tmp_path / 's2'} has a final evaluation that is not finite (a diverged policy): left out "
        "of the statistics\n"
    )
    # Beside runs scored by their training return, the diverged run is still left out, not scored by its own.
    for seed in (0, 1):
        (tmp_path / f"s{seed}" / "eval.json").unlink()
        runs[seed].columns["eval/return_mean"] = np.array([math.nan, math.nan])
    board = scoreboard_of(experiments_of(runs))
    assert board.cells[0].scores == (50.0, 50.0) and board.source == TRAINING_SOURCE
    assert f"{tmp_path / 's2'} has a final evaluation that is not finite" in capsys.readouterr().err


def test_a_seed_run_twice_is_noted(capsys):
    once, again, other = (
        replace(fake_run([0, 1], [0, 1], seed=s), run_dir=Path(d)) for s, d in ((0, "a"), (0, "b"), (1, "c"))
    )
    assert [len(g.runs) for g in experiments_of([once, other])] == [2]
    assert capsys.readouterr().err == ""
    assert [len(g.runs) for g in experiments_of([once, again, other])] == [3]
    assert capsys.readouterr().err == (
        f"canter: note: {once.run_dir} and {again.run_dir} are both seed 0 of one experiment; each counts as a run "
        "of its group, but a rerun repeats a seed rather than adding an independent one: leave one out, or train "
        "another seed\n"
    )
    longer = fake_run([0, 1], [0, 1], seed=0, **{"run.total_steps": 3_000_000})  # another group: no repeat
    experiments_of([once, longer])
    assert capsys.readouterr().err == ""


def test_grouping_and_labels():
    runs = [
        fake_run([0, 1], [0, 1], seed=0),
        fake_run([0, 1], [0, 1], seed=1, **{"run.out_dir": "elsewhere"}),
        fake_run([0, 1], [0, 1], seed=0, **{"ppo.clip": 0.3}),
    ]
    groups = experiments_of(runs)
    assert [len(g.runs) for g in groups] == [2, 1]
    assert [g.label for g in groups] == ["ppo.clip=0.2", "ppo.clip=0.3"]
    # Another budget is another group (an annealed learning rate stretches over it), labelled by it; and so is it
    # another method.
    longer = fake_run([0, 1], [0, 1], seed=2, **{"run.total_steps": 3_000_000})
    groups = experiments_of([*runs, longer])
    assert [g.label for g in groups] == [
        "ppo.clip=0.2, budget=1000000",
        "ppo.clip=0.3, budget=1000000",
        "ppo.clip=0.2, budget=3000000",
    ]
    assert method_labels([runs[0].config, longer.config]) == ["budget=1000000", "budget=3000000"]
    assert group_by_experiment([r.config for r in [*runs, longer]]) == [[0, 1], [2], [3]]

    fast = build_config("Hopper-v5", preset="fast")
    cleanrl = build_config("Hopper-v5", preset="cleanrl")
    cleanrl_clip = apply_overrides(cleanrl, {"ppo.clip": 0.1}, "test")
    # A preset changes many keys; the label names the preset, plus the key that tells equal presets apart.
    assert experiment_labels([fast, cleanrl, cleanrl_clip]) == [
        "preset=fast",
        "preset=cleanrl, ppo.clip=0.2",
        "preset=cleanrl, ppo.clip=0.1",
    ]
    assert experiment_labels([fast]) == ["env=Hopper-v5 algo=ppo preset=fast"]
    # A method is a label without its env: the same preset on two envs is one method.
    walker = build_config("Walker2d-v5", preset="fast")
    assert experiment_labels([fast, walker, cleanrl]) == [
        "env=Hopper-v5, preset=fast",
        "env=Walker2d-v5, preset=fast",
        "env=Hopper-v5, preset=cleanrl",
    ]
    assert method_labels([fast, walker, cleanrl]) == ["preset=fast", "preset=fast", "preset=cleanrl"]
    assert method_labels([fast]) == ["algo=ppo, preset=fast"]
    # A key changed on one env only is another method, though no other config on that env tells it apart; and the
    # same config on two envs stays one method, though a changed key tells it apart from a third config on one env.
    walker_clip = apply_overrides(walker, {"ppo.clip": 0.1}, "test")
    assert method_labels([fast, walker_clip]) == ["ppo.clip=0.2", "ppo.clip=0.1"]
    hopper_clip = apply_overrides(fast, {"ppo.clip": 0.1}, "test")
    assert method_labels([fast, hopper_clip, walker]) == ["ppo.clip=0.2", "ppo.clip=0.1", "ppo.clip=0.2"]
    # The values a preset gives each env (brax's per-env tables) are the preset's, not another method.
    ant, humanoid = build_config("ant", preset="brax"), build_config("humanoid", preset="brax")
    assert dict(experiment_key(ant))["ppo.n_steps"] != dict(experiment_key(humanoid))["ppo.n_steps"]
    assert method_labels([ant, humanoid]) == ["algo=ppo, preset=brax"] * 2
    # Once runs on one env differ in a key, every run's method names its value: 80 on ant (the preset's) and 80 set
    # on humanoid are one method, humanoid's preset value another.
    shorter = apply_overrides(humanoid, {"ppo.n_steps": 80}, "test")
    n_steps = dict(experiment_key(humanoid))["ppo.n_steps"]
    assert method_labels([ant, humanoid, shorter]) == ["ppo.n_steps=80", f"ppo.n_steps={n_steps}", "ppo.n_steps=80"]
    # A grid over a key whose preset value differs per env (fast: log_std_init -1 on Hopper, 0 on Walker2d) keeps
    # the grid's values apart; they merged where a value happened to be the preset's for its env.
    grid = [
        apply_overrides(build_config(env, preset="fast"), {"net.log_std_init": value}, "test")
        for env in ("Hopper-v5", "Walker2d-v5")
        for value in (-1.0, 0.0)
    ]
    assert [dict(experiment_key(c))["net.log_std_init"] for c in (fast, walker)] == [-1.0, 0.0]
    assert method_labels(grid) == ["net.log_std_init=-1.0", "net.log_std_init=0.0"] * 2
    # Another algorithm (its config section may differ too) is labelled by the algorithm alone.
    td3 = fast.replace(run=replace(fast.run, algo="td3"), net=replace(fast.net, hidden=(256, 256)))
    assert experiment_labels([fast, td3]) == ["algo=ppo", "algo=td3"]


def test_method_labels_name_only_keys_the_method_reads():
    ppo = build_config("Hopper-v5", preset="fast")
    sac = build_config("Hopper-v5", preset="fast", algo="sac")
    # The algorithm tells them apart; neither row lists the other's keys as `=none`.
    assert method_labels([ppo, sac]) == ["algo=ppo", "algo=sac"]
    # Settings that another algorithm's method does not share (budget, env count) are not named either.
    small = apply_overrides(ppo, {"ppo.minibatch_size": 128, "env.num_envs": 4, "run.total_steps": 1024}, "test")
    td3 = build_config("Hopper-v5", preset="fast", algo="td3")
    assert method_labels([small, sac, td3]) == ["algo=ppo", "algo=sac", "algo=td3"]


def test_method_labels_name_the_keys_methods_of_one_algorithm_differ_in():
    ppo = build_config("Hopper-v5", preset="fast")
    narrow = apply_overrides(ppo, {"net.hidden": (16, 16)}, "test")
    assert method_labels([ppo, narrow]) == ["net.hidden=64,64", "net.hidden=16,16"]
    # With another algorithm beside them, the algorithm is named too, and the sac row stays short.
    sac = build_config("Hopper-v5", preset="fast", algo="sac")
    assert method_labels([ppo, narrow, sac]) == ["algo=ppo, net.hidden=64,64", "algo=ppo, net.hidden=16,16", "algo=sac"]


def test_choose_metrics_defaults_and_globs():
    run = fake_run([0, 1], [0, 1])
    columns = dict(
        run.columns,
        sps=np.array([5.0, 6.0]),
        critic_loss=np.array([1.0, np.nan]),
        empty=np.array([np.nan, np.nan]),
        **{"info/reward_ctrl": np.array([1.0, 2.0]), "info/x_velocity": np.array([0.0, 1.0])},
    )
    run = RunCurves(run.run_dir, run.config, columns)
    assert choose_metrics([run], None) == ["episodic_return", "sps", "critic_loss"]
    assert choose_metrics([run], ["info/*", "sps"]) == ["info/reward_ctrl", "info/x_velocity", "sps"]
    with pytest.raises(CanterError, match="no column empty, nope"):
        choose_metrics([run], ["empty", "nope"])


def test_read_metrics_skips_text_columns_and_keeps_empty_cells_as_nan(tmp_path):
    (tmp_path / "metrics.csv").write_text("global_step,episodic_return,note\n10,,a\n20,1.5,b\n")
    columns = read_metrics(tmp_path / "metrics.csv")
    assert set(columns) == {"global_step", "episodic_return"}
    assert np.isnan(columns["episodic_return"][0]) and columns["episodic_return"][1] == 1.5


def run_cli(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
def test_plot_cli_png_and_svg(tiny_run, tiny_run_seed1, tmp_path, capsys):
    import matplotlib.image

    other = tmp_path / "clip03"
    shutil.copytree(tiny_run.run_dir, other)
    config = apply_overrides(load_run(other).config, {"ppo.clip": 0.3}, "test")
    (other / "config.toml").write_text(to_toml(config))

    runs = [str(tiny_run.run_dir), str(tiny_run_seed1.run_dir), str(other)]
    code, _out, err = run_cli(["plot", *runs, "--out", str(tmp_path / "c.png"), "--smooth", "3"], capsys)
    assert code == 0, err
    image = matplotlib.image.imread(tmp_path / "c.png")
    assert image.shape[0] > 600 and image.shape[1] > 1000 and image[..., :3].std() > 0.05

    code, _out, err = run_cli(
        ["plot", *runs, "--out", str(tmp_path / "c.svg"), "--x", "wall", "--metrics", "episodic_return,approx_kl"],
        capsys,
    )
    assert code == 0, err
    svg = (tmp_path / "c.svg").read_text()
    ET.fromstring(svg)  # well-formed
    for text in (
        "Pendulum-v1",
        "Episode return",
        "Approx. KL",
        "wall time (s)",
        "ppo.clip=0.2 (2 runs), band: range",
        "ppo.clip=0.3 (1 run), no band",
        "groups of fewer than 5 runs): min to max of the runs",
        # The final scores' statistics: the runs have no eval.json, so their recent training return counts.
        "Final scores: training return",
        "stratified-bootstrap CIs",
        "IQM",
        "Optimality gap",
        "ppo.clip=0.2 (n=2)",
        "Probability of improvement",
    ):
        assert text in svg, text
    assert "Clip fraction" not in svg and "95% bootstrap CI" not in svg
    # The default panels leave out the symmetry loss, which these runs (sym.coef = 0) log as 0.
    code, _out, err = run_cli(["plot", *runs, "--out", str(tmp_path / "all.svg")], capsys)
    assert code == 0, err
    svg = (tmp_path / "all.svg").read_text()
    assert "Policy loss" in svg and "Clip fraction" in svg and "Symmetry loss" not in svg
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_file()) == ["all.svg", "c.png", "c.svg"]


@pytest.mark.slow
def test_plot_cli_bad_input(tiny_run, tmp_path, capsys):
    no_metrics = tmp_path / "empty_run"
    no_metrics.mkdir()
    code, _out, err = run_cli(["plot", str(no_metrics), "--out", str(tmp_path / "c.png")], capsys)
    assert code == 2 and err.count("\n") == 1 and "no metrics.csv" in err

    code, _out, err = run_cli(["plot", str(tiny_run.run_dir), "--metrics", "nope"], capsys)
    assert code == 2 and err.count("\n") == 1 and "choose from: episodic_return" in err

    code, _out, err = run_cli(["plot", str(tiny_run.run_dir), "--out", str(tmp_path / "c.jpeg2")], capsys)
    assert code == 2 and ".png" in err

    blocker = tmp_path / "a_file"
    blocker.write_text("")
    code, _out, err = run_cli(["plot", str(tiny_run.run_dir), "--out", str(blocker / "c.png")], capsys)
    assert code == 2 and err.count("\n") == 1 and "cannot write" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "empty_run"]


def test_a_constant_curve_reads_its_value_on_the_axis(tmp_path):
    """A learning rate that is not annealed is constant; matplotlib's offset notation labelled its axis
    "1e-16+3e-4" with ticks at 0."""
    steps = np.cumsum(np.random.default_rng(0).integers(150_000, 170_000, 62))  # uneven, as iterations end
    run = fake_run(steps, [3e-4] * 62)  # interpolated onto a grid, it varies by about 1e-19
    fig = draw([Experiment("g", (run,))], ["episodic_return"])
    fig.canvas.draw()
    ax = fig.axes[0]
    assert ax.yaxis.get_offset_text().get_text() == ""
    assert any("0.0003" in label.get_text() for label in ax.get_yticklabels())


def test_a_run_with_one_logged_row_shows_its_point():
    """A line through one point draws nothing: each panel of a 2048-step run was empty."""
    one = fake_run(np.array([2048]), [-1200.0])
    fig = draw([Experiment("one", (one,))], ["episodic_return"])
    (line,) = fig.axes[0].get_lines()
    assert line.get_marker() == "o" and line.get_xydata().tolist() == [[2048.0, -1200.0]]
    # Several runs: the range of their points is a bar, which the axis spans.
    runs = tuple(fake_run(np.array([2048]), [value], seed=i) for i, value in enumerate([-1200.0, -1000.0, -900.0]))
    fig = draw([Experiment("three", runs)], ["episodic_return"])
    fig.canvas.draw()
    low, high = fig.axes[0].get_ylim()
    assert low <= -1200 and high >= -900 and len(fig.axes[0].collections) == 1
    longer = fake_run(np.array([2048, 4096]), [-1200.0, -1100.0])
    assert draw([Experiment("two", (longer,))], ["episodic_return"]).axes[0].get_lines()[0].get_marker() in ("None", "")


def test_an_x_axis_that_a_run_did_not_log_is_named_not_drawn_empty(archived_run, tmp_path, capsys):
    import csv

    with (archived_run / "metrics.csv").open(newline="") as file:
        rows = list(csv.reader(file))
    wall = rows[0].index("wall_time")
    with (archived_run / "metrics.csv").open("w", newline="") as file:
        csv.writer(file).writerows(row[:wall] + row[wall + 1 :] for row in rows)
    assert error_line(capsys, ["plot", str(archived_run), "--x", "wall", "--out", str(tmp_path / "a.png")]) == (
        f"no wall_time values in the metrics.csv of {archived_run}, which --x wall draws against; plot with --x steps"
    )
    assert main(["plot", str(archived_run), "--out", str(tmp_path / "a.png")]) == 0
    whole = tmp_path / "whole"
    shutil.copytree(ARCHIVED_RUN, whole)
    assert main(["plot", str(archived_run), str(whole), "--x", "wall", "--out", str(tmp_path / "b.png")]) == 0
    assert f"canter: note: {archived_run} has no wall_time values in metrics.csv: left out of the panels" in (
        capsys.readouterr().err
    )
