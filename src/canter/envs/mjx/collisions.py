"""Three of MJX's collision functions, written as C MuJoCo computes them, used while MJX steps a ported task.

- **Capsule on a plane: the contact frame.** A frictional contact's force depends on the direction of its first
  tangent, because MuJoCo's default friction cone is a pyramid whose edges follow the tangents. C MuJoCo takes that
  tangent from the capsule's axis projected on the plane whenever the projection is defined (`mjc_PlaneCapsule`,
  then `mju_makeFrame`). MJX 3.6.0 does so only when the projection is at least 0.5 long, and otherwise uses a fixed
  world axis. Ant's lower legs stand steeper than 60 degrees, so on their first foot contact MJX's friction pyramid
  turned against C MuJoCo's, and Ant's accelerations parted from Gymnasium's by several percent.
- **Sphere against a capsule, and capsule against capsule: the closest points.** C MuJoCo solves for them exactly
  (`mjc_SphereCapsule`, `mjraw_CapsuleCapsule`). MJX adds 1e-6 to the denominators, which moves the points, and the
  contact normal, by about 1e-6 over the squared segment length: 3e-5 on the normal of a Humanoid foot touching its
  other leg.

With all three, every ported task matches C MuJoCo to round-off on every step in float64 (benchmarks/mjx_equivalence).
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


def capsule_closest_point(center: jax.Array, axis: jax.Array, point: jax.Array) -> jax.Array:
    """The point of a capsule's segment (its center, and its axis scaled by the half-length) closest to `point`, as
    C MuJoCo's `mjc_SphereCapsule` finds it."""
    along = jnp.clip(jnp.dot(axis, point - center) / jnp.dot(axis, axis), -1, 1)
    return center + along * axis


def capsules_closest_points(
    center1: jax.Array, axis1: jax.Array, center2: jax.Array, axis2: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """The closest points of two capsules' segments (centers, and axes scaled by the half-lengths), as C MuJoCo's
    `mjraw_CapsuleCapsule` finds them: the lines' closest points, clipped to the first segment and then to the
    second. For exactly parallel axes C MuJoCo makes up to two contacts; MJX has one slot per pair, which gets C's
    first, from the first capsule's end at +axis."""
    dif = center1 - center2
    ma, mb, mc = jnp.dot(axis1, axis1), -jnp.dot(axis1, axis2), jnp.dot(axis2, axis2)
    u, v = -jnp.dot(axis1, dif), jnp.dot(axis2, dif)
    det = ma * mc - mb * mb
    parallel = jnp.abs(det) < 1e-15  # mjMINVAL
    det = jnp.where(parallel, 1, det)
    x1, x2 = (mc * u - mb * v) / det, (ma * v - mb * u) / det
    x2 = jnp.where(x1 > 1, (v - mb) / mc, jnp.where(x1 < -1, (v + mb) / mc, x2))
    x1 = jnp.clip(x1, -1, 1)
    x1 = jnp.where(x2 > 1, jnp.clip((u - mb) / ma, -1, 1), jnp.where(x2 < -1, jnp.clip((u + mb) / ma, -1, 1), x1))
    x2 = jnp.clip(x2, -1, 1)
    x1 = jnp.where(parallel, 1, x1)
    x2 = jnp.where(parallel, jnp.clip((v - mb) / mc, -1, 1), x2)
    return center1 + x1 * axis1, center2 + x2 * axis2


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
        closest = capsule_closest_point(capsule.pos, capsule.mat[:, 2] * capsule.size[1], sphere.pos)
        dist, pos, normal = collision_primitive._sphere_sphere(sphere.pos, sphere.size[0], closest, capsule.size[0])
        return dist, pos, math.make_frame(normal)

    @collision_primitive.collider(ncon=1)  # type: ignore[untyped-decorator]
    def capsule_capsule(first: Any, second: Any) -> tuple[jax.Array, jax.Array, jax.Array]:
        point1, point2 = capsules_closest_points(
            first.pos, first.mat[:, 2] * first.size[1], second.pos, second.mat[:, 2] * second.size[1]
        )
        dist, pos, normal = collision_primitive._sphere_sphere(point1, first.size[0], point2, second.size[0])
        return dist, pos, math.make_frame(normal)

    return {
        (GeomType.PLANE, GeomType.CAPSULE): plane_capsule,
        (GeomType.SPHERE, GeomType.CAPSULE): sphere_capsule,
        (GeomType.CAPSULE, GeomType.CAPSULE): capsule_capsule,
    }


@contextlib.contextmanager
def c_mujoco_collisions() -> Iterator[None]:
    """Within this block, MJX collides capsules with planes, spheres and capsules as C MuJoCo does (see the module's
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
