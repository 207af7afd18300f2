"""reconstruction.review's pieces on their own: the sequence of a reconstruction folder to review
(`pipeline.sequence_of`: exported or only refined), and the review built into a scene of the
caller's (as the Blender add-on does) with plain arrays animated."""

import os

import numpy as np
import pytest

from reconstruction.exports import export_sequence, from_refined
from reconstruction.pipeline import RunSettings, sequence_of, start
from reconstruction.refinement import RefinedSequence
from tests.reconstruction.cylinder import cylinder_template, wrapped
from tests.reconstruction.test_export import _cameras, _sequence


def _refined_folder(folder, template):
    """A reconstruction folder refined (frames 3 and 4 of the cylinder on its 12 mm level) but not exported."""
    template.save(folder / "template.npz", levels=(12,))
    start(folder, RunSettings(template=str(folder / "template.npz"), detections="groundtruth"))
    level = template.level(12)
    shape = wrapped(template, 12)
    refined = RefinedSequence(level_mm=12, positions=np.stack([shape, shape + 0.01]).astype(np.float32),
                              captured=np.arange(2 * len(shape)).reshape(2, -1) % 3 == 0, faces=level.sewn_faces,
                              frames=np.array([3, 4]), start_frame=0, source="groundtruth(test)", diagnostics=[{}, {}],
                              config={})
    refined.save(folder / "sequence.npz")
    return refined


def test_a_folder_refined_but_not_exported_is_reviewed_from_its_sequence_and_template(tmp_path):
    template = cylinder_template()
    refined = _refined_folder(tmp_path, template)
    sequence = sequence_of(tmp_path)
    level = template.level(12)
    np.testing.assert_array_equal(sequence.positions, refined.positions)
    np.testing.assert_array_equal(sequence.corner_uv, level.uv[level.faces].astype(np.float32))
    np.testing.assert_array_equal(sequence.captured, refined.captured)
    assert (sequence.frames.tolist(), sequence.fps, sequence.level_mm, sequence.source) == ([3, 4], 120.0, 12,
                                                                                              "groundtruth(test)")
    assert sequence_of(tmp_path, fps=30.0).fps == 30.0

    export_sequence(tmp_path / "export", from_refined(refined, template, 60.0), formats=("npz",), progress=False)
    assert sequence_of(tmp_path).fps == 60.0  # the export stage's, with its frame rate
    refined.save(tmp_path / "sequence.npz")  # refined again after the export: the export is stale
    later = (tmp_path / "export" / "sequence.npz").stat().st_mtime_ns + 10**9
    os.utime(tmp_path / "sequence.npz", ns=(later, later))
    assert sequence_of(tmp_path).fps == 120.0


def test_a_folder_without_a_sequence_is_refused_naming_the_stage(tmp_path):
    with pytest.raises(ValueError, match="no sequence.npz: run the reconstruction \\(its refine stage\\) first"):
        sequence_of(tmp_path)
    template = cylinder_template()
    refined = _refined_folder(tmp_path, template)
    elsewhere = RefinedSequence(4, refined.positions, refined.captured, refined.faces, refined.frames, 0, "", [], {})
    with pytest.raises(ValueError, match="the 4 mm level of template 'cylinder'.*not the sequence's template"):
        from_refined(elsewhere, template, 120.0)


@pytest.mark.slow
def test_the_review_goes_into_the_scene_and_collection_it_is_given(tmp_path):
    bpy = pytest.importorskip("bpy")
    from reconstruction.review import build_review_scene

    bpy.ops.wm.read_factory_settings(use_empty=True)
    main = bpy.context.scene
    main.frame_start, main.frame_end = 1, 250
    shading = main.display.shading.color_type
    other = bpy.data.scenes.new("review")
    folder = bpy.data.collections.new("mine")
    other.collection.children.link(folder)
    sequence = _sequence()
    with pytest.raises(ValueError, match="give the PC2 file's path"):
        build_review_scene(other, sequence, animation="mesh_cache")
    assert not bpy.data.objects and not bpy.data.meshes  # refused before anything was made

    made = build_review_scene(other, sequence, _cameras(), animation="mesh_cache", cache=tmp_path / "rec.pc2",
                              name="rec", collection=folder, cameras_name="rec cameras")
    assert made.animation == "mesh_cache" and made.garment.name == "rec"
    assert list(folder.objects) == [made.garment] and made.garment.data.materials[0].name == "rec"
    assert made.garment.modifiers["capture"].filepath == str(tmp_path / "rec.pc2")
    assert made.cameras.name == "rec cameras" and other.camera.name == "front"
    assert (other.frame_start, other.frame_end, other.frame_current) == (10, 14, 10)
    assert other.render.fps / other.render.fps_base == pytest.approx(120.0)
    assert other.display.shading.color_type == "VERTEX"
    # the context's scene is not touched
    assert (main.frame_start, main.frame_end, main.camera) == (1, 250, None)
    assert main.display.shading.color_type == shading


@pytest.mark.slow
def test_plain_positions_are_animated_at_their_frames(tmp_path):
    bpy = pytest.importorskip("bpy")
    from reconstruction.review import animate, new_mesh

    bpy.ops.wm.read_factory_settings(use_empty=True)
    sequence = _sequence()
    obj = bpy.data.objects.new("body", new_mesh("body", sequence.positions[0], sequence.faces))
    bpy.context.scene.collection.objects.link(obj)
    with pytest.raises(ValueError, match=r"positions must be \(T, 9, 3\) with T = 2 frames"):
        animate(obj, sequence.positions, [10, 12])
    with pytest.raises(ValueError, match="frames must increase"):
        animate(obj, sequence.positions, [10, 14, 12])
    assert animate(obj, sequence.positions, [3, 4, 6]) == "shape_keys"
    depsgraph = bpy.context.evaluated_depsgraph_get()
    for t, frame in enumerate((3, 4, 6)):
        bpy.context.scene.frame_set(frame)
        co = np.zeros(27, np.float32)
        obj.evaluated_get(depsgraph).data.vertices.foreach_get("co", co)
        np.testing.assert_allclose(co.reshape(9, 3), sequence.positions[t], atol=1e-6)
    assert not list(tmp_path.iterdir())  # shape keys write no cache
