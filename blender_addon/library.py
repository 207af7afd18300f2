"""Where the clothcapture project is, and which Python runs its tools.

The add-on is a UI over the project's packages (`assets`, `factory`, `reconstruction`): the light work
(reading results, posing a body) runs inside Blender, the long work runs the project's CLIs in a
background process (`jobs`).  Both need the project:

- project folder: the add-on preference, else the folder of the importable `assets` package (the bpy
  module in the project's venv imports it already);
- Python: the add-on preference, else the project's ``.venv`` interpreter, else this process's own
  interpreter when it is a Python (the bpy module) rather than a Blender executable.

Inside a Blender executable (4.2+: Python 3.11, as the project's venv), `ensure_importable` appends the
project folder and its venv's site-packages to ``sys.path`` (after Blender's own, so Blender's bundled
numpy stays in use), as ``factory/render.py`` does for ``blender -b -P``.
"""

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import bpy

#: the project's packages the add-on calls
PACKAGES = ("assets", "factory", "reconstruction")


class ClothCapturePreferences(bpy.types.AddonPreferences):
    bl_idname = __package__
    __annotations__ = {  # what Blender reads from annotations; as annotations, linters take strings for types
        "project_dir": bpy.props.StringProperty(
            name="Project Folder", subtype="DIR_PATH", default="",
            description="The clothcapture checkout (holding assets/, factory/, reconstruction/ and .venv/); "
                        "empty: found from the importable packages"),
        "python": bpy.props.StringProperty(
            name="Python", subtype="FILE_PATH", default="",
            description="The Python that runs the project's tools in the background (its venv's python); "
                        "empty: <project>/.venv/bin/python"),
    }

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "project_dir")
        layout.prop(self, "python")
        try:
            layout.label(text=f"Using {python_executable()} in {project_root()}", icon="CHECKMARK")
        except ValueError as exc:
            layout.label(text=str(exc), icon="ERROR")


def _preferences() -> ClothCapturePreferences | None:
    addon = bpy.context.preferences.addons.get(__package__)
    return addon.preferences if addon is not None else None


def _is_project(folder: Path) -> bool:
    return all((folder / name / "__init__.py").is_file() for name in PACKAGES)


def project_root() -> Path:
    """The project folder (ValueError when it cannot be found)."""
    prefs = _preferences()
    if prefs is not None and prefs.project_dir:
        root = Path(bpy.path.abspath(prefs.project_dir)).resolve()
        if not _is_project(root):
            raise ValueError(f"{root}: not a clothcapture project folder (needs {', '.join(PACKAGES)})")
        return root
    spec = importlib.util.find_spec("assets")
    if spec is not None and spec.origin and _is_project(Path(spec.origin).resolve().parents[1]):
        return Path(spec.origin).resolve().parents[1]
    raise ValueError("the clothcapture project was not found: set its folder in the add-on's preferences")


def _venv_python(root: Path) -> Path:
    return root / ".venv" / ("Scripts/python.exe" if os.name == "nt" else "bin/python")


def python_executable() -> str:
    """The interpreter of the background jobs (ValueError when there is none)."""
    prefs = _preferences()
    if prefs is not None and prefs.python:
        python = Path(bpy.path.abspath(prefs.python))
        if not python.is_file():
            raise ValueError(f"{python}: no such Python (add-on preferences)")
        return str(python)
    venv = _venv_python(project_root())
    if venv.is_file():
        return str(venv)
    if Path(sys.executable).name.lower().startswith("python"):
        return sys.executable
    raise ValueError(f"no Python for the background jobs: create {venv} (make test) or set one in the "
                     "add-on's preferences")


#: the modules the project's tools import (import name: what pip installs), by the part of the install
#: that provides them: "" the base install, else an extra of pyproject.toml
INSTALL = {
    "": {"numpy": "numpy", "scipy": "scipy", "cv2": "opencv-python-headless", "PIL": "pillow",
         "trimesh": "trimesh", "triangle": "triangle", "tqdm": "tqdm", "matplotlib": "matplotlib"},
    "factory": {"bpy": "bpy", "OpenEXR": "OpenEXR"},
    "reconstruction": {"warp": "warp-lang", "newton": "newton"},
    "networks": {"torch": "torch"},
}
#: the oldest Python the project runs on (pyproject.toml's requires-python)
MIN_PYTHON = (3, 11)
_PROBE = ("import importlib.util, json, sys; print(json.dumps({'version': list(sys.version_info[:3]), "
          "'missing': [m for m in sys.argv[1:] if importlib.util.find_spec(m) is None]}))")
_checked: set[tuple[str, tuple[str, ...]]] = set()


def check_python(extras: tuple[str, ...] = ()) -> str:
    """The interpreter of the background jobs, once asked whether it can run a job that needs the base
    install and `extras` (names of `INSTALL`); ValueError naming what it lacks and the command that
    installs it.  A Python that passed is not asked again in this session."""
    python, root = python_executable(), project_root()
    if (python, extras) in _checked:
        return python
    needed = {module: package for extra in ("", *extras) for module, package in INSTALL[extra].items()}
    try:
        answer = subprocess.run([python, "-c", _PROBE, *needed], capture_output=True, text=True, timeout=60,
                                stdin=subprocess.DEVNULL)
        found = json.loads(answer.stdout)
    except (OSError, subprocess.SubprocessError, ValueError) as exc:
        raise ValueError(f"{python}: not a Python that runs ({type(exc).__name__}: {exc}); set the project's "
                         "venv python in the add-on's preferences") from exc
    version = ".".join(map(str, found["version"]))
    if tuple(found["version"][:2]) < MIN_PYTHON:
        raise ValueError(f"{python} is Python {version}: the project needs {'.'.join(map(str, MIN_PYTHON))} or "
                         "later; set the project's venv python in the add-on's preferences")
    if found["missing"]:
        wanted = [extra for extra in extras if set(INSTALL[extra]) & set(found["missing"])]
        target = f"'{root}[{','.join(wanted)}]'" if wanted else str(root)
        raise ValueError(f"{python} (Python {version}) lacks {', '.join(needed[m] for m in found['missing'])}: "
                         f"install with {python} -m pip install -e {target}")
    _checked.add((python, extras))
    return python


def ensure_importable() -> None:
    """Make the project's packages importable in this process (a no-op where they already are)."""
    if all(importlib.util.find_spec(name) is not None for name in PACKAGES):
        return
    try:
        root = project_root()
    except ValueError:
        return  # the preferences say why; operators raise the same error when used
    version = f"python{sys.version_info.major}.{sys.version_info.minor}"
    site = root / ".venv" / ("Lib" if os.name == "nt" else f"lib/{version}") / "site-packages"
    for path in (root, site):
        if path.is_dir() and str(path) not in sys.path:
            sys.path.append(str(path))


def _venv_version(root: Path) -> str | None:
    """The Python version of the project's venv (``3.11``), None without one."""
    found = sorted((root / ".venv" / "lib").glob("python3.*"))
    return found[-1].name[len("python"):] if found else None


def project_module(name: str):
    """Module `name` of the project (``assets.motion.builtin``) imported into Blender's Python;
    ValueError saying exactly why it cannot be: no project, or what Blender's Python lacks."""
    ensure_importable()
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        root = project_root()  # ValueError when there is no project at all
        version = f"{sys.version_info.major}.{sys.version_info.minor}"
        venv = _venv_version(root)
        hint = f" (the project's venv is for Python {venv}, so its packages cannot serve it)" \
            if venv not in (None, version) else ""
        raise ValueError(f"Blender's Python {version} cannot load {name} of {root}: {exc}{hint}") from exc


def register() -> None:
    bpy.utils.register_class(ClothCapturePreferences)
    ensure_importable()


def unregister() -> None:
    bpy.utils.unregister_class(ClothCapturePreferences)
