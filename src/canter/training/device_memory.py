"""Whether a compiled training program fits the accelerator's memory, and a one-line error when it does not.

The largest arrays of a JAX-native run grow with env.num_envs (the envs' physics state, the rollout), so that is the
setting the error names. Where the device reports its memory (GPUs do; the CPU does not), the check runs after the
compile and before any training; an allocation that still fails later gets the same message. On the CPU, what the
program needs beyond its arguments (the train state and the envs, in memory already by then) is compared with the
machine's available memory: its rollout, batches and activations grow with env.num_envs, the rollout and batch
sizes and the hidden layer sizes."""

from __future__ import annotations

from typing import Any

from canter.errors import DoesNotFitError
from canter.training import host_memory
from canter.training.host_memory import size_text


def required_bytes(compiled: Any) -> int | None:
    """Arguments, outputs and scratch of a compiled program, or None where XLA does not say."""
    try:
        analysis = compiled.memory_analysis()
    except Exception:  # not every backend implements it
        return None
    if analysis is None:
        return None
    sizes = ("argument_size_in_bytes", "output_size_in_bytes", "temp_size_in_bytes")
    aliased = int(getattr(analysis, "alias_size_in_bytes", 0) or 0)
    return sum(int(getattr(analysis, name, 0) or 0) for name in sizes) - aliased


def free_bytes() -> int | None:
    """Free memory of the default device, or None where it reports none (the CPU)."""
    import jax

    stats = jax.devices()[0].memory_stats()
    if not stats or "bytes_limit" not in stats:
        return None
    return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))


def too_many_envs(num_envs: int, need: int | None = None, free: int | None = None) -> DoesNotFitError:
    amounts = f" (needs about {size_text(need)}, {size_text(free)} free)" if need and free else ""
    return DoesNotFitError(
        f"env.num_envs={num_envs} does not fit in the device's memory{amounts}",
        f"lower it, e.g. --set env.num_envs={max(num_envs // 2, 1)}",
    )


def too_large_for_the_host(more: int, available: int, sizes: str) -> DoesNotFitError:
    """`sizes`: the keys that size one call of the program, with their values ("env.num_envs=16, ppo.n_steps=64")."""
    return DoesNotFitError(
        f"the training program needs about {size_text(more)} of memory beyond its train state and envs (its "
        f"rollout, batches and activations), but {size_text(available)} are available",
        f"lower what sizes one call ({sizes}), the batch sizes, or the hidden layer sizes",
    )


def check_fits(compiled: Any, num_envs: int, sizes: str | None = None) -> None:
    """Refuse a compiled program the device (or on the CPU, the host) cannot hold. `sizes`: the keys that size one
    call, as the host refusal names them (default env.num_envs alone)."""
    need, free = required_bytes(compiled), free_bytes()
    if need is None:
        return
    if free is not None:
        if need > free:
            raise too_many_envs(num_envs, need, free)
        return
    import jax

    if jax.devices()[0].platform != "cpu":
        return
    available = host_memory.available_bytes()
    more = need - int(getattr(compiled.memory_analysis(), "argument_size_in_bytes", 0) or 0)
    if available is not None and more > host_memory.HEADROOM * available:
        raise too_large_for_the_host(more, available, sizes or f"env.num_envs={num_envs:,}")


def is_out_of_memory(exc: BaseException) -> bool:
    text = str(exc)
    return "RESOURCE_EXHAUSTED" in text or "Out of memory" in text or "out of memory" in text
