"""The numerical pieces of TRPO as pure functions over flat parameter vectors: conjugate gradient, the
Fisher-vector product by autodiff of the mean KL, and the backtracking line search. All are jittable
(`lax.while_loop`), so a whole TRPO iteration compiles into one program."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

Vector = jnp.ndarray


class CGResult(NamedTuple):
    x: Vector
    iterations: jnp.ndarray
    residual_norm: jnp.ndarray  # ||b - A x||, from the recurrence


def conjugate_gradient(matvec: Callable[[Vector], Vector], b: Vector, max_iters: int, tol: float = 1e-10) -> CGResult:
    """Solve A x = b for symmetric positive definite A given only `matvec(v) = A v`, starting from x = 0. Stops
    after `max_iters` iterations or once the squared residual drops below `tol`."""

    def cond(state):
        i, _, _, _, r_dot_r = state
        return (i < max_iters) & (r_dot_r > tol)

    def body(state):
        i, x, r, p, r_dot_r = state
        ap = matvec(p)
        step = r_dot_r / jnp.vdot(p, ap)
        x = x + step * p
        r = r - step * ap
        new_r_dot_r = jnp.vdot(r, r)
        p = r + (new_r_dot_r / r_dot_r) * p
        return i + 1, x, r, p, new_r_dot_r

    init = (jnp.zeros((), jnp.int32), jnp.zeros_like(b), b, b, jnp.vdot(b, b))
    i, x, _, _, r_dot_r = jax.lax.while_loop(cond, body, init)
    return CGResult(x, i, jnp.sqrt(r_dot_r))


def fisher_vector_product(
    mean_kl: Callable[[Vector], jnp.ndarray], theta: Vector, damping: float
) -> Callable[[Vector], Vector]:
    """`v -> (H + damping I) v`, H the Hessian of `mean_kl` at `theta`. With `mean_kl(θ) = E[KL(π_θold || π_θ)]`
    evaluated at θ = θold, H is the Fisher information matrix. The product is forward-over-reverse autodiff (a jvp of
    the gradient), never forming H."""
    grad_kl = jax.grad(mean_kl)

    def fvp(v: Vector) -> Vector:
        return jax.jvp(grad_kl, (theta,), (v,))[1] + damping * v

    return fvp


class LineSearchResult(NamedTuple):
    theta: Vector
    accepted: jnp.ndarray  # bool: a step was taken
    steps: jnp.ndarray  # candidates tried (1 = the full step)
    fraction: jnp.ndarray  # fraction of the full step taken (0 if rejected)
    improvement: jnp.ndarray  # surrogate gain of the accepted step (0 if rejected)
    kl: jnp.ndarray  # mean KL of the accepted step (0 if rejected)


def backtracking_line_search(
    surrogate: Callable[[Vector], jnp.ndarray],
    mean_kl: Callable[[Vector], jnp.ndarray],
    theta: Vector,
    full_step: Vector,
    max_kl: float,
    shrink: float,
    max_iters: int,
) -> LineSearchResult:
    """Try θ + shrink^j * full_step for j = 0, 1, ... and take the first candidate whose surrogate improves on
    `surrogate(theta)` and whose KL is at most `max_kl`. If none of `max_iters` candidates qualifies, keep θ."""
    base = surrogate(theta)

    def cond(state):
        j, accepted, *_ = state
        return (j < max_iters) & ~accepted

    def body(state):
        j, _, _, _, _ = state
        fraction = jnp.asarray(shrink, theta.dtype) ** j
        candidate = theta + fraction * full_step
        gain = surrogate(candidate) - base
        kl = mean_kl(candidate)
        ok = (gain > 0) & (kl <= max_kl) & jnp.isfinite(gain) & jnp.isfinite(kl)
        return j + 1, ok, fraction, gain, kl

    zero = jnp.zeros((), theta.dtype)
    j, accepted, fraction, gain, kl = jax.lax.while_loop(
        cond, body, (jnp.zeros((), jnp.int32), jnp.asarray(False), zero, zero, zero)
    )
    fraction = jnp.where(accepted, fraction, zero)
    return LineSearchResult(
        jnp.where(accepted, theta + fraction * full_step, theta),
        accepted,
        j,
        fraction,
        jnp.where(accepted, gain, zero),
        jnp.where(accepted, kl, zero),
    )
