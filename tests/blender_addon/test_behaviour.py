"""The add-on behaves like Blender (issue 49): what a new user meets, each on the quickest real run
(a 2 x 3 pattern at 50 DPI, a fifth of a second of the built-in walk), through the add-on installed
from its zip into the bpy module."""

import subprocess
import sys

import bpy
import pytest
from mathutils import Vector

from tests.blender_addon.conftest import begin, orphans, run_script, script_result


@pytest.fixture(scope="module")
def output(tmp_path_factory):
    return tmp_path_factory.mktemp("output")


@pytest.fixture
def settings(addon, output):
    """The current scene's settings (undo and file loads replace the scene) for the quickest runs."""
    settings = bpy.context.scene.clothcapture
    settings.output_dir = str(output)
    settings.pattern.rows, settings.pattern.cols, settings.pattern.dpi = 2, 3, 50.0
    motion = settings.motion
    motion.body_source, motion.source, motion.builtin = "DEFAULT", "BUILTIN", "walk"
    motion.seconds, motion.fps, motion.transition = 0.2, 30.0, "none"
    return settings


def finish(addon, job, timeout_s=120.0):
    """`job` waited for while it runs (what Blender's timer does); it must have succeeded."""
    addon.jobs.wait(job, timeout_s)
    assert job.state == addon.jobs.FINISHED, job.error
    return job


def test_the_default_output_folder_works_on_an_unsaved_file(addon, settings, tmp_path):
    paths = bpy.context.preferences.filepaths
    folder, temporary = settings.output_dir, paths.temporary_directory
    settings.output_dir, paths.temporary_directory = "//clothcapture/", str(tmp_path)
    try:
        assert bpy.data.filepath == ""
        assert bpy.ops.clothcapture.generate_pattern() == {"FINISHED"}
    finally:
        settings.output_dir, paths.temporary_directory = folder, temporary
    assert (tmp_path / "clothcapture" / "pattern" / "pattern.png").is_file()


def test_a_project_blender_cannot_load_is_named_and_no_placeholder_reaches_a_cli(addon_zip, tmp_path):
    """Blender's own Python lacks scipy (as Blender's builds do): the lists say why they are empty,
    and the operators refuse with that reason instead of running a CLI on the placeholder."""
    result = script_result(run_script("""
        import sys
        settings = bpy.context.scene.clothcapture
        commands = sys.modules["clothcapture.commands"]
        items = sys.modules["clothcapture.settings"]._builtin_motions(None, bpy.context)
        refusals = []
        for command in (commands.motion_command, commands.simulation_command, commands.render_command):
            try:
                command(settings)
                refusals.append(None)
            except ValueError as exc:
                refusals.append(str(exc))
        try:
            bpy.ops.clothcapture.import_motion()
            report = None
        except RuntimeError as exc:
            report = str(exc)
        jobs = sys.modules["clothcapture.jobs"].jobs()
        print("RESULT", json.dumps({"items": items, "value": settings.motion.builtin, "refusals": refusals,
                                    "report": report, "jobs": len(jobs)}))
    """, addon_zip, tmp_path, blocked=("scipy",)))
    [(identifier, name, description)] = result["items"]
    assert identifier == result["value"] and name == "(project not loaded)"
    assert "No module named 'scipy'" in description and "Blender's Python" in description
    assert all(refusal is not None and "No module named 'scipy'" in refusal for refusal in result["refusals"])
    assert "No module named 'scipy'" in result["report"] and "Traceback" not in result["report"]
    assert result["jobs"] == 0


def test_the_projects_python_is_checked_before_the_first_job_and_what_it_lacks_is_named(addon, settings,
                                                                                       tmp_path):
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(tmp_path / "bare")], check=True)
    python = tmp_path / "bare" / "bin" / "python"
    preferences = bpy.context.preferences.addons[addon.name].preferences
    before = len(addon.jobs.jobs())
    try:
        preferences.python = str(python)
        with pytest.raises(RuntimeError) as refused:
            bpy.ops.clothcapture.generate_pattern()
        preferences.python = "/bin/true"
        with pytest.raises(RuntimeError, match="/bin/true: not a Python"):
            bpy.ops.clothcapture.generate_pattern()
    finally:
        preferences.python = ""
    message = str(refused.value)
    assert f"{python} (Python {sys.version_info.major}.{sys.version_info.minor}" in message
    for module in ("numpy", "scipy", "opencv-python-headless", "tqdm"):
        assert module in message
    assert f"{python} -m pip install -e {addon.library.project_root()}" in message
    assert len(addon.jobs.jobs()) == before  # nothing started


@pytest.mark.parametrize("runner", ["bpy", "blender"])
def test_a_script_runs_the_operators_to_the_end_and_blender_b_produces_the_outputs(addon_zip, tmp_path, runner):
    """From a script (``python script.py`` with the bpy module, ``blender -b -P script.py``) an operator
    returns when its run is done and its results are imported, as Blender's own operators do."""
    out = tmp_path / "out"
    result = script_result(run_script(f"""
        settings = bpy.context.scene.clothcapture
        settings.output_dir = {str(out)!r}
        settings.pattern.rows, settings.pattern.cols, settings.pattern.dpi = 2, 3, 50.0
        returned = bpy.ops.clothcapture.generate_pattern()
        image = bpy.data.images.get("clothcapture pattern")
        print("RESULT", json.dumps({{"returned": sorted(returned), "image": list(image.size) if image else None}}))
    """, addon_zip, tmp_path, runner))
    assert result == {"returned": ["FINISHED"], "image": [284, 189]}
    assert (out / "pattern" / "pattern.png").is_file()


def test_an_import_is_one_undo_step_of_its_own(addon, settings):
    """The user changes something while a run goes on; Ctrl+Z after the import undoes the import alone."""
    if "Body" in bpy.data.objects:
        bpy.data.objects.remove(bpy.data.objects["Body"])
    bpy.ops.ed.undo_push(message="before")
    job = begin(addon, "import_motion")
    bpy.ops.mesh.primitive_cube_add("EXEC_DEFAULT", True, location=(3.0, 0.0, 0.0))  # the user's change
    cube = bpy.context.active_object.name
    finish(addon, job)
    assert {"Body", cube} <= set(bpy.data.objects.keys())
    bpy.ops.ed.undo()
    assert cube in bpy.data.objects and "Body" not in bpy.data.objects
    bpy.ops.ed.undo()
    assert cube not in bpy.data.objects
    bpy.ops.ed.redo()
    bpy.ops.ed.redo()
    assert {"Body", cube} <= set(bpy.data.objects.keys())


def test_a_run_whose_file_was_saved_meanwhile_is_still_imported(addon, settings, tmp_path):
    if "Body" in bpy.data.objects:
        bpy.data.objects.remove(bpy.data.objects["Body"])
    job = begin(addon, "import_motion")
    try:
        assert bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "first.blend")) == {"FINISHED"}
        finish(addon, job)
        assert "Body" in bpy.data.objects and job.message.startswith("walk on the default body")
    finally:
        bpy.ops.wm.read_homefile()  # unsaved again, for the tests that follow


def test_a_run_whose_file_was_replaced_meanwhile_offers_its_results_to_the_new_one(addon, settings):
    job = begin(addon, "import_motion")
    bpy.ops.wm.read_homefile()  # File > New while it runs
    finish(addon, job)
    assert "Body" not in bpy.data.objects and job.offered
    assert "another file was opened" in job.message
    assert bpy.ops.clothcapture.import_results(job_id=job.id) == {"FINISHED"}
    assert "Body" in bpy.data.objects and not job.offered and job.message.startswith("walk on the default body")


def test_messages_wrap_to_the_width_of_the_sidebar(addon):
    """The sidebar is about 35 characters wide by default and as wide as the user drags it: each line
    of a message fits the region's width in Blender's UI font (whole words; a long path is cut at a
    '/'), at any UI scale."""
    import blf

    message = ("the run finished but importing its results failed: ValueError: /tmp/pytest-of-root/clothcapture/"
               "simulations/skirt-walk/sequence.npz: positions (3, 5248, 3), expected (T, 5249, 3)")
    points = bpy.context.preferences.ui_styles[0].widget.points
    for width_px, scale in ((180, 1.0), (400, 1.0), (360, 2.0)):
        lines = addon.panels.wrap(message, width_px, scale)
        blf.size(0, points * scale)
        assert all(blf.dimensions(0, line)[0] <= width_px for line in lines), lines
        assert "".join(lines).replace(" ", "") == message.replace(" ", "")  # nothing lost
        assert len(lines) > 1
    narrow = addon.panels.wrap(message, 180)
    assert max(map(len, narrow)) <= 35 and "/tmp/pytest-of-root/" in narrow


def test_progress_reflects_the_whole_job_and_a_stage_that_ends_early_counts_as_done(addon, tmp_path):
    """A simulation's bars as tqdm writes them: sewing converges after 30 of at most 200 steps and its
    bar is cleared (``leave=False``), then the frames are simulated."""
    from tqdm import tqdm

    job = addon.jobs.Job("simulation", "simulation", [], tmp_path, stages=("sewing", "simulating"))
    job.log_path = tmp_path / "job.log"
    seen = []
    with open(job.log_path, "w") as log:
        def step(bar, n):
            bar.update(n)
            log.flush()
            job.read_output()
            seen.append(job.progress)

        sewing = tqdm(total=200, desc="sewing skirt", file=log, leave=False, mininterval=0)
        step(sewing, 30)
        sewing.close()
        step(sewing, 0)
        print("INFO factory.simulate: dressed skirt in 30 steps", file=log)
        simulating = tqdm(total=4, desc="simulating skirt", file=log, mininterval=0)
        step(simulating, 2)
        step(simulating, 2)
    assert seen == pytest.approx([0.075, 0.5, 0.75, 1.0])
    assert job.progress_text == "simulating skirt 4/4"


def test_an_import_is_selected_active_and_framed_in_the_3d_view(addon, settings):
    bpy.ops.mesh.primitive_cube_add(location=(0.0, 0.0, 0.0))  # the default cube, selected
    cube = bpy.context.active_object
    views = [area.spaces.active.region_3d for window in bpy.context.window_manager.windows
             for area in window.screen.areas if area.type == "VIEW_3D"]
    assert views  # the bpy module has a window with a 3D view, though nothing is drawn
    for view in views:
        view.view_location, view.view_distance = (0.0, 0.0, 0.0), 30.0
    assert bpy.ops.clothcapture.import_motion() == {"FINISHED"}
    body = bpy.data.objects["Body"]
    assert body.select_get() and bpy.context.view_layer.objects.active == body and not cube.select_get()
    corners = [body.matrix_world @ Vector(corner) for corner in body.bound_box]
    centre = sum(corners, Vector()) / 8
    for view in views:
        assert (view.view_location - centre).length < 0.05 and view.view_distance < 5.0


def test_importing_again_replaces_and_leaves_no_orphans_or_renamed_copies(addon, settings):
    before = orphans()
    for _ in range(2):
        assert bpy.ops.clothcapture.import_motion() == {"FINISHED"}
    body = bpy.data.objects["Body"]
    assert orphans() == before
    assert body.data.name == "Body" and [m.name for m in body.data.materials] == ["clothcapture skin"]
    assert body.data.shape_keys.animation_data.action.users == 1


def test_results_import_in_a_blender_whose_python_lacks_tqdm(addon_zip, tmp_path):
    """A distribution's Blender (Python 3.13) cannot use the venv's packages: tqdm, which only draws
    the CLIs' bars, must not be needed to read results inside Blender."""
    script_result(run_script("""
        import importlib
        importlib.import_module("clothcapture.results")
        print("RESULT {}")
    """, addon_zip, tmp_path, blocked=("tqdm",)))
