"""The ResNets: torchvision's state-dict contract, dilation semantics, loading weights from a file."""

import pytest
import torch

from networks.backbone import load_pretrained, resnet18, resnet50


def _bn(name, channels):
    return {f"{name}.weight": (channels,), f"{name}.bias": (channels,), f"{name}.running_mean": (channels,),
            f"{name}.running_var": (channels,), f"{name}.num_batches_tracked": ()}


def _torchvision_shapes(bottleneck, layers, num_classes=1000):
    """Key -> shape of torchvision's resnet18 / resnet50 state dict, written from its architecture:
    stem conv1 7x7 + bn1; stages of (64, 128, 256, 512) planes; BasicBlock conv1/conv2 3x3, Bottleneck
    conv1 1x1, conv2 3x3, conv3 1x1 (4x expansion); a downsample (1x1 conv + BN) on a stage's first
    block when the stride or width changes; fc."""
    shapes = {"conv1.weight": (64, 3, 7, 7), **_bn("bn1", 64)}
    in_channels = 64
    for stage, (planes, blocks) in enumerate(zip((64, 128, 256, 512), layers), start=1):
        out = planes * (4 if bottleneck else 1)
        for index in range(blocks):
            p = f"layer{stage}.{index}."
            if bottleneck:
                shapes[p + "conv1.weight"] = (planes, in_channels, 1, 1)
                shapes[p + "conv2.weight"] = (planes, planes, 3, 3)
                shapes[p + "conv3.weight"] = (out, planes, 1, 1)
                shapes.update({**_bn(p + "bn1", planes), **_bn(p + "bn2", planes), **_bn(p + "bn3", out)})
            else:
                shapes[p + "conv1.weight"] = (planes, in_channels, 3, 3)
                shapes[p + "conv2.weight"] = (planes, planes, 3, 3)
                shapes.update({**_bn(p + "bn1", planes), **_bn(p + "bn2", planes)})
            if index == 0 and (stage > 1 or in_channels != out):
                shapes[p + "downsample.0.weight"] = (out, in_channels, 1, 1)
                shapes.update(_bn(p + "downsample.1", out))
            in_channels = out
    shapes["fc.weight"] = (num_classes, in_channels)
    shapes["fc.bias"] = (num_classes,)
    return shapes


@pytest.mark.parametrize(
    "factory, bottleneck, layers, count, parameters",
    # parameter counts are torchvision's published ones for the 1000-class models
    [(resnet18, False, (2, 2, 2, 2), 122, 11_689_512), (resnet50, True, (3, 4, 6, 3), 320, 25_557_032)],
)
def test_state_dict_matches_torchvision(factory, bottleneck, layers, count, parameters):
    expected = _torchvision_shapes(bottleneck, layers)
    assert len(expected) == count
    model = factory(num_classes=1000)
    got = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    assert got == expected
    assert sum(p.numel() for p in model.parameters()) == parameters
    headless = factory(replace_stride_with_dilation=(True, True, True))
    assert set(headless.state_dict()) == set(expected) - {"fc.weight", "fc.bias"}


def test_dilation_semantics_and_output_strides():
    model = resnet18(replace_stride_with_dilation=(True, True, False))
    # torchvision: a stage's first block uses the dilation before it; later stages keep the dilation
    assert model.layer2[0].conv1.dilation == (1, 1) and model.layer2[0].conv1.stride == (1, 1)
    assert model.layer2[1].conv1.dilation == (2, 2) and model.layer2[1].conv2.dilation == (2, 2)
    assert model.layer3[0].conv1.dilation == (2, 2) and model.layer3[1].conv2.dilation == (4, 4)
    assert model.layer4[0].conv1.stride == (2, 2) and model.layer4[0].conv1.dilation == (4, 4)
    assert model.layer4[0].downsample[0].stride == (2, 2)
    model.eval()
    with torch.no_grad():
        assert model.features(torch.zeros(1, 3, 64, 96)).shape == (1, 512, 8, 12)
        assert model(torch.zeros(1, 3, 64, 96)).shape == (1, 512)
        wide = resnet50(replace_stride_with_dilation=(False, True, True), num_classes=5).eval()
        assert wide.layer4[2].conv2.dilation == (4, 4)
        assert wide.features(torch.zeros(1, 3, 64, 64)).shape == (1, 2048, 8, 8)
        assert wide(torch.zeros(2, 3, 64, 64)).shape == (2, 5)
        plain = resnet50().eval()
        assert plain.features(torch.zeros(1, 3, 64, 64)).shape == (1, 2048, 2, 2)


def _randomised(model):
    """Make every entry distinguishable from a fresh initialisation (running stats included)."""
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for value in model.state_dict().values():
            if value.is_floating_point():
                value.copy_(torch.rand(value.shape, generator=generator) + 0.5)
            else:
                value.fill_(7)
    return model


def test_load_pretrained_from_file(tmp_path):
    path = tmp_path / "resnet18-imagenet.pth"
    source = _randomised(resnet18(num_classes=1000))
    torch.save(source.state_dict(), path)

    target = resnet18(replace_stride_with_dilation=(True, True, False))
    load_pretrained(target, path)
    for key, value in target.state_dict().items():
        assert torch.equal(value, source.state_dict()[key]), key

    other_classes = resnet18(num_classes=10)
    fresh_fc = other_classes.fc.weight.detach().clone()
    load_pretrained(other_classes, path)
    assert torch.equal(other_classes.fc.weight, fresh_fc)  # mismatched fc keeps its initialisation
    assert torch.equal(other_classes.layer3[1].conv2.weight, source.layer3[1].conv2.weight)

    same_classes = resnet18(num_classes=1000)
    load_pretrained(same_classes, path)
    assert torch.equal(same_classes.fc.bias, source.fc.bias)


def test_load_pretrained_rejects_wrong_files(tmp_path):
    resnet18_file = tmp_path / "resnet18-imagenet.pth"
    torch.save(resnet18().state_dict(), resnet18_file)
    with pytest.raises(ValueError, match="resnet18-imagenet.pth.*not ImageNet weights of this ResNet"):
        load_pretrained(resnet50(), resnet18_file)

    text = tmp_path / "notes.txt"
    text.write_text("not weights")
    with pytest.raises(ValueError, match="notes.txt: not a torch state-dict file"):
        load_pretrained(resnet18(), text)

    a_list = tmp_path / "list.pth"
    torch.save([torch.zeros(1)], a_list)
    with pytest.raises(ValueError, match="list.pth: expected a torchvision state dict"):
        load_pretrained(resnet18(), a_list)

    partial = tmp_path / "partial.pth"
    state = resnet18().state_dict()
    del state["layer2.1.bn2.running_var"]
    torch.save(state, partial)
    with pytest.raises(ValueError, match=r"partial.pth.*1 missing key\(s\).*layer2.1.bn2.running_var"):
        load_pretrained(resnet18(), partial)

    with pytest.raises(FileNotFoundError, match="absent.pth"):
        load_pretrained(resnet18(), tmp_path / "absent.pth")
    with pytest.raises(TypeError, match="ResNet"):
        load_pretrained(torch.nn.Linear(2, 2), resnet18_file)
