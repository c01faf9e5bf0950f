"""Weights & Biases: one W&B run per seed, the seeds of an experiment in one W&B group (extra `canter[wandb]`).

The W&B project is `canter` unless WANDB_PROJECT says otherwise; WANDB_MODE=offline keeps everything local."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

from canter.errors import CanterError, first_line
from canter.run_layout import CONFIG_FILE, SUMMARY_FILE
from canter.training.trackers.base import RunContext, TrackSpec


def _wandb() -> Any:
    try:
        import wandb
    except ImportError:
        raise CanterError("--track wandb needs the W&B client; install canter[wandb]") from None
    return wandb


_LOCAL_MODES = ("offline", "disabled", "dryrun")


def _has_credentials() -> bool:
    """Whether W&B has a key to go online with: WANDB_API_KEY, an identity token, or what `wandb login` saved in the
    netrc file for the W&B host."""
    import netrc
    from urllib.parse import urlparse

    if os.environ.get("WANDB_API_KEY") or os.environ.get("WANDB_IDENTITY_TOKEN_FILE"):
        return True
    host = urlparse(os.environ.get("WANDB_BASE_URL", "https://api.wandb.ai")).hostname or "api.wandb.ai"
    try:
        return netrc.netrc(os.environ.get("NETRC")).authenticators(host) is not None
    except (OSError, netrc.NetrcParseError):
        return False


WANDB_FLUSH_SECONDS = 1.0


class WandbTracker:
    def check(self, spec: TrackSpec) -> None:
        _wandb()
        # Online without a key, every seed's run would fail to start after its env and run folder were made.
        if os.environ.get("WANDB_MODE", "online") not in _LOCAL_MODES and not _has_credentials():
            raise CanterError(
                "--track wandb has no W&B API key here; run `wandb login` (or set WANDB_API_KEY), or set "
                "WANDB_MODE=offline to keep the runs local"
            )

    def open_group(self, spec: TrackSpec, group: str) -> None:
        """A W&B group is only a name each run carries."""

    def start(self, context: RunContext, run_id: str | None) -> _WandbRun:
        wandb = _wandb()
        # The system monitor and the console capture cost seconds at start and add nothing canter does not log.
        # By default W&B writes its run file every 15 s, and a SIGKILL loses what it has not written, checkpointed
        # rows among them; once a second bounds that to the last second.
        settings = wandb.Settings(
            silent=True,
            console="off",
            x_disable_stats=True,
            x_disable_meta=True,
            x_transaction_log_flush_interval=WANDB_FLUSH_SECONDS,
        )
        try:
            run = wandb.init(
                project=context.recorded.get("project") or os.environ.get("WANDB_PROJECT", "canter"),
                entity=context.recorded.get("entity") or None,
                group=context.group,
                name=context.name,
                config={**context.config, **dict(context.spec.tags)},
                id=run_id,
                resume="must" if run_id else None,
                reinit="create_new",  # the seeds of a group each have their own run in this process
                settings=settings,
            )
        except Exception as exc:
            raise CanterError(f"--track wandb could not start a W&B run: {first_line(exc)}") from None
        return _WandbRun(run)


class _WandbRun:
    def __init__(self, run: Any) -> None:
        self._run = run
        self.run_id: str = run.id
        self.place = {key: str(value) for key in ("project", "entity") if (value := getattr(run, key, None))}

    def log(self, values: dict[str, float], step: int) -> None:
        self._run.log(values, step=step)

    def finish(self, out: Path, summary: dict[str, Any]) -> None:
        self._run.summary.update({f"summary/{k}": v for k, v in summary.items()})
        # Copied, not `run.save`d: save links the live file (a resume rewrites it) and warns once per file, per
        # seed; W&B uploads what its run folder holds when the run finishes.
        for name in (SUMMARY_FILE, CONFIG_FILE):
            shutil.copyfile(out / name, Path(self._run.dir) / name)
        self._run.finish()

    def close(self) -> None:
        self._run.finish(exit_code=1)
