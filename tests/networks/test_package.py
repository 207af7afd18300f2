"""The `networks` package as a user meets it: a flat documented API that imports without torch, no
import cycles among its modules, and no script beside the benchmarks that shadows it."""

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import networks

PROJECT = Path(__file__).resolve().parents[2]


def _imports(package: str) -> dict[str, set[str]]:
    """module -> the modules of `package` it imports anywhere in its source (function bodies and
    `if __name__ == "__main__"` blocks too: a cycle there is one as soon as that code runs)."""
    folder = PROJECT / package
    modules = {path.stem for path in folder.glob("*.py")}
    graph = {}
    for name in modules:
        found = set()
        for node in ast.walk(ast.parse((folder / f"{name}.py").read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                parts = node.module.split(".")
                if parts[0] == package and len(parts) > 1:
                    found.add(parts[1])
                elif node.module == package:
                    found |= {alias.name for alias in node.names}
            elif isinstance(node, ast.Import):
                found |= {alias.name.split(".")[1] for alias in node.names if alias.name.startswith(package + ".")}
        graph[name] = (found & modules) - {name}
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of `graph` (its modules in order, the first repeated at the end), or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for other in sorted(graph[node]):
            if state.get(other) == 1:
                return path[path.index(other):] + [other]
            if other not in state and (found := visit(other)):
                return found
        state[node] = 2
        path.pop()
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_the_cycle_finder_finds_one():
    assert _cycle({"data": {"synth"}, "synth": {"shards"}, "shards": {"data"}}) == ["data", "synth", "shards", "data"]
    assert _cycle({"data": {"synth"}, "synth": set(), "shards": {"data", "synth"}}) is None


def test_the_networks_modules_import_no_cycle():
    assert _cycle(_imports("networks")) is None


def test_import_networks_needs_no_torch():
    code = "import sys, networks; print(sorted(m for m in ('torch', 'cv2', 'tqdm') if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", code], cwd=PROJECT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_every_public_name_resolves_documented_and_survives_importing_the_modules():
    # importing a submodule sets it as an attribute of the package: no public name may be a module's
    for path in sorted((PROJECT / "networks").glob("*.py")):
        importlib.import_module(f"networks.{path.stem}")
    assert len(set(networks.__all__)) == len(networks.__all__)
    for name in networks.__all__:
        value = getattr(networks, name)
        assert not isinstance(value, type(networks)), name
        if callable(value):
            assert value.__doc__, name
        assert f"`{name}`" in networks.__doc__, f"{name} is not described in the package's docstring"
    assert set(networks.__all__) <= set(dir(networks))
    assert networks.TrainConfig("localizer").task == "localizer"


def test_no_script_beside_the_benchmarks_or_research_shadows_the_package():
    """`python benchmarks/x.py` puts benchmarks/ first on sys.path: a benchmarks/networks.py there would
    be imported for `import networks`."""
    for folder in ("benchmarks", "research"):
        assert not (PROJECT / folder / "networks.py").exists(), folder
