"""DM Control's own names and observations of a task that EnvPool runs (EnvPool spells some differently, e.g.
humanoid_CMU), for the EnvPool backend and for replaying a run in dm_control to render it."""

from __future__ import annotations

import warnings
from typing import Any


def suite_task(suite: Any, domain: str, task: str) -> tuple[str, str] | None:
    """dm_control's (domain, task) spelling of an EnvPool task, or None when its suite has no such task."""
    by_lower = {(d.lower(), t.lower()): (d, t) for d, t in suite.ALL_TASKS}
    return by_lower.get((domain.lower(), task.lower()))


def observation_keys(domain: str, task: str) -> frozenset[str] | None:
    """The keys of the task's own observation in dm_control, or None when dm_control cannot say (not installed, or
    no such task). EnvPool declares one observation space per domain, so some of its tasks carry the keys of their
    domain's other tasks (QuadrupedRun the ball and target of QuadrupedFetch and QuadrupedEscape)."""
    try:
        with warnings.catch_warnings():
            # dm_control loads its renderer on import, and on a machine without a display GLFW warns that it has
            # none: this lookup renders nothing, and videos choose their own OpenGL platform (canter.use.renderer).
            warnings.filterwarnings("ignore", message=r".*DISPLAY environment variable is missing")
            from dm_control import suite
    except ImportError:
        return None
    found = suite_task(suite, domain, task)
    if found is None:
        return None
    env = suite.load(*found)
    try:
        return frozenset(env.observation_spec())
    finally:
        env.close()
