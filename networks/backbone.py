"""ResNet-18 and ResNet-50, written here (no torchvision on our CPU machines) with torchvision's
state-dict keys, so ImageNet weights load from a torchvision file (`load_pretrained`).

Keys are a public contract: ``conv1.weight``, ``bn1.{weight,bias,running_mean,running_var,
num_batches_tracked}``, ``layer{1..4}.{block}.conv{1,2[,3]}.weight``, ``...bn{1,2[,3]}.*``,
``layer{k}.0.downsample.0.weight`` / ``.downsample.1.*`` and ``fc.{weight,bias}`` (122 entries for
resnet18, 320 for resnet50, `num_batches_tracked` included).

`replace_stride_with_dilation` has torchvision's semantics per stage (layer2, layer3, layer4): a
replaced stage keeps stride 1 and multiplies the running dilation by 2; the first block of every
stage uses the dilation in force before the stage, the later blocks the new one, and the dilation
stays in force in later stages (so ``(True, True, False)`` gives layer2 dilation 2, layer3
dilation 4 and a stride-2 layer4 whose 3 x 3 convolutions keep dilation 4).  Unlike torchvision,
`BasicBlock` accepts dilation > 1 (both of its 3 x 3 convolutions are dilated), which the Marker
Localizer's ResNet-18 needs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import torch
from torch import nn


def _conv3x3(in_channels: int, out_channels: int, stride: int = 1, dilation: int = 1) -> nn.Conv2d:
    return nn.Conv2d(in_channels, out_channels, 3, stride=stride, padding=dilation, dilation=dilation, bias=False)


def _conv1x1(in_channels: int, out_channels: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(in_channels, out_channels, 1, stride=stride, bias=False)


class BasicBlock(nn.Module):
    """Two 3 x 3 convolutions with a residual connection (ResNet-18/34)."""

    expansion = 1

    def __init__(self, in_channels: int, planes: int, stride: int = 1, downsample: nn.Module | None = None,
                 dilation: int = 1) -> None:
        super().__init__()
        self.conv1 = _conv3x3(in_channels, planes, stride, dilation)
        self.bn1 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = _conv3x3(planes, planes, dilation=dilation)
        self.bn2 = nn.BatchNorm2d(planes)
        self.downsample = downsample

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class Bottleneck(nn.Module):
    """1 x 1 -> 3 x 3 (strided, dilated) -> 1 x 1 with a residual connection (ResNet-50/101)."""

    expansion = 4

    def __init__(self, in_channels: int, planes: int, stride: int = 1, downsample: nn.Module | None = None,
                 dilation: int = 1) -> None:
        super().__init__()
        self.conv1 = _conv1x1(in_channels, planes)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = _conv3x3(planes, planes, stride, dilation)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = _conv1x1(planes, planes * self.expansion)
        self.bn3 = nn.BatchNorm2d(planes * self.expansion)
        self.relu = nn.ReLU(inplace=True)
        self.downsample = downsample

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.relu(self.bn2(self.conv2(out)))
        out = self.bn3(self.conv3(out))
        return self.relu(out + identity)


class ResNet(nn.Module):
    """torchvision's ResNet: stem (conv1 7 x 7 / 2, bn1, relu, maxpool 3 x 3 / 2), layer1..layer4,
    and, when `num_classes` is given, global average pooling and ``fc``.

    `features(x)`: (B, 3, H, W) float -> layer4 output (B, 512 * expansion, H / s, W / s) with
    s = 32 / 2^(number of replaced strides).  `forward(x)`: pooled (B, 512 * expansion) features,
    or (B, num_classes) logits when there is an ``fc``.
    """

    def __init__(self, block: type[BasicBlock] | type[Bottleneck], layers: Sequence[int],
                 replace_stride_with_dilation: Sequence[bool] = (False, False, False),
                 num_classes: int | None = None) -> None:
        super().__init__()
        if len(replace_stride_with_dilation) != 3:
            raise ValueError("replace_stride_with_dilation must have 3 entries (layer2, layer3, layer4), "
                             f"got {tuple(replace_stride_with_dilation)}")
        if len(layers) != 4:
            raise ValueError(f"layers must give the block count of 4 stages, got {tuple(layers)}")
        self.block = block
        self._in_channels = 64
        self._dilation = 1
        self.conv1 = nn.Conv2d(3, 64, 7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(64)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, stride=2, padding=1)
        self.layer1 = self._make_layer(block, 64, layers[0])
        self.layer2 = self._make_layer(block, 128, layers[1], 2, replace_stride_with_dilation[0])
        self.layer3 = self._make_layer(block, 256, layers[2], 2, replace_stride_with_dilation[1])
        self.layer4 = self._make_layer(block, 512, layers[3], 2, replace_stride_with_dilation[2])
        self.out_channels = 512 * block.expansion
        self.avgpool = nn.AdaptiveAvgPool2d(1)
        self.fc = None if num_classes is None else nn.Linear(self.out_channels, num_classes)
        for module in self.modules():  # torchvision's initialisation
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(module, nn.BatchNorm2d):
                nn.init.ones_(module.weight)
                nn.init.zeros_(module.bias)

    def _make_layer(self, block: type[BasicBlock] | type[Bottleneck], planes: int, blocks: int, stride: int = 1,
                    dilate: bool = False) -> nn.Sequential:
        previous_dilation = self._dilation
        if dilate:
            self._dilation *= stride
            stride = 1
        downsample = None
        if stride != 1 or self._in_channels != planes * block.expansion:
            downsample = nn.Sequential(_conv1x1(self._in_channels, planes * block.expansion, stride),
                                       nn.BatchNorm2d(planes * block.expansion))
        layers = [block(self._in_channels, planes, stride, downsample, previous_dilation)]
        self._in_channels = planes * block.expansion
        layers += [block(self._in_channels, planes, dilation=self._dilation) for _ in range(1, blocks)]
        return nn.Sequential(*layers)

    def stem(self, x: torch.Tensor) -> torch.Tensor:
        """conv1, bn1, relu: (B, 3, H, W) -> (B, 64, H / 2, W / 2) (before the max pool)."""
        return self.relu(self.bn1(self.conv1(x)))

    def stages(self, x: torch.Tensor) -> torch.Tensor:
        """maxpool and layer1..layer4 applied to the stem's output."""
        x = self.maxpool(x)
        return self.layer4(self.layer3(self.layer2(self.layer1(x))))

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """layer4 output of (B, 3, H, W) normalised images."""
        return self.stages(self.stem(x))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        pooled = torch.flatten(self.avgpool(self.features(x)), 1)
        return pooled if self.fc is None else self.fc(pooled)


def resnet18(replace_stride_with_dilation: Sequence[bool] = (False, False, False),
             num_classes: int | None = None) -> ResNet:
    """ResNet-18 (BasicBlock, 2-2-2-2); 512 output channels."""
    return ResNet(BasicBlock, (2, 2, 2, 2), replace_stride_with_dilation, num_classes)


def resnet50(replace_stride_with_dilation: Sequence[bool] = (False, False, False),
             num_classes: int | None = None) -> ResNet:
    """ResNet-50 (Bottleneck, 3-4-6-3); 2048 output channels."""
    return ResNet(Bottleneck, (3, 4, 6, 3), replace_stride_with_dilation, num_classes)


def load_pretrained(module: nn.Module, path: str | Path) -> None:
    """Load a torchvision ImageNet state-dict file (e.g. ``resnet50-0676ba61.pth``) into `module`.

    module: a `ResNet` of the file's architecture.  Every key of the module except ``fc`` must be in
    the file with the same shape; ``fc`` is loaded only when the module has one of the file's
    shape (a different number of classes keeps its fresh initialisation).  Nothing is downloaded.
    Raises ValueError naming the file when it is not a state dict of this architecture.
    """
    if not isinstance(module, ResNet):
        raise TypeError(f"load_pretrained loads into a ResNet, got {type(module).__name__}; "
                        "pass the network's `backbone`")
    path = Path(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: pretrained weights file not found") from None
    except Exception as exc:  # torch raises many types on a file that is not a torch save
        raise ValueError(f"{path}: not a torch state-dict file ({type(exc).__name__}: {exc})") from exc
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise ValueError(f"{path}: expected a torchvision state dict (name -> tensor), got {type(state).__name__}")
    own = module.state_dict()
    missing = sorted(k for k in own if not k.startswith("fc.") and k not in state)
    wrong = sorted(k for k in own if not k.startswith("fc.") and k in state and state[k].shape != own[k].shape)
    if missing or wrong:
        details = [f"{len(missing)} missing key(s) (e.g. {missing[:3]})"] if missing else []
        details += [f"{len(wrong)} key(s) of another shape (e.g. {wrong[0]}: file {tuple(state[wrong[0]].shape)}, "
                    f"model {tuple(own[wrong[0]].shape)})"] if wrong else []
        raise ValueError(f"{path}: not ImageNet weights of this ResNet ({module.block.__name__}, "
                         f"{module.out_channels} channels): " + "; ".join(details))
    selected = {k: state[k] for k in own if not k.startswith("fc.")}
    if module.fc is not None and all(k in state and state[k].shape == own[k].shape for k in ("fc.weight", "fc.bias")):
        selected.update({k: state[k] for k in ("fc.weight", "fc.bias")})
    module.load_state_dict(selected, strict=False)
