"""The marker codebook: one binary module grid per marker ID, far apart under every rotation.

Each marker carries an n x n grid of code modules (12 x 12 by default, 2 x 2 cells each).  The fixed
modules (`spec.fixed_modules`: orientation finder, clear corners, centre checker) are the same in
every marker; the free modules are seeded random bits.  IDs are accepted greedily in generation order
when their full module grid is at least `min_code_distance` modules away (Hamming) from every earlier
ID under each of the four 90-degree rotations, and from its own rotations; so ID k's code does not
depend on how many IDs are asked for, and a fabric of any size uses a prefix of the same codebook.

Distances are computed as inner products of +-1 vectors, ``hamming = (L - a.b) / 2``, so the check
of a batch against all accepted codes is one matrix product.
"""

from __future__ import annotations

import functools
import logging

import numpy as np

from assets.fileio import check_limit
from assets.pattern.spec import PatternSpec, fixed_modules

log = logging.getLogger(__name__)

_BATCH = 2048
#: codebook size generated unless told otherwise: the search compares each candidate batch with every
#: accepted code, so its time grows with num_ids^2 (4,096 IDs take about 1.4 s)
MAX_NUM_IDS = 16_384
#: free-module fill fraction allowed, so no marker is nearly blank or nearly solid
_BALANCE = (0.3, 0.7)


def rotations(grids: np.ndarray) -> np.ndarray:
    """(N, n, n) module grids -> (N, 4, n, n): rotated by 0, 90, 180, 270 degrees counter-clockwise."""
    return np.stack([np.rot90(grids, k, axes=(-2, -1)) for k in range(4)], axis=1)


def _signed(grids: np.ndarray) -> np.ndarray:
    """Binary grids (..., n, n) -> flattened float32 +-1 vectors (..., n*n)."""
    flat = grids.reshape(*grids.shape[:-2], -1)
    return flat.astype(np.float32) * 2.0 - 1.0


def hamming_to_rotations(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Minimum Hamming distance (Na, Nb) int32 from each grid of `a` (Na, n, n) to each grid of `b`
    (Nb, n, n) under all four rotations of `b`."""
    n_modules = a.shape[-1] * a.shape[-2]
    sa = _signed(a)
    sb = _signed(rotations(b))  # (Nb, 4, L)
    dots = sa @ sb.reshape(-1, n_modules).T  # (Na, Nb * 4)
    dist = (n_modules - dots.reshape(len(a), len(b), 4)) / 2
    return np.rint(dist.min(axis=2)).astype(np.int32)


def self_rotation_distance(grids: np.ndarray) -> np.ndarray:
    """(N,) smallest Hamming distance from each grid to its own 90, 180 and 270 degree rotations."""
    rot = rotations(grids)
    return (rot[:, 1:] != grids[:, None]).sum(axis=(2, 3)).min(axis=1).astype(np.int32)


def generate_codebook(spec: PatternSpec, max_ids: int = MAX_NUM_IDS) -> np.ndarray:
    """(spec.num_ids, n, n) uint8 module grids; row k is marker ID k.  Deterministic in `spec.seed`.

    Generated once per spec in a process (about 1.4 s for 4,096 IDs) and cached; each call returns
    its own copy.  A spec of more than `max_ids` IDs is refused before the search starts."""
    check_limit(spec.num_ids, max_ids, "num_ids (codebook size; its search costs num_ids squared)", "PatternSpec",
                "max_ids= (--max-ids of python -m assets.pattern)")
    return _cached_codebook(spec).copy()


@functools.lru_cache(maxsize=8)
def _cached_codebook(spec: PatternSpec) -> np.ndarray:
    n = spec.modules_per_side
    mask, value = fixed_modules(spec)
    free = ~mask
    n_free = int(free.sum())
    dmin = spec.min_code_distance
    rng = np.random.default_rng([spec.seed, 0xC0DE])
    accepted = np.zeros((0, n, n), dtype=np.uint8)
    batches = 0
    while len(accepted) < spec.num_ids:
        batches += 1
        bits = (rng.random((_BATCH, n_free)) < 0.5).astype(np.uint8)
        grids = np.broadcast_to(value, (_BATCH, n, n)).copy()
        grids[:, free] = bits
        fill = bits.mean(axis=1)
        ok = (fill >= _BALANCE[0]) & (fill <= _BALANCE[1]) & (self_rotation_distance(grids) >= dmin)
        if len(accepted):
            ok &= hamming_to_rotations(grids, accepted).min(axis=1) >= dmin
        conflicts = hamming_to_rotations(grids, grids) < dmin
        np.fill_diagonal(conflicts, False)
        # Greedy in generation order: a candidate loses only to an earlier accepted candidate.
        for i in np.flatnonzero(ok & conflicts.any(axis=1)):
            if (conflicts[i, :i] & ok[:i]).any():
                ok[i] = False
        if not ok.any():
            raise ValueError(
                f"cannot find {spec.num_ids} codes at min_code_distance={dmin} with {n_free} free "
                f"modules (a batch of {_BATCH} candidates gave none after {len(accepted)}); lower "
                "min_code_distance or num_ids"
            )
        accepted = np.concatenate([accepted, grids[ok]])
    log.debug("codebook: %d IDs from %d candidate batches", spec.num_ids, batches)
    return accepted[: spec.num_ids]


def codebook_min_distance(codes: np.ndarray) -> int:
    """The smallest Hamming distance between any two codes under any rotation, or between a code
    and its own non-trivial rotations."""
    d = hamming_to_rotations(codes, codes)
    np.fill_diagonal(d, np.iinfo(np.int32).max)
    return int(min(d.min(), self_rotation_distance(codes).min()))
