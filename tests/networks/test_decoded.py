"""Arrays decoded ahead into one memory-mapped file (`networks.decoded`)."""

import gc
import pickle
import tempfile

import numpy as np
import pytest

from networks.decoded import DecodedArrays


@pytest.fixture
def temp(tmp_path, monkeypatch):
    """The temporary folder the files are written to, empty at the start."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    return tmp_path


def _items(count: int, side: int = 24) -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(4)
    return [{"image": rng.integers(0, 256, (side + i, side + 2 * i, 3), dtype=np.uint8),
             "cells": rng.standard_normal(((side + i) // 8, (side + 2 * i) // 8, 11)).astype(np.float32)}
            for i in range(count)]


def test_items_come_back_exactly_as_read_only_aligned_views(temp):
    items = _items(5)
    items[2]["cells"][0, 0] = np.nan
    for i, item in enumerate(items):  # a scalar, an empty array and a transposed (not contiguous) one too
        item.update(width=np.asarray(100 + i), none=np.zeros((0, 5, 2), np.float32), turned=item["cells"][..., 0].T)
    decoded = DecodedArrays.write(iter(items), len(items))
    assert decoded is not None and list(temp.iterdir()) == [decoded.path] and len(decoded) == 5
    for item, back in zip(items, (decoded[i] for i in range(5))):
        assert back.keys() == item.keys()
        for key in item:
            assert back[key].dtype == item[key].dtype and back[key].shape == item[key].shape
            assert np.array_equal(back[key], item[key], equal_nan=True)
            assert not back[key].flags.writeable  # a worker cannot change what the others read
    assert all(offset % 64 == 0 for entry in decoded.layout for offset, _, _ in entry.values())


def test_a_pickled_copy_maps_the_file_anew_and_only_the_writer_deletes_it(temp):
    items = _items(3)
    decoded = DecodedArrays.write(items, len(items))
    decoded[0]  # the writer's map is open
    state = pickle.dumps(decoded)
    assert len(state) < 2000  # the layout travels, not the arrays
    copy = pickle.loads(state)
    assert copy._buffer is None and np.array_equal(copy[2]["image"], items[2]["image"])
    path = decoded.path
    del copy
    gc.collect()
    assert path.is_file()
    del decoded
    gc.collect()
    assert not path.exists()


def test_more_than_allowed_gives_none_and_leaves_no_file(temp):
    items = _items(4)
    size = sum(a.nbytes for a in items[0].values())
    assert DecodedArrays.write(items, 4, max_bytes=3 * size) is None  # the estimate is over
    grown = _items(1) + _items(3, side=200)  # the estimate passes; the larger later items do not
    assert DecodedArrays.write(grown, 4, max_bytes=8 * size) is None
    assert list(temp.iterdir()) == []


def test_a_failing_read_or_a_wrong_count_leaves_no_file(temp):
    def failing():
        yield _items(1)[0]
        raise ValueError("images/x.png: not a readable image")

    with pytest.raises(ValueError, match="not a readable image"):
        DecodedArrays.write(failing(), 3)
    with pytest.raises(ValueError, match="2 items given, 3 expected"):
        DecodedArrays.write(_items(2), 3)
    with pytest.raises(ValueError, match="no items"):
        DecodedArrays.write([], 0)
    assert list(temp.iterdir()) == []
