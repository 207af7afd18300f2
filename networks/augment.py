"""Augmentation of training images and crops: what a different camera would have seen.

`Augment` holds probabilities and ranges; ``Augment()(image, rng)`` (or `augment(image, rng, config)`)
applies, in the order a camera would: optical or motion blur, exposure, contrast, saturation and white
balance, sensor noise (read noise plus signal-dependent shot noise), a gamma curve, and JPEG
re-encoding.  Photometric steps move no pixel, so exact targets stay exact.  One step is geometric:
`ViewWarp`, a random zoom, rotation and compression of a rendered localizer training image, whose
targets are remade from its ground-truth points moved by the same homography
(`networks.data.RenderedDataset`).  Every random choice comes from the generator passed in, so an
item is reproducible from its seed.

Data loading on the GPU machine's cores bounds the localizer's training, so the
colour steps are one 3 x 4 affine transform (`cv2.transform`) and the sensor noise is read from a bank
of standard normal draws at a random offset: i.i.d. Gaussian within an image, at a fraction of the
cost of drawing it anew (the draws were half of an item's cost).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np


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
    camera distance with markers of 14-23 px (5th-95th percentile), and it is learnt by heart: without
    the warp the validation loss stopped falling after 3,000 of 15,000 steps at about five times the
    training loss.  Every view warp shows those images as a new camera would,
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
