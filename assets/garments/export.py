"""Template levels as standard mesh files through trimesh: OBJ (+ MTL pointing at the pattern
texture), PLY and GLB (texture embedded), either flat as printed or placed around the body."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from scipy.spatial.transform import Rotation

from assets.fileio import atomic_path
from assets.garments.template import Template

FORMATS = ("obj", "ply", "glb")


def flat_positions(template: Template, spacing_mm: int) -> np.ndarray:
    """(V, 3) the level laid out as on the printed sheet (metres, z = 0): panels do not overlap."""
    level = template.level(spacing_mm)
    width, height = template.layout.size_px
    metres_per_px = 0.0254 / template.layout.dpi
    uv = level.uv.astype(np.float64)
    return np.stack([uv[:, 0] * width * metres_per_px, uv[:, 1] * height * metres_per_px, np.zeros(len(uv))], 1)


def placed_positions(template: Template, spacing_mm: int) -> np.ndarray:
    """(V, 3) every panel moved by its placement hint (world frame, Z up): the pre-dressing pose."""
    level = template.level(spacing_mm)
    out = np.zeros((level.num_vertices, 3))
    for p, panel in enumerate(template.pattern.panels):
        if panel.placement is None:
            raise ValueError(f"pattern '{template.name}': panel '{panel.name}' has no placement hint")
        rotation = Rotation.from_euler("xyz", panel.placement.rotation_deg, degrees=True)
        mask = level.panel == p
        local = np.concatenate([level.pattern_xy[mask], np.zeros((mask.sum(), 1))], axis=1)
        out[mask] = rotation.apply(local) + np.asarray(panel.placement.translation)
    return out


def to_trimesh(template: Template, spacing_mm: int, positions: np.ndarray, texture: Image.Image | None = None) -> trimesh.Trimesh:
    level = template.level(spacing_mm)
    material = trimesh.visual.material.SimpleMaterial(image=texture)
    visual = trimesh.visual.TextureVisuals(uv=level.uv, material=material)
    return trimesh.Trimesh(vertices=positions, faces=level.faces, visual=visual, process=False)


def export_level(
    template: Template,
    spacing_mm: int,
    path: str | Path,
    positions: np.ndarray,
    texture_path: str | Path | None = None,
) -> None:
    """Write one level to `path` (.obj, .ply or .glb).  OBJ's MTL refers to `texture_path` (the
    print file, not copied); GLB embeds that image."""
    path = Path(path)
    kind = path.suffix.lower().lstrip(".")
    if kind not in FORMATS:
        raise ValueError(f"{path}: unsupported mesh format '{kind}' (use {', '.join(FORMATS)})")
    if kind == "glb":
        with Image.open(texture_path) as image:
            mesh = to_trimesh(template, spacing_mm, positions, image.convert("RGB"))
            data = trimesh.exchange.gltf.export_glb(mesh)
        with atomic_path(path) as tmp:
            tmp.write_bytes(data)
        return
    mesh = to_trimesh(template, spacing_mm, positions)
    if kind == "ply":  # UV as the s, t vertex properties, plus the panel index and vertex flags
        level = template.level(spacing_mm)
        mesh.vertex_attributes["panel"] = level.panel.astype(np.int32)
        mesh.vertex_attributes["flags"] = level.flags.astype(np.int32)
        with atomic_path(path) as tmp:
            tmp.write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary", include_attributes=True))
        return
    mtl_name = path.with_suffix(".mtl").name
    text = trimesh.exchange.obj.export_obj(mesh, include_normals=False, include_texture=True, mtl_name=mtl_name)
    mtl = f"newmtl {mtl_name[:-4]}\nKd 1.0 1.0 1.0\n"
    if texture_path is not None:
        mtl += f"map_Kd {Path(texture_path).name}\n"
    text = "\n".join(
        f"usemtl {mtl_name[:-4]}" if line.startswith("usemtl") else line for line in text.splitlines()
    )
    if f"mtllib {mtl_name}" not in text:
        text = f"mtllib {mtl_name}\nusemtl {mtl_name[:-4]}\n" + text
    with atomic_path(path.with_suffix(".mtl")) as tmp:
        tmp.write_text(mtl)
    with atomic_path(path) as tmp:
        tmp.write_text(text + "\n")
