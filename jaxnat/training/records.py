"""What a run writes and shows at the end: metrics/eval JSONL, the learning-curve PNG, the summary table."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from jaxnat.training.args import TrainError
from jaxnat.training.spec import RunSpec


def json_value(x):
    x = np.asarray(x)
    if np.issubdtype(x.dtype, np.integer) or x.dtype == bool:
        return int(x)
    value = float(x)
    return value if math.isfinite(value) else None


def read_jsonl(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def write_jsonl(path: Path, rows, mode: str = "a") -> None:
    with path.open(mode) as f:
        for row in rows:
            f.write(json.dumps(row) + "\n")


class History:
    """What the curve and the summary need, read from the run's metric rows: per update, each
    seed's train return and terminated fraction (`[updates, seeds]`, NaN where none); per
    evaluation, its update and each score over the seeds; every chunk's steps/s."""

    def __init__(self, spec: RunSpec):
        self.spec = spec
        self.updates = np.zeros(0)
        self.returns = self.terminated = np.zeros((0, spec.seeds))
        self.evals: list[dict] = []  # one per evaluation: update + arrays over seeds
        self.chunk_sps: list[float] = []

    @classmethod
    def load(cls, spec: RunSpec, metrics_rows: list[dict], eval_rows: list[dict]) -> History:
        history = cls(spec)
        index = {seed: i for i, seed in enumerate(spec.seed_values)}
        by_update: dict[int, np.ndarray] = {}
        for row in metrics_rows:
            arrays = by_update.setdefault(row["update"], np.full((2, spec.seeds), np.nan))
            for j, name in enumerate(("episode_return", "terminated_fraction")):
                value = row.get(name)
                arrays[j, index[row["seed"]]] = np.nan if value is None else value
        if by_update:
            history.updates = np.array(sorted(by_update))
            history.returns, history.terminated = np.stack([by_update[u] for u in history.updates], axis=1)
        evals: dict[int, dict] = {}
        for row in eval_rows:
            entry = evals.setdefault(row["update"], {"update": row["update"], "sps": row.get("steps_per_second")})
            for k, v in row.items():
                if k.startswith(("greedy_", "sampled_")):
                    entry.setdefault(k, np.full(spec.seeds, np.nan))[index[row["seed"]]] = np.nan if v is None else v
        for update in sorted(evals):
            sps = evals[update].pop("sps")
            history.evals.append(evals[update])
            if sps is not None:
                history.chunk_sps.append(sps)
        return history


def mean_std(values) -> tuple[float, float]:
    values = np.asarray(values, np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return float("nan"), float("nan")
    return float(values.mean()), float(values.std())


def nanmean(x, axis):
    x = np.asarray(x, np.float64)
    count = np.isfinite(x).sum(axis)
    total = np.where(np.isfinite(x), x, 0.0).sum(axis)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def terminated_label(env_id: str) -> str:
    """What the fraction of terminated episodes means, as displayed. Classify: "right label by
    episode end" (an episode ends at the first right guess, so with M guesses a random policy
    scores 1 - (1 - 1/classes)^M, 88% for 10 classes and M = 20: called "accuracy", it read as
    below chance beside a return far above it); Localize: "accuracy" (the target found); else
    "terminated" (a MuJoCo robot that fell, an Atari game over). The summary's keys keep the
    name "accuracy"."""
    family = env_id.split("/")[0]
    return {"Classify": "right label by episode end", "Localize": "accuracy"}.get(family, "terminated")


# Classify's first guess right (an episode that terminated at its first step): the accuracy a
# classifier reports, chance 1/classes; shown beside `terminated_label`'s fraction.
FIRST_GUESS = "first-guess accuracy"


def shows_first_guess(env_id: str) -> bool:
    """Whether the fraction of episodes ending at their first step is shown (`FIRST_GUESS`)."""
    return env_id.split("/")[0] == "Classify"


def line_with_band(ax, x, mean, low, high, label: str, **style):
    """Draw `mean` against `x` as a line with a shaded band from `low` to `high`; returns the line.

    Points where `mean` is not finite (an update in which no episode ended, in any seed) are left
    out, so the line joins the points on either side of a gap. Plotted as they are, with NaN, the
    line would break at every gap, and a value between two gaps would be an invisible point, the
    curve gone where episodes end less often than every update (long episodes, few envs).
    Carrying the last value over the gap instead would draw flat stretches nobody measured."""
    x, mean, low, high = (np.asarray(a, np.float64) for a in (x, mean, low, high))
    keep = np.isfinite(mean)
    line, = ax.plot(x[keep], mean[keep], label=label, **style)
    ax.fill_between(x[keep], low[keep], high[keep], alpha=0.2, color=line.get_color(), linewidth=0)
    return line


def plot(path: Path, spec: RunSpec, history: History, chance: dict | None = None) -> None:
    """Return and accuracy against env steps: train, test greedy and test sampled (mean ± std
    over seeds), and the uniform random policy's test scores (`chance`) as a dashed line."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    steps = history.updates * spec.steps_per_update
    eval_steps = np.array([e["update"] for e in history.evals]) * spec.steps_per_update
    fig = Figure(figsize=(11, 4.2), constrained_layout=True)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)

    def band(ax, x, per_seed, label, **style):
        if len(x) == 0:
            return
        mean = nanmean(per_seed, 1)
        centred = np.where(np.isfinite(per_seed), per_seed - mean[:, None], np.nan)
        std = np.sqrt(nanmean(centred**2, 1))
        line_with_band(ax, x, mean, mean - std, mean + std, label, **style)

    label = terminated_label(spec.env_id)
    panels = (("return", history.returns, "Episode return", "return"),
              ("terminated_fraction", history.terminated, f"{label.capitalize()} (fraction of episodes terminated)",
               label))
    for ax, (score, train, title, ylabel) in zip(axes, panels):
        band(ax, steps, train, "train (episodes ending in each rollout)", color="C0")
        for mode, color in (("greedy", "C1"), ("sampled", "C2")):
            key = f"{mode}_{score}"
            if history.evals and all(key in e for e in history.evals):  # (host runs score returns only)
                band(ax, eval_steps, np.stack([e[key] for e in history.evals]), f"test split, {mode}",
                     color=color, marker="o", markersize=3)
        if chance is not None and chance.get(score) is not None:
            ax.axhline(chance[score], color="0.4", linestyle="--", linewidth=1,
                       label="test split, uniform random policy")
        ax.set_title(title)
        ax.set_xlabel("env steps per seed")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    fig.suptitle(f"{spec.env_id}  {spec.algo}  (mean ± std over {spec.seeds} seeds)")
    fig.savefig(path, dpi=110)


def run_summary(spec: RunSpec, history: History, wall_time: float, complete: bool,
                chance: dict | None = None) -> dict:
    """The final table as JSON; `chance`: the uniform random policy's test scores (means over
    the seeds' evaluation keys), the baseline to read the test scores against."""
    updates = history.updates
    window = max(1, min(spec.eval_every, len(updates)))  # the last chunk's updates (NaN without any)
    per_seed = {"train_return": nanmean(history.returns[-window:], 0),
                "train_accuracy": nanmean(history.terminated[-window:], 0)}
    last = history.evals[-1] if history.evals else {}
    scores = [("test_greedy_return", "greedy_return"),
              ("test_greedy_accuracy", "greedy_terminated_fraction"),
              ("test_sampled_return", "sampled_return"),
              ("test_sampled_accuracy", "sampled_terminated_fraction")]
    if shows_first_guess(spec.env_id):
        scores += [("test_greedy_first_guess_accuracy", "greedy_first_step_terminated"),
                   ("test_sampled_first_guess_accuracy", "sampled_first_step_terminated")]
    for name, key in scores:
        per_seed[name] = last.get(key, np.full(spec.seeds, np.nan))
    metrics = {}
    for name, values in per_seed.items():
        mean, std = mean_std(values)
        metrics[name] = {"mean": json_value(mean), "std": json_value(std),
                         "per_seed": [json_value(v) for v in values]}
    sps_mean, sps_std = mean_std(history.chunk_sps)
    return {
        "env_id": spec.env_id, "algo": spec.algo, "seeds": spec.seed_values,
        "complete": complete,
        "updates": int(updates[-1]) if len(updates) else 0,
        "env_steps_per_seed": int(updates[-1]) * spec.steps_per_update if len(updates) else 0,
        "metrics": metrics,
        "chance": chance,
        "steps_per_second": {"mean": json_value(sps_mean), "std": json_value(sps_std),
                             "note": "env steps/s over all seeds, mean ± std over chunks"},
        "wall_time_s": wall_time,
    }


def print_summary(console, summary: dict) -> None:
    from rich.table import Table

    table = Table(title=f"{summary['env_id']} · {summary['algo']} · {len(summary['seeds'])} seeds · "
                        f"{summary['env_steps_per_seed']:,} env steps per seed")
    table.add_column("metric")
    table.add_column("mean", justify="right")
    table.add_column("± std", justify="right")
    term = terminated_label(summary["env_id"])
    labels = {"train_return": "train return (last chunk)", "train_accuracy": f"train {term} (last chunk)"}
    for mode in ("greedy", "sampled"):
        labels.update({f"test_{mode}_return": f"test {mode} return",
                       f"test_{mode}_first_guess_accuracy": f"test {mode} {FIRST_GUESS}",
                       f"test_{mode}_accuracy": f"test {mode} {term}"})

    def fmt(x, pattern):
        return "—" if x is None else format(x, pattern)

    for name, label in labels.items():
        if name not in summary["metrics"]:  # (first-guess accuracy: Classify, since it was recorded)
            continue
        m = summary["metrics"][name]
        pattern = ".1%" if "accuracy" in name else "+.4f"
        table.add_row(label, fmt(m["mean"], pattern), fmt(m["std"], pattern.lstrip("+")))
    chance = summary.get("chance")
    if chance:
        table.add_row("chance (random policy): test return", fmt(chance.get("return"), "+.4f"), "")
        if chance.get("terminated_fraction") is not None:
            table.add_row(f"chance (random policy): test {term}", fmt(chance["terminated_fraction"], ".1%"), "")
        if shows_first_guess(summary["env_id"]) and chance.get("first_step_terminated") is not None:
            table.add_row(f"chance (random policy): test {FIRST_GUESS}",
                          fmt(chance["first_step_terminated"], ".1%"), "")
    sps = summary["steps_per_second"]
    table.add_row("env steps/s (all seeds, over chunks)", fmt(sps["mean"], ",.0f"), fmt(sps["std"], ",.0f"))
    table.add_row("wall time", f"{summary['wall_time_s']:.1f} s", "")
    console.print(table)


# Logging sinks (`jaxnat train --log NAME ...`). metrics.jsonl and eval.jsonl stay the record of
# truth, written first; a sink mirrors the same rows to a tool's own viewer, and nothing is read
# back from it (on resume, rows dropped from the JSONL after the checkpoint may linger in a sink).
# Name -> (the module it imports, the pyproject extra that installs it).
SINKS = {"tensorboard": ("tensorboardX", "tensorboard"), "wandb": ("wandb", "wandb")}
# Row fields that place a value rather than being one.
ROW_KEYS = ("chunk", "update", "env_steps", "seed")


class Sink:
    """Where a run's rows are mirrored: `write(kind, rows)` with kind "train" (metrics.jsonl's
    rows, one per update per seed) or "eval" (eval.jsonl's, one per evaluation per seed), after
    they are in the JSONL; `close()` when the run stops."""

    def write(self, kind: str, rows: list[dict]) -> None:
        raise NotImplementedError

    def close(self) -> None:
        pass


def scalars(row: dict):
    """A row's `(name, value)` pairs worth plotting: its values, not where they belong, and no
    null (an update in which no episode ended has no return)."""
    return [(name, value) for name, value in row.items()
            if name not in ROW_KEYS and isinstance(value, (int, float)) and not isinstance(value, bool)]


def check_sinks(names) -> None:
    """Refuse an unknown sink or one whose package is missing, in one line, before anything is
    built or compiled: a run must not train for an hour and then fail to log."""
    import importlib

    for name in names:
        if name not in SINKS:
            raise TrainError(f"--log {name}: unknown sink; choose from {', '.join(SINKS)}")
        module, extra = SINKS[name]
        try:
            importlib.import_module(module)  # imported, not only found: a broken install fails now too
        except ImportError:
            raise TrainError(f"--log {name} needs the {module} package: pip install 'jaxnat[{extra}]'") from None


def open_sinks(names, run_dir: Path, config: dict) -> list[Sink]:
    """The sinks `names` (checked by `check_sinks`) for the run in `run_dir`; `config`: the run
    spec as JSON (W&B records it as the run's config)."""
    makers = {"tensorboard": TensorBoardSink, "wandb": WandbSink}
    return [makers[name](run_dir, config) for name in dict.fromkeys(names)]


class TensorBoardSink(Sink):
    """tensorboardX event files in `<run_dir>/tensorboard/seed_<s>/`: one TensorBoard run per
    seed, so the seeds' curves overlay on one chart per tag (`train/episode_return`,
    `eval/greedy_return`, ...), against env steps per seed like curve.png. A resumed run adds
    event files beside the earlier ones; TensorBoard reads them together."""

    def __init__(self, run_dir: Path, config: dict):
        self.root = Path(run_dir) / "tensorboard"
        self.writers: dict = {}

    def _writer(self, seed: int):
        if seed not in self.writers:
            from tensorboardX import SummaryWriter

            self.writers[seed] = SummaryWriter(logdir=str(self.root / f"seed_{seed}"))
        return self.writers[seed]

    def write(self, kind: str, rows: list[dict]) -> None:
        for row in rows:
            writer = self._writer(row["seed"])
            for name, value in scalars(row):
                writer.add_scalar(f"{kind}/{name}", value, global_step=row["env_steps"])
        for writer in self.writers.values():
            writer.flush()  # a chunk's rows are on disk when the chunk is (a viewer follows the run)

    def close(self) -> None:
        for writer in self.writers.values():
            writer.close()


class WandbSink(Sink):
    """One W&B run per jaxnat run, its id kept in `<run_dir>/wandb_run_id` so that `--resume`
    continues the same W&B run; W&B's files go under `<run_dir>/wandb/`. The user's W&B settings
    (WANDB_MODE, WANDB_PROJECT, WANDB_ENTITY, a login) apply as they are; without WANDB_PROJECT
    the project is "jaxnat". Values are keyed `seed_<s>/<kind>/<name>` and plotted against
    `env_steps` (a metric of its own, `define_metric`), not W&B's step: W&B drops a row whose
    step goes back, and a host run may train its seeds one after another (`--host-seeds
    sequential`: seed 1's updates start at 1 again), as a resume redoes the updates after its
    checkpoint."""

    def __init__(self, run_dir: Path, config: dict):
        import os
        import secrets

        import wandb

        id_path = Path(run_dir) / "wandb_run_id"
        run_id = id_path.read_text().strip() if id_path.is_file() else secrets.token_hex(4)
        id_path.write_text(run_id + "\n")
        options = {} if os.environ.get("WANDB_PROJECT") else {"project": "jaxnat"}
        self.run = wandb.init(id=run_id, resume="allow", name=Path(run_dir).name, dir=str(run_dir), config=config,
                              **options)
        self.run.define_metric("env_steps")
        self.run.define_metric("*", step_metric="env_steps")

    def write(self, kind: str, rows: list[dict]) -> None:
        # One log call per env-step count: every seed of a device run's update in one row.
        logged: dict[int, dict] = {}
        for row in rows:
            values = logged.setdefault(row["env_steps"], {"env_steps": row["env_steps"]})
            values.update({f"seed_{row['seed']}/{kind}/{name}": value for name, value in scalars(row)})
        for values in logged.values():
            self.run.log(values)

    def close(self) -> None:
        self.run.finish()
