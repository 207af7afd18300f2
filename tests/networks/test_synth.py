"""The pattern synthesizer: exact ground truth, determinism, partial and occluded markers."""

import cv2
import numpy as np
import pytest

from assets.pattern import (CROSSPOINT_CROP, PatternSpec, crop_crosspoints_px, generate_codebook,
                            reference_textures, unwarp)
from assets.geometry import apply_homography
from assets.pattern.observation import crosspoint_crops, crosspoint_markers, localizer_targets, recognizer_crops
from networks.data import synth_crops
from networks.synth import PatternSynthesizer, SynthConfig

#: plain appearance: the pattern's own colours on a plain background, nothing in front, no blur, seen square
PLAIN = SynthConfig(image_size=(384, 384), marker_px=(80, 140), shading=False, occluders=(0, 0),
                    boundary_probability=0.0, background_clutter=0, blur_px=(0.0, 0.0), foreshortening=1.0)


@pytest.fixture(scope="module")
def spec():
    return PatternSpec(rows=1, cols=1, num_ids=512)


@pytest.fixture(scope="module")
def codebook(spec):
    return generate_codebook(spec)


def _modules(crops: np.ndarray) -> np.ndarray:
    """The marker part of 112 px crops averaged per 8 x 8 px code module: (N, 12, 12, 3) float."""
    inner = crops[:, 8:104, 8:104].astype(np.float64)
    return inner.reshape(len(crops), 12, 8, 12, 8, 3).mean(axis=(2, 4))


def _pixel_difference(crops: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(N,) mean absolute difference over the marker part of 112 px crops."""
    return np.abs(crops[:, 8:104, 8:104].astype(np.float64) - reference[:, 8:104, 8:104]).mean(axis=(1, 2, 3))


def _gray_at(image: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Bilinear gray values at continuous pixel coordinates (N, 2) (centres at +0.5)."""
    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
    p = points.reshape(-1, 1, 2).astype(np.float32) - 0.5
    return cv2.remap(gray, p[..., 0], p[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).ravel()


def test_a_homography_sample_unwarps_to_the_reference_texture_of_its_id(spec, codebook):
    synth = PatternSynthesizer(spec, PLAIN.replace(deformation=0.0), codebook)
    checked = 0
    for index in range(3):
        image, gt = synth.sample(index)
        full = np.flatnonzero(gt.status == 2)
        if len(full) == 0:
            continue
        crops = unwarp(image, spec, CROSSPOINT_CROP, gt.points_px[full].astype(np.float64))
        reference = reference_textures(spec, codebook[gt.marker_id[full]], CROSSPOINT_CROP)
        right = _modules(reference)
        # pixel-exact: the points moved by 0.3 px in any direction unwarp to a worse match
        exact = _pixel_difference(crops, reference)
        for offset in ((0.3, 0), (-0.3, 0), (0, 0.3), (0, -0.3)):
            moved = unwarp(image, spec, CROSSPOINT_CROP, gt.points_px[full].astype(np.float64) + offset)
            assert np.all(exact < _pixel_difference(moved, reference) - 2), offset
        wrong = _modules(reference_textures(spec, codebook[(gt.marker_id[full] + 1) % len(codebook)], CROSSPOINT_CROP))
        seen = _modules(crops)
        assert np.abs(seen - right).mean(axis=(1, 2, 3)).max() < 6
        assert np.abs(seen - wrong).mean(axis=(1, 2, 3)).min() > 20
        # a pure homography: the crop's crosspoints sit exactly on the crop grid
        _, ids, xy, _ = crosspoint_crops(image, gt, spec)
        grid = crop_crosspoints_px(spec, CROSSPOINT_CROP)
        assert np.abs(xy[np.isin(ids, gt.marker_id[full])] - grid).max() < 1e-3
        checked += len(full)
    assert checked >= 3


def test_deformed_crosspoints_land_on_the_line_intersections(spec, codebook):
    synth = PatternSynthesizer(spec, PLAIN.replace(deformation=0.6, max_tilt=0.3, marker_px=(100, 160)), codebook)
    for index in range(3):
        s = synth.render(index)
        assert np.abs(s.warp.amplitude).sum() > 0
        points = s.gt.crosspoints_px[s.gt.crosspoint_visible]
        assert len(points) > 500
        exact = _gray_at(s.image, points).mean()
        # half a pixel off in any direction is brighter on average; a cell's inside far brighter
        for offset in ((0.5, 0), (-0.5, 0), (0, 0.5), (0, -0.5)):
            assert exact < _gray_at(s.image, points + np.array(offset)).mean() - 5, offset
        k = spec.crosspoints_per_side
        patch_uv = np.stack(np.meshgrid(np.arange(k - 1) + 0.5, np.arange(k - 1) + 0.5), axis=-1)
        inside, _ = s.warp.forward(patch_uv)
        assert exact < _gray_at(s.image, inside[np.isfinite(inside).all(axis=-1)]).mean() - 40


def test_samples_are_deterministic_per_seed_and_index(spec, codebook):
    config = SynthConfig(image_size=(128, 128), marker_px=(60, 100))
    a, b = PatternSynthesizer(spec, config, codebook), PatternSynthesizer(spec, config, codebook)
    image, gt = a.sample(5)
    again, gt_again = b.sample(5)
    assert np.array_equal(image, again)
    assert np.array_equal(gt.crosspoints_px, gt_again.crosspoints_px, equal_nan=True)
    assert np.array_equal(gt.marker_id, gt_again.marker_id)
    assert not np.array_equal(image, a.sample(6)[0])
    assert not np.array_equal(image, PatternSynthesizer(spec, config.replace(seed=1), codebook).sample(5)[0])


def test_ground_truth_is_consistent_and_makes_the_factory_targets(spec, codebook):
    config = SynthConfig(image_size=(256, 192), marker_px=(50, 90), boundary_probability=0.5)
    synth = PatternSynthesizer(spec, config, codebook)
    for index in range(3):
        image, gt = synth.sample(index)
        assert image.shape == (192, 256, 3) and image.dtype == np.uint8
        assert (gt.width, gt.height) == (256, 192) and np.all(gt.status > 0)
        assert len(np.unique(gt.marker_id)) == gt.num_markers
        xy = gt.crosspoints_px[gt.crosspoint_visible]
        assert np.all((xy >= 0) & (xy < [256, 192]))
        corners = gt.crosspoints_px[:, [12, 0, 0, 24, 24], [12, 0, 24, 0, 24]]  # centre, TL, TR, BL, BR
        assert np.array_equal(gt.points_px, corners, equal_nan=True)
        finite = np.isfinite(gt.points_px).all(axis=-1)
        assert np.all(gt.points_depth[finite] > 0) and np.all(np.isnan(gt.points_depth[~finite]))
        on = np.isfinite(gt.crosspoints_px).all(axis=-1)
        full = (gt.crosspoint_visible == on).all(axis=(1, 2)) & gt.point_visible.all(axis=1)
        assert np.array_equal(gt.status == 2, full)
        cells = localizer_targets(gt)
        assert cells.shape == (24, 32, 11)
        assert cells[..., 0].sum() == len(np.unique(np.floor(gt.points_px[gt.point_visible[:, 0], 0] / 8), axis=0))
        crops, ids = recognizer_crops(image, gt, spec)
        assert crops.shape[1:] == (96, 96, 3) and len(ids) == gt.point_visible.all(axis=1).sum()


def test_markers_cut_by_the_fabric_boundary_are_partial_with_nan_off_the_fabric(spec, codebook):
    config = PLAIN.replace(image_size=(256, 256), marker_px=(60, 100))
    whole = PatternSynthesizer(spec, config, codebook)
    cut = PatternSynthesizer(spec, config.replace(boundary_probability=1.0), codebook)
    partial_seen = 0
    for index in range(3):
        ref, s = whole.render(index), cut.render(index)
        gt_ref = ref.gt
        off = np.isnan(s.gt.crosspoints_px).any(axis=-1)
        assert not np.any(s.gt.crosspoint_visible & off)
        partial = np.flatnonzero(off.any(axis=(1, 2)) & ~off.all(axis=(1, 2)))
        partial_seen += len(partial)
        # where the cut fabric has no crosspoint, the uncut rendering's position shows something else
        by_id = {int(m): i for i, m in enumerate(gt_ref.marker_id)}
        moved = []
        for m in partial:
            if int(s.gt.marker_id[m]) in by_id:
                r = by_id[int(s.gt.marker_id[m])]
                hidden = off[m] & gt_ref.crosspoint_visible[r]
                moved.append(gt_ref.crosspoints_px[r][hidden])
                assert np.array_equal(s.gt.crosspoints_px[m][~off[m]], gt_ref.crosspoints_px[r][~off[m]])
        if moved:
            points = np.concatenate(moved)
            assert np.abs(_gray_at(s.image, points) - _gray_at(ref.image, points)).mean() > 10
        cells = localizer_targets(s.gt)
        present = cells[..., 0] > 0
        assert np.isfinite(cells[present][:, 1:3]).all()  # the centre is always on the fabric
    assert partial_seen > 0


def test_occluded_points_are_not_visible(spec, codebook):
    config = PLAIN.replace(image_size=(256, 256), marker_px=(60, 100))
    clear = PatternSynthesizer(spec, config, codebook)
    blocked = PatternSynthesizer(spec, config.replace(occluders=(4, 6), occluder_px=(60, 120)), codebook)
    hidden_total = 0
    for index in range(2):
        a, b = clear.render(index), blocked.render(index)
        _, ia, ib = np.intersect1d(a.gt.marker_id, b.gt.marker_id, return_indices=True)
        assert set(b.gt.marker_id) <= set(a.gt.marker_id)
        va, vb = a.gt.crosspoint_visible[ia], b.gt.crosspoint_visible[ib]
        assert not np.any(vb & ~va)
        hidden = va & ~vb
        hidden_total += hidden.sum()
        points = a.gt.crosspoints_px[ia][hidden]
        if len(points):
            assert np.abs(_gray_at(b.image, points) - _gray_at(a.image, points)).mean() > 10
            assert np.all(b.occluder[np.floor(points[:, 1]).astype(int), np.floor(points[:, 0]).astype(int)] >= 0.5)
        kept = a.gt.crosspoints_px[ia][vb]
        assert np.median(np.abs(_gray_at(b.image, kept) - _gray_at(a.image, kept))) == 0
        assert np.all(b.gt.status[ib][hidden.any(axis=(1, 2))] < 2)
    assert hidden_total > 0


def test_visible_crosspoint_targets_of_deformed_markers_lie_in_their_crops(spec, codebook):
    # samples whose strongly deformed markers bend visible crosspoints out of the crop (before, they
    # stayed visible there, up to 16 px outside)
    synth = PatternSynthesizer(spec, SynthConfig(image_size=(128, 128), centred=True, deformation=0.8), codebook)
    for index in (7, 10, 29):
        image, gt = synth.sample(index)
        _, ids, xy, visible = synth_crops("crosspoints", image, gt, spec)
        assert len(ids) > 0 and visible.mean() > 0.5
        assert np.isfinite(xy[visible]).all()
        assert ((xy[visible] >= 0) & (xy[visible] <= CROSSPOINT_CROP.size_px)).all(), index


def test_invalid_configs_are_refused(spec):
    with pytest.raises(ValueError, match="image_size"):
        SynthConfig(image_size=(100, 128))
    with pytest.raises(ValueError, match="deformation"):
        SynthConfig(deformation=0.95)
    with pytest.raises(ValueError, match="codebook"):
        PatternSynthesizer(spec, SynthConfig(), np.zeros((4, 3, 3), np.uint8))


def _longer_edge_px(gt) -> np.ndarray:
    """(M,) the longer side of each marker's parallelogram fitted to its four corners, pixels."""
    p = gt.points_px.astype(np.float64)
    p = p[np.isfinite(p).all(axis=(1, 2))]
    across = ((p[:, 2] - p[:, 1]) + (p[:, 4] - p[:, 3])) / 2
    down = ((p[:, 3] - p[:, 1]) + (p[:, 4] - p[:, 2])) / 2
    return np.linalg.svd(np.stack([across, down], axis=-1), compute_uv=False)[:, 0]


def test_default_markers_have_the_size_of_the_factory_renders():
    # the domain-gap bug of the first GPU run: markers were synthesized 40-160 px across while the
    # factory's 512 px renders show them 19-24 px across (5th-95th percentile), so a localizer
    # trained on the synthesizer found nothing in the renders
    spec = PatternSpec()
    synth = PatternSynthesizer(spec, SynthConfig(image_size=(128, 128)))
    edges = np.concatenate([_longer_edge_px(synth.sample(i)[1]) for i in range(4)])
    assert len(edges) > 100
    assert 18 < np.median(edges) < 26
    assert np.percentile(edges, 95) < 40


def test_marker_ids_are_drawn_from_the_given_set_and_repeat_when_the_view_needs_more(spec, codebook):
    ids = np.array([3, 7, 11, 20, 21, 40, 41, 42])
    config = SynthConfig(image_size=(128, 128), marker_px=(24, 32), foreshortening=1.0)
    synth = PatternSynthesizer(spec, config, codebook, marker_ids=ids)
    for index in range(2):
        s = synth.render(index)
        assert np.isin(s.patch_ids, ids).all() and s.patch_ids.size > len(ids)
        assert np.isin(s.gt.marker_id, ids).all()
        # row-major through the set from a random start, wrapping around
        flat = s.patch_ids.reshape(-1)
        position = np.searchsorted(ids, flat)
        assert np.all(np.diff(position) % len(ids) == 1)
    with pytest.raises(ValueError, match="marker_ids"):
        PatternSynthesizer(spec, config, codebook, marker_ids=np.array([0, len(codebook)]))


def test_jittered_crops_are_cut_where_the_points_moved_and_their_targets_follow(spec, codebook):
    """crop_jitter_px: crops come from moved five points (as the Detector's are), and the crosspoint
    targets are the true crosspoints seen through the moved crop; the same sample jitters the same way."""
    config = SynthConfig(image_size=(128, 128), centred=True, crop_jitter_px=1.5)
    synth = PatternSynthesizer(spec, config, codebook)
    image, gt = synth.sample(3)
    exact = synth_crops("crosspoints", image, gt, spec)
    moved = synth_crops("crosspoints", image, gt, spec, config, 3)
    assert np.array_equal(moved[0], synth_crops("crosspoints", image, gt, spec, config, 3)[0])
    assert len(moved[1]) > 0 and not np.array_equal(moved[0], exact[0])
    jittered = gt.jittered(1.5, np.random.default_rng([config.seed, 3, 7]))
    step = np.linalg.norm(jittered.points_px - gt.points_px, axis=-1)
    assert 0.5 < np.nanmedian(step) < 3.0 and np.array_equal(jittered.crosspoints_px, gt.crosspoints_px, equal_nan=True)
    pick, homography = crosspoint_markers(jittered, spec)
    centre = spec.crosspoints_per_side // 2
    pick = pick[gt.crosspoint_visible[pick, centre, centre]]  # synth_crops keeps the markers whose centre is seen
    homography = homography[np.isin(crosspoint_markers(jittered, spec)[0], pick)]
    back = apply_homography(np.linalg.inv(homography), moved[2].reshape(len(pick), -1, 2).astype(np.float64))
    truth = gt.crosspoints_px[pick].reshape(len(pick), -1, 2)
    seen = moved[3].reshape(len(pick), -1)
    assert np.abs(back - truth)[seen].max() < 1e-2
    assert gt.jittered(0.0, np.random.default_rng(0)) is gt
    with pytest.raises(ValueError, match="crop_jitter_px"):
        SynthConfig(crop_jitter_px=-1.0)
