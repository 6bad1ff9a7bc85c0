"""The README's code runs as written (its imports included)."""

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def _snippet(after: str) -> str:
    """The first ```python block after the heading `after`."""
    text = README.read_text()
    start = text.index(after)
    return re.search(r"```python\n(.*?)```", text[start:], re.S).group(1)


def test_agents_snippet_runs(capsys):
    from jaxnat.datasets import DatasetNotFoundError

    try:
        exec(compile(_snippet("## Agents"), "README.md (Agents)", "exec"), {})  # noqa: S102
    except DatasetNotFoundError:
        pytest.skip("Classify/Digits-v0 data not installed")
    printed = capsys.readouterr().out
    assert printed.count("[") == 2  # two per-seed arrays


def test_distraction_snippet_runs(capsys):
    """The one-program difficulty sweep: five strengths, one value each."""
    from jaxnat.datasets import DatasetNotFoundError

    try:
        exec(compile(_snippet("## Distraction as a dial"), "README.md (Distraction)", "exec"),  # noqa: S102
             {})
    except DatasetNotFoundError:
        pytest.skip("Classify/Digits-v0 data not installed")
    printed = capsys.readouterr().out
    assert printed.count(".") == 5  # five floats
