"""Counting intersecting triangle pairs, and refilling the regions around them."""

import numpy as np
import pytest

from reconstruction.intersections import count_intersections, intersecting_pairs, triangles_intersect, untangle


def grid(n: int, spacing: float, z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """An n x n vertex grid in the plane z (positions (n^2, 3), faces (2 (n-1)^2, 3))."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    positions = np.stack([i.ravel() * spacing, j.ravel() * spacing, np.full(n * n, z)], axis=1)
    index = np.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return positions, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def test_two_crossing_triangles_are_one_pair():
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],  # in z = 0
                          [0.2, 0.2, -0.5], [0.3, 0.25, 0.5], [0.9, 0.9, 0.4]], dtype=float)  # through it
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    assert intersecting_pairs(positions, faces).tolist() == [[0, 1]]
    # lifted clear of the first triangle: none
    assert count_intersections(positions + np.array([0, 0, 1.0]) * (np.arange(6) >= 3)[:, None], faces) == 0
    # beside it (the line through its edge misses the triangle): none
    assert count_intersections(positions + np.array([2.0, 0, 0]) * (np.arange(6) >= 3)[:, None], faces) == 0


def test_adjacent_triangles_never_count_even_folded_through_each_other():
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], dtype=float)
    faces = np.array([[0, 1, 2], [1, 3, 2]])  # sharing the edge 1-2
    assert count_intersections(flat, faces) == 0
    folded = flat.copy()
    folded[3] = [-0.2, -0.2, 0.1]  # the second triangle folded back over the first
    assert count_intersections(folded, faces) == 0
    # sharing only a vertex, one edge through the other triangle: they cross, but are not counted
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, -0.5], [0.3, 0.3, 0.5]], dtype=float)
    faces = np.array([[0, 1, 2], [0, 3, 4]])
    assert triangles_intersect(positions[faces[:1]], positions[faces[1:]]).all()
    assert count_intersections(positions, faces) == 0


def test_the_broad_phase_finds_exactly_what_testing_every_pair_finds():
    rng = np.random.default_rng(3)
    small = rng.uniform(0, 0.2, (300, 1, 3)) + rng.normal(0, 0.01, (300, 3, 3))  # a soup of small triangles
    slivers = rng.uniform(0, 0.2, (6, 1, 3)) + rng.normal(0, 0.08, (6, 3, 3)) * np.array([1.0, 1.0, 0.02])
    corners = np.concatenate([small, slivers])  # a few large, thin ones: cut into pieces by the broad phase
    positions, faces = corners.reshape(-1, 3), np.arange(len(corners) * 3).reshape(-1, 3)
    i, j = np.triu_indices(len(faces), k=1)
    brute = np.stack([i, j], 1)[triangles_intersect(corners[i], corners[j])]
    found = intersecting_pairs(positions, faces)
    assert len(brute) > 20 and np.isin(np.arange(300, 306), brute).any()  # the slivers take part
    assert found.tolist() == brute.tolist()


def test_a_sheet_pushed_through_another_is_counted_and_untangled():
    lower, faces = grid(12, 0.01, 0.0)
    upper, _ = grid(12, 0.01, 0.02)
    positions = np.concatenate([lower, upper])
    faces = np.concatenate([faces, faces + len(lower)])
    assert count_intersections(positions, faces) == 0
    pushed = positions.copy()
    centre = np.array([0.055, 0.055])
    distance = np.linalg.norm(pushed[:, :2] - centre, axis=1)
    patch = (np.arange(len(pushed)) >= len(lower)) & (distance < 0.03)
    pushed[patch, 2] -= 0.04 * np.cos(np.pi * distance[patch] / 0.06) ** 2  # a bump down through the lower sheet
    assert count_intersections(pushed, faces) > 0
    frozen = np.arange(len(pushed)) < len(lower)  # the lower sheet is captured: it must not move
    repaired, left = untangle(pushed, faces, frozen)
    assert left == 0 and count_intersections(repaired, faces) == 0
    assert np.array_equal(repaired[frozen], pushed[frozen])
    far = ~patch & (distance > 0.05)
    assert np.array_equal(repaired[far], pushed[far])  # only the region around the intersections moved


def test_bad_input_is_named():
    positions, faces = grid(3, 0.01)
    with pytest.raises(ValueError, match="positions"):
        intersecting_pairs(positions[:, :2], faces)
    with pytest.raises(ValueError, match="faces"):
        intersecting_pairs(positions, faces + 100)
    with pytest.raises(ValueError, match="finite"):
        intersecting_pairs(np.full_like(positions, np.nan), faces)
