"""The Detector's per-marker geometry as batched tensor code, for images and network outputs that stay
on a GPU: cutting crops, smoothing a marker's crosspoints and mapping crop pixels back to the image.

Each function computes what its host counterpart computes (`networks.detector.unwarp_markers`,
`networks.homography.smooth_crosspoints`, `networks.homography.crop_to_image`), on the tensors'
device, in a few launches per batch instead of NumPy loops or OpenCV calls per marker; the tests hold
them to those counterparts on CPU tensors.  Frames and conventions are `networks.homography`'s.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
from torch import nn

from assets.geometry import invert_3x3
from assets.pattern import CropSpec, PatternSpec, crop_homography
from networks.homography import SMOOTH_DEGREE, SMOOTH_POINTS_PER_TERM


def images_on_device(images: Sequence[np.ndarray], device: torch.device) -> list[torch.Tensor]:
    """uint8 (H, W, 3) images -> uint8 (3, H, W) tensors on `device`, each moved once."""
    return [torch.tensor(np.ascontiguousarray(image), device=device).permute(2, 0, 1) for image in images]


def unwarp_markers_on_device(images: Sequence[torch.Tensor], image_index: np.ndarray, points_px: np.ndarray,
                             spec: PatternSpec, crop: CropSpec) -> torch.Tensor:
    """`unwarp_markers` where the images already are: images uint8 (3, H, W) tensors on one device
    (see `images_on_device`).  Returns (N, 3, S, S) float32 in [0, 255] there: the same crop
    homographies, bilinear, zero outside the image, sampled at the crop's pixel centres (one
    `grid_sample` per image) and not rounded to uint8 as `unwarp`'s are."""
    count, size = len(image_index), crop.size_px
    device = images[0].device if len(images) else torch.device("cpu")
    out = torch.zeros((count, 3, size, size), dtype=torch.float32, device=device)
    if count == 0:
        return out
    # crop pixel centres -> image coordinates through the inverse crop homographies, in float64
    to_image = torch.as_tensor(np.linalg.inv(crop_homography(spec, crop, np.asarray(points_px, np.float64))),
                               device=device)
    centres = torch.arange(size, dtype=torch.float64, device=device) + 0.5
    v, u = torch.meshgrid(centres, centres, indexing="ij")
    crop_xy1 = torch.stack([u, v, torch.ones_like(u)], dim=-1).reshape(-1, 3)  # (S*S, 3), row-major
    xyw = torch.einsum("nij,pj->npi", to_image, crop_xy1)
    xy = xyw[..., :2] / xyw[..., 2:]
    index = torch.as_tensor(np.asarray(image_index), device=device)
    for i in torch.unique(index).tolist():
        pick = torch.nonzero(index == i)[:, 0]
        height, width = images[i].shape[1:]
        # grid_sample's align_corners=False puts -1 and 1 on the image's outer edges: our convention
        scale = torch.tensor([2.0 / width, 2.0 / height], dtype=torch.float64, device=device)
        grid = (xy[pick] * scale - 1.0).to(torch.float32).reshape(1, len(pick) * size, size, 2)
        sampled = nn.functional.grid_sample(images[i][None].float(), grid, mode="bilinear", padding_mode="zeros",
                                            align_corners=False)
        out[pick] = sampled[0].reshape(3, len(pick), size, size).permute(1, 0, 2, 3)
    return out


def crop_to_image_on_device(spec: PatternSpec, crop: CropSpec, points_px: np.ndarray,
                            crop_xy: torch.Tensor) -> torch.Tensor:
    """`crop_to_image` of crop pixels on a device: points_px (N, 5, 2) image pixels (host), crop_xy
    (N, ..., 2) crop pixels -> (N, ..., 2) float64 image pixels on crop_xy's device."""
    n = len(points_px)
    if n == 0:
        return torch.zeros(crop_xy.shape, dtype=torch.float64, device=crop_xy.device)
    to_image = torch.as_tensor(invert_3x3(crop_homography(spec, crop, np.asarray(points_px, np.float64))),
                               device=crop_xy.device)
    flat = crop_xy.reshape(n, -1, 2).to(torch.float64)
    mapped = flat @ to_image[:, :2, :2].transpose(1, 2) + to_image[:, None, :2, 2]
    w = flat @ to_image[:, 2:, :2].transpose(1, 2) + to_image[:, None, 2:, 2]
    return (mapped / w).reshape(crop_xy.shape)


def smooth_crosspoints_on_device(crop_xy: torch.Tensor, visible: torch.Tensor, tolerance_px: float,
                                 degree: int = SMOOTH_DEGREE) -> torch.Tensor:
    """`smooth_crosspoints` on a device: crop_xy (N, K, K, 2), visible (N, K, K) bool -> a new (N, K, K, 2)
    float64 tensor (the same fits, in float64, on the tensors' device)."""
    if crop_xy.ndim != 4 or crop_xy.shape[1] != crop_xy.shape[2] or crop_xy.shape[-1] != 2 \
            or tuple(visible.shape) != tuple(crop_xy.shape[:3]):
        raise ValueError(f"smooth_crosspoints_on_device: crop_xy must be (N, K, K, 2) and visible (N, K, K), got "
                         f"{tuple(crop_xy.shape)} and {tuple(visible.shape)}")
    if not tolerance_px > 0 or degree < 1:
        raise ValueError(f"smooth_crosspoints_on_device: tolerance_px must be > 0 and degree >= 1, got "
                         f"{tolerance_px}, {degree}")
    device = crop_xy.device
    n, k = crop_xy.shape[:2]
    grid = torch.linspace(-1.0, 1.0, k, dtype=torch.float64, device=device)
    row, col = (a.reshape(-1) for a in torch.meshgrid(grid, grid, indexing="ij"))
    terms = torch.stack([col ** i * row ** j for i in range(degree + 1) for j in range(degree + 1 - i)], dim=1)
    seen = visible.reshape(n, k * k)
    points = torch.where(seen[..., None], crop_xy.reshape(n, k * k, 2).to(torch.float64), 0.0)
    needed = SMOOTH_POINTS_PER_TERM * terms.shape[1]
    enough = seen.sum(dim=1) >= needed
    out = crop_xy.reshape(n, k * k, 2).to(torch.float64).clone()
    if n == 0 or not bool(enough.any()):
        return out.reshape(crop_xy.shape)
    eye = torch.eye(terms.shape[1], dtype=torch.float64, device=device)

    def fit(w: torch.Tensor) -> torch.Tensor:  # (N, P) bool weights -> (N, P, 2) fitted field
        weighted = (w[:, :, None] * terms).transpose(1, 2)  # (N, T, P)
        normal = weighted @ terms
        trace = normal.diagonal(dim1=1, dim2=2).sum(dim=1).clamp(min=1.0)
        normal = normal + eye * 1e-9 * trace[:, None, None]
        return terms @ torch.linalg.solve(normal, weighted @ points)

    near = (torch.linalg.norm(points - fit(seen.to(torch.float64)), dim=-1) <= tolerance_px) & seen
    refit = torch.where((near.sum(dim=1) >= needed)[:, None], near, seen)
    fitted = fit(refit.to(torch.float64))
    move = (torch.linalg.norm(points - fitted, dim=-1) <= tolerance_px) & seen & enough[:, None]
    out[move] = fitted[move]
    return out.reshape(crop_xy.shape)
