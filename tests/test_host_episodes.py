"""`trained.host_episodes` on a batch of games: rounds of the env's width, each env's first game
counted, the same games under one key, and a batch's greedy actions those of one game at a time."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

FAST = {"xla_backend_optimization_level": 0}  # compiles much faster on CPU
RUN = ["--env-id", "NaturalAtari/Breakout-v0", "--seeds", "1", "--total-timesteps", "32", "--num-envs", "2",
       "--num-steps", "8", "--num-minibatches", "2", "--eval-episodes", "1", "--eval-every", "1", "--algo", "ppo",
       "--env-kwargs", "obs_size=36", "num_threads=1", "background=noise"]


@pytest.fixture(scope="module")
def policy(tmp_path_factory):
    pytest.importorskip("ale_py")
    from jaxnat.train import main
    from jaxnat.trained import load_policy

    run_dir = tmp_path_factory.mktemp("host_episodes") / "run"
    assert main([*RUN, "max_episode_steps=12", "--run-dir", str(run_dir)], compiler_options=FAST) == 0
    policy = load_policy(run_dir, compiler_options=FAST)
    yield policy
    policy.env.close()


def test_a_batch_plays_rounds_of_its_width_the_same_games_under_one_key(policy):
    """5 games on 3 envs: two rounds (3 + 2 games), every game within the 12-step limit, the
    same results under the same key, recorded frames one per step plus the reset's."""
    import jaxnat
    from jaxnat.trained import host_episodes

    env = jaxnat.make_vec(policy.env_id, 3, split="test", **policy.env_kwargs)
    try:
        batch = dataclasses.replace(policy, env=env)
        first = host_episodes(batch, jax.random.key(7), 5, greedy=True)
        seen, again = host_episodes(batch, jax.random.key(7), 5, greedy=True, record=True)
    finally:
        env.close()
    assert {k: v.shape for k, v in first.items()} == {k: (5,) for k in ("return", "length", "terminated", "unfinished")}
    assert all(np.array_equal(first[k], again[k]) for k in first)
    assert first["length"].max() <= 12 and not first["unfinished"].any()
    assert [len(s) for s in seen] == (first["length"] + 1).tolist()


def test_a_batch_acts_as_the_policy_does_one_game_at_a_time(policy):
    """Greedy play on a 2-env batch (no background: its draws are the batch's): the first
    round's games are those of emulator seeds s and s + 1, each frame for frame the same game
    played alone on a one-game batch (games of other seeds differ from the first steps on)."""
    import jaxnat
    from jaxnat.trained import host_episodes

    kwargs = {**policy.env_kwargs, "background": "none"}
    env = jaxnat.make_vec(policy.env_id, 2, split="test", **kwargs)
    try:
        seen, together = host_episodes(dataclasses.replace(policy, env=env), jax.random.key(3), 2, greedy=True,
                                       record=True)
    finally:
        env.close()
    seed = int(jax.random.randint(jax.random.split(jax.random.key(3))[0], (2,), 0, 2 ** 30)[0])
    for offset in (0, 1):
        one = jaxnat.make_vec(policy.env_id, 1, split="test", **kwargs)
        try:
            obs, _ = one.reset(seed=seed + offset)
            frames, total, done = [obs[0]], 0.0, False
            while not done and len(frames) <= 12:
                action = np.asarray(policy.act(obs[0], jax.random.key(0), greedy=True)).reshape(1)
                obs, reward, term, trunc, _ = one.step(action)
                frames.append(obs[0])
                total, done = total + float(reward[0]), bool(term[0] or trunc[0])
        finally:
            one.close()
        assert together["return"][offset] == total and together["length"][offset] == len(frames) - 1
        assert np.array_equal(seen[offset], np.stack(frames))
    assert not np.array_equal(seen[0], seen[1])
