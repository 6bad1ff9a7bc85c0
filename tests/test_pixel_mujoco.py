"""PixelMuJoCo's pixel layer (jaxnat/mjx_pixel/pixel.py): frame skip and stack, floor modes,
the noise observation, video split, and the env contract.

Most tests drive the pixel layer with `Sliding`, a stand-in for the MJX physics: Gymnasium's
HalfCheetah in one pose (placed by MuJoCo C) slid along x. It compiles in seconds on a 2-core
CPU, where MJX's step takes minutes. The registered env with real MJX physics is run once, at
the end, on a tiny batch.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

mujoco = pytest.importorskip("mujoco")

from jaxnat import spaces  # noqa: E402
from jaxnat.core import Environment, EnvParams, EnvState  # noqa: E402
from jaxnat.mjx_pixel.pixel import PixelMuJoCo  # noqa: E402
from jaxnat.testing import check_env  # noqa: E402

SIZE = 32
VIDEO = dict(floor="video", video_shape=(32, 32), video_max_frames=64)  # a small video floor


@struct.dataclass
class Pose:
    """The fields of mjx.Data the pixel layer reads."""

    qpos: jax.Array
    geom_xpos: jax.Array
    geom_xmat: jax.Array
    subtree_com: jax.Array


@struct.dataclass
class SlidingState(EnvState):
    data: Pose


@struct.dataclass
class SlidingParams(EnvParams):
    stop_x: float = 1e9


class Sliding(Environment):
    """Stand-in physics: Gymnasium's HalfCheetah, joints bent (a fixed pose from mj_forward),
    starting at x ~ U(-1, 1) and moving +0.1 m along x per step whatever the action; reward =
    x after the step; terminated once x > `params.stop_x`."""

    def __init__(self):
        import importlib.resources

        path = importlib.resources.files("gymnasium") / "envs/mujoco/assets/half_cheetah.xml"
        self.model = mujoco.MjModel.from_xml_path(str(path))
        data = mujoco.MjData(self.model)
        data.qpos[3:] = np.linspace(-0.5, 0.5, self.model.nq - 3)
        mujoco.mj_forward(self.model, data)
        self._pose = Pose(*(jnp.asarray(a, jnp.float32) for a in (
            data.qpos, data.geom_xpos, data.geom_xmat.reshape(-1, 3, 3), data.subtree_com)))

    @property
    def default_params(self):
        return SlidingParams()

    def action_space(self, params):
        return spaces.Box(-1.0, 1.0, (6,), jnp.float32)

    def observation_space(self, params):
        return spaces.Box(-np.inf, np.inf, (self.model.nq,), jnp.float32)

    def place(self, x):
        """The pose with the root at x (everything shifted by x along the world x axis)."""
        shift = jnp.zeros(3).at[0].set(x)
        p = self._pose
        return Pose(p.qpos.at[0].set(x), p.geom_xpos + shift, p.geom_xmat, p.subtree_com + shift)

    def reset_env(self, key, params):
        data = self.place(jax.random.uniform(key, (), minval=-1.0, maxval=1.0))
        return data.qpos, SlidingState(time=jnp.zeros((), jnp.int32), data=data)

    def step_env(self, key, state, action, params):
        x = state.data.qpos[0] + 0.1
        data = self.place(x)
        return data.qpos, state.replace(data=data), x, x > params.stop_x, {"x": x}


@pytest.fixture(scope="module")
def physics():
    return Sliding()


def make_env(physics, **kwargs):
    kwargs.setdefault("height", SIZE)
    kwargs.setdefault("width", SIZE)
    return PixelMuJoCo(physics=physics, **kwargs)


@pytest.fixture(scope="module")
def checker(physics):
    env = make_env(physics)
    params = env.default_params
    return env, params, jax.jit(env.reset), jax.jit(env.step)


def test_contract(physics):
    env = make_env(physics)
    check_env(env, env.default_params, num_steps=6, num_envs=2)


def test_spaces_and_defaults(checker):
    env, params, *_ = checker
    assert env.observation_space(params).shape == (SIZE, SIZE, 4)  # gray, stack of 4
    assert env.observation_space(params).dtype == jnp.uint8
    assert params.max_steps_in_episode == 250  # Gymnasium's 1000 env steps / frame skip 4
    rgb = make_env(env.physics, grayscale=False, frame_stack=2)
    assert rgb.observation_space(rgb.default_params).shape == (SIZE, SIZE, 6)


def test_frame_skip_sums_rewards_and_the_stack_shifts(checker):
    env, params, reset, step = checker
    obs, state = reset(jax.random.key(0), params)
    # At reset the stack is four copies of the first frame.
    for k in range(1, 4):
        np.testing.assert_array_equal(obs[..., k], obs[..., 0])
    frames = [obs[..., 0]]
    for t in range(3):
        x0 = float(state.physics.data.qpos[0])
        obs, state, reward, *_ = step(jax.random.key(t), state, jnp.zeros(6), params)
        # Four repeats of +0.1 m; the reward is the sum of the four x positions.
        assert float(state.physics.data.qpos[0]) == pytest.approx(x0 + 0.4, abs=1e-5)
        assert float(reward) == pytest.approx(sum(x0 + 0.1 * k for k in range(1, 5)), abs=1e-4)
        frames.append(obs[..., 3])
        np.testing.assert_array_equal(obs[..., :3], np.stack(
            [frames[max(i, 0)] for i in range(len(frames) - 4, len(frames) - 1)], -1))
    # The frame is a render of the state after the last repeat (eager here, so float rounding
    # may move a value by one level).
    np.testing.assert_allclose(obs[..., 3], env.render(None, state.physics, params)[..., 0], atol=1)


@pytest.mark.parametrize("channels,depth,packed", [(1, 4, True), (1, 4, False), (3, 2, False), (1, 3, False)])
def test_frame_stack_layouts_give_the_last_frames_oldest_first(channels, depth, packed):
    # Two envs under jit(vmap), each with its own episode starts; the reference is a list of
    # the last `depth` frames, refilled with copies of the first frame at each start.
    from jaxnat.mjx_pixel.stack import FrameStack

    fs = FrameStack(5, 3, channels, depth)
    assert fs.packed == (channels == 1 and depth == 4)
    fs.packed = packed  # the bytes layout is the general one: it must agree where both apply
    steps = 9
    frames = np.random.default_rng(0).integers(0, 256, (steps, 2, 5, 3, channels), np.uint8)
    fresh = np.zeros((steps, 2), bool)
    fresh[0] = True
    fresh[[4, 5], [0, 1]] = True  # a new episode at step 4 in env 0, at step 5 in env 1
    observe = jax.jit(jax.vmap(fs.observation))
    push = jax.jit(jax.vmap(fs.push))
    history = jnp.stack([fs.empty()] * 2)
    expected = [None, None]
    for t in range(steps):
        if t:
            history = push(history, frames[t - 1], fresh[t - 1])
        obs = np.asarray(observe(history, frames[t], fresh[t]))
        assert obs.dtype == np.uint8 and obs.shape == (2, 5, 3, channels * depth)
        for e in range(2):
            expected[e] = [frames[t, e]] * depth if fresh[t, e] else expected[e][1:] + [frames[t, e]]
            np.testing.assert_array_equal(obs[e], np.concatenate(expected[e], -1), err_msg=f"t={t}")


def test_frame_stack_rejects_empty_shapes():
    from jaxnat.mjx_pixel.stack import FrameStack

    with pytest.raises(ValueError, match="must be >= 1"):
        FrameStack(84, 84, 1, 0)


def test_termination_stops_the_repeats(checker):
    env, params, reset, step = checker
    obs, state = reset(jax.random.key(0), params)
    x0 = float(state.physics.data.qpos[0])
    # Repeats reach x0 + 0.1, + 0.2, + 0.3 > stop_x: terminated; the fourth never runs.
    params = params.replace(physics=params.physics.replace(stop_x=x0 + 0.25))
    obs, state, reward, terminated, truncated, info = step(
        jax.random.key(1), state, jnp.zeros(6), params)
    assert bool(terminated) and not bool(truncated)
    assert float(state.physics.data.qpos[0]) == pytest.approx(x0 + 0.3, abs=1e-5)
    assert float(reward) == pytest.approx(3 * x0 + 0.6, abs=1e-4)
    assert float(info["x"]) == pytest.approx(x0 + 0.3, abs=1e-5)


def floor_mask(env, physics_state):
    data = physics_state.data
    pos, mat = env.camera.pose(data)
    hit = env.renderer.cast(pos, mat, data.geom_xpos, data.geom_xmat)
    return np.asarray(hit.geom == env.table.floor)


@pytest.fixture(scope="module")
def video_env(physics):
    natural = pytest.importorskip("jaxnat.natural")
    try:
        natural.default_video_paths()
    except Exception as err:  # opencv-doc missing
        pytest.skip(str(err))
    return make_env(physics, **VIDEO)


def test_floor_modes_change_only_floor_pixels(checker, video_env):
    env, params, reset, _ = checker
    _, state = reset(jax.random.key(3), params)
    floor = floor_mask(env, state.physics)
    assert 0.2 < floor.mean() < 0.9
    base = np.asarray(env.render(None, state.physics, params))
    noise_env = make_env(env.physics, floor="noise")
    cursor = state.cursor
    _, video_state = video_env.reset(jax.random.key(3), video_env.default_params)
    others = [
        np.asarray(noise_env.render(jax.random.key(1), state.physics, noise_env.default_params)),
        np.asarray(video_env.render(None, state.physics, video_env.default_params, video_state.cursor)),
    ]
    assert cursor is None
    for other in others:
        changed = np.any(other != base, axis=-1)
        assert changed.any()
        assert not (changed & ~floor).any(), "a non-floor pixel changed with the floor mode"
        assert changed[floor].mean() > 0.5


def test_video_floor_is_fixed_to_the_world(video_env):
    env, params = video_env, video_env.default_params
    _, state = env.reset(jax.random.key(0), params)
    tile = float(params.video_tile)

    def frame_at(x):
        physics = state.physics.replace(data=env.physics.place(x))
        return np.asarray(env.render(None, physics, params, state.cursor))

    # The camera follows the robot: moving by exactly one video tile shows the same picture
    # (the floor repeats every tile); by half a tile, the same robot over a shifted floor.
    np.testing.assert_array_equal(frame_at(2.0 + tile), frame_at(2.0))
    half = frame_at(2.0 + tile / 2) != frame_at(2.0)
    floor = floor_mask(env, state.physics)
    assert half[..., 0][floor].mean() > 0.3 and not half[..., 0][~floor].any()


def test_video_advances_one_frame_per_agent_step_and_splits_are_disjoint(video_env, physics):
    env, params = video_env, video_env.default_params
    _, state = env.reset(jax.random.key(0), params)
    offset = int(state.cursor.offset)
    length = int(params.video.lengths[int(state.cursor.video)])
    _, state, *_ = env.step(jax.random.key(1), state, jnp.zeros(6), params)
    assert int(state.cursor.offset) == (offset + 1 if offset + 1 < length else 0)
    test_env = make_env(physics, floor="video", video_split="test", video_shape=(32, 32),
                        video_max_frames=64)
    train_names = set(params.video.names)
    test_names = set(test_env.default_params.video.names)
    assert train_names and test_names and not train_names & test_names


def noise_law_checks(values, noise=None):
    """The draws follow the named pixel-noise law; None (no `noise=`) is `DEFAULT_NOISE`, the
    law of every family's noise control (N(0, 1) * 50 clipped at 0, truncated to uint8)."""
    from jaxnat.natural import DEFAULT_NOISE, noise_law
    from jaxnat.testing import check_noise_law

    law = noise_law(DEFAULT_NOISE if noise is None else noise)
    check_noise_law(values, law.probabilities(), f"PixelMuJoCo noise={noise!r}")


def law_kwargs(noise):
    return {} if noise is None else {"noise": noise}


@pytest.mark.parametrize("noise", [None, "centred"])
def test_noise_observation_is_fresh_gaussian_noise(physics, noise):
    env = make_env(physics, observation="noise", **law_kwargs(noise))
    params = env.default_params
    obs, state = env.reset(jax.random.key(0), params)
    assert obs.shape == (SIZE, SIZE, 4) and obs.dtype == jnp.uint8
    step = jax.jit(env.step)
    draws = [np.asarray(obs)]
    for t in range(1, 33):
        obs2, state, *_ = step(jax.random.key(t), state, jnp.zeros(6), params)
        draws.append(np.asarray(obs2))
    noise_law_checks(np.stack(draws), noise)
    obs, obs2 = draws[-2], draws[-1]
    assert (obs != obs2).mean() > 0.4, "noise must be redrawn every step"
    # Consecutive stacked frames are independent too (not a shifted stack).
    assert (obs2[..., :3] != obs[..., 1:]).mean() > 0.4


@pytest.mark.parametrize("noise", [None, "centred"])
def test_noise_floor_follows_the_noise_law(checker, noise):
    env, params, reset, _ = checker
    _, state = reset(jax.random.key(3), params)
    noise_env = make_env(env.physics, floor="noise", **law_kwargs(noise))
    floor = floor_mask(env, state.physics)
    render = jax.jit(noise_env.render)
    frames = [np.asarray(render(jax.random.key(k), state.physics, params))[..., 0][floor]
              for k in range(64)]
    noise_law_checks(np.concatenate(frames), noise)
    assert (frames[0] != frames[1]).mean() > 0.4


def compiled_renders(fn, *args):
    """Square roots the renderer's ops leave in the compiled program of `fn`: proportional to
    the number of frames it renders (XLA has dropped dead renders by then)."""
    from jaxnat.mjx_pixel.render import RENDER_SCOPE

    text = jax.jit(fn).lower(*args).compile().as_text()
    return sum(1 for line in text.splitlines() if RENDER_SCOPE in line and " sqrt(" in line)


def compiled_render_paths(fn, *args):
    """`compiled_renders` of `fn` split by XLA's conditionals: `(renders outside any
    conditional, [[renders of each branch] per conditional])`, a callee's renders counted with
    its caller."""
    import re

    from jaxnat.mjx_pixel.render import RENDER_SCOPE

    text = jax.jit(fn).lower(*args).compile().as_text()
    computations, name, entry = {}, None, None
    for line in text.splitlines():
        start = re.match(r"^(ENTRY )?%?([\w.\-]+) \(.*\{$", line)
        if start:
            name = start.group(2)
            computations[name] = []
            entry = name if start.group(1) else entry
        elif line == "}":
            name = None
        elif name:
            computations[name].append(line)

    def paths(computation):
        own, conditionals = 0, []
        for line in computations[computation]:
            own += RENDER_SCOPE in line and " sqrt(" in line
            branches = re.search(r"branch_computations=\{([^}]*)\}", line)
            if branches:
                conditionals.append([total(b.strip().lstrip("%")) for b in branches.group(1).split(",")])
                continue
            for callee in re.findall(r"(?:calls|to_apply|body|condition)=%([\w.\-]+)", line):
                callee_own, callee_conditionals = paths(callee)
                own, conditionals = own + callee_own, conditionals + callee_conditionals
        return own, conditionals

    def total(computation):
        own, conditionals = paths(computation)
        return own + sum(max(branches) for branches in conditionals)

    return paths(entry)


@pytest.fixture(scope="module")
def autoreset_batch(physics):
    """An autoresetting batch of 6 where some envs end at the first step (stop_x = 0). The XLA
    renderer on any backend: the render counter reads its ops in the compiled program."""
    from jaxnat.wrappers import AutoResetWrapper

    env = make_env(physics, render_kernel="xla")
    params = env.default_params
    params = params.replace(physics=params.physics.replace(stop_x=0.0))
    keys = jax.random.split(jax.random.key(5), 6)
    _, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    return env, AutoResetWrapper(env), params, state


def test_autoreset_renders_one_frame_per_step(autoreset_batch):
    env, auto, params, state = autoreset_batch
    keys = jax.random.split(jax.random.key(6), 6)
    args = (keys, state, jnp.zeros((6, 6)), params)
    one = compiled_renders(jax.vmap(env.observe, in_axes=(0, None)), state, params)
    assert one > 0

    def step(*a):  # what a training loop keeps: everything but info
        return auto.step(*a)[:5]

    def two_renders(key, state, action, params):  # a step and a reset, observations selected
        key_step, key_reset = jax.random.split(key)
        obs, *_, terminated, truncated, _ = env.step(key_step, state, action, params)
        return jnp.where(terminated | truncated, env.reset(key_reset, params)[0], obs)

    batched = lambda f: jax.vmap(f, in_axes=(0, 0, 0, None))  # noqa: E731
    assert compiled_renders(batched(two_renders), *args) == 2 * one  # the counter can tell
    # PixelMuJoCo's `gated_autoreset`: the step is one conditional on how many envs of the
    # batch ended (none; a few, in two tiers of rows: those reset alone; more: all), nothing
    # rendered outside it, one frame rendered in each branch.
    assert compiled_render_paths(batched(step), *args) == (0, [[one, one, one, one]])
    # Reading the final observation needs the stepped frame too, but only in a step where
    # some env ended (of those rows alone in the compacted branches: one more render op);
    # where none did, the final observation is the one frame rendered.
    final = batched(lambda *a: (lambda out: (out[0], out[5]["final_observation"]))(auto.step(*a)))
    assert compiled_render_paths(final, *args) == (0, [[one, 2 * one, 2 * one, 2 * one]])


def test_gated_autoreset_in_a_batch_where_no_episode_ends(physics):
    """No env of the batch ends: the observations and final observations are the stepped
    env's own, bit for bit, as where some do (the test below)."""
    from jaxnat.wrappers import AutoResetWrapper

    env = make_env(physics, render_kernel="xla")
    params = env.default_params  # stop_x = 1e9: no episode ends in these steps
    auto = AutoResetWrapper(env)
    _, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(jax.random.key(5), 4), params)
    step = jax.jit(jax.vmap(auto.step, in_axes=(0, 0, 0, None)))
    raw_step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    for t in range(2):
        keys = jax.random.split(jax.random.key(20 + t), 4)
        key_step = jax.vmap(jax.random.split)(keys)[:, 0]
        obs, next_state, _, terminated, truncated, info = step(keys, state, jnp.ones((4, 6)), params)
        raw_obs = raw_step(key_step, state, jnp.ones((4, 6)), params)[0]
        assert not np.asarray(terminated | truncated).any()
        np.testing.assert_array_equal(obs, raw_obs)
        np.testing.assert_array_equal(info["final_observation"], raw_obs)
        state = next_state


def test_autoreset_observations_are_those_of_step_or_reset(autoreset_batch):
    """The observation rendered after the select equals the stepped env's observation where
    the episode goes on and the fresh episode's first observation where it ended."""
    env, auto, params, state = autoreset_batch
    step = jax.jit(jax.vmap(auto.step, in_axes=(0, 0, 0, None)))
    raw_step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    reset = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))
    ended = 0
    for t in range(3):
        keys = jax.random.split(jax.random.key(10 + t), 6)
        key_step, key_reset = jax.vmap(jax.random.split, out_axes=1)(keys)
        obs, next_state, _, terminated, truncated, info = step(keys, state, jnp.zeros((6, 6)), params)
        raw_obs = raw_step(key_step, state, jnp.zeros((6, 6)), params)[0]
        first_obs = reset(key_reset, params)[0]
        done = np.asarray(terminated | truncated)
        ended += done.sum()
        expected = np.where(done[:, None, None, None], first_obs, raw_obs)
        np.testing.assert_array_equal(obs, expected)
        np.testing.assert_array_equal(info["final_observation"], raw_obs)
        state = next_state
    assert 0 < ended < 18, "some episodes should end and some go on"


@pytest.mark.parametrize("layout", ["flat", "nested"])
def test_autoreset_compacted_and_select_branches_agree(autoreset_batch, layout):
    """The compacted reset (only the ended rows reset and render their final frame) and the
    select (every row computes both) give the same step, bit for bit, flat and under nested
    vmap (seeds x envs: each inner batch compacts its own rows); so does `reset_share=None`."""
    from jaxnat.wrappers import AutoResetWrapper

    env, _, params, state = autoreset_batch
    keys = jax.random.split(jax.random.key(6), 6)
    action = jnp.linspace(-1.0, 1.0, 36).reshape(6, 6)
    outs = {}
    # Every batch compacted; one row compacted, a select past it; the default tiers; none.
    for share in (1.0, 1e-6, (0.125, 0.375), None):
        auto = AutoResetWrapper(env, reset_share=share)
        step = jax.vmap(auto.step, in_axes=(0, 0, 0, None))
        if layout == "nested":
            fold = lambda x: x.reshape(2, 3, *x.shape[1:])  # noqa: E731
            out = jax.jit(jax.vmap(step, in_axes=(0, 0, 0, None)))(
                *jax.tree.map(fold, (keys, state, action)), params)
            out = jax.tree.map(lambda x: x.reshape(6, *x.shape[2:]), out)
        else:
            out = jax.jit(step)(keys, state, action, params)
        outs[share] = out
    done = np.asarray(outs[1.0][3] | outs[1.0][4])
    assert done.sum() >= 2 and not done.all(), "some rows should end, more than one"
    if layout == "nested":
        assert done.reshape(2, 3).sum(1).max() >= 2, "an inner batch should fall to the select"
    for other in (1e-6, (0.125, 0.375), None):
        for a, b in zip(jax.tree.leaves(outs[1.0]), jax.tree.leaves(outs[other])):
            np.testing.assert_array_equal(a, b)


def test_state_observation(physics):
    env = make_env(physics, observation="state")
    params = env.default_params
    obs, state = env.reset(jax.random.key(0), params)
    assert env.observation_space(params).shape == (physics.model.nq,)
    np.testing.assert_array_equal(obs, state.physics.data.qpos)


def test_constant_observation_space(physics):
    env = make_env(physics, observation="constant")
    space = env.observation_space(env.default_params)
    assert isinstance(space, spaces.Box) and space.shape == (1,) and space.dtype == jnp.float32
    assert np.all(space.low == 0) and np.all(space.high == 0)
    from jaxnat.agents.normalize import wants_normalization

    assert wants_normalization(space), "a 1-D Box: the agents pick an MLP"


def test_constant_observation_is_constant_and_physics_is_state_s(physics):
    """observation="constant": zeros [1] at every reset and step, under jit and vmap; rewards,
    termination, truncation, info and the physics are observation="state"'s under the same
    keys and actions (stop_x and a 5-step limit: both episode ends happen; the agent step moves 0.4 m)."""
    envs = {name: make_env(physics, observation=name) for name in ("constant", "state")}
    params = envs["state"].default_params
    params = params.replace(physics=params.physics.replace(stop_x=1.2), max_steps_in_episode=5)
    from jaxnat.wrappers import AutoResetWrapper

    runs = {}
    for name, env in envs.items():
        auto = AutoResetWrapper(env)
        reset = jax.jit(jax.vmap(auto.reset, in_axes=(0, None)))
        step = jax.jit(jax.vmap(auto.step, in_axes=(0, 0, 0, None)))
        obs, state = reset(jax.random.split(jax.random.key(0), 8), params)
        observations, outputs = [obs], []
        for t in range(8):
            obs, state, *out = step(jax.random.split(jax.random.key(t + 1), 8), state, jnp.ones((8, 6)), params)
            observations.append(obs)
            outputs.append((out, state.physics))
        runs[name] = observations, outputs
    observations = np.stack(runs["constant"][0])
    assert observations.shape == (9, 8, 1) and observations.dtype == np.float32
    np.testing.assert_array_equal(observations, 0.0)

    def outcome(out):  # everything a step gives but the observations
        (reward, terminated, truncated, info), physics_state = out
        return reward, terminated, truncated, {k: v for k, v in info.items() if k != "final_observation"}, physics_state

    for constant, state in zip(runs["constant"][1], runs["state"][1]):
        for a, b in zip(jax.tree.leaves(outcome(constant)), jax.tree.leaves(outcome(state))):
            np.testing.assert_array_equal(a, b)
    steps = runs["constant"][1]
    assert any(np.any(out[0][1]) for out in steps) and any(np.any(out[0][2]) for out in steps), \
        "both termination and the time limit should occur"
    # Unbatched, unjitted: the same constant at reset and step.
    env = envs["constant"]
    obs, state = env.reset(jax.random.key(3), params)
    obs2, *_ = env.step(jax.random.key(4), state, jnp.zeros(6), params)
    for o in (obs, obs2):
        assert o.shape == (1,) and o.dtype == jnp.float32 and float(o[0]) == 0.0


def test_bad_arguments_are_clear_errors(physics):
    with pytest.raises(ValueError, match="observation must be one of"):
        make_env(physics, observation="rgb")
    with pytest.raises(ValueError, match="floor must be one of"):
        make_env(physics, floor="grass")
    with pytest.raises(ValueError, match="frame_skip"):
        make_env(physics, frame_skip=0)
    with pytest.raises(ValueError, match="robot must be one of"):
        PixelMuJoCo(robot="humanoid")


def test_registered_env_with_mjx_physics():
    """The real thing once: `jaxnat.make` with MJX physics and autoreset, a batch of two,
    pixels in the space, finite rewards, deterministic under a key, the camera on the torso
    (Swimmer: the fewest geoms and no contacts, so the fastest to compile). Every mode's full
    contract is checked above with the stand-in physics; the robots share this code."""
    import jaxnat

    env, params = jaxnat.make("PixelMuJoCo/Swimmer-v0", height=SIZE, width=SIZE)
    assert env.unwrapped.physics.model.nbody == 4 and params.max_steps_in_episode == 250
    space = env.observation_space(params)
    keys = jax.random.split(jax.random.key(0), 2)
    reset = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))
    step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    obs, state = reset(keys, params)
    actions = jnp.array([[1.0, -1.0], [-1.0, 1.0]])
    outputs = [step(keys, state, actions, params) for _ in range(2)]
    obs1, state1, reward, terminated, truncated, _ = outputs[0]
    for a, b in zip(jax.tree.leaves(outputs[0][:5]), jax.tree.leaves(outputs[1][:5])):
        np.testing.assert_array_equal(a, b)
    assert obs1.shape == (2, *space.shape) and obs1.dtype == space.dtype
    assert reward.dtype == jnp.float32 and np.all(np.isfinite(reward))
    assert not np.any(terminated) and not np.any(truncated)
    # The swimmer moved: the newest frame differs from the reset frame, the older ones shifted.
    assert np.any(obs1[..., 3] != obs[..., 3])
    np.testing.assert_array_equal(obs1[..., :3], obs[..., 1:])
    for robot in ("Ant", "HalfCheetah", "Hopper"):  # built (no compile): registered and wired
        other, other_params = jaxnat.make(f"PixelMuJoCo/{robot}-v0", autoreset=False)
        assert other.observation_space(other_params).shape == (84, 84, 4)
