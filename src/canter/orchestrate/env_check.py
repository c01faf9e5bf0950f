"""Checks of an env that tune and bench make before any job starts: a job's child process would otherwise find the
same fault in every trial or cell, each a failure that no re-run fixes."""

from __future__ import annotations

import contextlib

from canter.errors import CanterError, DiscreteActionsError


def check_continuous(env_id: str, backend: str = "auto") -> None:
    """Refuse an env with discrete actions (or an observation canter cannot flatten), as the trainer would refuse it
    in every job; and one whose episodes have no step limit, which every job's evaluations would play forever. Only a
    backend that builds single envs is asked about actions: making one of its envs is cheap, and the other backends
    list continuous-control ids only. An env that fails to build for another reason is left to the job, whose log
    holds the error in full."""
    from canter.envs.registry import get_backend, resolve_backend
    from canter.training.evaluation import check_episodes_end

    chosen = get_backend(resolve_backend(env_id, backend))
    check_episodes_end(env_id, chosen.name)  # every trial or cell ends with evaluations
    if not chosen.single_envs:
        return
    try:
        env = chosen.make_single(env_id)
    except DiscreteActionsError as exc:  # worded as the trainer words it (`canter.training.loop`)
        raise CanterError(
            f"canter's algorithms are continuous-only, but {env_id} has discrete actions ({exc.space}); choose an "
            f"env with Box actions"
        ) from None
    except CanterError:
        raise
    except Exception:  # not this check's to report: the job reports it, with its traceback in its log
        return
    with contextlib.suppress(Exception):
        env.close()
