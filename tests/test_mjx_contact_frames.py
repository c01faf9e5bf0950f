"""The capsule-on-plane contact frame that the mjx backend gives MJX, checked against C MuJoCo's.

C MuJoCo takes a capsule contact's first tangent from the capsule's axis projected on the plane; MJX 3.6.0 falls
back to a world axis when the capsule stands steeper than 60 degrees, which turned Ant's friction pyramid
(canter.envs.mjx.contact_frames). A capsule at 75 degrees, touching a tilted plane within its margin, tells the two
apart."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from canter.core.runtime import setup_jax
from canter.envs.mjx.contact_frames import c_mujoco_contact_frames, plane_capsule_frame

# A plane tilted about x, and a free capsule 75 degrees from horizontal whose lower end touches it.
STEEP_CAPSULE = """
<mujoco>
  <option timestep="0.01"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1" euler="10 0 0" margin="0.01"/>
    <body pos="0.1 0 0.27" euler="25 15 40">
      <freejoint/>
      <geom type="capsule" size="0.05 0.2" margin="0.01" friction="1 0.5 0.5"/>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.fixture(autouse=True)
def _float64_jax():
    setup_jax("gymnasium")  # float64, so that the only difference left to C MuJoCo is round-off, in any test order


def _touching_capsule():
    model = mujoco.MjModel.from_xml_string(STEEP_CAPSULE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    # Lower the capsule until C MuJoCo reports exactly one contact, its lower end inside the margin.
    while data.ncon == 0:
        data.qpos[2] -= 0.002
        mujoco.mj_forward(model, data)
    assert data.ncon == 1
    return model, data


def _axes(model, data):
    plane, capsule = data.geom_xmat.reshape(-1, 3, 3)
    return plane[:, 2], capsule[:, 2]


def test_the_frame_is_c_mujocos_for_a_steep_capsule():
    model, data = _touching_capsule()
    normal, axis = _axes(model, data)
    projected = axis - normal * (normal @ axis)
    assert np.linalg.norm(projected) < 0.5  # steep enough that MJX's own collider would use a world axis
    expected = data.contact.frame[0].reshape(3, 3)
    frame = np.asarray(plane_capsule_frame(jnp.asarray(normal), jnp.asarray(axis)))
    np.testing.assert_allclose(frame, expected, atol=1e-12)
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-12)  # orthonormal, right-handed by cross
    np.testing.assert_allclose(np.cross(frame[0], frame[1]), frame[2], atol=1e-12)


def test_an_upright_capsule_takes_the_world_x_axis_as_c_mujoco_does():
    normal = jnp.array([0.0, 0.0, 1.0])
    frame = np.asarray(plane_capsule_frame(normal, normal))
    np.testing.assert_array_equal(frame, [[0, 0, 1], [1, 0, 0], [0, 1, 0]])


@pytest.mark.slow
def test_mjx_inside_the_block_collides_and_accelerates_as_c_mujoco():
    from canter.envs.mjx.library import import_mjx

    mjx = import_mjx()
    model, data = _touching_capsule()
    mjx_model, state = mjx.put_model(model), mjx.put_data(model, data)
    # Separate functions: jit would reuse one function's trace, and the collider is chosen while tracing.
    with c_mujoco_contact_frames():
        matched = jax.jit(lambda m, d: mjx.forward(m, d))(mjx_model, state)
    own = jax.jit(lambda m, d: mjx.forward(m, d))(mjx_model, state)
    touching = np.asarray(matched._impl.contact.dist) < 0.02
    assert touching.sum() == 1
    np.testing.assert_allclose(
        np.asarray(matched._impl.contact.frame)[touching][0], data.contact.frame[0].reshape(3, 3), atol=1e-12
    )
    np.testing.assert_allclose(np.asarray(matched.qacc), data.qacc, rtol=1e-9, atol=1e-9)
    # After the block MJX has its own collider back: its tangent differs, and so does the friction force.
    assert np.abs(np.asarray(own._impl.contact.frame)[touching][0][1] - data.contact.frame[0][3:6]).max() > 0.1
    assert np.abs(np.asarray(own.qacc) - data.qacc).max() > 1e-3
