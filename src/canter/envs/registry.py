"""THE list of env backends. Adding one is a package under `canter.envs` exposing `BACKEND` plus one line here.

Each backend's package is imported on first use, and importing it imports no env library, so config validation and
the CLI read the names here without paying for gymnasium, envpool or mujoco.
"""

from __future__ import annotations

import difflib
import importlib
import re
import sys
from collections.abc import Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, NamedTuple

from canter.errors import CanterError

if TYPE_CHECKING:
    from canter.envs.base import Backend, VecEnv

AUTO = "auto"

# The env keys that change the physics of the backends with `solver_options`, each with the value that leaves the
# model's own (the XML's solver iterations, all its collisions).
MODEL_OWN_PHYSICS: Mapping[str, Any] = MappingProxyType(
    {"solver_iterations": 0, "solver_ls_iterations": 0, "contacts": "all"}
)

# name -> package. The order is `auto`'s: it takes the first backend that has the id, among those that step C MuJoCo
# on the host (a JAX-native backend is always asked for by name).
_BACKENDS = {
    "envpool": "canter.envs.envpool",
    "gymnasium": "canter.envs.gymnasium",
    "mjx": "canter.envs.mjx",
    "brax": "canter.envs.brax",
}


# Gymnasium's MuJoCo tasks. Their v2 and v3 ids are still registered but ran on mujoco-py, which Gymnasium dropped:
# making one fails with an ImportError about a missing dependency, which no install fixes here.
_MUJOCO_TASKS = (
    "Ant",
    "HalfCheetah",
    "Hopper",
    "Humanoid",
    "HumanoidStandup",
    "InvertedDoublePendulum",
    "InvertedPendulum",
    "Pusher",
    "Reacher",
    "Swimmer",
    "Walker2d",
)
_MUJOCO_PY_ID = re.compile(rf"({'|'.join(_MUJOCO_TASKS)})-v[23]")


def backend_names() -> tuple[str, ...]:
    return tuple(_BACKENDS)


def backend_choices() -> tuple[str, ...]:
    """What env.backend and --backend accept."""
    return (AUTO, *_BACKENDS)


def describe_backend_choices() -> str:
    """The accepted names as a phrase for messages: auto, envpool or gymnasium."""
    return _or(list(backend_choices()))


def backend_doc() -> str:
    """The reference text of env.backend: what `auto` picks, then the accepted names."""
    labels = [backend.label for backend in _auto_backends()]
    order = ", else ".join([f"{label} where it has the id" for label in labels[:-1]] + labels[-1:])
    return f"`{AUTO}` ({order}), {_or([f'`{name}`' for name in _BACKENDS])}."


def get_backend(name: str) -> Backend:
    if name not in _BACKENDS:
        raise CanterError(f"unknown env backend '{name}'; use {describe_backend_choices()}")
    return importlib.import_module(_BACKENDS[name]).BACKEND


def backends() -> list[Backend]:
    """Every backend, in `auto` order."""
    return [get_backend(name) for name in _BACKENDS]


def single_env_backend() -> Backend:
    """The backend that builds one Gymnasium-API env at a time: robustness sweeps edit its MuJoCo model and videos
    render it."""
    return next(backend for backend in backends() if backend.single_envs)


def held_only_elsewhere(env_id: str) -> str:
    """For an id the single-env backend lacks, which renders videos and is what --vary edits: the installed
    backends that have it, as a phrase for the error that says so."""
    single = single_env_backend()
    labels = [b.label for b in backends() if b is not single and b.available() and env_id in b.supported_ids()]
    return f"only {_or(labels)} has it" if labels else "no backend installed here has it"


def replay_note(env_id: str, trained_on: str, played_on: str) -> str | None:
    """A one-line note where a run is played on another backend than it trained on, whose env of that id differs
    (either way round: the difference is between a backend and the single-env one)."""
    single = single_env_backend().name
    if trained_on == played_on or {trained_on, played_on} - set(_BACKENDS) or single not in (trained_on, played_on):
        return None
    other = get_backend(played_on if trained_on == single else trained_on)
    how = other.differs_from_single_envs(env_id)
    if how is None:
        return None
    return (
        f"canter: note: {env_id} trained on {get_backend(trained_on).label} and played on "
        f"{get_backend(played_on).label} here, whose envs of it differ ({other.label}'s: {how}); the policy sees other "
        f"inputs than it learned on, and the return is another reward"
    )


_NOTED_REPLAYS: set[tuple[str, str, str]] = set()


def note_replay(env_id: str, trained_on: str, played_on: str) -> None:
    """Print `replay_note` once per process for each (env, trained on, played on): a sweep plays many times."""
    key = (env_id, trained_on, resolve_backend(env_id, played_on) if played_on == AUTO else played_on)
    note = replay_note(*key)
    if note and key not in _NOTED_REPLAYS:
        _NOTED_REPLAYS.add(key)
        print(note, file=sys.stderr)


def dm_control_task(env_id: str) -> tuple[str, str] | None:
    """(domain, task) of dm_control's suite that env_id runs, or None when it is not a DM Control env."""
    return next((task for backend in backends() if (task := backend.dm_control_task(env_id))), None)


def known_ids() -> list[str]:
    return sorted({env_id for backend in backends() for env_id in backend.supported_ids()})


def resolve_backend(env_id: str, backend: str) -> str:
    """The name of the backend that will run env_id, or a one-line error naming the nearest known ids."""
    if ":" in env_id:
        return _resolve_custom(env_id, backend)
    if backend == AUTO:
        for candidate in _auto_backends():
            if env_id in candidate.supported_ids():
                return candidate.name
        raise (
            _elsewhere(env_id)
            or _not_installed_home(env_id)
            or _unknown(env_id, sorted({i for b in _auto_backends() for i in b.supported_ids()}), "canter")
        )
    chosen = get_backend(backend)
    if not chosen.available():
        raise _not_installed(env_id, chosen)
    ids = chosen.supported_ids()
    if env_id not in ids and chosen.jax_native:
        raise _not_ported(env_id, chosen, sorted(ids))
    if env_id not in ids:
        raise _elsewhere(env_id, chosen) or _not_installed_home(env_id) or _unknown(env_id, sorted(ids), chosen.label)
    return chosen.name


class MujocoPyId(NamedTuple):
    """A mujoco-py version of a Gymnasium MuJoCo task, on a backend of Gymnasium's own envs that cannot make it."""

    problem: str  # Hopper-v3 is an old MuJoCo version that needs mujoco-py, which Gymnasium no longer runs
    newer: str  # its current versions there: Hopper-v5 (or Hopper-v4)
    ports: str  # the other installed backends with their own port of the id (envpool), or ""


def mujoco_py_id(env_id: str, backend_name: str) -> MujocoPyId | None:
    """What to say of env_id where it is a mujoco-py version of a Gymnasium MuJoCo task and backend_name (or what
    `auto` picks) is a backend of Gymnasium's own envs, whose gym.make would fail with an ImportError about a missing
    dependency that no install fixes; None otherwise. Other ids return at once, without importing an env library."""
    found = _MUJOCO_PY_ID.fullmatch(env_id)
    if found is None:
        return None
    try:
        backend = get_backend(resolve_backend(env_id, backend_name))
    except CanterError:
        return None  # the caller says why this id cannot run
    if not backend.single_envs:
        return None
    ids = backend.supported_ids()
    newer = [f"{found.group(1)}-v{version}" for version in (5, 4) if f"{found.group(1)}-v{version}" in ids]
    instead = f"{newer[0]}{f' (or {newer[1]})' if len(newer) > 1 else ''}" if newer else "its v5 or v4 version"
    ports = [b.name for b in backends() if b is not backend and b.available() and env_id in b.supported_ids()]
    problem = f"{env_id} is an old MuJoCo version that needs mujoco-py, which {backend.label} no longer runs"
    return MujocoPyId(problem, instead, _or(ports) if ports else "")


def refuse_mujoco_py(env_id: str, backend_name: str) -> None:
    """A one-line error for a mujoco-py version of a Gymnasium MuJoCo task that would train on a backend of
    Gymnasium's own envs (`mujoco_py_id`), naming the current versions (and a backend with its own port of this id,
    where one is installed)."""
    old = mujoco_py_id(env_id, backend_name)
    if old is None:
        return
    # Only a config reaches this check, so env.backend is the one Python name.
    port = (
        f", or pass --backend {old.ports} (env.backend from Python), which runs its own {env_id}" if old.ports else ""
    )
    raise CanterError(f"{old.problem}; train {old.newer} instead{port}")


def refuse_mujoco_py_replay(env_id: str, plays: str, instead: str, elsewhere: str = "") -> None:
    """The same error for a command that plays a trained run of env_id on the single-env backend (a video, a
    robustness sweep), which cannot make it: `plays` says what plays there, `instead` what to do instead (`{newer}` in
    it names the current versions) and `elsewhere`, added where another backend runs its own port of the id, what
    still plays this run (`{ports}` in it names those backends)."""
    old = mujoco_py_id(env_id, single_env_backend().name)
    if old is None:
        return
    other = elsewhere.format(ports=old.ports) if old.ports else ""
    raise CanterError(f"{old.problem}, and {plays} there; {instead.format(newer=old.newer)}{other}")


def refuse_video_of_own_envs(backend: str, env_id: str, fix: str) -> None:
    """One line for a video of a run on a backend whose envs are its own models (Brax): canter renders through
    Gymnasium's envs, which have no such model to show. `fix` says what to do instead."""
    if backend in (AUTO, "") or not get_backend(backend).own_observations:
        return
    label = get_backend(backend).label
    raise CanterError(
        f"a run on {label}'s own envs ({env_id}) has no video: canter renders through Gymnasium's envs, which do not "
        f"have {label}'s models; {fix}"
    )


def _elsewhere(env_id: str, chosen: Backend | None = None) -> CanterError | None:
    """The error for an id that another backend than the one chosen (or than `auto`'s) runs: it names that one."""
    where = [b.name for b in backends() if b is not chosen and b.available() and env_id in b.supported_ids()]
    if chosen is None:
        where = [name for name in where if get_backend(name).jax_native]  # auto would have found the others
    if not where:
        return None
    if chosen is None:
        labels = _or([get_backend(name).label for name in where])
        return CanterError(f"'{env_id}' is an env id of {labels}; {_python_backend(f'pass --backend {_or(where)}')}")
    advice = _python_backend(f"pass --backend {_or(where)}, or drop --backend")
    return CanterError(f"{chosen.label} does not run {env_id}; {advice}")


def _not_installed_homes(env_id: str, chosen: Backend | None = None) -> list[Backend]:
    """The backends other than `chosen`, not installed here, that would run env_id (`installable_ids`)."""
    return [b for b in backends() if b is not chosen and env_id in b.installable_ids and not b.available()]


def _install_and_pass(home: Backend) -> str:
    return f"{home.install} and pass --backend {home.name}"


def _not_installed_home(env_id: str) -> CanterError | None:
    """The error for an id that only a backend not installed here runs: its install, and --backend."""
    homes = _not_installed_homes(env_id)
    if not homes:
        return None
    advice = _python_backend(_install_and_pass(homes[0]))
    return CanterError(f"'{env_id}' is an env id of {homes[0].label}, which is not installed here; {advice}")


def _not_ported(env_id: str, chosen: Backend, ids: list[str]) -> CanterError:
    """The error for an id that a JAX-native backend does not run, with the ids it runs (few, unlike a CPU
    backend's): the backends that run it (or would, once installed), and the chosen one's id of the same task, which
    backends spell differently (hopper, Hopper-v5); for an id none runs, its nearest ids."""
    runs = f"--backend {chosen.name} runs {_or(ids)}"
    others = [b for b in backends() if b is not chosen and b.available() and env_id in b.supported_ids()]
    homes = _not_installed_homes(env_id, chosen)
    if not others and not homes:
        lowered = {known.lower(): known for known in ids}
        close = [lowered[match] for match in difflib.get_close_matches(env_id.lower(), list(lowered), n=3, cutoff=0.6)]
        hint = f"did you mean {', '.join(close)}? ({runs})" if close else runs
        return CanterError(f"unknown env id '{env_id}' for {chosen.label}; {hint}")
    fixes = []
    native = [b.name for b in others if b.jax_native]
    if native:
        fixes.append(f"pass --backend {_or(native)}")
    fixes.extend(_install_and_pass(home) for home in homes)
    if len(native) < len(others):  # `auto` finds it on a backend that steps it on the host
        fixes.append("drop --backend to run it on the CPU")
    same_task = [known for known in ids if _task(known) == _task(env_id)]
    if same_task:
        fixes.append(f"use {_or(same_task)} with --backend {chosen.name}")
    advice = fixes[0] if len(fixes) == 1 else f"{', '.join(fixes[:-1])}, or {fixes[-1]}"
    return CanterError(f"{chosen.label} does not run {env_id} ({runs}); {_python_backend(advice)}")


def _task(env_id: str) -> str:
    """An id without its version, case or underscores: hopper, Hopper-v5 and Hopper-v4 are one task."""
    return re.sub(r"-v\d+$", "", env_id).replace("_", "").lower()


def make_vec_env(env_id: str, backend: str, num_envs: int, seeds: list[int], shards: int = 0, **kwargs: Any) -> VecEnv:
    """`shards` applies to backends with pools (0: one single-threaded pool per core); kwargs go to the env."""
    return get_backend(resolve_backend(env_id, backend)).make(env_id, num_envs, seeds, shards, **kwargs)


def solver_backends() -> list[str]:
    """The backends that take env.solver_iterations, env.solver_ls_iterations and env.contacts."""
    return [backend.name for backend in backends() if backend.solver_options]


def pooled_backends() -> list[str]:
    """The backends that split their envs over pools as env.envpool_shards asks."""
    return [backend.name for backend in backends() if backend.pools]


def env_options(env: Any, backend: str) -> dict[str, Any]:
    """What an env section asks of the backend that steps it, as `make`'s keyword arguments: the physics settings
    where the backend takes them and they change the model (solver iterations 0 and contacts `all` leave its own)."""
    if backend == AUTO or not get_backend(backend).solver_options:
        return {}
    return {key: getattr(env, key) for key, own in MODEL_OWN_PHYSICS.items() if getattr(env, key) != own}


def _auto_backends() -> list[Backend]:
    return [backend for backend in backends() if not backend.jax_native]


def _resolve_custom(env_id: str, backend: str) -> str:
    custom = next(candidate for candidate in backends() if candidate.custom_ids)
    if backend not in (AUTO, custom.name):
        raise CanterError(
            f"custom env '{env_id}' needs the {custom.name} backend; {_python_backend(f'drop --backend {backend}')}"
        )
    custom.load_custom(env_id)
    return custom.name


def _unknown(env_id: str, candidates: list[str], where: str) -> CanterError:
    close = difflib.get_close_matches(env_id, candidates, n=3, cutoff=0.6)
    hint = f"; did you mean {', '.join(close)}?" if close else "; for a custom env pass module:EnvId"
    return CanterError(f"unknown env id '{env_id}' for {where}{hint}")


def _or(items: list[str]) -> str:
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} or {items[-1]}"


def _not_installed(env_id: str, chosen: Backend) -> CanterError:
    """Its install command, and the installed backends that run env_id too (none runs a backend's own envs)."""
    others = [
        other.name
        for other in backends()
        if other is not chosen and not chosen.own_observations and other.available() and env_id in other.supported_ids()
    ]
    ways = [chosen.install] if chosen.install else []
    if others:
        ways.append(_python_backend(f"use --backend {_or(others)}"))
    how = ", or ".join(ways) or "it cannot run here"
    return CanterError(f"{chosen.label} is not installed here; {how}")


def _python_backend(advice: str) -> str:
    """Advice that names --backend, followed by its Python names: these errors reach canter.train (a config's
    env.backend) and canter.evaluate (backend=) too, whose callers have no --backend to pass."""
    return f"{advice} (env.backend from Python; backend= for evaluate)"
