"""The add-on installed from its zip into the bpy module, nothing leaking into the user's Blender config.

Blender's user folders (preferences, extension caches, user scripts) are pointed at a temporary folder
before bpy is first imported (``BLENDER_USER_RESOURCES``); installs also go to a temporary extension
repository or script folder of their own, so they stay out of the user's config even where bpy was
imported earlier in the session.
"""

import atexit
import importlib
import os
import shutil
import sys
import tempfile
from pathlib import Path
from types import SimpleNamespace

import pytest

if "bpy" not in sys.modules and "BLENDER_USER_RESOURCES" not in os.environ:
    _USER = tempfile.mkdtemp(prefix="clothcapture-blender-user-")
    os.environ["BLENDER_USER_RESOURCES"] = _USER
    atexit.register(shutil.rmtree, _USER, ignore_errors=True)

ADDON_ID = "clothcapture"
#: the add-on's submodules the tests reach into (the job runner, the importers)
SUBMODULES = ("jobs", "results", "commands")


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


@pytest.fixture(scope="module")
def addon(addon_zip, tmp_path_factory):
    """The add-on enabled from its zip (an extension in a temporary repository), its output folder a
    temporary one; disabled and removed afterwards."""
    import bpy

    name, repo = install_extension(addon_zip, tmp_path_factory.mktemp("repo"))
    bpy.context.scene.clothcapture.output_dir = str(tmp_path_factory.mktemp("output"))
    yield addon_modules(name)
    uninstall_extension(name, repo)
