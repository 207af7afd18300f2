"""reconstruction.exports and reconstruction.review: files read back by other programs (trimesh, bpy).
The review is bpy's (a leaf module, imported only by the tests that need it)."""

import shutil

import cv2
import numpy as np
import pytest
import trimesh

from assets.cameras import Camera, save_cameras
from assets.fileio import load_npz, save_npz
from reconstruction.exports import (CAPTURED_RGB, FILLED_RGB, GarmentSequence, export_sequence, load_sequence_npz,
                                   read_pc2, save_sequence_npz, write_frame_meshes, write_obj, write_pc2, write_ply)
from reconstruction.pipeline import write_review

FRAMES = np.array([10, 12, 14])  # not starting at 0, step 2: offsets and scales must be right


def _sequence(frames=FRAMES, seed=0):
    """A 3 x 3 vertex grid (8 triangles, 10 cm cells) moving randomly; the right column of faces has
    its own UVs (a seam: the middle column of vertices has two UVs)."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(3) * 0.1, np.arange(3) * 0.1)
    grid = np.stack([x.ravel(), y.ravel(), np.zeros(9)], axis=1)
    quads = np.array([[r * 3 + c, r * 3 + c + 1, r * 3 + c + 4, r * 3 + c + 3] for r in range(2) for c in range(2)])
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    uv = grid[:, :2] * 4
    corner_uv = uv[faces]
    right = (grid[faces][:, :, 0] > 0.05).all(axis=1)
    corner_uv[right] += [0.05, 0.1]
    positions = grid + rng.normal(0, 0.02, (len(frames), 9, 3)) + [0.0, 0.0, 1.0]
    captured = rng.random((len(frames), 9)) < 0.6
    return GarmentSequence(positions=positions, faces=faces, corner_uv=corner_uv, captured=captured, frames=frames,
                           fps=120.0, source="groundtruth(noise=0.3px, dropout=0.1)", level_mm=12)


def _texture(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), np.arange(8 * 8 * 3, dtype=np.uint8).reshape(8, 8, 3))
    return path


def _no_partial_files(folder):
    assert not [p for p in folder.rglob("*") if p.name.endswith(".part")]


def test_sequence_npz_round_trip(tmp_path):
    sequence = _sequence()
    save_sequence_npz(tmp_path / "seq.npz", sequence)
    again = load_sequence_npz(tmp_path / "seq.npz")
    for key in ("positions", "faces", "corner_uv", "captured", "frames"):
        assert getattr(again, key).dtype == getattr(sequence, key).dtype
        np.testing.assert_array_equal(getattr(again, key), getattr(sequence, key))
    assert (again.fps, again.source, again.level_mm) == (120.0, sequence.source, 12)
    assert sequence.positions.dtype == np.float32 and sequence.faces.dtype == np.int32
    _no_partial_files(tmp_path)


def test_bad_input_is_refused_naming_the_argument(tmp_path):
    s = _sequence()
    fields = dict(positions=s.positions, faces=s.faces, corner_uv=s.corner_uv, captured=s.captured, frames=s.frames,
                  fps=s.fps)
    bad = {
        "positions": dict(positions=s.positions[:, :, :2]),
        "captured": dict(captured=s.captured[:, :4]),
        "faces": dict(faces=s.faces + 1),
        "corner_uv": dict(corner_uv=s.corner_uv[:3]),
        "frames": dict(frames=[10, 14, 12]),
        "fps": dict(fps=0.0),
    }
    for name, change in bad.items():
        with pytest.raises(ValueError, match=rf"GarmentSequence\.{name}"):
            GarmentSequence(**{**fields, **change})
    with pytest.raises(ValueError, match="GarmentSequence.captured: expected booleans"):
        GarmentSequence(**{**fields, "captured": s.captured.astype(float)})
    with pytest.raises(ValueError, match="GarmentSequence.positions: 1 value"):
        GarmentSequence(**{**fields, "positions": np.where(np.arange(3 * 9 * 3).reshape(3, 9, 3) == 5, np.nan,
                                                           s.positions)})
    with pytest.raises(ValueError, match=r"write_ply: captured: expected shape \(9,\)"):
        write_ply(tmp_path / "a.ply", s.positions[0], s.faces, s.captured[0, :5])
    with pytest.raises(ValueError, match=r"write_obj: corner_uv: expected shape \(8, 3, 2\)"):
        write_obj(tmp_path / "a.obj", s.positions[0], s.faces, s.corner_uv[:, :2])
    with pytest.raises(ValueError, match=r"write_pc2: positions: expected shape \(T, V, 3\)"):
        write_pc2(tmp_path / "a.pc2", s.positions[0])
    with pytest.raises(ValueError, match="evenly spaced"):
        _sequence(frames=np.array([0, 1, 3])).frame_step
    assert not list(tmp_path.iterdir())  # nothing written, not even a partial file

    write_pc2(tmp_path / "cut.pc2", s.positions)
    (tmp_path / "cut.pc2").write_bytes((tmp_path / "cut.pc2").read_bytes()[:-4])
    with pytest.raises(ValueError, match="cut.pc2: 3 samples of 9 points need 356 bytes, the file has 352"):
        read_pc2(tmp_path / "cut.pc2")
    save_npz(tmp_path / "seq.npz", {"positions": s.positions, "faces": s.faces})
    with pytest.raises(ValueError, match="seq.npz: missing array.*corner_uv"):
        load_sequence_npz(tmp_path / "seq.npz")
    save_sequence_npz(tmp_path / "seq.npz", s)
    save_npz(tmp_path / "seq.npz", {**load_npz(tmp_path / "seq.npz"), "captured": s.captured[:2]})
    with pytest.raises(ValueError, match=r"seq.npz: GarmentSequence.captured: expected shape \(3, 9\)"):
        load_sequence_npz(tmp_path / "seq.npz")
    (tmp_path / "other.pc2").write_bytes(b"NOTACACHE000" + bytes(20))
    with pytest.raises(ValueError, match="other.pc2: not a PC2 file"):
        read_pc2(tmp_path / "other.pc2")


def test_ply_loads_in_trimesh(tmp_path):
    sequence = _sequence()
    paths = write_frame_meshes(tmp_path, sequence, "ply", progress=False)
    assert [p.name for p in paths] == ["f000010.ply", "f000012.ply", "f000014.ply"]
    for t, path in enumerate(paths):
        mesh = trimesh.load(path, process=False)
        np.testing.assert_array_equal(mesh.vertices, sequence.positions[t])
        np.testing.assert_array_equal(mesh.faces, sequence.faces)
        expected = np.where(sequence.captured[t][:, None], CAPTURED_RGB, FILLED_RGB)
        np.testing.assert_array_equal(mesh.visual.vertex_colors[:, :3], expected)
        raw = mesh.metadata["_ply_raw"]["vertex"]["data"]
        np.testing.assert_array_equal(raw["captured"], sequence.captured[t])
    assert b"comment clothcapture reconstruction frame 14 source groundtruth(noise=0.3px, dropout=0.1)" in \
        paths[2].read_bytes()
    _no_partial_files(tmp_path)


def test_obj_loads_in_trimesh_with_uvs_and_texture(tmp_path):
    sequence = _sequence()
    write_frame_meshes(tmp_path / "elsewhere", sequence, "obj", texture=_texture(tmp_path / "texture.png"),
                       progress=False)
    assert (tmp_path / "elsewhere" / "garment.mtl").read_text().splitlines()[-1] == "map_Kd ../texture.png"
    # trimesh reads textures from the OBJ's folder only
    paths = write_frame_meshes(tmp_path / "obj", sequence, "obj", texture=_texture(tmp_path / "obj" / "texture.png"),
                               progress=False)
    assert (tmp_path / "obj" / "garment.mtl").read_text().splitlines()[-1] == "map_Kd texture.png"
    unique_uv = len(np.unique(sequence.corner_uv.reshape(-1, 2), axis=0))
    assert unique_uv == 9 + 3  # the seam's middle column of vertices has a second UV
    for t, path in enumerate(paths):
        lines = path.read_text().splitlines()
        assert sum(line.startswith("v ") for line in lines) == sequence.num_vertices
        assert sum(line.startswith("vt ") for line in lines) == unique_uv
        assert "mtllib garment.mtl" in lines and "usemtl garment" in lines
        mesh = trimesh.load(path, process=False)
        assert len(mesh.faces) == len(sequence.faces)
        np.testing.assert_allclose(mesh.vertices[mesh.faces], sequence.positions[t][sequence.faces], atol=6e-7)
        np.testing.assert_allclose(mesh.visual.uv[mesh.faces], sequence.corner_uv, atol=6e-8)
        assert mesh.visual.material.image.size == (8, 8)
    # trimesh splits the vertices of the seam: 9 positions + 3 second UVs
    assert len(mesh.vertices) == unique_uv

    write_obj(tmp_path / "one.obj", sequence.positions[1], sequence.faces, sequence.corner_uv)
    text = (tmp_path / "one.obj").read_text()
    assert "mtllib" not in text and not (tmp_path / "one.mtl").exists()
    mesh = trimesh.load(tmp_path / "one.obj", process=False)
    np.testing.assert_allclose(mesh.visual.uv[mesh.faces], sequence.corner_uv, atol=6e-8)
    _no_partial_files(tmp_path)


def test_pc2_round_trip_and_header(tmp_path):
    sequence = _sequence()
    write_pc2(tmp_path / "a.pc2", sequence.positions, start_frame=10.0, sample_rate=2.0)
    data = (tmp_path / "a.pc2").read_bytes()
    assert data[:12] == b"POINTCACHE2\0"
    assert np.frombuffer(data[12:32], dtype="<i4")[[0, 1, 4]].tolist() == [1, 9, 3]  # version, points, samples
    assert np.frombuffer(data[12:32], dtype="<f4")[[2, 3]].tolist() == [10.0, 2.0]  # start frame, sample rate
    assert len(data) == 32 + 3 * 9 * 3 * 4
    cache = read_pc2(tmp_path / "a.pc2")
    np.testing.assert_array_equal(cache.positions, sequence.positions)
    assert (cache.start_frame, cache.sample_rate) == (10.0, 2.0)


def test_export_sequence_writes_every_file_format(tmp_path):
    sequence = _sequence()
    written = export_sequence(tmp_path, sequence, progress=False, texture=_texture(tmp_path / "texture.png"))
    assert {k: len(v) for k, v in written.items()} == {"npz": 1, "obj": 3, "ply": 3, "pc2": 1}
    assert (tmp_path / "obj" / "garment.mtl").exists() and not (tmp_path / "review.blend").exists()
    cache = read_pc2(tmp_path / "garment.pc2")
    assert (cache.start_frame, cache.sample_rate) == (10.0, 2.0)
    np.testing.assert_array_equal(load_sequence_npz(tmp_path / "sequence.npz").positions, cache.positions)
    with pytest.raises(ValueError, match="unknown format.*glb"):
        export_sequence(tmp_path, sequence, formats=("glb",))


def test_the_review_is_written_in_a_process_of_its_own_and_its_failure_keeps_the_previous_export(tmp_path):
    """The pipeline's review (`write_review`: python -m reconstruction.review) gives export_sequence its
    .blend without bpy in this process' modules; a review that fails discards the staged files."""
    import sys

    pytest.importorskip("bpy")
    sequence, cameras = _sequence(), tmp_path / "cameras.json"
    save_cameras(cameras, _cameras())
    texture = _texture(tmp_path / "texture.png")
    loaded = "bpy" in sys.modules
    written = export_sequence(tmp_path / "export", sequence, progress=False, texture=texture,
                              review=lambda path: write_review(path, sequence, cameras, texture))
    assert written["blend"] == [tmp_path / "export" / "review.blend"] and written["blend"][0].stat().st_size > 0
    assert ("bpy" in sys.modules) == loaded  # this process did not load it
    before = {p: p.stat().st_mtime_ns for p in (tmp_path / "export").rglob("*")}
    with pytest.raises(RuntimeError, match=r"review.blend: the review .blend was not written: .*nowhere.png"):
        export_sequence(tmp_path / "export", _sequence(seed=1), progress=False,
                        review=lambda path: write_review(path, sequence, cameras, tmp_path / "nowhere.png"))
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "export").rglob("*")} == before


def _cameras():
    front = Camera.look_at((0.1, -1.5, 1.6), (0.1, 0.1, 1.0), focal_mm=35.0, width=640, height=480, name="front")
    side = Camera.look_at((1.2, 0.1, 1.3), (0.1, 0.1, 1.0), focal_mm=50.0, width=400, height=600)
    K = side.K.copy()
    K[0, 2], K[1, 2] = 181.25, 322.5  # off-centre principal point: Blender's shifts
    return [front, Camera(K=K, R=side.R, t=side.t, width=400, height=600)]


def test_choose_animation_by_size():
    review = pytest.importorskip("reconstruction.review")
    SHAPE_KEY_MAX_VERTEX_FRAMES, choose_animation = review.SHAPE_KEY_MAX_VERTEX_FRAMES, review.choose_animation
    small = _sequence().positions
    assert choose_animation(small) == "shape_keys"
    for vertices, expected in ((SHAPE_KEY_MAX_VERTEX_FRAMES // 2, "shape_keys"),
                               (SHAPE_KEY_MAX_VERTEX_FRAMES // 2 + 1, "mesh_cache")):
        two_frames = np.zeros((2, vertices, 3), np.float32)
        assert choose_animation(two_frames) == expected
    assert choose_animation(two_frames, "shape_keys") == "shape_keys"
    with pytest.raises(ValueError, match="animation must be one of"):
        choose_animation(small, "alembic")


def _evaluated_positions(bpy, obj, frame, subframe=0.0):
    bpy.context.scene.frame_set(frame, subframe=subframe)
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    co = np.zeros(len(evaluated.data.vertices) * 3, dtype=np.float32)
    evaluated.data.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


@pytest.mark.slow
@pytest.mark.parametrize("animation", ["shape_keys", "mesh_cache"])
def test_review_blend_opens_in_blender(tmp_path, animation):
    bpy = pytest.importorskip("bpy")
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    from reconstruction.review import CAPTURED_RGBA, FILLED_RGBA, write_review_blend

    sequence, cameras = _sequence(), _cameras()
    texture = _texture(tmp_path / "made" / "texture.png")
    written = write_review_blend(tmp_path / "made" / "review.blend", sequence, cameras=cameras, texture=texture,
                                 animation=animation)
    assert [p.name for p in written] == ["review.blend"] + (["review.pc2"] if animation == "mesh_cache" else [])
    _no_partial_files(tmp_path)
    shutil.move(tmp_path / "made", tmp_path / "moved")  # the .blend refers to its texture and cache relatively

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "moved" / "review.blend"))
    scene = bpy.context.scene
    assert scene.frame_current == 10
    obj = bpy.data.objects["garment"]
    assert (obj["source"], obj["level_mm"]) == (sequence.source, 12)
    mesh = obj.data
    assert (len(mesh.vertices), len(mesh.polygons)) == (9, 8)
    loops = np.zeros(24, dtype=np.int32)
    mesh.loops.foreach_get("vertex_index", loops)
    np.testing.assert_array_equal(loops.reshape(8, 3), sequence.faces)
    uv = np.zeros(48, dtype=np.float32)
    mesh.uv_layers["UVMap"].data.foreach_get("uv", uv)
    np.testing.assert_array_equal(uv.reshape(8, 3, 2), sequence.corner_uv)

    colour = mesh.color_attributes["captured"]
    assert (colour.domain, colour.data_type) == ("POINT", "FLOAT_COLOR")
    rgba = np.zeros(36, dtype=np.float32)
    colour.data.foreach_get("color", rgba)
    expected = np.where(sequence.captured[0][:, None], CAPTURED_RGBA, FILLED_RGBA)
    np.testing.assert_allclose(rgba.reshape(9, 4), expected, atol=1e-6)
    fraction = np.zeros(9, dtype=np.float32)
    mesh.attributes["captured_fraction"].data.foreach_get("value", fraction)
    np.testing.assert_allclose(fraction, sequence.captured.mean(axis=0), atol=1e-6)
    image = next(n for n in mesh.materials[0].node_tree.nodes if n.type == "TEX_IMAGE").image
    assert image.filepath.startswith("//") and image.size[:] == (8, 8)

    for t, frame in enumerate(FRAMES):
        np.testing.assert_allclose(_evaluated_positions(bpy, obj, int(frame)), sequence.positions[t], atol=1e-6)
    quarter = 0.75 * sequence.positions[0] + 0.25 * sequence.positions[1]  # linear between captured frames
    np.testing.assert_allclose(_evaluated_positions(bpy, obj, 10, subframe=0.5), quarter, atol=1e-6)
    if animation == "mesh_cache":
        assert obj.modifiers["capture"].filepath == "//review.pc2"
    else:
        assert len(mesh.shape_keys.key_blocks) == 3 and not obj.modifiers

    assert (scene.frame_start, scene.frame_end) == (10, 14)
    assert scene.display.shading.color_type == "VERTEX"  # Solid shading shows the "captured" colours
    assert scene.render.fps / scene.render.fps_base == pytest.approx(120.0)
    blender_cameras = bpy.data.collections["cameras"].objects
    assert [c.name for c in blender_cameras] == ["front", "camera01"] and scene.camera.name == "front"
    point = np.array([[0.13, 0.08, 1.02]])
    for camera, obj in zip(cameras, blender_cameras):
        scene.render.resolution_x, scene.render.resolution_y = obj["resolution_x"], obj["resolution_y"]
        ndc = world_to_camera_view(scene, obj, Vector(point[0].tolist()))
        pixel = np.array([ndc.x * camera.width, (1.0 - ndc.y) * camera.height])  # Blender's y points up
        np.testing.assert_allclose(pixel, camera.project(point)[0][0], atol=1e-3)


@pytest.mark.slow
def test_review_blend_of_a_single_frame_without_cameras(tmp_path):
    bpy = pytest.importorskip("bpy")
    from reconstruction.review import write_review_blend

    sequence = _sequence(frames=np.array([7]))
    assert write_review_blend(tmp_path / "one.blend", sequence) == [tmp_path / "one.blend"]
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "one.blend"))
    scene = bpy.context.scene
    obj = bpy.data.objects["garment"]
    assert obj.data.shape_keys is None and scene.camera is None and not bpy.data.cameras
    assert (scene.frame_start, scene.frame_end) == (7, 7)
    np.testing.assert_array_equal(_evaluated_positions(bpy, obj, 7), sequence.positions[0])
    material = obj.data.materials[0].node_tree.nodes
    assert next(n for n in material if n.type == "VERTEX_COLOR").layer_name == "captured"
