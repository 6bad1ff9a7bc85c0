"""`NaturalAtariVecEnv`: a batch of ALE games with natural backgrounds, emulated on the host.

    env = jaxnat.make_vec("NaturalAtari/Breakout-v0", 8, background="video", split="train")
    obs, info = env.reset(seed=0)              # uint8[8, 84, 84, 4]
    obs, reward, terminated, truncated, info = env.step(np.zeros(8, np.int32))
"""

from __future__ import annotations

import time

import numpy as np

from jaxnat import spaces
from jaxnat.atari import hostpass
from jaxnat.atari.area import area_plan
from jaxnat.atari.backgrounds import BACKGROUNDS, make_background
from jaxnat.atari.chunks import ChunkRunner, default_threads
from jaxnat.atari.compositor import FrameStack, composite_and_resize, composite_gray
from jaxnat.atari.games import rom_id, rom_path
from jaxnat.natural.noise import DEFAULT_NOISE
from jaxnat.natural.sampler import seed_groups

__all__ = ["NaturalAtariVecEnv", "PREPROCESSINGS", "SCREEN_SHAPE"]

SCREEN_SHAPE = (210, 160)  # ALE's screen, rows x columns
_AUTORESET_MODES = {"same_step": "SameStep", "next_step": "NextStep"}
_HOST_PASSES = ("auto", "pool")
# `preprocessing=` presets: name -> (default sticky_actions, FIRE at reset, episodic life, sign-clipped
# rewards). "standard": Machado et al.'s evaluation protocol as ale-py's v5 envs; "deepmind": the
# authors' (baselines' `wrap_deepmind` on NoFrameskip-v4 games, through pytorch-a2c-ppo-acktr).
PREPROCESSINGS = {"standard": (0.25, False, False, False), "deepmind": (0.0, True, True, True)}
_ENVS_PER_HOST_CHUNK = 4  # default host_threads: at least this many envs per chunk
# Default host_threads, at most. Beside ALE's threads on a fully used host, numba's parallel
# pass (jaxnat.atari.hostpass) still gains from 8 threads, while more would take cores from the
# emulation; the Python thread pool gains nothing past about 4 chunks, whose hand-offs through
# the GIL then cost what more threads save. The host_threads sweeps behind both numbers are in
# bench/results/natural_atari.md.
_DEFAULT_HOST_THREADS = {"numba": 8, "pool": 4}


class NaturalAtariVecEnv:
    """`num_envs` copies of an Atari game whose black background shows natural video or noise.

    Emulation: ale-py's C++ `AtariVectorEnv` on `num_threads` threads, full-resolution (210x160)
    screens after its frame skip (`frame_skip` frames, rewards summed) and max-pool over the last
    two frames (`pool="gray"`: of ALE's gray screens, as ale-py's and Gymnasium's own
    preprocessing, bit-identical to them with background "none"; `pool="rgb"`: of the RGB screens,
    per channel, then ALE's grayscale; the background mask is the same either way, see
    jaxnat.atari.compositor), sticky actions with probability `sticky_actions` (ALE's
    `repeat_action_probability`, applied at every emulated frame), a random number of no-ops in
    `[0, noop_max)` at each reset, truncation after `max_episode_steps` agent steps, and what
    `preprocessing` sets:

    - "standard" (default; Machado et al.'s protocol, as ale-py's v5 envs): sticky actions 0.25
      unless `sticky_actions` says otherwise, no FIRE at reset, whole games as episodes (no life
      loss signal), rewards unclipped.
    - "deepmind" (the authors': baselines' `wrap_deepmind` on NoFrameskip-v4 games, through
      pytorch-a2c-ppo-acktr): no sticky actions (v4; `sticky_actions=0.25` states v5 instead);
      FIRE at every game reset in games whose action set has it (ale-py's: one FIRE frame, then
      the no-ops less one; baselines presses FIRE for an agent step after its no-ops); a lost
      life (fewer lives after the step than before it, some left: baselines' `EpisodicLifeEnv`)
      ends the training episode, `terminated` with `info["life_lost"]` True, while ALE's game
      goes on: the frame stack restarts from zeros, the background and the game's score do not.
      After a lost life the agent presses FIRE itself: baselines' `FireResetEnv` presses it in
      hidden reset steps, which ale-py's vector env (every env steps in every batch step) cannot
      take for one env alone. In "next_step" autoreset the reset step after a lost life is a
      NOOP (baselines' hidden `step(0)`), reward 0. Rewards are `sign(r)`, the game's score
      change in `info["unclipped_reward"]` (baselines' `ClipRewardEnv`). The episode statistics
      below stay whole games, unclipped: evaluation counts `returned_episode`, i.e. games.
      Unlike Gymnasium's `AtariPreprocessing(terminal_on_life_loss=True)` the frame skip is not
      cut short at a lost life, and the game is not reset (baselines' `MaxAndSkipEnv` and
      `EpisodicLifeEnv` do as here); the frames agree up to that step.

    Then on the host, whole-batch calls (jaxnat.atari.compositor; compositing and resizing are
    one fused pass of jaxnat.atari.area's kernel, bit-identical to OpenCV's): pixels whose
    three channels are all 0 take this step's background frame (`background`: "none" black,
    "noise" i.i.d. noise per pixel and channel each step from the pixel-noise law `noise`
    (`jaxnat.natural.NOISE_LAWS`; default `clip(N(0,1)*50, 0)`, the authors'; `noise_sigma`
    replaces its scale when not None, one value or one per env), "video" consecutive
    frames of a random natural video, one per agent step, a new video at a random offset at every
    reset, "image" a random still photo per episode); then ALE's grayscale, INTER_AREA resize to
    `obs_size`, and a stack of the last `stack` frames, channels-last, oldest first (zeros before
    the first frame of an episode). With `background="none"` (and `pool="gray"`) nothing is
    composited, so ALE resizes in its own threads: observations are ale-py's own preprocessing.

    Videos and photos come from `jaxnat.natural` (`video_sources`: None = opencv-doc's samples),
    split by whole files: `split="train"` and `"test"` never share a file, `"all"` uses both.

    The distraction dial, fixed when the env is built, one value for every env or one per env
    (a sequence of `num_envs`, so one batch can play a whole difficulty curve); the defaults
    are the plain env, draw for draw: `video_alpha` in [0, 1] (background "video" or "image",
    default 1): an env's background frames are `round(alpha * frame)` in gray, the video over
    ALE's black (0: the black background of "none", composited); `frame_rate` (whole >= 0,
    "video", default 1): video frames per agent step (0 freezes an episode's first frame; a
    video that ends inside a jump hands over to a new one at its first frame); `num_videos`
    (None: all; a count in [1, the bank's videos], "video" or "image"): the bank's first videos
    an env draws from (the bank's order: by content hash within the split). A value for another
    background, or out of range, is a one-line `ValueError`.

    Autoreset (`autoreset_mode`): "same_step" (default, as jaxnat's `AutoResetWrapper`): the
    step that ends an episode returns the next episode's first observation, and the final one in
    `info["final_observation"]` (every row; equal to `obs` where the episode did not end).
    "next_step" (Gymnasium's vector default): the ending step returns the final observation;
    the next step ignores that env's action, resets it and returns reward 0.

    `step` returns numpy arrays: obs `uint8[B, h, w, stack]`, reward `float32[B]` (the game's
    score change, unclipped in "standard" preprocessing, see `ClipRewardWrapper`; its sign in
    "deepmind"), terminated and truncated `bool[B]`, and `info` with `lives`,
    `returned_episode` (a whole game ended: game over or time limit, never a lost life),
    `returned_episode_returns` and `returned_episode_lengths` (return and length in agent steps
    of each env's last finished whole game, unclipped, held until the next one ends), and in
    "deepmind" preprocessing `life_lost` and `unclipped_reward`.

    Deterministic given `seed` (env `i`'s emulator is seeded with `seed + i`), the actions, and
    `sticky_actions=0` or not: ALE's sticky actions use the emulator's own seeded generator.

    Threads (`docs/design.md`, "Host threads", says why): ALE emulates on `num_threads` C++
    threads (0: one per env, at most one per CPU, as ale-py). The host work after it and the
    noise draws are split into `host_threads` chunks of envs run in parallel (0: as many as
    ALE's threads but at most 8 on numba's threads, 4 on the Python pool, at least 4 envs a
    chunk; 1: the calling thread alone): one parallel numba call (jaxnat.atari.hostpass) with
    gray pooling at a size the exact resize kernel covers (84x84 does) unless
    `host_pass="pool"`, else a pool of Python threads. The attributes `host_pass` ("numba",
    "pool", or "inline" where ALE resized and only the stacking is left) and `host_threads` say
    what was chosen. Observations depend on neither: each env draws its noise from its own
    generator. `step_timings`
    adds up, over steps, the seconds spent in ALE's send and recv (`ale_s`: handing over the
    actions, then waiting for the emulation), on the background while ALE emulates
    (`ahead_s`), and in the rest of `step` (`host_s`).
    """

    def __init__(
        self,
        game: str = "Breakout",
        num_envs: int = 8,
        *,
        background: str = "none",
        split: str = "train",
        video_sources=None,
        preprocessing: str = "standard",
        sticky_actions: float | None = None,
        noop_max: int = 30,
        frame_skip: int = 4,
        maxpool: bool = True,
        pool: str = "gray",
        full_action_space: bool = False,
        max_episode_steps: int = 27_000,
        obs_size: int | tuple[int, int] = 84,
        stack: int = 4,
        num_threads: int = 0,
        host_threads: int = 0,
        host_pass: str = "auto",
        autoreset_mode: str = "same_step",
        noise: str = DEFAULT_NOISE,
        noise_sigma: float | None = None,
        seed: int = 0,
        video_alpha=1.0,
        frame_rate=1,
        num_videos=None,
    ):
        for name, value, choices in (("background", background, BACKGROUNDS), ("split", split, ("train", "test", "all")),
                                     ("autoreset_mode", autoreset_mode, tuple(_AUTORESET_MODES)),
                                     ("pool", pool, ("gray", "rgb")), ("host_pass", host_pass, _HOST_PASSES),
                                     ("preprocessing", preprocessing, tuple(PREPROCESSINGS))):
            if value not in choices:
                raise ValueError(f"{name} must be one of {choices}, got {value!r}")
        default_sticky, fire_reset, self.episodic_life, self.clip_rewards = PREPROCESSINGS[preprocessing]
        sticky_actions = default_sticky if sticky_actions is None else sticky_actions
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        if not 0.0 <= float(sticky_actions) <= 1.0:
            raise ValueError(f"sticky_actions is a probability in [0, 1], got {sticky_actions}")
        if int(stack) < 1 or int(frame_skip) < 1 or int(noop_max) < 0:
            raise ValueError(f"need stack >= 1, frame_skip >= 1, noop_max >= 0; got {stack}, {frame_skip}, {noop_max}")
        for name, value in (("num_threads", num_threads), ("host_threads", host_threads)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise ValueError(f"{name} must be an integer >= 0 (0: one per env, at most one "
                                 f"per CPU), got {value!r}")
        _check_dial(background, int(num_envs), video_alpha, frame_rate, num_videos, noise_sigma)
        rom_path(game)  # clear errors for unknown games and missing ROMs, before ale-py's
        from ale_py.vector_env import AtariVectorEnv  # noqa: PLC0415  (optional dependency)

        self.game = game
        self.num_envs = int(num_envs)
        self.background = background
        self.split = split
        self.preprocessing = preprocessing
        self.sticky_actions = float(sticky_actions)
        self.video_sources = video_sources
        self.autoreset_mode = autoreset_mode
        self.pool = pool
        self.obs_size = (obs_size, obs_size) if isinstance(obs_size, int) else tuple(obs_size)
        self.max_episode_steps = int(max_episode_steps)
        self._seeds = [int(seed)]  # the next reset's seed of each group of envs (see reset)
        # Nothing to composite: ALE resizes in its threads, as ale-py's own preprocessing.
        self._ale_resizes = background == "none" and pool == "gray"
        ale_shape = self.obs_size if self._ale_resizes else SCREEN_SHAPE
        self._ale = AtariVectorEnv(
            rom_id(game),
            self.num_envs,
            img_height=ale_shape[0],
            img_width=ale_shape[1],
            grayscale=pool == "gray",
            stack_num=1,
            frameskip=int(frame_skip),
            maxpool=bool(maxpool),
            noop_max=int(noop_max),
            use_fire_reset=fire_reset,
            episodic_life=False,
            reward_clipping=False,
            repeat_action_probability=float(sticky_actions),
            full_action_space=bool(full_action_space),
            max_num_frames_per_episode=self.max_episode_steps * int(frame_skip),
            num_threads=int(num_threads),
            autoreset_mode=_AUTORESET_MODES[autoreset_mode],
        )
        # gray screens at a size the exact kernel handles (84x84 does): jaxnat.atari.hostpass
        self._fused_plan = (area_plan(SCREEN_SHAPE, self.obs_size)
                            if pool == "gray" and not self._ale_resizes and host_pass == "auto"
                            and hostpass.usable() else None)
        self.host_pass = ("inline" if self._ale_resizes
                          else "numba" if self._fused_plan is not None else "pool")
        ale_threads = int(num_threads) or default_threads(self.num_envs)
        most = _DEFAULT_HOST_THREADS["numba" if self._fused_plan is not None else "pool"]
        chunks = int(host_threads) or min(ale_threads, most, self.num_envs // _ENVS_PER_HOST_CHUNK)
        self._runner = ChunkRunner(self.num_envs, max(1, chunks))
        self._background = make_background(
            background, self.num_envs, SCREEN_SHAPE, split=split, sources=video_sources,
            seed=self._seeds[0], noise=noise, noise_sigma=noise_sigma, runner=self._runner,
            **({"video_alpha": video_alpha, "frame_rate": frame_rate, "num_videos": num_videos}
               if background in ("video", "image") else {}),
        )
        self._stack = FrameStack(stack)
        self.step_timings = {"steps": 0, "ale_s": 0.0, "ahead_s": 0.0, "host_s": 0.0}
        n_actions = int(self._ale.single_action_space.n)
        self.single_action_space = spaces.Discrete(n_actions)
        self.single_observation_space = spaces.Box(0, 255, (*self.obs_size, int(stack)), np.uint8)
        self._env_ids = np.arange(self.num_envs)
        self._returns = np.zeros(self.num_envs, np.float64)
        self._lengths = np.zeros(self.num_envs, np.int32)
        self._last_returns = np.zeros(self.num_envs, np.float32)
        self._last_lengths = np.zeros(self.num_envs, np.int32)
        self._ended = np.zeros(self.num_envs, bool)  # next_step mode: reset at the next step
        self._game_ended = np.zeros(self.num_envs, bool)  # next_step mode: ... and ALE resets it
        self._lives = np.zeros(self.num_envs, np.int32)  # at the last step's end (episodic life)
        self._needs_reset = True
        self._pending = None  # step_async's timestamps until step_wait

    # -- the batched API ------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, seeds=None):
        """Reset every env. `seed` seeds env `i`'s emulator with `seed + i` and restarts the
        background draws from `seed`; without it, the first reset uses the constructor's seed
        and later ones continue the random streams (new games, new videos).

        `seeds` (G of them, G dividing `num_envs`): the batch as G equal groups of `n` envs,
        each reset as a batch of `n` envs of its own reset with `seed=seeds[g]` (group `g`'s
        env `j` is emulator `g * n + j`, seeded `seeds[g] + j`; its backgrounds draw from
        `seeds[g]`), and later resets without a seed continue each group's streams: the seeds
        of a run side by side, each playing the games of its run alone, on one ALE batch."""
        if seed is not None and seeds is not None:
            raise ValueError("reset takes seed (one batch) or seeds (one per group), not both")
        if seed is not None or seeds is not None:
            self._seeds = seed_groups(int(seed) if seeds is None else seeds, self.num_envs)[0]
            self._background.seed(self._seeds)
        size = self.num_envs // len(self._seeds)
        ale_seed = (self._seeds[0] if len(self._seeds) == 1
                    else np.concatenate([np.arange(s, s + size) for s in self._seeds]))
        self._seeds = [s + size for s in self._seeds]  # a later reset() without a seed starts new games
        raw, info = self._ale.reset(seed=ale_seed)
        self._background.reset(None)
        self._stack.allocate(self.num_envs, self.obs_size)
        obs, _ = self._observe(raw[:, 0], np.ones(self.num_envs, bool), None)
        self._returns[:] = 0
        self._lengths[:] = 0
        self._ended[:] = False
        self._game_ended[:] = False
        self._lives[:] = info["lives"]
        self._needs_reset = False
        return obs, {"lives": np.asarray(info["lives"])}

    def step(self, actions):
        """One agent step of every env; numpy in (`int[B]` actions) and out."""
        self.step_async(actions)
        return self.step_wait()

    def step_async(self, actions) -> None:
        """`step`'s first half: hands the actions to ALE's threads and returns while they
        emulate (after this step's background draws); `step_wait` returns the outcome. Between
        the two the caller may do other work, e.g. the policy call of another batch of envs
        (`jaxnat.atari.wrappers.PipelinedVecEnv`)."""
        if self._needs_reset:
            raise RuntimeError("Call reset() before step().")
        actions = np.asarray(actions)
        if actions.shape != (self.num_envs,) or not np.issubdtype(actions.dtype, np.integer):
            raise ValueError(
                f"actions must be integers of shape ({self.num_envs},), got {actions.dtype} "
                f"{actions.shape}"
            )
        if actions.min() < 0 or actions.max() >= self.single_action_space.n:
            raise ValueError(
                f"actions must lie in [0, {self.single_action_space.n}), got {actions.min()} .. "
                f"{actions.max()}"
            )
        if self._pending is not None:
            raise RuntimeError("step_async() twice without step_wait()")
        actions = actions.astype(np.int64)
        if self.episodic_life and self.autoreset_mode == "next_step":
            # the reset step after a lost life: NOOP, as baselines' EpisodicLifeEnv.reset
            actions[self._ended & ~self._game_ended] = 0
        start = time.perf_counter()
        self._ale.send(actions)
        sent = time.perf_counter()
        self._background.advance()  # next video frames, noise draws: while ALE emulates
        self._pending = (start, sent, time.perf_counter())

    def step_wait(self):
        """`step`'s second half: waits for ALE's emulation of the actions `step_async` sent and
        returns the step's outcome, as `step` does."""
        if self._pending is None:
            raise RuntimeError("step_wait() without step_async()")
        start, sent, advanced = self._pending
        self._pending = None
        waiting = time.perf_counter()
        raw, reward, terminated, truncated, ale_info = self._ale.recv()
        received = time.perf_counter()
        # ale-py's ordered mode (batch = all envs) puts env i in row i; checked, as it is cheap
        if (ale_info["env_id"] != self._env_ids).any():
            raise RuntimeError(f"ale-py returned envs out of order: {ale_info['env_id']}")
        reward = reward.astype(np.float32)
        game_done = terminated | truncated  # ALE's game ended (it resets the game)
        lives = np.asarray(ale_info["lives"])
        info = {"lives": lives}
        same_step = self.autoreset_mode == "same_step"
        if self.episodic_life:  # a lost life ends the training episode, the game goes on
            life_lost = (lives < self._lives) & (lives > 0) & ~game_done  # as EpisodicLifeEnv
            self._lives[:] = lives
            terminated = terminated | life_lost
            info["life_lost"] = life_lost
        done = terminated | truncated
        # same_step: ended envs start their next episode in this step's observation;
        # next_step: envs that ended last step were reset by this one.
        new_episode = done if same_step else self._ended
        new_game = game_done if same_step else self._game_ended  # backgrounds follow whole games
        final_backgrounds = self._background.reset(new_game) if new_game.any() else None
        ended = np.flatnonzero(done) if same_step else None
        final_screens = None
        if same_step and ended.size:
            over = game_done[ended]
            if over.all():
                final_screens = ale_info["final_obs"][ended, 0]
            else:  # a life lost: the game's own screen, no reset in between
                final_screens = raw[ended, 0]
                if over.any():
                    final_screens[over] = ale_info["final_obs"][ended[over], 0]
                if final_backgrounds is not None:  # backgrounds(ended), those of new games before
                    before, final_backgrounds = final_backgrounds, self._background.frames()[ended]
                    final_backgrounds[over] = before
        game_reward = reward
        if not same_step and self.episodic_life:  # the NOOP reset step of a lost life scores 0
            reward = np.where(self._ended & ~self._game_ended, np.float32(0), reward)
        if self.clip_rewards:
            info["unclipped_reward"] = reward
            reward = np.sign(reward)
        restarted = self._game_ended
        obs, final = self._observe(  # the bookkeeping overlaps the Python pool's chunks, if used
            raw[:, 0], new_episode, final_backgrounds, ended, final_screens,
            alongside=lambda: self._record_episodes(game_reward, game_done, restarted, info))
        if same_step:
            info["final_observation"] = final
        else:
            self._ended = done
            self._game_ended = game_done
        timings = self.step_timings
        timings["steps"] += 1
        timings["ale_s"] += sent - start + received - waiting
        timings["ahead_s"] += advanced - sent
        timings["host_s"] += time.perf_counter() - received
        return obs, reward, terminated, truncated, info

    @property
    def background_bank(self):
        """The `jaxnat.natural.FrameBank` (gray frames) the "video" and "image" backgrounds draw
        from; None for "none" and "noise"."""
        return getattr(self._background, "bank", None)

    @property
    def host_threads(self) -> int:
        """How many chunks of envs the host work is split into (the `host_threads` argument,
        or the default it resolved to)."""
        return self._runner.threads

    def close(self) -> None:
        self._ale.close()
        self._background.close()
        self._runner.close()

    def __repr__(self) -> str:
        return (
            f"NaturalAtariVecEnv({self.game}, num_envs={self.num_envs}, "
            f"background={self.background!r}, split={self.split!r})"
        )

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- internals ------------------------------------------------------------------------
    def _observe(self, screens: np.ndarray, new_episode: np.ndarray, final_backgrounds=None,
                 ended=None, final_screens=None, alongside=None) -> tuple[np.ndarray, np.ndarray]:
        """This step's observations from ALE's screens `[B, ...]` (left as they are; the envs
        `new_episode` start an episode: zeros before their frame), and the final observations:
        the envs `ended` (sorted indices, same-step autoreset) ended on `final_screens`, shown
        against `final_backgrounds` (the backgrounds they had before this step's background
        reset, None where it changed none: this step's). Returns `(obs, final)`; `final` is
        `obs` where no episode ended. `alongside()` (independent work) runs on the calling
        thread while the Python pool finishes its chunks, or after numba's pass."""
        backgrounds = self._background.frames()
        newest = self._stack.rotate()
        if ended is not None and ended.size:  # before clear_older: their older frames
            if final_backgrounds is None and backgrounds is not None:
                final_backgrounds = backgrounds[ended]  # noise: this step's draws
            final_frames = self._frames(final_screens, final_backgrounds)
            final_stacks = self._stack.with_newest(ended, final_frames)
        if new_episode.any():
            self._stack.clear_older(new_episode)
        obs = np.empty((self.num_envs, *self.obs_size, self._stack.depth), np.uint8)

        def rows(lo: int, hi: int) -> None:  # a chunk of envs: whole-chunk, GIL-free calls
            bg = None if backgrounds is None else backgrounds[lo:hi]
            self._frames(screens[lo:hi], bg, out=newest[lo:hi])
            self._stack.observation(slice(lo, hi), out=obs)

        if self._ale_resizes:  # nothing to composite or resize: one copy, one merge, no pool
            rows(0, self.num_envs)
        elif self._fused_plan is not None:  # the whole pass in one call on numba's threads
            hostpass.composite_resize_stack(
                screens, screens if backgrounds is None else backgrounds, self._stack.ring,
                self._stack.slots(), obs, self._fused_plan, self._runner.threads)
        else:
            self._runner.run(rows, alongside=alongside)
            alongside = None
        if alongside is not None:
            alongside()
        if ended is None or not ended.size:
            return obs, obs
        final = obs.copy()
        final[ended] = final_stacks
        return obs, final

    def _frames(self, screens: np.ndarray, backgrounds, out: np.ndarray | None = None) -> np.ndarray:
        """Pooled screens `[n, 210, 160]` gray or `[n, 210, 160, 3]` RGB, and gray backgrounds
        `[n, 210, 160]` (or None) -> composited, gray, resized `[n, h, w]` (into `out` when
        given). Screens ALE resized (background "none") are the frames already."""
        if self._ale_resizes:
            if out is not None:
                np.copyto(out, screens)
            return screens if out is None else out
        if self.pool == "rgb":  # the RGB mask: composite before grayscale
            screens, backgrounds = composite_gray(screens, backgrounds), None
        return composite_and_resize(screens, backgrounds, self.obs_size, out=out)

    def _record_episodes(self, reward, done, restarted, info) -> None:
        """Whole-game returns and lengths (rewards unclipped), PureJaxRL's info keys."""
        self._returns[restarted] = 0  # next_step mode: the restart step is not part of a game
        self._lengths[restarted] = 0
        live = ~restarted
        self._returns[live] += reward[live]
        self._lengths[live] += 1
        self._last_returns[done] = self._returns[done]
        self._last_lengths[done] = self._lengths[done]
        self._returns[done] = 0
        self._lengths[done] = 0
        info["returned_episode"] = done.copy()
        info["returned_episode_returns"] = self._last_returns.copy()
        info["returned_episode_lengths"] = self._last_lengths.copy()


def _check_dial(background: str, num_envs: int, video_alpha, frame_rate, num_videos, noise_sigma=None) -> None:
    """One-line `ValueError`s for the distraction dial: a value the background would ignore, or
    out of range (the ranges `num_videos` needs the bank for are the sampler's, when it loads)."""
    from jaxnat.natural.sampler import per_env_values

    if noise_sigma is not None:
        per_env_values("noise_sigma", noise_sigma, num_envs, low=0.0)
        if background != "noise":
            raise ValueError(f"noise_sigma needs background='noise', got background={background!r}")

    per_env_values("video_alpha", video_alpha, num_envs, low=0.0, high=1.0)
    per_env_values("frame_rate", frame_rate, num_envs, low=0, whole=True)
    if num_videos is not None:
        per_env_values("num_videos", num_videos, num_envs, low=1, whole=True)
    plain = {"video_alpha": np.all(np.asarray(video_alpha) == 1.0), "frame_rate": np.all(np.asarray(frame_rate) == 1),
             "num_videos": num_videos is None}
    needs = {"video_alpha": ("video", "image"), "frame_rate": ("video",), "num_videos": ("video", "image")}
    for name, is_plain in plain.items():
        if not is_plain and background not in needs[name]:
            wanted = " or ".join(repr(b) for b in needs[name])
            raise ValueError(f"{name} needs background={wanted}, got background={background!r}")
