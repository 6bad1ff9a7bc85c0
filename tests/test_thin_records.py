"""scripts/thin_records.py: a reproduce folder's finished cells as committable records."""

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def thin():
    spec = importlib.util.spec_from_file_location("thin_records", ROOT / "scripts" / "thin_records.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _cell(out: Path, name: str, complete: bool) -> None:
    folder = out / name
    (folder / "checkpoints").mkdir(parents=True)
    (folder / "checkpoints" / "big.bin").write_bytes(b"\0" * 1000)
    (folder / "config.json").write_text('{"algo": "ppo"}')
    (folder / "summary.json").write_text(json.dumps({"complete": complete}))
    (folder / "eval.jsonl").write_text('{"update": 0, "test_return": 1.0}\n')
    rows = [{"update": 1, "seed": s, "env_steps": 64, "episode_return": 0.5 + s, "episodes": 3, "loss": 0.1,
             "approx_kl": 0.01, "entropy": 8.5} for s in range(2)] + [{"chunk": 1, "seconds": 2.0}]
    (folder / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_finished_cells_thinned_with_their_timings(thin, tmp_path, capsys):
    out, dest = tmp_path / "out", tmp_path / "dest"
    _cell(out, "mujoco-a", True)
    _cell(out, "mujoco-b", False)  # unfinished: stays behind
    _cell(out, "classify-c", True)
    timings = [{"cell": c, "seconds": 1.0} for c in ("mujoco-a", "mujoco-b", "classify-c")]
    (out / "timings.jsonl").write_text("".join(json.dumps(r) + "\n" for r in timings))

    assert thin.main([str(out), str(dest), "--cells", "mujoco-*"]) == 0
    assert sorted(p.name for p in dest.iterdir()) == ["mujoco-a", "timings.jsonl"]
    assert sorted(p.name for p in (dest / "mujoco-a").iterdir()) == ["config.json", "eval.jsonl", "metrics.jsonl",
                                                                     "summary.json"]
    rows = [json.loads(line) for line in (dest / "mujoco-a" / "metrics.jsonl").read_text().splitlines()]
    assert rows == [{"update": 1, "seed": s, "env_steps": 64, "episode_return": 0.5 + s, "episodes": 3,
                     "entropy": 8.5} for s in range(2)]
    assert (dest / "mujoco-a" / "eval.jsonl").read_text() == (out / "mujoco-a" / "eval.jsonl").read_text()
    assert [json.loads(r)["cell"] for r in (dest / "timings.jsonl").read_text().splitlines()] == ["mujoco-a"]

    # A cell already there is refused in one line; --skip-existing keeps it and adds the rest,
    # each timing row once.
    with pytest.raises(SystemExit) as exit_:
        thin.main([str(out), str(dest)])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "already holds mujoco-a: pass --skip-existing" in err
    assert thin.main([str(out), str(dest), "--skip-existing"]) == 0
    assert sorted(p.name for p in dest.iterdir()) == ["classify-c", "mujoco-a", "timings.jsonl"]
    assert [json.loads(r)["cell"] for r in (dest / "timings.jsonl").read_text().splitlines()] == ["mujoco-a",
                                                                                                  "classify-c"]


def test_not_a_folder(thin, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        thin.main([str(tmp_path / "missing"), str(tmp_path / "dest")])
    assert exit_.value.code == 2
    assert "is not a folder: give the --out folder of jaxnat reproduce" in capsys.readouterr().err
    assert not (tmp_path / "dest").exists()
