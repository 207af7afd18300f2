"""`benchmarks/rounding.py`: chosen parts of a checkpoint rounded coarser, the rest untouched."""

import pytest
import torch

from networks.checkpoint import dequantize_weights, quantize_weights


@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("rounding")


def test_only_the_named_part_is_rounded_and_8_bits_is_the_compact_checkpoints_rounding(bench):
    torch.manual_seed(0)
    state = {"head.conv.weight": torch.randn(8, 4, 3, 3), "head.out.weight": torch.randn(3, 8, 1, 1),
             "head.out.bias": torch.randn(3), "backbone.conv1.weight": torch.randn(4, 3, 3, 3),
             "backbone.bn1.num_batches_tracked": torch.tensor(5)}
    head = bench.rounded_state(state, "head", 4)
    for key in ("head.out.bias", "backbone.conv1.weight", "backbone.bn1.num_batches_tracked"):
        assert torch.equal(head[key], state[key]), key
    for key in ("head.conv.weight", "head.out.weight"):
        step = state[key].abs().amax(dim=(1, 2, 3), keepdim=True) / 7  # 4 bits: 7 levels each side
        assert not torch.equal(head[key], state[key])
        assert torch.all((head[key] - state[key]).abs() <= step / 2 + 1e-6), key
        assert len(torch.unique(head[key][0])) <= 15
    # a prefix names whole key components: "head.o" is no part, "head.out" is
    assert all(torch.equal(bench.rounded_state(state, "head.o", 4)[k], v) for k, v in state.items())
    assert torch.equal(bench.rounded_state(state, "head.out", 4)["head.conv.weight"], state["head.conv.weight"])
    assert all(torch.equal(bench.rounded_state(state, "none", 2)[k], v) for k, v in state.items())
    # at 8 bits it is what a compact checkpoint stores
    model, scales = quantize_weights(state)
    compact = dequantize_weights(model, scales)
    eight = bench.rounded_state(state, "backbone", 8)
    assert torch.allclose(eight["backbone.conv1.weight"], compact["backbone.conv1.weight"], atol=1e-6)
