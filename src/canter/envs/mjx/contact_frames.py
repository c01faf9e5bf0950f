"""C MuJoCo's contact frame for a capsule on a plane, used while MJX steps a ported task.

A frictional contact's force depends on the direction of its first tangent, because MuJoCo's default friction cone
is a pyramid whose edges follow the tangents. For a capsule on a plane, C MuJoCo takes that tangent from the
capsule's axis projected on the plane whenever the projection is defined (`mjc_PlaneCapsule`, then
`mju_makeFrame`). MJX 3.6.0 does so only when the projection is at least 0.5 long, and otherwise uses a fixed world
axis. Ant's lower legs stand steeper than 60 degrees, so on their first foot contact MJX's friction pyramid turned
against C MuJoCo's, and Ant's physics parted from Gymnasium's by several percent from there on. With this
collider, mjx Ant matches C MuJoCo to float64 round-off on every physics step (benchmarks/mjx_equivalence).

The replacement is scoped: it holds while a ported task's step is traced, and MJX's own collider is back after it,
so Brax's envs (the brax backend, and Brax's own trainer in the side-by-side benchmark) keep MJX's physics."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import jax
import jax.numpy as jnp

from canter.envs.mjx.library import import_mjx


def plane_capsule_frame(normal: jax.Array, axis: jax.Array) -> jax.Array:
    """The contact frame (rows: normal, first and second tangent) of a capsule with axis `axis` on a plane with unit
    normal `normal`, as C MuJoCo builds it: the tangent is the axis projected on the plane, or the world x axis where
    that projection vanishes (a capsule standing upright), as `mju_normalize3` does."""
    projected = axis - normal * jnp.dot(normal, axis)
    length = jnp.linalg.norm(projected)
    undefined = length < 1e-15  # mjMINVAL
    world_x = jnp.array([1.0, 0.0, 0.0], normal.dtype)
    tangent = jnp.where(undefined, world_x, projected / jnp.where(undefined, 1, length))
    return jnp.stack([normal, tangent, jnp.cross(normal, tangent)])


def _plane_capsule_collider() -> Any:
    from mujoco.mjx._src import collision_primitive

    @collision_primitive.collider(ncon=2)  # type: ignore[untyped-decorator]
    def plane_capsule(plane: Any, capsule: Any) -> tuple[jax.Array, jax.Array, jax.Array]:
        normal, axis = plane.mat[:, 2], capsule.mat[:, 2]
        frame = plane_capsule_frame(normal, axis)[None]
        segment = axis * capsule.size[1]
        ends = [
            collision_primitive._plane_sphere(normal, plane.pos, capsule.pos + offset, capsule.size[0])
            for offset in (segment, -segment)
        ]
        dist = jnp.stack([d for d, _ in ends])
        pos = jnp.stack([p for _, p in ends])
        return dist, pos, jnp.concatenate([frame, frame])

    return plane_capsule


@contextlib.contextmanager
def c_mujoco_contact_frames() -> Iterator[None]:
    """Within this block, MJX collides capsules with planes as C MuJoCo does (see the module's docstring)."""
    import_mjx()
    from mujoco.mjx._src import collision_driver
    from mujoco.mjx._src.types import GeomType

    key = (GeomType.PLANE, GeomType.CAPSULE)
    table = collision_driver._COLLISION_FUNC
    original = table[key]
    table[key] = _plane_capsule_collider()
    try:
        yield
    finally:
        table[key] = original
