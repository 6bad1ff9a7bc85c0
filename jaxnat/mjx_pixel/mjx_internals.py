"""Every use of MJX's private internals, in one place, checked when it is imported.

The robots (`base.py`, `ant.py`) need three kinds of thing MJX keeps private:

- the RK4 tableau and state advance of `mujoco.mjx._src.forward` and the per-joint scan of
  `mujoco.mjx._src.scan`, to run MJX's own Runge-Kutta stages as one `lax.scan`
  (`base._rk4_step`);
- `mjx.Data._impl`'s `contact` (the contact frames are rebuilt as MuJoCo C makes them,
  `base._forward_with_c_capsule_frames`) and `efc_J` (whether there are constraints);
- `mjx.Data._impl.cfrc_ext` (Ant's contact forces), read and set alone;
- for `impl="warp"` (`warp_physics.py`): which Warp data fields have a world axis
  (`mujoco.mjx.warp.types._BATCH_DIM`), MJX's name for a pytree path of a `Data`
  (`mujoco.mjx._src.types.tree_path_to_attr_str`) and the Warp model's overflow warnings
  (`Model.opt._impl.warn_overflow`). Warp is optional, so its names are read when called.

A mujoco-mjx release may move or rename any of them. Importing this module checks every name
below and, if one is missing, raises a one-line ImportError that names the release range this
code was written for (`WRITTEN_FOR`), instead of an AttributeError deep in a trace.
tests/test_mjx_internals.py checks the same names, and the `_impl` fields on a real `mjx.Data`.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata

from jaxnat.mjx_pixel.models import import_mjx

# The mujoco-mjx releases this module was written for (tested with 3.17.0), as a pip spec.
WRITTEN_FOR = "mujoco-mjx==3.17.*"

# (module, attribute) pairs read from MJX's private modules.
NAMES = (
    ("mujoco.mjx._src.forward", "_RK4_A"),
    ("mujoco.mjx._src.forward", "_RK4_B"),
    ("mujoco.mjx._src.forward", "_integrate_pos"),
    ("mujoco.mjx._src.forward", "_advance"),
    ("mujoco.mjx._src.scan", "flat"),
    ("mujoco.mjx._src.types", "tree_path_to_attr_str"),
)
# Fields of `mjx.Data._impl` (MJX's JAX implementation, `mujoco.mjx._src.types.DataJAX`).
IMPL_CLASS = ("mujoco.mjx._src.types", "DataJAX")
IMPL_FIELDS = ("contact", "efc_J", "cfrc_ext")


def installed_version() -> str:
    """The installed mujoco-mjx's version, or "unknown"."""
    try:
        return importlib.metadata.version("mujoco-mjx")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def missing() -> list[str]:
    """The internals above that the installed MJX lacks, as dotted names (empty: all there)."""
    import_mjx()  # first through the import that keeps MJX's Warp notices quiet
    gone = []
    for module_name, attribute in (*NAMES, IMPL_CLASS):
        try:
            module = importlib.import_module(module_name)
        except ImportError:
            gone.append(module_name)
            continue
        if not hasattr(module, attribute):
            gone.append(f"{module_name}.{attribute}")
    if not gone:
        impl = getattr(importlib.import_module(IMPL_CLASS[0]), IMPL_CLASS[1])
        fields = ({f.name for f in dataclasses.fields(impl)} if dataclasses.is_dataclass(impl)
                  else set())
        gone += [f"mjx.Data._impl.{name}" for name in IMPL_FIELDS if name not in fields]
    return gone


def check() -> None:
    """Raise a one-line ImportError naming what is missing (see `missing`), if anything is."""
    gone = missing()
    if gone:
        raise ImportError(
            f"jaxnat.mjx_pixel uses MJX internals written for {WRITTEN_FOR}; the installed "
            f"mujoco-mjx {installed_version()} lacks {', '.join(gone)} (install "
            f"'{WRITTEN_FOR}', or port jaxnat/mjx_pixel/mjx_internals.py)")


check()

_mjx = import_mjx()
from mujoco.mjx._src import forward as _forward  # noqa: E402  (checked above)
from mujoco.mjx._src import scan as _scan  # noqa: E402
from mujoco.mjx._src import types as _types  # noqa: E402

RK4_A = _forward._RK4_A  # Butcher tableau of `mjx.rungekutta4` (its `a` matrix)
RK4_B = _forward._RK4_B  # and its weights
integrate_pos = _forward._integrate_pos  # (jnt_types, qpos, qvel, dt=) -> qpos
advance = _forward._advance  # (m, d, act_dot, qacc, qvel) -> d: MJX's state update
scan_flat = _scan.flat  # MJX's per-joint-type scan


def contact(d):
    """The contacts of `d` (an `mjx.Data`): `geom`, `frame`, ..."""
    return d._impl.contact


def replace_contact_frame(d, frame):
    """`d` with its contacts' frames replaced by `frame`."""
    return d.tree_replace({"_impl.contact.frame": frame})


def constraint_jacobian(d):
    """`efc_J` of `d`: size 0 when the model makes no constraints."""
    return d._impl.efc_J


def cfrc_ext(d):
    """`cfrc_ext` of `d`: per body, the external contact forces (after `rne_postconstraint`)."""
    return d._impl.cfrc_ext


def with_cfrc_ext(m, d):
    """`d` with `cfrc_ext` filled as `mjx.rne_postconstraint` fills it, and `cacc`,
    `cfrc_int` left as they were.

    `rne_postconstraint` also runs two passes over the body tree for `cacc` and `cfrc_int`,
    which no robot here reads; taking only `cfrc_ext` from its result lets XLA drop them.
    """
    return d.tree_replace({"_impl.cfrc_ext": _mjx.rne_postconstraint(m, d)._impl.cfrc_ext})


def field_name(path) -> str:
    """MJX's dotted name of the `mjx.Data` field at pytree `path` (`qpos`; Warp's own fields
    without their `_impl.`)."""
    return _types.tree_path_to_attr_str(path).removeprefix("_impl.")


def warp_world_axis() -> dict:
    """Warp data field name -> whether it has a world axis (MuJoCo Warp installed)."""
    from mujoco.mjx.warp import types as warp_types  # noqa: PLC0415  optional

    return dict(warp_types._BATCH_DIM["Data"])


def without_warp_warnings(warp_model, flags: int):
    """`warp_model` (impl="warp") with Warp's overflow warnings `flags` turned off."""
    opt = warp_model.opt
    kept = int(opt._impl.warn_overflow) & ~int(flags)
    return warp_model.replace(opt=opt.replace(_impl=opt._impl.replace(warn_overflow=kept)))
