"""Every panel's operators on tiny inputs, through the add-on installed from its zip: the real CLIs run in
background processes (called from a script, an operator waits for its job; a job started in the
background is driven by the job runner's `tick`, as Blender's timer does) and their results are
checked in the scene (objects, materials, animation frames) and on disk.

One pipeline per module: the skirt (the quickest garment to dress) at the 12 mm level with a 30 DPI
texture, dressed and simulated for 3 frames of the built-in walk, captured from frames 1 and 2 by three
64 x 48 Workbench cameras, reconstructed from the capture's ground truth at the 12 mm level.
"""

import json
import shutil
import time

import bpy
import numpy as np
import pytest

from assets.fileio import load_npz
from assets.garments import Template

from tests.blender_addon.conftest import begin, orphans

pytestmark = pytest.mark.slow  # a dressing, a simulation, renders and a Newton refine

SIM_FRAMES = 3


#: job kind -> the progress of a run followed in the background, sampled as Blender's timer would
PROGRESS: dict[str, list[float]] = {}


def run(addon, operator, kind):
    """Call a background operator (from a script: it returns when its job is done); returns the job."""
    assert operator() == {"FINISHED"}
    job = addon.jobs.latest(kind)
    assert job.state == addon.jobs.FINISHED, job.error
    return job


def follow(addon, operator):
    """Start `operator`'s job in the background, as its button in Blender's window does, and tick it to
    its end, keeping its progress in `PROGRESS`; returns the job."""
    job = begin(addon, operator)
    seen = PROGRESS.setdefault(job.kind, [])
    while job.active:
        seen.append(job.progress or 0.0)
        addon.jobs.tick()
        time.sleep(0.05)
    seen.append(job.progress)
    assert job.state == addon.jobs.FINISHED, job.error
    return job


def evaluated_positions(obj, frame):
    """The object's vertex positions (V, 3) as Blender shows them at scene frame `frame`."""
    bpy.context.scene.frame_set(frame)
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = evaluated.to_mesh()
    positions = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", positions)
    evaluated.to_mesh_clear()
    return positions.reshape(-1, 3)


def image_of(material):
    return next(node.image for node in material.node_tree.nodes if node.type == "TEX_IMAGE")


@pytest.fixture(scope="module")
def settings(addon):
    return bpy.context.scene.clothcapture


@pytest.fixture(scope="module")
def garment(addon, settings):
    settings.garment.source, settings.garment.level_mm, settings.garment.texture_dpi = "skirt", "12", 30.0
    job = run(addon, bpy.ops.clothcapture.import_garment, "garment")
    return job, bpy.data.objects["skirt"]


@pytest.fixture(scope="module")
def simulation(addon, settings, garment):
    settings.motion.body_source, settings.motion.source, settings.motion.builtin = "DEFAULT", "BUILTIN", "walk"
    settings.motion.speed, settings.garment.sim_frames = 1.0, SIM_FRAMES
    return follow(addon, "simulate")


@pytest.fixture(scope="module")
def capture(addon, settings, simulation):
    render = settings.render
    render.rig, render.engine, render.samples, render.denoise = "CAPTURE", "WORKBENCH", 1, False
    render.width, render.height, render.texture_dpi = 64, 48, 30.0
    render.frames, render.first_frame, render.cameras = 2, 1, 3
    return follow(addon, "render")


@pytest.fixture(scope="module")
def reconstruction(addon, settings, capture):
    review = settings.review
    review.detections, review.noise_px, review.levels = "groundtruth", 0.3, "12"
    review.show_groundtruth, review.groundtruth_offset, review.heatmap, review.import_cameras = True, 0.8, True, True
    return follow(addon, "reconstruct")


# ---- Pattern ---------------------------------------------------------------------------------------
def test_the_pattern_is_generated_and_applied_to_a_mesh_through_its_uvs(addon, settings):
    pattern = settings.pattern
    pattern.rows, pattern.cols, pattern.dpi, pattern.seed, pattern.pitch_mm = 2, 3, 50.0, 3, 2.0
    job = run(addon, bpy.ops.clothcapture.generate_pattern, "pattern")
    folder = addon.commands.pattern_dir(settings)
    spec = json.loads((folder / "spec.json").read_text())
    assert (spec["rows"], spec["cols"], spec["seed"]) == (2, 3, 3)
    image = bpy.data.images["clothcapture pattern"]
    assert tuple(image.size) == (284, 189)  # 2 x 3 markers of 48 mm at 50 DPI
    assert job.message == f"pattern.png 284 x 189 px in {folder}"
    bpy.ops.mesh.primitive_plane_add()
    plane = bpy.context.active_object
    assert bpy.ops.clothcapture.apply_pattern() == {"FINISHED"}
    assert [m.name for m in plane.data.materials] == ["clothcapture pattern"]
    assert image_of(plane.data.materials[0]) == image


def test_a_pattern_run_can_be_cancelled_and_leaves_no_half_file(addon, settings):
    pattern = settings.pattern
    pattern.rows, pattern.cols, pattern.dpi = 32, 32, 600.0  # minutes of work
    job = begin(addon, "generate_pattern")
    with pytest.raises(RuntimeError, match="still running"):
        bpy.ops.clothcapture.generate_pattern()  # one run per kind at a time
    folder = addon.commands.pattern_dir(settings)
    before = (folder / "pattern.png").stat().st_mtime_ns
    deadline = time.monotonic() + 120
    while not job.progress and time.monotonic() < deadline:  # until it is writing the image
        addon.jobs.tick()
        assert job.active, job.error
        time.sleep(0.05)
    assert job.progress_text.startswith("render ")
    assert bpy.ops.clothcapture.cancel_job(job_id=job.id) == {"FINISHED"}
    addon.jobs.wait(job, 30)
    assert job.state == addon.jobs.CANCELLED
    assert (folder / "pattern.png").stat().st_mtime_ns == before  # the earlier file is untouched
    assert not list(folder.rglob("*.part"))
    assert bpy.ops.clothcapture.dismiss_job(job_id=job.id) == {"FINISHED"}
    assert job not in addon.jobs.jobs()
    pattern.rows, pattern.cols, pattern.dpi = 2, 3, 50.0


# ---- Body & Motion ---------------------------------------------------------------------------------
def test_a_builtin_motion_becomes_an_animated_body_at_its_frame_rate(addon, settings):
    motion = settings.motion
    motion.body_source, motion.source, motion.builtin = "DEFAULT", "BUILTIN", "walk"
    motion.seconds, motion.fps, motion.transition = 0.5, 120.0, "A"
    job = run(addon, bpy.ops.clothcapture.import_motion, "motion")
    folder = addon.commands.output_root(settings) / "motions" / "walk"
    vertices = load_npz(folder / "body_sequence.npz")["vertices"]
    body, scene = bpy.data.objects["Body"], bpy.context.scene
    assert len(body.data.vertices) == vertices.shape[1] and job.message.startswith("walk on the default body")
    assert (scene.frame_start, scene.frame_end, scene.render.fps / scene.render.fps_base) == (0, len(vertices) - 1, 120)
    # 1.5 s of a 13k-vertex body is too much for shape keys: a mesh cache plays it
    assert [m.type for m in body.modifiers] == ["MESH_CACHE"] and body.data.shape_keys is None
    assert (folder / "blender" / "body.pc2").is_file() and "(mesh cache)" in job.message
    for frame in (0, 100, len(vertices) - 1):
        np.testing.assert_allclose(evaluated_positions(body, frame), vertices[frame], atol=1e-5)


def test_an_amass_file_drives_an_smpl_model_file(addon, settings, tmp_path):
    from tests.assets.body_fixtures import smpl_arrays

    rng = np.random.default_rng(0)
    np.savez(tmp_path / "model.npz", **smpl_arrays(rng))
    np.savez(tmp_path / "clip.npz", poses=rng.normal(0, 0.2, (12, 72)), trans=np.zeros((12, 3)),
             betas=np.zeros(10), mocap_framerate=np.array(60.0), gender=np.array("neutral"))
    motion = settings.motion
    motion.body_source, motion.body_file = "FILE", str(tmp_path / "model.npz")
    motion.source, motion.file, motion.fps, motion.transition = "FILE", str(tmp_path / "clip.npz"), 30.0, "none"
    run(addon, bpy.ops.clothcapture.import_motion, "motion")
    vertices = load_npz(addon.commands.output_root(settings) / "motions" / "clip" / "body_sequence.npz")["vertices"]
    body = bpy.data.objects["Body"]
    assert len(body.data.vertices) == 40 and len(body.data.shape_keys.key_blocks) == len(vertices) > 1
    np.testing.assert_allclose(evaluated_positions(body, 3), vertices[3], atol=1e-5)
    motion.body_source = "DEFAULT"


def test_a_bvh_file_is_retargeted_onto_the_default_body(addon, settings, tmp_path):
    from tests.assets.test_motion_bvh import random_motion, write_bvh

    path = write_bvh(tmp_path / "clip.bvh", *random_motion(frames=8))
    motion = settings.motion
    motion.source, motion.file, motion.fps, motion.transition = "FILE", str(path), 120.0, "none"
    run(addon, bpy.ops.clothcapture.import_motion, "motion")
    body = bpy.data.objects["Body"]
    assert body["clothcapture_motion"] == "clip" and bpy.context.scene.frame_end == 7
    assert len(body.data.shape_keys.key_blocks) == 8 and not body.modifiers  # the mesh cache is gone


def test_a_failing_run_shows_the_tools_error_and_changes_nothing(addon, settings, tmp_path):
    (tmp_path / "broken.bvh").write_text("HIERARCHY\nnot a skeleton\n")
    motion = settings.motion
    motion.source, motion.file = "FILE", str(tmp_path / "broken.bvh")
    body = bpy.data.objects["Body"].data
    with pytest.raises(RuntimeError, match="broken.bvh"):  # a script's call raises the tool's error
        bpy.ops.clothcapture.import_motion()
    job = addon.jobs.latest("motion")
    assert job.state == addon.jobs.FAILED and "broken.bvh" in job.error and "exit status 2" in job.error
    assert bpy.data.objects["Body"].data == body
    log = job.log_path
    assert str(log) in job.error and log.is_file()  # kept for a look until dismissed
    assert bpy.ops.clothcapture.dismiss_job(job_id=job.id) == {"FINISHED"}
    assert not log.exists()
    motion.file = str(tmp_path / "missing.bvh")  # caught before anything starts
    with pytest.raises(RuntimeError, match="missing.bvh does not exist"):
        bpy.ops.clothcapture.import_motion()
    motion.source = "BUILTIN"


# ---- Garment ---------------------------------------------------------------------------------------
def test_a_garment_template_is_imported_at_its_level_with_its_texture(addon, settings, garment):
    job, skirt = garment
    folder = addon.commands.garment_dir(settings)
    level = Template.load(folder / "template.npz").level(12)
    assert len(skirt.data.vertices) == level.num_vertices and len(skirt.data.polygons) == len(level.faces)
    uv = np.empty(len(skirt.data.loops) * 2, np.float32)
    skirt.data.uv_layers["UVMap"].data.foreach_get("uv", uv)
    np.testing.assert_allclose(uv.reshape(-1, 3, 2), level.uv[level.faces], atol=1e-6)
    image = image_of(skirt.active_material)
    assert image.filepath == str(folder / "pattern_texture.png") and image.size[0] > 0


def test_applying_the_pattern_rebuilds_a_garment_with_the_new_seed(addon, settings, garment):
    _, skirt = garment
    texture = addon.commands.garment_dir(settings) / "pattern_texture.png"
    before = texture.read_bytes()
    bpy.ops.object.select_all(action="DESELECT")
    skirt.select_set(True)
    settings.pattern.seed = 5
    unused = orphans()
    try:
        run(addon, bpy.ops.clothcapture.apply_pattern, "garment")
    finally:
        settings.pattern.seed = 3
    template = Template.load(addon.commands.garment_dir(settings) / "template.npz")
    assert template.layout.spec.seed == 5 and texture.read_bytes() != before
    assert bpy.data.objects["skirt"] == skirt and "skirt.001" not in bpy.data.objects
    assert orphans() == unused and skirt.data.name == "skirt" and skirt.active_material.name == "skirt pattern"


def test_dress_and_simulate_plays_the_garment_on_its_body(addon, settings, simulation):
    folder = addon.commands.simulation_dir(settings)
    data = load_npz(folder / "sequence.npz")
    assert data["positions"].shape[0] == SIM_FRAMES and "3 frames at 120 Hz" in simulation.message
    garment, body, scene = bpy.data.objects["skirt simulation"], bpy.data.objects["Body"], bpy.context.scene
    assert (scene.frame_start, scene.frame_end, scene.render.fps) == (0, SIM_FRAMES - 1, 120)
    for frame in range(SIM_FRAMES):
        np.testing.assert_allclose(evaluated_positions(garment, frame), data["positions"][frame], atol=1e-5)
    assert image_of(garment.active_material).filepath.endswith("pattern_texture.png")
    assert len(body.data.shape_keys.key_blocks) == SIM_FRAMES and bpy.data.objects["skirt"].hide_render
    meta = json.loads(str(data["meta"]))
    assert meta["garment_spec"] == str(addon.commands.garment_dir(settings) / "template.npz")


# ---- Render ----------------------------------------------------------------------------------------
def test_a_capture_renders_with_ground_truth_and_its_cameras_are_imported(addon, settings, simulation, capture):
    folder = addon.commands.render_dir(settings)
    cameras = json.loads((folder / "cameras.json").read_text())["cameras"]
    assert len(cameras) == 3
    for camera in cameras:
        names = sorted(p.name for p in (folder / camera["name"]).iterdir())
        assert {"f000001.png", "f000002.png", "f000001_gt.npz", "f000002_gt.npz"} <= set(names)
    rig = bpy.data.collections["capture cameras"]
    assert sorted(o.name for o in rig.objects) == sorted(c["name"] for c in cameras)
    assert bpy.context.scene.camera in list(rig.objects) and bpy.context.scene.render.resolution_x == 64
    assert f"{folder.name} contact sheet" in bpy.data.images
    simulated = load_npz(addon.commands.simulation_dir(settings) / "sequence.npz")["positions"]
    np.testing.assert_array_equal(load_npz(folder / "garment.npz")["positions"], simulated[1:3])
    assert any("already holds" in line for line in capture.log)  # the Garment panel's simulation, reused


def test_a_dataset_renders_one_variation_of_a_listed_frame(addon, settings, simulation):
    render = settings.render
    render.rig, render.engine, render.samples, render.denoise = "DATASET", "WORKBENCH", 1, False
    render.width, render.height, render.texture_dpi = 48, 48, 30.0
    render.frame_list, render.variations = "2", 1
    job = run(addon, bpy.ops.clothcapture.render, "render")
    folder = addon.commands.render_dir(settings)
    manifest = (folder / "manifest.jsonl").read_text().splitlines()
    assert len(manifest) == 1 and job.message.startswith("1 images")
    assert len(list((folder / "images").glob("*.png"))) == 1 and len(list((folder / "gt").glob("*.npz"))) == 1
    render.rig = "CAPTURE"


# ---- Review ----------------------------------------------------------------------------------------
def test_a_reconstruction_is_imported_beside_its_ground_truth_with_an_error_heat_map(addon, settings,
                                                                                   reconstruction):
    folder = addon.commands.reconstruction_dir(settings)
    assert (folder / "export" / "sequence.npz").is_file() and (folder / "evaluation.json").is_file()
    from reconstruction.refinement import RefinedSequence

    refined = RefinedSequence.load(folder / "sequence.npz")
    obj, truth = bpy.data.objects["reconstruction"], bpy.data.objects["ground truth"]
    assert refined.frames.tolist() == [1, 2]
    for t, frame in enumerate(refined.frames):
        np.testing.assert_allclose(evaluated_positions(obj, int(frame)), refined.positions[t], atol=1e-5)
    attributes = obj.data.attributes
    assert {"captured", "captured_fraction", "error_mm", "error_mm_max", "error"} <= set(attributes.keys())
    assert obj.data.color_attributes.active_color.name == "error"
    errors = np.empty(len(obj.data.vertices), np.float32)
    attributes["error_mm"].data.foreach_get("value", errors)
    garment = load_npz(addon.commands.capture_dir(settings) / "garment.npz")
    expected = np.linalg.norm(refined.positions - garment["positions"], axis=-1).mean(axis=0) * 1e3
    np.testing.assert_allclose(errors, expected, rtol=1e-4, atol=1e-4)
    assert tuple(truth.location) == pytest.approx((0.8, 0.0, 0.0))
    np.testing.assert_allclose(evaluated_positions(truth, 2), garment["positions"][1], atol=1e-5)
    assert len(bpy.data.collections["reconstruction cameras"].objects) == 3
    assert bpy.context.scene.frame_start == 1 and bpy.context.scene.frame_end == 2


def test_the_review_shows_garment_coverage_and_captured_fraction_with_the_evaluations_definitions(
        addon, settings, reconstruction):
    evaluation = json.loads((addon.commands.reconstruction_dir(settings) / "evaluation.json").read_text())
    summary, definitions = evaluation["summary"], evaluation["definitions"]
    obj = bpy.data.objects["reconstruction"]
    assert obj["clothcapture_evaluation"]["frames"] == 2
    assert f"(garment coverage {summary['garment_coverage']:.0%})" in reconstruction.message
    lines = addon.panels.evaluation_lines(obj)
    assert lines[:2] == [(f"garment_coverage: {summary['garment_coverage']:.1%}", definitions["garment_coverage"]),
                         (f"captured_fraction: {summary['captured_fraction']:.1%}", definitions["captured_fraction"])]
    assert definitions["garment_coverage"].startswith("triangulated crosspoints / all crosspoints")
    assert {line.split(":")[0] for line, _ in lines} == {k for k, v in summary.items() if isinstance(v, (int, float))}


def test_importing_again_replaces_the_review_without_the_ground_truth(addon, settings, reconstruction):
    review = settings.review
    review.show_groundtruth, review.heatmap, review.import_cameras = False, False, False
    bpy.data.objects.remove(bpy.data.objects["ground truth"])
    unused = orphans()
    try:
        assert bpy.ops.clothcapture.import_reconstruction() == {"FINISHED"}
    finally:
        review.show_groundtruth, review.heatmap, review.import_cameras = True, True, True
    obj = bpy.data.objects["reconstruction"]
    assert "ground truth" not in bpy.data.objects and "reconstruction.001" not in bpy.data.objects
    assert orphans() == unused and obj.data.name == "reconstruction" and obj.active_material.name == "reconstruction"
    assert "error" not in obj.data.attributes and obj.data.color_attributes.active_color.name == "captured"


def test_a_reconstruction_refined_but_not_exported_is_imported_from_its_sequence(addon, settings, reconstruction):
    from reconstruction.refinement import RefinedSequence

    folder = addon.commands.reconstruction_dir(settings)
    review = settings.review
    review.show_groundtruth, review.heatmap, review.import_cameras = False, False, False
    shutil.move(folder / "export", folder / "export.kept")
    try:
        assert bpy.ops.clothcapture.import_reconstruction() == {"FINISHED"}
    finally:
        shutil.move(folder / "export.kept", folder / "export")
        review.show_groundtruth, review.heatmap, review.import_cameras = True, True, True
    refined = RefinedSequence.load(folder / "sequence.npz")
    obj = bpy.data.objects["reconstruction"]
    level = Template.load(addon.commands.capture_dir(settings) / "template.npz").level(refined.level_mm)
    uv = np.empty(len(obj.data.loops) * 2, np.float32)
    obj.data.uv_layers["UVMap"].data.foreach_get("uv", uv)
    np.testing.assert_allclose(uv.reshape(-1, 3, 2), level.uv[level.faces], atol=1e-6)
    for t, frame in enumerate(refined.frames):
        np.testing.assert_allclose(evaluated_positions(obj, int(frame)), refined.positions[t], atol=1e-5)


def test_the_neighbour_check_is_turned_off_from_the_review_panel(addon, settings, capture):
    from reconstruction.__main__ import build_parser

    review = settings.review
    argv, _ = addon.commands.reconstruction_command(settings)
    assert review.neighbour_check and not build_parser().parse_args(argv[2:]).no_neighbour_check
    review.neighbour_check = False
    try:
        argv, _ = addon.commands.reconstruction_command(settings)
    finally:
        review.neighbour_check = True
    assert build_parser().parse_args(argv[2:]).no_neighbour_check  # the CLI hands it to triangulation


def test_the_networks_mode_hands_each_checkpoint_to_its_flag(addon, settings, tmp_path):
    """The Review panel's three checkpoints reach `python -m reconstruction run` as --localizer PT
    --recognizer PT --crosspoints PT (the project's one CLI vocabulary), in the Detector's order."""
    from assets.cli import networks_of
    from reconstruction.__main__ import build_parser

    (tmp_path / "cameras.json").write_text(json.dumps({"cameras": []}))
    review = settings.review
    checkpoints = {name: tmp_path / f"{name}.pt" for name in ("crosspoints", "localizer", "recognizer")}
    for name, path in checkpoints.items():
        path.write_bytes(b"")
        setattr(review, name, str(path))
    review.capture_dir, review.detections = str(tmp_path), "networks"
    try:
        argv, _ = addon.commands.reconstruction_command(settings)
    finally:
        review.capture_dir, review.detections = "", "groundtruth"
        for name in checkpoints:
            setattr(review, name, "")
    args = build_parser().parse_args(argv[2:])
    assert networks_of(args) == tuple(str(checkpoints[n]) for n in ("localizer", "recognizer", "crosspoints"))


def test_the_progress_of_a_run_goes_forward_over_its_stages_to_the_end(simulation, capture, reconstruction):
    """Sewing (its bar cleared when it converges), simulating; a capture's texture, simulation reused,
    three cameras' images and ground truth; a reconstruction's detect to export: each run's progress
    never goes back and reaches its end (a stage's bar used to restart it, or leave it at 15%)."""
    for kind in ("simulation", "render", "reconstruction"):
        seen = PROGRESS[kind]
        assert seen == sorted(seen) and seen[-1] == 1.0, (kind, seen)
        assert max(seen[:-1]) >= 0.5, (kind, seen)  # half way through its stages while it ran
