"""`jaxnat.trained.load_policy` and `jaxnat eval`: a run's policy, loaded, acts as the trainer's
evaluation acts.

The contract: `policy.act(obs, key, greedy=g)` is the trainer's evaluation step
(`rollout.evaluate.make_evaluate`: `choose(act(network, params, normalize(normalizer, obs)),
key, g)`, then `env_action`) on `obs` as a batch of one, with `params, normalizer` the seed's
slice of `learner.policy_of(runner)` for the runner the trainer ended with. Greedy actions do
not depend on the batch, so `jax.vmap(policy.act)` gives the trainer's greedy actions for a
whole batch.

The runs are tiny (Classify/Digits-v0 PPO, 2 seeds x 2 envs x 8 steps, 2 updates; a vector-obs
probe for the observation normaliser), compiled with XLA's backend optimisation off, as
test_train's.
"""

import json
import re
import shutil
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnat
from jaxnat import cli, eval_run, registration
from jaxnat.agents import normalize
from jaxnat.agents.rollout import act, choose, env_action
from jaxnat.trained import LoadError, load_policy, play_episodes
from jaxnat.training import parse_args, train
from jaxnat.training.device_backend import compiled_program, make_envs
from jaxnat.training.spec import RunSpec

FAST = {"xla_backend_optimization_level": 0}
TINY = ["--env-id", "Classify/Digits-v0", "--algo", "ppo", "--seeds", "2", "--num-envs", "2", "--num-steps", "8",
        "--total-timesteps", "32", "--eval-every", "2", "--eval-episodes", "4", "--trunk", "mnist"]
README = Path(__file__).resolve().parents[1] / "README.md"


from test_train import _digits_available, needs_digits  # noqa: E402 (one data check for both files)


def _train(argv, run_dir):
    """(run_dir, the trainer's final vmapped runner, the trainer's learner)."""
    result = train(parse_args([*argv, "--run-dir", str(run_dir)]), compiler_options=FAST)
    assert result.complete
    spec = RunSpec.from_json(json.loads((run_dir / "config.json").read_text())["spec"])
    return run_dir, result.runner, compiled_program(spec, FAST).learner


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    if not _digits_available():
        pytest.skip("Classify/Digits-v0 data not installed")
    return _train(TINY, tmp_path_factory.mktemp("trained") / "digits")


def _trainer_actions(learner, runner, seed, obs, key, greedy, action_space):
    """The trainer's evaluation step (`make_evaluate`'s policy) on a batch `obs`, one key for the batch."""
    params, normalizer = jax.tree.map(lambda x: x[seed], learner.policy_of(runner))
    logits, _, _ = act(learner.network, params, normalize.normalize(normalizer, obs), None)
    return env_action(choose(logits, key, greedy), action_space)


def _test_observations(policy, n):
    obs, _ = jax.vmap(policy.env.reset, in_axes=(0, None))(jax.random.split(jax.random.key(7), n), policy.env_params)
    return obs


def _check_trainer_contract(policy, learner, runner, seed):
    space = policy.env.action_space(policy.env_params)
    obs = _test_observations(policy, 8)
    keys = jax.random.split(jax.random.key(3), 8)
    greedy = jax.vmap(lambda o, k: policy.act(o, k, greedy=True))(obs, keys)
    np.testing.assert_array_equal(greedy, _trainer_actions(learner, runner, seed, obs, keys[0], True, space))
    for i in range(3):
        sampled = policy.act(obs[i], keys[i])
        expected = _trainer_actions(learner, runner, seed, obs[i][None], keys[i], False, space)[0]
        np.testing.assert_array_equal(sampled, expected)


@needs_digits
@pytest.mark.parametrize("seed", [0, 1])
def test_loaded_policy_acts_as_the_trainer_evaluates(tiny_run, seed):
    run_dir, runner, learner = tiny_run
    policy = load_policy(run_dir, seed=seed, compiler_options=FAST)
    assert (policy.seed_index, policy.seed_value, policy.update, policy.split) == (seed, seed, 2, "test")
    assert policy.env_id == "Classify/Digits-v0" and policy.algo == "ppo" and policy.config.num_steps == 8
    assert policy.normalization is None  # images: raw observations
    expected = jax.tree.map(lambda x: x[seed], learner.policy_of(runner)[0])
    jax.tree.map(np.testing.assert_array_equal, policy.params, expected)
    # The test split, built as the trainer builds its evaluation env.
    spec = RunSpec.from_json(json.loads((run_dir / "config.json").read_text())["spec"])
    _, _, _, test_params = make_envs(spec)
    jax.tree.map(np.testing.assert_array_equal, policy.env_params, test_params)
    _check_trainer_contract(policy, learner, runner, seed)


@needs_digits
def test_greedy_is_deterministic_and_sampling_uses_the_key(tiny_run):
    policy = load_policy(tiny_run[0], compiler_options=FAST)
    obs = _test_observations(policy, 16)
    keys = jax.random.split(jax.random.key(0), 4)
    greedy = [jax.vmap(lambda o: policy.act(o, k, greedy=True))(obs) for k in keys]
    for other in greedy[1:]:
        np.testing.assert_array_equal(greedy[0], other)
    np.testing.assert_array_equal(policy.act(obs[0], keys[0]), policy.act(obs[0], keys[0]))
    one, two = (play_episodes(policy, jax.random.key(5), 6, greedy=True) for _ in range(2))
    for name in ("return", "length", "terminated"):
        np.testing.assert_array_equal(one[name], two[name])
    assert one["return"].shape == (6,)


@needs_digits
def test_split_train_is_the_training_env(tiny_run):
    policy = load_policy(tiny_run[0], split="train", compiler_options=FAST)
    _, train_params = jaxnat.make("Classify/Digits-v0", split="train")
    assert policy.split == "train"
    jax.tree.map(np.testing.assert_array_equal, policy.env_params, train_params)


def test_a_folder_without_a_run_is_refused_in_one_line(tmp_path, capsys):
    with pytest.raises(LoadError, match=r"is not a run directory: no config.json there"):
        load_policy(tmp_path)
    with pytest.raises(LoadError, match=r"is not a run directory: no such folder"):
        load_policy(tmp_path / "missing")
    assert cli.main(["eval", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxnat eval: error: ") and err.count("\n") == 1 and "no config.json" in err


@needs_digits
def test_bad_seed_index_split_and_missing_checkpoint_are_refused(tiny_run, tmp_path):
    run_dir = tiny_run[0]
    for seed in (2, -1):
        with pytest.raises(LoadError, match=rf"seed index {seed} is out of range: .* trained 2 seeds, indices 0 to 1$"):
            load_policy(run_dir, seed=seed)
    with pytest.raises(LoadError, match="split 'validation' is not one of test, train"):
        load_policy(run_dir, split="validation")
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(run_dir / "config.json", bare / "config.json")
    with pytest.raises(LoadError, match="has no checkpoint yet"):
        load_policy(bare)
    config = json.loads((run_dir / "config.json").read_text())
    config["spec"]["env_id"] = "NaturalAtari/Pong-v0"
    (bare / "config.json").write_text(json.dumps(config))
    with pytest.raises(LoadError, match=r"has no checkpoint of seed 0 \(index 0\) yet: checkpoints/seed_0 holds none"):
        load_policy(bare)  # a host run's checkpoints are per seed (tests/test_host_loop.py loads one)


@needs_digits
def test_jaxnat_eval_prints_the_mean_return_and_accuracy(tiny_run, capsys):
    assert cli.COMMANDS["eval"][0] == "jaxnat.eval_run"
    assert eval_run.main([str(tiny_run[0]), "--episodes", "8", "--seed-index", "1", "--greedy"],
                         compiler_options=FAST) == 0
    out = capsys.readouterr().out
    assert "checkpoint at update 2 · test split" in out
    assert re.search(r"8 episodes, greedy actions .*\n  return +[-+]\d+\.\d{4} \[[-+]\d", out), out
    assert re.search(r"  right label by episode end +\d+\.\d%", out), out
    assert re.search(r"  first-guess accuracy +\d+\.\d%", out), out


@needs_digits
def test_readme_snippet_runs(tiny_run, tmp_path, monkeypatch, capsys):
    """The README's "Loading a trained policy" code, as written, on the tiny run at the path
    its shell lines train to."""
    text = README.read_text()
    section = text[text.index("## Loading a trained policy"):]
    run_path = re.search(r"--run-dir (\S+)", section).group(1)
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    shutil.copytree(tiny_run[0], tmp_path / run_path)
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README.md (Loading a trained policy)", "exec"), {})  # noqa: S102
    assert "TrainedPolicy(ppo on Classify/Digits-v0" in capsys.readouterr().out


def test_the_observation_normaliser_is_applied(tmp_path, monkeypatch):
    """A vector-observation run normalises observations: the loaded policy reads them through
    the seed's frozen moments, as the trainer's evaluation does."""
    spec = registration.EnvSpec("Probe/LoadSign-v0", "jaxnat.agents.probes:SignProbe", {})
    monkeypatch.setitem(registration._REGISTRY, spec.id, spec)  # registered for this test only
    argv = ["--env-id", "Probe/LoadSign-v0", "--algo", "ppo", "--seeds", "2", "--num-envs", "4", "--num-steps", "4",
            "--total-timesteps", "32", "--eval-every", "2", "--eval-episodes", "4", "--trunk", "mlp",
            "--normalize-observations", "True"]
    run_dir, runner, learner = _train(argv, tmp_path / "probe")
    policy = load_policy(run_dir, seed=1, compiler_options=FAST)
    assert policy.normalization is not None and float(policy.normalization.obs.count) > 0
    expected = jax.tree.map(lambda x: x[1], learner.policy_of(runner)[1])
    jax.tree.map(np.testing.assert_array_equal, policy.normalization, expected)
    _check_trainer_contract(policy, learner, runner, 1)
    assert jnp.shape(policy.act(jnp.ones((1,)), jax.random.key(0))) == ()  # Discrete: one integer
