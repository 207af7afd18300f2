"""The add-on's zip: Blender's own validator accepts it; it installs into the bpy module as an extension
and as a legacy add-on, registers its tab, settings and operators, and unregisters without a trace,
repeatedly."""

import ast
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from blender_addon.package import build_zip, files, manifest

from tests.blender_addon.conftest import ADDON_ID, install_extension, uninstall_extension

ADDON = Path(__file__).resolve().parents[2] / "blender_addon"
PANELS = ("main", "pattern", "motion", "garment", "render", "review")
OPERATORS = ("generate_pattern", "apply_pattern", "import_motion", "import_garment", "simulate", "render",
             "reconstruct", "import_reconstruction", "import_results", "cancel_job", "dismiss_job")


def registered() -> dict:
    """What the add-on puts into Blender: settings on the scene, panels, operators."""
    import bpy

    return {"settings": hasattr(bpy.types.Scene, "clothcapture"),
            "panels": [p for p in PANELS if hasattr(bpy.types, f"CLOTHCAPTURE_PT_{p}")],
            "operators": [o for o in OPERATORS if hasattr(bpy.types, f"CLOTHCAPTURE_OT_{o}")]}


EVERYTHING = {"settings": True, "panels": list(PANELS), "operators": list(OPERATORS)}
NOTHING = {"settings": False, "panels": [], "operators": []}


def test_the_zip_holds_one_folder_with_the_manifest_and_blender_validates_it(addon_zip, tmp_path):
    import bpy

    names = zipfile.ZipFile(addon_zip).namelist()
    assert addon_zip.name == f"{ADDON_ID}-{manifest()['version']}.zip"
    assert sorted(names) == sorted(f"{ADDON_ID}/{p.as_posix()}" for p in files())
    assert f"{ADDON_ID}/blender_manifest.toml" in names and f"{ADDON_ID}/__init__.py" in names
    assert not any("__pycache__" in n or n.endswith(("package.py", "README_SECTION.md")) for n in names)
    assert build_zip(tmp_path).read_bytes() == addon_zip.read_bytes()  # same sources, same bytes
    tool = Path(bpy.utils.system_resource("SCRIPTS")) / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"
    result = subprocess.run([sys.executable, str(tool), "validate", str(addon_zip)], capture_output=True, text=True)
    assert result.returncode == 0 and "Success" in result.stdout, result.stdout + result.stderr


def test_the_extension_registers_and_unregisters_cleanly_twice(addon_zip, tmp_path):
    import addon_utils
    import bpy

    assert registered() == NOTHING
    name, repo = install_extension(addon_zip, tmp_path / "repo")
    try:
        assert (tmp_path / "repo" / ADDON_ID / "blender_manifest.toml").is_file()  # nowhere else
        for _ in range(2):
            assert name in bpy.context.preferences.addons
            assert registered() == EVERYTHING
            settings = bpy.context.scene.clothcapture
            assert settings.output_dir == "//clothcapture/" and settings.pattern.pitch_mm == 2.0
            assert settings.motion.builtin == "walk" and settings.garment.source == "shirt"
            assert bpy.context.preferences.addons[name].preferences.project_dir == ""
            addon_utils.disable(name, default_set=True)
            assert name not in bpy.context.preferences.addons
            assert registered() == NOTHING
            jobs = sys.modules[f"{name}.jobs"]
            assert not bpy.app.timers.is_registered(jobs._timer) and not jobs.active()
            addon_utils.enable(name, default_set=True)
        assert registered() == EVERYTHING
    finally:
        uninstall_extension(name, repo)
    assert registered() == NOTHING


def test_the_same_zip_installs_as_a_legacy_addon(addon_zip, tmp_path):
    import addon_utils
    import bpy

    scripts = bpy.context.preferences.filepaths.script_directories.new()
    scripts.name, scripts.directory = "clothcapture-test", str(tmp_path)
    try:
        result = bpy.ops.preferences.addon_install(filepath=str(addon_zip), target="clothcapture-test",
                                                   overwrite=True, enable_on_install=True)
        assert result == {"FINISHED"}
        assert (tmp_path / "addons" / ADDON_ID / "__init__.py").is_file()
        assert ADDON_ID in bpy.context.preferences.addons
        assert registered() == EVERYTHING
        assert sys.modules[ADDON_ID].bl_info["blender"] == (4, 2, 0)
        # an operator of the legacy add-on at work: a missing reconstruction is reported, not raised
        bpy.context.scene.clothcapture.review.reconstruction_dir = str(tmp_path / "nowhere")
        with pytest.raises(RuntimeError, match="nowhere: no sequence.npz"):
            bpy.ops.clothcapture.import_reconstruction()
        addon_utils.disable(ADDON_ID, default_set=True)
        assert registered() == NOTHING
    finally:
        if ADDON_ID in bpy.context.preferences.addons:
            addon_utils.disable(ADDON_ID, default_set=True)
        sys.modules.pop(ADDON_ID, None)
        sys.path[:] = [p for p in sys.path if not p.startswith(str(tmp_path))]
        bpy.context.preferences.filepaths.script_directories.remove(scripts)


def test_panels_use_only_settings_and_operators_that_exist():
    """Panels cannot be drawn headless (no window): check statically every name they draw."""
    from blender_addon import settings

    known = set().union(*(cls.__annotations__ for name, cls in vars(settings).items()
                          if name.startswith("CLOTHCAPTURE_PG_")))
    tree = ast.parse((ADDON / "panels.py").read_text())
    calls = [node for node in ast.walk(tree) if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)]
    drawn = {node.args[-1].value for node in calls if node.func.attr == "prop"
             and isinstance(node.args[-1], ast.Constant)}
    drawn |= {e.value for node in ast.walk(tree) if isinstance(node, ast.For) and isinstance(node.iter, ast.Tuple)
              for e in node.iter.elts}  # `for name in ("pitch_mm", ...): column.prop(pattern, name)`
    operators = {node.args[0].value for node in calls if node.func.attr == "operator"}
    assert len(drawn) > 30 and drawn <= known, sorted(drawn - known)
    assert operators == {f"clothcapture.{o}" for o in OPERATORS}
