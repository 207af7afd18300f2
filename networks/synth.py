"""Procedural training samples with exact ground truth: the printed pattern, warped on the fly.

Rendering cloth in Blender costs seconds per image; this synthesizer makes a 512 x 512 sample in a
fraction of a second, so the networks can see an unlimited stream of markers, IDs, scales, warps and
lighting (mixed with rendered data by `networks.data.MixedDataset`).

One sample (`PatternSynthesizer.render(index)`, deterministic in (config.seed, index)):

* Geometry.  A patch of marker fabric in its grid coordinates g = (u, v) (cells, u = column right,
  v = row down, as printed; `assets.pattern.spec`) is seen through ``F = D o H``: H a homography
  (marker edge `marker_px` long at the image centre, an in-plane rotation, mostly near upright as on
  a standing person, a foreshortening along a random direction as where the cloth turns away from
  the camera, a perspective tilt; its third homogeneous coordinate is the relative depth of the
  plane) and D(p) = p + sum_i a_i sin(k_i.p + phi_i) a smooth displacement in image pixels whose
  Lipschitz constant sum |a_i| |k_i| stays below `deformation` < 1, so F is invertible and
  orientation-preserving.  Ground-truth crosspoints are F(g) exactly.  Marker IDs run row-major over
  the patch from a random first ID through the synthesizer's `marker_ids` (default: the whole
  codebook), wrapping around, so every ID is equally likely (a view larger than the ID set repeats
  IDs).
* Appearance.  The fabric texture is `assets.pattern.raster.render_grid_view` (the printable
  pattern's exact box filter) at about one texel per image pixel; each supersampled image pixel looks
  it up at F^-1 (Newton's method on a coarse grid of nodes, Catmull-Rom interpolated in between).
  Shading (when on): wrinkle shading that follows the displacement terms, elongated highlights, a
  light gradient, exposure and a colour cast; a fabric boundary (a gently curved cut line, sometimes
  two) beyond which the background shows; a smooth background with clutter; random occluders
  (polygons and ellipses, plain, graded or striped) with soft shadows; last a slight Gaussian blur
  (`blur_px`: a renderer's pixel filter and denoiser).
* Visibility follows `assets.pattern.observation.ImageGroundTruth`: a point is visible when it is on
  the fabric, inside the image and its pixel (floor of its coordinates) is less than half covered by
  occluders; off-fabric points are NaN, as the factory writes them.  Depth is the plane's camera depth
  (`depth_m` at the image centre).

The defaults match the factory's renders (512 x 512, the garment filling the frame; measured on the
20 Blender renders of a shirt walk): markers 19-24 px across (longer edge, 5th to 95th
percentile), foreshortened by 1.6 (median; 3.3 at the 75th percentile), 75 % of them within 30
degrees of upright, the same white / code-colour contrast and blur (a crop's correlation with its
reference texture) and fold shading of about the same strength.  The first defaults (markers 40-160
px, square, any rotation, sharp) matched none of it, and a localizer trained on them found no marker
in the renders.

Randomness comes from separate generators per part (geometry, IDs, lighting, occluders, background,
camera), each seeded from (seed, index, part), so switching a part off (no occluders, no shading)
leaves the others unchanged: tests compare such pairs.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from assets.fileio import check_json_object
from assets.geometry import apply_homography
from assets.pattern.codebook import generate_codebook
from assets.pattern.crops import MAX_CROP_JITTER_PX, CropGeometry
from assets.pattern.observation import ImageGroundTruth
from assets.pattern.raster import render_grid_view
from assets.pattern.spec import PatternSpec
from assets.pattern.table import MarkerTable, localization_rc
from networks.config import without_removed

#: `SynthConfig` fields that measurements removed (docs/journal/2026-11-28-crop-options-removed.md):
#: name -> the only value a saved config (a shard folder's shards.json) may still carry
SYNTH_REMOVED_FIELDS: dict[str, object] = {"crosspoint_margin_cells": 2, "crosspoint_bend": False,
                                            "recognizer_bend": False}

_GEOMETRY, _IDS, _LIGHT, _OCCLUDERS, _BACKGROUND, _CAMERA = range(6)
_SKIN_RGB = np.array([[224, 172, 140], [198, 134, 102], [141, 85, 60], [92, 58, 40], [240, 200, 175]], np.float32)


@dataclass(frozen=True)
class SynthConfig:
    """Ranges of one synthetic sample.  Pixels of the output image unless named otherwise.

    image_size (width, height) multiples of 8; marker_px: marker edge length at the image centre
    (along the direction that is not foreshortened), log-uniform; foreshortening: largest
    compression factor of the fabric along one random direction (1: none; drawn as
    foreshortening ** (U^3), U uniform in [0, 1), so most views are mildly compressed);
    upright_probability: chance that the marker rotation is near upright (normal, upright_spread_deg
    standard deviation), else uniform; max_tilt: relative depth change of the plane from the image
    centre to the middle of the nearest image edge (perspective); deformation: largest Lipschitz
    constant of the smooth displacement (0: a pure homography; < 0.9); wavelength_markers:
    displacement wavelengths in marker edges, log-uniform; shading: False renders the pattern's own
    colours only (no lighting, highlights, cast or shadows); boundary_probability: chance of a fabric
    cut line through the view;
    occluders: (min, max) count, occluder_px: their (min, max) diameter; centred: a marker's centre
    lies within 1/6 marker of the image centre (crop tasks: a whole marker in most samples, whatever
    its size); depth_m: the plane's depth at the image centre; blur_px: (min, max) standard deviation
    of the final Gaussian blur, uniform; supersample: rendering resolution factor before area
    averaging; node_px: spacing of the nodes where F^-1 is solved.  crop_jitter_px: crop tasks cut
    their crops from five points moved by Gaussian noise of this standard deviation
    (`ImageGroundTruth.jittered`), as the Detector cuts them from the localizer's points (0: exact
    points, the reference's crops).  recognizer_partial: recognizer crops of partial markers with a
    visible centre too (`assets.pattern.observation.recognizer_markers`), not only of whole ones
    (False: the reference's, whole markers only; `TrainConfig.recognizer_partial`).  `crop_geometry()`
    is the crop recipe of its crops, which a shard folder records.
    """

    image_size: tuple[int, int] = (512, 512)
    marker_px: tuple[float, float] = (16.0, 32.0)
    foreshortening: float = 4.0
    upright_probability: float = 0.8
    upright_spread_deg: float = 20.0
    max_tilt: float = 0.25
    deformation: float = 0.5
    deformation_terms: int = 4
    wavelength_markers: tuple[float, float] = (0.75, 6.0)
    shading: bool = True
    exposure: tuple[float, float] = (0.6, 1.25)
    light_gradient: float = 0.6
    wrinkle_shading: float = 0.6
    colour_cast: float = 0.12
    highlights: tuple[int, int] = (0, 3)
    highlight_strength: tuple[float, float] = (0.1, 0.6)
    shadow_strength: tuple[float, float] = (0.0, 0.5)
    boundary_probability: float = 0.5
    occluders: tuple[int, int] = (0, 4)
    occluder_px: tuple[float, float] = (20.0, 220.0)
    background_clutter: int = 12
    depth_m: float = 1.0
    blur_px: tuple[float, float] = (0.2, 0.7)
    centred: bool = False
    supersample: int = 2
    node_px: int = 8
    seed: int = 0
    crop_jitter_px: float = 0.0
    recognizer_partial: bool = True

    def __post_init__(self) -> None:
        w, h = self.image_size
        problems = []
        if not 0 <= self.crop_jitter_px <= MAX_CROP_JITTER_PX:
            problems.append(f"crop_jitter_px must be in [0, {MAX_CROP_JITTER_PX:g}] pixels, got {self.crop_jitter_px}")
        if w < 8 or h < 8 or w % 8 or h % 8:
            problems.append(f"image_size must be multiples of 8, got {self.image_size}")
        if not 0 < self.marker_px[0] <= self.marker_px[1]:
            problems.append(f"marker_px must be 0 < min <= max, got {self.marker_px}")
        if not 1 <= self.foreshortening <= 10:
            problems.append(f"foreshortening must be in [1, 10], got {self.foreshortening}")
        if not 0 <= self.upright_probability <= 1 or self.upright_spread_deg < 0:
            problems.append(f"upright_probability must be in [0, 1] and upright_spread_deg >= 0, got "
                            f"{self.upright_probability}, {self.upright_spread_deg}")
        if not 0 <= self.blur_px[0] <= self.blur_px[1]:
            problems.append(f"blur_px must be 0 <= min <= max, got {self.blur_px}")
        if not 0 <= self.max_tilt < 0.5:
            problems.append(f"max_tilt must be in [0, 0.5), got {self.max_tilt}")
        if not 0 <= self.deformation < 0.9:
            problems.append(f"deformation must be in [0, 0.9), got {self.deformation}")
        if not 0 < self.wavelength_markers[0] <= self.wavelength_markers[1]:
            problems.append(f"wavelength_markers must be 0 < min <= max, got {self.wavelength_markers}")
        if not 0 <= self.boundary_probability <= 1:
            problems.append(f"boundary_probability must be in [0, 1], got {self.boundary_probability}")
        if not 0 <= self.occluders[0] <= self.occluders[1] or not 0 < self.occluder_px[0] <= self.occluder_px[1]:
            problems.append(f"occluders {self.occluders} / occluder_px {self.occluder_px} must be ordered ranges")
        if self.supersample < 1 or self.node_px < 2 or self.deformation_terms < 1:
            problems.append("supersample >= 1, node_px >= 2 and deformation_terms >= 1 are required")
        if problems:
            raise ValueError("invalid SynthConfig: " + "; ".join(problems))

    def crop_geometry(self) -> CropGeometry:
        """How the crop tasks' crops are cut: the reference's crops from points jittered by crop_jitter_px."""
        return CropGeometry(jitter_px=float(self.crop_jitter_px))

    def replace(self, **changes: object) -> "SynthConfig":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, object]:
        """Plain JSON types (ranges as lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, data: object, source: str = "SynthConfig") -> "SynthConfig":
        """From a dict as `to_dict` writes (missing fields take the defaults); errors name `source`, as
        do removed options of another value than `SYNTH_REMOVED_FIELDS`."""
        check_json_object(data, [f.name for f in dataclasses.fields(cls)] + list(SYNTH_REMOVED_FIELDS), source)
        data = without_removed(data, SYNTH_REMOVED_FIELDS, source)
        try:
            return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{source}: {exc}") from exc


@dataclass(frozen=True, eq=False)
class Warp:
    """F: patch grid coordinates (u, v) in cells -> image pixels, ``F = D o H`` (module docstring).

    homography (3, 3) grid -> flat image pixels, with third homogeneous coordinate = relative depth;
    wave (T, 2) wave vectors k_i (radians per pixel), amplitude (T, 2) a_i (pixels), phase (T,);
    shading (T,) relative wrinkle-shading amplitude of each term."""

    homography: np.ndarray
    wave: np.ndarray
    amplitude: np.ndarray
    phase: np.ndarray
    shading: np.ndarray

    def displacement(self, p: np.ndarray) -> np.ndarray:
        """d(p) (..., 2) at flat image points p (..., 2)."""
        return np.sin(p @ self.wave.T + self.phase) @ self.amplitude

    def jacobian(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """d(p) (..., 2) and its Jacobian (..., 2, 2) at flat image points p (..., 2)."""
        theta = p @ self.wave.T + self.phase  # (..., T)
        jac = (np.cos(theta) @ (self.amplitude[:, :, None] * self.wave[:, None, :]).reshape(-1, 4))
        return np.sin(theta) @ self.amplitude, jac.reshape(p.shape[:-1] + (2, 2))

    def forward(self, grid_uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Grid points (..., 2) -> image pixels (..., 2) and relative plane depth (...,) (> 0 in view)."""
        g = np.asarray(grid_uv, dtype=np.float64)
        homogeneous = np.concatenate([g, np.ones(g.shape[:-1] + (1,))], axis=-1) @ self.homography.T
        p = homogeneous[..., :2] / homogeneous[..., 2:]
        return p + self.displacement(p), homogeneous[..., 2]

    def flat(self, q: np.ndarray, iterations: int = 30, tolerance_px: float = 1e-6) -> np.ndarray:
        """D^-1: image pixels q (..., 2) -> flat image points p with p + d(p) = q (Newton's method)."""
        p = np.array(q, dtype=np.float64)
        for _ in range(iterations):
            d, jac = self.jacobian(p)
            r = p + d - q
            if np.abs(r).max(initial=0.0) < tolerance_px:
                return p
            a, b, c, e = 1 + jac[..., 0, 0], jac[..., 0, 1], jac[..., 1, 0], 1 + jac[..., 1, 1]
            det = a * e - b * c
            p[..., 0] -= (e * r[..., 0] - b * r[..., 1]) / det
            p[..., 1] -= (a * r[..., 1] - c * r[..., 0]) / det
        raise RuntimeError(f"Warp.flat: Newton's method did not converge (residual {np.abs(r).max():.2e} px); "
                           "lower SynthConfig.deformation")

    def inverse(self, q: np.ndarray) -> np.ndarray:
        """F^-1: image pixels (..., 2) -> grid coordinates (..., 2)."""
        return apply_homography(np.linalg.inv(self.homography), self.flat(q))

    def wrinkles(self, p: np.ndarray) -> np.ndarray:
        """Relative wrinkle shading (...,) at flat image points p (..., 2)."""
        return np.cos(p @ self.wave.T + self.phase) @ self.shading


@dataclass(frozen=True, eq=False)
class SynthSample:
    """One synthetic image and what made it: image (H, W, 3) uint8, its ground truth (markers with
    status > 0), fabric and occluder coverage (H, W) float32 in [0, 1], the warp, and the patch's
    marker IDs (R, C) int64 (marker (i, j) spans grid u in [24 j, 24 j + 24], v in [24 i, 24 i + 24])."""

    image: np.ndarray
    gt: ImageGroundTruth
    fabric: np.ndarray
    occluder: np.ndarray
    warp: Warp
    patch_ids: np.ndarray


class PatternSynthesizer:
    """Draws samples of the pattern `spec` (its rows, cols and origin are ignored: every sample is a
    patch of its own) with IDs from `codebook` (num_ids, n, n), generated from the spec if not given.
    marker_ids: the IDs that may appear (e.g. a garment's, `networks.data.garment_marker_ids`);
    default every ID of the codebook."""

    def __init__(self, spec: PatternSpec, config: SynthConfig = SynthConfig(), codebook: np.ndarray | None = None,
                 marker_ids: np.ndarray | None = None):
        self.spec = spec
        self.config = config
        self.codebook = generate_codebook(spec) if codebook is None else np.asarray(codebook, dtype=np.uint8)
        n = spec.modules_per_side
        if self.codebook.ndim != 3 or self.codebook.shape[1:] != (n, n):
            raise ValueError(f"codebook must have shape (num_ids, {n}, {n}), got {self.codebook.shape}")
        ids = np.arange(len(self.codebook)) if marker_ids is None else np.asarray(marker_ids, dtype=np.int64)
        if ids.ndim != 1 or len(ids) == 0 or ids.min() < 0 or ids.max() >= len(self.codebook):
            raise ValueError(f"marker_ids must be a non-empty list of IDs in 0..{len(self.codebook) - 1}")
        self.marker_ids = ids

    def sample(self, index: int) -> tuple[np.ndarray, ImageGroundTruth]:
        """(image (H, W, 3) uint8, ground truth) of sample `index`."""
        s = self.render(index)
        return s.image, s.gt

    def render(self, index: int) -> SynthSample:
        """Sample `index` with everything that made it (`SynthSample`); see the module docstring."""
        cfg = self.config
        rngs = [np.random.default_rng([cfg.seed, int(index), part]) for part in range(6)]
        width, height = cfg.image_size
        ss = cfg.supersample
        warp = self._warp(rngs[_GEOMETRY])
        # F^-1 on coarse nodes, interpolated to every supersampled pixel centre
        nodes_x = (np.arange(-(-width // cfg.node_px) + 4) - 1) * cfg.node_px
        nodes_y = (np.arange(-(-height // cfg.node_px) + 4) - 1) * cfg.node_px
        q = np.stack(np.meshgrid(nodes_x, nodes_y), axis=-1).astype(np.float64)
        p = warp.flat(q)
        g = apply_homography(np.linalg.inv(warp.homography), p)
        fields = [g[..., 0], g[..., 1]]
        if cfg.shading:
            fields += [warp.wrinkles(p), _highlights(rngs[_LIGHT], cfg, q)]
        ax = _catmull_rom((np.arange(width * ss) + 0.5) / ss / cfg.node_px + 1, len(nodes_x))
        ay = _catmull_rom((np.arange(height * ss) + 0.5) / ss / cfg.node_px + 1, len(nodes_y))
        # float32 suffices: grid coordinates of a few hundred cells keep ~1e-4 cell precision
        dense = [ay @ (f.astype(np.float32) @ ax.T) for f in fields]
        u, v = dense[0], dense[1]

        # the patch of markers covering the view, and its texture at about one texel per pixel
        n = self.spec.cells_per_side
        lo, hi = np.floor(g.reshape(-1, 2).min(axis=0) / n), np.floor(g.reshape(-1, 2).max(axis=0) / n)
        j0, i0 = int(lo[0]), int(lo[1])  # the nodes reach beyond the image: so does the patch
        cols, rows = int(hi[0] - lo[0]) + 1, int(hi[1] - lo[1]) + 1
        u -= j0 * n
        v -= i0 * n
        shift = np.array([[1, 0, -j0 * n], [0, 1, -i0 * n], [0, 0, 1]], dtype=np.float64)
        warp = dataclasses.replace(warp, homography=warp.homography @ np.linalg.inv(shift))
        pool = self.marker_ids
        ids = pool[(rngs[_IDS].integers(len(pool)) + np.arange(rows * cols)) % len(pool)]
        texture, tex_u0, tex_v0, texels = self._texture(ids, rows, cols, u, v, g)
        fabric = cv2.remap(texture, (u - tex_u0) * texels - 0.5, (v - tex_v0) * texels - 0.5,
                           cv2.INTER_LINEAR).astype(np.float32)
        side = _fabric_side(rngs[_GEOMETRY], cfg, self.spec, g[1:-2, 1:-2].reshape(-1, 2) - [j0 * n, i0 * n])
        distance = side(np.stack([u, v], axis=-1))
        on_fabric = (distance >= 0).astype(np.float32)
        # the factory's texture outlines each panel with a 0.5 mm cut line; half the cuts show one
        if rngs[_GEOMETRY].uniform() < 0.5:
            hem = (distance < 0.5 / self.spec.pitch_mm)[..., None]
            fabric = np.where(hem, np.asarray(self.spec.line_rgb, np.float32), fabric)
        if cfg.shading:
            fabric *= np.clip(1 + dense[2], 0.1, None)[..., None]
            fabric += dense[3][..., None] * (255 - fabric)
        image = _background(rngs[_BACKGROUND], cfg, (height * ss, width * ss))
        image += on_fabric[..., None] * (fabric - image)
        occluder = _occluders(rngs[_OCCLUDERS], cfg, image)
        image = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
        occluder = cv2.resize(occluder, (width, height), interpolation=cv2.INTER_AREA)
        on_fabric = cv2.resize(on_fabric, (width, height), interpolation=cv2.INTER_AREA)
        if cfg.shading:
            image = _light(rngs[_LIGHT], cfg, image, occluder)
        blur = rngs[_CAMERA].uniform(*cfg.blur_px)
        if blur > 0:
            image = cv2.GaussianBlur(image, (0, 0), blur, borderType=cv2.BORDER_REFLECT)
        image = np.clip(image + 0.5, 0, 255).astype(np.uint8)
        gt = self._ground_truth(warp, ids.reshape(rows, cols), side, occluder)
        return SynthSample(image, gt, on_fabric * (1 - occluder), occluder, warp, ids.reshape(rows, cols))

    # ---- parts -----------------------------------------------------------------------------------
    def _warp(self, rng: np.random.Generator) -> Warp:
        cfg = self.config
        width, height = cfg.image_size
        n = self.spec.cells_per_side
        marker = float(np.exp(rng.uniform(*np.log(cfg.marker_px))))
        if rng.uniform() < cfg.upright_probability:
            angle = np.radians(rng.normal(0, cfg.upright_spread_deg))
        else:
            angle = rng.uniform(0, 2 * np.pi)
        scale = marker / n
        rotate = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
        squeeze = cfg.foreshortening ** -(rng.uniform() ** 3)  # 1 / compression along `across`
        across = rng.uniform(0, np.pi)
        c, s = np.cos(across), np.sin(across)
        foreshorten = np.eye(3)
        foreshorten[:2, :2] = np.array([[c, -s], [s, c]]) @ np.diag([squeeze, 1.0]) @ np.array([[c, s], [-s, c]])
        phase = rng.uniform(0, n, 2)  # grid point at the image centre
        if cfg.centred:
            phase = n / 2 + (phase - n / 2) / 3  # within 1/6 marker of a marker's centre
        tilt_dir = rng.uniform(0, 2 * np.pi)
        tilt = np.sqrt(rng.uniform()) * cfg.max_tilt / (min(width, height) / 2)
        perspective = np.array([[1, 0, 0], [0, 1, 0], [tilt * np.cos(tilt_dir), tilt * np.sin(tilt_dir), 1]])
        centre = np.array([[1, 0, width / 2], [0, 1, height / 2], [0, 0, 1]])
        to_centre = np.array([[scale, 0, -scale * phase[0]], [0, scale, -scale * phase[1]], [0, 0, 1]])
        homography = centre @ perspective @ foreshorten @ rotate @ to_centre
        terms = cfg.deformation_terms
        wavelength = marker * np.exp(rng.uniform(*np.log(cfg.wavelength_markers), terms))
        direction = rng.uniform(0, 2 * np.pi, terms)
        wave = (2 * np.pi / wavelength)[:, None] * np.stack([np.cos(direction), np.sin(direction)], axis=1)
        share = rng.dirichlet(np.ones(terms))
        lipschitz = rng.uniform(0, cfg.deformation)
        along = direction + rng.normal(0, 0.5, terms)  # mostly compression waves, as wrinkles seen from above
        magnitude = lipschitz * share * wavelength / (2 * np.pi)
        amplitude = magnitude[:, None] * np.stack([np.cos(along), np.sin(along)], axis=1)
        strength = cfg.wrinkle_shading * lipschitz / max(cfg.deformation, 1e-9)
        shading = strength * share * rng.uniform(-1, 1, terms)
        return Warp(homography, wave, amplitude, rng.uniform(0, 2 * np.pi, terms), shading)

    def _texture(self, ids: np.ndarray, rows: int, cols: int, u: np.ndarray, v: np.ndarray, g: np.ndarray):
        """The patch texture over the view: (texture (h, w, 3) uint8, u0, v0, texels per cell)."""
        cfg = self.config
        # finest image scale in pixels per cell, from the node grid's Jacobian
        du = np.diff(g, axis=1)[:-1] / cfg.node_px
        dv = np.diff(g, axis=0)[:, :-1] / cfg.node_px
        jac = np.stack([du, dv], axis=-1)  # (.., 2 [u, v], 2 [x, y]) cells per pixel
        smallest = np.linalg.svd(jac, compute_uv=False)[..., -1].min()
        texels = float(np.clip(1 / max(smallest, 1e-6), 0.5, 64))  # one texel per pixel where finest
        u0, v0 = float(np.floor(u.min())) - 1, float(np.floor(v.min())) - 1
        tex_w = int(np.ceil((u.max() + 1 - u0) * texels)) + 2
        tex_h = int(np.ceil((v.max() + 1 - v0) * texels)) + 2
        if max(tex_w, tex_h) > 8192:
            raise ValueError(f"texture of {tex_w} x {tex_h} texels is too large; "
                             "lower SynthConfig.marker_px or image_size")
        # only the codes and the spec's geometry and colours are used: marker IDs are ours (`ids`), and a
        # large view may hold more markers than the codebook has IDs (they repeat)
        spec = dataclasses.replace(self.spec, rows=rows, cols=cols, origin_xy=(0.0, 0.0),
                                   num_ids=max(self.spec.num_ids, rows * cols))
        table = MarkerTable(spec=spec, codes=self.codebook[ids])
        texture = render_grid_view(table, u0 + np.arange(tex_w + 1) / texels, v0 + np.arange(tex_h + 1) / texels)
        return texture, u0, v0, texels

    def _ground_truth(self, warp: Warp, ids: np.ndarray, side, occluder: np.ndarray) -> ImageGroundTruth:
        cfg = self.config
        width, height = cfg.image_size
        spec = self.spec
        n, k = spec.cells_per_side, spec.crosspoints_per_side
        rows, cols = ids.shape
        # the patch reaches beyond the image: keep the markers whose coarse 5 x 5 crosspoints, grown by
        # their spacing (F is smooth, nearly affine over a marker), come near the image
        coarse = _marker_grid(rows, cols, n, np.linspace(0, n, 5))
        cpx, _ = warp.forward(coarse)
        spacing = np.abs(np.diff(cpx, axis=1)).max(axis=(1, 2, 3)) + np.abs(np.diff(cpx, axis=2)).max(axis=(1, 2, 3))
        with np.errstate(invalid="ignore"):
            near = ((cpx.max(axis=(1, 2)) + spacing[:, None] >= 0).all(axis=1)
                    & (cpx.min(axis=(1, 2)) - spacing[:, None] < [width, height]).all(axis=1))
        near = np.flatnonzero(near)
        ids = ids.reshape(-1)[near]
        grid = _marker_grid(rows, cols, n, np.arange(k))[near]
        px, w = warp.forward(grid)
        on = (side(grid) >= 0) & (w > 0)
        px[~on] = np.nan
        with np.errstate(invalid="ignore"):
            seen = on & (px[..., 0] >= 0) & (px[..., 0] < width) & (px[..., 1] >= 0) & (px[..., 1] < height)
        col = np.clip(np.floor(np.nan_to_num(px[..., 0])).astype(np.int64), 0, width - 1)
        row = np.clip(np.floor(np.nan_to_num(px[..., 1])).astype(np.int64), 0, height - 1)
        seen &= occluder[row, col] < 0.5
        rc = localization_rc(spec)
        point_visible = seen[:, rc[:, 0], rc[:, 1]]
        full = (seen == on).all(axis=(1, 2)) & point_visible.all(axis=1)
        status = np.where(full, 2, np.where(seen.any(axis=(1, 2)), 1, 0)).astype(np.int8)
        depth = np.where(on, w * cfg.depth_m, np.nan).astype(np.float32)
        gt = ImageGroundTruth(
            width=width, height=height, marker_id=ids.astype(np.int32),
            points_px=px[:, rc[:, 0], rc[:, 1]].astype(np.float32), points_depth=depth[:, rc[:, 0], rc[:, 1]],
            point_visible=point_visible, crosspoints_px=px.astype(np.float32), crosspoint_visible=seen,
            status=status)
        return gt.select(status > 0)


# ---- helpers -------------------------------------------------------------------------------------
def _marker_grid(rows: int, cols: int, cells: int, local: np.ndarray) -> np.ndarray:
    """(rows * cols, L, L, 2) float64 grid points (u, v) of every marker at local offsets (L,) cells,
    markers row-major, points [row, col]."""
    gu = np.arange(cols)[None, :, None, None] * cells + local[None, None, None, :]
    gv = np.arange(rows)[:, None, None, None] * cells + local[None, None, :, None]
    grid = np.stack(np.broadcast_arrays(gu, gv), axis=-1)
    return grid.reshape(rows * cols, len(local), len(local), 2).astype(np.float64)


def _catmull_rom(t: np.ndarray, count: int) -> np.ndarray:
    """(len(t), count) weights interpolating values on nodes 0..count-1 at positions t (node units)."""
    i0 = np.floor(t).astype(np.int64)
    f = t - i0
    weights = np.stack([(-f**3 + 2 * f**2 - f) / 2, (3 * f**3 - 5 * f**2 + 2) / 2,
                        (-3 * f**3 + 4 * f**2 + f) / 2, (f**3 - f**2) / 2], axis=1)
    cols = i0[:, None] + np.arange(-1, 3)
    if cols.min() < 0 or cols.max() >= count:
        raise ValueError("interpolation nodes do not cover the image")
    out = np.zeros((len(t), count), dtype=np.float32)
    np.put_along_axis(out, cols, weights.astype(np.float32), axis=1)
    return out


def _fabric_side(rng: np.random.Generator, cfg: SynthConfig, spec: PatternSpec, view_uv: np.ndarray):
    """Signed distance-like function on grid points (..., 2) -> (...,) cells: >= 0 on the fabric (inside
    every cut line drawn), +inf without cuts.  Cut lines pass through a random point of the view."""
    cuts = []
    if rng.uniform() < cfg.boundary_probability:
        for _ in range(1 + int(rng.uniform() < 0.3)):
            origin = view_uv[rng.integers(len(view_uv))]
            angle = rng.uniform(0, 2 * np.pi)
            normal = np.array([np.cos(angle), np.sin(angle)])
            cuts.append((origin, normal, rng.uniform(-1, 1) / (8 * spec.cells_per_side)))

    def side(grid: np.ndarray) -> np.ndarray:
        out = np.full(grid.shape[:-1], np.inf, dtype=grid.dtype)
        for origin, normal, curvature in cuts:
            d = grid - origin
            along = d[..., 0] * -normal[1] + d[..., 1] * normal[0]
            out = np.minimum(out, d @ normal.astype(grid.dtype) + curvature * along**2)
        return out

    return side


def _smooth_field(rng: np.random.Generator, shape: tuple[int, int], cells: int, channels: int) -> np.ndarray:
    coarse = rng.uniform(0, 1, (cells, cells, channels)).astype(np.float32)
    field = cv2.resize(coarse, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)
    return field.reshape(shape[0], shape[1], channels)


def _background(rng: np.random.Generator, cfg: SynthConfig, shape: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) float32 about 0..255 (clipped with the whole image): a smooth random colour field,
    coarse grain and clutter shapes."""
    base = rng.uniform(0, 255, 3).astype(np.float32)
    image = base + rng.uniform(20, 120) * (_smooth_field(rng, shape, int(rng.integers(2, 8)), 3) - 0.5)
    grain = _smooth_field(rng, shape, max(2, shape[0] // 16), 1)
    image += rng.uniform(0, 40) * (grain - 0.5)
    h, w = shape
    for _ in range(int(rng.integers(0, cfg.background_clutter + 1))):
        colour = tuple(float(c) for c in rng.uniform(0, 255, 3))
        kind = rng.integers(3)
        a = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        if kind == 0:
            b = (int(rng.integers(0, w)), int(rng.integers(0, h)))
            cv2.line(image, a, b, colour, int(rng.integers(1, 6 * cfg.supersample)), cv2.LINE_AA)
        elif kind == 1:
            cv2.circle(image, a, int(rng.integers(4, h // 4)), colour, -1, cv2.LINE_AA)
        else:
            b = (a[0] + int(rng.integers(8, w // 3)), a[1] + int(rng.integers(8, h // 3)))
            cv2.rectangle(image, a, b, colour, -1)
    return image


def _occluders(rng: np.random.Generator, cfg: SynthConfig, image: np.ndarray) -> np.ndarray:
    """Paint occluders over `image` (H, W, 3) float32 in place; returns their coverage (H, W) float32."""
    h, w = image.shape[:2]
    ss = cfg.supersample
    coverage = np.zeros((h, w), dtype=np.float32)
    for _ in range(int(rng.integers(cfg.occluders[0], cfg.occluders[1] + 1))):
        radius = 0.5 * ss * float(np.exp(rng.uniform(*np.log(cfg.occluder_px))))
        centre = rng.uniform([0, 0], [w, h])
        if rng.uniform() < 0.5:
            count = int(rng.integers(3, 10))
            angles = np.sort(rng.uniform(0, 2 * np.pi, count))
            polygon = centre + (radius * rng.uniform(0.4, 1, count))[:, None] * np.stack(
                [np.cos(angles), np.sin(angles)], axis=1)
        else:
            t = np.linspace(0, 2 * np.pi, 48, endpoint=False)
            tilt = rng.uniform(0, np.pi)
            a, b = radius, radius * rng.uniform(0.2, 1)
            x, y = a * np.cos(t), b * np.sin(t)
            polygon = centre + np.stack([x * np.cos(tilt) - y * np.sin(tilt), x * np.sin(tilt) + y * np.cos(tilt)], 1)
        mask = np.zeros((h, w), dtype=np.uint8)
        cv2.fillPoly(mask, [np.round(polygon * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
        ys, xs = np.nonzero(mask)
        if len(ys) == 0:
            continue
        colour = _SKIN_RGB[rng.integers(len(_SKIN_RGB))] if rng.uniform() < 0.3 else rng.uniform(0, 255, 3)
        gradient = rng.normal(0, 60, (2, 3)) / max(radius, 1)
        paint = colour + (xs - centre[0])[:, None] * gradient[0] + (ys - centre[1])[:, None] * gradient[1]
        if rng.uniform() < 0.4:
            angle, period = rng.uniform(0, np.pi), rng.uniform(4, 30) * ss
            stripes = np.sin(2 * np.pi * (xs * np.cos(angle) + ys * np.sin(angle)) / period) > 0
            paint += stripes[:, None] * rng.uniform(-120, 120, 3)
        image[ys, xs] = np.clip(paint, 0, 255)
        coverage[ys, xs] = 1.0
    return coverage


def _highlights(rng: np.random.Generator, cfg: SynthConfig, q: np.ndarray) -> np.ndarray:
    """Blend-to-white weight (...,) in [0, 1) at image points q (..., 2): elongated Gaussian blobs."""
    width, height = cfg.image_size
    out = np.zeros(q.shape[:-1])
    for _ in range(int(rng.integers(cfg.highlights[0], cfg.highlights[1] + 1))):
        centre = rng.uniform([0, 0], [width, height])
        angle = rng.uniform(0, np.pi)
        sigma = np.array([rng.uniform(30, 160), rng.uniform(2, 5) * cfg.node_px])
        axes = np.array([[np.cos(angle), np.sin(angle)], [-np.sin(angle), np.cos(angle)]])
        local = (q - centre) @ axes.T / sigma
        out += rng.uniform(*cfg.highlight_strength) * np.exp(-0.5 * (local**2).sum(axis=-1))
    return np.clip(out, 0, 0.95)


def _light(rng: np.random.Generator, cfg: SynthConfig, image: np.ndarray, occluder: np.ndarray) -> np.ndarray:
    """Soft occluder shadows, a light gradient, exposure and a colour cast on the (H, W, 3) image."""
    height, width = image.shape[:2]
    offset = rng.normal(0, 6, 2)
    shifted = cv2.warpAffine(occluder, np.array([[1, 0, offset[0]], [0, 1, offset[1]]]), (width, height))
    shadow = cv2.GaussianBlur(shifted, (0, 0), rng.uniform(2, 10))
    image = image * (1 - rng.uniform(*cfg.shadow_strength) * shadow * (1 - occluder))[..., None]
    direction = rng.normal(0, 1, 2)
    direction *= rng.uniform(0, cfg.light_gradient) / max(np.linalg.norm(direction), 1e-9) / max(width, height)
    xs, ys = np.arange(width) - width / 2, np.arange(height) - height / 2
    gain = 1 + ys[:, None] * direction[1] + xs[None, :] * direction[0]
    cast = rng.uniform(*cfg.exposure) * (1 + rng.uniform(-cfg.colour_cast, cfg.colour_cast, 3))
    return image * gain[..., None].astype(np.float32) * cast.astype(np.float32)
