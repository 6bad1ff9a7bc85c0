"""RGB frames of jaxnat envs for Gymnasium's `render_mode="rgb_array"` (`Frames`).

The rule: an image observation is shown as the agent sees it (noise included); an env whose
observation is not an image (MuJoCo state, PixelMuJoCo's "state", "noise" or "constant") is
shown through the robot's tracking camera by the pure-JAX ray caster, so a video of a
state-based run needs no OpenGL. Per family:

- `Classify/*`: the image channels (gray repeated to RGB; unrevealed pixels black), the current
  window blended half-way with red.
- `Localize/*`: the photo, the footprint blended half-way with red (`obs["pixels"]`).
- `PixelMuJoCo/*` with `observation="pixels"`: the newest frame of the stack (gray repeated).
- `MuJoCo/*` and `PixelMuJoCo/*` with any other observation: the scene, RGB, checker floor, the
  pixel envs' camera and size (84x84 for `MuJoCo/*`).
- Any other env with a uint8 `[H, W, C]` observation: RGB if `C == 3`, else its last channel
  (the newest frame of a grayscale stack) repeated.
"""

from __future__ import annotations

import sys

import jax
import numpy as np

from jaxnat.core import Environment

__all__ = ["Frames", "RenderError"]

TINT = np.array([255, 0, 0], np.uint16)  # the window/footprint colour (red)
DEFAULT_FPS = 30  # Gymnasium's RecordVideo default: envs without a physical time step
SCENE_SIZE = (84, 84)  # MuJoCo/* scenes: the pixel envs' default frame


class RenderError(ValueError):
    """The env has no RGB frame to show."""


class Frames:
    """`frames(obs, state)` -> uint8 `[..., H, W, 3]` for `env` (leading batch axes allowed
    when `batched`). `fps` is the env's steps per second of simulated time (`render_fps`);
    `timed` says whether it is one (a MuJoCo robot's) or `DEFAULT_FPS` for an env without a
    physical time step. `reads_state`: the frame is drawn from `state` (the chase camera) and
    `obs` is ignored; otherwise from `obs` alone, and `state` may be None (so a recorder keeps
    only the one it needs)."""

    def __init__(self, env: Environment, params, *, batched: bool = False):
        self.fps, self.timed = DEFAULT_FPS, False
        self._scene = None
        self._view = None
        base = env.unwrapped
        classify = sys.modules.get("jaxnat.vision_envs.classify")
        localize = sys.modules.get("jaxnat.vision_envs.localize")
        pixel = sys.modules.get("jaxnat.mjx_pixel.pixel")
        mjx = sys.modules.get("jaxnat.mjx_pixel.base")
        space = env.observation_space(params)
        if classify and isinstance(base, classify.Classify):
            channels = space.shape[-1] - 2
            self._view = lambda obs: _tinted(obs[..., :channels], obs[..., channels + 1])
        elif localize and isinstance(base, localize.Localize):
            self._view = lambda obs: _tinted(obs["pixels"][..., :3], obs["pixels"][..., 3])
        elif pixel and isinstance(base, pixel.PixelMuJoCo) and base.observation == "pixels":
            channels = base.renderer.channels
            self._view = lambda obs: _rgb(obs[..., -channels:])
            self.fps, self.timed = _fps(base.physics, base.frame_skip), True
        elif pixel and isinstance(base, pixel.PixelMuJoCo):
            self._scene = _scene(env, base.physics, lambda s: s.physics, base.frame_skip,
                                 (base.renderer.height, base.renderer.width), batched)
            self.fps, self.timed = _fps(base.physics, base.frame_skip), True
        elif mjx and isinstance(base, mjx.MJXEnv):
            self._scene = _scene(env, base, lambda s: s, 1, SCENE_SIZE, batched)
            self.fps, self.timed = _fps(base, 1), True
        elif getattr(space, "dtype", None) == np.uint8 and len(space.shape) == 3:
            rgb = space.shape[-1] == 3
            self._view = lambda obs: _rgb(obs if rgb else obs[..., -1:])
        else:
            raise RenderError(f"{env.name} has no RGB frame: its observation {space} is not an image "
                              "and it is not a MuJoCo robot")
        self.reads_state = self._scene is not None

    def __call__(self, obs, state) -> np.ndarray:
        if self._view is not None:
            return self._view(obs)
        return np.asarray(self._scene(state))


def _rgb(image: np.ndarray) -> np.ndarray:
    """uint8 `[..., 1 or 3]` -> `[..., 3]` (gray repeated), a fresh array."""
    image = np.asarray(image, np.uint8)
    return np.repeat(image, 3, axis=-1) if image.shape[-1] == 1 else image.copy()


def _tinted(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The image in RGB, blended half-way with `TINT` where the 255/0 `mask` is set."""
    rgb = _rgb(image)
    blend = ((rgb.astype(np.uint16) + TINT) // 2).astype(np.uint8)
    return np.where(np.asarray(mask)[..., None] > 0, blend, rgb)


def _fps(physics, frame_skip: int) -> int:
    """Agent steps per second of simulated time (at least 1)."""
    return max(1, round(1.0 / (physics.dt * frame_skip)))


def _scene(env, physics, physics_state, frame_skip, size, batched):
    """A jitted `state -> uint8 [H, W, 3]` (vmapped when `batched`) of the robot seen by its
    tracking camera: a `PixelMuJoCo` around the same physics, RGB with the checker floor.
    Only wrappers that keep the inner env's state (the observation-noise one) may wrap it."""
    from jaxnat.mjx_pixel.pixel import PixelMuJoCo
    from jaxnat.wrappers import NoiseObservationWrapper, Wrapper

    inner = env
    while isinstance(inner, Wrapper):
        if not isinstance(inner, NoiseObservationWrapper):
            raise RenderError(f"cannot render {env.name}: {type(inner).__name__} changes the state "
                              "the camera reads; render the unwrapped env")
        inner = inner._env
    camera = PixelMuJoCo(physics=physics, observation="state", frame_skip=frame_skip,
                         height=size[0], width=size[1], grayscale=False)
    params = camera.default_params
    key = jax.random.key(0)  # the checker floor draws nothing

    def frame(state):
        return camera.render(key, physics_state(state), params)

    return jax.jit(jax.vmap(frame) if batched else frame)
