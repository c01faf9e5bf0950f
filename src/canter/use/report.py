"""One self-contained HTML page about run folders: what was trained (config), how well it does (an evaluation
table), how it learned (the curves of `canter.use.plot`), how robust it is (any robustness plot under the run), and
what it looks like (a video from the run's videos/ folder). Images and videos are embedded as base64 data URIs
and the page has no scripts, so it opens anywhere, offline, as a single file.
"""

from __future__ import annotations

import base64
import html
import math
import re
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from canter.config.schema import Config
from canter.config.serialize import to_toml
from canter.config.values import set_text
from canter.errors import CanterError
from canter.parsing import json_value
from canter.run_layout import VIDEOS_FOLDER
from canter.signals import StopFlag
from canter.training import checkpoint
from canter.use.scoreboard import Scoreboard
from canter.use.statistics import MIN_RUNS_FOR_INTERVAL
from canter.use.video_file import is_unfinished_video

VIDEO_TYPES = {".mp4": "video/mp4", ".webm": "video/webm"}
IMAGE_TYPES = {".gif": "image/gif", ".png": "image/png"}


@dataclass(frozen=True)
class RunFacts:
    run_dir: Path
    config: Config
    summary: dict[str, Any]  # summary.json of a finished training (empty while a run is going)
    robustness_plots: tuple[Path, ...]
    videos: tuple[Path, ...]  # finished RUN/videos/*.mp4|*.webm|*.gif in natural order; the last is embedded


@dataclass(frozen=True)
class EvalRow:
    run: str
    global_step: int
    return_mean: float
    return_std: float
    length_mean: float
    length_std: float
    eval_seconds: float
    episodes: int


def _natural_key(path: Path) -> list:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def run_facts(run_dir: str | Path, which: str | None = checkpoint.LAST) -> RunFacts:
    """What the report needs from a run folder; a one-line error when it lacks the checkpoint `which` names (None:
    the page plays none, as an archived run kept without checkpoints allows)."""
    from canter.run_layout import read_summary
    from canter.training.run_folder import read_config

    run_dir = Path(run_dir)
    if which is not None:
        # Refuses a folder without that checkpoint, or a file of another run, before any work is done: with
        # --episodes 0 nothing loads it later, yet the page names it.
        checkpoint.resolve_own(run_dir, which)
    else:
        checkpoint.need_run_folder(run_dir)  # a missing folder, or a bench's, told as such
    config = read_config(run_dir)
    summary = read_summary(run_dir) or {}  # none while training, or a damaged one: the table shows dashes
    robustness = (
        tuple(sorted((p for p in (run_dir / "robustness").rglob("*.png") if p.is_file()), key=_natural_key))
        if (run_dir / "robustness").is_dir()
        else ()
    )
    videos_dir = run_dir / VIDEOS_FOLDER
    videos = (
        tuple(
            sorted(
                (
                    p
                    for p in videos_dir.iterdir()
                    if p.suffix.lower() in (*VIDEO_TYPES, ".gif") and not is_unfinished_video(p) and p.is_file()
                ),
                key=_natural_key,
            )
        )
        if videos_dir.is_dir()
        else ()
    )
    return RunFacts(run_dir, config, summary, robustness, videos)


def evaluate_runs(run_dirs: Sequence[Path], episodes: int, seed: int, which: str = checkpoint.LAST) -> list[EvalRow]:
    """Deterministic evaluation of a checkpoint of each run (`which`) with frozen normalizer statistics."""
    from canter.use.evaluate import evaluate
    from canter.use.policy import load

    rows = []
    for run_dir in run_dirs:
        policy = load(run_dir, which)
        result = evaluate(policy, episodes=episodes, deterministic=True, seed=seed)
        rows.append(
            EvalRow(
                run_dir.name,
                policy.facts.global_step,
                result.mean,
                result.std,
                float(result.lengths.mean()),
                float(result.lengths.std()),
                result.wall_seconds,
                int(result.returns.size),
            )
        )
    return rows


# ------------------------------------------------------------------------------------------------------ HTML


def data_uri(path_or_bytes: Path | bytes, mime: str) -> str:
    data = path_or_bytes.read_bytes() if isinstance(path_or_bytes, Path) else path_or_bytes
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _number(value: Any) -> float | None:
    """A summary.json value that is a number, else None (a damaged or hand-edited file shows a dash)."""
    if not isinstance(value, int | float) or isinstance(value, bool):
        return None
    try:
        number = float(value)
    except OverflowError:  # an integer past float's range
        return None
    return number if math.isfinite(number) else None


def _duration(seconds: float | None) -> str:
    if seconds is None:
        return "–"
    seconds = round(seconds)
    return f"{seconds // 3600}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]], numeric_from: int = 1) -> str:
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join(
        "<tr>"
        + "".join(f"<td class='{'num' if i >= numeric_from else ''}'>{_e(c)}</td>" for i, c in enumerate(row))
        + "</tr>"
        for row in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def config_section(facts: Sequence[RunFacts]) -> str:
    """The keys in which the runs differ (the seed included), then each run's full resolved config."""
    from canter.config.experiment import flat_config

    flats = [flat_config(f.config) for f in facts]
    keys = list(dict.fromkeys(k for fl in flats for k in fl))
    parts = []
    if len(facts) > 1:
        differing = [k for k in keys if any(fl.get(k) != flats[0].get(k) for fl in flats[1:]) and k != "run.out_dir"]
        if differing:
            rows = [[k] + [set_text(fl.get(k)) for fl in flats] for k in differing]
            parts.append(
                "<p>Keys that differ between the runs:</p>"
                + _table(["key"] + [f"run {i + 1}" for i in range(len(facts))], rows, numeric_from=99)
            )
        else:
            parts.append("<p>The runs have identical configs.</p>")
    for i, f in enumerate(facts):
        parts.append(
            f"<details><summary>run {i + 1}: {_e(f.run_dir.name)} — full resolved config</summary>"
            f"<pre>{_e(to_toml(f.config))}</pre></details>"
        )
    return "\n".join(parts)


def experiment_groups(facts: Sequence[RunFacts]) -> list[tuple[str, list[int]]]:
    """The runs' groups (runs that differ only in seed share one), each with its label as `canter plot` draws it and
    its runs' indices, in order of first appearance."""
    from canter.config.experiment import group_by_experiment
    from canter.use.experiments import experiment_labels

    groups = group_by_experiment([f.config for f in facts])
    return list(zip(experiment_labels([facts[members[0]].config for members in groups]), groups))


def experiment_of_each(facts: Sequence[RunFacts]) -> list[str]:
    """For each run, the label of its group."""
    of_each = [""] * len(facts)
    for label, members in experiment_groups(facts):
        for i in members:
            of_each[i] = label
    return of_each


def runs_section(facts: Sequence[RunFacts]) -> str:
    rows = []
    for i, (f, group) in enumerate(zip(facts, experiment_of_each(facts))):
        s = f.summary
        rows.append(
            [
                f"{i + 1}. {f.run_dir.name}",
                group,
                f.config.run.seed,
                f"{step:,.0f}" if (step := _number(s.get("global_step"))) is not None else "–",
                _duration(_number(s.get("wall_seconds"))),
                f"{sps:,.0f}" if (sps := _number(s.get("sps"))) is not None else "–",
                str(s.get("stop_reason", "–")),
            ]
        )
    return _table(
        ["run", "group (config differences)", "seed", "steps", "train time (h:mm:ss)", "SPS", "stopped by"],
        rows,
        numeric_from=2,
    )


def eval_section(facts: Sequence[RunFacts], rows: Sequence[EvalRow]) -> str:
    """One row per run, then one summary row per group of runs that differ only in seed (mean ± std over the
    runs' mean returns)."""
    table_rows = [
        [
            f"{i + 1}. {r.run}",
            f"{r.global_step:,}",
            r.episodes,
            f"{r.return_mean:.1f} ± {r.return_std:.1f}",
            f"{r.length_mean:.1f} ± {r.length_std:.1f}",
            f"{r.eval_seconds:.2f}",
        ]
        for i, r in enumerate(rows)
    ]
    for label, members in experiment_groups(facts):
        if len(members) > 1:
            means = np.array([rows[i].return_mean for i in members])
            lengths = np.array([rows[i].length_mean for i in members])
            table_rows.append(
                [
                    f"{label}: mean of {len(members)} runs",
                    "",
                    "",
                    f"{means.mean():.1f} ± {means.std():.1f}",
                    f"{lengths.mean():.1f} ± {lengths.std():.1f}",
                    "",
                ]
            )
    return _table(
        ["run", "steps", "episodes", "return (mean ± std)", "episode length (steps)", "eval time (s)"], table_rows
    )


def media_section(
    facts: Sequence[RunFacts], recorded: dict[Path, tuple[Path, list[float]]] | None = None
) -> tuple[str, str]:
    """(robustness HTML, video HTML); empty strings when no run has any. `recorded` maps a run folder to a video
    made for this report and its episode returns; it is shown instead of the run's own videos."""
    robustness, videos = [], []
    for i, f in enumerate(facts):
        for plot in f.robustness_plots:
            robustness.append(
                f"<figure><img alt='robustness plot of run {i + 1}' "
                f"src='{data_uri(plot, 'image/png')}'><figcaption>run {i + 1}: "
                f"{_e(plot.relative_to(f.run_dir))}</figcaption></figure>" + robustness_table(plot.with_suffix(".json"))
            )
        if recorded is not None and f.run_dir in recorded:
            chosen, returns = recorded[f.run_dir]
            shown = ", ".join(f"{r:.1f}" for r in returns)
            caption = f"run {i + 1}: recorded for this report, deterministic, episode return {_e(shown)}"
        elif f.videos:
            chosen = f.videos[-1]
            caption = f"run {i + 1}: {_e(chosen.name)}"
            if len(f.videos) > 1:
                caption += f" (newest of {len(f.videos)} in videos/)"
        else:
            continue
        suffix = chosen.suffix.lower()
        if suffix in VIDEO_TYPES:
            tag = (
                f"<video controls muted loop playsinline preload='auto' "
                f"src='{data_uri(chosen, VIDEO_TYPES[suffix])}'></video>"
            )
        else:
            tag = f"<img alt='video of run {i + 1}' src='{data_uri(chosen, IMAGE_TYPES[suffix])}'>"
        videos.append(f"<figure>{tag}<figcaption>{caption}</figcaption></figure>")
    return "\n".join(robustness), "\n".join(videos)


def robustness_table(path: Path) -> str:
    """The numbers behind a robustness plot, from the JSON `canter eval --vary` writes beside it: return
    mean ± std at each scale, one column per run. Empty when there is no such file or it has another layout."""
    try:
        data = json_value(path.read_text())
        runs = data["runs"]
        scales = [p["scale"] for p in runs[0]["points"]]
        rows = [[f"{scale:g}"] + [_robustness_cell(r["points"][j]) for r in runs] for j, scale in enumerate(scales)]
        header = ["scale"] + [f"return: {r['label']}" for r in runs]
        note = f"{data['env']}, {data['vary']}, {data['episodes']} episodes per value"
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        return ""
    return f"<p class='note'>{_e(note)}</p>" + _table(header, rows)


def _robustness_cell(point: dict[str, Any]) -> str:
    if point.get("unstable_warnings"):
        return f"unstable ({point['unstable_warnings']} MuJoCo warnings)"
    return f"{point['return_mean']:.1f} ± {point['return_std']:.1f}"


STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 2rem auto; max-width: 1400px;
       padding: 0 1rem; color: #222; }
h1 { font-size: 1.5rem; } h2 { font-size: 1.2rem; margin-top: 2rem; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; font-size: 0.9rem; margin: 0.5rem 0; }
th, td { border: 1px solid #ddd; padding: 0.25rem 0.6rem; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; } th { background: #f4f4f4; }
img, video { max-width: 100%; } figure { margin: 0.5rem 0 1rem; } figcaption { color: #666; font-size: 0.85rem; }
pre { background: #f7f7f7; padding: 0.6rem; font-size: 0.8rem; overflow-x: auto; }
.note { color: #666; font-size: 0.85rem; }
"""


def render_html(
    facts: Sequence[RunFacts],
    eval_rows: Sequence[EvalRow] | None,
    episodes: int,
    curves_png: bytes,
    smooth: int,
    recorded: dict[Path, tuple[Path, list[float]]] | None = None,
    which: str = checkpoint.LAST,
    board: Scoreboard | None = None,
) -> str:
    from canter import __version__

    envs = sorted({f.config.env.id for f in facts})
    title = f"canter report: {', '.join(envs)} ({len(facts)} run{'s' if len(facts) > 1 else ''})"
    robustness, videos = media_section(facts, recorded)
    if eval_rows is None:
        evaluation = "<p class='note'>Not evaluated (--episodes 0).</p>"
    else:
        evaluation = (
            f"<p class='note'>{_e(_checkpoint_note(which))}: {episodes} deterministic episodes per run on fresh "
            f"envs, normalizer statistics frozen; ± is the standard deviation over episodes.</p>"
            + eval_section(facts, eval_rows)
        )
    smoothing = f"trailing moving average over {smooth} logged rows" if smooth > 1 else "unsmoothed"
    sections = [
        ("Runs", runs_section(facts)),
        ("Evaluation", evaluation),
        ("Statistics", statistics_section(board)),
        (
            "Learning curves",
            f"<p class='note'>Runs that differ only in seed are averaged; shaded: the range (min to max) of "
            f"the runs for groups of fewer than {MIN_RUNS_FOR_INTERVAL} runs, the 95% bootstrap confidence band of "
            f"the mean for groups of {MIN_RUNS_FOR_INTERVAL} or more (the legend names each group's band and its n); "
            f"{smoothing}. "
            f"Below the curves: the statistics of the final scores, as in the Statistics section.</p>"
            f"<img alt='learning curves' src='{data_uri(curves_png, 'image/png')}'>",
        ),
        (
            "Robustness",
            robustness
            or "<p class='note'>No robustness plot in these runs "
            "(<code>canter eval RUN --vary ...</code> writes one under RUN/robustness/).</p>",
        ),
        ("Video", videos or "<p class='note'>No video in these runs' videos/ folders.</p>"),
        ("Config", config_section(facts)),
    ]
    generated = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    body = "\n".join(f"<section><h2>{_e(name)}</h2>\n{content}\n</section>" for name, content in sections)
    return (
        f"<!DOCTYPE html>\n<html lang='en'>\n<head>\n<meta charset='utf-8'>\n"
        f"<meta name='viewport' content='width=device-width, initial-scale=1'>\n<title>{_e(title)}</title>\n"
        f"<style>{STYLE}</style>\n</head>\n<body>\n<h1>{_e(title)}</h1>\n"
        f"<p class='note'>Generated {generated} by canter {_e(__version__)}.</p>\n{body}\n</body>\n</html>\n"
    )


def statistics_section(board: Scoreboard | None) -> str:
    """The scoreboard's tables: aggregates with their intervals, profiles and probabilities of improvement."""
    if board is None:
        return (
            "<p class='note'>No statistics: they need a group of two or more runs with a score (an evaluation, or "
            "a finished training).</p>"
        )
    parts = []
    for table in board.tables():
        parts.append(f"<h3>{_e(table.title)}</h3><p class='note'>{_e(table.note)}</p>")
        parts.append(_table(table.header, table.rows, numeric_from=len(table.header)))
    note = board.normalizer_note()
    return "\n".join(parts + ([f"<p class='note'>{_e(note)}</p>"] if note else []))


def _temp_video_error(exc: CanterError, folder: str) -> CanterError:
    """A video that could not be written to the report's temp folder, which is gone by the time the user reads the
    error: the fix names where that folder was made (TMPDIR), not the folder itself."""
    if folder not in str(exc):
        return exc
    parent = Path(folder).parent
    return CanterError(
        f"cannot write the report's videos in {parent}, the temp folder (TMPDIR): it is full or not writable; "
        f"free space in {parent}, or set TMPDIR to a folder with room, then run the command again"
    )


def _checkpoint_note(which: str) -> str:
    if which == checkpoint.BEST:
        return (
            "Best checkpoints (checkpoints/best.npz), on held-out env seeds apart from the evaluations during "
            "training that chose them"
        )
    return "Newest checkpoints" if which == checkpoint.LAST else f"Checkpoint {Path(which).name}"


def _refuse_uninstalled_backends(facts: Sequence[RunFacts]) -> None:
    """A run evaluates on the backend it trained on, which the report has no flag to change (as `canter eval`'s
    --backend does): where that backend is not installed, the one line says so and names --episodes 0."""
    from canter.envs.registry import AUTO, get_backend

    for f in facts:
        if f.config.env.backend == AUTO:
            continue
        backend = get_backend(f.config.env.backend)
        if not backend.available():
            install = f"{backend.install}, or " if backend.install else ""
            raise CanterError(
                f"{backend.label} is not installed here, and the report evaluates {f.run_dir} on it, as it trained; "
                f"{install}pass --episodes 0 to report it without an evaluation"
            )


def build_report(
    run_dirs: Sequence[str | Path],
    episodes: int = 10,
    seed: int = 0,
    smooth: int = 1,
    video: bool = False,
    which: str = checkpoint.LAST,
) -> str:
    """The report page, evaluating the checkpoint `which` names (`last`, `best` or a file). With `video`, one
    deterministic episode of each run is rendered for it (canter.use.video) into a temp folder, rather than embedding
    the newest file of the run's videos/ folder. SIGINT or SIGTERM stops the rendering and acts once the temp folder
    is removed, as it would have (`StopFlag.deliver`); where the caller's own handler returns instead, so does this,
    with a page of the videos finished before the stop."""
    from canter.use.curves import load_run
    from canter.use.plot import render_runs

    if episodes < 0:
        raise CanterError(f"--episodes must be >= 0 (0 skips the evaluation), got {episodes}")
    if smooth < 1:
        raise CanterError(f"--smooth must be >= 1 rows, got {smooth}")
    # Without a play the default `last` may be missing (an archived run kept without checkpoints); `best` or a file
    # was asked for by name, so a run without it is refused as it is when the page plays it.
    needs_checkpoint = bool(episodes) or video or which != checkpoint.LAST
    facts = [run_facts(r, which if needs_checkpoint else None) for r in run_dirs]
    if video:  # before the evaluation, which can take minutes
        from canter.envs.registry import refuse_mujoco_py_replay, refuse_video_of_own_envs

        for f in facts:
            refuse_video_of_own_envs(f.config.env.backend, f.config.env.id, "drop --video")
            refuse_mujoco_py_replay(
                f.config.env.id, "report --video renders its video", "drop --video, or report a run of {newer}"
            )
    if episodes:
        _refuse_uninstalled_backends(facts)
    runs = [load_run(f.run_dir) for f in facts]  # a folder the curves cannot be read from fails now, not later
    rows = evaluate_runs([f.run_dir for f in facts], episodes, seed, which) if episodes else None
    # The statistics use this report's evaluation where there is one, else each run's own final score.
    source = f"this report's evaluation ({_checkpoint_note(which).lower()}, {episodes} deterministic episodes)"
    scores = {f.run_dir: (r.return_mean, source) for f, r in zip(facts, rows)} if rows else None
    curves, board = render_runs(runs, "png", smooth=smooth, seed=seed, scores=scores)
    if not video:
        return render_html(facts, rows, episodes, curves, smooth, which=which, board=board)
    from canter.use.video import record_video

    # A stop signal is held back until the temp folder is gone, which SIGTERM's default action would leave behind.
    with StopFlag() as stop, tempfile.TemporaryDirectory(prefix="canter-report-") as folder:
        recorded = {}
        for i, f in enumerate(facts):
            if stop.signal is not None:
                break
            path = Path(folder) / f"run{i + 1}.mp4"
            try:
                returns = record_video(f.run_dir, path, episodes=1, seed=seed, checkpoint=which, stop=stop)
            except CanterError as exc:
                raise _temp_video_error(exc, folder) from None
            if stop.signal is None:  # a render that the stop cut short wrote no file
                recorded[f.run_dir] = (path, returns)
        page = render_html(facts, rows, episodes, curves, smooth, recorded, which, board)
    stop.deliver()
    return page
