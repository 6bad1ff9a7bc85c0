"""MuJoCo Warp as the physics of the MJX robots: `MJXEnv(impl="warp")`.

MJX 3.17 steps a model through MuJoCo Warp (`mjx.put_model(model, impl="warp")`, the optional
`mujoco-warp` and `warp-lang` packages, the `warp` extra), whose kernels are faster than MJX's
JAX implementation on a GPU at the same model and solver bounds (bench/results/mjx_physics.md).
Warp's data is a batch of worlds, not one world: its contacts live in one pool across all the
worlds (`naconmax` in all), so the one-env state of jaxnat's envs, `vmap`ped by the caller,
cannot carry it. Here the env's state stays the JAX implementation's `mjx.Data` and Warp is a
pure function of it:

- **One env step** (`WarpPhysics.advance(data, action)`) copies the MuJoCo state of `data`
  (`STATE_FIELDS`: positions, velocities, controls, the solver's warm start, time) into Warp
  worlds whose other fields are as `mj_resetData` leaves them and whose contact pool is empty,
  runs `frame_skip` Warp `mj_step`s, and copies back every public field both implementations
  hold (positions of bodies and geoms, velocities, forces, ...): what the rewards, the
  observations and the renderer read. Contacts and constraint rows are rebuilt by each step's
  collision detection, as in MuJoCo C; they are not carried from one env step to the next.
  The JAX-implementation fields that Warp does not fill (its own contact and constraint
  arrays, in `data._impl`) keep the values reset left in them.
- **Batching**: `advance` is written for one world; under `jax.vmap`, nested or not (seeds x
  envs), a custom batching rule gathers every world of the call into one Warp batch, so one
  call steps `seeds x envs` worlds with one contact pool sized for all of them. Reset stays
  the JAX implementation's (`MJXEnv._reset_data`: positions only), so `AutoResetWrapper`'s
  select between the reset and the stepped state is a select of JAX arrays.
- **Capacity**: Warp allocates its contacts (across the worlds) and constraint rows (per
  world) up front and drops what does not fit (with a warning). `capacity` sizes them from
  MuJoCo C rollouts of the model under random actions: four times the most contacts one world
  had, and constraint rows for that many contacts plus twice the other rows a world had.
- **Warnings**: Warp prints a line when a step hits the Newton or line-search iteration
  bound; the fast settings bound them on purpose (MJX's JAX implementation stops there
  silently), so those two warnings are off. Dropped contacts and constraint rows still warn.
- **Not supported**: `mj_rnePostConstraint`'s `cfrc_ext` (Ant's observation and contact
  cost read it; MJX's Warp implementation has no such call), gradients through the step.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxnat.mjx_pixel import mjx_internals

__all__ = ["WarpPhysics", "capacity", "rows_per_contact", "require_warp", "STATE_FIELDS"]

# What one env step reads of the previous one: MuJoCo's state (mjSTATE_INTEGRATION's fields
# these robots have) and the solver's warm start. Everything else is recomputed by mj_step.
STATE_FIELDS = ("time", "qpos", "qvel", "act", "ctrl", "qacc_warmstart", "qfrc_applied",
                "xfrc_applied", "mocap_pos", "mocap_quat", "eq_active")


def require_warp():
    """MJX's module with MuJoCo Warp usable, or a one-line ImportError naming the fix."""
    try:
        import mujoco_warp  # noqa: F401, PLC0415
        import warp  # noqa: F401, PLC0415
        from mujoco import mjx  # noqa: PLC0415
        from mujoco.mjx.warp import types  # noqa: F401, PLC0415
    except ImportError as err:
        raise ImportError(f"impl='warp' needs MuJoCo Warp ({err}): pip install 'jaxnat[warp]' "
                          f"(mujoco-warp and warp-lang), or use impl='jax'") from None
    return mjx


def capacity(model: mujoco.MjModel, frame_skip: int, episodes: int = 3, steps: int = 300,
             seed: int = 0) -> tuple[int, int]:
    """`(contacts, constraints)` for one world of `model`, from MuJoCo C rollouts of `episodes`
    x `steps` env steps (`frame_skip` `mj_step`s each) under uniform random controls, from
    `mj_resetData`: four times the most contacts one world had, and room for that many
    contacts' constraint rows (each the most rows one contact of the model can make) plus
    twice the most other rows (joint limits, equalities, friction loss) a world had.

    A trained policy reaches states random controls do not (a flipped cheetah touches the
    floor with more geoms): sized from the random rollouts alone (twice their rows), Warp ran
    out of constraint rows in HalfCheetah's PPO on a GPU.
    """
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    contacts = other_rows = 1
    low, high = model.actuator_ctrlrange.T
    for _ in range(episodes):
        mujoco.mj_resetData(model, data)
        for _ in range(steps):
            data.ctrl[:] = rng.uniform(low, high)
            mujoco.mj_step(model, data, nstep=frame_skip)
            contact_rows = int(np.sum(data.efc_type >= int(mujoco.mjtConstraint.mjCNSTR_CONTACT_FRICTIONLESS)))
            contacts = max(contacts, data.ncon)
            other_rows = max(other_rows, data.nefc - contact_rows)
    contacts *= 4
    return contacts, contacts * rows_per_contact(model) + 2 * other_rows


def rows_per_contact(model: mujoco.MjModel) -> int:
    """The most constraint rows one contact of `model` can make: `condim` for elliptic friction
    cones, `2 (condim - 1)` for pyramidal ones (1 for a frictionless contact)."""
    condim = int(max(np.max(model.geom_condim, initial=1), np.max(model.pair_dim, initial=1)))
    if condim == 1 or model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC:
        return condim
    return 2 * (condim - 1)


class WarpPhysics:
    """`frame_skip` MuJoCo Warp `mj_step`s of `model` as a function of a JAX-implementation
    `mjx.Data` (see the module docstring). `contacts` and `constraints` per world default to
    `capacity(model, frame_skip)`."""

    def __init__(self, model: mujoco.MjModel, frame_skip: int, contacts: int | None = None,
                 constraints: int | None = None):
        mjx = require_warp()
        from mujoco_warp import OverflowType  # noqa: PLC0415

        self._mjx = mjx
        self.model = model
        self.frame_skip = int(frame_skip)
        if contacts is None or constraints is None:
            found = capacity(model, self.frame_skip)
            contacts = found[0] if contacts is None else contacts
            constraints = found[1] if constraints is None else constraints
        self.contacts, self.constraints = int(contacts), int(constraints)
        # The fast settings bound the solver's iterations on purpose: no warning for reaching them.
        self.warp_model = mjx_internals.without_warp_warnings(
            mjx.put_model(model, impl="warp"), OverflowType.ITERATIONS | OverflowType.LS_ITERATIONS)
        self._world_axis = mjx_internals.warp_world_axis()
        self._worlds_cache: dict[int, object] = {}
        jax_data = mjx.make_data(model, impl="jax")
        warp_data = mjx.make_data(model, impl="warp", naconmax=self.contacts, njmax=self.constraints)
        names = [f.name for f in dataclasses.fields(jax_data) if f.name != "_impl"]
        # Every public field both hold, with the same shape per world: copied back after a step.
        self.out_fields = tuple(
            n for n in names
            if getattr(jax_data, n) is not None and getattr(warp_data, n) is not None
            and np.shape(getattr(jax_data, n)) == np.shape(getattr(warp_data, n))
            and np.size(getattr(jax_data, n)) > 0)
        self.in_fields = tuple(n for n in STATE_FIELDS if n in self.out_fields)
        self._step_many = self._batched_step()

    def advance(self, data, action: jax.Array):
        """`data` (JAX implementation, one world) after `ctrl = action` and `frame_skip` steps."""
        state = {n: getattr(data, n) for n in self.in_fields}
        state["ctrl"] = jnp.asarray(action, data.ctrl.dtype)
        out = self._step_many(jax.tree.map(lambda x: x[None], state))
        return data.replace(**jax.tree.map(lambda x: x[0], out))

    def _worlds(self, n: int):
        """Warp data for `n` worlds as `mj_resetData` leaves them, the contact pool empty.
        Fields that hold one value are made with `jnp.full` (no literal of the pool's size in
        the program); the others broadcast one world's values."""
        if n not in self._worlds_cache:
            with jax.ensure_compile_time_eval():  # host arrays, also when called under a trace
                data = self._mjx.make_data(self.model, impl="warp", naconmax=n * self.contacts,
                                           njmax=self.constraints)
                self._worlds_cache[n] = jax.tree.map(np.asarray, data)
        data = self._worlds_cache[n]

        def fill(path, leaf):
            batched = self._world_axis.get(mjx_internals.field_name(path), True)
            shape = ((n,) if batched else ()) + leaf.shape
            if leaf.size == 0 or np.all(leaf == leaf.flat[0]):
                return jnp.full(shape, leaf.flat[0] if leaf.size else 0, leaf.dtype)
            return jnp.broadcast_to(jnp.asarray(leaf), shape)

        return jax.tree_util.tree_map_with_path(fill, data)

    def _advance_worlds(self, state: dict) -> dict:
        """`frame_skip` steps of every world of `state` (leaves `[worlds, ...]`) in one batch."""
        mjx = self._mjx
        data = self._worlds(state["qpos"].shape[0]).replace(**state)
        data = jax.lax.fori_loop(0, self.frame_skip, lambda _, d: mjx.step(self.warp_model, d), data)
        return {n: getattr(data, n) for n in self.out_fields}

    def _batched_step(self):
        """`_advance_worlds` with a batching rule that folds each `vmap` axis into the worlds."""

        @jax.custom_batching.custom_vmap
        def step_many(state):
            return self._advance_worlds(state)

        @step_many.def_vmap
        def rule(axis_size, in_batched, state):
            state = jax.tree.map(
                lambda x, b: x if b else jnp.broadcast_to(x, (axis_size,) + x.shape),
                state, in_batched[0])
            worlds = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), state)
            out = step_many(worlds)  # itself batched again under an outer vmap
            out = jax.tree.map(lambda x: x.reshape((axis_size, -1) + x.shape[1:]), out)
            return out, jax.tree.map(lambda _: True, out)

        return step_many

