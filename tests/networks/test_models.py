"""The three networks: output shapes, losses on hand-made targets, training steps, pretrained weights."""

import math

import numpy as np
import pytest
import torch

from assets.pattern import CROSSPOINT_CROP, PatternSpec, crop_crosspoints_px
from networks.backbone import resnet18, resnet50
from networks.models import (
    IMAGENET_MEAN,
    IMAGENET_STD,
    CrosspointLocalizer,
    MarkerLocalizer,
    MarkerRecognizer,
    crosspoint_loss,
    localizer_loss,
    normalize,
    recognizer_loss,
)


def test_normalize():
    images = torch.zeros(2, 3, 4, 5, dtype=torch.uint8)
    images[1] = 255
    out = normalize(images)
    assert out.dtype == torch.float32 and out.shape == (2, 3, 4, 5)
    for c in range(3):
        assert torch.allclose(out[0, c], torch.tensor(-IMAGENET_MEAN[c] / IMAGENET_STD[c]))
        assert torch.allclose(out[1, c], torch.tensor((1 - IMAGENET_MEAN[c]) / IMAGENET_STD[c]))
    assert torch.equal(normalize(images.float()), out)  # float32 on the 0-255 scale: the same
    with pytest.raises(ValueError, match="uint8"):
        normalize(images.double())
    with pytest.raises(ValueError, match="uint8"):
        normalize(images[:, :2])


def test_output_shapes_and_input_checks():
    torch.manual_seed(0)
    with torch.no_grad():
        localizer = MarkerLocalizer().eval()
        assert localizer(torch.randn(2, 3, 64, 96)).shape == (2, 11, 8, 12)
        assert localizer.head.conv.kernel_size == (3, 3) and localizer.head.out.out_channels == 11
        with pytest.raises(ValueError, match="multiples of 8"):
            localizer(torch.randn(1, 3, 60, 96))

        recognizer = MarkerRecognizer(num_ids=7).eval()
        assert recognizer(torch.randn(2, 3, 96, 96)).shape == (2, 7)

        crosspoints = CrosspointLocalizer().eval()
        crop, reference = torch.randn(1, 3, 112, 112), torch.randn(1, 3, 112, 112)
        out = crosspoints(crop, reference)
        assert out.shape == (1, 3, 25, 25)
        with pytest.raises(ValueError, match="expected 112 x 112 crops"):
            crosspoints(torch.randn(1, 3, 96, 96), torch.randn(1, 3, 96, 96))
        with pytest.raises(ValueError, match="reference: expected 112 x 112"):
            crosspoints(torch.randn(1, 3, 112, 112), torch.randn(1, 3, 112, 96))

        # xy is an offset from each crosspoint's canonical crop position: a zero decoder output gives
        # exactly the flat marker's crosspoints (8, 12, ..., 104 for the default crop)
        crosspoints.decoder.out.weight.zero_()
        crosspoints.decoder.out.bias.zero_()
        out = crosspoints(crop, reference)
        canonical = crop_crosspoints_px(PatternSpec(), CROSSPOINT_CROP)
        assert canonical[0, 0].tolist() == [8.0, 8.0] and canonical[0, 24].tolist() == [104.0, 8.0]
        np.testing.assert_array_equal(out[:, 1:].permute(0, 2, 3, 1).numpy(), np.broadcast_to(canonical, (1, 25, 25, 2)))
        assert torch.count_nonzero(out[:, 0]) == 0
        # the reference reaches the output: the fuse layer's reference half is trainable and used
        crosspoints.decoder.out.weight.normal_()
        crosspoints.fuse.weight[:, 64:].normal_()
        changed = crosspoints(crop, torch.randn(1, 3, 112, 112))
        assert not torch.allclose(changed, crosspoints(crop, reference))


def _bce(logit, target):
    return math.log(1 + math.exp(-logit)) if target else math.log(1 + math.exp(logit))


def test_localizer_loss_by_hand():
    output = torch.zeros(1, 11, 2, 3)
    cells = torch.zeros(1, 2, 3, 11)
    # marker cell (0, 1): logit 2, predictions 0; targets centre (3, 4), TL (1, 1), TR off the fabric,
    # BL (2, 0), BR (0, 0)
    output[0, 0, 0, 1] = 2.0
    cells[0, 0, 1] = torch.tensor([1, 3, 4, 1, 1, float("nan"), float("nan"), 2, 0, 0, 0])
    # marker cell (1, 2): logit -1; TL prediction (5, 5), target (5, 7): only the TL error is non-zero
    output[0, 0, 1, 2] = -1.0
    output[0, 3:5, 1, 2] = 5.0
    cells[0, 1, 2] = torch.tensor([1, 0, 0, 5, 7, 0, 0, 0, 0, 0, 0])
    # an empty cell whose (meaningless) point targets must be ignored; its logit 0.5
    output[0, 0, 1, 0] = 0.5
    cells[0, 1, 0, 1:] = 100.0
    output.requires_grad_(True)
    loss, parts = localizer_loss(output, cells)

    presence = (_bce(2.0, 1) + _bce(-1.0, 1) + _bce(0.5, 0) + 3 * _bce(0.0, 0)) / 6
    # per point: mean of squared coordinate errors over the marker cells where the point exists
    centre = (9 + 16 + 0 + 0) / 4
    tl = (1 + 1 + 0 + 4) / 4
    tr = (0 + 0) / 2  # only the second marker has TR
    bl = (4 + 0 + 0 + 0) / 4
    br = 0.0
    points = centre + tl + tr + bl + br
    assert parts["presence"].item() == pytest.approx(presence, rel=1e-6)
    assert parts["points"].item() == pytest.approx(points, rel=1e-6)
    assert loss.item() == pytest.approx(10 * presence + points / 5, rel=1e-6)
    loss.backward()
    assert torch.isfinite(output.grad).all()
    assert torch.count_nonzero(output.grad[0, 1:, 1, 0]) == 0  # empty cell: no point gradient
    assert torch.count_nonzero(output.grad[0, 5:7, 0, 1]) == 0  # NaN TR target: no gradient

    no_markers, parts = localizer_loss(torch.zeros(1, 11, 2, 3), torch.zeros(1, 2, 3, 11))
    assert no_markers.item() == pytest.approx(10 * math.log(2)) and parts["points"].item() == 0.0
    with pytest.raises(ValueError, match="cells must have shape"):
        localizer_loss(torch.zeros(1, 11, 2, 3), torch.zeros(1, 3, 2, 11))


def test_recognizer_loss_by_hand():
    logits = torch.zeros(3, 5)
    assert recognizer_loss(logits, torch.tensor([0, 4, 2])).item() == pytest.approx(math.log(5))
    logits[0, 1] = 2.0
    expected = (-math.log(math.exp(2) / (math.exp(2) + 4)) + 2 * math.log(5)) / 3
    assert recognizer_loss(logits, torch.tensor([1, 4, 2])).item() == pytest.approx(expected, rel=1e-6)
    with pytest.raises(ValueError, match="ids"):
        recognizer_loss(logits, torch.tensor([1, 4]))


def test_crosspoint_loss_by_hand():
    k = 25
    output = torch.zeros(2, 3, k, k)
    xy = torch.full((2, k, k, 2), float("nan"))
    visible = torch.zeros(2, k, k, dtype=torch.bool)
    # two visible crosspoints with known errors; one hidden crosspoint with a finite, ignored target
    visible[0, 3, 4] = visible[1, 0, 0] = True
    output[0, 0, 3, 4] = 1.5
    output[0, 1:, 3, 4] = torch.tensor([10.0, 20.0])
    xy[0, 3, 4] = torch.tensor([13.0, 20.0])
    output[1, 1:, 0, 0] = torch.tensor([8.0, 8.0])
    xy[1, 0, 0] = torch.tensor([7.0, 10.0])
    xy[1, 5, 5] = torch.tensor([500.0, 500.0])
    output.requires_grad_(True)
    loss, parts = crosspoint_loss(output, xy, visible)
    visibility = (_bce(1.5, 1) + _bce(0.0, 1) + (2 * k * k - 2) * _bce(0.0, 0)) / (2 * k * k)
    mse = (9 + 0 + 1 + 4) / 4
    assert parts["visibility"].item() == pytest.approx(visibility, rel=1e-6)
    assert parts["xy"].item() == pytest.approx(mse, rel=1e-6)
    assert loss.item() == pytest.approx(100 * visibility + mse, rel=1e-6)
    loss.backward()
    assert torch.isfinite(output.grad).all()
    assert torch.count_nonzero(output.grad[1, 1:, 5, 5]) == 0
    with pytest.raises(ValueError, match="expected xy"):
        crosspoint_loss(output, xy[:, :24], visible)


def test_crosspoint_loss_ignores_visible_crosspoints_without_a_target():
    k = 25
    output = torch.zeros(1, 3, k, k, requires_grad=True)
    xy = torch.full((1, k, k, 2), 10.0)
    xy[0, 0, 0, 1] = float("nan")  # one coordinate of a visible crosspoint: only the other counts
    xy[0, 1, 1] = float("nan")
    visible = torch.zeros(1, k, k, dtype=torch.bool)
    visible[0, :2, :2] = True
    loss, parts = crosspoint_loss(output, xy, visible)
    # 4 visible crosspoints, 8 coordinates, 3 of them NaN: the mean over the 5 others, each (0 - 10)^2
    assert parts["xy"].item() == pytest.approx(100.0)
    loss.backward()
    assert torch.isfinite(output.grad).all() and torch.count_nonzero(output.grad[0, 1:, 1, 1]) == 0


def _train(model, inputs, loss_fn, steps, lr=1e-4):
    """Adam steps on one fixed batch (batch-norm in training mode); returns the loss before and after."""
    torch.manual_seed(0)
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    model.train()
    losses = []
    for _ in range(steps + 1):
        loss = loss_fn(model(*inputs))
        losses.append(loss.item())
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return losses[0], losses[-1]


def test_localizer_training_steps_reduce_its_loss():
    generator = torch.Generator().manual_seed(1)
    images = torch.randn(2, 3, 32, 48, generator=generator)
    cells = torch.zeros(2, 4, 6, 11)
    cells[0, 1, 2] = torch.tensor([1, 3, 5, -9, -8, 14, -9, -9, 15, 15, 16])
    cells[1, 2, 4] = torch.tensor([1, 6, 2, -5, -4, 9, -5, -5, 8, 9, 9])
    cells[1, 0, 0] = torch.tensor([1, 1, 1, float("nan"), float("nan"), 9, -5, -5, 8, 9, 9])
    torch.manual_seed(0)
    before, after = _train(MarkerLocalizer(), (images,), lambda out: localizer_loss(out, cells)[0], 4)
    assert after < 0.8 * before


def test_recognizer_training_steps_reduce_its_loss():
    generator = torch.Generator().manual_seed(1)
    crops = torch.randn(2, 3, 96, 96, generator=generator)
    ids = torch.tensor([2, 0])
    torch.manual_seed(0)
    before, after = _train(MarkerRecognizer(num_ids=3), (crops,), lambda out: recognizer_loss(out, ids), 4)
    assert after < 0.8 * before


def test_crosspoint_training_steps_reduce_its_loss():
    generator = torch.Generator().manual_seed(1)
    crop = torch.randn(2, 3, 112, 112, generator=generator)
    reference = torch.randn(2, 3, 112, 112, generator=generator)
    canonical = torch.as_tensor(crop_crosspoints_px(PatternSpec(), CROSSPOINT_CROP), dtype=torch.float32)
    xy = canonical + torch.randn(2, 25, 25, 2, generator=generator)
    visible = torch.rand(2, 25, 25, generator=generator) > 0.3
    xy[~visible] = float("nan")
    torch.manual_seed(0)
    before, after = _train(CrosspointLocalizer(), (crop, reference),
                           lambda out: crosspoint_loss(out, xy, visible)[0], 4)
    # the loss is dominated by 100 x BCE of 70 % visible crosspoints; the best constant is 61.1
    assert after < before - 0.2


def _weights_file(path, factory):
    """A torchvision-layout file whose every entry differs from a fresh model's."""
    model = factory(num_classes=1000)
    generator = torch.Generator().manual_seed(3)
    with torch.no_grad():
        for value in model.state_dict().values():
            if value.is_floating_point():
                value.copy_(torch.rand(value.shape, generator=generator) + 0.5)
    torch.save(model.state_dict(), path)
    return model.state_dict()


def test_pretrained_weights_load_into_each_network(tmp_path):
    small = _weights_file(tmp_path / "resnet18.pth", resnet18)
    localizer = MarkerLocalizer(pretrained=tmp_path / "resnet18.pth")
    for key, value in localizer.backbone.state_dict().items():
        assert torch.equal(value, small[key]), key

    large = _weights_file(tmp_path / "resnet50.pth", resnet50)
    recognizer = MarkerRecognizer(num_ids=6, pretrained=str(tmp_path / "resnet50.pth"))
    assert torch.equal(recognizer.backbone.layer4[2].bn3.running_var, large["layer4.2.bn3.running_var"])
    assert recognizer.backbone.fc.weight.shape == (6, 2048)  # the 1000-class fc is not loaded

    crosspoints = CrosspointLocalizer(pretrained=tmp_path / "resnet50.pth")
    assert torch.equal(crosspoints.backbone.conv1.weight, large["conv1.weight"])
    assert torch.equal(crosspoints.reference_conv.weight, large["conv1.weight"])
    assert torch.equal(crosspoints.reference_bn.running_mean, large["bn1.running_mean"])

    with pytest.raises(ValueError, match="resnet18.pth"):
        MarkerRecognizer(num_ids=6, pretrained=tmp_path / "resnet18.pth")
