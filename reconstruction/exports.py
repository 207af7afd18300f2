"""Exports of a reconstructed garment sequence: npz, per-frame PLY and OBJ, PC2 point cache.

Everything works on plain arrays, gathered and checked once in `GarmentSequence` (T frames, V
vertices and F faces of the sewn mesh of one template level):

  positions (T, V, 3) float32   complete vertex positions, world metres
  faces (F, 3) int32            the level's sewn faces (``Level.sewn_faces``), counter-clockwise
                                seen from the outside
  corner_uv (F, 3, 2) float32   texture coordinates per face corner, origin bottom-left (seams have
                                one UV per side: ``level.uv[level.faces]``)
  captured (T, V) bool          vertex observed by the cameras (True) or filled by physics (False)
  frames (T,) int64             capture frame numbers, increasing, >= 0
  fps float                     the capture's frame rate, Hz
  source str                    where the 2D observations came from ("detector",
                                "groundtruth(noise=..px, dropout=..)"): kept in every file
  level_mm int                  template level of the mesh (0 when unknown)

Axes: the world frame, right-handed, Z up, metres, which is Blender's, so no file here converts
axes: PC2, PLY and OBJ hold the world coordinates as they are.  (Blender's OBJ importer assumes Y up by
default; import with Forward Y, Up Z to keep the coordinates as written.)

Files (every writer is atomic, `assets.fileio`):
- `save_sequence_npz` / `load_sequence_npz`: the whole sequence in one npz.
- `write_ply`: one frame, binary little-endian; per vertex x, y, z (float32), red, green, blue (the
  captured / filled colours) and ``captured`` (uchar 0/1); faces as ``vertex_indices``.  No UVs (OBJ
  carries them).
- `write_obj`: one frame with the template's UVs: ``v`` in vertex order (vertex i of the sequence is
  OBJ vertex i + 1), one ``vt`` per distinct corner UV, ``f v/vt``; with a texture, an MTL beside it
  whose ``map_Kd`` is the texture path relative to the MTL.
- `write_frame_meshes`: every frame as ``f<frame:06d>.obj`` / ``.ply`` in a folder (OBJs share one
  ``garment.mtl``).
- `write_pc2` / `read_pc2`: the point cache of Blender's Mesh Cache modifier (and 3ds Max): header
  b"POINTCACHE2\\0", int32 version 1, int32 points, float32 start frame, float32 sample rate (frames
  between samples), int32 samples; then float32 x, y, z per point per sample, little-endian.  Blender
  ignores start frame and sample rate in its default 'FRAME' time mode: its modifier's own
  ``frame_start`` and ``frame_scale`` place the samples (`reconstruction.review` sets them).
- `export_sequence`: any of these into one folder, for the CLI, with the review .blend that a caller
  writes (`reconstruction.pipeline.write_review`: bpy, in a process of its own; this module never
  imports bpy or `reconstruction.review`).
- `from_refined`: the post-processing's `RefinedSequence` with its template's UVs, ready for these.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple, Sequence

import numpy as np

from assets.fileio import atomic_path, load_npz, save_npz, staged_outputs

#: Vertex colours (RGB, 0-255) of captured and filled vertices in PLY files.
CAPTURED_RGB = (40, 160, 60)
FILLED_RGB = (220, 100, 30)
MESH_FORMATS = ("obj", "ply")
EXPORT_FORMATS = ("npz", "obj", "ply", "pc2")

_PC2_MAGIC = b"POINTCACHE2\0"
_PC2_HEADER = np.dtype([("magic", "S12"), ("version", "<i4"), ("points", "<i4"), ("start", "<f4"),
                        ("rate", "<f4"), ("samples", "<i4")])
_NPZ_KEYS = ("positions", "faces", "corner_uv", "captured", "frames", "fps", "source", "level_mm")


# ---- the sequence ----------------------------------------------------------------------------------
def _array(value, where: str, shape: tuple, kind: str) -> np.ndarray:
    """`value` as an array of `shape` (ints fixed, strings free) whose dtype kind is in `kind`
    ('b' bool, 'iu' integers, 'iuf' real numbers, which must then be finite); else ValueError naming
    `where`."""
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: expected an array, got {type(value).__name__} ({exc})") from None
    expected = "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
    if array.ndim != len(shape) or any(isinstance(s, int) and n != s for n, s in zip(array.shape, shape)):
        raise ValueError(f"{where}: expected shape {expected}, got {array.shape}")
    names = {"b": "booleans", "iu": "integers", "iuf": "real numbers"}[kind]
    if array.dtype.kind not in kind:
        raise ValueError(f"{where}: expected {names}, got dtype {array.dtype}")
    if array.dtype.kind == "f" and not np.isfinite(array).all():
        raise ValueError(f"{where}: {np.count_nonzero(~np.isfinite(array))} value(s) are not finite")
    return array


def _faces(value, where: str, num_vertices: int) -> np.ndarray:
    faces = _array(value, where, ("F", 3), "iu")
    if faces.size and (faces.min() < 0 or faces.max() >= num_vertices):
        raise ValueError(f"{where}: vertex indices must lie in [0, {num_vertices}), got [{faces.min()}, {faces.max()}]")
    return faces.astype(np.int32)


@dataclass(frozen=True, eq=False)
class GarmentSequence:
    """A complete garment sequence ready for export (shapes and units in the module docstring).

    Arrays are converted to the documented dtypes; bad shapes, dtypes, non-finite values, face
    indices out of range and unordered frames raise ValueError naming the field."""

    positions: np.ndarray
    faces: np.ndarray
    corner_uv: np.ndarray
    captured: np.ndarray
    frames: np.ndarray
    fps: float
    source: str = ""
    level_mm: int = 0

    def __post_init__(self) -> None:
        name = type(self).__name__
        positions = _array(self.positions, f"{name}.positions", ("T", "V", 3), "iuf").astype(np.float32)
        t, v = positions.shape[:2]
        faces = _faces(self.faces, f"{name}.faces", v)
        corner_uv = _array(self.corner_uv, f"{name}.corner_uv", (len(faces), 3, 2), "iuf").astype(np.float32)
        captured = _array(self.captured, f"{name}.captured", (t, v), "b")
        frames = _array(self.frames, f"{name}.frames", (t,), "iu").astype(np.int64)
        if t == 0:
            raise ValueError(f"{name}.positions: expected at least one frame, got shape {positions.shape}")
        if frames.min() < 0 or (np.diff(frames) <= 0).any():
            raise ValueError(f"{name}.frames: expected increasing frame numbers >= 0, got {frames.tolist()[:10]}...")
        if isinstance(self.fps, bool) or not isinstance(self.fps, (int, float, np.integer, np.floating)) \
                or not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"{name}.fps: expected a frame rate > 0 (Hz), got {self.fps!r}")
        if not isinstance(self.source, str):
            raise ValueError(f"{name}.source: expected a string, got {self.source!r}")
        if isinstance(self.level_mm, bool) or not isinstance(self.level_mm, (int, np.integer)) or self.level_mm < 0:
            raise ValueError(f"{name}.level_mm: expected an integer >= 0 (0: unknown), got {self.level_mm!r}")
        for key, value in (("positions", positions), ("faces", faces), ("corner_uv", corner_uv),
                           ("captured", captured), ("frames", frames), ("fps", float(self.fps)),
                           ("level_mm", int(self.level_mm))):
            object.__setattr__(self, key, value)

    def __len__(self) -> int:
        return len(self.positions)

    @property
    def num_vertices(self) -> int:
        return self.positions.shape[1]

    @property
    def frame_step(self) -> int:
        """Frames between consecutive samples (1 for a single frame); ValueError unless uniform."""
        return frame_step(self.frames, f"{type(self).__name__}.frames")


def frame_step(frames: np.ndarray, where: str = "frames") -> int:
    """Frames between consecutive frame numbers `frames` (T,) (1 for a single frame); ValueError naming
    `where` unless they are evenly spaced (a point cache plays samples at a fixed rate)."""
    steps = np.unique(np.diff(np.asarray(frames)))
    if len(steps) > 1:
        raise ValueError(f"{where}: a point cache needs evenly spaced frames, got steps {steps.tolist()}")
    return int(steps[0]) if len(steps) else 1


def from_refined(refined, template, fps: float) -> GarmentSequence:
    """A refined sequence (`reconstruction.refinement.RefinedSequence`) on its level of `template`
    (`assets.garments.Template`) as a `GarmentSequence` with the level's corner UVs, at `fps` Hz."""
    level = template.level(refined.level_mm)
    if len(refined.faces) != len(level.faces):
        raise ValueError(f"from_refined: the sequence has {len(refined.faces)} faces, the {refined.level_mm} mm level "
                         f"of template '{template.name}' {len(level.faces)}: not the sequence's template")
    return GarmentSequence(refined.positions, refined.faces, level.uv[level.faces], refined.captured, refined.frames,
                           fps, refined.source, refined.level_mm)


def save_sequence_npz(path: str | os.PathLike, sequence: GarmentSequence) -> None:
    """Write `sequence` (every field, keys as the field names) to one npz, atomically."""
    save_npz(path, {"positions": sequence.positions, "faces": sequence.faces, "corner_uv": sequence.corner_uv,
                    "captured": sequence.captured, "frames": sequence.frames, "fps": np.float64(sequence.fps),
                    "source": np.array(sequence.source), "level_mm": np.int64(sequence.level_mm)})


def load_sequence_npz(path: str | os.PathLike) -> GarmentSequence:
    """Read a file written by `save_sequence_npz`; errors name the file and the field."""
    data = load_npz(path, required=_NPZ_KEYS)
    try:
        return GarmentSequence(positions=data["positions"], faces=data["faces"], corner_uv=data["corner_uv"],
                               captured=data["captured"], frames=data["frames"], fps=data["fps"][()],
                               source=str(data["source"]), level_mm=data["level_mm"][()])
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc


# ---- PLY -----------------------------------------------------------------------------------------
def _comment(text: str) -> str:
    return " ".join(text.split())  # one line, whatever the source string holds


def write_ply(path: str | os.PathLike, positions: np.ndarray, faces: np.ndarray, captured: np.ndarray,
              comment: str = "") -> None:
    """One frame as a binary little-endian PLY.

    positions (V, 3) metres; faces (F, 3) int; captured (V,) bool, written as the vertex colour
    (`CAPTURED_RGB` / `FILLED_RGB`) and as the uchar property ``captured``; comment: a header line."""
    positions = _array(positions, "write_ply: positions", ("V", 3), "iuf")
    faces = _faces(faces, "write_ply: faces", len(positions))
    captured = _array(captured, "write_ply: captured", (len(positions),), "b")
    vertex = np.empty(len(positions), dtype=[("xyz", "<f4", (3,)), ("rgb", "u1", (3,)), ("captured", "u1")])
    vertex["xyz"] = positions
    vertex["rgb"] = np.where(captured[:, None], CAPTURED_RGB, FILLED_RGB)
    vertex["captured"] = captured
    face = np.empty(len(faces), dtype=[("count", "u1"), ("vertex_indices", "<i4", (3,))])
    face["count"] = 3
    face["vertex_indices"] = faces
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {_comment(comment)}"] if comment.strip() else []
    header += [f"element vertex {len(vertex)}"] + [f"property float {a}" for a in "xyz"]
    header += [f"property uchar {c}" for c in ("red", "green", "blue", "captured")]
    header += [f"element face {len(face)}", "property list uchar int vertex_indices", "end_header"]
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii", errors="replace"))
        f.write(vertex.tobytes())
        f.write(face.tobytes())


# ---- OBJ -----------------------------------------------------------------------------------------
def _obj_topology(faces: np.ndarray, corner_uv: np.ndarray) -> str:
    """The ``vt`` and ``f v/vt`` lines of a mesh (the same for every frame)."""
    uv, corner_vt = np.unique(corner_uv.reshape(-1, 2), axis=0, return_inverse=True)
    corners = np.stack([faces.reshape(-1) + 1, corner_vt.reshape(-1) + 1], axis=1)  # 1-based (v, vt)
    texture_lines = ("vt %.7f %.7f\n" * len(uv)) % tuple(uv.ravel())
    return texture_lines + ("f %d/%d %d/%d %d/%d\n" * len(faces)) % tuple(corners.ravel())


def _obj_vertices(positions: np.ndarray) -> str:
    """``v`` lines at micrometre resolution (positions in metres)."""
    return ("v %.6f %.6f %.6f\n" * len(positions)) % tuple(positions.ravel())


def _write_mtl(path: Path, texture: str | os.PathLike, read_from: Path | None = None) -> None:
    """The MTL of material "garment" at `path`; `texture` relative to `read_from` (default: the MTL's
    folder), the folder the MTL is read from when it is written elsewhere first."""
    relative = os.path.relpath(Path(texture).resolve(), (read_from or path.parent).resolve())
    with atomic_path(path) as tmp:
        tmp.write_text(f"newmtl garment\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum 1\nmap_Kd {relative}\n")


def _write_obj_text(path: str | os.PathLike, positions: np.ndarray, topology: str, mtl_name: str | None,
                    comment: str) -> None:
    head = f"# {_comment(comment)}\n" if comment.strip() else ""
    head += f"mtllib {mtl_name}\nusemtl garment\n" if mtl_name else ""
    with atomic_path(path) as tmp:
        tmp.write_text(head + _obj_vertices(positions) + topology)


def write_obj(path: str | os.PathLike, positions: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray,
              texture: str | os.PathLike | None = None, comment: str = "") -> None:
    """One frame as an OBJ with the template's UVs.

    positions (V, 3) metres; faces (F, 3) int; corner_uv (F, 3, 2) per face corner, origin
    bottom-left.  With `texture` (a PNG path), also writes ``<path stem>.mtl`` (material "garment",
    ``map_Kd`` relative to it) and refers to it.  comment: a ``#`` line at the top."""
    path = Path(path)
    positions = _array(positions, "write_obj: positions", ("V", 3), "iuf")
    faces = _faces(faces, "write_obj: faces", len(positions))
    corner_uv = _array(corner_uv, "write_obj: corner_uv", (len(faces), 3, 2), "iuf")
    mtl_name = None
    if texture is not None:
        mtl_name = path.with_suffix(".mtl").name
        _write_mtl(path.with_suffix(".mtl"), texture)
    _write_obj_text(path, positions, _obj_topology(faces, corner_uv), mtl_name, comment)


def frame_mesh_path(folder: str | os.PathLike, frame: int, fmt: str) -> Path:
    """Where `write_frame_meshes` puts frame `frame`: ``<folder>/f<frame:06d>.<fmt>``."""
    return Path(folder) / f"f{frame:06d}.{fmt}"


def write_frame_meshes(folder: str | os.PathLike, sequence: GarmentSequence, fmt: str = "obj",
                       texture: str | os.PathLike | None = None, progress: bool = True,
                       read_from: str | os.PathLike | None = None) -> list[Path]:
    """Every frame of `sequence` as `frame_mesh_path(folder, frame, fmt)`, fmt 'obj' or 'ply'.

    OBJs carry the UVs and, with `texture`, share ``<folder>/garment.mtl``; PLYs carry the captured
    flags.  read_from: the folder the meshes will be read from when `folder` is a staging folder
    (default `folder`); the MTL's texture path is relative to it.  Returns the mesh paths in frame
    order."""
    if fmt not in MESH_FORMATS:
        raise ValueError(f"write_frame_meshes: fmt must be one of {', '.join(MESH_FORMATS)}, got {fmt!r}")
    folder = Path(folder)
    topology = _obj_topology(sequence.faces, sequence.corner_uv) if fmt == "obj" else ""
    mtl_name = "garment.mtl" if fmt == "obj" and texture is not None else None
    if mtl_name:
        _write_mtl(folder / mtl_name, texture, Path(read_from) if read_from is not None else None)
    paths = []
    from tqdm import tqdm  # here, not at import: Blender's own Python may lack it
    for t in tqdm(range(len(sequence)), desc=f"export {fmt}", unit="frame", disable=not progress):
        frame = int(sequence.frames[t])
        paths.append(frame_mesh_path(folder, frame, fmt))
        comment = f"clothcapture reconstruction frame {frame} source {sequence.source or 'unknown'}"
        if fmt == "obj":
            _write_obj_text(paths[-1], sequence.positions[t], topology, mtl_name, comment)
        else:
            write_ply(paths[-1], sequence.positions[t], sequence.faces, sequence.captured[t], comment)
    return paths


# ---- PC2 -----------------------------------------------------------------------------------------
class PointCache(NamedTuple):
    """A PC2 file's content: positions (T, V, 3) float32, start frame, sample rate (frames)."""

    positions: np.ndarray
    start_frame: float
    sample_rate: float


def write_pc2(path: str | os.PathLike, positions: np.ndarray, start_frame: float = 0.0,
              sample_rate: float = 1.0) -> None:
    """Positions (T, V, 3) metres (world, Z up: no axis change) as a PC2 point cache.

    start_frame: frame of the first sample; sample_rate: frames between samples (> 0)."""
    positions = _array(positions, "write_pc2: positions", ("T", "V", 3), "iuf")
    if not (np.isfinite(start_frame) and np.isfinite(sample_rate) and sample_rate > 0):
        raise ValueError(f"write_pc2: start_frame must be finite and sample_rate > 0, got {start_frame}, {sample_rate}")
    header = np.array((_PC2_MAGIC, 1, positions.shape[1], start_frame, sample_rate, positions.shape[0]),
                      dtype=_PC2_HEADER)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(header.tobytes())
        f.write(np.ascontiguousarray(positions, dtype="<f4").tobytes())


def read_pc2(path: str | os.PathLike) -> PointCache:
    """Read a PC2 file; errors name the file and what is wrong with it."""
    path = Path(path)
    size = path.stat().st_size
    if size < _PC2_HEADER.itemsize:
        raise ValueError(f"{path}: not a PC2 file ({size} bytes, shorter than its {_PC2_HEADER.itemsize}-byte header)")
    header = np.fromfile(path, dtype=_PC2_HEADER, count=1)[0]
    if header["magic"] + b"\0" != _PC2_MAGIC:  # numpy drops the trailing NUL of an "S12" field
        raise ValueError(f"{path}: not a PC2 file (starts with {bytes(header['magic'])!r}, expected {_PC2_MAGIC!r})")
    if header["version"] != 1:
        raise ValueError(f"{path}: PC2 version {header['version']}, expected 1")
    points, samples = int(header["points"]), int(header["samples"])
    expected = _PC2_HEADER.itemsize + 12 * points * samples
    if points < 0 or samples < 0 or size != expected:
        raise ValueError(f"{path}: {samples} samples of {points} points need {expected} bytes, the file has {size}")
    positions = np.fromfile(path, dtype="<f4", offset=_PC2_HEADER.itemsize).reshape(samples, points, 3)
    return PointCache(positions, float(header["start"]), float(header["rate"]))


# ---- everything at once --------------------------------------------------------------------------
def export_sequence(folder: str | os.PathLike, sequence: GarmentSequence, formats: Sequence[str] = EXPORT_FORMATS,
                    texture: str | os.PathLike | None = None, progress: bool = True,
                    review: Callable[[Path], list[Path]] | None = None) -> dict[str, list[Path]]:
    """Write `sequence` into `folder` in each of `formats` (`EXPORT_FORMATS`):

    npz -> ``sequence.npz``; obj -> ``obj/f<frame>.obj`` (+ ``obj/garment.mtl`` with a texture);
    ply -> ``ply/f<frame>.ply``; pc2 -> ``garment.pc2`` (evenly spaced frames only).
    review: writes the review .blend at the path it is given, ``<folder>/review.blend``, and returns the
    paths it wrote (`reconstruction.pipeline.write_review`).  Returns {format: written paths}, the
    review's as "blend".

    The files are replaced together or not at all (`assets.fileio.staged_outputs`): a failure part way
    leaves the previous export as it was, never new meshes beside an old point cache.  The review
    writes last, in place, before the staged files replace the old ones: Blender makes the texture's
    path relative to where the file is saved, and its failure still discards the staged files."""
    unknown = sorted(set(formats) - set(EXPORT_FORMATS))
    if unknown:
        raise ValueError(f"export_sequence: unknown format(s) {', '.join(unknown)} (use {', '.join(EXPORT_FORMATS)})")
    folder = Path(folder)
    staged: dict[str, list[Path]] = {}
    with staged_outputs(folder) as stage:
        if "npz" in formats:
            save_sequence_npz(stage / "sequence.npz", sequence)
            staged["npz"] = [stage / "sequence.npz"]
        for fmt in MESH_FORMATS:
            if fmt in formats:
                staged[fmt] = write_frame_meshes(stage / fmt, sequence, fmt, texture if fmt == "obj" else None,
                                                 progress, read_from=folder / fmt)
        if "pc2" in formats:
            write_pc2(stage / "garment.pc2", sequence.positions, float(sequence.frames[0]),
                      float(sequence.frame_step))
            staged["pc2"] = [stage / "garment.pc2"]
        written = {fmt: [folder / p.relative_to(stage) for p in paths] for fmt, paths in staged.items()}
        if review is not None:
            written["blend"] = review(folder / "review.blend")
    return written
