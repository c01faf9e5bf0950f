"""The two collision functions that the mjx backend gives MJX, checked against C MuJoCo's (canter.envs.mjx.collisions).

- Capsule on a plane: C MuJoCo takes the contact's first tangent from the capsule's axis projected on the plane; MJX
  3.6.0 falls back to a world axis when the capsule stands steeper than 60 degrees, which turned Ant's friction
  pyramid. A capsule at 75 degrees, touching a tilted plane within its margin, tells the two apart.
- Sphere against a capsule, and capsule against capsule: C MuJoCo finds the closest points exactly; MJX adds 1e-6 to
  the denominators. Short capsules (squared length 0.01) make that 1e-4 of a point's position."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from canter.core.runtime import setup_jax
from canter.envs.mjx.collisions import (
    c_mujoco_collisions,
    capsule_closest_point,
    capsules_closest_points,
    plane_capsule_frame,
)

# A plane tilted about x and a free capsule 75 degrees from horizontal, lowered until its end touches the plane; high
# above them, a free sphere pressed into a short free capsule, off its axis, and two short capsules crossing.
SCENE = """
<mujoco>
  <option timestep="0.01"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1" euler="10 0 0" margin="0.01"/>
    <body name="steep" pos="0.1 0 0.27" euler="25 15 40">
      <freejoint/>
      <geom type="capsule" size="0.05 0.2" margin="0.01" friction="1 0.5 0.5"/>
    </body>
    <body name="short" pos="2 0 2" euler="30 20 0">
      <freejoint/>
      <geom type="capsule" size="0.05 0.05"/>
    </body>
    <body name="ball" pos="2.07 0.03 2.04">
      <freejoint/>
      <geom type="sphere" size="0.05"/>
    </body>
    <body name="rod1" pos="-2 0 2" euler="0 80 10">
      <freejoint/>
      <geom type="capsule" size="0.04 0.06"/>
    </body>
    <body name="rod2" pos="-2.03 0.02 2.06" euler="50 0 30">
      <freejoint/>
      <geom type="capsule" size="0.04 0.06"/>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.fixture(autouse=True)
def _float64_jax():
    setup_jax("gymnasium")  # float64, so that the only difference left to C MuJoCo is round-off, in any test order


def _scene():
    model = mujoco.MjModel.from_xml_string(SCENE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert data.ncon == 2  # the sphere in the short capsule, and the crossing capsules
    while data.ncon == 2:  # lower the steep capsule until its lower end is inside the plane's margin
        data.qpos[2] -= 0.002
        mujoco.mj_forward(model, data)
    assert data.ncon == 3
    return model, data


def _contact(model, data, geom_type):
    """C MuJoCo's contact that involves a geom of this type, and that geom."""
    for contact in data.contact[: data.ncon]:
        for geom in contact.geom:
            if model.geom_type[geom] == geom_type:
                return contact, geom
    raise AssertionError(geom_type)


def test_the_plane_frame_is_c_mujocos_for_a_steep_capsule():
    model, data = _scene()
    contact, _ = _contact(model, data, mujoco.mjtGeom.mjGEOM_PLANE)
    plane, capsule = contact.geom
    normal = data.geom_xmat[plane].reshape(3, 3)[:, 2]
    axis = data.geom_xmat[capsule].reshape(3, 3)[:, 2]
    assert np.linalg.norm(axis - normal * (normal @ axis)) < 0.5  # steep: MJX's own collider would use a world axis
    frame = np.asarray(plane_capsule_frame(jnp.asarray(normal), jnp.asarray(axis)))
    np.testing.assert_allclose(frame, contact.frame.reshape(3, 3), atol=1e-12)
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.cross(frame[0], frame[1]), frame[2], atol=1e-12)


def test_an_upright_capsule_takes_the_world_x_axis_as_c_mujoco_does():
    normal = jnp.array([0.0, 0.0, 1.0])
    frame = np.asarray(plane_capsule_frame(normal, normal))
    np.testing.assert_array_equal(frame, [[0, 0, 1], [1, 0, 0], [0, 1, 0]])


def test_the_closest_point_of_a_capsule_by_hand_and_by_search():
    center, unit = jnp.array([1.0, 2.0, 3.0]), jnp.array([0.0, 0.6, 0.8])
    axis = 0.5 * unit  # scaled by the half-length
    # Beside the segment: the foot of the perpendicular, 0.2 along the axis.
    point = center + 0.2 * unit + jnp.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(capsule_closest_point(center, axis, point), center + 0.2 * unit, atol=1e-12)
    # Beyond an end: the end.
    np.testing.assert_allclose(capsule_closest_point(center, axis, center + 3 * unit), center + axis)
    # Anywhere: the closest of 200,001 points along the segment.
    point = np.array([1.3, 2.9, 2.1])
    samples = np.asarray(center) + np.linspace(-1, 1, 200_001)[:, None] * np.asarray(axis)
    nearest = samples[np.argmin(np.linalg.norm(samples - point, axis=1))]
    np.testing.assert_allclose(capsule_closest_point(center, axis, jnp.asarray(point)), nearest, atol=1e-5)


def test_the_closest_points_of_two_capsules_by_hand_and_by_search():
    # Crossing at right angles, one above the other: the crossing points.
    first, second = capsules_closest_points(
        jnp.zeros(3), jnp.array([1.0, 0.0, 0.0]), jnp.array([0.2, 0.3, 1.0]), jnp.array([0.0, 2.0, 0.0])
    )
    np.testing.assert_allclose(first, [0.2, 0, 0], atol=1e-12)
    np.testing.assert_allclose(second, [0.2, 0, 1], atol=1e-12)
    # Parallel and side by side: C MuJoCo's first contact, from the first capsule's +axis end.
    first, second = capsules_closest_points(
        jnp.zeros(3), jnp.array([0.0, 0.0, 0.5]), jnp.array([0.1, 0.0, 0.2]), jnp.array([0.0, 0.0, 0.5])
    )
    np.testing.assert_allclose(first, [0, 0, 0.5], atol=1e-12)
    np.testing.assert_allclose(second, [0.1, 0, 0.5], atol=1e-12)
    # Skewed, with the closest points at an end of each or inside: the closest pair of a 2,001 x 2,001 grid.
    rng = np.random.default_rng(0)
    grid = np.linspace(-1, 1, 2001)
    for _ in range(5):
        c1, a1, c2, a2 = rng.normal(size=(4, 3)) * [[0.3], [0.5], [0.3], [0.5]]
        p1 = c1 + grid[:, None] * a1
        p2 = c2 + grid[:, None] * a2
        distances = np.linalg.norm(p1[:, None, :] - p2[None, :, :], axis=2)
        i, j = np.unravel_index(np.argmin(distances), distances.shape)
        first, second = capsules_closest_points(*(jnp.asarray(x) for x in (c1, a1, c2, a2)))
        assert np.linalg.norm(np.asarray(first) - np.asarray(second)) <= distances[i, j] + 1e-12
        np.testing.assert_allclose(np.linalg.norm(np.asarray(first) - np.asarray(second)), distances[i, j], atol=1e-5)


@pytest.mark.slow
def test_mjx_inside_the_block_collides_and_accelerates_as_c_mujoco():
    from canter.envs.mjx.library import import_mjx

    mjx = import_mjx()
    model, data = _scene()
    mjx_model, state = mjx.put_model(model), mjx.put_data(model, data)
    # Separate functions: jit would reuse one function's trace, and the colliders are chosen while tracing.
    with c_mujoco_collisions():
        matched = jax.jit(lambda m, d: mjx.forward(m, d))(mjx_model, state)
    own = jax.jit(lambda m, d: mjx.forward(m, d))(mjx_model, state)

    def frames(result):
        contacts = result._impl.contact
        touching = np.asarray(contacts.dist) < np.asarray(contacts.includemargin)
        return {
            tuple(int(i) for i in g): f
            for g, f in zip(np.asarray(contacts.geom)[touching], np.asarray(contacts.frame)[touching])
        }

    expected = {tuple(int(g) for g in c.geom): c.frame.reshape(3, 3) for c in data.contact[: data.ncon]}
    assert frames(matched).keys() == expected.keys()
    for pair, frame in frames(matched).items():
        np.testing.assert_allclose(frame, expected[pair], atol=1e-12, err_msg=str(pair))
    np.testing.assert_allclose(np.asarray(matched.qacc), data.qacc, rtol=1e-9, atol=1e-9)
    # After the block MJX has its own colliders back: both contacts' frames differ from C MuJoCo's, and so do the
    # accelerations.
    for pair, frame in frames(own).items():
        assert np.abs(frame - expected[pair]).max() > 1e-6, pair
    assert np.abs(np.asarray(own.qacc) - data.qacc).max() > 1e-3
