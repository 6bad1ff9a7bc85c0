"""The import graph: no cycles between modules, and the layering of the packages.

Every `import` in jaxnat's source counts, at any depth (an import inside a function is a
dependency all the same). `from jaxnat.a import b` depends on the module `jaxnat.a.b` when that
is a module, else on `jaxnat.a` (its `__init__`).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "jaxnat"

# package -> packages it must never import. The agents learn and know nothing of run
# directories; envs know nothing of agents or training.
FORBIDDEN = {
    "agents": {"training"},
    **{env: {"agents", "training"} for env in ("vision_envs", "mjx_pixel", "atari", "datasets", "natural",
                                               "wrappers", "compat")},
}
# The data packages are layered one way: `natural` (frame banks, noise, the clutter scenes) builds on
# `datasets` (finding, caching and decoding files, its errors); `datasets` never imports `natural`.
FORBIDDEN["datasets"] = FORBIDDEN["datasets"] | {"natural"}


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in ROOT.rglob("*.py")}


def _imports(path: Path, modules: dict[str, Path]) -> set[str]:
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.split(".")[0] == "jaxnat")
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            if base.split(".")[0] != "jaxnat":
                continue
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                found.add(sub if sub in modules else base)
    return {m for m in found if m in modules and m != name}


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(path, modules) for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycles():
    assert _cycles(_graph()) == []


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_package_layering(package):
    bad = sorted(f"{module} imports {target}" for module, targets in _graph().items()
                 if module.split(".")[1:2] == [package]
                 for target in targets if target.split(".")[1:2] and target.split(".")[1] in FORBIDDEN[package])
    assert bad == []


def test_the_cycle_finder_finds_cycles():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


@pytest.mark.parametrize("script", sorted(p.name for p in (ROOT.parent / "bench").glob("*.py")))
def test_bench_scripts_compile(script):
    """The benches are not imported by the suite (their peers are optional installs), so a
    compile-time error (a misplaced `global`, say) would otherwise reach the GPU first."""
    path = ROOT.parent / "bench" / script
    compile(path.read_text(), str(path), "exec")


# The fields only learners' runners have (`rollout.RunnerState`, `dqn.DQNRunner`,
# `rollout.HostState`), and the ones they share with other objects (an env wrapper's state has
# `env_state`), which count only on a runner's usual names.
RUNNER_ONLY_FIELDS = {"train_state", "normalizer", "target_params", "buffer", "recent"}
RUNNER_SHARED_FIELDS = {"update", "learner", "env_state", "obs", "memory", "key"}
RUNNER_NAMES = {"runner", "runners", "state", "saved", "restored", "resumed"}


def _runner_field_reads(path: Path) -> list[str]:
    """`file:line: expression` for each read of a runner's field in `path` (a method call such
    as `dict.update(...)` is not a field read)."""
    tree = ast.parse(path.read_text(), str(path))
    called = {id(node.func) for node in ast.walk(tree) if isinstance(node, ast.Call)}
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute) or id(node) in called:
            continue
        base = node.value.attr if isinstance(node.value, ast.Attribute) else getattr(node.value, "id", None)
        if node.attr in RUNNER_ONLY_FIELDS or (node.attr in RUNNER_SHARED_FIELDS and base in RUNNER_NAMES):
            found.append((node.lineno, f"{path.name}:{node.lineno}: {ast.unparse(node)}"))
    return [read for _, read in sorted(found)]


def test_nothing_outside_the_agents_names_a_runners_fields():
    """The learner seam: training, reproduce, jaxnat's other modules that may use the agents,
    the benches and scripts read a runner only through its learner (`Learner.policy_of`,
    `per_env`, `updates_of`; `HostLearner.params`, `updates_of`), so an algorithm may change what
    its runner holds without touching them. (The env packages may not import the agents at
    all: `test_package_layering`.)"""
    envs = {package for package, forbidden in FORBIDDEN.items() if "agents" in forbidden}
    files = [p for p in ROOT.rglob("*.py") if p.relative_to(ROOT).parts[0] not in envs | {"agents"}]
    files += sorted((ROOT.parent / "bench").glob("*.py")) + sorted((ROOT.parent / "scripts").glob("*.py"))
    assert [read for path in files for read in _runner_field_reads(path)] == []


def test_the_runner_field_finder_finds_field_reads(tmp_path):
    path = tmp_path / "probe.py"
    path.write_text("x = runner.train_state.params\nstate.update\nd.update({})\nwrapped.env_state\n"
                    "self.learner.init(key)\nn = state.normalizer\n")
    assert [line.split(": ", 1)[1] for line in _runner_field_reads(path)] == [
        "runner.train_state", "state.update", "state.normalizer"]
