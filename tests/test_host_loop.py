"""The host driver (jaxnat.agents.rollout.host_steps) and its learners on probe envs behind a numpy batched API,
and `jaxnat train` on NaturalAtari (a real ROM: ale-py ships them) with checkpoints and resume.

The probes are jaxnat's own (jaxnat.agents.probes); `HostProbe` steps a batch of them through
a jitted function and hands numpy arrays out, as `NaturalAtariVecEnv` does (same-step autoreset,
`final_observation` and PureJaxRL's episode keys in `info`), so the loop is tested on envs whose
right answers are known.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat.agents import a2c, dqn, ppo
from jaxnat.agents.dqn_host import make_host_dqn
from jaxnat.agents.rollout import EnvStep, evaluate_host, host_steps_pipelined, on_policy_host_learner
from jaxnat.atari.wrappers import PipelinedVecEnv
from jaxnat.agents.probes import make_probe
from jaxnat.wrappers import LogWrapper

CONFIGS = {
    "ppo": ppo.PPOConfig(total_timesteps=4096, num_envs=4, num_steps=16, update_epochs=2,
                         num_minibatches=2, trunk="mlp", lr=3e-3),
    "a2c": a2c.A2CConfig(total_timesteps=4096, num_envs=4, num_steps=8, trunk="mlp", lr=1e-3),
}
RULES = {"ppo": ppo.RULE, "a2c": a2c.RULE}
# As tests/test_dqn.py's probe config, with one env step of 4 envs per update.
DQN = dqn.DQNConfig(total_timesteps=4096, num_envs=4, num_steps=1, gradient_steps=1, buffer_size=1024,
                    optimizer="adam", lr=3e-3, eps_end=0.0, exploration_steps=1024, learning_starts=128,
                    target_update_period=25, double_dqn=True, trunk="mlp")
FAST = {"xla_backend_optimization_level": 0}  # compiles much faster on CPU


class HostProbe:
    """`num_envs` copies of a probe with numpy `reset(seed=)` / `step(actions)`."""

    def __init__(self, name: str, num_envs: int):
        env, self.params = make_probe(name)
        self.env = LogWrapper(env)
        self.num_envs = num_envs
        self.single_observation_space = env.observation_space(self.params)
        self.single_action_space = env.action_space(self.params)
        self._reset = jax.jit(jax.vmap(self.env.reset, in_axes=(0, None)))
        self._step = jax.jit(jax.vmap(self.env.step, in_axes=(0, 0, 0, None)))

    def reset(self, seed: int = 0):
        self._key = jax.random.key(seed)
        obs, self._state = self._reset(self._keys(), self.params)
        return np.asarray(obs), {}

    def step(self, actions):
        obs, self._state, reward, terminated, truncated, info = self._step(
            self._keys(), self._state, jnp.asarray(actions), self.params
        )
        return (np.asarray(obs), np.asarray(reward), np.asarray(terminated),
                np.asarray(truncated), jax.tree_util.tree_map(np.asarray, info))

    def _keys(self):
        self._key, key = jax.random.split(self._key)
        return jax.random.split(key, self.num_envs)


@functools.cache
def trained(probe: str, algo: str, gamma: float = 0.99, parts: int = 1, **static):
    if algo == "dqn":
        config = DQN.replace(gamma=gamma, **static)
        learner = make_host_dqn(config, HostProbe(probe, config.num_envs), FAST)
    else:
        config = CONFIGS[algo].replace(gamma=gamma)
        env = (HostProbe(probe, config.num_envs) if parts == 1 else
               PipelinedVecEnv([HostProbe(probe, config.num_envs // parts) for _ in range(parts)]))
        learner = on_policy_host_learner(config, env, FAST, rule=RULES[algo])
    state, history = learner.train(jax.random.key(0))
    return learner, learner.params(state), history


def value(learner, params, obs):
    return np.asarray(learner.network.apply(params, jnp.asarray(obs, jnp.float32))[1])


@pytest.mark.parametrize("algo", ["ppo", "a2c", "dqn"])
def test_policy_learns_the_sign_probe(algo):
    learner, params, history = trained("sign", algo)
    assert np.nanmean([h["episode_return"] for h in history[-5:]]) >= 0.9
    greedy = evaluate_host(learner, params, HostProbe("sign", 4), 20, jax.random.key(1),
                           greedy=True)
    assert greedy.shape == (20,) and (greedy == 1.0).all()


def test_pipelined_policy_learns_the_sign_probe():
    learner, params, history = trained("sign", "ppo", parts=2)
    assert np.nanmean([h["episode_return"] for h in history[-5:]]) >= 0.9
    assert learner.timings["steps"] == learner.num_updates * CONFIGS["ppo"].num_steps


@pytest.mark.parametrize("parts", [1, 2])
def test_truncated_steps_bootstrap_from_the_final_observation(parts):
    """As tests/test_agents.py: 5-step episodes that are truncated, never terminated; the first
    step shows [1, 0] and pays -10, later ones [0, 1] and pay 1; gamma 0.9: V([0, 1]) = 10 and
    V([1, 0]) = -1. Bootstrapping from the next episode's first observation gives V([0, 1])
    about -11; treating truncation as termination gives about 2.7. Pipelined too (two parts)."""
    learner, params, history = trained("costly_start", "ppo", gamma=0.9, parts=parts)
    start, later = value(learner, params, [[1.0, 0.0], [0.0, 1.0]])
    assert 8.0 < later < 12.0, later
    assert abs(start + 1.0) < 2.0, start
    assert history[-1]["episode_return"] == -10.0 + 4.0
    assert history[-1]["terminated_fraction"] == 0.0


class WholeCounter:
    """Envs whose observation counts their steps (env j of a part starts at its seed + j),
    rewarding the action; `step` only (no `step_async`/`step_wait`)."""

    single_observation_space = None
    single_action_space = None

    def __init__(self, name, num_envs, log):
        self.name, self.num_envs, self.log, self._sent = name, num_envs, log, None

    def reset(self, seed=0):
        self.count = seed + np.arange(self.num_envs)
        return self.count.copy(), {}

    def step(self, actions):
        self.count = self.count + 1
        zeros = np.zeros(self.num_envs, bool)
        return self.count.copy(), np.asarray(actions, np.float32), zeros, zeros, {}

    def close(self):
        self.log.append(("close", self.name))


class HalvesCounter(WholeCounter):
    """`WholeCounter` with `step_async`/`step_wait`, logging the calls."""

    def step_async(self, actions):
        self.log.append(("send", self.name))
        self._sent = actions

    def step_wait(self):
        self.log.append(("wait", self.name))
        return self.step(self._sent)


def counter(name, num_envs, log, halves=True):
    return (HalvesCounter if halves else WholeCounter)(name, num_envs, log)


@pytest.mark.parametrize("halves", [True, False])
def test_pipelined_steps_act_on_each_part_s_latest_observation(halves):
    """Each action is computed from its part's latest observation and lands on that part;
    keys are split once per part and step; with `step_async` the next part is sent before the
    previous one is waited for (its emulation overlaps the driver's work)."""
    log = []
    env = PipelinedVecEnv([counter("a", 2, log, halves), counter("b", 3, log, halves)])
    obs, _ = env.reset(seed=10)
    seen = []

    def policy(carry, obs, key, t, part):
        log.append(("policy", "ab"[part]))
        return (obs * 100 + t)[:, None], (np.asarray(obs), jax.random.key_data(key))  # actions [B, F]

    def observe(carry, s: EnvStep, aux, t, part):
        seen.append((t, part, aux[0], np.asarray(s.obs), s.action, s.reward, s.next_obs, aux[1]))
        return carry + 1, (t, part)

    (carry, obs, key), records = host_steps_pipelined(env, 3, policy, observe, 0, obs, jax.random.key(0))
    assert carry == 6 and [(t, p) for t, p, *_ in seen] == [(t, p) for t in range(3) for p in range(2)]
    assert records == [(t, p) for t in range(3) for p in range(2)]  # in the order the steps ran
    np.testing.assert_array_equal(obs, 10 + np.arange(5) + 3)
    for t, part, policy_obs, step_obs, action, reward, next_obs, _ in seen:
        start = 10 + (np.arange(2) if part == 0 else 2 + np.arange(3))
        np.testing.assert_array_equal(policy_obs, start + t)  # the latest observation of these envs
        np.testing.assert_array_equal(step_obs, start + t)
        np.testing.assert_array_equal(reward, (start + t) * 100 + t)  # its own action
        np.testing.assert_array_equal(action[:, 0], reward)
        np.testing.assert_array_equal(next_obs, start + t + 1)
    expected_key = jax.random.key(0)
    for *_, key_data in seen:
        expected_key, key_act = jax.random.split(expected_key)
        np.testing.assert_array_equal(key_data, jax.random.key_data(key_act))
    if halves:
        assert log[:6] == [("policy", "a"), ("policy", "b"), ("send", "a"), ("send", "b"), ("wait", "a"),
                           ("policy", "a")]
    with pytest.raises(ValueError, match="two or more"):
        host_steps_pipelined(PipelinedVecEnv([counter("a", 2, log)]), 1, policy, observe, 0, obs[:2],
                             jax.random.key(0))


def test_pipelined_env_step_sends_every_part_before_awaiting_any():
    """`PipelinedVecEnv.step` (one batch of every part): every part with `step_async` is sent
    its actions before any is awaited, then they are awaited in turn; a part without it steps
    when sent its actions; the outcome is the parts' outcomes in order."""
    log = []
    env = PipelinedVecEnv([HalvesCounter("a", 2, log), HalvesCounter("b", 3, log), WholeCounter("c", 1, log)])
    obs, _ = env.reset(seed=10)
    actions = np.array([5, 6, 7, 8, 9, 4])
    for step in range(2):
        obs, reward, terminated, truncated, _ = env.step(actions)
        np.testing.assert_array_equal(obs, 10 + np.arange(6) + step + 1)
        np.testing.assert_array_equal(reward, actions)
        assert not terminated.any() and not truncated.any()
    assert [entry for entry in log if entry[0] == "send"][:2] == [("send", "a"), ("send", "b")]
    assert log.index(("send", "b")) < log.index(("wait", "a")) < log.index(("wait", "b"))
    assert ("wait", "c") not in log  # "c" has no step_wait: it stepped when sent its actions
    env.close()
    assert log[-3:] == [("close", "a"), ("close", "b"), ("close", "c")]


def test_terminal_steps_do_not_bootstrap():
    """One-step episodes with a constant reward: V = that reward, not reward / (1 - gamma)."""
    learner, params, _ = trained("constant_reward", "a2c")
    probe = HostProbe("constant_reward", 1)
    expected = float(probe.params.reward)
    assert abs(value(learner, params, probe.reset()[0])[0] - expected) < 0.1


def test_batch_size_must_match_the_env():
    with pytest.raises(ValueError, match="num_envs"):
        on_policy_host_learner(CONFIGS["ppo"], HostProbe("sign", 3), rule=ppo.RULE)
    with pytest.raises(ValueError, match="less than one rollout"):
        on_policy_host_learner(CONFIGS["ppo"].replace(total_timesteps=10), HostProbe("sign", 4),
                               rule=ppo.RULE)


def test_dqn_host_loop_learns_two_steps_with_nstep_returns():
    """The host DQN stores n-step transitions on the device as the jitted one does."""
    learner, params, history = trained("two_step", "dqn", n_step=2)
    assert np.nanmean([h["episode_return"] for h in history[-50:]]) >= 0.9
    greedy = evaluate_host(learner, params, HostProbe("two_step", 4), 20, jax.random.key(1),
                           greedy=True)
    assert (greedy == 1.0).all()


@pytest.mark.parametrize("algo", ["ppo", "dqn"])
def test_checkpoint_round_trip_continues_exactly(algo, tmp_path):
    """A state saved after 3 updates and restored into a fresh learner's structure equals the
    saved one leaf for leaf (params, optimizer state, DQN's target network, buffer and n-step
    window, key, update count), and running on from either gives the same result bit for bit
    (the env restarts from the state's key in both: only the emulator cannot be restored)."""
    from jaxnat.training.checkpoints import Checkpoints

    if algo == "dqn":
        config = DQN.replace(total_timesteps=48, learning_starts=8, n_step=2)
        make = lambda: make_host_dqn(config, HostProbe("two_step", 4), FAST)  # noqa: E731
    else:
        config = CONFIGS["ppo"].replace(total_timesteps=4 * 16 * 6)
        make = lambda: on_policy_host_learner(config, HostProbe("two_step", 4), FAST, rule=ppo.RULE)  # noqa: E731
    learner = make()
    state, _ = learner.run(learner.init(jax.random.key(3)), num_updates=3)
    checkpoints = Checkpoints(tmp_path / "checkpoints")
    checkpoints.save(state, {"update": 3})
    other = make()  # as a new process would: its own jitted functions and optimizer
    restored, meta = checkpoints.restore(other.init(jax.random.key(99)))
    checkpoints.close()
    assert meta["update"] == 3 and int(restored.update) == 3
    for a, b in zip(_leaves(state), _leaves(restored), strict=True):
        np.testing.assert_array_equal(a, b)
    expected, expected_history = learner.run(state)
    actual, history = other.run(restored)
    assert len(history) == learner.num_updates - 3
    np.testing.assert_equal(history, expected_history)  # NaN where no episode ended
    for a, b in zip(_leaves(expected), _leaves(actual), strict=True):
        np.testing.assert_array_equal(a, b)


ATARI = ["--env-id", "NaturalAtari/Breakout-v0", "--seeds", "2", "--total-timesteps", "32",
         "--num-envs", "2", "--eval-episodes", "2", "--eval-every", "1", "--env-kwargs",
         "obs_size=36", "num_threads=1", "max_episode_steps=10", "background=noise"]
ALGO_ARGS = {"ppo": ["--num-steps", "8", "--num-minibatches", "2"],
             "dqn": ["--num-steps", "8", "--buffer-size", "64", "--learning-starts", "16",
                     "--gradient-steps", "2", "--batch-size", "8", "--n-step", "3"]}


def _leaves(tree):
    from jaxnat.training.checkpoints import to_saveable

    return [np.asarray(x) for x in jax.tree.leaves(to_saveable(tree))]


@pytest.mark.parametrize("algo", ["ppo", "dqn"])  # a2c: the same on-policy host loop as ppo
def test_jaxnat_train_natural_atari_checkpoints_and_resume(algo, tmp_path):
    """`jaxnat train` routes NaturalAtari ids to the host loop and writes a run directory; a run
    of seeds one after another (DQN's way; PPO's with `--host-seeds sequential`: its seeds side
    by side are tests/test_host_seeds.py's) stopped after 3 checkpoints (seed 0 done, seed 1 at
    update 1) and resumed restores exactly what was saved (params, optimizer state, DQN's
    buffer, the update count and key), finishes seed 1 only, and its metrics hold every (seed,
    update) once."""
    pytest.importorskip("ale_py")
    import json

    from jaxnat.atari.wrappers import ClipRewardWrapper
    from jaxnat.training import host_backend as host
    from jaxnat.train import main
    from jaxnat.training import RunSpec
    from jaxnat.training.checkpoints import Checkpoints

    run_dir = tmp_path / "run"
    argv = [*ATARI, "--algo", algo, *ALGO_ARGS[algo], *(["--host-seeds", "sequential"] if algo == "ppo" else [])]
    assert main([*argv, "--run-dir", str(run_dir)], compiler_options=FAST, stop_after_chunks=3) == 0
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    assert [(r["seed"], r["update"]) for r in rows] == [(0, 1), (0, 2), (1, 1)]
    # 10-step games (time limit) in 8-step rollouts: both envs' first games end in update 2.
    assert rows[0]["episodes"] == 0 and rows[1]["episodes"] == 2
    assert rows[1]["episode_length"] == 10.0
    summary = json.loads((run_dir / "summary.json").read_text())
    tested = summary["metrics"]["test_sampled_return"]["per_seed"]
    assert not summary["complete"] and np.isfinite(tested[0]) and tested[1] is None  # seed 1 not finished

    # What the checkpoint of seed 1 holds is what the resumed run starts from.
    spec = RunSpec.from_json(json.loads((run_dir / "config.json").read_text())["spec"])
    assert spec.env_parts == 1 and spec.host_seeds == "sequential"  # one batch, the loop as it always was
    if algo == "dqn":
        assert spec.config.loss == "huber"  # Nature DQN's loss is the Atari default
    env = ClipRewardWrapper(jaxnat_make_vec(spec, "train"))
    learner = host.make_learner(algo, spec.config, env, FAST)
    checkpoints = Checkpoints(run_dir / "checkpoints" / "seed_1")
    saved, meta = checkpoints.restore(learner.init(jax.random.key(1)))
    checkpoints.close()
    assert meta["update"] == 1 and int(saved.update) == 1
    fresh = learner.init(jax.random.key(1))
    assert not all(np.array_equal(a, b) for a, b in zip(_leaves(saved.learner), _leaves(fresh.learner)))

    assert main(["--resume", str(run_dir)], compiler_options=FAST) == 0
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    assert [(r["seed"], r["update"]) for r in rows] == [(0, 1), (0, 2), (1, 1), (1, 2)]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["complete"] and all(np.isfinite(summary["metrics"]["test_sampled_return"]["per_seed"]))
    assert summary["env_steps_per_seed"] == 32
    evals = [json.loads(line) for line in (run_dir / "eval.jsonl").read_text().splitlines()]
    # Each seed's untrained policy (update 0), then its trained one; seed 1's untrained score
    # was written before the interruption and kept.
    assert [(e["seed"], e["update"]) for e in evals] == [(0, 0), (0, 2), (1, 0), (1, 2)]
    env.close()


def jaxnat_make_vec(spec, split):
    import jaxnat

    return jaxnat.make_vec(spec.env_id, spec.config.num_envs, split=split, **spec.env_kwargs)


def test_algorithm_without_host_loop_is_a_clear_error(capsys, monkeypatch):
    """Every algorithm has a host loop today; one without it is refused in one line."""
    from jaxnat.train import main
    from jaxnat.training import host_backend

    monkeypatch.setattr(host_backend, "HOST_ALGORITHMS", ("ppo", "a2c", "dqn"))
    assert main(["--env-id", "NaturalAtari/Breakout-v0", "--algo", "acktr"]) == 2
    assert "acktr has no host loop" in capsys.readouterr().err


def test_acktr_learns_the_sign_probe_on_the_host():
    """ACKTR on a host-batched env, as the paper ran it on Atari: K-FAC statistics from the
    host rollouts (`acktr.make_host_acktr`)."""
    from jaxnat.agents.acktr import ACKTRConfig, make_host_acktr

    config = ACKTRConfig(total_timesteps=4096, num_envs=4, num_steps=8, trunk="mlp")
    learner = make_host_acktr(config, HostProbe("sign", 4), FAST)
    state, history = learner.train(jax.random.key(0))
    assert np.nanmean([h["episode_return"] for h in history[-5:]]) >= 0.9
    greedy = evaluate_host(learner, learner.params(state), HostProbe("sign", 4), 20, jax.random.key(1), greedy=True)
    assert (greedy == 1.0).all()
    with pytest.raises(TypeError):  # one device: K-FAC's factors are the whole batch's
        make_host_acktr(config, HostProbe("sign", 4), FAST, devices=2)


def test_host_runs_check_counts_as_the_jitted_path(capsys, tmp_path):
    from jaxnat.train import main

    assert main(["--env-id", "NaturalAtari/Breakout-v0", "--eval-every", "0",
                 "--run-dir", str(tmp_path / "run")]) == 2
    assert "--eval-every must be at least 1" in capsys.readouterr().err


def test_jaxnat_train_env_parts_pipelines_records_and_resumes(tmp_path, monkeypatch):
    """`--env-parts 2` trains through the pipelined driver, is saved in config.json, resumes,
    and a resume naming other parts is refused."""
    pytest.importorskip("ale_py")
    import json

    from jaxnat.agents.rollout import on_policy_host
    from jaxnat.train import main

    calls = []
    pipelined = on_policy_host.host_steps_pipelined
    monkeypatch.setattr(on_policy_host, "host_steps_pipelined",
                        lambda env, *a, **k: calls.append(len(env.parts)) or pipelined(env, *a, **k))
    run_dir = tmp_path / "run"
    argv = [*ATARI, "--seeds", "1", "--algo", "ppo", *ALGO_ARGS["ppo"], "--env-parts", "2"]
    assert main([*argv, "--run-dir", str(run_dir)], compiler_options=FAST, stop_after_chunks=1) == 0
    assert calls == [2]  # one update, two parts of one env
    config = json.loads((run_dir / "config.json").read_text())
    assert config["spec"]["env_parts"] == 2 and config["args"]["env_parts"] == 2
    assert config["spec"]["host_seeds"] == "sequential"  # unset with parts, as such runs trained before
    assert main(["--resume", str(run_dir), "--env-parts", "1"]) == 2
    assert main(["--resume", str(run_dir), "--env-parts", "2"], compiler_options=FAST) == 0
    assert calls == [2, 2]
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    assert [(r["seed"], r["update"]) for r in rows] == [(0, 1), (0, 2)]
    assert json.loads((run_dir / "summary.json").read_text())["complete"]


@pytest.mark.parametrize("argv, message", [
    (["--num-envs", "3", "--env-parts", "2"], "--env-parts 2 must divide num_envs=3"),
    (["--algo", "dqn", "--env-parts", "2"], "--env-parts applies to ppo, a2c, acktr: dqn's host loop"),
    (["--env-parts", "0"], "--env-parts must be at least 1"),
])
def test_env_parts_errors(argv, message, tmp_path, capsys):
    pytest.importorskip("ale_py")
    from jaxnat.train import main

    assert main(["--env-id", "NaturalAtari/Breakout-v0", "--env-kwargs", "obs_size=36", *argv,
                 "--run-dir", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxnat train: error: ") and message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "run").exists()


def test_host_backend_builds_parts_and_no_more_test_envs_than_test_games():
    pytest.importorskip("ale_py")
    from jaxnat.training import RunSpec
    from jaxnat.training.host_backend import HostBackend

    kwargs = {"obs_size": 36, "num_threads": 1, "max_episode_steps": 10}
    config = CONFIGS["ppo"].replace(trunk="atari", num_envs=4)
    for parts, episodes, pipelined, test_envs in ((1, 2, False, 2), (2, 8, True, 4)):
        backend = HostBackend(RunSpec("NaturalAtari/Breakout-v0", kwargs, "ppo", config, 1, 0, 1, episodes, parts))
        try:
            assert isinstance(backend.env, PipelinedVecEnv) == pipelined and backend.env.num_envs == 4
            assert backend.test_env.num_envs == test_envs
        finally:
            backend.close()


def test_a_run_records_the_videos_it_saw(tmp_path):
    """`jaxnat train` writes the videos of each split into `config.json` as `data`: per video
    its file name, the SHA-256 of its bytes and the frames used (`FrameBank.manifest`); the
    splits are disjoint and together every clip."""
    pytest.importorskip("ale_py")
    pytest.importorskip("numba")
    import hashlib
    import json

    from test_atari import _write_video

    from jaxnat.train import main

    folder = tmp_path / "clips"
    folder.mkdir()
    clips = [_write_video(folder / f"clip{v}.avi", v, 6 + v) for v in range(4)]
    run_dir = tmp_path / "run"
    argv = [*ATARI[:-1], "background=video", f"video_sources={folder}", "--algo", "ppo", *ALGO_ARGS["ppo"],
            "--run-dir", str(run_dir)]
    assert main(argv, compiler_options=FAST) == 0
    data = json.loads((run_dir / "config.json").read_text())["data"]
    (train,), (test,) = data["train"], data["test"]
    sha = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in clips}
    assert {m["name"] for m in train}.isdisjoint({m["name"] for m in test})
    assert sorted(m["name"] for m in train + test) == sorted(sha)
    assert all(m["sha256"] == sha[m["name"]] and m["frames"] == 6 + int(m["name"][4]) for m in train + test)


def test_a_natural_atari_run_loads_acts_greedily_and_evaluates(tmp_path, capsys):
    """`load_policy` on a host run of seeds one after another: seed 0's checkpoint (seed 1 never
    trained: one line), its
    greedy action the network's most likely one, `host_episodes` the same games under one key
    (whole games within the 10-step limit), and `jaxnat eval` scores them."""
    pytest.importorskip("ale_py")
    import re

    from jaxnat import eval_run
    from jaxnat.train import main
    from jaxnat.trained import LoadError, host_episodes, load_policy

    run_dir = tmp_path / "run"
    assert main([*ATARI, "--algo", "ppo", *ALGO_ARGS["ppo"], "--host-seeds", "sequential", "--run-dir", str(run_dir)],
                compiler_options=FAST, stop_after_chunks=2) == 0  # seed 0 done (2 updates), seed 1 not started
    with pytest.raises(LoadError, match=r"has no checkpoint of seed 1 \(index 1\) yet: checkpoints/seed_1 holds none"):
        load_policy(run_dir, seed=1, compiler_options=FAST)
    policy = load_policy(run_dir, compiler_options=FAST)
    assert (policy.update, policy.seed_value, policy.env_params, policy.split) == (2, 0, None, "test")
    obs, _ = policy.env.reset(seed=3)
    logits, _ = policy.network.apply(policy.params, jnp.asarray(obs))
    action = np.asarray(policy.act(obs[0], jax.random.key(0), greedy=True))  # one factor: Discrete's
    (factor,) = logits  # the logits of the one factor, [1, actions]
    assert action.shape == (1,) and action[0] == int(jnp.argmax(factor[0]))
    first = host_episodes(policy, jax.random.key(5), 2, greedy=False)
    again = host_episodes(policy, jax.random.key(5), 2, greedy=False)
    assert all(np.array_equal(first[k], again[k]) for k in first)
    assert first["length"].tolist() == [10, 10] and not first["unfinished"].any()  # the time limit ends them
    seen, results = host_episodes(policy, jax.random.key(5), 2, record=True)
    assert [len(s) for s in seen] == [11, 11] and seen[0].shape[1:] == obs.shape[1:]
    assert all(np.array_equal(results[k], first[k]) for k in first)
    assert eval_run.main([str(run_dir), "--episodes", "2", "--greedy"], compiler_options=FAST) == 0
    out = capsys.readouterr().out
    assert "ppo on NaturalAtari/Breakout-v0 · seed 0 · checkpoint at update 2 · test split" in out
    assert re.search(r"2 episodes, greedy actions .*\n  return +[-+]\d+\.\d{4}", out), out
    policy.env.close()
    # jaxnat play: the same games as a GIF, each 10 steps + its reset, the newest frame of each stack.
    av = pytest.importorskip("av")
    from jaxnat import play_run

    path = tmp_path / "games.gif"
    assert play_run.main([str(run_dir), "--episodes", "2", "--key", "5", "--out", str(path), "--scale", "2"],
                         compiler_options=FAST) == 0
    with av.open(str(path)) as container:
        frames = np.stack([f.to_ndarray(format="rgb24") for f in container.decode(container.streams.video[0])])
    assert frames.shape == (22, 72, 72, 3)  # 36x36 observations at scale 2
    newest = np.repeat(np.repeat(seen[1][-1][..., -1], 2, axis=0), 2, axis=1)
    # The GIF's palette dithers each pixel (a noise background most): the frame's mean is kept.
    assert abs(frames[-1][..., 0].mean() - newest.mean()) < 2


def test_observation_space_leaves_the_background_dial_out():
    """The default trunk's probe (one env, no background) takes a run's kwargs without the ones
    only a background takes: `jaxnat train` on a dimmed video background sets up, and the
    space is the plain env's."""
    pytest.importorskip("ale_py")
    from jaxnat.training.host_backend import observation_space

    plain = observation_space("NaturalAtari/Breakout-v0", {"obs_size": 42})
    dimmed = observation_space("NaturalAtari/Breakout-v0", {"obs_size": 42, "background": "video",
                                                             "video_alpha": 0.5, "frame_rate": 0})
    assert (dimmed.shape, dimmed.dtype) == (plain.shape, plain.dtype) == ((42, 42, 4), np.uint8)
