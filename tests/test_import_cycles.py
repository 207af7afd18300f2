"""No import cycles in the project's packages (issue 49): the graph of which module imports which, read
from the source with `ast` (imports in function bodies and `if __name__ == "__main__"` blocks count:
they make a cycle as soon as that code runs), across packages too."""

import ast
from pathlib import Path

import pytest

PROJECT = Path(__file__).resolve().parents[1]
#: the packages kept free of cycles
PACKAGES = ("assets", "factory", "networks", "reconstruction")


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(packages: tuple[str, ...], root: Path = PROJECT) -> dict[str, set[str]]:
    """module -> the modules of `packages` (folders of `root`) it imports (a `from package import name`
    imports the module `package.name` when there is one, else the package itself)."""
    files = {module_name(path, root): path for package in packages for path in sorted((root / package).rglob("*.py"))}
    graph = {}
    for name, path in files.items():
        own_package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        found = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:  # relative: from the package `level` - 1 levels above this one
                    anchor = own_package.split(".")[: len(own_package.split(".")) - node.level + 1]
                    base = ".".join(anchor + ([base] if base else []))
                targets = [f"{base}.{alias.name}" for alias in node.names] + [base]
            else:
                continue
            for target in targets:
                while target and target not in files:
                    target = target.rpartition(".")[0]
                if target and target != name:
                    found.add(target)
                    break  # `from a.b import c`: module a.b.c if it is one, else a.b
        graph[name] = found
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of `graph` (its modules in order, the first repeated at the end), or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for other in sorted(graph.get(node, ())):
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


def test_the_finder_sees_a_cycle_through_a_function_level_and_a_relative_import(tmp_path):
    package = tmp_path / "pkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "build.py").write_text("from pkg.dataset import Config\n")
    (package / "dataset.py").write_text("class Config: ...\n\ndef main():\n    from . import merge\n")
    (package / "merge.py").write_text("import pkg.build\n")
    graph = import_graph(("pkg",), tmp_path)
    assert graph == {"pkg": set(), "pkg.build": {"pkg.dataset"}, "pkg.dataset": {"pkg.merge"},
                     "pkg.merge": {"pkg.build"}}
    assert find_cycle(graph) == ["pkg.build", "pkg.dataset", "pkg.merge", "pkg.build"]
    (package / "merge.py").write_text("import json\n")
    assert find_cycle(import_graph(("pkg",), tmp_path)) is None


@pytest.mark.parametrize("package", PACKAGES)
def test_a_package_has_no_import_cycle(package):
    graph = import_graph((package,))
    cycle = find_cycle(graph)
    assert cycle is None, f"import cycle: {' -> '.join(cycle)}"


def test_no_import_cycle_runs_across_the_packages():
    cycle = find_cycle(import_graph(PACKAGES))
    assert cycle is None, f"import cycle: {' -> '.join(cycle)}"
