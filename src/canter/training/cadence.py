"""When work paced in env steps falls due: checkpoints (`run.checkpoint_every`), evaluations (`run.eval_every`) and
videos (`run.video_every`).

Training counts env steps in whole iterations, so a step count rarely lands on a multiple of `every`; the work is
due at the first iteration boundary on or past each multiple, once, however many multiples one iteration passes.
"""

from __future__ import annotations

from dataclasses import dataclass


def next_due(step: int, every: int) -> int:
    """The first multiple of `every` after `step`: where work done at `step` (or a run starting there) is next due."""
    return (step // every + 1) * every


@dataclass(frozen=True)
class Cadence:
    """Work due every `every` env steps (0: never), last done, or started counting, at step `after`."""

    every: int
    after: int

    def __post_init__(self) -> None:
        if self.every < 0:
            raise ValueError(f"a cadence needs every >= 0, got {self.every}")

    def due(self, step: int) -> bool:
        return self.every > 0 and step >= next_due(self.after, self.every)

    def advance(self, step: int) -> Cadence:
        """The cadence once the work is done at `step`."""
        return Cadence(self.every, step)
