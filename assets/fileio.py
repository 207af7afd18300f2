"""Atomic, deterministic file writing and the checks on untrusted names and sizes, shared by every stage.

Every file the project writes goes through `atomic_path`: the data is written to a temporary name in
the destination folder and renamed over the target only when complete, so an interrupted run never
leaves a half file and never destroys an earlier good one; a full disk is reported naming the file.
A stage that writes several files that belong together writes them through `staged_outputs`, so its
outputs are replaced together or not at all.  `save_npz` writes byte-identical archives for identical
arrays (numpy's own `savez` stamps the current time into the zip entries).

Names read from files or arguments that become parts of a path (garments, panels, cameras, images,
motions, jobs) pass `safe_name`, so no input can make a stage write outside its output folder; sizes
read from input pass `check_limit` before anything is allocated.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import json
import os
import shutil
import tempfile
import zipfile
import zlib
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
    except OSError as exc:
        raise _named_os_error(exc, path) from exc
    finally:
        tmp.unlink(missing_ok=True)


def _named_os_error(exc: OSError, path: Path) -> OSError:
    """`exc` itself, or for a full disk or quota an OSError that names the file being written."""
    if exc.errno not in (errno.ENOSPC, errno.EDQUOT) or str(path) in str(exc):
        return exc
    return OSError(exc.errno, f"{path}: disk full while writing ({exc.strerror or exc})")


def copy_file(source: str | os.PathLike, target: str | os.PathLike) -> None:
    """Copy `source` to `target` atomically (a full disk leaves no half `target`)."""
    with atomic_path(target) as tmp:
        shutil.copyfile(source, tmp)


@contextlib.contextmanager
def staged_outputs(folder: str | os.PathLike) -> Iterator[Path]:
    """Yield a hidden staging folder inside `folder`; on success move every file written there into
    `folder` (same relative paths), on error delete it and leave `folder` as it was.

    A stage writes all of its outputs into the staging folder, so a failure part way (a bad argument
    found late, a full disk, an interrupt) never leaves new files beside old ones; files of `folder`
    that the stage does not write are kept."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=".staged.", dir=folder))
    try:
        yield stage
        files = sorted(p for p in stage.rglob("*") if p.is_file())
        targets = [folder / source.relative_to(stage) for source in files]
        for target in targets:  # what would stop a rename part way is refused before the first one
            blocked = next((p for p in (target, *target.parents) if p != folder and p.is_relative_to(folder)
                            and (p.is_dir() if p == target else p.exists() and not p.is_dir())), None)
            if blocked is not None:
                raise OSError(errno.EEXIST, f"{blocked}: in the way of the output {target}")
        for source, target in zip(files, targets):
            os.chmod(source, 0o666 & ~_UMASK)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(source, target)  # renames within one file system: cannot run out of space
    except OSError as exc:
        raise _named_os_error(exc, Path(exc.filename) if exc.filename else folder) from exc
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def file_digest(path: str | os.PathLike) -> str:
    """The SHA-256 of a file's bytes (hex), what a resumed stage compares its inputs by."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def safe_name(name: object, source: str) -> str:
    """`name` if it can be one path component: a non-empty string without separators, `..`, `.`,
    control characters or a leading dot; else a ValueError naming `source` (where the name came from:
    a file and field, or an argument)."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"{source}: a name must be a non-empty string, got {name!r}")
    bad = ("/" in name or "\\" in name or name in (".", "..") or name.startswith(".")
           or any(ord(c) < 32 or ord(c) == 127 for c in name) or len(name.encode()) > 200)
    if bad:
        raise ValueError(f"{source}: name {name!r} cannot be a file name (one path component without "
                         "separators, '..', a leading dot or control characters, at most 200 bytes)")
    return name


def check_limit(value: float, limit: float, what: str, source: str, option: str) -> None:
    """Refuse `value` above `limit` before anything is allocated: a ValueError naming `source`, the
    quantity and `option`, the setting that raises the bound."""
    if not value <= limit:
        raise ValueError(f"{source}: {what} is {value:,.6g}, above the limit of {limit:,.6g}; "
                         f"raise it with {option} if this is intended")


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


def npz_headers(path: str | os.PathLike) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """Shape and dtype of every array of a `.npz`, read from the `.npy` headers without decompressing
    any data: what a reader checks before a small compressed file expands to gigabytes."""
    path = Path(path)
    readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
    out = {}
    try:
        with zipfile.ZipFile(path) as archive:
            for member in archive.namelist():
                if not member.endswith(".npy"):
                    continue
                with archive.open(member) as file:
                    version = np.lib.format.read_magic(file)
                    if version not in readers:
                        raise ValueError(f"{path}: {member}: .npy format version {version} is not supported")
                    shape, _, dtype = readers[version](file)
                out[member[: -len(".npy")]] = (shape, dtype)
    except FileNotFoundError:
        raise
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError, RuntimeError) as exc:
        raise ValueError(f"{path}: not a readable .npz file ({exc})") from exc
    except ValueError as exc:
        raise exc if str(exc).startswith(str(path)) else ValueError(f"{path}: not a readable .npz file ({exc})")
    return out


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
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
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


def check_settings(path: str | os.PathLike, settings: Mapping[str, object]) -> None:
    """Refuse to run a stage whose settings differ from the earlier run's recorded in `path` (a
    ValueError naming the file and the settings that differ); nothing to check where `path` does not
    exist.  `record_stage` checks and records in one call."""
    record_stage(path, settings, write=False)


def _json_data(settings: Mapping[str, object]) -> dict:
    return json.loads(json.dumps(settings))


def record_stage(path: str | os.PathLike, settings: Mapping[str, object], *, changeable: Iterable[str] = (),
                 recompute: bool = False, write: bool = True) -> bool:
    """The one way a stage records what it was made with: `settings` (JSON data) in `path` beside its
    outputs.  A rerun with the same settings returns True: the outputs there are this run's and may be
    reused.  Settings that differ from the recorded ones are refused with a ValueError naming the file
    and each differing setting (``name: old -> new``), so a rerun never mixes outputs made two ways;
    with `recompute` the record is replaced instead and False returned (the stage must then redo its
    outputs).  Keys in `changeable` (those that do not change what the outputs are, e.g. a training
    run's time limit) may differ: the record takes the new values.  A first run records and returns
    False.  write=False only checks."""
    path = Path(path)
    current = _json_data(settings)
    if not path.exists():
        if write:
            save_json(path, current)
        return False
    saved = load_json(path)
    if not isinstance(saved, dict):
        raise ValueError(f"{path}: expected a JSON object of settings, got {type(saved).__name__}")
    free = set(changeable)
    differ = sorted(key for key in {*saved, *current} if key not in free and saved.get(key) != current.get(key))
    if differ and not recompute:
        named = [change for key in differ for change in _changes(key, saved.get(key), current.get(key))]
        detail = "; ".join(f"{key}: {_short(old)} -> {_short(new)}" for key, old, new in named)
        raise ValueError(f"{path}: this folder holds a run made with other settings or inputs ({detail}); "
                         "use a new output folder, or delete this one to start over")
    if write and saved != current:
        save_json(path, current)
    return not differ


def _changes(key: str, old: object, new: object) -> list[tuple[str, object, object]]:
    """(dotted key, old, new) of what differs between two settings values: within tables present on both
    sides by their dotted keys ({"synth": {"seed": 3}} -> "synth.seed"), so a refusal names the setting,
    not the table holding it; anything else (a table against none or an empty one) as a whole."""
    if not (isinstance(old, dict) and isinstance(new, dict) and old and new):
        return [(key, old, new)]
    return [change for sub in sorted({*old, *new}) if old.get(sub) != new.get(sub)
            for change in _changes(f"{key}.{sub}", old.get(sub), new.get(sub))]


def _short(value: object, limit: int = 60) -> str:
    text = "(none)" if value is None else json.dumps(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def check_json_object(data: object, fields: Iterable[str], source: str) -> dict:
    """`data` as read from JSON for a record with these `fields`: a ValueError naming `source` unless it
    is an object whose keys are all among them (missing ones are the reader's business)."""
    if not isinstance(data, dict):
        raise ValueError(f"{source}: expected a JSON object, got {type(data).__name__}")
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ValueError(f"{source}: unknown field(s) {', '.join(map(str, unknown))}")
    return data
