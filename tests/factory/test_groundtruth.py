"""Ground truth of marker points in images of a real (small) garment template, with depth maps made
by ray casting the mesh at pixel centres (trimesh), as a renderer's Z pass would give them."""

import dataclasses

import numpy as np
import pytest
import trimesh

from assets.cameras import Camera
from assets.garments import SewingPattern, Template
from assets.pattern import (
    CROSSPOINT_CROP,
    RECOGNIZER_CROP,
    PatternSpec,
    crop_crosspoints_px,
    generate_codebook,
    localization_rc,
    reference_textures,
    render_region,
)
from assets.pattern.raster import pixels_per_metre
from assets.pattern.observation import (
    MIN_COMPLETION_CROSSPOINTS,
    ImageGroundTruth,
    crosspoint_crops,
    localizer_targets,
    recognizer_crops,
)
from assets.garments.markers import MarkerSurface
from factory.groundtruth import image_ground_truth
from tests.assets.garment_fixtures import tube

#: 64 IDs keep the codebook fast to generate; rows and cols are set per panel by the layout
SPEC = PatternSpec(rows=1, cols=1, num_ids=64)
#: a convex "house": 0.2 m wide, walls 0.3 m, roof peak at 0.34 m.  Tiled by 5 x 8 markers of 48 mm
#: from (0, 0): column 4 is cut by the right wall, the top rows by the roof.
HOUSE = np.array([[0.0, 0.0], [0.2, 0.0], [0.2, 0.3], [0.1, 0.34], [0.0, 0.3]])
SIZE = 256
FOLD_Y = 0.096  # a grid line of the 12 mm mesh and a marker border: the bottom two marker rows fold
GAP = 0.01


@pytest.fixture(scope="module")
def codebook():
    return generate_codebook(SPEC)


@pytest.fixture(scope="module")
def house(codebook):
    pattern = SewingPattern.from_dict({
        "name": "house",
        "panels": [{"name": "house", "vertices": HOUSE.tolist(), "edges": [{"name": n} for n in "abcde"]}],
    })
    template = Template.build(pattern, SPEC, dpi=150.0)
    tables = template.layout.tables(codebook)
    return template, tables, MarkerSurface.build(template, 12, tables)


def placed(template, fold=None):
    """Sewn-mesh positions of the house standing in the plane y = 0 (pattern x -> world x, pattern
    y -> world z), printed side towards -y.  fold=-1 / +1: the part below FOLD_Y turned 180 degrees
    about the fold line so that it lies GAP in front (-y) / behind (+y) of the rest."""
    level = template.level(12)
    x, y = level.pattern_xy[:, 0], level.pattern_xy[:, 1]
    world = np.stack([x, np.zeros_like(x), y], axis=1)
    if fold is not None:
        flap = y < FOLD_Y - 1e-9
        world[flap] = np.stack([x[flap], np.full(flap.sum(), fold * GAP), 2 * FOLD_Y - y[flap]], axis=1)
    return level.sew(world)


def depth_map(camera, positions, faces):
    """(H, W) float32 camera-frame depth of the nearest surface at every pixel centre, inf on the background."""
    rows, cols = np.mgrid[0 : camera.height, 0 : camera.width]
    pixels = np.stack([cols.ravel() + 0.5, rows.ravel() + 0.5], axis=1)
    directions = camera.unproject(pixels, np.ones(len(pixels))) - camera.center
    origins = np.broadcast_to(camera.center, directions.shape)
    mesh = trimesh.Trimesh(positions, faces, process=False)
    hits, ray, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=True)
    depth = np.full(len(pixels), np.inf)
    np.minimum.at(depth, ray, camera.to_camera(hits)[:, 2])
    return depth.reshape(camera.height, camera.width).astype(np.float32)


def front_camera(x, z, distance, name="front"):
    return Camera.look_at((x, -distance, z), (x, 0.0, z), focal_mm=50.0, sensor_mm=36.0, width=SIZE, height=SIZE, name=name)


def marker_xy(tables):
    return np.concatenate([t.marker_crosspoint_xy for t in tables])  # (M, 25, 25, 2)


def inside_house(xy):
    """On the fabric: inside the convex outline (edges included)."""
    a, b = HOUSE, np.roll(HOUSE, -1, axis=0)
    cross = (b - a)[:, 0] * (xy[..., None, 1] - a[:, 1]) - (b - a)[:, 1] * (xy[..., None, 0] - a[:, 0])
    return (cross >= -1e-12).all(axis=-1)


def test_surface_locates_every_crosspoint_in_its_own_panel_of_a_sewn_tube(codebook):
    template = Template.build(tube(), SPEC, dpi=150.0)
    tables = template.layout.tables(codebook)
    surface = MarkerSurface.build(template, 12, tables)
    level = template.level(12)
    np.testing.assert_array_equal(surface.marker_id, np.arange(sum(t.num_markers for t in tables)))
    np.testing.assert_array_equal(surface.sewn_faces, level.sewn_faces)
    assert surface.num_vertices == level.num_sewn_vertices < level.num_vertices
    xy = marker_xy(tables)
    on = surface.xp_face >= 0
    assert 0.3 < on.mean() < 0.95  # the tiling covers each panel's bounding box; curved edges cut it
    face = surface.xp_face[on]
    # the face is in the marker's panel and its weights give back the crosspoint's pattern position
    np.testing.assert_array_equal(level.panel[level.faces[face, 0]], np.broadcast_to(surface.panel[:, None, None], on.shape)[on])
    located = np.einsum("nkd,nk->nd", level.pattern_xy[level.faces[face]], surface.xp_bary[on])
    np.testing.assert_allclose(located, xy[on], atol=1e-12)
    assert surface.xp_bary[on].min() >= -1e-9
    # no face of its panel contains a point called off the fabric (checked against every face)
    for p in range(len(tables)):
        off = xy[~on & (surface.panel[:, None, None] == p)]
        tri = level.pattern_xy[level.faces[level.panel[level.faces[:, 0]] == p]]
        v0, v1, v2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], off[:, None] - tri[:, 0]
        det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
        l1 = (v2[..., 0] * v1[:, 1] - v2[..., 1] * v1[:, 0]) / det
        l2 = (v0[:, 0] * v2[..., 1] - v0[:, 1] * v2[..., 0]) / det
        assert (np.minimum(np.minimum(l1, l2), 1 - l1 - l2) < 0).all()
    rc = localization_rc(SPEC)
    np.testing.assert_array_equal(surface.loc_face, surface.xp_face[:, rc[:, 0], rc[:, 1]])
    # the sewn mesh with the front panel's vertices at their pattern positions (its seams pair it only
    # with the back panel, so no two of its vertices merge): its points are the pattern positions
    front = level.panel[level.faces[:, 0]] == 0
    flat = np.zeros((level.num_sewn_vertices, 3))
    flat[level.sewn_faces[front].ravel(), :2] = level.pattern_xy[level.faces[front].ravel()]
    mine = on & (surface.panel[:, None, None] == 0)
    np.testing.assert_allclose(surface.points(flat)[1][mine][:, :2], xy[mine], atol=1e-12)
    assert np.isnan(surface.points(flat)[1][~on]).all()


def test_flat_panel_projects_by_the_exact_affine_map_with_the_expected_visibility(house):
    template, tables, surface = house
    camera = front_camera(0.2, 0.2, 0.5)  # sees x, z in [0.02, 0.38]: cuts the left column and bottom row
    positions = placed(template)
    gt = image_ground_truth(surface, positions, camera, depth_map(camera, positions, surface.sewn_faces))
    f = camera.K[0, 0]
    xy = marker_xy(tables)
    expected = np.stack([SIZE / 2 + f * (xy[..., 0] - 0.2) / 0.5, SIZE / 2 - f * (xy[..., 1] - 0.2) / 0.5], axis=-1)
    on = inside_house(xy)
    np.testing.assert_array_equal(surface.xp_face >= 0, on)
    np.testing.assert_allclose(gt.crosspoints_px[on], expected[on], atol=1e-3)
    assert np.isnan(gt.crosspoints_px[~on]).all()
    rc = localization_rc(SPEC)
    np.testing.assert_array_equal(gt.points_px, gt.crosspoints_px[:, rc[:, 0], rc[:, 1]])
    np.testing.assert_allclose(gt.points_depth[on[:, rc[:, 0], rc[:, 1]]], 0.5, atol=1e-6)
    inside = ((expected >= 0) & (expected < SIZE)).all(axis=-1)
    np.testing.assert_array_equal(gt.crosspoint_visible, on & inside)
    loc_ok = (on & inside)[:, rc[:, 0], rc[:, 1]].all(axis=1)
    want = np.where(loc_ok & (inside | ~on).all(axis=(1, 2)), 2, np.where((on & inside).any(axis=(1, 2)), 1, 0))
    np.testing.assert_array_equal(gt.status, want)
    assert set(gt.status.tolist()) == {0, 1, 2}  # hidden, partial and full markers
    assert (gt.status == 2).sum() >= 12


def test_panel_seen_from_behind_is_hidden(house):
    template, _, surface = house
    camera = Camera.look_at((0.1, 0.5, 0.2), (0.1, 0.0, 0.2), width=SIZE, height=SIZE)
    positions = placed(template)
    gt = image_ground_truth(surface, positions, camera, depth_map(camera, positions, surface.sewn_faces))
    inside = ((gt.crosspoints_px >= 0) & (gt.crosspoints_px < SIZE)).all(axis=-1)
    assert inside.mean() > 0.5  # in view and unoccluded, but back-facing
    assert not gt.crosspoint_visible.any() and not gt.point_visible.any() and (gt.status == 0).all()


def test_a_fold_hides_what_it_covers_and_shows_its_printed_side_only_to_the_far_side(house):
    template, tables, surface = house
    xy = marker_xy(tables)
    full = inside_house(xy).all(axis=(1, 2))
    marker_bottom = xy[:, -1, 0, 1]  # BL's y: rows above the fold start at 0.192, covered rows at 0.096 and 0.144

    # flap towards the camera: its back faces the camera and covers the marker rows 0.096 .. 0.192
    camera = front_camera(0.1, 0.2, 0.5)
    positions = placed(template, fold=-1)
    depth = depth_map(camera, positions, surface.sewn_faces)
    gt = image_ground_truth(surface, positions, camera, depth)
    unfolded_view = image_ground_truth(surface, positions, camera, np.full_like(depth, np.inf))
    uncovered = full & (marker_bottom > 0.19)
    assert uncovered.sum() >= 8 and (gt.status[uncovered] == 2).all()
    covered = (xy[..., 1] > FOLD_Y + 0.004) & (xy[..., 1] < 2 * FOLD_Y - 0.004) & (surface.xp_face >= 0)
    assert unfolded_view.crosspoint_visible[covered].mean() > 0.99  # front-facing, in front, in the image ...
    assert not gt.crosspoint_visible[covered].any()  # ... but occluded by the flap
    assert (gt.status[(marker_bottom > 0.09) & (marker_bottom < 0.19)] < 2).all()
    assert not gt.crosspoint_visible[xy[..., 1] < FOLD_Y - 1e-9].any()  # the flap shows its back
    assert (gt.status[marker_bottom < 0.01] == 0).all()  # the bottom row: all on the flap

    # flap towards the back, seen from behind: the flap's printed side is on top, the rest faces away
    camera = Camera.look_at((0.1, 0.5, 0.2), (0.1, 0.0, 0.2), focal_mm=50.0, width=SIZE, height=SIZE, name="back")
    positions = placed(template, fold=+1)
    gt = image_ground_truth(surface, positions, camera, depth_map(camera, positions, surface.sewn_faces))
    flap = full & (marker_bottom < 0.01)  # (the row above it has its top border on the crease)
    assert flap.sum() == 4 and (gt.status[flap] == 2).all()
    assert not gt.crosspoint_visible[xy[..., 1] > FOLD_Y + 1e-9].any()
    # its printed side is seen turned by 180 degrees, not mirrored: TL right of TR and below BL
    tl, tr, bl = gt.points_px[flap, 1], gt.points_px[flap, 2], gt.points_px[flap, 3]
    assert (tl[:, 0] > tr[:, 0] + 10).all() and (tl[:, 1] > bl[:, 1] + 10).all()


@pytest.fixture(scope="module")
def close_up(house):
    """A fronto-parallel close-up of the four markers around the crosspoint (0.096, 0.24), and its
    image rendered exactly (the flat panel's image is the printed pattern at f / d pixels per metre)."""
    template, tables, surface = house
    distance, (x, z) = 0.15, (0.096, 0.24)
    camera = front_camera(x, z, distance, name="close")
    positions = placed(template)
    gt = image_ground_truth(surface, positions, camera, depth_map(camera, positions, surface.sewn_faces))
    ppm = camera.K[0, 0] / distance
    half = SIZE / 2 / ppm
    image = render_region(tables[0], (x - half, z - half, x + half, z + half), dpi=ppm / pixels_per_metre(1.0))
    assert image.shape == (SIZE, SIZE, 3)
    return tables, surface, camera, gt, image


def test_recognizer_crops_of_a_fronto_parallel_marker_look_like_its_reference(close_up):
    tables, surface, _, gt, image = close_up
    crops, ids = recognizer_crops(image, gt, surface.spec)
    assert crops.shape == (4, 96, 96, 3) and crops.dtype == np.uint8 and ids.dtype == np.int32
    np.testing.assert_array_equal(ids, np.flatnonzero(gt.point_visible.all(axis=1)))
    references = reference_textures(SPEC, tables[0].codes, RECOGNIZER_CROP).astype(np.float64).mean(axis=-1)
    grey = crops.astype(np.float64).mean(axis=-1)
    corr = np.corrcoef(np.concatenate([grey.reshape(len(ids), -1), references.reshape(len(references), -1)]))
    corr = corr[: len(ids), len(ids) :]  # (crops, all markers)
    # about 0.97; half a pixel of misregistration (a pixel-centre convention slip) gives about 0.74
    assert (corr[np.arange(len(ids)), ids] > 0.93).all(), corr[np.arange(len(ids)), ids]
    np.testing.assert_array_equal(corr.argmax(axis=1), ids)


@pytest.mark.parametrize("oblique", [False, True])
def test_crosspoint_crop_coordinates_of_a_flat_marker_are_the_canonical_ones(house, close_up, oblique):
    tables, surface, camera, gt, image = close_up
    if oblique:  # any view of a flat marker is a homography: the crop coordinates stay exact
        # (128 px: trimesh casts oblique rays at a plane slowly)
        camera = Camera.look_at((0.25, -0.3, 0.4), (0.1, 0.0, 0.22), focal_mm=35.0, width=128, height=128)
        positions = placed(house[0])
        gt = image_ground_truth(surface, positions, camera, depth_map(camera, positions, surface.sewn_faces))
        image = np.zeros((128, 128, 3), np.uint8)
    crops, ids, xy, visible = crosspoint_crops(image, gt, surface.spec)
    rc = localization_rc(SPEC)
    # the markers whose five points lie on the fabric, and the cut ones whose missing points are
    # completed from their crosspoints on it (`completed_points`)
    on_fabric = surface.xp_face >= 0
    expect = (gt.status > 0) & ((on_fabric[:, rc[:, 0], rc[:, 1]]).all(axis=1)
                                | (on_fabric.sum(axis=(1, 2)) >= MIN_COMPLETION_CROSSPOINTS))
    assert (expect & ~(on_fabric[:, rc[:, 0], rc[:, 1]]).all(axis=1)).any() or oblique  # cut markers among them
    np.testing.assert_array_equal(ids, np.flatnonzero(expect))
    assert crops.shape == (len(ids), 112, 112, 3) and xy.shape == (len(ids), 25, 25, 2) and len(ids) >= 4
    np.testing.assert_array_equal(visible, gt.crosspoint_visible[ids])
    canonical = np.broadcast_to(crop_crosspoints_px(SPEC, CROSSPOINT_CROP), xy.shape)
    on = surface.xp_face[ids] >= 0
    np.testing.assert_allclose(xy[on], canonical[on], atol=0.05)
    assert np.isnan(xy[~on]).all()
    if not oblique:
        whole = gt.status[ids] == 2
        assert whole.sum() == 4  # four whole markers and the cut ones around them
        references = reference_textures(SPEC, tables[0].codes[ids[whole]], CROSSPOINT_CROP).mean(axis=-1)
        inner = (slice(8, 104), slice(8, 104))  # the marker itself (the margin shows neighbours' codes)
        for crop, reference in zip(crops[whole].mean(axis=-1), references):
            assert np.corrcoef(crop[inner].ravel(), reference[inner].ravel())[0, 1] > 0.93


def test_localizer_targets_mark_each_present_centre_in_its_cell(close_up, house):
    _, _, _, gt, _ = close_up
    targets = localizer_targets(gt)
    assert targets.shape == (SIZE // 8, SIZE // 8, 11) and targets.dtype == np.float32
    present = np.flatnonzero((gt.status > 0) & gt.point_visible[:, 0])
    assert len(present) == 4 and targets[..., 0].sum() == len(present)
    centre = gt.points_px[present, 0]
    cell = np.floor(centre / 8).astype(int)
    cells = targets[cell[:, 1], cell[:, 0]]
    assert (cells[:, 0] == 1).all()
    offsets = cells[:, 1:].reshape(-1, 5, 2)
    assert ((offsets[:, 0] >= 0) & (offsets[:, 0] < 8)).all()
    np.testing.assert_allclose(offsets + cell[:, None, :] * 8, gt.points_px[present], atol=1e-4)
    assert (targets[targets[..., 0] == 0] == 0).all()

    # two centres in one cell: the nearer marker wins
    a, b = present[:2]
    points, depth = gt.points_px.copy(), gt.points_depth.copy()
    points[b] = points[a] + 0.25
    depth[b] = depth[a] - 0.1
    crowded = dataclasses.replace(gt, points_px=points, points_depth=depth)
    cell = np.floor(points[a, 0] / 8).astype(int)
    np.testing.assert_allclose(localizer_targets(crowded)[cell[1], cell[0], 1:3], points[b, 0] - cell * 8, atol=1e-6)
    assert localizer_targets(crowded)[..., 0].sum() == len(present) - 1
    with pytest.raises(ValueError, match="not a multiple of the cell size 8"):
        localizer_targets(dataclasses.replace(gt, width=SIZE - 4))


def test_ground_truth_files_keep_the_seen_markers_and_name_what_is_wrong(close_up, tmp_path):
    _, surface, camera, gt, _ = close_up
    path = tmp_path / "gt.npz"
    gt.save(path)
    loaded = ImageGroundTruth.load(path)
    kept = gt.status > 0
    assert (loaded.width, loaded.height) == (SIZE, SIZE) and loaded.num_markers == kept.sum() < gt.num_markers
    for field in dataclasses.fields(ImageGroundTruth):
        if field.name not in ("width", "height"):
            np.testing.assert_array_equal(getattr(loaded, field.name), getattr(gt, field.name)[kept])
    np.testing.assert_array_equal(localizer_targets(loaded), localizer_targets(gt))

    arrays = dict(np.load(path))
    arrays["status"] = arrays["status"][:-1]
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ValueError, match=r"bad\.npz: ImageGroundTruth\.status: expected shape"):
        ImageGroundTruth.load(tmp_path / "bad.npz")
    del arrays["crosspoint_visible"]
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ValueError, match=r"bad\.npz: missing array\(s\) crosspoint_visible"):
        ImageGroundTruth.load(tmp_path / "bad.npz")
    with pytest.raises(ValueError, match=r"depth has shape \(10, 10\), expected \(H, W\) = \(256, 256\) of camera 'close'"):
        image_ground_truth(surface, np.zeros((surface.num_vertices, 3)), camera, np.zeros((10, 10)))
    with pytest.raises(ValueError, match=r"positions must have shape"):
        image_ground_truth(surface, np.zeros((5, 3)), camera, np.zeros((SIZE, SIZE)))
    with pytest.raises(ValueError, match=r"image has shape \(10, 10, 3\)"):
        recognizer_crops(np.zeros((10, 10, 3), np.uint8), gt, surface.spec)
