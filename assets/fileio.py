"""Atomic, deterministic file writing shared by every stage.

Every file the project writes goes through `atomic_path`: the data is written to a temporary name in
the destination folder and renamed over the target only when complete, so an interrupted run never
leaves a half file and never destroys an earlier good one.  `save_npz` writes byte-identical archives
for identical arrays (numpy's own `savez` stamps the current time into the zip entries).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
import zipfile
from pathlib import Path
from typing import Iterable, Iterator, Mapping

import numpy as np

_EPOCH = (1980, 1, 1, 0, 0, 0)
_UMASK = os.umask(0)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to `path`; on success rename it to `path`, on error delete it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; finished files get the usual mode
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def save_npz(path: str | os.PathLike, arrays: Mapping[str, np.ndarray]) -> None:
    """Write `arrays` as a compressed `.npz` with fixed zip timestamps (same arrays, same bytes)."""
    with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(arrays):
            buf = io.BytesIO()
            array = np.asarray(arrays[name])  # (ascontiguousarray would turn 0-d into 1-d)
            np.lib.format.write_array(buf, array if array.flags.c_contiguous else array.copy(), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_EPOCH)
            info.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(info, buf.getvalue())


def load_npz(path: str | os.PathLike, required: tuple[str, ...] = (),
             only: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """Read a `.npz` without pickles; raise naming the file when it is unreadable or lacks a key.

    only: read just these arrays (all required; members are decompressed on access, so the others
    cost nothing)."""
    path = Path(path)
    wanted = tuple(required) + tuple(k for k in only or () if k not in required)
    try:
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise ValueError(f"{path}: a single array, not an .npz archive")
        with data:
            missing = [key for key in wanted if key not in data.files]
            if missing:
                raise ValueError(f"{path}: missing array(s) {', '.join(missing)}")
            return {key: data[key] for key in (only if only is not None else data.files)}
    except FileNotFoundError:
        raise
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: not a readable .npz file ({exc})") from exc
    except ValueError as exc:
        raise exc if str(exc).startswith(str(path)) else ValueError(f"{path}: not a readable .npz file ({exc})")


def save_json(path: str | os.PathLike, obj: object) -> None:
    """Write `obj` as indented JSON, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n")


def load_json(path: str | os.PathLike) -> object:
    """Read JSON; raise naming the file and the position of a syntax error."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot read ({exc})") from exc
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from exc


def check_json_object(data: object, fields: Iterable[str], source: str) -> dict:
    """`data` as read from JSON for a record with these `fields`: a ValueError naming `source` unless it
    is an object whose keys are all among them (missing ones are the reader's business)."""
    if not isinstance(data, dict):
        raise ValueError(f"{source}: expected a JSON object, got {type(data).__name__}")
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ValueError(f"{source}: unknown field(s) {', '.join(map(str, unknown))}")
    return data
