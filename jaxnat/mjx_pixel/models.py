"""The four robots' MuJoCo models, exactly as Gymnasium's MuJoCo v5 tasks load them.

The MJCF files are read from the installed `gymnasium` package (`gymnasium/envs/mujoco/assets`),
so the physics is Gymnasium v5's by construction. MJX (mujoco-mjx >= 3.2) accepts all four
unchanged: primitive geoms only (plane, sphere, capsule), Euler (HalfCheetah) and RK4 (Ant,
Hopper, Swimmer) integrators, the Newton solver, and for Swimmer the inertia-box fluid model
(`density`, `viscosity` in `<option>`), which MJX implements in `mjx.passive`. No copy or
adaptation is shipped.

In every model the robot's root body is named `torso` and has body id 1; the renderer's
tracking camera follows it (`torso_body_id`).
"""

from __future__ import annotations

import contextlib
import copy
import datetime
import functools
import importlib.resources
import io
import sys

import mujoco

from jaxnat.datasets.cache import cache_dir

__all__ = ["ROBOTS", "TORSO_BODY", "load_model", "model_path", "torso_body_id", "import_mjx", "mujoco_log_path"]


def mujoco_log_path():
    """Where MuJoCo's warnings go: `mujoco.log` in jaxnat's cache folder (MuJoCo's own default
    is `MUJOCO_LOG.TXT` in whatever folder the program runs in)."""
    return cache_dir() / "mujoco.log"


def _log_warning(message: str) -> None:
    path = mujoco_log_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as log:
        log.write(f"{datetime.datetime.now().isoformat(timespec='seconds')} {message}\n")


if mujoco.get_mju_user_warning() is None:  # a handler the user set stays
    mujoco.set_mju_user_warning(_log_warning)


def import_mjx():
    """`mujoco.mjx`, without the lines it prints when its optional Warp backend is not installed
    (jaxnat runs MJX's JAX backend only); anything else it prints still shows."""
    with contextlib.redirect_stdout(io.StringIO()) as printed:
        from mujoco import mjx
    kept = [line for line in printed.getvalue().splitlines() if not line.startswith("Failed to import")]
    if kept:
        print("\n".join(kept), file=sys.stdout)
    return mjx

# Robot name -> Gymnasium's XML file.
ROBOTS = {
    "ant": "ant.xml",
    "half_cheetah": "half_cheetah.xml",
    "hopper": "hopper.xml",
    "swimmer": "swimmer.xml",
}
TORSO_BODY = "torso"


def model_path(name: str) -> str:
    """Path of Gymnasium v5's MJCF for robot `name` (one of `ROBOTS`)."""
    if name not in ROBOTS:
        raise ValueError(f"Unknown robot {name!r}; choose one of {sorted(ROBOTS)}")
    try:
        assets = importlib.resources.files("gymnasium") / "envs" / "mujoco" / "assets"
    except ModuleNotFoundError as err:
        raise ImportError(
            "The MuJoCo robots' models come from Gymnasium's MuJoCo assets, and gymnasium is "
            "not installed. Fix: pip install 'jaxnat[mujoco]'"
        ) from err
    path = assets / ROBOTS[name]
    if not path.is_file():
        raise FileNotFoundError(
            f"{path} is missing: the installed gymnasium has no MuJoCo v5 assets. "
            "Fix: pip install 'gymnasium>=1.0'"
        )
    return str(path)


@functools.cache
def _load(name: str) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(model_path(name))


def load_model(name: str) -> mujoco.MjModel:
    """Robot `name`'s compiled `mujoco.MjModel` (a fresh copy: callers may change it)."""
    return copy.copy(_load(name))  # MjModel's copy is a deep copy


def torso_body_id(model_or_name) -> int:
    """Body id of the robot's torso (the body the tracking camera follows)."""
    model = load_model(model_or_name) if isinstance(model_or_name, str) else model_or_name
    body_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, TORSO_BODY)
    if body_id < 0:
        raise ValueError(f"model has no body named {TORSO_BODY!r}")
    return body_id
