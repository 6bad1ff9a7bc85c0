"""Registry: make, close-match errors, kwargs routing, lazy optional dependencies."""

import jax
import numpy as np
import pytest

import jaxnat
from jaxnat.registration import MissingDependencyError, UnknownEnvError
from jaxnat.wrappers import AutoResetWrapper, VmapWrapper

CLASSIFY_IDS = {
    f"Classify/{n}-v0" for n in ["MNIST", "FashionMNIST", "Digits", "CIFAR10", "CIFAR100", "ImageFolder"]
}


def test_classify_ids_registered():
    assert CLASSIFY_IDS <= set(jaxnat.registered_envs())


def test_unknown_id_lists_close_matches():
    with pytest.raises(UnknownEnvError) as err:
        jaxnat.make("Classify/MNSIT-v0")
    assert "Classify/MNIST-v0" in str(err.value)
    with pytest.raises(UnknownEnvError, match="Classify/CIFAR10-v0"):
        jaxnat.make("classify/cifar10-v0")


def test_bad_id_format_rejected():
    with pytest.raises(ValueError, match="Namespace/Name-v0"):
        jaxnat.register("NoNamespace", "x:y")


@pytest.fixture
def toy_registered(toy_dataset):
    jaxnat.register("Test/Toy-v0", "jaxnat.vision_envs.classify:Classify", dataset=toy_dataset)
    yield "Test/Toy-v0"


def test_kwargs_go_to_constructor_or_params(toy_registered):
    env, params = jaxnat.make(toy_registered, start="center", w=2, max_steps_in_episode=7)
    assert isinstance(env, AutoResetWrapper)
    assert env.unwrapped.start == "center"
    assert int(params.window) == 2 and int(params.max_steps_in_episode) == 7
    raw, _ = jaxnat.make(toy_registered, autoreset=False)
    assert not isinstance(raw, AutoResetWrapper)


def test_unknown_kwarg_is_named(toy_registered):
    with pytest.raises(TypeError, match=r"\['windw'\].*window"):
        jaxnat.make(toy_registered, windw=3)


@pytest.mark.parametrize("kwargs, error, message", [
    ({"window": 11}, ValueError, r"Test/Toy-v0: window w=11 must be in \[1, 10\] for 12x10 images"),
    ({"window": 0}, ValueError, r"window w=0 must be in \[1, 10\]"),
    ({"max_steps_in_episode": 0}, ValueError, r"Test/Toy-v0: max_steps_in_episode \(M\) must be at least 1"),
    ({"M": 0}, ValueError, r"M=0 must be at least 1"),
    ({"window": "5"}, TypeError, r"Test/Toy-v0: window='5' must be a number"),
    ({"window": 2.5}, TypeError, r"window=2.5 must be a whole number"),
    ({"wrong_reward": None}, TypeError, r"wrong_reward=None must be a number"),
])
def test_params_are_checked_at_make_time(toy_registered, kwargs, error, message):
    """Traced params given to `make` get the same one-line errors as the constructor's `w=`:
    under jit an env cannot raise, so out-of-range values would silently misbehave."""
    with pytest.raises(error, match=message):
        jaxnat.make(toy_registered, **kwargs)


def test_params_in_range_and_arrays_pass(toy_registered):
    _, params = jaxnat.make(toy_registered, window=10, max_steps_in_episode=np.int32(3), correct_reward=2)
    assert int(params.window) == 10 and int(params.max_steps_in_episode) == 3 and float(params.correct_reward) == 2.0
    # Traced params stay vmappable: the check skips values it cannot see.
    env, params = jaxnat.make(toy_registered)
    windows = jax.numpy.array([1, 3])
    obs = jax.vmap(lambda w: env.reset(jax.random.key(0), params.replace(window=w))[0])(windows)
    assert obs.shape[0] == 2


def test_constructor_parameters_are_the_kwargs_make_routes_to_the_constructor(toy_registered):
    from jaxnat.registration import constructor_parameters

    parameters = constructor_parameters(toy_registered)
    assert {"dataset", "split", "start"} <= set(parameters) and "self" not in parameters
    assert parameters["start"].default == "random"
    assert "window" not in parameters  # a params field, not a constructor argument
    with pytest.raises(UnknownEnvError):
        constructor_parameters("Test/NoSuchEnv-v0")


def test_make_vec(toy_registered):
    env = jaxnat.make_vec(toy_registered, 6, window=2)
    assert isinstance(env, VmapWrapper)
    obs, state = env.reset(jax.random.key(0))
    assert obs.shape == (6, 12, 10, 3)
    # The params `make` built from the kwargs are the batch's defaults.
    assert int(env.default_params.window) == 2
    _, params = jaxnat.make(toy_registered, window=2)
    np.testing.assert_array_equal(obs, jax.vmap(jaxnat.make(toy_registered, window=2)[0].reset, in_axes=(0, None))(
        jax.random.split(jax.random.key(0), 6), params)[0])


def test_missing_optional_dependency_names_the_fix(tmp_path, monkeypatch):
    (tmp_path / "env_with_missing_dep.py").write_text("import no_such_dependency_xyz\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    jaxnat.register("Test/NeedsMissing-v0", "env_with_missing_dep:Env", extra="atari")
    with pytest.raises(MissingDependencyError, match=r"pip install 'jaxnat\[atari\]'"):
        jaxnat.make("Test/NeedsMissing-v0")
    from jaxnat.registration import constructor_parameters

    with pytest.raises(MissingDependencyError):
        constructor_parameters("Test/NeedsMissing-v0")


def test_import_stays_light():
    """`import jaxnat` must not pull in optional or heavy modules."""
    import subprocess
    import sys

    code = (
        "import sys, jaxnat; heavy = [m for m in ('optax', 'gymnasium', 'mujoco', 'ale_py', "
        "'cv2', 'jaxnat.vision_envs.classify') if m in sys.modules]; print(heavy)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_make_vec_of_a_host_batched_env_is_a_host_batched_env():
    pytest.importorskip("ale_py")
    from jaxnat.core import HostBatchedEnv

    env = jaxnat.make_vec("NaturalAtari/Pong-v0", 2, background="none", num_threads=1)
    try:
        assert isinstance(env, HostBatchedEnv) and env.num_envs == 2
        obs, info = env.reset(seed=0)
        assert obs.shape == (2, *env.single_observation_space.shape)
        obs, reward, terminated, truncated, info = env.step(np.zeros(2, np.int64))
        assert {"final_observation", "returned_episode", "returned_episode_returns"} <= set(info)
    finally:
        env.close()
    assert not isinstance(object(), HostBatchedEnv)


def test_close_matches_as_spelled_then_ignoring_case_without_repeats():
    from jaxnat.registration import close_matches
    names = ["Breakout", "SpaceInvaders", "Pong"]
    assert close_matches("Breakot", names) == ["Breakout"]  # found both ways, listed once
    assert close_matches("SPACEINVADER", names) == ["SpaceInvaders"]  # only ignoring case
    assert close_matches("Zzzz", names) == []


def test_jaxnat_envs_lists_every_registered_id_by_family(capsys):
    from jaxnat import cli

    assert cli.main(["envs"]) == 0
    lines = capsys.readouterr().out.splitlines()
    listed = {f"{line.split(' ')[0]}/{name}" for line in lines for name in line.split(": ", 1)[1].split()}
    assert listed == set(jaxnat.registered_envs())
    shown = [line.split(" ")[0] for line in lines]  # (other tests may have registered families of their own)
    assert shown == sorted(set(shown)) and {"Classify", "Localize", "MuJoCo", "NaturalAtari", "PixelMuJoCo"} <= set(shown)
    assert cli.main(["envs", "MuJoCo"]) == 0
    assert capsys.readouterr().out == "MuJoCo (4): Ant-v0 HalfCheetah-v0 Hopper-v0 Swimmer-v0\n"
    assert cli.main(["envs", "Clasify"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxnat envs: error: unknown family 'Clasify' (did you mean 'Classify'?); families: Classify, ")
    assert err.count("\n") == 1
