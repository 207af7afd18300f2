"""Augmentation of training images and crops: what a different camera would have seen.

`Augment` holds probabilities and ranges; ``Augment()(image, rng)`` (or `augment(image, rng, config)`)
applies, in the order a camera would: optical or motion blur, exposure, contrast, saturation and white
balance, sensor noise (read noise plus signal-dependent shot noise), a gamma curve, and JPEG
re-encoding.  Photometric steps move no pixel, so exact targets stay exact.  Two steps are geometric:
`ViewWarp`, a random zoom, rotation and compression of a rendered localizer training image, whose
targets are remade from its ground-truth points moved by the same homography, and `MarkerShrink`,
which shows a rendered crop's marker smaller, as a camera farther away would
(`networks.data.RenderedDataset`).  Every random choice comes from the generator passed in, so an
item is reproducible from its seed.

Data loading on the GPU machine's cores bounds the localizer's training (RESULTS.md, issue 7), so the
colour steps are one 3 x 4 affine transform (`cv2.transform`) and the sensor noise is read from a bank
of standard normal draws at a random offset: i.i.d. Gaussian within an image, at a fraction of the
cost of drawing it anew (the draws were half of an item's cost).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, replace

import cv2
import numpy as np

from assets.pattern.observation import ImageGroundTruth, completed_points
from networks.homography import marker_side_px

_LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)
#: standard normal draws shared by all images of a process (made on first use, 8 MiB); an image's
#: noise is a slice at a random offset
_NOISE_BANK_SIZE = 1 << 21
_noise_bank: np.ndarray | None = None


def _standard_normal(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """(shape) float32 standard normal values: a slice of the process's bank at an offset drawn from
    `rng` (fresh draws when the image is larger than the bank)."""
    global _noise_bank
    count = int(np.prod(shape))
    if count > _NOISE_BANK_SIZE // 2:
        return rng.standard_normal(shape, dtype=np.float32)
    if _noise_bank is None:
        _noise_bank = np.random.default_rng(0x5EED).standard_normal(_NOISE_BANK_SIZE, dtype=np.float32)
    start = int(rng.integers(0, _NOISE_BANK_SIZE - count + 1))
    return _noise_bank[start:start + count].reshape(shape)


@dataclass(frozen=True)
class Augment:
    """Probabilities (in [0, 1]) and ranges (min, max) of each augmentation.  Intensities are in
    8-bit levels; blur in pixels; brightness, contrast and saturation are factors (1: unchanged);
    channel_gain is the largest relative white-balance change per channel; shot_noise scales the
    noise variance with the signal (variance = sigma^2 + shot_noise * level)."""

    blur_probability: float = 0.3
    blur_sigma: tuple[float, float] = (0.3, 1.5)
    motion_blur_probability: float = 0.15
    motion_blur_px: tuple[int, int] = (3, 9)
    colour_probability: float = 0.8
    brightness: tuple[float, float] = (0.6, 1.4)
    contrast: tuple[float, float] = (0.7, 1.3)
    saturation: tuple[float, float] = (0.5, 1.5)
    channel_gain: float = 0.1
    noise_probability: float = 0.5
    noise_sigma: tuple[float, float] = (1.0, 8.0)
    shot_noise: tuple[float, float] = (0.0, 0.5)
    gamma_probability: float = 0.4
    gamma: tuple[float, float] = (0.7, 1.5)
    jpeg_probability: float = 0.4
    jpeg_quality: tuple[int, int] = (30, 95)

    def __post_init__(self) -> None:
        problems = []
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name.endswith("_probability") and not 0 <= value <= 1:
                problems.append(f"{f.name} must be in [0, 1], got {value}")
            if isinstance(value, tuple) and not (len(value) == 2 and 0 <= value[0] <= value[1]):
                problems.append(f"{f.name} must be a range (min, max) with 0 <= min <= max, got {value}")
        if not 0 <= self.channel_gain < 1:
            problems.append(f"channel_gain must be in [0, 1), got {self.channel_gain}")
        if self.motion_blur_px[0] < 1 or not 1 <= self.jpeg_quality[0] <= self.jpeg_quality[1] <= 100:
            problems.append(f"motion_blur_px >= 1 and jpeg_quality in 1..100 required, got "
                            f"{self.motion_blur_px}, {self.jpeg_quality}")
        if problems:
            raise ValueError("invalid Augment: " + "; ".join(problems))

    def __call__(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return augment(image, rng, self)


def augment(image: np.ndarray, rng: np.random.Generator, config: Augment = Augment()) -> np.ndarray:
    """A photometrically augmented copy of `image` (H, W, 3) uint8 RGB; same shape and dtype."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"augment: expected an (H, W, 3) uint8 RGB image, got {image.shape} {image.dtype}")
    c = config
    x = image.astype(np.float32)
    if rng.uniform() < c.motion_blur_probability:
        x = cv2.filter2D(x, -1, _motion_kernel(int(rng.integers(c.motion_blur_px[0], c.motion_blur_px[1] + 1)),
                                               rng.uniform(0, np.pi)), borderType=cv2.BORDER_REFLECT)
    elif rng.uniform() < c.blur_probability:
        x = cv2.GaussianBlur(x, (0, 0), rng.uniform(*c.blur_sigma), borderType=cv2.BORDER_REFLECT)
    if rng.uniform() < c.colour_probability:
        # gain g per channel, contrast k about the mean m of the gained image, saturation s about the
        # luma: x -> A (k g x + (1 - k) m) with A = s I + (1 - s) 1 luma^T, one affine map
        gain = rng.uniform(*c.brightness) * (1 + rng.uniform(-c.channel_gain, c.channel_gain, 3))
        mean = gain * np.asarray(cv2.mean(x)[:3])
        contrast, saturation = rng.uniform(*c.contrast), rng.uniform(*c.saturation)
        a = saturation * np.eye(3) + (1 - saturation) * np.outer(np.ones(3), _LUMA)
        affine = np.concatenate([contrast * a * gain[None, :], ((1 - contrast) * a @ mean)[:, None]], axis=1)
        x = cv2.transform(x, affine.astype(np.float32))
    if rng.uniform() < c.noise_probability:
        sigma, shot = rng.uniform(*c.noise_sigma), rng.uniform(*c.shot_noise)
        std = np.sqrt(sigma**2 + shot * np.clip(x, 0, 255)) if shot > 0 else np.float32(sigma)
        x += std * _standard_normal(rng, x.shape)
    out = np.clip(x + 0.5, 0, 255).astype(np.uint8)
    if rng.uniform() < c.gamma_probability:
        table = 255 * (np.arange(256) / 255) ** rng.uniform(*c.gamma)
        out = cv2.LUT(out, np.clip(table + 0.5, 0, 255).astype(np.uint8))
    if rng.uniform() < c.jpeg_probability:
        quality = int(rng.integers(c.jpeg_quality[0], c.jpeg_quality[1] + 1))
        ok, data = cv2.imencode(".jpg", out[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
        if not ok:
            raise RuntimeError(f"augment: JPEG encoding failed for an image of shape {out.shape}")
        out = cv2.imdecode(data, cv2.IMREAD_COLOR)[:, :, ::-1]
    return np.ascontiguousarray(out)


def _motion_kernel(length: int, angle: float) -> np.ndarray:
    """(length, length) float32 kernel: a line of `length` pixels at `angle` radians, sum 1."""
    kernel = np.zeros((length, length), dtype=np.float32)
    c = (length - 1) / 2
    t = np.linspace(-c, c, 4 * length)
    cols = np.clip(np.round(c + t * np.cos(angle)).astype(int), 0, length - 1)
    rows = np.clip(np.round(c + t * np.sin(angle)).astype(int), 0, length - 1)
    kernel[rows, cols] = 1.0
    return kernel / kernel.sum()


@dataclass(frozen=True)
class ViewWarp:
    """A random change of view of a rendered localizer training image, from the camera's position
    about the garment: with `probability`, a zoom by `scale` (log-uniform; > 1 enlarges), an
    in-plane rotation (normal, `rotation_deg` standard deviation) and a compression along a random
    direction by a factor between `squeeze` and 1 (log-uniform; the cloth turned further from the
    camera), about a random point of the image.

    The localizer's rendered training set is about a hundred images of one garment, seen from one
    camera distance with markers of 14-23 px (5th-95th percentile), and it is learnt by heart: in the
    seventh and eighth GPU runs the validation loss stopped falling after 3,000 of 15,000 steps at
    about five times the training loss.  Every view warp shows those images as a new camera would,
    with exact targets."""

    probability: float = 0.75
    scale: tuple[float, float] = (0.75, 1.4)
    rotation_deg: float = 15.0
    squeeze: float = 0.6

    def __post_init__(self) -> None:
        problems = []
        if not 0 <= self.probability <= 1:
            problems.append(f"probability must be in [0, 1], got {self.probability}")
        if not 0 < self.scale[0] <= self.scale[1]:
            problems.append(f"scale must be a range (min, max) with 0 < min <= max, got {self.scale}")
        if not 0 <= self.rotation_deg <= 180:
            problems.append(f"rotation_deg must be in [0, 180], got {self.rotation_deg}")
        if not 0 < self.squeeze <= 1:
            problems.append(f"squeeze must be in (0, 1], got {self.squeeze}")
        if problems:
            raise ValueError("invalid ViewWarp: " + "; ".join(problems))

    def homography(self, rng: np.random.Generator, source_size: tuple[int, int],
                   out_size: tuple[int, int]) -> np.ndarray | None:
        """(3, 3) float64 homography from the source image's pixels to an output image of `out_size`
        (width, height), in continuous pixel coordinates (pixel centres at integer + 0.5), or None
        when this draw leaves the image unwarped.  The output's centre shows a random point of the
        source, chosen so that the output lies inside the source where it can."""
        if rng.uniform() >= self.probability:
            return None
        zoom = float(np.exp(rng.uniform(*np.log(self.scale))))
        angle = np.radians(rng.normal(0.0, self.rotation_deg))
        squeeze = float(np.exp(rng.uniform(np.log(self.squeeze), 0.0)))
        across = rng.uniform(0.0, np.pi)
        rotate = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        c, s = np.cos(across), np.sin(across)
        direction = np.array([[c, -s], [s, c]])
        linear = zoom * rotate @ direction @ np.diag([squeeze, 1.0]) @ direction.T
        half_out = np.array(out_size, np.float64) / 2
        box = np.array([[-1, -1], [1, -1], [-1, 1], [1, 1]]) * half_out
        reach = np.abs(box @ np.linalg.inv(linear).T).max(axis=0)  # the output's half extent in the source
        size = np.array(source_size, np.float64)
        low, high = np.minimum(reach, size / 2), np.maximum(size - reach, size / 2)
        centre = rng.uniform(low, high)
        out = np.eye(3)
        out[:2, :2] = linear
        out[:2, 2] = half_out - linear @ centre
        return out


def warp_image(image: np.ndarray, homography: np.ndarray, out_size: tuple[int, int]) -> np.ndarray:
    """`image` (H, W, C) seen through `homography` (continuous pixel coordinates, source -> output) as
    an image of `out_size` (width, height): bilinear, the source's border pixels repeated outside it."""
    shift = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])
    to_index = np.linalg.inv(shift) @ homography @ shift  # OpenCV's pixel centres are at integers
    return cv2.warpPerspective(image, to_index, tuple(int(v) for v in out_size), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REPLICATE)


@dataclass(frozen=True)
class MarkerShrink:
    """A rendered marker seen smaller and more obliquely, as a farther camera or cloth turned further
    away shows it: with `probability`, the image around a marker is compressed along a random
    direction by a factor drawn log-uniformly between `squeeze` and 1, then shrunk evenly so that the
    marker's side (`marker_side_px`, the square root of its area) becomes a size drawn uniformly
    between `min_px` and its side after the compression; both with area resampling (as a camera with
    larger pixels), the points (and crosspoints) moved with the image (`Shrunk`).  The compression
    never takes the side under `min_px`; markers at most `min_px`, or with a point off the fabric,
    are left as they are.

    Written because the recognizer's errors are on small markers (fully visible ones: 0.87-0.90 top-1
    under 12 px, 0.998 at 16-24 px, twenty-fourth GPU run), as are the crosspoint network's largest
    crop errors, and synthesized small markers did not help (the nineteenth and twenty-third runs).
    Measured since (`benchmarks/partial_ids.py --shrink-to --shrink-squeeze`, RESULTS.md): the stored
    recognizer reads larger held-out markers shrunk to 8 px 0.999 right, and compressed by 0.3 and
    shrunk to 10 px 0.994, against 0.87 for rendered markers under 12 px.  What it misreads is
    curved cloth (five points off a homography), not size, so these examples are mostly easy ones;
    off by default (`TrainConfig.marker_shrink` 0) and not yet measured in training."""

    probability: float = 0.5
    min_px: float = 8.0
    squeeze: float = 0.25
    #: the window shrunk reaches this many marker sides (and 2 px) beyond the points: the crops'
    #: bilinear samples (and the crosspoint crop's margin of 2 to 4 cells of 24) stay inside it
    margin_sides: float = 0.25

    def __post_init__(self) -> None:
        problems = []
        if not 0 <= self.probability <= 1:
            problems.append(f"probability must be in [0, 1], got {self.probability}")
        if not 4 <= self.min_px <= 64:
            problems.append(f"min_px must be in [4, 64] pixels, got {self.min_px}")
        if not 0.05 <= self.squeeze <= 1:
            problems.append(f"squeeze must be in [0.05, 1], got {self.squeeze}")
        if not 0 <= self.margin_sides <= 2:
            problems.append(f"margin_sides must be in [0, 2], got {self.margin_sides}")
        if problems:
            raise ValueError("invalid MarkerShrink: " + "; ".join(problems))

    def __call__(self, image: np.ndarray, points_px: np.ndarray, rng: np.random.Generator) -> "Shrunk":
        """The image to cut the marker of five points `points_px` (5, 2) from, and how its pixels map
        to the given image's: at this draw's odds, the part of `image` around it compressed and
        shrunk, else `image`."""
        if rng.uniform() >= self.probability:
            return Shrunk(image)
        side = float(marker_side_px(np.asarray(points_px, np.float64)[None])[0])
        if not side > self.min_px:  # small already, or a point off the fabric (NaN)
            return Shrunk(image)
        lowest = max(self.squeeze, (self.min_px / side) ** 2)  # the area, and so the side squared, scales with it
        squeeze = float(np.exp(rng.uniform(np.log(lowest), 0.0)))
        angle = float(rng.uniform(0.0, np.pi))
        squeezed = side * np.sqrt(squeeze)
        scale = float(rng.uniform(self.min_px, squeezed) / squeezed) if squeezed > self.min_px else 1.0
        return shrink_around(image, points_px, scale, self.margin_sides * side + 2, squeeze, angle)


@dataclass(frozen=True)
class Shrunk:
    """An image shrunk around a marker (`shrink_around`): its pixels, and the affine map (2, 3) from
    the source image's continuous pixel coordinates to its own (None: the source image itself)."""

    image: np.ndarray
    affine: np.ndarray | None = None

    def points(self, points_px: np.ndarray) -> np.ndarray:
        """Source pixel coordinates (..., 2) in the shrunk image's (NaN stays NaN)."""
        if self.affine is None:
            return points_px
        return np.asarray(points_px, np.float64) @ self.affine[:, :2].T + self.affine[:, 2]

    def ground_truth(self, gt: ImageGroundTruth) -> ImageGroundTruth:
        """`gt`'s markers as the shrunk image shows them: points and crosspoints moved, the image size
        the shrunk image's; depths, visibility and status as they were.  Points off the fabric are
        completed in the source first (`completed_points`), as `ImageGroundTruth.jittered` does, and
        moved: a least-squares completion is not invariant under the squeeze, and from a few nearly
        collinear crosspoints a completion made after it landed a corner 1,000 px off, so the marker
        failed the crop-sanity test (it stopped the twenty-seventh run's `crosspoints_shrink`)."""
        if self.affine is None:
            return gt
        return replace(gt, width=int(self.image.shape[1]), height=int(self.image.shape[0]),
                       points_px=self.points(completed_points(gt)).astype(np.float32),
                       crosspoints_px=self.points(gt.crosspoints_px).astype(np.float32))


def shrink_around(image: np.ndarray, points_px: np.ndarray, scale: float, margin_px: float,
                  squeeze: float = 1.0, angle: float = 0.0) -> Shrunk:
    """The window of `image` (H, W, C) that holds `points_px` (N, 2; continuous pixel coordinates,
    pixel centres at integer + 0.5; NaN ignored) with `margin_px` around them (clipped to the image),
    compressed by `squeeze` along the direction `angle` (radians from the x axis; turned so that
    direction is the result's x axis, bilinear), then resized by `scale`; both with area resampling
    (< 1), as a camera with larger pixels.  Points outside the image (a partial marker's completed
    corners) stay outside the window alike."""
    if not 0 < scale <= 1 or not 0 < squeeze <= 1:
        raise ValueError(f"scale and squeeze must be in (0, 1], got {scale} and {squeeze}")
    points = np.asarray(points_px, np.float64).reshape(-1, 2)
    h, w = image.shape[:2]
    with np.errstate(invalid="ignore"):
        low = np.clip(np.floor(np.nanmin(points, axis=0) - margin_px), 0, [w, h])
        high = np.clip(np.ceil(np.nanmax(points, axis=0) + margin_px), 0, [w, h])
    extent = high - low
    if not (extent >= 1).all():  # off the image, or no finite point: nothing to shrink
        return Shrunk(image)
    lo, hi = low.astype(int), high.astype(int)
    window = image[lo[1]:hi[1], lo[0]:hi[0]]
    to_window = np.array([[1.0, 0.0, -low[0]], [0.0, 1.0, -low[1]], [0.0, 0.0, 1.0]])
    if squeeze < 1:  # turn the window so the squeeze is along x (a canvas holding all of it)
        c, s = np.cos(angle), np.sin(angle)
        turn = np.array([[c, s], [-s, c]])
        corners = np.array([[0.0, 0.0], [extent[0], 0.0], [0.0, extent[1]], extent]) @ turn.T
        start = corners.min(axis=0)
        extent = np.ceil(corners.max(axis=0) - start)
        turned = np.eye(3)
        turned[:2, :2], turned[:2, 2] = turn, -start
        window = warp_image(window, turned, (int(extent[0]), int(extent[1])))
        to_window = turned @ to_window
    size = np.maximum(1, np.round(extent * scale * np.array([squeeze, 1.0]))).astype(int)
    small = cv2.resize(window, (int(size[0]), int(size[1])), interpolation=cv2.INTER_AREA)
    return Shrunk(small, (np.diag([*(size / extent), 1.0]) @ to_window)[:2])
