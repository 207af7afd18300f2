"""The project's shape: packages import, and light stages do not pull heavy dependencies."""

import importlib
import subprocess
import sys

import pytest

PACKAGES = ["assets", "factory", "networks", "reconstruction", "blender_addon"]


@pytest.mark.parametrize("name", PACKAGES)
def test_package_imports(name):
    assert importlib.import_module(name).__file__


def test_assets_does_not_import_heavy_dependencies():
    code = (
        "import sys, assets.pattern, assets.pattern.__main__\n"
        "heavy = {'bpy', 'torch', 'warp', 'newton'} & set(sys.modules)\n"
        "print(sorted(heavy))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"
