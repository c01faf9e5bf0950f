"""Which OpenGL platform MuJoCo renders through here, and a renderer that cannot render refused in one line.

MuJoCo picks its OpenGL platform from MUJOCO_GL when `mujoco` is first imported, so `configure_gl()` must run before
anything imports mujoco, gymnasium's MuJoCo envs or dm_control. It probes EGL, then OSMesa, each in a throwaway
subprocess (a failing GL library can abort the process instead of raising).
"""

from __future__ import annotations

import os
import platform
import re
import subprocess
import sys
from collections.abc import Mapping, Sequence

from canter.errors import CanterError
from canter.training.videos import quiet_fork

GL_PACKAGES = {"egl": "libegl1", "osmesa": "libosmesa6"}
# What MuJoCo's own GL context reads from MUJOCO_GL (lower-cased): its renderers and its switches.
MUJOCO_GL_VALUES = frozenset(
    {"egl", "osmesa", "glfw", "glx", "cgl", "wgl", "enable", "on", "true", "1", "disable", "off", "false", "0"}
)
# Values under which MuJoCo's GLContext is GLFW's on Linux (its default, `enable` and the like), which opens an X11 or
# Wayland connection: headless, it fails only at the first frame, deep inside Gymnasium's renderer.
_DISPLAY_GL = frozenset({"glfw", "glx", "enable", "on", "true", "1"})
_NO_GL = frozenset({"disable", "off", "false", "0"})
_PLATFORM_GL = {"cgl": "Darwin", "wgl": "Windows", "glx": "Linux", "egl": "Linux", "osmesa": "Linux"}
# What to set instead, by platform.system(): canter chooses between the headless EGL and OSMesa on Linux only.
_GL_FIX = {
    "Linux": "unset MUJOCO_GL to let canter choose, or set egl or osmesa (headless)",
    "Darwin": "set MUJOCO_GL=cgl, or glfw with a display",
    "Windows": "set MUJOCO_GL=wgl, or glfw with a display",
}


def gl_fix(system: str | None = None) -> str:
    return _GL_FIX.get(system or platform.system(), _GL_FIX["Linux"])


_PROBE = "import mujoco; c = mujoco.GLContext(16, 16); c.make_current(); c.free()"


def _probe(backend: str) -> bool:
    env = dict(os.environ, MUJOCO_GL=backend)
    env.pop("PYOPENGL_PLATFORM", None)
    try:
        with quiet_fork():
            done = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, timeout=120)
        return done.returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def unavailable_message(tried: list[str]) -> str:
    packages = " ".join(GL_PACKAGES[b] for b in tried if b in GL_PACKAGES) or " ".join(GL_PACKAGES.values())
    return (
        f"headless rendering is unavailable: MuJoCo could not open an OpenGL context with MUJOCO_GL="
        f"{' or '.join(tried)}; install the system package(s): apt-get install -y {packages}"
    )


def configure_gl() -> str:
    """Choose MUJOCO_GL for this process (a user's choice is kept if it works) and return it."""
    chosen = os.environ.get("MUJOCO_GL")
    if chosen:
        check_renderer_name(chosen)
        if chosen in GL_PACKAGES and "mujoco" not in sys.modules and not _probe(chosen):
            raise CanterError(unavailable_message([chosen]))
        return chosen
    if "mujoco" in sys.modules:
        raise CanterError(
            "mujoco was imported before MUJOCO_GL was set; set MUJOCO_GL=egl (or osmesa) in the environment"
        )
    for backend in GL_PACKAGES:
        if _probe(backend):
            os.environ["MUJOCO_GL"] = backend
            if backend == "osmesa":
                os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
            return backend
    raise CanterError(unavailable_message(list(GL_PACKAGES)))


def check_renderer_name(chosen: str) -> None:
    """Refuse a MUJOCO_GL that names none of MuJoCo's renderers."""
    if chosen.lower().strip() not in MUJOCO_GL_VALUES:
        raise CanterError(
            f"MUJOCO_GL={chosen} is not one of MuJoCo's renderers; set egl or osmesa (headless), glfw, glx, cgl "
            f"or wgl (a display), or unset it to let canter choose"
        )


def renderer_problem(chosen: str, system: str, environ: Mapping[str, str]) -> str | None:
    """Why MUJOCO_GL=`chosen` cannot render on this `system` (platform.system()) with these environment variables,
    or None. Kept apart from `configure_gl`, which accepts every name MuJoCo knows, whatever the machine."""
    value = chosen.lower().strip()
    if value in _NO_GL:
        return f"MUJOCO_GL={chosen} turns MuJoCo's rendering off; {gl_fix(system)}"
    if _PLATFORM_GL.get(value, system) != system:
        return f"MUJOCO_GL={chosen} is MuJoCo's renderer on {_PLATFORM_GL[value]}, not {system}; {gl_fix(system)}"
    if system == "Linux" and value in _DISPLAY_GL and not (environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY")):
        return f"MUJOCO_GL={chosen} needs a display, and DISPLAY is not set; {gl_fix(system)}"
    return None


def check_renderer() -> None:
    """Refuse, in one line and before any rendering, a MUJOCO_GL that cannot render here. Training with videos
    checks it before its run folder is made: a renderer that fails later costs only its videos."""
    if os.environ.get("MUJOCO_GL"):
        check_renderer_name(os.environ["MUJOCO_GL"])
    problem = renderer_problem(os.environ.get("MUJOCO_GL", ""), platform.system(), os.environ)
    if problem:
        raise CanterError(problem)


def headless_in_this_process() -> bool:
    """True when MuJoCo in this process renders (or will render) through EGL or OSMesa."""
    if "mujoco" not in sys.modules:
        return True
    return sys.modules["mujoco"].GLContext.__module__ in ("mujoco.egl", "mujoco.osmesa")


def gl_failure(env_id: str, gl: str, error: str, warned: Sequence[str]) -> str:
    """The one line for MuJoCo's FatalError at the first frame: the first warning the glfw package gave as it
    failed (such as `X11: Failed to open display :1`) names the cause better than MuJoCo's own message."""
    # glfw formats its errors as `(code) b'text'`.
    reason = re.sub(r"^\(\d+\) b(['\"])(.*)\1$", r"\2", warned[0]) if warned else error.partition(",")[0]
    return f"cannot render {env_id} with MUJOCO_GL={gl}: {reason}; {gl_fix()}"
