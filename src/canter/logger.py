"""Metric outputs: metrics.csv (stable columns that plot and bench read), TensorBoard events, and a progress bar.

metrics.csv has one row per iteration. Columns:
- `global_step`: env steps so far (autoreset steps excluded); `iteration`; `wall_time`: seconds since the run
  started, compile included; `sps`: steps per second over this iteration, compile excluded.
- `episodes`, `episodic_return`, `episodic_length`: episodes finished in this iteration and their mean raw return
  and length (empty when none finished).
- then the algorithm's diagnostics, in the order of its `metric_names`. For ppo: `policy_loss`, `value_loss`,
  `entropy`, `approx_kl`, `clip_frac`, `explained_variance`, `learning_rate`, `epochs_run`, averaged over the
  iteration's minibatches.
- `info/<key>`: per-episode reward terms the env reports (sums for reward/cost terms, per-step means otherwise).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

BASE_COLUMNS = ("global_step", "iteration", "wall_time", "sps", "episodes", "episodic_return", "episodic_length")


def columns_for(metric_names: tuple[str, ...], info_keys: tuple[str, ...]) -> list[str]:
    return list(BASE_COLUMNS) + list(metric_names) + [f"info/{k}" for k in info_keys]


class MetricsLogger:
    def __init__(self, run_dir: Path, metric_names: tuple[str, ...], info_keys: tuple[str, ...],
                 tensorboard: bool) -> None:
        self.path = Path(run_dir) / "metrics.csv"
        self.columns = columns_for(metric_names, info_keys)
        exists = self.path.is_file() and self.path.stat().st_size > 0
        self._file = open(self.path, "a", newline="")
        self._writer = csv.DictWriter(self._file, fieldnames=self.columns, extrasaction="ignore")
        if not exists:
            self._writer.writeheader()
        self._tb = None
        if tensorboard:
            from tensorboardX import SummaryWriter

            self._tb = SummaryWriter(str(Path(run_dir) / "tb"))

    def log(self, row: dict[str, Any]) -> None:
        clean = {k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()}
        self._writer.writerow(clean)
        self._file.flush()
        if self._tb is not None:
            step = int(row["global_step"])
            for key, value in row.items():
                if key in ("global_step", "iteration") or value is None:
                    continue
                if isinstance(value, float) and math.isnan(value):
                    continue
                tag = key if "/" in key else (f"charts/{key}" if key in ("episodic_return", "episodic_length",
                                                                           "sps", "learning_rate", "episodes")
                                              else f"losses/{key}")
                self._tb.add_scalar(tag, value, step)

    def scalar(self, tag: str, value: float, step: int) -> None:
        if self._tb is not None:
            self._tb.add_scalar(tag, value, step)

    def close(self) -> None:
        self._file.close()
        if self._tb is not None:
            self._tb.close()


class Progress:
    """A rich progress bar with steps, SPS, ETA and the recent mean return; a no-op when quiet."""

    def __init__(self, total: int, start: int, quiet: bool, description: str) -> None:
        self._bar = None
        if quiet:
            return
        from rich.progress import BarColumn, Progress as RichProgress, TextColumn, TimeRemainingColumn

        self._total = total
        self._bar = RichProgress(TextColumn("[bold]{task.description}"), BarColumn(bar_width=24),
                                 TextColumn("{task.fields[steps]}"), TextColumn("{task.fields[sps]} SPS"),
                                 TextColumn("ret {task.fields[ret]}"), TextColumn("ETA"), TimeRemainingColumn(),
                                 transient=False)
        self._bar.start()
        self._task = self._bar.add_task(description, total=total, completed=start, steps=self._steps(start),
                                        sps="-", ret="-")

    def _steps(self, step: int) -> str:
        def short(n: float) -> str:
            return f"{n / 1e6:.2f}M" if n >= 1e6 else f"{n / 1e3:.0f}k"
        return f"{short(step)}/{short(self._total)}"

    def update(self, step: int, sps: float, recent_return: float | None) -> None:
        if self._bar is None:
            return
        ret = "-" if recent_return is None else f"{recent_return:.1f}"
        self._bar.update(self._task, completed=step, steps=self._steps(step), sps=f"{sps:,.0f}", ret=ret)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.stop()
