"""The host backend of `jaxnat train`: runs on host-batched envs (`NaturalAtari/*`).

The jitted, vmapped trainer needs a pure-JAX env; ALE runs in C++ on the host, so these runs
use the agents' host learners (`rollout.host_steps`) on rewards clipped to [-1, 1]
(`ClipRewardWrapper`, as DQN and the authors' code); the returns reported (train and test) are
whole games with unclipped rewards. The seeds train (`--host-seeds`, the spec's `host_seeds`):

- together (PPO, A2C, ACKTR; their default): one group of every seed, side by side on one
  batch of all their envs (`make_train_env(..., seeds=S)`: one ALE batch, seed `s`'s envs a
  slice of it reset as that seed's batch alone), one vmapped policy call per env step and
  one vmapped update for all of them (`on_policy_host_learner(..., seeds=S)`); each seed keeps
  its own keys and games, so its training is its run alone to float tolerance (its test games
  are not: one test env, never reseeded, serves every evaluation in the order they run);
- sequential (DQN's only way, the default with `--env-parts` above 1, and every run written
  before the setting): one seed after another, each from a fresh learner state.

Before the first update (the untrained policy, the baseline a trained one must beat) and when
the last one is done, each seed's policy plays `eval_episodes` whole games on the test split
(videos the agent never saw), sampled and greedy, on at most `eval_episodes` envs.
`chunk_loop.run_training` does the rest, as for every run: the run directory, checkpoints
(`checkpoints/seed_<s>/` in both modes, every `--eval-every` updates: seeds side by side save
each seed's slice of their stacked state, so `--resume`, `jaxnat.trained.load_policy` and
`jaxnat eval` read either the same way), `--resume`, the summary.

`--env-parts N` (PPO, A2C, ACKTR) trains on a `PipelinedVecEnv` of N equal parts, which the learner
steps in turn (`rollout.host_steps_pipelined`): the policy's call for one part overlaps the
emulation of the others. The actions are sampled with other keys than in one batch, so a run
with parts differs from the one-batch run (N=1, the default, is that run unchanged). With
`--host-seeds together` as well, each part holds `num_envs / N` envs of every seed (one ALE
batch), so each seed trains as its run alone in N parts; unset, `--host-seeds` is sequential
with parts, as runs with parts trained before.

Several devices: `jaxnat train --devices N` (PPO, A2C; `check_host_devices`) trains each seed
in turn with its update data parallel over N devices of the process (`make_learner(...,
devices=N)` on the whole batch). Several hosts (the API; `jaxnat train` runs in one process):
`make_train_env(..., devices="all")` builds this process's share of the batch and
`make_learner(..., devices="all")` its data-parallel learner (PPO, A2C; `rollout.on_policy_host_learner`): one ALE batch per
process, the update data parallel over every process's devices, the same parameters in all
(one seed per learner: not with `seeds=`).

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
from jaxnat.agents.rollout import evaluate_host, seed_slice, stack_seeds
from jaxnat.atari.wrappers import ClipRewardWrapper, PipelinedVecEnv
from jaxnat.datasets import DatasetFormatError, DatasetNotFoundError
from jaxnat.registration import MissingDependencyError, UnknownEnvError
from jaxnat.sharding import check_split, process_share
from jaxnat.training.args import TrainArgs, TrainError, check_split_kwargs, default_eval_episodes, parse_env_kwargs
from jaxnat.training.spec import RunSpec, resolve_config

__all__ = ["HOST_ALGORITHMS", "PIPELINED_ALGORITHMS", "DATA_PARALLEL_ALGORITHMS", "SIDE_BY_SIDE_ALGORITHMS",
           "HOST_SEEDS", "MAX_EVAL_EPISODES", "HostBackend", "is_host_env", "new_host_spec", "check_env_parts",
           "check_host_seeds", "check_host_devices", "observation_space", "make_learner",
           "make_train_env", "host_errors"]

MAX_EVAL_EPISODES = 32  # whole Atari games are thousands of steps
EVAL_SEED_OFFSET = 10_000  # a seed's test games are played with key(EVAL_SEED_OFFSET + seed)

HOST_ALGORITHMS = tuple(name for name, algorithm in ALGORITHMS.items() if algorithm.make_host is not None)
# The host learners that step a `PipelinedVecEnv` in turn (`rollout.on_policy_host_learner`).
PIPELINED_ALGORITHMS = ("ppo", "a2c", "acktr")
# The host learners that train data parallel (`make_learner(..., devices=)`).
DATA_PARALLEL_ALGORITHMS = tuple(name for name in HOST_ALGORITHMS
                                 if "devices" in inspect.signature(ALGORITHMS[name].make_host).parameters)
# The host learners that train seeds side by side (`make_learner(..., seeds=)`).
SIDE_BY_SIDE_ALGORITHMS = tuple(name for name in HOST_ALGORITHMS
                                if "seeds" in inspect.signature(ALGORITHMS[name].make_host).parameters)
HOST_SEEDS = ("together", "sequential")  # `--host-seeds`: how a host run trains its seeds


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


def make_train_env(env_id: str, num_envs: int, env_kwargs: dict, parts: int = 1, devices=None,
                   seeds: int | None = None):
    """The env a host run trains on: `num_envs` envs of the train split, rewards clipped to
    [-1, 1]; with `parts` > 1 a `PipelinedVecEnv` of that many equal batches, each with the
    same env kwargs (ALE threads included: the parts mostly emulate in turn), which the
    on-policy learners step in turn so that the policy calls overlap the emulation. With
    `devices` (for `make_learner(..., devices=)`) only this process's share of the `num_envs`
    envs (`jaxnat.sharding.process_share`; all of them in one process).

    `seeds` (S, for `make_learner(..., seeds=S)`): one batch of S * `num_envs` envs, seed `s`'s
    envs `s * num_envs ..` (the learner resets it with `reset(seeds=...)`: each seed's slice as
    that seed's batch alone, its games and backgrounds included), so all the seeds' envs share
    one ALE batch and its threads (`num_threads`, 0: one per env, at most one per CPU) and one
    host pass a step. With `parts` > 1 as well: a `PipelinedVecEnv(groups=S)` of that many
    such batches, each holding `num_envs / parts` envs of every seed (seed `s`'s envs in part
    after part, as its batch alone in parts); not with `devices`.

    A per-env dial in `env_kwargs` (`PER_ENV_KWARGS`: a sequence of one value per env of the
    `num_envs`) follows its envs: each batch gets the values of the envs it holds, for every
    seed it holds."""
    from jaxnat.atari.backgrounds import PER_ENV_KWARGS  # the atari extra's (OpenCV)

    if seeds is not None and devices is not None:
        raise ValueError("seeds side by side step one batch of all their envs on one device: leave devices out")
    for name in PER_ENV_KWARGS:
        if np.ndim(env_kwargs.get(name)) == 1 and len(env_kwargs[name]) != num_envs:
            raise ValueError(f"{name}: one value for every env or one per env of a seed ({num_envs}), got "
                             f"{len(env_kwargs[name])}")
    first = 0
    if devices is not None:
        first, num_envs = process_share(num_envs, devices)
    if parts < 1 or num_envs % parts:
        raise ValueError(f"parts={parts} must be >= 1 and divide num_envs={num_envs}")
    copies, size = seeds or 1, num_envs // parts

    def batch(lo: int):  # envs lo .. lo + size - 1 (of the run's num_envs) of every seed, one ALE batch
        kwargs = {name: (np.tile(np.asarray(value)[lo:lo + size], copies).tolist()
                         if name in PER_ENV_KWARGS and np.ndim(value) == 1 else value)
                  for name, value in env_kwargs.items()}
        return ClipRewardWrapper(jaxnat.make_vec(env_id, copies * size, split="train", **kwargs))

    if parts == 1:
        return batch(first)
    return PipelinedVecEnv([batch(first + p * size) for p in range(parts)], groups=seeds)


def make_learner(algo: str, config, env, compiler_options: dict | None = None, devices=None,
                 seeds: int | None = None):
    """The host learner of `algo` (one of `HOST_ALGORITHMS`) for `config` on `env`; with
    `devices` (a count, "all", devices) data parallel over them and every process, `env` this
    process's share (`make_train_env(..., devices=)`); with `seeds` (one of
    `SIDE_BY_SIDE_ALGORITHMS`) that many seeds side by side on `make_train_env(..., seeds=)`."""
    make = ALGORITHMS[algo].make_host
    if seeds is not None:
        if algo not in SIDE_BY_SIDE_ALGORITHMS:
            raise ValueError(f"{algo}'s host learner trains one seed at a time: leave seeds out, or train "
                             f"{', '.join(SIDE_BY_SIDE_ALGORITHMS)} side by side")
        if devices is not None:
            raise ValueError("seeds side by side train on one device: leave devices out, or train one seed at a time "
                             "data parallel")
        return make(config, env, compiler_options, seeds=seeds)
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


def new_host_spec(args: TrainArgs, console, devices: int | None = None) -> RunSpec:
    """The spec of a new host run (`eval_every` not yet resolved) of a known algorithm; with
    `devices` (`--devices N`), its update data parallel over them (`check_host_devices`)."""
    if args.algo not in HOST_ALGORITHMS:
        raise TrainError(f"{args.algo} has no host loop: {args.env_id} (host-emulated) trains "
                         f"with {', '.join(HOST_ALGORITHMS)}")
    env_kwargs = parse_env_kwargs(args.env_kwargs, args.env_id)
    check_split_kwargs(env_kwargs)
    with host_errors(args.env_id):  # (DQN takes Nature DQN's Huber loss here: `agents.defaults`)
        config, sources = resolve_config(args, observation_space(args.env_id, env_kwargs))
    check_env_parts(args.env_parts, args.algo, config.num_envs)
    check_host_devices(devices, args.shard, args.algo, args.host_seeds)
    host_seeds = check_host_seeds(args.host_seeds, args.algo, args.env_parts, devices)
    eval_episodes = args.eval_episodes or min(default_eval_episodes(args.env_id), MAX_EVAL_EPISODES)
    if eval_episodes > MAX_EVAL_EPISODES:
        console.print(f"[dim]evaluating {MAX_EVAL_EPISODES} test games per seed (not "
                      f"{eval_episodes}): whole Atari games are long[/dim]")
        eval_episodes = MAX_EVAL_EPISODES
    if devices is not None:  # each device takes an equal share of the update
        try:
            check_split(config.num_envs, devices, "num_envs", "--num-envs ")
        except ValueError as err:
            raise TrainError(str(err)) from None
    return RunSpec(args.env_id, env_kwargs, args.algo, config, args.seeds, args.seed, 1, eval_episodes,
                   args.env_parts, devices=devices or 1, shard=None if devices is None else "envs",
                   host_seeds=host_seeds, config_sources=sources)


def check_env_parts(parts: int, algo: str, num_envs: int) -> None:
    """`--env-parts` (at least 1, `rundir.check_counts`): more than 1 only for the learners
    that step parts in turn, and dividing num_envs (the parts are equal)."""
    if parts > 1 and algo not in PIPELINED_ALGORITHMS:
        raise TrainError(f"--env-parts applies to {', '.join(PIPELINED_ALGORITHMS)}: {algo}'s host loop steps "
                         "its envs as one batch")
    if num_envs % parts:
        raise TrainError(f"--env-parts {parts} must divide num_envs={num_envs} (the parts are equal)")


def check_host_devices(devices: int | None, shard: str | None, algo: str, host_seeds: str | None) -> None:
    """`--devices N` on a host env: the update data parallel over N devices of this process
    (`make_learner(..., devices=)`, `--shard envs`, the default), one seed at a time; every
    other request is a one-line `TrainError` that names the fix."""
    if devices is None:
        return
    if shard == "seeds":
        raise TrainError("--shard seeds places whole seeds on devices; a host env's seeds share the host's cores "
                         "(one ALE batch): use --shard envs (the update data parallel) or leave --devices out")
    if algo not in DATA_PARALLEL_ALGORITHMS:
        raise TrainError(f"--devices trains a host env's update data parallel with "
                         f"{', '.join(DATA_PARALLEL_ALGORITHMS)}; {algo}'s host learner needs the whole batch on one "
                         "device: leave --devices out")
    if host_seeds == "together":
        raise TrainError("--host-seeds together trains every seed on one device; with --devices the seeds train one "
                         "after another, each data parallel: give --host-seeds sequential or leave --devices out")


def check_host_seeds(mode: str | None, algo: str, parts: int, devices: int | None = None) -> str:
    """`--host-seeds` resolved: `together` or `sequential` as given, else together for the
    `SIDE_BY_SIDE_ALGORITHMS` on one batch (`--env-parts 1`) on one device, and sequential
    otherwise (runs written before seeds could be pipelined side by side keep training as they
    did); together with an algorithm that cannot is refused."""
    if mode is None:
        return ("together" if algo in SIDE_BY_SIDE_ALGORITHMS and parts == 1 and devices is None
                else "sequential")
    if mode not in HOST_SEEDS:
        raise TrainError(f"--host-seeds takes {' or '.join(HOST_SEEDS)}, got {mode!r}")
    if mode == "together" and algo not in SIDE_BY_SIDE_ALGORITHMS:
        raise TrainError(f"--host-seeds together applies to {', '.join(SIDE_BY_SIDE_ALGORITHMS)}: {algo}'s host "
                         "learner trains one seed at a time (--host-seeds sequential)")
    return mode


@contextlib.contextmanager
def host_errors(env_id: str):
    """Turn the env's and the learner's setup errors into one-line `TrainError`s."""
    try:
        yield
    except (MissingDependencyError, DatasetNotFoundError, DatasetFormatError, TypeError, ValueError) as err:
        raise TrainError(f"{env_id}: {err}") from None


class HostBackend:
    """`chunk_loop.Backend` for host-batched envs. With `spec.host_seeds` "together": one group
    of every seed, trained side by side from one stacked state (`rollout.stacked`), each seed
    checkpointed in `checkpoints/seed_<s>/` (`checkpoints_per_seed`); else one seed after
    another, each from a fresh learner state, its `HostState` in `checkpoints/seed_<s>/`. The
    emulators are built once (train and test split) and serve every group."""

    evaluates_each_chunk = False
    eval_steps = None  # whole games: their length is known when they end (`EvalProgress` shows time only)

    def __init__(self, spec: RunSpec, compiler_options: dict | None = None):
        self.spec = spec
        self.side_by_side = spec.host_seeds == "together"
        self.checkpoints_per_seed = self.side_by_side
        self.groups = [list(spec.seed_values)] if self.side_by_side else [[seed] for seed in spec.seed_values]
        seeds = spec.seeds if self.side_by_side else None
        devices = spec.devices if spec.shard == "envs" else None  # data parallel over this process's devices
        check_split_kwargs(spec.env_kwargs)
        with host_errors(spec.env_id):
            self.env = make_train_env(spec.env_id, spec.config.num_envs, spec.env_kwargs, spec.env_parts, devices,
                                      seeds)
            # No more test envs than test games: the first games to end are the short ones, so
            # many envs would bias the scores (and step emulators whose games are never counted).
            self.test_env = jaxnat.make_vec(spec.env_id, min(spec.config.num_envs, spec.eval_episodes), split="test",
                                            **spec.env_kwargs)
            self.learner = make_learner(spec.algo, spec.config, self.env, compiler_options, devices, seeds)
        self._updates = None

    def checkpoint_dir(self, group) -> str:
        """A seed's folder (`group` of one seed: with `checkpoints_per_seed` the loop asks per seed)."""
        (seed,) = group
        return f"checkpoints/seed_{seed}"

    def init(self, group):
        if self.side_by_side:
            return self.learner.init(stack_seeds([jax.random.key(seed) for seed in group]))
        return self.learner.init(jax.random.key(group[0]))

    def update_of(self, state) -> int:
        return int(np.max(np.asarray(self.learner.updates_of(state))))

    def begin(self, group, state) -> None:
        self._updates = self.learner.updates(state)  # new games, seeded from the state's key (per seed)

    def chunk(self, state, num_updates: int, progress):
        rows = []
        for state, metrics, _ in itertools.islice(self._updates, num_updates):
            rows.append(metrics)
            update = self.update_of(state)
            for seed_metrics in self._per_seed(metrics):
                progress(update, seed_metrics)
        return state, {name: np.stack([np.atleast_1d(row[name]) for row in rows], axis=1) for name in rows[0]}

    def _per_seed(self, metrics: dict) -> list[dict]:
        """One update's metrics as one dict of scalars per seed of the group."""
        if not self.side_by_side:
            return [metrics]
        return [{name: float(value[i]) for name, value in metrics.items()} for i in range(self.spec.seeds)]

    def evaluate(self, group, state, progress=None) -> dict:
        params = self.learner.params(state)
        scores = {"sampled_return": [], "greedy_return": []}
        for i, seed in enumerate(group):
            own = seed_slice(params, i) if self.side_by_side else params
            for mode in ("sampled", "greedy"):
                returns = evaluate_host(self.learner, own, self.test_env, self.spec.eval_episodes,
                                        jax.random.key(EVAL_SEED_OFFSET + seed), greedy=mode == "greedy")
                scores[f"{mode}_return"].append(returns.mean())
        return {name: np.asarray(values) for name, values in scores.items()}

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
