"""Wrappers for host-batched envs (numpy `reset()` / `step(actions)`): reward clipping, JAX arrays,
and a batch made of parts that the host driver steps in turn.

    env = ClipRewardWrapper(jaxnat.make_vec("NaturalAtari/Breakout-v0", 8))
    env = DeviceArraysWrapper(env)      # jax arrays out, for jitted agents
    env = PipelinedVecEnv([ClipRewardWrapper(jaxnat.make_vec("NaturalAtari/Breakout-v0", 4)) for _ in range(2)])
"""

from __future__ import annotations

import jax
import numpy as np

__all__ = ["HostVecWrapper", "ClipRewardWrapper", "DeviceArraysWrapper", "PipelinedVecEnv"]


class HostVecWrapper:
    """Base: forwards `reset`, `step` and every other attribute to the wrapped env; a wrapper
    changes the actions going in (`_actions`) and the outcome of a step coming out (`_outcome`)."""

    def __init__(self, env):
        self.env = env

    def reset(self, **kwargs):
        return self.env.reset(**kwargs)

    def step(self, actions):
        return self._outcome(self.env.step(self._actions(actions)))

    def step_async(self, actions) -> None:
        """`step` in two halves, where the env has them (`NaturalAtariVecEnv`): named here so
        that a wrapper's `step_wait` is not bypassed by the attribute forwarding below."""
        self.env.step_async(self._actions(actions))

    def step_wait(self):
        return self._outcome(self.env.step_wait())

    def _actions(self, actions):
        return actions

    def _outcome(self, outcome):
        return outcome

    def __getattr__(self, name):
        return getattr(self.env, name)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.env!r})"


class ClipRewardWrapper(HostVecWrapper):
    """Training-time reward clipping to `[-bound, bound]` (DQN's sign clipping for bound 1).

    The unclipped reward stays in `info["unclipped_reward"]` (the env's own where it has one:
    `preprocessing="deepmind"` clips already, and clipping twice changes nothing else); the
    episode statistics in `info` (`returned_episode_returns`) are the env's, i.e. whole games
    with unclipped rewards.
    """

    def __init__(self, env, bound: float = 1.0):
        super().__init__(env)
        self.bound = float(bound)

    def _outcome(self, outcome):
        obs, reward, terminated, truncated, info = outcome
        info = {**info, "unclipped_reward": info.get("unclipped_reward", reward)}
        return obs, np.clip(reward, -self.bound, self.bound), terminated, truncated, info


class DeviceArraysWrapper(HostVecWrapper):
    """Outputs as JAX arrays on `device` (default: JAX's default device), for jitted agents.

    One `jax.device_put` of the whole output per call (a single host-to-device transfer of the
    observation batch; on the CPU backend, numpy memory may be used without a copy). Actions may
    be JAX arrays: they come back to the host once per step, as the emulator needs them there.
    """

    def __init__(self, env, device=None):
        super().__init__(env)
        self.device = device

    def reset(self, **kwargs):
        return jax.device_put(self.env.reset(**kwargs), self.device)

    def _actions(self, actions):
        return np.asarray(actions)

    def _outcome(self, outcome):
        return jax.device_put(outcome, self.device)


class PipelinedVecEnv:
    """One batch of `sum(part.num_envs)` envs made of `parts` (host-batched envs of the same
    game and settings): env `j` of the batch is env `j - offset` of the part holding it.

    As an env it steps every part (their emulators at once, where they step in two halves) and
    concatenates (`reset(seed=s)` seeds part `i` with `s + offset_i`, so emulator `j` gets seed
    `s + j`, as in one batch; `reset(seeds=...)` seeds each part as a batch of its own). The host driver
    (`jaxnat.agents.rollout.host_steps_pipelined`) steps the parts in turn instead: while ALE
    emulates one part, the device computes the next actions of another, so the policy's round
    trip, the host pass and the emulation overlap (EnvPool's asynchronous idea) while every
    action is still chosen by the current policy on the latest observation (exact on-policy
    steps). Parts with `step_async`/`step_wait` (`NaturalAtariVecEnv`, and the wrappers here
    around it) also overlap one part's host pass with the next part's emulation.

    `groups` (G, for the seeds of a run side by side in pipelined parts): every part holds an
    equal slice of each of G groups of envs (part `p`'s envs `g * k .. g * k + k - 1` are envs
    `p * k ..` of group `g`, `k` a part's envs per group), and `reset(seeds=...)` takes one
    seed per group: each group's envs reset as one batch of their own reset with its seed
    would, in parts (part `p` resets its groups with `reset(seeds=[seeds[g] + p * k ...])`,
    which its envs must take: `NaturalAtariVecEnv.reset(seeds=)`).
    """

    def __init__(self, parts, groups: int | None = None):
        if len(parts) < 1:
            raise ValueError("PipelinedVecEnv needs at least one part")
        self.parts = list(parts)
        sizes = [int(part.num_envs) for part in self.parts]
        if groups is not None and (groups < 1 or len(set(sizes)) != 1 or sizes[0] % groups):
            raise ValueError(f"groups={groups}: every part must hold an equal slice of each group; the parts have "
                             f"{sizes} envs")
        self.groups = groups
        self.offsets = list(np.cumsum([0, *sizes]))
        self.num_envs = int(self.offsets[-1])
        self.single_observation_space = self.parts[0].single_observation_space
        self.single_action_space = self.parts[0].single_action_space

    def split(self, batch):
        """`[num_envs, ...]` -> one view per part."""
        return [batch[lo:hi] for lo, hi in zip(self.offsets[:-1], self.offsets[1:])]

    def reset(self, *, seed: int | None = None, seeds=None):
        """Reset every part: with `seed`, as one batch (emulator `j` gets `seed + j`); with `seeds`
        (one per part), part `i` as a batch of its own reset with `seeds[i]` (its emulator `j`
        gets `seeds[i] + j`): parts that each replay another run's batch, such as the seeds of
        a run trained side by side; with `groups`, one per group (see the class)."""
        if seeds is not None:
            if seed is not None:
                raise ValueError("reset takes seed (one batch) or seeds (one per part or group), not both")
            count, per = (len(self.parts), "part") if self.groups is None else (self.groups, "group")
            if len(seeds) != count:
                raise ValueError(f"seeds: one per {per} ({count}), got {len(seeds)}")
            if self.groups is None:
                options = [{"seed": int(s)} for s in seeds]
            else:
                k = self.parts[0].num_envs // self.groups
                options = [{"seeds": [int(s) + p * k for s in seeds]} for p in range(len(self.parts))]
        else:
            options = [{} if seed is None else {"seed": int(seed) + int(offset)} for offset in self.offsets[:-1]]
        outs = [part.reset(**kwargs) for part, kwargs in zip(self.parts, options)]
        return np.concatenate([obs for obs, _ in outs]), _concat_infos([info for _, info in outs])

    def step(self, actions):
        """Every part steps; the parts with `step_async` get their actions before any outcome
        is awaited, so that their emulators run at once; then they are awaited in turn."""
        sent = []
        for part, a in zip(self.parts, self.split(np.asarray(actions))):
            if hasattr(part, "step_async"):
                part.step_async(a)
                sent.append(None)
            else:
                sent.append(part.step(a))
        outs = [part.step_wait() if out is None else out for part, out in zip(self.parts, sent)]
        obs, reward, terminated, truncated = (np.concatenate([out[i] for out in outs]) for i in range(4))
        return obs, reward, terminated, truncated, _concat_infos([out[4] for out in outs])

    def close(self) -> None:
        for part in self.parts:
            part.close()

    def __repr__(self) -> str:
        return f"PipelinedVecEnv({self.parts!r})"


def _concat_infos(infos):
    return {name: np.concatenate([np.asarray(info[name]) for info in infos]) for name in infos[0]
            if all(name in info for info in infos)}
