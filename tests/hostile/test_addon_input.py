"""The add-on's folders are named after the user's files: a file name that is not one plain path
component must not lead them outside the add-on's output folder (the real add-on, installed from its zip)."""

from __future__ import annotations

import pytest

from tests.blender_addon.conftest import addon, addon_zip  # noqa: F401 (the installed add-on's fixtures)


@pytest.mark.hostile("outside")
@pytest.mark.parametrize("garment, motion", [("/data/..", "/data/walk.npz"), ("/data/shirt.json", "/data/.npz"),
                                             ("/data/../template.npz", "/data/walk.npz")])
def test_the_add_on_refuses_file_names_that_would_lead_outside_its_folders(addon, garment, motion):
    import bpy

    settings = bpy.context.scene.clothcapture
    settings.garment.source, settings.garment.file = "FILE", garment
    settings.motion.source, settings.motion.file = "FILE", motion
    with pytest.raises(ValueError, match="cannot be a file name"):
        addon.commands.simulation_dir(settings)


@pytest.mark.hostile("outside")
def test_the_add_on_names_a_motion_file_by_its_label(addon, tmp_path):
    import bpy

    settings = bpy.context.scene.clothcapture
    settings.garment.source = "shirt"
    settings.motion.source, settings.motion.file = "FILE", str(tmp_path / "CMU_01_01_poses.npz")
    assert addon.commands.simulation_dir(settings).name == "shirt-CMU_01_01_poses"
