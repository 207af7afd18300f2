"""The add-on behaves like Blender (issue 49): what a new user meets, each on the quickest real run
(a 2 x 3 pattern at 50 DPI, a fifth of a second of the built-in walk), through the add-on installed
from its zip into the bpy module."""

import bpy
import pytest


@pytest.fixture(scope="module")
def settings(addon):
    settings = bpy.context.scene.clothcapture
    settings.pattern.rows, settings.pattern.cols, settings.pattern.dpi = 2, 3, 50.0
    motion = settings.motion
    motion.body_source, motion.source, motion.builtin = "DEFAULT", "BUILTIN", "walk"
    motion.seconds, motion.fps, motion.transition = 0.2, 30.0, "none"
    return settings


def finish(addon, kind, timeout_s=120.0):
    """The latest job of `kind`, waited for while it runs; it must have succeeded."""
    job = addon.jobs.wait(addon.jobs.latest(kind), timeout_s)
    assert job.state == addon.jobs.FINISHED, job.error
    return job


def test_the_default_output_folder_works_on_an_unsaved_file(addon, settings, tmp_path):
    paths = bpy.context.preferences.filepaths
    folder, temporary = settings.output_dir, paths.temporary_directory
    settings.output_dir, paths.temporary_directory = "//clothcapture/", str(tmp_path)
    try:
        assert bpy.data.filepath == ""
        assert bpy.ops.clothcapture.generate_pattern() == {"FINISHED"}
        finish(addon, "pattern")
    finally:
        settings.output_dir, paths.temporary_directory = folder, temporary
    assert (tmp_path / "clothcapture" / "pattern" / "pattern.png").is_file()
