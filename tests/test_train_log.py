"""`jaxnat train --log`: the sinks that mirror metrics.jsonl and eval.jsonl (TensorBoard, W&B),
and extending a finished run with `--resume RUN --total-timesteps N`.

One tiny run (test_train.py's TINY) trains with both sinks, W&B's a fake module (no network,
no heavy install), then is extended; the TensorBoard events are read back with tensorboardX's
own protobuf and TFRecord's framing, so the test needs no TensorFlow or tensorboard package.
"""

import json
import struct
import sys
import types

import pytest

from jaxnat import train
from jaxnat.training import command as train_command
from tests.test_train import FAST, TINY, _error, _lines, _not_reached, needs_digits


def _events(run_dir, seed) -> dict:
    """`{(tag, step): value}` from every event file of a seed's TensorBoard run (TFRecord
    framing: length u64, its crc u32, the event, its crc u32)."""
    from tensorboardX.proto import event_pb2

    scalars = {}
    for path in sorted((run_dir / "tensorboard" / f"seed_{seed}").glob("events.out.tfevents.*")):
        data, i = path.read_bytes(), 0
        while i < len(data):
            (length,) = struct.unpack("<Q", data[i:i + 8])
            event = event_pb2.Event.FromString(data[i + 12:i + 12 + length])
            i += 12 + length + 4
            for value in event.summary.value:
                scalars[(value.tag, event.step)] = value.simple_value
    return scalars


def _expected(rows, kind, seed) -> dict:
    return {(f"{kind}/{name}", row["env_steps"]): value for row in rows if row["seed"] == seed
            for name, value in row.items()
            if name not in ("chunk", "update", "env_steps", "seed") and isinstance(value, (int, float))}


class FakeRun:
    def __init__(self, calls, **options):
        self.calls = calls
        calls.append(("init", options))

    def define_metric(self, name, **options):
        self.calls.append(("define_metric", name, options))

    def log(self, values):
        self.calls.append(("log", values))

    def finish(self):
        self.calls.append(("finish",))


@pytest.fixture
def fake_wandb(monkeypatch):
    """A `wandb` module that records its calls."""
    calls = []
    module = types.ModuleType("wandb")
    module.init = lambda **options: FakeRun(calls, **options)
    monkeypatch.setitem(sys.modules, "wandb", module)
    monkeypatch.delenv("WANDB_PROJECT", raising=False)
    return calls


def _check_sinks(run, calls, updates):
    metrics, evals = _lines(run / "metrics.jsonl"), _lines(run / "eval.jsonl")
    assert max(r["update"] for r in metrics) == updates
    for seed in (0, 1):
        events = _events(run, seed)
        expected = {**_expected(metrics, "train", seed), **_expected(evals, "eval", seed)}
        assert events.keys() == expected.keys()
        assert events == pytest.approx(expected, rel=1e-6)

    logged = [c[1] for c in calls if c[0] == "log"]
    steps = sorted({r["env_steps"] for r in metrics} | {r["env_steps"] for r in evals})
    assert sorted({values["env_steps"] for values in logged}) == steps
    train_logged = {}
    for values in logged:
        train_logged.update({(k, values["env_steps"]): v for k, v in values.items() if "/train/" in k})
    assert train_logged == {(f"seed_{r['seed']}/train/{k}", r["env_steps"]): v for r in metrics
                            for k, v in r.items() if k not in ("update", "env_steps", "seed") and v is not None}


@needs_digits
def test_sinks_mirror_the_records_and_a_finished_run_extends(tmp_path, capsys, fake_wandb):
    run = tmp_path / "run"
    assert train.main([*TINY, "--run-dir", str(run), "--log", "tensorboard", "wandb"], compiler_options=FAST) == 0
    init = fake_wandb[0]
    assert init[0] == "init" and init[1]["config"]["config"]["total_timesteps"] == 512
    assert init[1]["project"] == "jaxnat" and init[1]["id"] == (run / "wandb_run_id").read_text().strip()
    assert ("define_metric", "*", {"step_metric": "env_steps"}) in fake_wandb
    assert fake_wandb[-1] == ("finish",)
    _check_sinks(run, fake_wandb, 4)

    # Shortening the run, or lengthening it by less than an update, is refused before compiling;
    # the message shows both values, and nothing in the run directory changes.
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(train_command, "compiled_program", _not_reached)
        for steps, why in (("256", "cannot shorten"), ("600", "adds no update")):
            capsys.readouterr()
            assert train.main(["--resume", str(run), "--total-timesteps", steps]) == 2
            err = _error(capsys)
            assert err.count("\n") == 1 and why in err and f"--total-timesteps {steps} (the run: 512" in err
            assert "give at least 640" in err
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before

    # Extended from 4 to 6 updates: the records continue where they were (the first rows
    # unchanged, nothing redone), evaluation keeps its cadence, the sinks follow.
    (calls_before, metrics_before) = len(fake_wandb), (run / "metrics.jsonl").read_text()
    assert train.main(["--resume", str(run), "--total-timesteps", "768", "--log", "tensorboard", "wandb"],
                      compiler_options=FAST) == 0
    assert "extending the run from 4 to 6 updates" in capsys.readouterr().out
    assert (run / "metrics.jsonl").read_text().startswith(metrics_before)
    metrics, evals = _lines(run / "metrics.jsonl"), _lines(run / "eval.jsonl")
    assert [(m["update"], m["seed"]) for m in metrics] == [(u, s) for u in range(1, 7) for s in (0, 1)]
    assert [(e["update"], e["chunk"]) for e in evals[::2]] == [(0, 0), (2, 1), (4, 2), (6, 3)]
    summary = json.loads((run / "summary.json").read_text())
    assert summary["complete"] and summary["env_steps_per_seed"] == 768
    config = json.loads((run / "config.json").read_text())
    assert config["spec"]["config"]["total_timesteps"] == 768 and config["spec"]["num_updates"] == 6
    assert config["extensions"][0]["total_timesteps"] == [512, 768]
    assert fake_wandb[calls_before][1]["id"] == init[1]["id"]  # the same W&B run, continued
    _check_sinks(run, fake_wandb, 6)  # both sessions' rows, W&B's and TensorBoard's
    # The rate after the extension is the new schedule's, not the old one's end (0, where the
    # policy would not move between PPO's minibatches and every approx_kl would be 0): it learns.
    assert all(m["approx_kl"] > 0 for m in metrics if m["update"] > 4)
    # Resumed again without --total-timesteps: the run's length is now 6 updates, all done.
    assert train.main(["--resume", str(run)], compiler_options=FAST) == 0
    assert "finished before" in capsys.readouterr().out


def test_a_missing_sink_package_is_refused_before_compiling(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(train_command, "compiled_program", _not_reached)
    monkeypatch.setattr(train_command, "_setup", _not_reached)
    monkeypatch.setitem(sys.modules, "wandb", None)  # import wandb raises ImportError
    assert train.main([*TINY, "--run-dir", str(tmp_path / "run"), "--log", "wandb"]) == 2
    err = _error(capsys)
    assert err.count("\n") == 1 and "pip install 'jaxnat[wandb]'" in err
    assert train.main([*TINY, "--run-dir", str(tmp_path / "run"), "--log", "mlflow"]) == 2
    assert "unknown sink" in _error(capsys)
    assert not (tmp_path / "run").exists()


@needs_digits
def test_the_real_wandb_package_takes_the_records_offline(tmp_path, monkeypatch):
    """The sink against W&B itself (skipped where the `wandb` extra is not installed, as in CI):
    an offline run (`WANDB_MODE=offline`) under `<run_dir>/wandb/`, its id the one jaxnat keeps,
    every record row logged through the real `Run.log` with `env_steps` as its x-axis."""
    wandb = pytest.importorskip("wandb")
    from wandb.sdk.wandb_run import Run

    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    monkeypatch.delenv("WANDB_PROJECT", raising=False)
    logged, real_log = [], Run.log

    def log(self, data, *args, **kwargs):
        logged.append(dict(data))
        return real_log(self, data, *args, **kwargs)

    monkeypatch.setattr(Run, "log", log)
    run = tmp_path / "run"
    assert train.main([*TINY, "--run-dir", str(run), "--log", "wandb"], compiler_options=FAST) == 0
    run_id = (run / "wandb_run_id").read_text().strip()
    (offline,) = (run / "wandb").glob("offline-run-*")
    assert offline.name.endswith(run_id) and (offline / f"run-{run_id}.wandb").stat().st_size > 0
    metrics, evals = _lines(run / "metrics.jsonl"), _lines(run / "eval.jsonl")
    assert sorted({v["env_steps"] for v in logged}) == sorted({r["env_steps"] for r in [*metrics, *evals]})
    last = next(r for r in reversed(metrics) if r["seed"] == 1)
    row = next(v for v in logged if v["env_steps"] == last["env_steps"] and "seed_1/train/episode_return" in v)
    assert row["seed_1/train/episode_return"] == pytest.approx(last["episode_return"], rel=1e-6)
    assert wandb.run is None  # finished
