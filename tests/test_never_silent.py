"""`jaxnat train` never silent, never late: evaluation sized to the family's episode length,
a progress display while the test split is scored, and plainly named accuracies.

Nothing here trains: the runs stop at the env or are fed by hand, so the file takes seconds."""

import pytest

from jaxnat.training import command as train_command
from jaxnat.training.args import EVAL_EPISODES, default_eval_episodes, parse_args


class _Built(Exception):
    """Raised in place of building the envs: carries the spec `_setup` had resolved."""


def _spec_of(argv, tmp_path, monkeypatch):
    def stop(spec):
        raise _Built(spec)

    monkeypatch.setattr(train_command, "make_envs", stop)
    with pytest.raises(_Built) as built:
        train_command._setup(parse_args([*argv, "--run-dir", str(tmp_path / "run")]), None)
    return built.value.args[0]


@pytest.mark.parametrize("env_id, episodes", [("Classify/Digits-v0", 1000), ("Localize/Clutter-v0", 1000),
                                              ("MuJoCo/Hopper-v0", 10), ("PixelMuJoCo/Hopper-v0", 10)])
def test_eval_episodes_default_to_the_familys(env_id, episodes, tmp_path, monkeypatch):
    # 1,000 one-thousand-step MuJoCo episodes per seed per evaluation kept a CPU busy (and
    # silent) for 13 minutes: the default follows the episode length.
    assert _spec_of(["--env-id", env_id], tmp_path, monkeypatch).eval_episodes == episodes
    assert _spec_of(["--env-id", env_id, "--eval-episodes", "7"], tmp_path, monkeypatch).eval_episodes == 7


def test_every_family_has_a_documented_default(capsys):
    import jaxnat

    families = {env_id.split("/")[0] for env_id in jaxnat.registered_envs()}
    assert families <= set(EVAL_EPISODES)
    assert default_eval_episodes("NaturalAtari/Pong-v0") == 32
    with pytest.raises(SystemExit):
        parse_args(["--help"])
    help_text = " ".join(capsys.readouterr().out.replace("│", " ").split())
    assert "MuJoCo 10" in help_text and "Classify 1000" in help_text


def test_evaluation_programs_report_their_steps_once_per_step_not_per_seed():
    import jax
    import numpy as np

    import jaxnat
    from jaxnat.agents.rollout import make_chance

    env, params = jaxnat.make("Classify/Digits-v0", autoreset=False)
    steps = int(params.max_steps_in_episode)  # 20: a report after every step
    calls = []
    keys = jax.random.split(jax.random.key(0), 2)  # two seeds, vmapped as the trainer does
    reported = jax.jit(jax.vmap(make_chance(env, params, 4, progress=lambda *a: calls.append(tuple(map(int, a))))))
    scores = jax.device_get(reported(keys))
    assert sorted(calls) == [(0, t) for t in range(1, steps + 1)]
    # The report draws no key and returns nothing: the scores are the silent program's.
    silent = jax.device_get(jax.jit(jax.vmap(make_chance(env, params, 4)))(keys))
    for name in silent:
        np.testing.assert_array_equal(scores[name], silent[name])
    # Classify's first guess right: an episode that terminated at its first step.
    assert np.all((0 <= scores["first_step_terminated"]) & (scores["first_step_terminated"] <= scores["terminated_fraction"]))


def test_a_long_evaluation_prints_what_it_plays_and_an_estimate_without_a_terminal():
    import io
    import time

    from rich.console import Console

    from jaxnat.training.progress import EvalProgress

    out = io.StringIO()
    console = Console(file=out, force_terminal=False, width=200)
    with EvalProgress(console, "evaluating update 0 (2 seeds x 10 episodes of up to 1,000 steps)", 2, 1000,
                      interval=0.05) as shown:
        shown(0, 500)
        shown(0, 400)  # a late report from another device is not a step back
        time.sleep(0.2)
    lines = out.getvalue().splitlines()
    assert lines and lines[0].startswith("evaluating update 0 (2 seeds x 10 episodes of up to 1,000 steps)")
    assert "step 500/2,000" in lines[0] and "eta 0:00" in lines[0]
    out.truncate(0)
    with EvalProgress(console, "quick", 1, 20, interval=60):
        pass
    assert out.getvalue() == ""  # a quick evaluation adds nothing to a log


def test_a_terminal_shows_evaluation_in_the_training_bar():
    import io

    from rich.console import Console

    from jaxnat.training.progress import EvalProgress, Progress
    from jaxnat.training.spec import RunSpec

    class Config:
        num_envs, num_steps, total_timesteps = 8, 16, 512

    console = Console(file=io.StringIO(), force_terminal=True)
    bar = Progress(console, RunSpec("Classify/Digits-v0", {}, "ppo", Config(), 2, 0, 2, 16), 2, 0)
    with bar.progress, EvalProgress(console, "evaluating", 2, 20, bar) as shown:
        shown(1, 10)
        assert bar.progress.tasks[0].fields["test"] == "evaluating 75%"


def _summary(env_id: str) -> dict:
    metric = {"mean": 0.5, "std": 0.1, "per_seed": [0.4, 0.6]}
    names = ["train_return", "train_accuracy", "test_greedy_return", "test_greedy_accuracy",
             "test_sampled_return", "test_sampled_accuracy"]
    if env_id.startswith("Classify/"):
        names += ["test_greedy_first_guess_accuracy", "test_sampled_first_guess_accuracy"]
    return {"env_id": env_id, "algo": "ppo", "seeds": [0, 1], "env_steps_per_seed": 512,
            "metrics": dict.fromkeys(names, metric),
            "chance": {"return": 0.08, "terminated_fraction": 0.871, "first_step_terminated": 0.1},
            "steps_per_second": {"mean": 1000.0, "std": 10.0}, "wall_time_s": 3.0}


def test_classify_names_first_guess_accuracy_and_the_fraction_right_by_the_end(monkeypatch):
    # "accuracy" was the fraction of episodes that named the right label within M guesses (a
    # random policy: 87%), which read as below chance beside a return 5x chance.
    import io

    from rich.console import Console

    from jaxnat.training.chunk_loop import _scores_field
    from jaxnat.training.records import print_summary

    out = io.StringIO()
    print_summary(Console(file=out, width=200), _summary("Classify/Digits-v0"))
    table = out.getvalue()
    assert "test greedy first-guess accuracy" in table and "test greedy right label by episode end" in table
    assert "chance (random policy): test first-guess accuracy" in table and "10.0%" in table
    assert " accuracy " not in table.replace("first-guess accuracy", "")
    out = io.StringIO()
    print_summary(Console(file=out, width=200), _summary("MuJoCo/Hopper-v0"))
    assert "first-guess" not in out.getvalue() and "test greedy terminated" in out.getvalue()

    scores = {"greedy_return": [0.5], "sampled_return": [0.6], "greedy_terminated_fraction": [0.95],
              "greedy_first_step_terminated": [0.62]}
    assert "(first-guess accuracy 62.0%, right label by episode end 95.0%)" in _scores_field(scores, "Classify/MNIST-v0")
    assert "first-guess" not in _scores_field(scores, "Localize/Clutter-v0")


def _readme_block(heading: str) -> str:
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    return re.search(r"```python\n(.*?)```", text[text.index(heading):], re.S).group(1)


def test_readme_quick_start_draws_a_key_per_use(capsys):
    code = _readme_block("## Quick start")
    calls = [line for line in code.splitlines() if "env.reset" in line or ".sample)" in line or "= step(" in line]
    used = [line.split("jax.random.split(")[1].split(",")[0] for line in calls]
    assert len(used) == 3 and len(set(used)) == 3, used  # reset, sampling and step: three keys
    exec(compile(code.replace("n = 65536", "n = 256"), "README.md (Quick start)", "exec"), {})  # noqa: S102
    reward, terminated = map(float, capsys.readouterr().out.split())
    assert 0.0 < terminated < 0.3 and -0.1 < reward < 0.2


def test_readme_ppo_snippet_shows_its_output():
    code = _readme_block("## Agents")
    after = code[code.index("print(scores"):].splitlines()[1:]
    assert any(line.startswith("# [") for line in after), "the printed per-seed arrays, as they look"


def test_jaxnat_list_lists_the_env_ids(capsys):
    from jaxnat import cli

    assert cli.main(["list"]) == 0
    assert "Classify (" in capsys.readouterr().out
