"""Gymnasium adapter: spaces, next-step autoreset, determinism, action checks, one compile."""

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from jaxnat import registration
from jaxnat.compat import GymnasiumVectorEnv, make_gymnasium_vec
from jaxnat.datasets import ImageDataset
from jaxnat.vision_envs.classify import DOWN, RIGHT, Classify
from jaxnat.wrappers import AutoResetWrapper, LogWrapper, VmapWrapper

N = 4  # envs
M = 5  # time limit
WINDOW = 9 * 255  # channel sum of one revealed 3x3 window


@pytest.fixture(scope="module")
def env():
    """conftest's `toy_dataset`, built once so that the module shares one adapter (compiling
    takes most of these tests' time): pixel (r, c) of image i is 1 + 120 i + 10 r + c."""
    r, c = np.meshgrid(np.arange(12), np.arange(10), indexing="ij")
    images = np.stack([1 + i * 120 + r * 10 + c for i in range(3)]).astype(np.uint8)[..., None]
    dataset = ImageDataset("toy", "train", images, np.arange(3, dtype=np.int32), ("0", "1", "2"))
    return Classify(dataset, w=3, M=M)


@pytest.fixture(scope="module")
def vec(env):
    """Shared by the tests below; each starts with `reset`."""
    return GymnasiumVectorEnv(env, num_envs=N, seed=0)


def labels(obs):
    """Each env's label, read off a revealed pixel: pixel (r, c) of image i is
    (1 + 120 i + 10 r + c) mod 256, and image i has label i."""
    out = []
    for o in obs:
        r, c = np.argwhere(o[..., 1] == 255)[0]
        out.append(next(i for i in range(3) if (1 + 120 * i + 10 * r + c) % 256 == o[r, c, 0]))
    return np.array(out)


def act(move, label):
    return np.stack([np.full(N, move), label], axis=1)


def revealed(obs):
    return obs[..., 1].astype(np.int64).sum(axis=(1, 2))


def test_spaces(vec):
    assert vec.num_envs == N
    assert vec.metadata["autoreset_mode"] == gymnasium.vector.AutoresetMode.NEXT_STEP
    assert vec.metadata["render_modes"] == ["rgb_array"] and vec.render() is None
    assert isinstance(vec.single_action_space, gymnasium.spaces.MultiDiscrete)
    np.testing.assert_array_equal(vec.single_action_space.nvec, [4, 3])
    # Gymnasium batches MultiDiscrete into an integer Box (as SyncVectorEnv does).
    assert vec.action_space.shape == (N, 2)
    np.testing.assert_array_equal(vec.action_space.high, [[3, 2]] * N)
    box = vec.single_observation_space
    assert isinstance(box, gymnasium.spaces.Box)
    assert box.shape == (12, 10, 3) and box.dtype == np.uint8
    assert box.low.min() == 0 and box.high.max() == 255
    assert vec.observation_space.shape == (N, 12, 10, 3)
    assert vec.observation_space.dtype == np.uint8


def test_truncation_then_next_step_reset(vec):
    obs, info = vec.reset(seed=0)
    assert info == {} and obs.dtype == np.uint8 and obs.shape == (N, 12, 10, 3)
    for t in range(1, M + 1):
        obs, reward, terminated, truncated, info = vec.step(act(DOWN, (labels(obs) + 1) % 3))
        assert reward.dtype == np.float64 and terminated.dtype == truncated.dtype == np.bool_
        np.testing.assert_allclose(reward, -0.1, rtol=1e-6)
        assert not terminated.any()
        assert truncated.all() == (t == M) and truncated.any() == (t == M)
        assert info == {}
    # The next step resets: the (right-label) action is ignored, one window is revealed.
    obs, reward, terminated, truncated, info = vec.step(act(DOWN, labels(obs)))
    np.testing.assert_array_equal(revealed(obs), WINDOW)
    np.testing.assert_array_equal(reward, 0.0)
    assert not terminated.any() and not truncated.any() and info == {}
    # A full episode follows: the reset step did not count as a step.
    for t in range(1, M + 1):
        obs, _, _, truncated, _ = vec.step(act(DOWN, (labels(obs) + 1) % 3))
        assert truncated.all() == (t == M) and truncated.any() == (t == M)


def test_termination_then_next_step_reset_per_env(vec):
    obs, _ = vec.reset(seed=1)
    right = labels(obs)
    ends = np.array([True, True, False, False])
    obs, reward, terminated, truncated, _ = vec.step(act(RIGHT, np.where(ends, right, right + 1) % 3))
    np.testing.assert_array_equal(terminated, ends)
    assert not truncated.any()
    np.testing.assert_allclose(reward, np.where(ends, 1.0, -0.1), rtol=1e-6)
    before = revealed(obs)
    obs, reward, terminated, truncated, _ = vec.step(act(DOWN, (labels(obs) + 1) % 3))
    np.testing.assert_allclose(reward, np.where(ends, 0.0, -0.1), rtol=1e-6)
    assert not terminated.any() and not truncated.any()
    np.testing.assert_array_equal(revealed(obs)[ends], WINDOW)
    assert (revealed(obs)[~ends] >= before[~ends]).all()


def rollout(vec, seed, steps=12):
    rng = np.random.default_rng(0)
    out = [vec.reset(seed=seed)[0]]
    for _ in range(steps):
        out.extend(vec.step(rng.integers(0, [4, 3], size=(N, 2)))[:4])
    return out


def test_determinism(env, vec):
    a, b = GymnasiumVectorEnv(env, num_envs=N, seed=7), GymnasiumVectorEnv(env, num_envs=N, seed=7)
    for x, y in zip(rollout(a, seed=None), rollout(b, seed=None)):
        np.testing.assert_array_equal(x, y)
    again = rollout(vec, seed=3)
    for x, y in zip(again, rollout(vec, seed=3)):
        np.testing.assert_array_equal(x, y)
    assert any(not np.array_equal(x, y) for x, y in zip(again, rollout(vec, seed=4)))


def test_sampled_rollout_stays_in_spaces(vec):
    vec.action_space.seed(0)
    obs, _ = vec.reset(seed=0)
    assert vec.observation_space.contains(obs)
    ended = 0
    for _ in range(3 * M):
        obs, reward, terminated, truncated, info = vec.step(vec.action_space.sample())
        assert vec.observation_space.contains(obs)
        assert reward.shape == terminated.shape == truncated.shape == (N,)
        ended += int((terminated | truncated).sum())
    assert ended > 0


def test_actions_are_checked(env, vec):
    with pytest.raises(RuntimeError, match="reset"):
        GymnasiumVectorEnv(env, num_envs=N).step(np.zeros((N, 2), np.int64))
    vec.reset(seed=0)
    with pytest.raises(ValueError, match=r"expected shape \(4, 2\)"):
        vec.step(np.zeros((N - 1, 2), np.int64))
    with pytest.raises(ValueError, match=r"expected shape \(4, 2\)"):
        vec.step(np.zeros(2, np.int64))
    # Outside the space: refused, as Gymnasium's envs do, not rounded or remapped.
    with pytest.raises(TypeError, match="must be integers"):
        vec.step(np.full((N, 2), 1.0))
    for bad in ([4, 0], [0, 3], [-1, 0]):  # MultiDiscrete([4, 3]): 3 labels
        actions = np.zeros((N, 2), np.int64)
        actions[2] = bad
        with pytest.raises(ValueError, match=r"of env 2 is \[.*\], outside MultiDiscrete\(\[4, 3\]\)"):
            vec.step(actions)
    vec.step(np.tile([3, 2], (N, 1)))  # the largest valid action


def test_wrappers(env, vec):
    stripped = GymnasiumVectorEnv(AutoResetWrapper(env), num_envs=N)
    for x, y in zip(rollout(stripped, seed=2), rollout(vec, seed=2)):
        np.testing.assert_array_equal(x, y)
    for bad in (LogWrapper(AutoResetWrapper(env)), VmapWrapper(env, N)):
        with pytest.raises(ValueError, match="without its"):
            GymnasiumVectorEnv(bad, num_envs=N)


def test_step_info_in_vector_layout(env):
    logged = GymnasiumVectorEnv(LogWrapper(env), num_envs=N)
    obs, _ = logged.reset()
    _, _, terminated, _, info = logged.step(act(RIGHT, labels(obs)))
    assert terminated.all()
    assert info["returned_episode"].shape == (N,) and info["returned_episode"].all()
    assert info["_returned_episode"].all()
    _, _, _, _, info = logged.step(act(RIGHT, labels(obs)))
    assert not info["_returned_episode"].any(), "envs that reset did not step"


def test_make_gymnasium_vec(monkeypatch, toy_dataset):
    spec = registration.EnvSpec("Test/Toy-v0", Classify, {"dataset": toy_dataset})
    monkeypatch.setitem(registration._REGISTRY, spec.id, spec)
    vec = make_gymnasium_vec(spec.id, 2, seed=0, w=3, M=M, wrong_reward=-0.5)
    assert "Classify[toy/train]" in repr(vec) and vec.num_envs == 2
    obs, _ = vec.reset()
    assert obs.shape == (2, 12, 10, 3)
    _, reward, _, _, _ = vec.step(np.stack([[DOWN, DOWN], (labels(obs) + 1) % 3], axis=1))
    np.testing.assert_allclose(reward, -0.5)
    vec.close()


def test_partial_reset_with_reset_mask(vec):
    """`reset(options={"reset_mask": m})` restarts the masked envs at once (no wasted next step)
    and leaves the others as they were."""
    obs, _ = vec.reset(seed=5)
    ends = np.array([True, False, True, False])
    obs, _, terminated, _, _ = vec.step(act(DOWN, np.where(ends, labels(obs), labels(obs) + 1) % 3))
    np.testing.assert_array_equal(terminated, ends)
    stepped = obs.copy()
    obs, info = vec.reset(options={"reset_mask": ends})
    assert info == {}
    np.testing.assert_array_equal(obs[~ends], stepped[~ends])
    np.testing.assert_array_equal(revealed(obs)[ends], WINDOW)
    # The masked envs' pending autoreset is cancelled: this step is a real step for every env.
    obs, reward, terminated, _, _ = vec.step(act(RIGHT, labels(obs)))
    np.testing.assert_allclose(reward, 1.0, rtol=1e-6)
    assert terminated.all()
    for bad in (ends.astype(np.int64), ends[:2], list(ends)):
        with pytest.raises(ValueError, match="reset_mask"):
            vec.reset(options={"reset_mask": bad})
    with pytest.raises(ValueError, match="no reset options but 'reset_mask'"):
        vec.reset(options={"other": 1})
    with pytest.raises(RuntimeError, match="before a partial reset"):
        GymnasiumVectorEnv(vec.jax_env, num_envs=N).reset(options={"reset_mask": ends})


def test_step_compiles_once(vec):
    """Runs last: the shared adapter has stepped and reset through every test above."""
    vec.reset(seed=0)
    for t in range(3 * M):
        vec.step(np.tile([t % 4, t % 3], (N, 1)).astype(np.int64 if t % 2 else np.int32))
    vec.reset(seed=1)
    vec.step(np.zeros((N, 2), np.int64))
    # Partial resets here too: with pytest-xdist the other tests may run in another process.
    for first in (True, False):
        vec.reset(options={"reset_mask": np.arange(N) % 2 == first})
    assert vec._step_fn._cache_size() == 1
    assert vec._reset_fn._cache_size() == 1
    assert vec._reset_some_fn._cache_size() == 1
