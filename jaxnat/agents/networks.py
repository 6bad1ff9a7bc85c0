"""Actor-critic networks: the paper's trunks and a ResNet-18, channels-last, uint8 in.

Trunks (`TRUNKS`): the paper's CNNs `mnist`, `cifar`, `cityscapes` and `atari` (its appendix;
`_PAPER_CNNS`, tabled in `docs/environments.md` section 5), every conv VALID and followed by
ReLU, then a ReLU dense layer of 512; `resnet18` (3x3 stem, BasicBlocks [2, 2, 2, 2], no pool);
`mlp` (dense 64, 64, tanh; actor and critic each) for vector observations. `default_trunk`
picks one by observation size.

uint8 pixels are scaled to [0, 1] inside the network. `dtype` is the computation dtype of the
trunk (flax's convention: parameters stay float32): `"bfloat16"` runs its convolutions and dense
layer on a GPU's bf16 tensor cores; the heads (logits, value) always compute in float32, so
log-probabilities and value targets keep full precision. Dict observations (`{"pixels", "goal"}`)
embed the integer goal and concatenate it to the trunk's features. Heads: one categorical per
action factor (e.g. move and label) for Discrete and MultiDiscrete actions, or for a `Box` a
diagonal Gaussian (`distributions.Gaussian`): a linear mean and a learned, state-independent
log-std initialised at 0 (the authors' `DiagGaussian`, CleanRL, Brax); and a scalar value.
The convolutional trunks are shared by both heads, as the authors' `CNNBase`; the `mlp` trunk
is two networks, an actor MLP under the policy heads and a critic MLP under the value head, as
the authors' `MLPBase`, PureJaxRL and CleanRL have for vector observations (`docs/design.md`
says why). DQN's Q-network (`q_network=True`) has one MLP for its heads instead, `Q_MLP`.
With `memory > 0` a GRU over the trunk's features (and the previous action and reward) makes
the policy recurrent; the heads read features and GRU output side by side (`ActorCritic`).
The ResNet uses GroupNorm rather than BatchNorm: running batch statistics are mutable state that
does not fit a pure, vmapped on-policy learner.
"""

from __future__ import annotations

import functools
from typing import NamedTuple, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaxnat import spaces
from jaxnat.agents.conv import IMPLEMENTATIONS, conv2d, im2col_patches
from jaxnat.agents.distributions import Gaussian

__all__ = ["TRUNKS", "DTYPES", "ActorCritic", "LogStd", "Memory", "initial_memory", "one_step_sequence",
           "make_actor_critic", "default_trunk", "action_dims", "action_size", "is_box", "init_params",
           "im2col_patches"]

# (features, kernel, stride) per conv layer.
_PAPER_CNNS = {
    "mnist": [(10, 5, 2), (20, 5, 1), (10, 5, 1)],
    "cifar": [(6, 5, 2), (16, 5, 1), (6, 5, 1)],
    "cityscapes": [(32, 8, 7), (64, 4, 4), (32, 3, 1)],
    "atari": [(32, 8, 4), (64, 4, 2), (32, 3, 1)],
}
TRUNKS = (*_PAPER_CNNS, "resnet18", "mlp")
# The `mlp` trunk of a Q-network (DQN): CleanRL's and PureJaxRL's QNetwork.
Q_MLP = ((120, 84), "relu")
DTYPES = ("float32", "bfloat16")


def _dense(features: int, scale: float = np.sqrt(2), dtype: str = "float32", name: str | None = None) -> nn.Dense:
    return nn.Dense(features, kernel_init=nn.initializers.orthogonal(scale), dtype=dtype, name=name)


class ValidConv(nn.Module):
    """A VALID, strided 2-D convolution with an HWIO kernel (as `nn.Conv`); `implementation`
    picks how it is computed (`jaxnat.agents.conv`: im2col on CPU; on GPU XLA's own per seed,
    strided layers on space-to-depth inputs)."""

    features: int
    kernel: int
    stride: int
    implementation: str = "auto"
    dtype: str = "float32"  # computation dtype; the parameters are float32

    @nn.compact
    def __call__(self, x):
        kernel = self.param("kernel", nn.initializers.orthogonal(np.sqrt(2)),
                            (self.kernel, self.kernel, x.shape[-1], self.features))
        bias = self.param("bias", nn.initializers.zeros, (self.features,))
        x, kernel, bias = (a.astype(self.dtype) for a in (x, kernel, bias))
        return conv2d(x, kernel, self.stride, self.implementation) + bias


class PaperCNN(nn.Module):
    layers: Sequence[tuple[int, int, int]]
    dense: int = 512
    dtype: str = "float32"
    conv: str = "auto"  # `ValidConv.implementation`

    @nn.compact
    def __call__(self, x):
        for features, kernel, stride in self.layers:
            x = nn.relu(ValidConv(features, kernel, stride, self.conv, dtype=self.dtype)(x))
        x = x.reshape(*x.shape[:-3], -1)
        return nn.relu(_dense(self.dense, dtype=self.dtype)(x))


class BasicBlock(nn.Module):
    features: int
    stride: int
    dtype: str = "float32"

    @nn.compact
    def __call__(self, x):
        conv = functools.partial(nn.Conv, use_bias=False, dtype=self.dtype)
        norm = functools.partial(nn.GroupNorm, num_groups=8, dtype=self.dtype)
        residual = x
        y = nn.relu(norm()(conv(self.features, (3, 3), self.stride, padding="SAME")(x)))
        y = norm()(conv(self.features, (3, 3), padding="SAME")(y))
        if residual.shape != y.shape:
            residual = norm()(conv(self.features, (1, 1), self.stride)(residual))
        return nn.relu(y + residual)


class ResNet18(nn.Module):
    dense: int = 512
    dtype: str = "float32"

    @nn.compact
    def __call__(self, x):
        stem = nn.Conv(64, (3, 3), padding="SAME", use_bias=False, dtype=self.dtype)
        x = nn.relu(nn.GroupNorm(num_groups=8, dtype=self.dtype)(stem(x)))
        for i, features in enumerate([64, 128, 256, 512]):
            for j in range(2):
                x = BasicBlock(features, stride=2 if i > 0 and j == 0 else 1, dtype=self.dtype)(x)
        x = jnp.mean(x, axis=(-3, -2))
        return nn.relu(_dense(self.dense, dtype=self.dtype)(x))


class MLP(nn.Module):
    sizes: Sequence[int] = (64, 64)
    activation: str = "tanh"  # or "relu"
    dtype: str = "float32"

    @nn.compact
    def __call__(self, x):
        activation = {"tanh": nn.tanh, "relu": nn.relu}[self.activation]
        for size in self.sizes:
            x = activation(_dense(size, dtype=self.dtype)(x))
        return x


class LogStd(nn.Module):
    """A Gaussian policy's learned, state-independent log-std, broadcast to the mean's shape
    `[..., D]`: a bias with no kernel (its parameter is named `bias`), so K-FAC treats it as a
    layer whose input is the constant 1, as the authors' `AddBias` (`jaxnat.agents.kfac`)."""

    @nn.compact
    def __call__(self, mean):
        return jnp.broadcast_to(self.param("bias", nn.initializers.zeros, mean.shape[-1:]), mean.shape)


class Memory(NamedTuple):
    """What a recurrent policy reads beside the observation, per env (leading axes `[T, B]` in
    a call on a sequence, except `hidden`, which is the state before its first step, `[B, H]`).

    `prev_action` and `prev_reward` are those of the env's previous step: a policy that cannot
    see what it did cannot remember it (a classification agent must know which labels it has
    already been told were wrong). At an episode's first step (`start`) all three are zeroed.
    """

    hidden: jax.Array  # [B, H] float32: the GRU state
    prev_action: jax.Array  # int32 [..., F] (float32 [..., D] for a Box)
    prev_reward: jax.Array  # float32 [...]
    start: jax.Array  # bool [...]: the first step of an episode


def initial_memory(network: ActorCritic, batch: int) -> Memory:
    """The memory of `batch` envs before their first step (`network.memory > 0`)."""
    previous = ((batch, network.action_size), jnp.float32) if network.action_size else \
        ((batch, len(network.action_dims)), jnp.int32)
    return Memory(hidden=jnp.zeros((batch, network.memory), jnp.float32),
                  prev_action=jnp.zeros(*previous),
                  prev_reward=jnp.zeros((batch,), jnp.float32),
                  start=jnp.ones((batch,), bool))


def one_step_sequence(memory: Memory) -> Memory:
    """`memory` of a batch `[B, ...]` as a sequence of one step (per-step fields `[1, B, ...]`),
    the form a recurrent `ActorCritic` is called with."""
    per_step = jax.tree_util.tree_map(lambda x: x[None], memory._replace(hidden=None))
    return per_step._replace(hidden=memory.hidden)


class _ResettingGRU(nn.Module):
    """One GRU step whose state is zeroed first where an episode starts (scanned over time)."""

    features: int

    @nn.compact
    def __call__(self, hidden, inputs):
        x, start = inputs
        hidden = jnp.where(start[:, None], 0.0, hidden)
        return nn.GRUCell(self.features)(hidden, x)


class ActorCritic(nn.Module):
    """`(obs) -> (policy, value)`: the policy is a tuple of logits, one per action factor, or
    with `action_size > 0` (a Box of that many dimensions) a `Gaussian(mean, log_std)`.

    The `mlp` trunk's `actor` and `critic` MLPs have disjoint parameters (a Dict observation's
    goal embedding is built in each). With `memory`, the GRU is the actor's: the value reads the
    critic's features and the GRU output through a `stop_gradient`, so the value loss trains
    critic parameters only and the policy loss actor parameters only.

    With `memory > 0` (a GRU of that size) the call is `(obs, Memory) -> (logits, value,
    hidden)` over a sequence: `obs` `[T, B, ...]`, the memory's per-step fields `[T, B, ...]`
    and its `hidden` `[B, H]`; outputs are `[T, B, ...]` and the state after the last step.
    The trunk runs on all `T * B` observations at once; only the GRU steps through time, on the
    (actor) trunk's features with the previous action (one-hot per factor) and reward.
    """

    action_dims: Sequence[int]  # categories per factor; () with a Box
    trunk: str = "mnist"
    num_goals: int = 0  # > 0 for dict observations with an integer "goal"
    dtype: str = "float32"  # the trunk's computation dtype (see the module docstring)
    memory: int = 0  # GRU state size; 0: feed-forward (the paper's agents)
    q_network: bool = False  # DQN's: the "logits" are Q values, the value head is unused
    action_size: int = 0  # > 0: a Box of this many dimensions, a Gaussian policy
    conv: str = "auto"  # how the paper's trunks compute their convolutions (`jaxnat.agents.conv`)

    @nn.compact
    def __call__(self, obs, memory: Memory | None = None):
        if self.memory:
            if memory is None:
                raise ValueError("a recurrent network (memory > 0) is called as (obs, Memory)")
            time_batch = memory.start.shape
            obs = jax.tree_util.tree_map(lambda x: x.reshape(-1, *x.shape[len(time_batch):]), obs)
        separate = self.trunk == "mlp" and not self.q_network
        if separate:
            features, critic = self._features(obs, "actor"), self._features(obs, "critic")
        else:
            features = critic = self._features(obs)
        if self.memory:
            features, critic = (f.reshape(*time_batch, -1) for f in (features, critic))
            keep = ~memory.start[..., None]
            previous = ([memory.prev_action * keep] if self.action_size else
                        [jax.nn.one_hot(memory.prev_action[..., i], n) * keep for i, n in enumerate(self.action_dims)])
            x = jnp.concatenate([features, *previous, (memory.prev_reward[..., None] * keep)], axis=-1)
            gru = nn.scan(_ResettingGRU, variable_broadcast="params", split_rngs={"params": False})
            hidden, outputs = gru(self.memory, name="memory")(memory.hidden, (x, memory.start))
            features = jnp.concatenate([features, outputs], axis=-1)
            critic = jnp.concatenate([critic, jax.lax.stop_gradient(outputs)], axis=-1) if separate else features
        if self.action_size:
            mean = _dense(self.action_size, 0.01, name="mean")(features)
            policy = Gaussian(mean, LogStd(name="log_std")(mean))
        else:
            policy = tuple(_dense(n, 0.01)(features) for n in self.action_dims)
        value = _dense(1, 1.0)(critic)[..., 0]
        if self.memory:
            return policy, value, hidden
        return policy, value

    def _features(self, obs, branch: str | None = None):
        """The trunk's features (with the goal's embedding); `branch` names the modules of one
        of several trunks ("actor", "critic"), None keeps flax's automatic names."""
        named = (lambda suffix: f"{branch}{suffix}") if branch else (lambda suffix: None)
        pixels = obs["pixels"] if isinstance(obs, dict) else obs
        x = pixels.astype(jnp.float32)
        if pixels.dtype == jnp.uint8:
            x = x / 255.0
        x = x.astype(self.dtype)
        if self.trunk == "mlp":
            sizes, activation = Q_MLP if self.q_network else ((64, 64), "tanh")
            features = MLP(sizes, activation, dtype=self.dtype, name=named(""))(x)
        elif self.trunk == "resnet18":
            features = ResNet18(dtype=self.dtype)(x)
        else:
            features = PaperCNN(_PAPER_CNNS[self.trunk], dtype=self.dtype, conv=self.conv)(x)
        features = features.astype(jnp.float32)
        if self.num_goals:
            goal = nn.Embed(self.num_goals, 32, name=named("_goal"))(obs["goal"])
            features = nn.relu(_dense(512, name=named("_goal_dense"))(jnp.concatenate([features, goal], axis=-1)))
        return features


def is_box(action_space) -> bool:
    """Whether the env takes continuous actions (a `Box`, jaxnat's or gymnax's: duck-typed)."""
    return hasattr(action_space, "low") and hasattr(action_space, "high")


def action_dims(action_space) -> tuple[int, ...]:
    """Category counts per factor: Discrete(n) -> (n,), MultiDiscrete([a, b]) -> (a, b); a Box
    -> () (see `action_size`). Duck-typed (`nvec`, `n`, `low`/`high`), so gymnax's spaces work too."""
    if hasattr(action_space, "nvec"):
        return tuple(int(n) for n in action_space.nvec)
    if hasattr(action_space, "n") and not hasattr(action_space, "spaces"):
        return (int(action_space.n),)
    if is_box(action_space):
        return ()
    raise TypeError(f"The agents handle Discrete, MultiDiscrete and Box actions; this env's space is "
                    f"{action_space}")


def action_size(action_space) -> int:
    """A Box's dimension count (the Gaussian policy's size); 0 for discrete spaces."""
    if not is_box(action_space):
        return 0
    shape = tuple(np.shape(action_space.low)) or tuple(getattr(action_space, "shape", ()))
    if len(shape) != 1:
        raise ValueError(f"The agents take Box actions of one dimension [D]; this env's are shaped {shape}")
    return int(shape[0])


def _pixels(observation_space: spaces.Space) -> spaces.Space:
    """The image (or vector) part of an observation space: a Dict's "pixels", else the space."""
    return observation_space.spaces["pixels"] if isinstance(observation_space, spaces.Dict) else observation_space


def default_trunk(observation_space: spaces.Space) -> str:
    """The paper's trunk for an observation shape: 28 -> mnist, 32 -> cifar, 256 -> cityscapes,
    84 -> atari, 1-D -> mlp; other image sizes get the atari trunk if it fits, else resnet18."""
    shape = tuple(_pixels(observation_space).shape)
    if len(shape) == 1:
        return "mlp"
    side = min(shape[:2])
    by_size = {28: "mnist", 32: "cifar", 256: "cityscapes", 84: "atari"}
    return by_size.get(side, "atari" if side >= 36 else "resnet18")


def make_actor_critic(observation_space: spaces.Space, action_space: spaces.Space, trunk: str | None = None,
                      dtype: str = "float32", memory: int = 0, q_network: bool = False,
                      conv: str = "auto") -> ActorCritic:
    """An `ActorCritic` for these spaces; checks that the trunk fits the observation.
    `q_network`: DQN's network (the `mlp` trunk is then `Q_MLP`, one MLP for all heads), which
    needs discrete actions. `conv`: how the paper's trunks compute convolutions (one of
    `jaxnat.agents.conv.IMPLEMENTATIONS`; the same function each way)."""
    trunk = trunk or default_trunk(observation_space)
    if trunk not in TRUNKS:
        raise ValueError(f"Unknown trunk {trunk!r}; choose one of {TRUNKS}")
    if dtype not in DTYPES:
        raise ValueError(f"Unknown network dtype {dtype!r}; choose one of {DTYPES}")
    if conv not in IMPLEMENTATIONS:
        raise ValueError(f"Unknown conv implementation {conv!r}; choose one of {IMPLEMENTATIONS}")
    pixels = _pixels(observation_space)
    num_goals = int(observation_space.spaces["goal"].n) if pixels is not observation_space else 0
    if trunk in _PAPER_CNNS:
        if len(pixels.shape) != 3:
            raise ValueError(f"The {trunk!r} trunk needs [H, W, C] images; observations are {pixels.shape}. Use trunk='mlp'.")
        side = min(pixels.shape[:2])
        for _, kernel, stride in _PAPER_CNNS[trunk]:
            side = (side - kernel) // stride + 1
        if side < 1:
            raise ValueError(
                f"The {trunk!r} trunk does not fit {pixels.shape[0]}x{pixels.shape[1]} observations "
                f"(its convolutions shrink them below 1 pixel). Try trunk={default_trunk(observation_space)!r} "
                f"or 'resnet18'."
            )
    if trunk == "mlp" and len(pixels.shape) != 1:
        raise ValueError(f"trunk='mlp' needs vector observations; these are {pixels.shape}")
    if memory < 0:
        raise ValueError(f"memory is the GRU state size (0: feed-forward), got {memory}")
    if q_network and is_box(action_space):
        raise ValueError(f"DQN takes Discrete or MultiDiscrete actions, not {action_space}; "
                         f"train continuous actions with ppo, a2c or acktr")
    return ActorCritic(action_dims=action_dims(action_space), trunk=trunk, num_goals=num_goals, dtype=dtype,
                       memory=memory, q_network=q_network, action_size=action_size(action_space), conv=conv)


def init_params(network: ActorCritic, observation_space: spaces.Space, key: jax.Array):
    """The network's initial parameters; under `vmap` (one set per seed) they are built one
    seed after another.

    Why not batched: the orthogonal initialiser runs a QR, and jaxlib 0.10's CPU LAPACK kernels
    split a batched QR into tasks on XLA's intra-op pool and block waiting for them, which
    deadlocks when several run at once on a small pool (`jit(vmap(train))` over 5 seeds hung on
    2 cores). `sequential_vmap` turns the vmap of this one function into a loop; the result
    is the same stacked parameters, and init runs once per training run.
    """
    dummy = jax.tree_util.tree_map(jnp.zeros_like, observation_space.sample(jax.random.key(0)))
    args = (dummy,)
    if network.memory:  # a sequence of one step of one env
        args = (jax.tree_util.tree_map(lambda x: x[None, None], dummy), one_step_sequence(initial_memory(network, 1)))
    return jax.custom_batching.sequential_vmap(lambda k: network.init(k, *args))(key)
