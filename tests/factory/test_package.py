"""The `factory` package as a user meets it: a flat documented API whose names resolve to the entry
points, that imports nothing heavy (no bpy, no torch, not even the simulation) until a name is used."""

import importlib
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import factory

PROJECT = Path(__file__).resolve().parents[2]


def test_import_factory_loads_none_of_its_modules_nor_bpy_or_torch():
    code = ("import sys, factory; print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('bpy', 'torch', 'warp', 'newton', 'cv2', 'scipy') or m.startswith('factory.')))")
    loaded = subprocess.run([sys.executable, "-c", code], cwd=PROJECT, capture_output=True, text=True, check=True)
    assert loaded.stdout.strip() == "[]"


@pytest.mark.parametrize("name", factory.__all__)
def test_every_api_name_is_its_modules_object_and_documented(name):
    module, attribute = factory._API[name]
    assert getattr(factory, name) is getattr(importlib.import_module(module), attribute)
    assert f"`{name}`" in factory.__doc__
    assert name in dir(factory)


def test_no_api_name_is_shadowed_by_a_module_of_the_package():
    """`factory.simulate` is the module, so the function is `simulate_garment`: an API name that were a
    module's would change meaning once that module is imported."""
    modules = {info.name for info in pkgutil.iter_modules(factory.__path__)}
    assert {"simulate", "build", "capture", "dataset"} <= modules
    assert not set(factory.__all__) & modules
    simulate_module = importlib.import_module("factory.simulate")
    assert factory.simulate is simulate_module and factory.simulate_garment is simulate_module.simulate


def test_an_unknown_name_is_an_attribute_error_naming_it():
    with pytest.raises(AttributeError, match="'nonesuch'"):
        factory.nonesuch  # noqa: B018


@pytest.mark.parametrize("module, argv", [("factory.simulate", []), ("factory.dressing", []), ("factory.render", []),
                                          ("factory.dataset", ["build"]), ("factory.dataset", ["capture"]),
                                          ("factory.dataset", ["merge"]), ("factory.dataset", ["preview"])])
def test_every_factory_cli_names_things_as_the_project_does(module, argv, capsys):
    """The shared vocabulary (`assets.cli`): --out DIR, --no-progress; never --num-cpus or --quiet."""
    with pytest.raises(SystemExit) as done:
        importlib.import_module(module).main([*argv, "--help"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    assert "--out DIR" in text
    assert "--no-progress" in text or argv == ["preview"]
    assert "--num-cpus" not in text and "--quiet" not in text
