"""Seeds side by side on the host (`--host-seeds together`, issue #42): the on-policy host
learners with `seeds=S` train every seed from one stacked state on one batch of all their envs
(one ALE batch, each seed's envs reset as its batch alone: `NaturalAtariVecEnv.reset(seeds=)`),
and each seed's result is its run alone; `jaxnat train` checkpoints each seed's slice where a
one-seed run would, so `--resume`, `load_policy` and `jaxnat eval` read them as before.

Equality is to float tolerance, not bit for bit: the vmapped programs (a batched matmul where
the one-seed learner has a matmul) may round otherwise. The keys, the update counts and the
games are the same exactly (the same actions were sampled, or the episode statistics in the
metrics would differ).
"""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat.agents import a2c, ppo
from jaxnat.agents.acktr import ACKTRConfig, make_host_acktr
from jaxnat.agents.rollout import on_policy_host_learner, seed_slice, stack_seeds
from jaxnat.atari.wrappers import PipelinedVecEnv
from jaxnat.training.checkpoints import to_saveable
from test_host_loop import ALGO_ARGS, ATARI, CONFIGS, FAST, HostProbe

SEEDS = (3, 4)
TOLERANCE = {"atol": 1e-5, "rtol": 1e-5}


def _make(algo: str):
    if algo == "acktr":
        return make_host_acktr
    rule = {"ppo": ppo.RULE, "a2c": a2c.RULE}[algo]
    return lambda config, env, options, **kwargs: on_policy_host_learner(config, env, options, rule=rule, **kwargs)


def _assert_same_run(alone, alone_history, side, side_history, index):
    """Seed `index` of the side-by-side state and history against its run alone: keys and
    update counts equal, every other array (params, optimizer state) and metric to
    `TOLERANCE`; episode statistics (which the games decide) equal."""
    mine = seed_slice(side, index)
    np.testing.assert_array_equal(jax.random.key_data(mine.key), jax.random.key_data(alone.key))
    assert int(mine.update) == int(alone.update)
    a, b = jax.tree.leaves(to_saveable(alone.learner)), jax.tree.leaves(to_saveable(mine.learner))
    assert len(a) == len(b)
    for x, y in zip(a, b):
        np.testing.assert_allclose(np.asarray(y), np.asarray(x), **TOLERANCE)
    assert len(side_history) == len(alone_history)
    for row, alone_row in zip(side_history, alone_history):
        assert row.keys() == alone_row.keys()
        for name in ("episodes", "episode_return", "episode_length"):
            np.testing.assert_equal(row[name][index], alone_row[name])
        for name, value in alone_row.items():
            np.testing.assert_allclose(row[name][index], value, atol=1e-4, rtol=1e-4)


def test_split_keys_splits_one_key_or_each_seed_s_key_as_its_own():
    """`split_keys`: one key splits as `jax.random.split`; stacked keys `[S]` each as that
    seed's key alone, so a seed's stream side by side is its stream alone."""
    from jaxnat.agents.rollout.stacked import split_keys

    key = jax.random.key(3)
    expected = jax.random.key_data(jax.random.split(key))
    np.testing.assert_array_equal(np.stack([jax.random.key_data(k) for k in split_keys(key)]), expected)
    keys = stack_seeds([jax.random.key(seed) for seed in SEEDS])
    both = [jax.random.key_data(k) for k in split_keys(keys)]
    for index, seed in enumerate(SEEDS):
        np.testing.assert_array_equal(np.stack([k[index] for k in both]),
                                      jax.random.key_data(jax.random.split(jax.random.key(seed))))


@pytest.mark.parametrize("algo", ["ppo", "a2c", "acktr"])
def test_seeds_side_by_side_learn_as_each_seed_alone_on_probes(algo):
    """On a probe (mlp trunk, fast): two seeds side by side (a `PipelinedVecEnv` of one batch per
    seed, which the learner takes as one batch of both seeds' envs) end with each seed's params, optimizer state, key and update count of that seed's
    learner alone, given the same key; the metrics are each seed's."""
    config = (ACKTRConfig(num_envs=4, num_steps=8, trunk="mlp") if algo == "acktr" else CONFIGS[algo])
    config = config.replace(total_timesteps=config.num_envs * config.num_steps * 3)
    make = _make(algo)
    alone = [make(config, HostProbe("sign", 4), FAST).train(jax.random.key(seed)) for seed in SEEDS]
    learner = make(config, PipelinedVecEnv([HostProbe("sign", 4) for _ in SEEDS]), FAST, seeds=len(SEEDS))
    assert learner.seeds == 2
    state, history = learner.train(stack_seeds([jax.random.key(seed) for seed in SEEDS]))
    assert np.asarray(state.update).tolist() == [3, 3] and history[0]["episode_return"].shape == (2,)
    for index, (alone_state, alone_history) in enumerate(alone):
        _assert_same_run(alone_state, alone_history, state, history, index)


@pytest.mark.parametrize("background, parts", [("none", 1), ("noise", 1), ("noise", 2)])
def test_seeds_side_by_side_train_breakout_as_each_seed_alone(background, parts):
    """Breakout on the host, as `jaxnat train` builds it (`host_backend.make_train_env` and
    `make_learner`): PPO on 2 seeds side by side, 2 envs each, ends with each seed's state of
    its run alone (the same game seeds: each seed's envs reset as that seed's lone batch, its
    noise background included) to `TOLERANCE`; in 2 pipelined parts (one env of each seed a
    part), each seed's run alone in 2 parts."""
    pytest.importorskip("ale_py")
    from jaxnat.training.host_backend import make_learner, make_train_env

    env_id = "NaturalAtari/Breakout-v0"
    kwargs = {"obs_size": 36, "num_threads": 1, "max_episode_steps": 10, "background": background}
    config = ppo.PPOConfig(total_timesteps=2 * 8 * 2, num_envs=2, num_steps=8, num_minibatches=2, trunk="atari")
    alone = []
    for seed in SEEDS:
        env = make_train_env(env_id, 2, kwargs, parts)
        alone.append(make_learner("ppo", config, env, FAST).train(jax.random.key(seed)))
        env.close()
    env = make_train_env(env_id, 2, kwargs, parts, seeds=len(SEEDS))
    # one ALE batch of every seed's envs, or one per part
    assert env.num_envs == 4 and len(getattr(env, "parts", [env])) == parts
    state, history = make_learner("ppo", config, env, FAST, seeds=len(SEEDS)).train(
        stack_seeds([jax.random.key(seed) for seed in SEEDS]))
    env.close()
    # 10-step games in 8-step rollouts: the first games end in update 2, so the episode
    # statistics there are each seed's own games (the same actions were taken).
    assert all(h[1]["episodes"] == 2 for _, h in alone)
    for index, (alone_state, alone_history) in enumerate(alone):
        _assert_same_run(alone_state, alone_history, state, history, index)


def test_seeds_side_by_side_make_one_batch_of_all_their_envs(monkeypatch):
    """`make_train_env(..., seeds=S)`: one batch of S x `num_envs` envs of the train split, the
    other kwargs (ALE threads included) as given, a per-env dial's values for every seed,
    rewards clipped; with `parts` P, P such batches of S x `num_envs / P` (a
    `PipelinedVecEnv` of `groups=S`); not with devices."""
    import jaxnat
    from jaxnat.atari.wrappers import ClipRewardWrapper
    from jaxnat.training.host_backend import make_train_env

    made = []

    def make_vec(env_id, num_envs, **kwargs):
        made.append((num_envs, kwargs))
        return HostProbe("sign", num_envs)

    monkeypatch.setattr(jaxnat, "make_vec", make_vec)
    env = make_train_env("NaturalAtari/Breakout-v0", 4, {"num_threads": 5, "obs_size": 36}, seeds=3)
    assert isinstance(env, ClipRewardWrapper) and env.num_envs == 12
    assert made == [(12, {"split": "train", "num_threads": 5, "obs_size": 36})]
    made.clear()
    env = make_train_env("NaturalAtari/Breakout-v0", 4, {"num_threads": 5}, parts=2, seeds=3)
    assert isinstance(env, PipelinedVecEnv) and env.groups == 3 and [p.num_envs for p in env.parts] == [6, 6]
    assert made == [(6, {"split": "train", "num_threads": 5})] * 2
    made.clear()  # a per-env dial follows its envs: each batch the values of the envs it holds, for every seed
    make_train_env("NaturalAtari/Breakout-v0", 4, {"video_alpha": [0.1, 0.2, 0.3, 0.4], "frame_rate": 2}, seeds=3)
    make_train_env("NaturalAtari/Breakout-v0", 4, {"video_alpha": [0.1, 0.2, 0.3, 0.4]}, parts=2, seeds=3)
    assert [kwargs["video_alpha"] for _, kwargs in made] == [[0.1, 0.2, 0.3, 0.4] * 3, [0.1, 0.2] * 3, [0.3, 0.4] * 3]
    assert made[0][1]["frame_rate"] == 2
    with pytest.raises(ValueError, match=r"video_alpha: one value for every env or one per env of a seed \(4\), got 12"):
        make_train_env("NaturalAtari/Breakout-v0", 4, {"video_alpha": [0.5] * 12}, seeds=3)
    with pytest.raises(ValueError, match="seeds side by side step one batch of all their envs on one device"):
        make_train_env("NaturalAtari/Breakout-v0", 4, {}, devices=1, seeds=2)
    with pytest.raises(ValueError, match="parts=3 must be >= 1 and divide num_envs=4"):
        make_train_env("NaturalAtari/Breakout-v0", 4, {}, parts=3, seeds=2)


def test_host_backend_trains_every_seed_in_one_group():
    """`HostBackend` with `host_seeds="together"`: one group of every seed on one ALE batch (in
    env parts: a part of every seed's envs each),
    checkpointed per seed, metrics `[seeds, updates]` and test scores `[seeds]` (each seed's
    own params, scored with its own evaluation key); sequential: a group per seed."""
    pytest.importorskip("ale_py")
    from jaxnat.training import RunSpec
    from jaxnat.training.host_backend import HostBackend

    kwargs = {"obs_size": 36, "num_threads": 1, "max_episode_steps": 10}
    config = ppo.PPOConfig(total_timesteps=2 * 8 * 2, num_envs=2, num_steps=8, num_minibatches=2, trunk="atari")
    backend = HostBackend(RunSpec("NaturalAtari/Breakout-v0", kwargs, "ppo", config, 3, 5, 1, 2,
                                  host_seeds="together"), FAST)
    try:
        assert backend.groups == [[5, 6, 7]] and backend.checkpoints_per_seed
        assert backend.env.num_envs == 6 and not isinstance(backend.env, PipelinedVecEnv)
        assert backend.learner.seeds == 3
        assert backend.checkpoint_dir([6]) == "checkpoints/seed_6"
        state = backend.init([5, 6, 7])
        assert backend.update_of(state) == 0
        backend.begin([5, 6, 7], state)
        calls = []
        state, metrics = backend.chunk(state, 1, lambda update, row: calls.append((update, type(row["entropy"]))))
        assert backend.update_of(state) == 1 and calls == [(1, float)] * 3
        assert metrics["entropy"].shape == (3, 1)
        scores = backend.evaluate([5, 6, 7], state)
        assert scores["greedy_return"].shape == scores["sampled_return"].shape == (3,)
    finally:
        backend.close()
    pipelined = HostBackend(RunSpec("NaturalAtari/Breakout-v0", kwargs, "ppo", config, 3, 5, 1, 2, env_parts=2,
                                    host_seeds="together"), FAST)
    try:  # together in 2 parts: each part one ALE batch of one env of every seed
        assert pipelined.groups == [[5, 6, 7]] and pipelined.learner.seeds == 3
        assert pipelined.env.groups == 3 and [part.num_envs for part in pipelined.env.parts] == [3, 3]
    finally:
        pipelined.close()
    sequential = HostBackend(RunSpec("NaturalAtari/Breakout-v0", kwargs, "ppo", config, 2, 0, 1, 2), FAST)
    try:
        assert sequential.groups == [[0], [1]] and not sequential.checkpoints_per_seed
        assert sequential.env.num_envs == 2 and not isinstance(sequential.env, PipelinedVecEnv)
        assert sequential.learner.seeds is None
    finally:
        sequential.close()


def _rows(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_jaxnat_train_seeds_together_checkpoints_per_seed_and_resumes(tmp_path, capsys):
    """`jaxnat train` (PPO's default: together) trains both seeds in one group: after the first
    chunk both have update 1 in metrics.jsonl and a checkpoint in `checkpoints/seed_<s>/`, each
    a one-seed learner's `HostState` (it restores into `make_learner`'s own state, as
    `load_policy` does, and equals the side-by-side state's slice); the run resumes, finishes
    both, evaluates each seed before and after; a run stopped between two seeds' saves (seed
    1's last checkpoint gone) resumes both seeds from their last common update; `load_policy`
    and `jaxnat eval` load a seed."""
    pytest.importorskip("ale_py")
    import shutil

    from jaxnat import eval_run
    from jaxnat.train import main
    from jaxnat.trained import load_policy
    from jaxnat.training import RunSpec
    from jaxnat.training import host_backend as host
    from jaxnat.training.checkpoints import Checkpoints

    run_dir = tmp_path / "run"
    argv = [*ATARI, "--algo", "ppo", *ALGO_ARGS["ppo"], "--run-dir", str(run_dir)]
    assert main(argv, compiler_options=FAST, stop_after_chunks=1) == 0
    assert [(r["seed"], r["update"]) for r in _rows(run_dir / "metrics.jsonl")] == [(0, 1), (1, 1)]
    assert [(r["seed"], r["update"]) for r in _rows(run_dir / "eval.jsonl")] == [(0, 0), (1, 0)]
    spec = RunSpec.from_json(json.loads((run_dir / "config.json").read_text())["spec"])
    assert spec.host_seeds == "together"
    assert "side by side" in capsys.readouterr().out

    # Each seed's folder holds what a one-seed run would: it restores into the one-seed state.
    env = host.make_train_env(spec.env_id, spec.config.num_envs, spec.env_kwargs)
    learner = host.make_learner("ppo", spec.config, env, FAST)
    saved = []
    for seed in (0, 1):
        checkpoints = Checkpoints(run_dir / "checkpoints" / f"seed_{seed}")
        state, meta = checkpoints.restore(learner.init(jax.random.key(seed)))
        checkpoints.close()
        assert meta["update"] == 1 and int(state.update) == 1
        saved.append(state)
    env.close()
    assert not np.array_equal(*(np.asarray(jax.tree.leaves(s.learner.params)[0]) for s in saved))

    assert main(["--resume", str(run_dir)], compiler_options=FAST) == 0
    assert [(r["seed"], r["update"]) for r in _rows(run_dir / "metrics.jsonl")] == [(0, 1), (1, 1), (0, 2), (1, 2)]
    assert [(e["seed"], e["update"]) for e in _rows(run_dir / "eval.jsonl")] == [(0, 0), (1, 0), (0, 2), (1, 2)]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["complete"] and all(np.isfinite(summary["metrics"]["test_sampled_return"]["per_seed"]))

    # Stopped between the seeds' saves of update 2: both resume from update 1 and redo update 2.
    shutil.rmtree(run_dir / "checkpoints" / "seed_1" / "2")
    assert main(["--resume", str(run_dir)], compiler_options=FAST) == 0
    assert "resumed from checkpoint at update 1" in capsys.readouterr().out
    assert [(r["seed"], r["update"]) for r in _rows(run_dir / "metrics.jsonl")] == [(0, 1), (1, 1), (0, 2), (1, 2)]
    for seed in (0, 1):
        checkpoints = Checkpoints(run_dir / "checkpoints" / f"seed_{seed}")
        assert checkpoints.latest_step() == 2
        checkpoints.close()

    policy = load_policy(run_dir, seed=1, compiler_options=FAST)
    assert (policy.update, policy.seed_value) == (2, 1)
    policy.env.close()
    assert eval_run.main([str(run_dir), "--seed-index", "1", "--episodes", "2", "--greedy"], compiler_options=FAST) == 0
    assert "seed 1 · checkpoint at update 2" in capsys.readouterr().out


def test_host_seeds_defaults_and_records():
    """Unset, `--host-seeds` is together for the on-policy learners on one batch, sequential for
    DQN and with env parts (as runs with parts trained before); together with parts is taken as
    asked; a run spec written before the setting reads as None (sequential)."""
    from jaxnat.training import RunSpec
    from jaxnat.training.host_backend import SIDE_BY_SIDE_ALGORITHMS, check_host_seeds

    assert SIDE_BY_SIDE_ALGORITHMS == ("ppo", "a2c", "acktr")
    assert [check_host_seeds(None, algo, 1) for algo in ("ppo", "a2c", "acktr", "dqn")] == \
        ["together"] * 3 + ["sequential"]
    assert check_host_seeds(None, "ppo", 2) == "sequential"
    assert check_host_seeds("sequential", "ppo", 1) == "sequential"
    assert check_host_seeds("together", "ppo", 2) == "together"
    saved = RunSpec("NaturalAtari/Breakout-v0", {}, "ppo", ppo.PPOConfig(trunk="atari"), 2, 0, 1, 10,
                    host_seeds="together").to_json()
    assert RunSpec.from_json(saved).host_seeds == "together"
    del saved["host_seeds"]
    assert RunSpec.from_json(saved).host_seeds is None


@pytest.mark.parametrize("argv, message", [
    (["--algo", "dqn", "--host-seeds", "together"],
     "--host-seeds together applies to ppo, a2c, acktr: dqn's host learner trains one seed at a time"),
    (["--host-seeds", "both"], "--host-seeds takes together or sequential, got 'both'"),
    (["--env-id", "Classify/Digits-v0", "--host-seeds", "sequential"],
     "--host-seeds applies to host-batched envs (NaturalAtari/*); Classify/Digits-v0 is a JAX env"),
])
def test_host_seeds_errors(argv, message, tmp_path, capsys):
    pytest.importorskip("ale_py")
    from jaxnat.train import main

    assert main(["--env-id", "NaturalAtari/Breakout-v0", "--env-kwargs", "obs_size=36", "--num-envs", "4", *argv,
                 "--run-dir", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxnat train: error: ") and message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "run").exists()


def test_resume_keeps_the_way_seeds_train():
    from jaxnat.training import RunSpec, TrainError, parse_args
    from jaxnat.training.rundir import check_resume_args

    saved = RunSpec("NaturalAtari/Breakout-v0", {}, "ppo", ppo.PPOConfig(trunk="atari"), 2, 0, 1, 10,
                    host_seeds="together").to_json()
    check_resume_args(parse_args(["--resume", "run", "--host-seeds", "together"]), saved)
    with pytest.raises(TrainError, match=r"^--host-seeds 'sequential' \(the run: 'together'\) conflicts"):
        check_resume_args(parse_args(["--resume", "run", "--host-seeds", "sequential"]), saved)


def test_learner_api_refuses_bad_combinations():
    """One-line `ValueError`s: seeds side by side with devices, DQN side by side, and an env
    that is not one batch of seeds x `num_envs` envs (or parts: one per seed, or of `groups`)."""
    from jaxnat.training.host_backend import make_learner

    config = CONFIGS["ppo"]
    env = PipelinedVecEnv([HostProbe("sign", 4) for _ in SEEDS])
    with pytest.raises(ValueError, match="seeds side by side train on one device"):
        make_learner("ppo", config, env, FAST, devices=1, seeds=2)
    with pytest.raises(ValueError, match="seeds side by side train on one device"):
        on_policy_host_learner(config, env, FAST, devices=1, rule=ppo.RULE, seeds=2)
    with pytest.raises(ValueError, match="dqn's host learner trains one seed at a time"):
        make_learner("dqn", config, env, FAST, seeds=2)
    with pytest.raises(ValueError, match=r"one batch of seeds x config.num_envs = 3 x 4 envs .* has \[4, 4\] envs"):
        on_policy_host_learner(config, env, FAST, rule=ppo.RULE, seeds=3)
    with pytest.raises(ValueError, match=r"= 2 x 4 envs .*; the env has 4 envs$"):
        on_policy_host_learner(config, HostProbe("sign", 4), FAST, rule=ppo.RULE, seeds=2)
    with pytest.raises(ValueError, match=r"the env has \[2, 6\] envs"):  # parts: one per seed
        on_policy_host_learner(config, PipelinedVecEnv([HostProbe("sign", 2), HostProbe("sign", 6)]), FAST,
                               rule=ppo.RULE, seeds=2)
    with pytest.raises(ValueError, match=r"the env has 8 envs"):  # one part of both seeds: neither layout
        on_policy_host_learner(config, PipelinedVecEnv([HostProbe("sign", 8)]), FAST, rule=ppo.RULE, seeds=2)


def test_seeds_at_different_updates_are_refused():
    learner = on_policy_host_learner(CONFIGS["ppo"], PipelinedVecEnv([HostProbe("sign", 4) for _ in SEEDS]), FAST,
                                     rule=ppo.RULE, seeds=2)
    state = learner.init(stack_seeds([jax.random.key(seed) for seed in SEEDS]))
    with pytest.raises(ValueError, match=r"different updates \(\[0, 1\]\)"):
        learner.run(state._replace(update=jnp.asarray([0, 1], jnp.int32)))
