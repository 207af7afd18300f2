"""Checks of the plain-array records every stage passes on (ground truth, detections, captured points)."""

from __future__ import annotations

from typing import Mapping

import numpy as np


def check_fields(record: object, expected: Mapping[str, tuple[tuple[int, ...], type]], valid: bool = True) -> None:
    """Raise ValueError naming ``Type.field`` unless every field of `record` named in `expected` is an
    ndarray of exactly that (shape, dtype); `valid` False (a size that could not be read) fails all."""
    owner = type(record).__name__
    for name, (shape, dtype) in expected.items():
        array = getattr(record, name)
        if not isinstance(array, np.ndarray) or array.shape != shape or array.dtype != dtype or not valid:
            got = f"{array.shape} {array.dtype}" if isinstance(array, np.ndarray) else type(array).__name__
            raise ValueError(f"{owner}.{name}: expected shape {shape} {np.dtype(dtype).name}, got {got}")
