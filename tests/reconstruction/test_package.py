"""The `reconstruction` package as a user meets it: a flat documented API that imports without OpenCV,
torch or bpy, no import cycles among its modules, and bpy in one leaf module (the review) that no other
module imports."""

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import reconstruction

PROJECT = Path(__file__).resolve().parents[2]
FOLDER = PROJECT / "reconstruction"


def _imports(path: Path) -> set[str]:
    """Every module `path` imports anywhere in its source (function bodies too: a lazy import is an
    import as soon as that code runs), by full name."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
            found |= {f"{node.module}.{alias.name}" for alias in node.names}
        elif isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
    return found


def _graph() -> dict[str, set[str]]:
    """module -> the modules of the package it imports."""
    modules = {path.stem for path in FOLDER.glob("*.py")} - {"__init__"}
    return {name: {m.split(".")[1] for m in _imports(FOLDER / f"{name}.py") if m.startswith("reconstruction.")}
            & modules - {name} for name in modules}


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
    assert _cycle({"exports": {"review"}, "review": {"pipeline"}, "pipeline": {"exports"}}) == \
        ["exports", "review", "pipeline", "exports"]
    assert _cycle({"exports": set(), "review": {"exports"}, "pipeline": {"exports"}}) is None


def test_the_modules_import_no_cycle_and_only_the_review_imports_bpy():
    graph = _graph()
    assert _cycle(graph) is None
    assert [name for name in graph if "review" in graph[name]] == []  # a leaf: run in its own process
    uses_bpy = sorted(path.stem for path in FOLDER.glob("*.py")
                      if any(m == "bpy" or m.startswith("bpy.") for m in _imports(path)))
    assert uses_bpy == ["review"]


def test_import_reconstruction_needs_nothing_heavy_and_its_stages_no_torch_or_bpy():
    """The package imports nothing; the stages, resolved, import neither torch (detection imports it
    when it runs the networks) nor bpy (the review runs in a process of its own) nor warp."""
    heavy = "print(sorted(m for m in ('torch', 'cv2', 'bpy', 'warp') if m in sys.modules))"
    for code, expected in ((f"import sys, reconstruction; {heavy}", "[]"),
                           (f"import sys, reconstruction; reconstruction.export; {heavy}", "['cv2']")):  # assets'
        done = subprocess.run([sys.executable, "-c", code], cwd=PROJECT, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        assert done.stdout.strip() == expected, code


def test_every_public_name_resolves_documented_and_survives_importing_the_modules():
    # importing a submodule sets it as an attribute of the package: no public name may be a module's
    for path in sorted(FOLDER.glob("*.py")):
        if path.stem not in ("__init__", "__main__", "review"):
            importlib.import_module(f"reconstruction.{path.stem}")
    assert len(set(reconstruction.__all__)) == len(reconstruction.__all__)
    for name in reconstruction.__all__:
        value = getattr(reconstruction, name)
        assert not isinstance(value, type(reconstruction)), name
        if callable(value):
            assert value.__doc__, name
        assert f"`{name}`" in reconstruction.__doc__, f"{name} is not described in the package's docstring"
    assert set(reconstruction.__all__) <= set(dir(reconstruction))
    assert reconstruction.RunSettings(template="shirt", detections="groundtruth").level_mm == 12
