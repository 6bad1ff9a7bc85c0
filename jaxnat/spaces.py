"""Small jittable spaces: `Discrete`, `MultiDiscrete`, `Box`, `Dict`.

Every space has `sample(key)`, `contains(x)` (a traced boolean, usable under jit and vmap),
`check(x, what)` (a trace-time shape/dtype check with a readable error) and
`to_gymnasium()` for the Gymnasium adapter. Shapes and bounds are static Python/NumPy values,
so a space never depends on traced parameters.
"""

from __future__ import annotations

from typing import Any, Mapping

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Space", "Discrete", "MultiDiscrete", "Box", "Dict"]


def _require_gymnasium():
    try:
        import gymnasium
    except ImportError as err:  # pragma: no cover - exercised only without the extra
        raise ImportError(
            "Converting jaxnat spaces to Gymnasium spaces needs gymnasium: "
            "pip install 'jaxnat[gym]'"
        ) from err
    return gymnasium


class Space:
    """Base class. Subclasses set `shape` and `dtype`."""

    shape: tuple[int, ...]
    dtype: jnp.dtype

    def sample(self, key: jax.Array) -> Any:
        raise NotImplementedError

    def contains(self, x: Any) -> jax.Array:
        raise NotImplementedError

    def to_gymnasium(self):
        raise NotImplementedError

    def check(self, x: Any, what: str = "value") -> None:
        """Raise at trace time if `x` cannot belong to this space (wrong shape or dtype kind).

        Values are not checked (they are traced); shapes and dtypes are.
        """
        x_shape = tuple(jnp.shape(x))
        if x_shape != tuple(self.shape):
            raise ValueError(
                f"{what} has shape {x_shape} but the space {self} expects shape {tuple(self.shape)}. "
                "If you batched environments, call the env inside jax.vmap (or use VmapWrapper) "
                "so that each call sees one environment's " + what + "."
            )
        x_dtype = jnp.result_type(x)
        want_int = jnp.issubdtype(self.dtype, jnp.integer)
        if want_int and not jnp.issubdtype(x_dtype, jnp.integer):
            raise TypeError(
                f"{what} has dtype {x_dtype} but {self} holds integers ({self.dtype}). "
                f"Cast it, e.g. {what}.astype(jnp.int32)."
            )
        if not want_int and jnp.issubdtype(x_dtype, jnp.bool_):
            raise TypeError(f"{what} has dtype bool but {self} holds {self.dtype}.")


class Discrete(Space):
    """Integers `0 ... n-1`, scalar."""

    def __init__(self, n: int, dtype=jnp.int32):
        if int(n) < 1:
            raise ValueError(f"Discrete needs n >= 1, got {n}")
        self.n = int(n)
        self.shape = ()
        self.dtype = jnp.dtype(dtype)

    def sample(self, key: jax.Array) -> jax.Array:
        return jax.random.randint(key, (), 0, self.n, dtype=self.dtype)

    def contains(self, x: Any) -> jax.Array:
        x = jnp.asarray(x)
        return (jnp.shape(x) == ()) & jnp.all((x >= 0) & (x < self.n)) & _is_integral(x)

    def to_gymnasium(self):
        return _require_gymnasium().spaces.Discrete(self.n)

    def __repr__(self) -> str:
        return f"Discrete({self.n})"


class MultiDiscrete(Space):
    """A vector of independent integers, entry `i` in `0 ... nvec[i]-1`."""

    def __init__(self, nvec, dtype=jnp.int32):
        self.nvec = np.asarray(nvec, dtype=np.int64)
        if self.nvec.ndim != 1 or np.any(self.nvec < 1):
            raise ValueError(f"MultiDiscrete needs a 1-D vector of sizes >= 1, got {nvec!r}")
        self.shape = (int(self.nvec.shape[0]),)
        self.dtype = jnp.dtype(dtype)

    def sample(self, key: jax.Array) -> jax.Array:
        u = jax.random.uniform(key, self.shape)
        return jnp.floor(u * self.nvec).astype(self.dtype)

    def contains(self, x: Any) -> jax.Array:
        x = jnp.asarray(x)
        if jnp.shape(x) != self.shape:
            return jnp.asarray(False)
        return jnp.all((x >= 0) & (x < self.nvec)) & _is_integral(x)

    def to_gymnasium(self):
        return _require_gymnasium().spaces.MultiDiscrete(self.nvec)

    def __repr__(self) -> str:
        return f"MultiDiscrete({self.nvec.tolist()})"


class Box(Space):
    """An array of shape `shape` with entries in `[low, high]` (bounds broadcast)."""

    def __init__(self, low, high, shape: tuple[int, ...], dtype=jnp.float32):
        self.shape = tuple(int(s) for s in shape)
        self.dtype = jnp.dtype(dtype)
        self.low = np.broadcast_to(np.asarray(low), self.shape)
        self.high = np.broadcast_to(np.asarray(high), self.shape)
        if np.any(self.low > self.high):
            raise ValueError("Box needs low <= high everywhere")

    def sample(self, key: jax.Array) -> jax.Array:
        if jnp.issubdtype(self.dtype, jnp.integer):
            return jax.random.randint(
                key, self.shape, self.low, self.high.astype(np.int64) + 1, dtype=jnp.int32
            ).astype(self.dtype)
        low = np.maximum(self.low, -1e6)  # unbounded boxes sample a wide, finite range
        high = np.minimum(self.high, 1e6)
        return jax.random.uniform(key, self.shape, self.dtype, low, high)

    def contains(self, x: Any) -> jax.Array:
        x = jnp.asarray(x)
        if jnp.shape(x) != self.shape:
            return jnp.asarray(False)
        return jnp.all((x >= self.low) & (x <= self.high))

    def to_gymnasium(self):
        gym = _require_gymnasium()
        dtype = np.dtype(self.dtype)
        # The bounds in the space's own dtype (they are held as float64): Gymnasium warns of a
        # "precision lowered" cast otherwise, though no representable bound changes.
        return gym.spaces.Box(np.asarray(self.low).astype(dtype), np.asarray(self.high).astype(dtype),
                              self.shape, dtype)

    def __repr__(self) -> str:
        lo, hi = np.min(self.low), np.max(self.high)
        return f"Box({lo}, {hi}, {self.shape}, {self.dtype})"


class Dict(Space):
    """A mapping of named sub-spaces; samples and members are dicts with the same keys."""

    def __init__(self, spaces: Mapping[str, Space]):
        self.spaces = dict(spaces)
        self.shape = ()
        self.dtype = None

    def sample(self, key: jax.Array) -> dict:
        keys = jax.random.split(key, len(self.spaces))
        return {name: s.sample(k) for (name, s), k in zip(self.spaces.items(), keys)}

    def contains(self, x: Any) -> jax.Array:
        if not isinstance(x, Mapping) or set(x) != set(self.spaces):
            return jnp.asarray(False)
        ok = jnp.asarray(True)
        for name, s in self.spaces.items():
            ok = ok & s.contains(x[name])
        return ok

    def check(self, x: Any, what: str = "value") -> None:
        if not isinstance(x, Mapping) or set(x) != set(self.spaces):
            got = sorted(x) if isinstance(x, Mapping) else type(x).__name__
            raise ValueError(f"{what} must be a dict with keys {sorted(self.spaces)}, got {got}")
        for name, s in self.spaces.items():
            s.check(x[name], f"{what}[{name!r}]")

    def to_gymnasium(self):
        gym = _require_gymnasium()
        return gym.spaces.Dict({k: s.to_gymnasium() for k, s in self.spaces.items()})

    def __repr__(self) -> str:
        inner = ", ".join(f"{k!r}: {s}" for k, s in self.spaces.items())
        return f"Dict({{{inner}}})"


def _is_integral(x: jax.Array) -> jax.Array:
    if jnp.issubdtype(x.dtype, jnp.integer):
        return jnp.asarray(True)
    return jnp.all(x == jnp.round(x))
