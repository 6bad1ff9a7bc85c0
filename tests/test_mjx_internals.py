"""The MJX internals jaxnat.mjx_pixel relies on (jaxnat/mjx_pixel/mjx_internals.py) are there.

A mujoco-mjx upgrade that moves one fails here, naming it, rather than in a robot's trace.
"""

import importlib

import numpy as np
import pytest

pytest.importorskip("mujoco.mjx", reason="mujoco-mjx is not installed")

import mujoco  # noqa: E402
from mujoco import mjx  # noqa: E402

# A plane and a capsule resting on it: one contact, so constraints exist.
_XML = """
<mujoco>
  <worldbody>
    <geom type="plane" size="5 5 0.1"/>
    <body pos="0 0 0.05">
      <freejoint/>
      <geom type="capsule" size="0.05" fromto="-0.2 0 0 0.2 0 0"/>
    </body>
  </worldbody>
</mujoco>
"""


def _internals():
    try:
        from jaxnat.mjx_pixel import mjx_internals
    except ImportError as err:  # the module's own one-line message names what moved
        pytest.fail(str(err), pytrace=False)
    return mjx_internals


def test_every_private_name_used_exists():
    internals = _internals()
    for module_name, attribute in internals.NAMES:
        module = importlib.import_module(module_name)
        assert hasattr(module, attribute), (
            f"mujoco-mjx {internals.installed_version()} has no {module_name}.{attribute} "
            f"(jaxnat.mjx_pixel.mjx_internals was written for {internals.WRITTEN_FOR})")
    assert internals.missing() == []


def test_impl_fields_on_a_real_data():
    """`mjx.Data._impl` of MJX's JAX implementation holds the fields the robots read."""
    internals = _internals()
    model = mujoco.MjModel.from_xml_string(_XML)
    d = mjx.forward(mjx.put_model(model), mjx.make_data(model))
    for name in internals.IMPL_FIELDS:
        assert hasattr(d._impl, name), (
            f"mjx.Data._impl has no {name} in mujoco-mjx {internals.installed_version()} "
            f"(written for {internals.WRITTEN_FOR})")
    contact = internals.contact(d)
    assert contact.frame.shape[-2:] == (3, 3) and contact.geom.shape[-1] == 2
    moved = internals.replace_contact_frame(d, contact.frame + 1.0)
    np.testing.assert_array_equal(np.asarray(internals.contact(moved).frame),
                                  np.asarray(contact.frame) + 1.0)
    assert internals.constraint_jacobian(d).shape[-1] == model.nv
    assert internals.cfrc_ext(d).shape == (model.nbody, 6)


def test_a_moved_name_gives_one_clear_line(monkeypatch):
    internals = _internals()
    forward = importlib.import_module("mujoco.mjx._src.forward")
    monkeypatch.delattr(forward, "_RK4_A")
    with pytest.raises(ImportError) as err:
        internals.check()
    message = str(err.value)
    assert "\n" not in message
    assert "mujoco.mjx._src.forward._RK4_A" in message and internals.WRITTEN_FOR in message
