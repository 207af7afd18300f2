"""The three networks of the reference and their losses.

* `MarkerLocalizer` (ResNet-18, dilated): dense per-8 x 8-cell marker presence and five localization
  points; `localizer_loss`.  Decoding to markers is `networks.decode.decode_localizer`.
* `MarkerRecognizer` (ResNet-50): marker ID logits from a 96 x 96 unwarped crop; `recognizer_loss`.
* `MarkerModuleReader` (ResNet-50, not the reference's): one logit per code module of the same crop,
  decoded against any codebook by `networks.codes.CodeDecoder`; `module_loss`.
* `CrosspointLocalizer` (ResNet-50, dilated, two inputs): visibility and crop position of the 25 x 25
  crosspoints from a 112 x 112 unwarped crop and the reference texture of its ID; `crosspoint_loss`.

Every network takes ImageNet-normalised float images (`normalize` of uint8 (B, 3, H, W)) and
returns raw logits: sigmoid / softmax are applied at inference, not in `forward`.  `pretrained` is
the path of a torchvision ImageNet state-dict file of the backbone (resnet18 / resnet50), or None.
Pixel coordinates are continuous (x right, y down, pixel centres at integer + 0.5).
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from assets.pattern import CropGeometry, PatternSpec, crop_crosspoints_px
from networks.backbone import ResNet, load_pretrained, resnet18, resnet50
from networks.config import CROSSPOINT_VISIBILITY_WEIGHT

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

#: Output stride of the Marker Localizer: one prediction per CELL x CELL pixels.
CELL = 8
NUM_POINTS = 5


def normalize(images: torch.Tensor) -> torch.Tensor:
    """uint8 (B, 3, H, W) RGB, or float32 on the same 0-255 scale -> float32 (B, 3, H, W): / 255, then
    ImageNet mean and std per channel."""
    if images.dtype not in (torch.uint8, torch.float32) or images.ndim != 4 or images.shape[1] != 3:
        raise ValueError(f"normalize expects uint8 (or float32 0-255) images of shape (B, 3, H, W), got "
                         f"{images.dtype} {tuple(images.shape)}")
    mean = torch.tensor(IMAGENET_MEAN, device=images.device).view(1, 3, 1, 1)
    std = torch.tensor(IMAGENET_STD, device=images.device).view(1, 3, 1, 1)
    return (images.float() / 255.0 - mean) / std


def _check_images(x: torch.Tensor, name: str) -> None:
    if x.ndim != 4 or x.shape[1] != 3 or not x.is_floating_point():
        raise ValueError(f"{name}: expected normalised float images (B, 3, H, W), got {x.dtype} {tuple(x.shape)}")


def _load_backbone(backbone: ResNet, pretrained: str | Path | None) -> None:
    if pretrained is not None:
        load_pretrained(backbone, pretrained)


# ---- Marker Localizer ---------------------------------------------------------------------------

class MarkerLocalizer(nn.Module):
    """ResNet-18 with layer2 and layer3 at stride 1 (dilation 2 and 4) and a stride-2 layer4, so
    its 512-channel features are at 1/8 of the input; head ``head.conv`` (3 x 3, 512 -> 128), ReLU,
    ``head.out`` (1 x 1, 128 -> 11).

    forward: x float (B, 3, H, W), H and W multiples of 8 -> (B, 11, H / 8, W / 8): channel 0 the
    presence logit of a marker centre in the 8 x 8 cell, channels 1-10 (x, y) of centre, TL, TR, BL,
    BR in pixels relative to the cell's top-left corner.
    """

    def __init__(self, pretrained: str | Path | None = None) -> None:
        super().__init__()
        self.backbone = resnet18(replace_stride_with_dilation=(True, True, False))
        _load_backbone(self.backbone, pretrained)
        self.head = nn.Sequential()
        self.head.add_module("conv", nn.Conv2d(self.backbone.out_channels, 128, 3, padding=1))
        self.head.add_module("relu", nn.ReLU(inplace=True))
        self.head.add_module("out", nn.Conv2d(128, 1 + 2 * NUM_POINTS, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        _check_images(x, "MarkerLocalizer input")
        if x.shape[2] % CELL or x.shape[3] % CELL:
            raise ValueError(f"MarkerLocalizer input: height and width must be multiples of {CELL}, "
                             f"got {x.shape[2]} x {x.shape[3]}")
        return self.head(self.backbone.features(x))


def localizer_loss(output: torch.Tensor, cells: torch.Tensor, presence_weight: float = 10.0,
                   points_weight: float = 1.0 / NUM_POINTS, count_mean=None) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """presence_weight * BCE(presence) + points_weight * sum over the 5 points of MSE.

    output: (B, 11, h, w) `MarkerLocalizer` output.  cells: (B, h, w, 11) float32 targets
    (`assets.pattern.observation.localizer_targets`): channel 0 presence in {0, 1}, channels 1-10
    the points relative to the cell corner, NaN for a point off the fabric.
    BCE is the mean over all cells.  The MSE of a point is the mean over both coordinates of the
    cells with a marker where that point is not NaN (0 where there is none).
    Returns (loss, {"presence": BCE, "points": sum of the point MSEs}), both unweighted parts detached.
    count_mean: under DDP, the mean over the ranks of a count tensor (`networks.distributed`): the MSEs
    are then divided by it, so the ranks' averaged gradients are those of the global batch's MSE.
    """
    b, c, h, w = output.shape
    if c != 1 + 2 * NUM_POINTS or tuple(cells.shape) != (b, h, w, c):
        raise ValueError(f"localizer_loss: cells must have shape {(b, h, w, 1 + 2 * NUM_POINTS)} for an output of "
                         f"shape {tuple(output.shape)}, got {tuple(cells.shape)}")
    pred = output.permute(0, 2, 3, 1)
    presence = F.binary_cross_entropy_with_logits(pred[..., 0], cells[..., 0].to(pred.dtype))
    target = cells[..., 1:].reshape(b, h, w, NUM_POINTS, 2).to(pred.dtype)
    points = pred[..., 1:].reshape(b, h, w, NUM_POINTS, 2)
    valid = (cells[..., 0] > 0.5)[..., None, None] & torch.isfinite(target)
    squared = torch.where(valid, points - torch.where(valid, target, 0.0), 0.0) ** 2
    count = valid.sum(dim=(0, 1, 2, 4))  # (5,) coordinates per point
    if count_mean is not None:
        count = count_mean(count.to(squared.dtype))
    point_mse = squared.sum(dim=(0, 1, 2, 4)) / count.clamp(min=1)
    points_sum = point_mse.sum()
    loss = presence_weight * presence + points_weight * points_sum
    return loss, {"presence": presence.detach(), "points": points_sum.detach()}


# ---- Marker Recognizer --------------------------------------------------------------------------

class _CropNetwork(nn.Module):
    """ResNet-50 -> global average pool -> flatten -> ``backbone.fc`` Linear(2048 -> outputs) on
    recognizer crops; what the ID classifier and the module reader share (their state-dict keys too)."""

    def __init__(self, outputs: int, pretrained: str | Path | None, crops: CropGeometry) -> None:
        super().__init__()
        self.crops = crops
        self.backbone = resnet50(num_classes=outputs)
        _load_backbone(self.backbone, pretrained)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        _check_images(x, f"{type(self).__name__} input")
        return self.backbone(x)


class MarkerRecognizer(_CropNetwork):
    """ResNet-50 -> global average pool -> flatten -> ``backbone.fc`` Linear(2048 -> num_ids).

    forward: x float (B, 3, 96, 96) normalised crops (`assets.pattern.RECOGNIZER_CROP`) -> logits
    (B, num_ids); softmax at inference.  crops: how its crops are cut (`assets.pattern.CropGeometry`;
    `crops.recognizer`): whoever cuts them (the Detector) reads it here.
    """

    def __init__(self, num_ids: int, pretrained: str | Path | None = None,
                 crops: CropGeometry = CropGeometry()) -> None:
        if num_ids < 2:
            raise ValueError(f"MarkerRecognizer: num_ids must be >= 2, got {num_ids}")
        super().__init__(num_ids, pretrained, crops)
        self.num_ids = num_ids


def recognizer_loss(logits: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
    """Cross-entropy of logits (B, num_ids) against marker IDs int64 (B,); scalar."""
    if logits.ndim != 2 or ids.shape != logits.shape[:1]:
        raise ValueError(f"recognizer_loss: expected logits (B, num_ids) and ids (B,), got {tuple(logits.shape)} "
                         f"and {tuple(ids.shape)}")
    return F.cross_entropy(logits, ids.long())


class MarkerModuleReader(_CropNetwork):
    """ResNet-50 -> global average pool -> flatten -> ``backbone.fc`` Linear(2048 -> n * n): the
    Marker Recognizer's network with one output per code module instead of one per marker ID.

    forward: x float (B, 3, 96, 96) normalised crops (`assets.pattern.RECOGNIZER_CROP`) -> logits
    (B, n * n), module (row r, col c) of the crop's canonical orientation (TL corner top-left) at
    r * n + c; sigmoid is the probability that the module is filled with the code colour (1 in the
    codebook's grids).  It knows no IDs: `networks.codes.CodeDecoder` matches its logits against any
    codebook of the pattern, so IDs no training garment printed are read too.  crops: as for
    `MarkerRecognizer`.
    """

    def __init__(self, modules_per_side: int, pretrained: str | Path | None = None,
                 crops: CropGeometry = CropGeometry()) -> None:
        if modules_per_side < 2:
            raise ValueError(f"MarkerModuleReader: modules_per_side must be >= 2, got {modules_per_side}")
        super().__init__(modules_per_side * modules_per_side, pretrained, crops)
        self.modules_per_side = modules_per_side


def module_loss(logits: torch.Tensor, modules: torch.Tensor) -> torch.Tensor:
    """Mean binary cross-entropy of module logits (B, L) against the IDs' module grids (B, L) in {0, 1}
    (`networks.codes.module_targets` rows); scalar."""
    if logits.ndim != 2 or modules.shape != logits.shape:
        raise ValueError(f"module_loss: expected logits (B, L) and module grids of the same shape, got "
                         f"{tuple(logits.shape)} and {tuple(modules.shape)}")
    return F.binary_cross_entropy_with_logits(logits, modules.to(logits.dtype))


# ---- Crosspoint Localizer -----------------------------------------------------------------------

class CrosspointLocalizer(nn.Module):
    """Crosspoint visibility and position from an unwarped crop and the reference texture of its ID.

    Architecture (112 x 112 inputs, both ImageNet-normalised):
      crop      -> backbone stem (``backbone.conv1``, ``bn1``, ReLU; 7 x 7 / 2)  -> (64, 56, 56)
      reference -> ``reference_conv`` (7 x 7 / 2), ``reference_bn``, ReLU       -> (64, 56, 56)
      concatenation (128) -> ``fuse`` 1 x 1 conv back to 64, ReLU -> ResNet-50 maxpool, layer1,
      layer2 and layer3 at stride 1 with dilation 2 and 4, layer4 at stride 2 -> (2048, 14, 14)
      decoder ``decoder.up`` ConvTranspose2d(2048 -> 512, 2, stride 2) -> ReLU ->
      ``decoder.conv`` Conv2d(512 -> 64, 4, no padding) -> ReLU -> ``decoder.out`` Conv2d(64 -> 3, 1)
      sizes 112 -> 56 -> 28 (maxpool) -> 28 -> 28 -> 14 (layer4) -> 28 -> 25.
    ``decoder.out`` starts at zero (visibility 0.5, every crosspoint at its canonical position).
    ``fuse`` starts as the identity on the crop's features and zero on the reference's, so the
    pretrained layers first see what ImageNet trained them on; with `pretrained` the reference stem
    also starts from the ImageNet ``conv1`` / ``bn1``.

    forward: crop, reference float (B, 3, 112, 112) -> (B, 3, K, K) for crosspoint (row, col):
    channel 0 the visibility logit, channels 1, 2 (x, y) in crop pixels.  The (x, y) channels are
    the decoder's output added to each crosspoint's canonical crop position (buffer
    ``canonical_px`` (2, K, K) from `assets.pattern.crop_crosspoints_px`), so the output is absolute
    crop pixels but the regression starts at the right place (an offset of 0 is a flat,
    fronto-parallel marker).  crops: how its crops are cut (`assets.pattern.CropGeometry`; `crop` is
    `crops.crosspoints`, the reference's 112 x 112 by default): whoever cuts them reads it here.
    """

    def __init__(self, pretrained: str | Path | None = None, crosspoints_per_side: int = 25,
                 crops: CropGeometry = CropGeometry()) -> None:
        super().__init__()
        k = crosspoints_per_side
        self.crops = crops
        self.crop = crops.crosspoints
        size = self.crop.size_px // 4  # feature size after the decoder's up-convolution
        if not 1 <= k <= size:
            raise ValueError(f"CrosspointLocalizer: crosspoints_per_side must be in 1..{size}, got {k}")
        self.crosspoints_per_side = k
        self.backbone = resnet50(replace_stride_with_dilation=(True, True, False))
        self.reference_conv = nn.Conv2d(3, 64, 7, stride=2, padding=3, bias=False)
        self.reference_bn = nn.BatchNorm2d(64)
        nn.init.kaiming_normal_(self.reference_conv.weight, mode="fan_out", nonlinearity="relu")
        if pretrained is not None:
            load_pretrained(self.backbone, pretrained)
            self.reference_conv.load_state_dict(self.backbone.conv1.state_dict())
            self.reference_bn.load_state_dict(self.backbone.bn1.state_dict())
        self.fuse = nn.Conv2d(128, 64, 1)
        with torch.no_grad():
            self.fuse.weight.zero_()
            self.fuse.weight[:, :64, 0, 0] = torch.eye(64)
            self.fuse.bias.zero_()
        self.decoder = nn.Sequential()
        self.decoder.add_module("up", nn.ConvTranspose2d(self.backbone.out_channels, 512, 2, stride=2))
        self.decoder.add_module("relu1", nn.ReLU(inplace=True))
        self.decoder.add_module("conv", nn.Conv2d(512, 64, size - k + 1))
        self.decoder.add_module("relu2", nn.ReLU(inplace=True))
        self.decoder.add_module("out", nn.Conv2d(64, 3, 1))
        # start at the canonical positions with visibility 0.5: the first optimizer steps cannot
        # throw the outputs far away through 2048 freshly initialised channels
        nn.init.zeros_(self.decoder.out.weight)
        nn.init.zeros_(self.decoder.out.bias)
        spec = PatternSpec(crosspoints_per_side=k)
        canonical = torch.as_tensor(crop_crosspoints_px(spec, self.crop), dtype=torch.float32)
        self.register_buffer("canonical_px", canonical.permute(2, 0, 1).contiguous(), persistent=False)

    def forward(self, crop: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
        size = self.crop.size_px
        for name, x in (("crop", crop), ("reference", reference)):
            _check_images(x, f"CrosspointLocalizer {name}")
            if tuple(x.shape[2:]) != (size, size):
                raise ValueError(f"CrosspointLocalizer {name}: expected {size} x {size} crops "
                                 f"(its crops.crosspoints), got {x.shape[2]} x "
                                 f"{x.shape[3]}; the decoder yields {self.crosspoints_per_side} x "
                                 f"{self.crosspoints_per_side} only from that size")
        if crop.shape[0] != reference.shape[0]:
            raise ValueError(f"CrosspointLocalizer: {crop.shape[0]} crops but {reference.shape[0]} references")
        image = self.backbone.stem(crop)
        ref = F.relu(self.reference_bn(self.reference_conv(reference)))
        fused = F.relu(self.fuse(torch.cat([image, ref], dim=1)))
        features = self.decoder.relu1(self.decoder.up(self.backbone.stages(fused)))
        out = self.decoder.out(self.decoder.relu2(self.decoder.conv(features)))
        return torch.cat([out[:, :1], out[:, 1:] + self.canonical_px], dim=1)


def crosspoint_loss(output: torch.Tensor, xy: torch.Tensor, visible: torch.Tensor, count_mean=None
                    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The reference's loss: CROSSPOINT_VISIBILITY_WEIGHT (100) * BCE(visibility) + MSE of (x, y) on
    visible crosspoints.

    output: (B, 3, K, K) `CrosspointLocalizer` output.  xy: (B, K, K, 2) float32 crop pixels, NaN off
    the fabric; visible: (B, K, K) bool.  BCE is the mean over all crosspoints; the MSE the mean over
    both coordinates of the visible crosspoints with finite xy (0 where there is none).
    Returns (loss, {"visibility": BCE, "xy": MSE}), the unweighted parts detached.  count_mean: as
    for `localizer_loss`.
    """
    b, c, k, k2 = output.shape
    if c != 3 or k != k2 or tuple(xy.shape) != (b, k, k, 2) or tuple(visible.shape) != (b, k, k):
        raise ValueError(f"crosspoint_loss: for an output of shape {tuple(output.shape)} expected xy {(b, k, k2, 2)} "
                         f"and visible {(b, k, k2)}, got {tuple(xy.shape)} and {tuple(visible.shape)}")
    visible = visible.bool()
    visibility = F.binary_cross_entropy_with_logits(output[:, 0], visible.to(output.dtype))
    pred = output[:, 1:].permute(0, 2, 3, 1)
    target = xy.to(pred.dtype)
    valid = visible[..., None] & torch.isfinite(target)
    squared = torch.where(valid, pred - torch.where(valid, target, 0.0), 0.0) ** 2
    count = valid.sum() if count_mean is None else count_mean(valid.sum().to(squared.dtype))
    mse = squared.sum() / count.clamp(min=1)
    loss = CROSSPOINT_VISIBILITY_WEIGHT * visibility + mse
    return loss, {"visibility": visibility.detach(), "xy": mse.detach()}
