"""The pattern-neighbour check on the cylinder garment (an exact, strain-free wrap of its pattern): a
wrong marker's points at a wrong depth go, right points stay, also those beside the wrong marker;
right regions that no other marker confirms go too (documented behaviour)."""

import numpy as np
import pytest

from assets.cameras import Camera
from networks.detections import Detections
from reconstruction.consistency import NeighbourConfig, consistent_points
from reconstruction.correspondence import CrosspointMap
from reconstruction.triangulation import TriangulationConfig, triangulate_frame
from tests.reconstruction.cylinder import cylinder_template, wrapped

K = 25


@pytest.fixture(scope="module")
def cylinder():
    """The cylinder's 12 mm crosspoints and every crosspoint on its fabric at its wrapped shape:
    (CrosspointMap, flat (G',), xyz (G', 3), positions of the sewn level (V, 3))."""
    template = cylinder_template()
    crosspoints = CrosspointMap.build(template, 12)
    positions = wrapped(template, 12)
    flat = np.flatnonzero(crosspoints.face >= 0)
    return crosspoints, flat, crosspoints.points(positions, crosspoints.unflat(flat)), positions


def _interior_marker(crosspoints, panel=0):
    """Row of a marker of `panel` whose crosspoints and whose 8 neighbours' are all on the fabric."""
    on = (crosspoints.face[crosspoints.marker_flat] >= 0).all(axis=(1, 2))
    for m in np.flatnonzero(on & (crosspoints.panel == panel)):
        near = [n for n in range(len(on)) if crosspoints.panel[n] == panel
                and np.isin(crosspoints.marker_flat[n], crosspoints.marker_flat[m]).any()]
        if len(near) == 9 and on[near].all():
            return m
    raise AssertionError("the cylinder has no marker with 8 whole neighbours")


def test_a_wrong_marker_at_a_wrong_depth_goes_and_its_neighbours_stay(cylinder):
    crosspoints, flat, xyz, _ = cylinder
    assert consistent_points(crosspoints, flat, xyz).kept.all()  # the right garment confirms itself
    wrong = np.isin(flat, crosspoints.marker_flat[_interior_marker(crosspoints)])
    moved = xyz.copy()
    # 4 cm outwards along the marker's normal (radial on the cylinder), all 625 points together:
    # consistent with each other, far from their neighbours' points
    normal = np.r_[xyz[wrong, :2].mean(axis=0), 0.0]
    moved[wrong] += 0.04 * normal / np.linalg.norm(normal)
    check = consistent_points(crosspoints, flat, moved)
    np.testing.assert_array_equal(check.kept, ~wrong)
    assert len(np.unique(check.component[wrong])) == 1  # one self-consistent component, not vouched for


def test_right_regions_that_no_other_marker_confirms_go(cylinder):
    crosspoints, flat, xyz, _ = cylinder
    row = np.full(crosspoints.num_crosspoints, -1)
    row[flat] = np.arange(len(flat))
    # one whole marker alone (625 points, exact): what a wrong marker looks like, so it is dropped
    alone = row[crosspoints.marker_flat[_interior_marker(crosspoints)].ravel()]
    assert not consistent_points(crosspoints, flat[alone], xyz[alone]).kept.any()
    # a patch across the border of two markers: kept with at least min_points points
    m = _interior_marker(crosspoints)
    grid = crosspoints.marker_flat[m]
    right = crosspoints.marker_flat[[n for n in range(len(crosspoints.marker_id))
                                     if crosspoints.panel[n] == crosspoints.panel[m]
                                     and (crosspoints.marker_flat[n][:, 0] == grid[:, K - 1]).all()][0]]
    both = np.concatenate([grid, right[:, 1:]], axis=1)  # (K, 2K - 1) crosspoints side by side
    patch = row[both[:12, K - 6:K + 6].ravel()]  # 12 x 12 = 144 points, half in each marker
    assert consistent_points(crosspoints, flat[patch], xyz[patch]).kept.all()
    small = row[both[:8, K - 4:K + 4].ravel()]  # 64 points
    assert not consistent_points(crosspoints, flat[small], xyz[small]).kept.any()
    assert consistent_points(crosspoints, flat[small], xyz[small], NeighbourConfig(min_points=50)).kept.all()


def test_points_apart_by_more_than_the_stretch_are_not_neighbours(cylinder):
    crosspoints, flat, xyz, _ = cylinder
    centre = xyz.mean(axis=0)
    assert consistent_points(crosspoints, flat, centre + 1.4 * (xyz - centre)).kept.all()
    assert not consistent_points(crosspoints, flat, centre + 1.6 * (xyz - centre)).kept.any()
    wider = NeighbourConfig(max_stretch=1.7)
    assert consistent_points(crosspoints, flat, centre + 1.6 * (xyz - centre), wider).kept.all()


def test_bad_input_is_refused(cylinder):
    crosspoints, flat, xyz, _ = cylinder
    with pytest.raises(ValueError, match="twice"):
        consistent_points(crosspoints, flat[[0, 0]], xyz[:2])
    with pytest.raises(ValueError, match=r"xyz \(P, 3\)"):
        consistent_points(crosspoints, flat, xyz[:-1])
    for bad, match in (({"max_stretch": 0.9}, "max_stretch"), ({"strides": ()}, "strides"),
                       ({"strides": (0, 1)}, "strides"), ({"min_points": 0}, "min_points")):
        with pytest.raises(ValueError, match=match):
            NeighbourConfig(**bad)


def _cameras():
    angles = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    return [Camera.look_at((1.5 * np.cos(a), 1.5 * np.sin(a), 1.15), (0.0, 0.0, 1.15), focal_mm=30.0, width=640,
                           height=480, name=f"cam{i}") for i, a in enumerate(angles)]


def _detections(crosspoints, marker_xyz, cameras):
    """Every camera's exact detections of the crosspoints facing it; marker_xyz (M, K, K, 3)."""
    out = []
    for camera in cameras:
        pixels = camera.project(marker_xyz.reshape(-1, 3))[0].reshape(marker_xyz.shape[:3] + (2,))
        with np.errstate(invalid="ignore"):
            facing = ((camera.center - marker_xyz)[..., :2] * marker_xyz[..., :2]).sum(axis=-1) > 0
        visible = facing & np.isfinite(pixels).all(axis=-1)
        keep = visible.any(axis=(1, 2))
        m = int(keep.sum())
        out.append(Detections(marker_id=crosspoints.marker_id[keep], confidence=np.ones(m, np.float32),
                              points_px=np.zeros((m, 5, 2), np.float32), crosspoints_px=pixels[keep].astype(np.float32),
                              crosspoint_visible=visible[keep], partial=np.zeros(m, bool)))
    return out


def test_triangulation_drops_a_wrong_id_seen_in_two_views(cylinder):
    """Camera k reads a marker as B where camera j alone sees the real B, at pixels whose rays meet
    camera j's 30% beyond B: both views agree (no RANSAC outlier), the neighbour check drops them."""
    crosspoints, _, _, positions = cylinder
    cameras = _cameras()
    marker_xyz = crosspoints.points(positions, crosspoints.unflat(crosspoints.marker_flat.ravel()))
    marker_xyz = marker_xyz.reshape(crosspoints.marker_flat.shape + (3,))
    detections = _detections(crosspoints, marker_xyz, cameras)
    b = _interior_marker(crosspoints)
    b_id = crosspoints.marker_id[b]
    seen = [d.crosspoint_visible[d.marker_id == b_id].all() if (d.marker_id == b_id).any() else False
            for d in detections]
    j = int(np.flatnonzero(seen)[0])
    k = (j + 1) % len(cameras) if seen[(j + 1) % len(cameras)] else (j - 1) % len(cameras)
    assert seen[k]
    far = cameras[j].center + 1.3 * (marker_xyz[b] - cameras[j].center)  # (K, K, 3) on camera j's rays
    for c, found in enumerate(detections):
        if c == j:
            continue
        others = found.select(found.marker_id != b_id)
        if c == k:  # the impostor: B's interior where the far points project (its border is not read)
            impostor = found.select(found.marker_id == b_id)
            pixels = cameras[k].project(far.reshape(-1, 3))[0].reshape(K, K, 2).astype(np.float32)
            visible = np.zeros((1, K, K), bool)
            visible[0, 1:-1, 1:-1] = True
            impostor = Detections(**{**impostor.to_dict(), "crosspoints_px": pixels[None],
                                     "crosspoint_visible": visible})
            others = Detections(**{name: np.concatenate([getattr(others, name), getattr(impostor, name)])
                                   for name in others.to_dict()})
        detections[c] = others
    interior = crosspoints.marker_flat[b][1:-1, 1:-1].ravel()
    unchecked = triangulate_frame(crosspoints, cameras, detections, TriangulationConfig(neighbours=None))
    flat = crosspoints.flat(unchecked.key)
    error = np.linalg.norm(unchecked.xyz - crosspoints.points(positions, unchecked.key), axis=1)
    wrong = np.isin(flat, interior)
    assert wrong.sum() == len(interior) and (error[wrong] > 0.05).all()  # captured, 30% too deep
    assert error[~wrong].max() < 1e-5
    checked = triangulate_frame(crosspoints, cameras, detections)
    np.testing.assert_array_equal(crosspoints.flat(checked.key), flat[~wrong])  # every right point stays
