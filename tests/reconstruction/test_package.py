"""The `reconstruction` package as a user meets it: a flat documented API that imports without OpenCV,
torch or bpy, and bpy in one leaf module (the review) that no other module imports.  (No import
cycles: tests/test_import_cycles.py.)"""

import ast
import subprocess
import sys
from pathlib import Path

import reconstruction
from tests.package_api import check_flat_api

PROJECT = Path(__file__).resolve().parents[2]
FOLDER = PROJECT / "reconstruction"


def _imports(path: Path) -> set[str]:
    """Every module `path` imports anywhere in its source (function bodies too: a lazy import is an
    import as soon as that code runs), by full name (``from a import b``: a and a.b)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
            found |= {f"{node.module}.{alias.name}" for alias in node.names}
        elif isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
    return found


def test_only_the_review_imports_bpy_and_no_module_imports_the_review():
    """The review is a leaf (its cycle with export and pipeline is gone: tests/test_import_cycles.py),
    run by the export stage in a process of its own."""
    imports = {path.stem: _imports(path) for path in FOLDER.glob("*.py")}
    assert sorted(name for name, found in imports.items() if any(m.split(".")[0] == "bpy" for m in found)) == ["review"]
    assert sorted(name for name, found in imports.items() if "reconstruction.review" in found) == []


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
    check_flat_api(reconstruction, skip=("review",))
    assert reconstruction.RunSettings(template="shirt", detections="groundtruth").level_mm == 12
