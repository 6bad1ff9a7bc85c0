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
