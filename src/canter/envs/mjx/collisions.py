"""Two of MJX's collision functions, written as C MuJoCo computes them, used while MJX steps a ported task.

- **Capsule on a plane: the contact frame.** A frictional contact's force depends on the direction of its first
  tangent, because MuJoCo's default friction cone is a pyramid whose edges follow the tangents. C MuJoCo takes that
  tangent from the capsule's axis projected on the plane whenever the projection is defined (`mjc_PlaneCapsule`,
  then `mju_makeFrame`). MJX 3.6.0 does so only when the projection is at least 0.5 long, and otherwise uses a fixed
  world axis. Ant's lower legs stand steeper than 60 degrees, so on their first foot contact MJX's friction pyramid
  turned against C MuJoCo's, and Ant's accelerations parted from Gymnasium's by several percent.
- **Sphere against a capsule: the closest point.** C MuJoCo projects the sphere's center on the capsule's unit
  axis and clamps it to the half-length (`mjc_SphereCapsule`). MJX divides by the squared segment length plus 1e-6,
  which moves the point, and the contact normal, by about 1e-6 over the squared length: 3e-5 on the normal of a
  Humanoid foot touching its other leg.

With both, every ported task matches C MuJoCo to round-off on every step in float64 (benchmarks/mjx_equivalence).
The replacement is scoped: it holds while a ported task's step is traced, and MJX's own functions are back after
it, so Brax's envs (the brax backend, and Brax's own trainer in the side-by-side benchmark) keep MJX's physics."""

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


def capsule_closest_point(center: jax.Array, axis: jax.Array, half_length: jax.Array, point: jax.Array) -> jax.Array:
    """The point of a capsule's segment (its center, unit axis and half-length) closest to `point`."""
    along = jnp.clip(jnp.dot(point - center, axis), -half_length, half_length)
    return center + along * axis


def _colliders() -> dict[Any, Any]:
    from mujoco.mjx._src import collision_primitive, math
    from mujoco.mjx._src.types import GeomType

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

    @collision_primitive.collider(ncon=1)  # type: ignore[untyped-decorator]
    def sphere_capsule(sphere: Any, capsule: Any) -> tuple[jax.Array, jax.Array, jax.Array]:
        closest = capsule_closest_point(capsule.pos, capsule.mat[:, 2], capsule.size[1], sphere.pos)
        dist, pos, normal = collision_primitive._sphere_sphere(sphere.pos, sphere.size[0], closest, capsule.size[0])
        return dist, pos, math.make_frame(normal)

    return {(GeomType.PLANE, GeomType.CAPSULE): plane_capsule, (GeomType.SPHERE, GeomType.CAPSULE): sphere_capsule}


@contextlib.contextmanager
def c_mujoco_collisions() -> Iterator[None]:
    """Within this block, MJX collides capsules with planes and spheres as C MuJoCo does (see the module's
    docstring). JAX reuses a jitted function's trace, so the block must hold while the step is traced."""
    import_mjx()
    from mujoco.mjx._src import collision_driver

    table = collision_driver._COLLISION_FUNC
    replacements = _colliders()
    originals = {key: table[key] for key in replacements}
    table.update(replacements)
    try:
        yield
    finally:
        table.update(originals)
