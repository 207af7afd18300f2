"""The add-on installed from its zip into the bpy module, nothing leaking into the user's Blender config.

Blender's user folders (preferences, extension caches, user scripts) are pointed at a temporary folder
before bpy is first imported (``BLENDER_USER_RESOURCES``); installs also go to a temporary extension
repository or script folder of their own, so they stay out of the user's config even where bpy was
imported earlier in the session.
"""

import atexit
import importlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path
from types import SimpleNamespace

import pytest

if "bpy" not in sys.modules and "BLENDER_USER_RESOURCES" not in os.environ:
    _USER = tempfile.mkdtemp(prefix="clothcapture-blender-user-")
    os.environ["BLENDER_USER_RESOURCES"] = _USER
    atexit.register(shutil.rmtree, _USER, ignore_errors=True)

ADDON_ID = "clothcapture"
#: the add-on's submodules the tests reach into (the job runner, the importers)
SUBMODULES = ("jobs", "results", "commands", "operators", "panels", "library")


@pytest.fixture(scope="session")
def addon_zip(tmp_path_factory):
    from blender_addon.package import build_zip

    return build_zip(tmp_path_factory.mktemp("addon"))


def install_extension(zip_path: Path, folder: Path) -> tuple[str, object]:
    """Install and enable the zip as an extension in a new repository in `folder`; returns the
    add-on's module name and the repository."""
    import bpy

    module = f"cc_test_{folder.name.replace('-', '_')}"
    repo = bpy.context.preferences.extensions.repos.new(name=module, module=module, custom_directory=str(folder),
                                                        source="USER")
    result = bpy.ops.extensions.package_install_files(filepath=str(zip_path), repo=module, enable_on_install=True)
    assert result == {"FINISHED"}
    return f"bl_ext.{module}.{ADDON_ID}", repo


def uninstall_extension(name: str, repo) -> None:
    import addon_utils
    import bpy

    if name in bpy.context.preferences.addons:
        addon_utils.disable(name, default_set=True)
    bpy.context.preferences.extensions.repos.remove(repo)


def addon_modules(name: str) -> SimpleNamespace:
    return SimpleNamespace(name=name, **{sub: importlib.import_module(f"{name}.{sub}") for sub in SUBMODULES})


def begin(addon, operator: str):
    """Start operator `operator`'s job ("simulate") in the background, as its button in Blender's window
    does (a script's call waits for it); returns the job."""
    import bpy

    spec = getattr(addon.operators, f"CLOTHCAPTURE_OT_{operator}").prepare(bpy.context)
    job = addon.operators.start(bpy.context, spec)
    assert job.active
    return job


@pytest.fixture(scope="module")
def addon(addon_zip, tmp_path_factory):
    """The add-on enabled from its zip (an extension in a temporary repository), its output folder a
    temporary one; disabled and removed afterwards, the scene's settings back at their defaults."""
    import bpy

    name, repo = install_extension(addon_zip, tmp_path_factory.mktemp("repo"))
    bpy.context.scene.clothcapture.output_dir = str(tmp_path_factory.mktemp("output"))
    yield addon_modules(name)
    bpy.context.scene.property_unset("clothcapture")
    uninstall_extension(name, repo)


ROOT = Path(__file__).resolve().parents[2]
#: what a script run by `run_script` starts with: modules of BLOCKED cannot be imported (a Blender whose
#: Python lacks them), then the add-on is installed from ZIP as a legacy add-on into the user scripts
#: folder (a temporary one) and enabled, with the project's folder in its preferences
_PRELUDE = '''
import importlib.abc, json, sys

class _Blocked(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)

sys.meta_path.insert(0, _Blocked())
import bpy  # (the bpy module provides addon_utils once imported)
import addon_utils

assert bpy.ops.preferences.addon_install(filepath=ZIP) == {"FINISHED"}
addon_utils.enable("clothcapture", default_set=True)
bpy.context.preferences.addons["clothcapture"].preferences.project_dir = ROOT
'''


def run_script(body: str, zip_path: Path, folder: Path, runner: str = "bpy", blocked: tuple[str, ...] = (),
               timeout_s: float = 300.0) -> subprocess.CompletedProcess:
    """Run `body` (a user's script) after `_PRELUDE` in a new process: the bpy module's Python
    (``python script.py``) or the `blender` executable (``blender -b --factory-startup -P script.py``),
    with Blender's user folders in `folder`."""
    script = folder / "script.py"
    script.write_text(f"BLOCKED = {set(blocked)!r}\nZIP = {str(zip_path)!r}\nROOT = {str(ROOT)!r}\n"
                      + _PRELUDE + textwrap.dedent(body))
    if runner == "bpy":
        command = [sys.executable, str(script)]
    else:
        blender = shutil.which("blender")
        if blender is None:
            pytest.fail("no `blender` executable on PATH: `apt-get install blender` (Debian's 3.4) to run this test")
        command = [blender, "-b", "--factory-startup", "-P", str(script)]
    env = {**os.environ, "BLENDER_USER_RESOURCES": str(folder / "user"),
           "BLENDER_USER_SCRIPTS": str(folder / "scripts"), "BLENDER_USER_CONFIG": str(folder / "config")}
    return subprocess.run(command, cwd=folder, env=env, capture_output=True, text=True, timeout=timeout_s)


def script_result(process: subprocess.CompletedProcess) -> dict:
    """What a `run_script` body printed as ``RESULT <json>`` (the process must have succeeded)."""
    assert process.returncode == 0, process.stdout[-3000:] + process.stderr[-3000:]
    line = next(line for line in reversed(process.stdout.splitlines()) if line.startswith("RESULT "))
    return json.loads(line[len("RESULT "):])


def orphans() -> list[str]:
    """Datablocks nothing uses (they vanish on saving, and push new names to '.001')."""
    import bpy

    return [f"{kind} {block.name}" for kind in ("meshes", "materials", "images", "actions", "shape_keys", "cameras")
            for block in getattr(bpy.data, kind) if block.users == 0]
