"""Writing a posed body sequence: one `.npz`, meshes per frame on request, and a PNG preview.

The preview draws a few frames side by side, each an orthographic view from the front-left (the
camera looks at the body from -Y, turned 30 degrees about Z), shaded by the facing ratio of every
triangle and painted back to front; it needs matplotlib, nothing from Blender.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from assets.body.model import PosedBody
from assets.fileio import atomic_path, save_npz
from assets.rotations import rotvec_to_matrix

PREVIEW_VIEW_DEG = -30.0
_SKIN = np.array([0.85, 0.68, 0.58])


def save_posed_sequence(path: str | os.PathLike, posed: PosedBody, fps: float, **meta: str) -> None:
    """Write vertices (T, V, 3) float32, joints (T, J, 3) float32, faces and fps to one `.npz`."""
    arrays = {
        "vertices": posed.vertices.astype(np.float32),
        "joints": posed.joints.astype(np.float32),
        "faces": posed.faces.astype(np.int32),
        "fps": np.array(float(fps)),
    }
    arrays.update({f"meta_{k}": np.array(str(v)) for k, v in meta.items()})
    save_npz(path, arrays)


def write_frame_meshes(folder: str | os.PathLike, posed: PosedBody, fmt: str = "obj") -> list[Path]:
    """One mesh file per frame (`frame_0000.obj` ...), `fmt` 'obj' or 'ply'; returns the paths."""
    import trimesh

    if fmt not in ("obj", "ply"):
        raise ValueError(f"mesh format must be 'obj' or 'ply', got {fmt!r}")
    folder = Path(folder)
    paths = []
    for t, vertices in enumerate(posed.vertices):
        path = folder / f"frame_{t:04d}.{fmt}"
        mesh = trimesh.Trimesh(vertices, posed.faces, process=False)
        with atomic_path(path) as tmp:
            mesh.export(tmp, file_type=fmt)
        paths.append(path)
    return paths


def preview_frames(count: int, frames: int) -> np.ndarray:
    """`count` frame indices spread evenly over a sequence of `frames`, first and last included."""
    return np.unique(np.linspace(0, frames - 1, min(count, frames)).round().astype(int))


def render_preview(
    path: str | os.PathLike, posed: PosedBody, frames: np.ndarray | None = None, title: str = "", dpi: int = 100,
    extra: tuple[tuple[np.ndarray, np.ndarray, tuple[float, float, float]], ...] = (),
    labels: list[str] | None = None,
) -> None:
    """Draw the given frames (default: 6 spread over the sequence) side by side into a PNG.  `extra`
    meshes (vertices (T, V, 3) on the same frames, faces, RGB colour), e.g. a garment, are drawn with
    the body, both sides of their triangles shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    frames = preview_frames(6, len(posed.vertices)) if frames is None else np.asarray(frames)
    view = rotvec_to_matrix(np.array([0.0, 0.0, np.deg2rad(PREVIEW_VIEW_DEG)]))
    # (vertices, faces, colour, two-sided): the body shows its outside only, cloth both sides
    layers = [(posed.vertices, posed.faces, _SKIN, False)] + [(v, f, np.asarray(c, float), True) for v, f, c in extra]
    # Every panel is centred on its own root joint (a walk travels metres) at one common scale.
    centre = posed.joints[frames, 0] * np.array([1.0, 1.0, 0.0])
    points = [(v[frames] - centre[:, None]) @ view.T for v, _, _, _ in layers]
    stacked = np.concatenate([p.reshape(-1, 3) for p in points])
    lo, hi = stacked.min(axis=0), stacked.max(axis=0)
    fig, axes = plt.subplots(1, len(frames), figsize=(2.2 * len(frames), 4.2), squeeze=False)
    light = np.array([-0.4, -1.0, 0.6])
    light /= np.linalg.norm(light)
    for i, (ax, t) in enumerate(zip(axes[0], frames)):
        tri = np.concatenate([p[i][f] for p, (_, f, _, _) in zip(points, layers)])  # x right, y depth, z up
        base = np.concatenate([np.broadcast_to(c, (len(f), 3)) for _, f, c, _ in layers])
        two_sided = np.concatenate([np.full(len(f), both) for _, f, _, both in layers])
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        normal[two_sided & (normal[:, 1] > 0.0)] *= -1.0  # a two-sided triangle faces the camera
        visible = normal[:, 1] < 0.0  # facing the camera, which looks along +y
        shade = 0.25 + 0.75 * np.clip(normal[visible] @ light, 0.0, 1.0)
        order = np.argsort(-tri[visible, :, 1].mean(axis=1))  # far first
        polys = tri[visible][order][:, :, [0, 2]]
        colours = np.clip(shade[order, None] * base[visible][order], 0.0, 1.0)
        ax.add_collection(PolyCollection(polys, facecolors=colours, edgecolors="none", antialiased=False))
        ax.set_xlim(lo[0] - 0.05, hi[0] + 0.05)
        ax.set_ylim(lo[2] - 0.05, hi[2] + 0.05)
        ax.set_aspect("equal")
        ax.set_title(labels[i] if labels else f"frame {t}", fontsize=8)
        ax.axis("off")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
