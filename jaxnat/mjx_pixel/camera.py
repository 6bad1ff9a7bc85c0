"""The tracking camera: the pose MuJoCo gives a model camera with `mode="track"` or `"trackcom"`.

Gymnasium's MuJoCo XMLs (Ant, HalfCheetah, Hopper, Swimmer) each put a camera named `track`
with `mode="trackcom"` on the torso. MuJoCo (`mj_camlight`) places such a camera each step at

- `trackcom`: `subtree_com[body] + cam_poscom0` (the torso subtree's centre of mass plus the
  offset it had at the reference pose), orientation `cam_mat0`, fixed in the world;
- `track`: `xpos[body] + cam_pos0`, orientation `cam_mat0`;
- `fixed`: the body's frame times the camera's local pose (`cam_pos`, `cam_quat`).

So the view translates with the robot and never rotates. `TrackingCamera.pose(data)` computes
the same from `subtree_com` / `xpos` / `xmat` of an `mjx.Data` or `mujoco.MjData`.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

__all__ = ["TrackingCamera"]

_FIXED, _TRACK, _TRACKCOM = 0, 1, 2  # mujoco.mjtCamLight values used here


@dataclasses.dataclass(frozen=True)
class TrackingCamera:
    """A model camera's static description (host numbers).

    Attributes:
        body: the body it is attached to (the torso for Gymnasium's `track` camera).
        mode: mjtCamLight: 0 fixed, 1 track, 2 trackcom.
        offset: float32 [3]: `cam_poscom0` (trackcom), `cam_pos0` (track) or `cam_pos` (fixed).
        mat: float32 [3, 3]: `cam_mat0` (world orientation; for fixed: local, from cam_quat).
        fovy: vertical field of view in degrees.
    """

    body: int
    mode: int
    offset: np.ndarray
    mat: np.ndarray
    fovy: float

    @classmethod
    def from_model(cls, model, name: str = "track") -> "TrackingCamera":
        """The model camera called `name` (Gymnasium's robots: `"track"`)."""
        import mujoco

        cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
        if cam < 0:
            names = [model.camera(i).name for i in range(model.ncam)]
            raise ValueError(f"the model has no camera named {name!r}; its cameras: {names}")
        mode = int(model.cam_mode[cam])
        if mode == _TRACKCOM:
            offset = model.cam_poscom0[cam]
        elif mode == _TRACK:
            offset = model.cam_pos0[cam]
        elif mode == _FIXED:
            offset = model.cam_pos[cam]
        else:
            raise ValueError(f"camera {name!r} has mode {mode}; supported: fixed, track, trackcom")
        if mode == _FIXED:
            mat = np.zeros(9)
            mujoco.mju_quat2Mat(mat, model.cam_quat[cam])
        else:
            mat = np.asarray(model.cam_mat0[cam])
        return cls(body=int(model.cam_bodyid[cam]), mode=mode,
                   offset=np.asarray(offset, np.float32),
                   mat=np.asarray(mat, np.float32).reshape(3, 3), fovy=float(model.cam_fovy[cam]))

    def pose(self, data) -> tuple:
        """`(pos [3], mat [3, 3])` in the world for `data` (mjx.Data or MjData), jittable. A
        track/trackcom camera's orientation comes back as host numbers (numpy): it never
        changes, and the renderer then makes its ray directions compile-time constants."""
        if self.mode == _TRACKCOM:
            return jnp.asarray(data.subtree_com[self.body]) + self.offset, self.mat
        if self.mode == _TRACK:
            return jnp.asarray(data.xpos[self.body]) + self.offset, self.mat
        body_mat = jnp.asarray(data.xmat[self.body]).reshape(3, 3)
        return jnp.asarray(data.xpos[self.body]) + body_mat @ self.offset, body_mat @ self.mat
