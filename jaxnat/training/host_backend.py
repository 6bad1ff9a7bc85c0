"""The host backend of `jaxnat train`: runs on host-batched envs (`NaturalAtari/*`).

The jitted, vmapped trainer needs a pure-JAX env; ALE runs in C++ on the host, so these runs
use the agents' host learners (`rollout.host_steps`), one seed after another, on rewards
clipped to [-1, 1] (`ClipRewardWrapper`, as DQN and the authors' code); the returns reported
(train and test) are whole games with unclipped rewards. Before a seed's first update (the
untrained policy, the baseline a trained one must beat) and when its last update is done, its
policy plays `eval_episodes` whole games on the test split (videos the agent never saw),
sampled and greedy, on at most `eval_episodes` envs. `chunk_loop.run_training` does the rest, as
for every run: the run directory, checkpoints (`checkpoints/seed_<s>/`, every `--eval-every`
updates), `--resume`, the summary.

`--env-parts N` (PPO, A2C) trains on a `PipelinedVecEnv` of N equal parts, which the learner
steps in turn (`rollout.host_steps_pipelined`): the policy's call for one part overlaps the
emulation of the others. The actions are sampled with other keys than in one batch, so a run
with parts differs from the one-batch run (N=1, the default, is that run unchanged).

Several hosts (the API; `jaxnat train` runs in one process): `make_train_env(...,
devices="all")` builds this process's share of the batch and `make_learner(..., devices="all")`
its data-parallel learner (PPO, A2C; `rollout.on_policy_host_learner`): one ALE batch per
process, the update data parallel over every process's devices, the same parameters in all.

What a host checkpoint holds: params, optimizer state, DQN's target network and replay buffer,
the update count and the PRNG key. The emulators' state cannot be saved, so a resumed seed
starts new games (from a seed drawn from the restored key): unlike a resumed jitted run, the
result is not the uninterrupted one bit for bit.
"""

from __future__ import annotations

import contextlib
import inspect
import itertools

import jax
import numpy as np

import jaxnat
from jaxnat.agents import ALGORITHMS
from jaxnat.agents.rollout import evaluate_host
from jaxnat.atari.wrappers import ClipRewardWrapper, PipelinedVecEnv
from jaxnat.datasets import DatasetFormatError, DatasetNotFoundError
from jaxnat.registration import MissingDependencyError, UnknownEnvError
from jaxnat.sharding import process_share
from jaxnat.training.args import TrainArgs, TrainError, check_split_kwargs, default_eval_episodes, parse_env_kwargs
from jaxnat.training.spec import RunSpec, resolve_config

__all__ = ["HOST_ALGORITHMS", "PIPELINED_ALGORITHMS", "DATA_PARALLEL_ALGORITHMS", "MAX_EVAL_EPISODES", "HostBackend",
           "is_host_env", "new_host_spec", "check_env_parts", "observation_space", "make_learner", "make_train_env",
           "host_errors"]

MAX_EVAL_EPISODES = 32  # whole Atari games are thousands of steps
EVAL_SEED_OFFSET = 10_000  # a seed's test games are played with key(EVAL_SEED_OFFSET + seed)

HOST_ALGORITHMS = tuple(name for name, algorithm in ALGORITHMS.items() if algorithm.make_host is not None)
# The host learners that step a `PipelinedVecEnv` in turn (`rollout.on_policy_host_learner`).
PIPELINED_ALGORITHMS = ("ppo", "a2c", "acktr")
# The host learners that train data parallel (`make_learner(..., devices=)`).
DATA_PARALLEL_ALGORITHMS = tuple(name for name in HOST_ALGORITHMS
                                 if "devices" in inspect.signature(ALGORITHMS[name].make_host).parameters)


def observation_space(env_id: str, env_kwargs: dict):
    """The observation space, from one env without background (cheap), for the default trunk
    (the background's own kwargs left out: without one they are refused)."""
    from jaxnat.atari.backgrounds import BACKGROUND_KWARGS

    plain = {key: value for key, value in env_kwargs.items() if key not in BACKGROUND_KWARGS}
    probe = jaxnat.make_vec(env_id, 1, **{**plain, "background": "none"})
    try:
        return probe.single_observation_space
    finally:
        probe.close()


def make_train_env(env_id: str, num_envs: int, env_kwargs: dict, parts: int = 1, devices=None):
    """The env a host run trains on: `num_envs` envs of the train split, rewards clipped to
    [-1, 1]; with `parts` > 1 a `PipelinedVecEnv` of that many equal batches, each with the
    same env kwargs (ALE threads included: the parts mostly emulate in turn), which the
    on-policy learners step in turn so that the policy calls overlap the emulation. With
    `devices` (for `make_learner(..., devices=)`) only this process's share of the `num_envs`
    envs (`jaxnat.sharding.process_share`; all of them in one process)."""
    if devices is not None:
        num_envs = process_share(num_envs, devices)[1]
    if parts < 1 or num_envs % parts:
        raise ValueError(f"parts={parts} must be >= 1 and divide num_envs={num_envs}")
    if parts == 1:
        return ClipRewardWrapper(jaxnat.make_vec(env_id, num_envs, split="train", **env_kwargs))
    return PipelinedVecEnv([ClipRewardWrapper(jaxnat.make_vec(env_id, num_envs // parts, split="train",
                                                              **env_kwargs)) for _ in range(parts)])


def make_learner(algo: str, config, env, compiler_options: dict | None = None, devices=None):
    """The host learner of `algo` (one of `HOST_ALGORITHMS`) for `config` on `env`; with
    `devices` (a count, "all", devices) data parallel over them and every process, `env` this
    process's share (`make_train_env(..., devices=)`)."""
    make = ALGORITHMS[algo].make_host
    if devices is None:
        return make(config, env, compiler_options)
    if algo not in DATA_PARALLEL_ALGORITHMS:
        raise ValueError(f"{algo}'s host learner needs the whole batch on one device: leave devices out, or "
                         f"train {' or '.join(DATA_PARALLEL_ALGORITHMS)} data parallel")
    return make(config, env, compiler_options, devices=devices)


def is_host_env(env_id: str) -> bool:
    try:
        return jaxnat.spec(env_id).batched
    except UnknownEnvError:
        return False  # the main path reports it


def new_host_spec(args: TrainArgs, console) -> RunSpec:
    """The spec of a new host run (`eval_every` not yet resolved) of a known algorithm."""
    if args.algo not in HOST_ALGORITHMS:
        raise TrainError(f"{args.algo} has no host loop: {args.env_id} (host-emulated) trains "
                         f"with {', '.join(HOST_ALGORITHMS)}")
    env_kwargs = parse_env_kwargs(args.env_kwargs, args.env_id)
    check_split_kwargs(env_kwargs)
    with host_errors(args.env_id):  # (DQN takes Nature DQN's Huber loss here: `agents.defaults`)
        config, sources = resolve_config(args, observation_space(args.env_id, env_kwargs))
    check_env_parts(args.env_parts, args.algo, config.num_envs)
    eval_episodes = args.eval_episodes or min(default_eval_episodes(args.env_id), MAX_EVAL_EPISODES)
    if eval_episodes > MAX_EVAL_EPISODES:
        console.print(f"[dim]evaluating {MAX_EVAL_EPISODES} test games per seed (not "
                      f"{eval_episodes}): whole Atari games are long[/dim]")
        eval_episodes = MAX_EVAL_EPISODES
    return RunSpec(args.env_id, env_kwargs, args.algo, config, args.seeds, args.seed, 1, eval_episodes,
                   args.env_parts, config_sources=sources)


def check_env_parts(parts: int, algo: str, num_envs: int) -> None:
    """`--env-parts` (at least 1, `rundir.check_counts`): more than 1 only for the learners
    that step parts in turn, and dividing num_envs (the parts are equal)."""
    if parts > 1 and algo not in PIPELINED_ALGORITHMS:
        raise TrainError(f"--env-parts applies to {', '.join(PIPELINED_ALGORITHMS)}: {algo}'s host loop steps "
                         "its envs as one batch")
    if num_envs % parts:
        raise TrainError(f"--env-parts {parts} must divide num_envs={num_envs} (the parts are equal)")


@contextlib.contextmanager
def host_errors(env_id: str):
    """Turn the env's and the learner's setup errors into one-line `TrainError`s."""
    try:
        yield
    except (MissingDependencyError, DatasetNotFoundError, DatasetFormatError, TypeError, ValueError) as err:
        raise TrainError(f"{env_id}: {err}") from None


class HostBackend:
    """`chunk_loop.Backend` for host-batched envs: one seed after another, each from a fresh
    learner state; the emulators are built once (train and test split) and reused by every
    seed. Checkpoints: `checkpoints/seed_<s>/`, the learner's `HostState`."""

    evaluates_each_chunk = False
    eval_steps = None  # whole games: their length is known when they end (`EvalProgress` shows time only)

    def __init__(self, spec: RunSpec, compiler_options: dict | None = None):
        self.spec = spec
        self.groups = [[seed] for seed in spec.seed_values]
        check_split_kwargs(spec.env_kwargs)
        with host_errors(spec.env_id):
            self.env = make_train_env(spec.env_id, spec.config.num_envs, spec.env_kwargs, spec.env_parts)
            # No more test envs than test games: the first games to end are the short ones, so
            # many envs would bias the scores (and step emulators whose games are never counted).
            self.test_env = jaxnat.make_vec(spec.env_id, min(spec.config.num_envs, spec.eval_episodes), split="test",
                                            **spec.env_kwargs)
            self.learner = make_learner(spec.algo, spec.config, self.env, compiler_options)
        self._updates = None

    def checkpoint_dir(self, group) -> str:
        return f"checkpoints/seed_{group[0]}"

    def init(self, group):
        return self.learner.init(jax.random.key(group[0]))

    def update_of(self, state) -> int:
        return int(self.learner.updates_of(state))

    def begin(self, group, state) -> None:
        self._updates = self.learner.updates(state)  # new games, seeded from the state's key

    def chunk(self, state, num_updates: int, progress):
        rows = []
        for state, metrics, _ in itertools.islice(self._updates, num_updates):
            rows.append(metrics)
            progress(self.learner.updates_of(state), metrics)
        return state, {name: np.asarray([[row[name] for row in rows]]) for name in rows[0]}

    def evaluate(self, group, state, progress=None) -> dict:
        scores = {}
        for mode in ("sampled", "greedy"):
            returns = evaluate_host(self.learner, self.learner.params(state), self.test_env, self.spec.eval_episodes,
                                    jax.random.key(EVAL_SEED_OFFSET + group[0]), greedy=mode == "greedy")
            scores[f"{mode}_return"] = np.asarray([returns.mean()])
        return scores

    def chance(self, progress=None) -> None:
        """Not measured: random play of whole Atari games costs as much as evaluating a seed."""
        return None

    def data_manifest(self) -> dict:
        """The background's videos or photos (`natural.bank_manifests`), per split (a pipelined
        env's parts hold the same bank: its first part's)."""
        from jaxnat.natural import bank_manifests

        return {"train": bank_manifests(getattr(self.env, "parts", [self.env])[0]),
                "test": bank_manifests(self.test_env)}

    def close(self) -> None:
        self.env.close()
        self.test_env.close()
