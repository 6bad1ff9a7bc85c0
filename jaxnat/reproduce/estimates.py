"""How long the cells of `jaxnat reproduce` take, roughly: the estimate printed before starting
and the progress bar's plan, per cell and per stream of cells (the device cells, on one GPU or
shared among several, and the host cells alongside them on an accelerator), on this machine's
platform."""

from __future__ import annotations

from jaxnat.agents import ALGORITHMS
from jaxnat.reproduce.grid import CALIBRATION, Cell

# Rough env steps/s (all seeds of a cell together) and the seconds a cell spends besides
# training (compiling, where it is not hidden behind the cell before, evaluating, test play),
# per experiment, for the estimate printed before starting (with streams side by side, that of
# the longest stream: `estimate_total`) and for sharing the cells among GPUs; the progress bar's
# ETA then follows the measured pace. On a GPU the rate grows with the envs stepped at once
# (E = envs per seed x seeds) and saturates: `GPU_RATES[experiment] = (saturated rate, E at half
# of it)`, fitted to the quick profile's cells (bench/reproduce_cost.py) and the larger batches
# of bench/results (classification PPO at 2,048 envs x 5 seeds, PixelMuJoCo PPO at 1,024 x 5)
# and of the paper profile's first sitting (docs/reproduction/paper/SITTINGS.md: Clutter's A2C
# at 512 envs x 5 seeds).
# Natural Atari is bound by the host's cores: one rate. A calibration cell counts as its group's
# experiment; PixelMuJoCo's observations without rendering are faster by `OBSERVATION_SPEEDUP`
# (the state and constant cells: MJX's physics, not the renderer, bounds them; fitted to the
# paper profile's fourth sitting).
RATES = {"cpu": {"classify": 2e3, "localize": 3e2, "atari": 1e3, "mujoco": 2e2}}
GPU_RATES = {"classify": (6.5e5, 770), "localize": (7e4, 600), "atari": (1e4, 0), "mujoco": (1.05e5, 2048)}
OBSERVATION_SPEEDUP = {"noise": 1.5, "state": 2.0, "constant": 2.0}
COMPILE_S = {"cpu": {"classify": 15, "localize": 45, "atari": 15, "mujoco": 60},
             "gpu": {"classify": 8, "localize": 23, "atari": 106, "mujoco": 35}}
# Seconds a GPU spends per update besides stepping envs, by algorithm: what the rate model
# misses at the authors' small batches, where a cell is bound by its per-update launches (and
# ACKTR by its K-FAC step) rather than by env steps. Fitted to the paper profile's classification
# cells at the authors' batch (their times: bench/results/reproduce_cost.md); at 512 envs and for
# PPO the rate model alone holds. Device cells only; the CPU rates are per env step.
UPDATE_S = {"a2c": 0.0018, "acktr": 0.026}
# Per update, where a family's algorithm differs from `UPDATE_S`: PixelMuJoCo's A2C pays its
# float32 trunk and its evaluations (every `eval_every` updates, which 5-step rollouts make 3.2x
# as frequent per env step as PPO's) beyond the rate model, which PPO's cells fitted. Fitted to
# the paper profile's ninth sitting (bench/results/reproduce_cost.md).
FAMILY_UPDATE_S = {("mujoco", "a2c"): 0.1}
# Seconds a GPU spends per PPO optimizer step (updates x epochs x minibatches), beyond the rate
# model: the paper profile's classification PPO at 512 x 32 took about twice as long with the
# authors' 64 minibatches as with 4 at 10M env steps per seed (bench/results/reproduce_cost.md).
MINIBATCH_S = {"ppo": 0.00106}


def _family(cell: Cell) -> str:
    """The experiment whose rates a cell has (a calibration cell: its group's)."""
    return cell.labels.get("group", cell.experiment) if cell.experiment == CALIBRATION else cell.experiment


def rate(cell: Cell, seeds: int, platform: str) -> float:
    """The rough env steps/s of `cell` with `seeds` seeds on `platform` ("cpu" or "gpu")."""
    family = _family(cell)
    if platform == "cpu":
        base = RATES["cpu"][family]
    else:
        saturated, half = GPU_RATES[family]
        envs = cell.overrides.get("num_envs", ALGORITHMS[cell.algo].config().num_envs) * seeds
        base = saturated * envs / (envs + half)
    return base * OBSERVATION_SPEEDUP.get(cell.labels.get("observation"), 1.0) if family == "mujoco" else base


def detect_platform() -> str:
    """"cpu" when JAX runs on the CPU, else "gpu" (an accelerator): the key of `RATES`."""
    import jax

    return "cpu" if jax.default_backend() == "cpu" else "gpu"


def estimate_seconds(cell: Cell, seeds: int, platform: str) -> float:
    """A rough wall time of `cell` (compile + training + evaluation), for the ETA; on a GPU a
    device cell's updates add `UPDATE_S` (or `FAMILY_UPDATE_S`) each, and PPO's optimizer steps
    `MINIBATCH_S` each."""
    steps = cell.budget.total_timesteps * seeds
    seconds = COMPILE_S[platform][_family(cell)] + steps / rate(cell, seeds, platform)
    if platform == "gpu" and not cell.host and (cell.algo in UPDATE_S or cell.algo in MINIBATCH_S):
        config = ALGORITHMS[cell.algo].config()
        batch = cell.overrides.get("num_envs", config.num_envs) * cell.overrides.get("num_steps", config.num_steps)
        updates = cell.budget.total_timesteps / batch
        seconds += updates * FAMILY_UPDATE_S.get((_family(cell), cell.algo), UPDATE_S.get(cell.algo, 0.0))
        if cell.algo in MINIBATCH_S:
            steps = cell.overrides.get("update_epochs", config.update_epochs) * cell.overrides.get(
                "num_minibatches", config.num_minibatches)
            seconds += updates * steps * MINIBATCH_S[cell.algo]
    return seconds


def balance(cells: list[Cell], count: int, seconds: dict[str, float]) -> list[list[Cell]]:
    """`cells` shared among `count` streams by their estimated `seconds` (cell name -> seconds):
    longest first, each onto the stream with the least so far (LPT: the longest stream is then
    within 4/3 of the best split's; ties go to the cell earlier in the grid and the lower
    stream), each stream's cells then in grid order."""
    order = {c.name: i for i, c in enumerate(cells)}
    loads, parts = [0.0] * count, [[] for _ in range(count)]
    for cell in sorted(cells, key=lambda c: -seconds[c.name]):  # stable: equal estimates keep grid order
        least = loads.index(min(loads))
        loads[least] += seconds[cell.name]
        parts[least].append(cell)
    return [sorted(part, key=lambda c: order[c.name]) for part in parts]


# Cluster shares are balanced by the GPU estimates whatever machine a shard runs on, so that
# every shard of one grid computes the same split (`shard_cells`).
SHARD_PLATFORM = "gpu"


def shard_cells(cells: list[Cell], index: int, count: int, seeds: int) -> list[Cell]:
    """The `index`-th (0-based) of `count` disjoint shares of `cells` (every runnable cell of a
    grid, finished or not, so the split never moves as cells finish), balanced by their
    estimated GPU seconds (`balance`): the same on every machine, in grid order."""
    seconds = {c.name: estimate_seconds(c, seeds, SHARD_PLATFORM) for c in cells}
    return balance(cells, count, seconds)[index]


# A device cell whose update steps few envs (all its seeds together) leaves a GPU idle between
# small kernels: latency-bound, as the authors' A2C (16 x 5) and ACKTR (32 x 20) batches are.
# Several such cells sharing a GPU fill each other's idle time and each keep most of their pace
# (`PACK_PACE`, measured in the paper profile's third sitting: bench/results/reproduce_cost.md),
# where a cell with a large batch already fills the GPU and sharing slows it: `--pack-small N`
# packs only small cells.
SMALL_BATCH = 8192  # env steps per update, all seeds: at most this many is a small cell
PACK_PACE = 0.6  # each packed small cell's pace against its pace alone


def small(cell: Cell, seeds: int) -> bool:
    """Whether `cell` is a small (latency-bound) device cell: at most `SMALL_BATCH` env steps
    per update over its `seeds` seeds."""
    config = ALGORITHMS[cell.algo].config()
    envs = cell.overrides.get("num_envs", config.num_envs)
    steps = cell.overrides.get("num_steps", getattr(config, "num_steps", 1))
    return not cell.host and envs * steps * seeds <= SMALL_BATCH


def stream_gpu(name: str) -> int | None:
    """The GPU index of a stream named `gpu<i>` or, packed, `gpu<i>-<j>` (None: not a GPU's)."""
    if not name.startswith("gpu"):
        return None
    return int(name[3:].split("-")[0])


def _packed_split(device: list[Cell], gpus: int, pack: int, seconds: dict[str, float],
                  seeds: int) -> dict[str, list[Cell]]:
    """Device streams with the small cells `pack` to a GPU: the large cells on GPUs of their own
    (`gpu<i>`), the small ones on the others (`gpu<i>-<j>`), the GPUs shared between the two kinds
    by estimated work (a packed GPU does `pack x PACK_PACE` cells' work at once). With one GPU both
    kinds share it."""
    few = [c for c in device if small(c, seeds)]
    many = [c for c in device if not small(c, seeds)]
    if few and many and gpus >= 2:
        work_few = sum(seconds[c.name] for c in few) / (pack * PACK_PACE)
        work_many = sum(seconds[c.name] for c in many)
        packed = min(gpus - 1, max(1, round(gpus * work_few / (work_few + work_many))))
    else:
        packed = gpus if few else 0
    first = gpus - packed if gpus >= 2 or not few else 0  # the first packed GPU
    streams = {f"gpu{i}": part for i, part in enumerate(balance(many, max(first, 1), seconds)) if part}
    parts = balance(few, packed * pack, seconds) if few else []
    # Stream k on GPU first + k % packed: with fewer small cells than places, a GPU each first.
    streams.update({f"gpu{first + k % packed}-{k // packed}": part for k, part in enumerate(parts) if part})
    return streams


def split_streams(cells: list[Cell], overlap: bool, gpus: int = 1,
                  seconds: dict[str, float] | None = None, pack: int = 1, seeds: int = 1) -> dict[str, list[Cell]]:
    """The cells as the streams that run at the same time, each in grid order. With `gpus` >= 2:
    the device cells as `gpu0` ... (`balance`d by `seconds`; a stream with no cell is left out)
    and the host cells as `host`. With `pack` >= 2 and a GPU or more, the small device cells
    (`small`, with `seeds` seeds) train `pack` to a GPU in streams `gpu<i>-<j>` (`_packed_split`).
    Else `{"device": ..., "host": ...}` when `overlap` and both kinds have cells, or
    `{"all": cells}` (one after another)."""
    device, host = [c for c in cells if not c.host], [c for c in cells if c.host]
    if pack >= 2 and gpus >= 1:
        streams = _packed_split(device, gpus, pack, seconds, seeds)
        return {**streams, "host": host} if host else streams
    if gpus >= 2:
        streams = {f"gpu{i}": part for i, part in enumerate(balance(device, gpus, seconds)) if part}
        return {**streams, "host": host} if host else streams
    return {"device": device, "host": host} if overlap and device and host else {"all": list(cells)}


def estimate_total(streams: dict[str, list[Cell]], seeds: int, platform: str) -> float:
    """The estimated wall time of `streams` (`split_streams`): the longest stream, as they run at
    the same time (the sum of its cells' `estimate_seconds`). Contention between the streams
    (the accelerator's time, the host's cores while compiling) is not counted."""
    return max((sum(estimate_seconds(c, seeds, platform) for c in cells) for cells in streams.values()), default=0.0)


def duration(seconds: float) -> str:
    """`1h05m` or `4m07s`: an estimate as printed."""
    seconds = int(round(seconds))
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m" if seconds >= 3600 else f"{seconds // 60}m{seconds % 60:02d}s"
