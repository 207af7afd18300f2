"""Arrays decoded once and kept in one file, memory-mapped: what rendered training items read of their images.

A rendered item reads a random image of the split each time.  For the localizer, decoding its PNG
(8 ms at 512 x 512) and reading its cells from samples/<name>.npz (3 ms) were two thirds of the item's
18 ms on our CPU, and the per-worker cache rarely hits, so the localizer on renders alone trained at
16.5 steps/s against 27.5 with half its items from shards (33.1 with this file).  A jittered crosspoint crop spent 17 of its 21 ms reading the PNG and the
markers' ground truth.  With `RenderedDataset(decode_ahead=True)` the dataset decodes every image
of its split once, in the process that makes it, into one file in the temporary folder
(`DecodedArrays.write`); each DataLoader worker maps that file read-only, and the page cache shares
it between workers.  The file is deleted when the object that wrote it is collected or its process
exits.
"""

from __future__ import annotations

import itertools
import logging
import os
import shutil
import tempfile
import weakref
from pathlib import Path
from typing import Iterable

import numpy as np
from tqdm import tqdm

log = logging.getLogger(__name__)

#: the most a dataset decodes ahead (bytes); a larger split is read item by item as before
MAX_BYTES = 16 << 30
#: each array starts at a multiple of this many bytes in the file
_ALIGN = 64


def _padded(nbytes: int) -> int:
    return -(-nbytes // _ALIGN) * _ALIGN


def _unlink(path: str) -> None:
    Path(path).unlink(missing_ok=True)


class DecodedArrays:
    """Items (dicts of named numpy arrays) in one file, read back as read-only memory-mapped views:
    ``decoded[i]`` is item i's dict.  Pickles without its map, so each worker opens its own."""

    def __init__(self, path: str | Path, layout: list[dict[str, tuple[int, tuple[int, ...], str]]]):
        """`layout`: per item, name -> (byte offset, shape, numpy dtype string) in the file at `path`."""
        self.path = Path(path)
        self.layout = layout
        self._buffer: np.memmap | None = None

    @classmethod
    def write(cls, items: Iterable[dict[str, np.ndarray]], count: int, max_bytes: int = MAX_BYTES,
              desc: str = "decode ahead") -> DecodedArrays | None:
        """The `count` items of `items` written to a new file in the temporary folder; None (and no
        file) when they would take more than `max_bytes` or more than half the free space there (the
        first item times `count` is the estimate, checked again while writing)."""
        items = iter(items)
        first = next(items, None)
        if first is None or count < 1:
            raise ValueError(f"{desc}: no items to decode ahead")
        folder = tempfile.gettempdir()
        limit = min(int(max_bytes), shutil.disk_usage(folder).free // 2)
        estimate = count * sum(_padded(np.asarray(a).nbytes) for a in first.values())
        if estimate > limit:
            log.info("%s: %d items would take %.1f GiB, more than the %.1f GiB allowed in %s; read per item",
                     desc, count, estimate / 2**30, limit / 2**30, folder)
            return None
        fd, name = tempfile.mkstemp(prefix="clothcapture-decoded-", suffix=".bin", dir=folder)
        layout: list[dict[str, tuple[int, tuple[int, ...], str]]] = []
        try:
            with os.fdopen(fd, "wb") as file:
                for item in tqdm(itertools.chain([first], items), total=count, desc=desc, disable=count < 50):
                    entry = {}
                    for key, array in item.items():
                        array = np.asarray(array, order="C")  # ascontiguousarray would make a 0-d array 1-d
                        entry[key] = (file.tell(), tuple(array.shape), array.dtype.str)
                        file.write(array.tobytes())
                        file.write(bytes(_padded(array.nbytes) - array.nbytes))
                    layout.append(entry)
                    if file.tell() > limit:
                        log.info("%s: more than the %.1f GiB allowed after %d of %d items; read per item",
                                 desc, limit / 2**30, len(layout), count)
                        _unlink(name)
                        return None
        except BaseException:
            _unlink(name)
            raise
        if len(layout) != count:
            _unlink(name)
            raise ValueError(f"{desc}: {len(layout)} items given, {count} expected")
        decoded = cls(name, layout)
        weakref.finalize(decoded, _unlink, name)  # only the writer's object: unpickled copies do not delete
        return decoded

    def __len__(self) -> int:
        return len(self.layout)

    def __getitem__(self, index: int) -> dict[str, np.ndarray]:
        if self._buffer is None:
            self._buffer = np.memmap(self.path, dtype=np.uint8, mode="r")
        out = {}
        for key, (offset, shape, dtype) in self.layout[index].items():
            dtype = np.dtype(dtype)
            nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
            out[key] = self._buffer[offset:offset + nbytes].view(dtype).reshape(shape)
        return out

    @property
    def nbytes(self) -> int:
        return self.path.stat().st_size

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_buffer": None}
