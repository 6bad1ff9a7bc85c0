"""PixelMuJoCo: an MJX robot seen through its tracking camera: `PixelMuJoCo/*-v0`.

Semantics: `docs/environments.md` section 4.

- **Physics**: the robot's MJX env (`jaxnat.mjx_pixel.{ant,half_cheetah,hopper,swimmer}`,
  Gymnasium MuJoCo v5 dynamics, rewards, termination and reset noise).
- **Frame skip**: one agent step repeats the action for `frame_skip` (4) physics-env steps and
  sums their rewards (unclipped); when a step terminates the episode, the remaining repeats are
  skipped (the state and the reward stay those of the terminating step).
- **Time limit**: `1000 // frame_skip` agent steps (Gymnasium's 1000 env steps), `truncated`.
- **Observation** (`observation=`):
  - `"pixels"`: uint8 `[H, W, C * frame_stack]`, the last `frame_stack` (4) frames, oldest
    first, `C` = 1 (grayscale, default) or 3. One frame is rendered per agent step, after the
    last repeat (frames inside a skip are never rendered). At reset the stack holds copies of
    the first frame. Frames come from `render.Renderer` (pure JAX ray casting, 84x84 by
    default) through the model's `track` camera (`camera.TrackingCamera`).
  - `"noise"`: uint8 of the same shape, every value i.i.d. from the pixel-noise law `noise=`
    (default `jaxnat.natural.DEFAULT_NOISE`: N(0, 1) * 50 clipped at 0, the authors' law) (the
    paper's open-loop test), fresh each step; nothing is rendered.
  - `"state"`: the physics env's float32 observation after the last repeat (no stacking).
  - `"constant"`: float32 zeros of shape `[1]` (a `Box(0, 0, (1,))`) at every reset and step:
    a policy that sees nothing, so the best it can learn is the best state-independent action
    distribution (the reference for "learns nothing from what it sees"). A vector, so agents
    pick an MLP. Nothing is rendered and no noise is drawn; the physics, rewards, termination,
    time limit and info are those of the other observations, step for step under the same keys
    and actions (`floor=` is ignored, as with "noise" and "state").
- **Floor** (`floor=`, pixels only): the pixels whose nearest hit is the floor plane take
  `"checker"` (the model's checker), `"video"` (the current frame of a natural video laid on
  the floor in world x-y, `video_tile` metres per copy; the video advances one frame per agent
  step; `video_split` "train"/"test" picks disjoint videos) or `"noise"` (fresh Gaussian
  noise each frame, the same law `noise=`). See `floor.py`. The checker and the video are
  mip-filtered by each pixel's footprint (`floor_filter="mip"`, the default), so the far floor
  fades to the texture's average as in MuJoCo's renderer; `floor_filter="nearest"` reads the
  nearest texel everywhere (moire near the horizon). The video's mip levels are built once,
  when the bank is loaded (`PixelParams.video_mips`: 4/3 of the bank's memory again).
- **Distraction** (`PixelParams.distraction`, a `Distraction`; the constructor's keywords of
  the same names set its defaults, which reproduce the plain env bit for bit): how strong the
  video floor is, as traced params, so one jitted program sweeps a whole difficulty curve
  (`PixelParams.sweep` builds the batched params and their `in_axes` for `jax.vmap`):
  - `video_alpha` (float in [0, 1], default 1; floor="video" only): the floor is
    `video_alpha * video + (1 - video_alpha) * checker`, per colour channel before lighting;
    0 gives exactly floor="checker"'s frames (same key: the physics and the cursor draw from
    the same splits), 1 exactly the video floor (`floor.blend_video` selects the endpoints).
    The checker is computed alongside the video at every step (closed form, no texel read).
  - `frame_rate` (int >= 0, default 1; floor="video" only): video frames the cursor advances
    per agent step (the authors' MuJoCo code advanced 4); 0 freezes the episode's first frame.
    A video that ends inside a jump hands over to a new random video at its first frame, as at
    rate 1.
  - `sky_alpha` (float in [0, 1], default 0; floor="video" only): the pixels that hit nothing
    show `sky_alpha * video + (1 - sky_alpha) * sky`, the current video frame stretched over
    the whole image (fixed to the screen, nearest texel: `floor.screen_video`) over the sky
    gradient; 0 is today's sky exactly, 1 the video alone (the same selected endpoints). The
    stretched frame is two small gathers a render, made at every strength.
  - `num_videos` (int in [1, the bank's videos], or None, the default: all; floor="video"
    only): the videos in play, the bank's first `num_videos` (the bank's order: by content
    hash within the split, the same on every machine), each reset and each hand-over drawing among them alone, so 1
    plays a single video over and over. None is today's draws bit for bit.
  - `noise_sigma` (float >= 0, default the law's scale: 50 for both `NOISE_LAWS`;
    observation="noise" or floor="noise" only): the noise's spread. The values are the law's
    cells drawn as before, each cell's quantile z scaled: `clip(floor(mean + noise_sigma * z),
    0, 255)` (`natural.scaled_noise`), so under one key every value moves away from the law's
    mean as sigma grows, 0 is the constant `floor(mean)` (black for "authors"), and the law's
    own scale selects its table: today's draws bit for bit.
  Out-of-range values are one-line `ValueError`s when the env is built and in `check_params`
  (`jaxnat.make` calls it); traced values cannot be checked, and are clipped instead
  (`video_alpha` and `sky_alpha` to [0, 1], `frame_rate` and `noise_sigma` to >= 0,
  `num_videos` to [1, the bank's videos]).
- **Info**: the physics env's info of the last repeat that ran.
- **Cost**: one render per agent step, also batched under autoreset (`jaxnat.make`'s
  default). The state holds the newest frame and the `frame_stack - 1` before it apart (for
  grayscale x 4, packed as the bytes of one uint32 per pixel: `stack.FrameStack`), plus the
  key of its noise; `observe` renders the newest frame from the state and writes it. A step
  carries the older frames over without rendering them again, and `AutoResetWrapper` selects
  between the stepped and the reset state first and calls `observe` once on the result, so the
  frames the step and the reset rendered are dead code to XLA. A caller that reads
  `info["final_observation"]` (a learner bootstrapping from it) needs the stepped frame of an
  ended episode too; the env sets `gated_autoreset`, so under `vmap` the reset and that second
  frame are computed only in steps where some env of the batch ended, for those envs alone
  where they are few (for every env where more did), and a step where none did renders once.
  The noise observation is drawn the same way, once per step.

Example::

    import jax, jaxnat
    env, params = jaxnat.make("PixelMuJoCo/HalfCheetah-v0", floor="video")
    obs, state = env.reset(jax.random.key(0), params)        # uint8 [84, 84, 4]
    action = env.action_space(params).sample(jax.random.key(1))
    obs, state, reward, terminated, truncated, info = env.step(
        jax.random.key(2), state, action, params)

    # Five strengths of the video floor in one program (one env per strength):
    swept, axes = params.sweep(video_alpha=jnp.linspace(0.0, 1.0, 5))
    keys = jax.random.split(jax.random.key(0), 5)
    obs, state = jax.vmap(env.reset, in_axes=(0, axes))(keys, swept)
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxnat import spaces
from jaxnat.core import Environment, EnvParams, EnvState, is_concrete, sweep_distraction
from jaxnat.mjx_pixel.camera import TrackingCamera
from jaxnat.mjx_pixel.floor import FLOOR_MODES, blend_video, floor_rgb, screen_video
from jaxnat.mjx_pixel.render import GeomTable, Renderer
from jaxnat.mjx_pixel.stack import FrameStack
from jaxnat.natural.noise import DEFAULT_NOISE, NOISE_SCALE, NoiseLaw, noise_law

__all__ = ["PixelMuJoCo", "PixelState", "PixelParams", "Distraction", "PHYSICS", "OBSERVATIONS", "NAMED_POINTS"]

# Robot name -> its MJX physics env ("module:class").
PHYSICS = {
    "ant": "jaxnat.mjx_pixel.ant:Ant",
    "half_cheetah": "jaxnat.mjx_pixel.half_cheetah:HalfCheetah",
    "hopper": "jaxnat.mjx_pixel.hopper:Hopper",
    "swimmer": "jaxnat.mjx_pixel.swimmer:Swimmer",
}
OBSERVATIONS = ("pixels", "noise", "state", "constant")
# The named points of the distraction dial (`distraction=`): name -> floor -> the `Distraction`
# fields it sets (the others keep the plain env's). "paper": the authors' MuJoCo code advanced 4
# video frames per agent step; their noise is the default law at its own scale.
NAMED_POINTS = {None: {}, "paper": {"video": {"frame_rate": 4}}}


@struct.dataclass
class PixelState(EnvState):
    physics: Any  # the physics env's state; `physics.data` is its mjx.Data
    key: jax.Array  # uint32 data of the key that draws this state's noise (floor, observation)
    latest: jax.Array  # "pixels": the newest frame [H, W, C]; "state": the physics obs; else [0]
    history: jax.Array  # "pixels": the frame_stack - 1 frames before it (`stack.FrameStack`)
    fresh: jax.Array  # bool: the episode's first state (the stack is `latest` repeated)
    cursor: Any = None  # natural.VideoCursor with floor="video", else None


@struct.dataclass
class Distraction:
    """The distraction's strength (module docstring, **Distraction**): traced numbers, so a
    sweep over them is one jitted, vmapped program. A group of its own inside `PixelParams` so
    that `in_axes` can name it apart from the physics and the video bank, which a sweep shares
    (`PixelParams.sweep`). The defaults are the plain env."""

    video_alpha: float = 1.0  # floor="video": the video's weight over the checker, in [0, 1]
    frame_rate: int = 1  # floor="video": video frames per agent step, >= 0 (0: frozen)
    sky_alpha: float = 0.0  # floor="video": the video's weight over the sky, in [0, 1]
    noise_sigma: float = NOISE_SCALE  # observation or floor "noise": the noise's spread, >= 0
    num_videos: int | None = None  # floor="video": the bank's first videos in play (None: all)


@struct.dataclass(kw_only=True)
class PixelParams(EnvParams):
    physics: Any  # the physics env's params
    video: Any = None  # natural.FrameBank on the device, with floor="video"
    video_tile: float = 4.0  # metres of floor one video frame covers (x and y)
    # floor="video" with floor_filter="mip": every bank frame's mip chain, `floor.pack_mips`
    # (uint8 [F, M, C]: 4/3 of the bank, level 0 included, so a pixel reads one array), built
    # once when the bank is loaded.
    video_mips: Any = None
    max_steps_in_episode: int = 250
    distraction: Distraction = struct.field(default_factory=Distraction)

    def sweep(self, **values) -> tuple[PixelParams, Any]:
        """`(params, in_axes)`: these params with the named `Distraction` fields replaced by
        arrays of one leading length (a strength axis), and the matching `in_axes` prefix for
        `jax.vmap` (0 on those fields, None everywhere else: the physics params and the video
        bank stay shared, not copied per strength)::

            swept, axes = params.sweep(video_alpha=jnp.linspace(0, 1, 5))
            jax.vmap(env.step, in_axes=(0, 0, 0, axes))(keys, states, actions, swept)
        """
        # Ranges now, while the values are concrete (the floor is the env's: `check_params`).
        bank_videos = None if self.video is None else self.video.lengths.shape[0]
        return sweep_distraction(self, values, lambda arrays: _check_distraction(
            **{k: a for k, a in arrays.items() if is_concrete(a)}, bank_videos=bank_videos))


class PixelMuJoCo(Environment[PixelState, PixelParams]):
    """An MJX robot observed as pixels, pure noise, state or a constant (see the module docstring).

    Args:
        robot: "ant", "half_cheetah", "hopper" or "swimmer" (ignored when `physics` is an env).
        observation: "pixels", "noise", "state" or "constant" (float32 zeros `[1]`).
        floor: "checker", "video" or "noise".
        noise: the pixel-noise law of observation="noise" and floor="noise": a name in
            `jaxnat.natural.NOISE_LAWS` (`"authors"`, the default, or `"centred"`) or a
            `NoiseLaw`.
        frame_skip: physics-env steps per agent step (4).
        frame_stack: frames per observation (4).
        height, width: frame size in pixels (84x84).
        grayscale: 1 channel per frame (True, the paper's preprocessing) or RGB.
        shadows: render the light's shadows (off by default: about twice the render work).
        render_kernel: the renderer's nearest-hit search: "auto" (a Pallas kernel on a GPU,
            plain JAX elsewhere), "xla" or "pallas" (see `render.Renderer`, `pallas_cast.py`).
        floor_filter: "mip" (the floor texture filtered by each pixel's footprint, as MuJoCo's
            mipmaps) or "nearest" (the nearest texel); see `render.Renderer`.
        videos: natural video sources for floor="video" (None: opencv-doc's videos; else files,
            a directory or a glob; see `jaxnat.natural.load_videos`).
        video_alpha: floor="video": the default `Distraction.video_alpha`, the video's weight
            over the checker in [0, 1] (1: the video floor; 0: the checker's frames).
        distraction: a named point of the dial: None (the plain env) or "paper" (the authors'
            settings: their MuJoCo code advanced 4 video frames per agent step, so
            `frame_rate=4` on the video floor; the other fields are the plain env's). A dial
            field given beside "paper" that it sets is a one-line error.
        frame_rate: floor="video": the default `Distraction.frame_rate`, video frames per agent
            step (1; 0 freezes the episode's first frame).
        sky_alpha: floor="video": the default `Distraction.sky_alpha`, the video's weight over
            the sky in [0, 1] (0: today's sky).
        num_videos: floor="video": the default `Distraction.num_videos`, how many of the bank's
            videos are in play (None: all).
        noise_sigma: observation="noise" or floor="noise": the default
            `Distraction.noise_sigma`, the noise's spread (None: the law's scale, today's
            draws).
        video_split: "train", "test" (disjoint videos) or "all".
        video_shape: (H, W) the videos are decoded to before being laid on the floor.
        video_max_frames: cap on the frames held on the device (None: all).
        physics: `"default"` or `"fast"`: `robot`'s physics env with that `physics=` setting
            (see `mjx_pixel/base.py`); or a physics env instance to wrap instead of `robot`'s
            (its state must carry an `mjx.Data` as `.data` and the env its `mujoco.MjModel` as
            `.model`).
        physics_impl: who steps `robot`'s physics: `"jax"` (MJX's JAX implementation) or
            `"warp"` (MuJoCo Warp, the `warp` extra; `mjx_pixel/warp_physics.py`). Only with
            `physics` given as a string.
    """

    params_type = PixelParams
    # A reset runs the robot's kinematics and renders, and a step rendering the final frame of
    # an ended episode renders twice; few envs of a batch end an episode in a step (none for
    # robots that never terminate, between their time limits): `AutoResetWrapper` computes both
    # only for the envs that ended (its docstring).
    gated_autoreset = True

    def __init__(
        self,
        robot: str = "half_cheetah",
        observation: str = "pixels",
        floor: str = "checker",
        frame_skip: int = 4,
        frame_stack: int = 4,
        height: int = 84,
        width: int = 84,
        grayscale: bool = True,
        shadows: bool = False,
        videos=None,
        video_split: str = "train",
        video_shape: tuple[int, int] = (128, 128),
        video_max_frames: int | None = None,
        physics: Environment | str = "default",
        render_kernel: str = "auto",
        noise: str | NoiseLaw = DEFAULT_NOISE,
        floor_filter: str = "mip",
        video_alpha: float = 1.0,
        frame_rate: int | None = None,
        sky_alpha: float = 0.0,
        noise_sigma: float | None = None,
        num_videos: int | None = None,
        distraction: str | None = None,
        physics_impl: str = "jax",
    ):
        if observation not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {OBSERVATIONS}, got {observation!r}")
        if floor not in FLOOR_MODES:
            raise ValueError(f"floor must be one of {FLOOR_MODES}, got {floor!r}")
        if int(frame_skip) < 1 or int(frame_stack) < 1:
            raise ValueError(f"frame_skip and frame_stack must be >= 1, got {frame_skip}, {frame_stack}")
        law = noise_law(noise)
        noise_sigma = law.scale if noise_sigma is None else noise_sigma
        if distraction not in NAMED_POINTS:
            raise ValueError(f"distraction must be one of {sorted(NAMED_POINTS, key=str)}, got {distraction!r}")
        point = NAMED_POINTS[distraction].get(floor, {})
        if "frame_rate" in point and frame_rate is not None:
            raise ValueError(f"distraction={distraction!r} sets frame_rate={point['frame_rate']}; leave frame_rate out")
        frame_rate = point.get("frame_rate", 1) if frame_rate is None else frame_rate
        _check_distraction(floor, "noise" in (observation, floor), law.scale,
                           video_alpha=video_alpha, frame_rate=frame_rate, sky_alpha=sky_alpha,
                           noise_sigma=noise_sigma)
        if physics is None or isinstance(physics, str):
            if robot not in PHYSICS:
                raise ValueError(f"robot must be one of {sorted(PHYSICS)}, got {robot!r}")
            module, _, cls = PHYSICS[robot].partition(":")
            physics = getattr(importlib.import_module(module), cls)(physics=physics or "default",
                                                                    impl=physics_impl)
        elif physics_impl != "jax":
            raise ValueError(f"physics_impl={physics_impl!r} applies to the robot's own physics "
                             f"env; pass impl= to the physics env you give instead")
        self.robot = robot
        self.physics = physics
        self.observation = observation
        self.floor = floor
        self.noise = law
        self.frame_skip, self.frame_stack = int(frame_skip), int(frame_stack)
        self.camera = TrackingCamera.from_model(physics.model)
        self.table = GeomTable.from_model(physics.model)
        self.renderer = Renderer(self.table, height, width, fovy=self.camera.fovy,
                                 grayscale=grayscale, shadows=shadows, kernel=render_kernel,
                                 floor_filter=floor_filter)
        self.stack = FrameStack(height, width, self.renderer.channels, self.frame_stack)
        self._video = None
        if observation == "pixels" and floor == "video":
            from jaxnat import natural

            bank = natural.load_videos(videos, shape=tuple(video_shape), grayscale=grayscale,
                                       split=video_split, max_frames=video_max_frames)
            self._video = bank.to_device()
        if num_videos is not None:  # its upper bound is the bank's count, known now
            _check_distraction(floor, num_videos=num_videos,
                               bank_videos=None if self._video is None else self._video.num_videos)
        self._video_mips = None
        if self._video is not None and self.renderer.floor_filter == "mip":
            from jaxnat.mjx_pixel.floor import pack_mips

            self._video_mips = pack_mips(self._video.frames)
        self.video_split = video_split
        self.distraction = Distraction(video_alpha=float(video_alpha), frame_rate=int(frame_rate),
                                       sky_alpha=float(sky_alpha),
                                       noise_sigma=float(noise_sigma),
                                       num_videos=None if num_videos is None else int(num_videos))

    @property
    def name(self) -> str:
        return f"PixelMuJoCo[{self.robot}, {self.observation}, floor={self.floor}]"

    @property
    def default_params(self) -> PixelParams:
        return PixelParams(physics=self.physics.default_params, video=self._video,
                           video_mips=self._video_mips,
                           max_steps_in_episode=max(1, 1000 // self.frame_skip),
                           distraction=self.distraction)

    def check_params(self, params: PixelParams) -> None:
        super().check_params(params)
        d = params.distraction
        _check_distraction(self.floor, "noise" in (self.observation, self.floor),
                           self.noise.scale,
                           bank_videos=None if params.video is None else params.video.lengths.shape[0],
                           **{f.name: getattr(d, f.name) for f in dataclasses.fields(d)
                              if getattr(d, f.name) is not None and is_concrete(getattr(d, f.name))})

    def action_space(self, params: PixelParams) -> spaces.Space:
        return self.physics.action_space(params.physics)

    def observation_space(self, params: PixelParams) -> spaces.Space:
        if self.observation == "state":
            return self.physics.observation_space(params.physics)
        if self.observation == "constant":
            return spaces.Box(0.0, 0.0, (1,), jnp.float32)
        r = self.renderer
        return spaces.Box(0, 255, (r.height, r.width, r.channels * self.frame_stack), jnp.uint8)

    def get_obs(self, state: PixelState, params: PixelParams) -> jax.Array:
        if self.observation == "pixels":
            return self.stack.observation(state.history, state.latest, state.fresh)
        if self.observation == "noise":
            return self.noise.sample_scaled(_noise_key(state), self.observation_space(params).shape,
                                            params.distraction.noise_sigma)
        if self.observation == "constant":
            return jnp.zeros((1,), jnp.float32)
        return state.latest

    def observe(self, state: PixelState, params: PixelParams):
        """Render the newest frame of `state` ("pixels") and write it; `(obs, state)`."""
        if self.observation == "pixels":
            frame = self.render(_noise_key(state), state.physics, params, state.cursor)
            state = state.replace(latest=frame)
        return self.get_obs(state, params), state

    def render(self, key, physics_state, params: PixelParams, cursor=None) -> jax.Array:
        """One uint8 `[H, W, C]` frame of `physics_state` with this env's floor. `key` draws the
        noise floor; `cursor` picks the video frame (floor="video")."""
        data = physics_state.data
        cam_pos, cam_mat = self.camera.pose(data)
        frames = frame_index = sky = None
        if self.floor == "video":
            from jaxnat.natural import cursor_index

            video = params.video
            frames = video.frames
            frame_index = cursor_index(video, cursor)
            r = self.renderer
            sky = blend_video(screen_video(frames, frame_index, r.height, r.width),
                              r.sky_gradient(), params.distraction.sky_alpha)

        def floor(xy, footprint=None):  # the renderer passes a footprint with floor_filter="mip"
            return floor_rgb(self.floor, self.table, xy, footprint, frame=frames,
                             frame_index=frame_index,
                             tile=params.video_tile, key=key, channels=self.renderer.channels,
                             noise=self.noise, mips=params.video_mips,
                             video_alpha=params.distraction.video_alpha,
                             noise_sigma=params.distraction.noise_sigma)

        return self.renderer.render(cam_pos, cam_mat, data.geom_xpos, data.geom_xmat, floor, sky)

    def reset_env(self, key, params: PixelParams):
        key_physics, key_video, key_obs = jax.random.split(key, 3)
        physics_obs, physics_state = self.physics.reset_env(key_physics, params.physics)
        cursor = None
        if self._video is not None:
            from jaxnat.natural import cursor_reset

            cursor = cursor_reset(key_video, params.video, params.distraction.num_videos)
        # The frames are placeholders until `observe` renders the first one.
        latest, history = self._placeholders(physics_obs, params)
        state = PixelState(time=jnp.zeros((), jnp.int32), physics=physics_state,
                           key=jax.random.key_data(key_obs),
                           latest=latest, history=history, fresh=jnp.ones((), jnp.bool_),
                           cursor=cursor)
        return self.observe(state, params)

    def step_env(self, key, state: PixelState, action, params: PixelParams):
        key_physics, key_video, key_obs = jax.random.split(key, 3)
        physics_obs, physics_state, reward, terminated, info = self._repeat(
            key_physics, state.physics, action, params)
        cursor = state.cursor
        if cursor is not None:
            from jaxnat.natural import cursor_step

            # `frame_rate` frames on: the cursor steps once from `rate - 1` frames ahead, so
            # rate 1 is `cursor_step` itself (same draws) and a video that ends inside the jump
            # hands over as at rate 1.
            rate = jnp.maximum(jnp.asarray(params.distraction.frame_rate, jnp.int32), 0)
            cursor = cursor_step(key_video, cursor.replace(offset=cursor.offset + (rate - 1)),
                                 params.video, params.distraction.num_videos)
        latest, history = self._placeholders(physics_obs, params)
        if self.observation == "pixels":  # the stack so far, less its oldest frame
            history = self.stack.push(state.history, state.latest, state.fresh)
        state = state.replace(physics=physics_state, key=jax.random.key_data(key_obs),
                              latest=latest, history=history,
                              fresh=jnp.zeros((), jnp.bool_), cursor=cursor)
        obs, state = self.observe(state, params)
        return obs, state, reward, terminated, info

    def _placeholders(self, physics_obs, params):
        """(latest, history) before `observe`: zero frames ("pixels"), the physics observation
        ("state"), nothing ("noise", "constant")."""
        if self.observation == "state":
            return physics_obs, jnp.zeros((0,), jnp.uint8)
        if self.observation in ("noise", "constant"):
            return jnp.zeros((0,), jnp.uint8), jnp.zeros((0,), jnp.uint8)
        r = self.renderer
        return jnp.zeros((r.height, r.width, r.channels), jnp.uint8), self.stack.empty()

    def _repeat(self, key, physics_state, action, params: PixelParams):
        """`frame_skip` physics steps with `action`; steps after a termination are void."""
        physics = self.physics
        step = physics.step_env
        shapes = jax.eval_shape(step, key, physics_state, action, params.physics)
        zeros = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), (shapes[0], shapes[4]))

        def body(carry, key):
            state, obs, total, done, info = carry
            new_obs, new_state, reward, terminated, new_info = step(key, state, action, params.physics)
            keep = lambda new, old: jnp.where(done, old, new)  # noqa: E731
            state = jax.tree.map(keep, new_state, state)
            obs, info = jax.tree.map(keep, (new_obs, new_info), (obs, info))
            total = total + jnp.where(done, 0.0, reward)
            return (state, obs, total, done | terminated, info), None

        init = (physics_state, zeros[0], jnp.zeros((), jnp.float32), jnp.zeros((), jnp.bool_), zeros[1])
        (state, obs, total, done, info), _ = jax.lax.scan(
            body, init, jax.random.split(key, self.frame_skip))
        return obs, state, total, done, info


def _check_distraction(floor: str | None = None, noisy: bool | None = None,
                       law_scale: float = NOISE_SCALE, video_alpha=1.0, frame_rate=1,
                       sky_alpha=0.0, noise_sigma=None, num_videos=None, bank_videos=None) -> None:
    """One-line `ValueError`s for `Distraction` values out of range (host numbers or arrays).
    `floor` and `noisy` (the env draws noise: observation or floor "noise") also refuse a
    strength the env would ignore; None (`PixelParams.sweep`, which has no env) skips that.
    `bank_videos`: the video bank's count, `num_videos`' upper bound (None: unknown here)."""
    if num_videos is not None:
        count = np.asarray(num_videos)
        if not (np.issubdtype(count.dtype, np.integer) or np.all(count == np.round(count))):
            raise ValueError(f"num_videos must be a whole number of videos, got {num_videos}")
        if not np.all(count >= 1):
            raise ValueError(f"num_videos must be >= 1 (None: every video of the bank), got {num_videos}")
        if bank_videos is not None and np.any(count > bank_videos):
            raise ValueError(f"num_videos={num_videos} exceeds the video bank's {bank_videos} videos: use at "
                             f"most {bank_videos}, or load more videos (videos=)")
        if floor not in (None, "video"):
            raise ValueError(f'num_videos needs floor="video", got floor={floor!r}')
    alpha, rate = np.asarray(video_alpha, np.float64), np.asarray(frame_rate)
    sky = np.asarray(sky_alpha, np.float64)
    sigma = np.asarray(law_scale if noise_sigma is None else noise_sigma, np.float64)
    for name, value, given in (("video_alpha", alpha, video_alpha), ("sky_alpha", sky, sky_alpha)):
        if not np.all((value >= 0.0) & (value <= 1.0)):
            raise ValueError(f"{name} must lie in [0, 1], got {given}")
    if not np.all(np.isfinite(sigma) & (sigma >= 0.0)):
        raise ValueError(f"noise_sigma must be a finite number >= 0, got {noise_sigma}")
    if not (np.issubdtype(rate.dtype, np.integer) or np.all(rate == np.round(rate))):
        raise ValueError(f"frame_rate must be a whole number of video frames, got {frame_rate}")
    if not np.all(rate >= 0):
        raise ValueError(f"frame_rate must be >= 0 (0 freezes the frame), got {frame_rate}")
    if floor not in (None, "video") and (np.any(alpha != 1.0) or np.any(rate != 1)
                                         or np.any(sky != 0.0)):
        raise ValueError(f'video_alpha, frame_rate and sky_alpha need floor="video", got '
                         f'floor={floor!r}')
    if noisy is False and np.any(sigma != law_scale):
        raise ValueError(f'noise_sigma needs observation="noise" or floor="noise", got '
                         f'floor={floor!r}')


def _noise_key(state: PixelState) -> jax.Array:
    """The typed key of `state`'s noise (the state holds its data: plain uint32 arrays)."""
    return jax.random.wrap_key_data(state.key)
