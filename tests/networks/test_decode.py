"""Localizer decoding, NMS and border-duplicated targets on hand-made inputs."""

import math

import numpy as np
import pytest
import torch

from networks.decode import decode_localizer, duplicate_border_targets, nms

NAN = float("nan")


def _marker(centre, spread=10.0):
    """Ten offsets: centre (x, y) and TL, TR, BL, BR at +-spread around it."""
    x, y = centre
    return [x, y, x - spread, y - spread, x + spread, y - spread, x - spread, y + spread, x + spread, y + spread]


def _points(cell_rc, offsets, cell=8):
    """Absolute (5, 2) points of offsets read in cell (row, col)."""
    return np.asarray(offsets, dtype=np.float32).reshape(5, 2) + np.array([cell_rc[1], cell_rc[0]]) * cell


def test_decode_localizer_by_hand():
    output = torch.full((2, 11, 3, 4), -10.0)
    # image 0: one marker in cell (1, 2); a cell at probability exactly 0.5 is not a detection
    output[0, 0, 1, 2] = 3.0
    output[0, 1:, 1, 2] = torch.tensor(_marker((2.5, 3.5)))
    output[0, 0, 2, 3] = 0.0
    # image 1: one marker seen from two cells across a border (centres 0.3 px apart) and another one
    output[1, 0, 1, 1] = 1.0
    output[1, 1:, 1, 1] = torch.tensor(_marker((7.6, 4.0)))
    output[1, 0, 1, 2] = 2.0
    output[1, 1:, 1, 2] = torch.tensor(_marker((-0.1, 4.2)))
    output[1, 0, 0, 0] = 0.5
    output[1, 1:, 0, 0] = torch.tensor(_marker((4.0, 4.0)))

    (points0, score0), (points1, score1) = decode_localizer(output)
    assert points0.dtype == np.float32 and score0.dtype == np.float32
    np.testing.assert_allclose(points0, [_points((1, 2), _marker((2.5, 3.5)))])
    np.testing.assert_allclose(points0[0, 0], [18.5, 11.5])
    np.testing.assert_allclose(score0, [1 / (1 + math.exp(-3))], rtol=1e-6)

    np.testing.assert_allclose(points1, [_points((1, 2), _marker((-0.1, 4.2))), _points((0, 0), _marker((4.0, 4.0)))])
    np.testing.assert_allclose(score1, [1 / (1 + math.exp(-2)), 1 / (1 + math.exp(-0.5))], rtol=1e-6)

    # without NMS both cells of the border marker are reported; a higher threshold drops the weak ones
    (_, _), (points, _) = decode_localizer(output, nms_radius_px=0.0)
    assert len(points) == 3
    (points, _), (points1, _) = decode_localizer(output, threshold=0.85)
    assert len(points) == 1 and len(points1) == 1
    # cell size 4: corners move accordingly
    (points, _), _ = decode_localizer(output, cell=4)
    np.testing.assert_allclose(points[0, 0], [8 + 2.5, 4 + 3.5])

    empty = decode_localizer(torch.full((3, 11, 2, 2), -5.0))
    assert len(empty) == 3 and all(p.shape == (0, 5, 2) and s.shape == (0,) for p, s in empty)
    with pytest.raises(ValueError, match="localizer output"):
        decode_localizer(torch.zeros(1, 10, 2, 2))


def _centres(xy):
    points = np.zeros((len(xy), 5, 2))
    points[:, 0] = xy
    return points


def _greedy_nms(points, score, radius):
    """The textbook loop, for comparison."""
    order = sorted(range(len(score)), key=lambda i: (-score[i], i))
    kept = []
    for i in order:
        if all(np.linalg.norm(points[i, 0] - points[j, 0]) > radius for j in kept):
            kept.append(i)
    return kept


def test_nms_by_hand():
    # a chain: A suppresses B, B (suppressed) must not suppress C
    points = _centres([[0.0, 0.0], [3.0, 0.0], [6.0, 0.0], [6.0, 3.9], [50.0, 50.0]])
    score = np.array([0.9, 0.8, 0.7, 0.75, 0.1])
    assert nms(points, score, 4.0).tolist() == [0, 3, 4]  # D (0.75) suppresses C (0.7) at 3.9 px
    assert nms(points, score, 2.0).tolist() == [0, 1, 3, 2, 4]
    # equal scores: the lower index wins; the radius is inclusive
    assert nms(_centres([[0.0, 0.0], [4.0, 0.0]]), np.array([0.5, 0.5]), 4.0).tolist() == [0]
    assert nms(np.zeros((0, 5, 2)), np.zeros(0), 4.0).tolist() == []
    assert nms(_centres([[1.0, 1.0]]), np.array([0.3]), 4.0).tolist() == [0]
    with pytest.raises(ValueError, match="finite"):
        nms(_centres([[NAN, 1.0], [0.0, 0.0]]), np.array([0.3, 0.2]), 4.0)


def test_nms_matches_the_greedy_loop():
    rng = np.random.default_rng(5)
    points = rng.uniform(0, 60, size=(300, 5, 2))
    score = rng.uniform(size=300).round(2)  # ties included
    for radius in (2.0, 4.0, 9.0):
        assert nms(points, score, radius).tolist() == _greedy_nms(points, score, radius)


def _cells(h, w, markers):
    """(h, w, 11) targets with markers {(row, col): ten offsets}."""
    cells = np.zeros((h, w, 11), dtype=np.float32)
    for (r, c), offsets in markers.items():
        cells[r, c] = [1.0, *offsets]
    return cells


def test_duplicate_border_targets_by_hand():
    near_corner = _marker((0.5, 7.5))
    near_corner[4:6] = [NAN, NAN]  # TR off the fabric
    middle = _marker((4.0, 4.0))
    near_right = _marker((7.2, 3.0))
    cells = _cells(3, 4, {(1, 1): near_corner, (0, 2): middle, (0, 3): near_right})
    out = duplicate_border_targets(cells)
    expected = cells.copy()
    left = np.array(near_corner) + np.tile([8.0, 0.0], 5)
    below = np.array(near_corner) + np.tile([0.0, -8.0], 5)
    expected[1, 0] = [1.0, *left]
    expected[2, 1] = [1.0, *below]
    expected[2, 0] = [1.0, *(left + np.tile([0.0, -8.0], 5))]
    # the marker near the right border of the last column has no neighbour there; the middle one moves nowhere
    np.testing.assert_array_equal(out, expected)
    assert out.dtype == np.float32 and np.isnan(out[2, 0, 5:7]).all()

    # the copies address the same pixels as the original
    np.testing.assert_allclose(_points((2, 0), out[2, 0, 1:]), _points((1, 1), cells[1, 1, 1:]))

    # a copy never replaces a cell with its own marker; competing copies: the nearer centre wins
    own = _cells(2, 3, {(0, 0): _marker((7.5, 4.0)), (0, 1): middle})
    np.testing.assert_array_equal(duplicate_border_targets(own), own)
    compete = _cells(1, 3, {(0, 0): _marker((7.8, 4.0)), (0, 2): _marker((0.5, 4.0))})
    out = duplicate_border_targets(compete)
    np.testing.assert_allclose(out[0, 1, 1:3], [-0.2, 4.0], atol=1e-6)
    # margin 0 duplicates only centres exactly on a border
    np.testing.assert_array_equal(duplicate_border_targets(compete, margin_px=0.0), compete)


def test_duplicate_border_targets_batched_and_torch():
    a = _cells(2, 2, {(0, 0): _marker((7.9, 0.2))})
    b = _cells(2, 2, {(1, 1): _marker((0.1, 4.0))})
    batch = np.stack([a, b])
    out = duplicate_border_targets(batch)
    np.testing.assert_array_equal(out[0], duplicate_border_targets(a))
    np.testing.assert_array_equal(out[1], duplicate_border_targets(b))
    assert out[0, :, :, 0].sum() == 2 and out[1, :, :, 0].sum() == 2  # (0, 0) has no row above
    tensor = duplicate_border_targets(torch.from_numpy(batch))
    assert torch.is_tensor(tensor) and tensor.dtype == torch.float32
    np.testing.assert_array_equal(tensor.numpy(), out)
    with pytest.raises(ValueError, match="expected cells"):
        duplicate_border_targets(np.zeros((2, 2, 10), dtype=np.float32))


def test_duplicated_targets_decode_to_each_marker_once():
    """A perfect network trained on duplicated targets fires in both cells; NMS reports each marker once,
    at its own points whichever cell wins."""
    markers = {(1, 1): _marker((0.4, 7.7), spread=12), (1, 3): _marker((7.5, 3.0), spread=12),
               (3, 2): _marker((4.0, 4.0), spread=12)}
    cells = duplicate_border_targets(_cells(5, 5, markers))
    assert cells[..., 0].sum() == 3 + 1 + 1 + 1 + 1  # corner marker: 3 copies, right-border marker: 1
    logits = np.where(cells[..., :1] > 0, 4.0, -4.0)
    offsets = np.where(np.isnan(cells[..., 1:]), 0.0, cells[..., 1:])
    output = torch.from_numpy(np.concatenate([logits, offsets], axis=-1)).permute(2, 0, 1)[None]
    (points, score), = decode_localizer(output)
    expected = np.stack([_points(rc, offsets) for rc, offsets in markers.items()])
    order = np.lexsort((points[:, 0, 1], points[:, 0, 0]))
    np.testing.assert_allclose(points[order], expected[np.lexsort((expected[:, 0, 1], expected[:, 0, 0]))], atol=1e-5)
    assert len(score) == 3
