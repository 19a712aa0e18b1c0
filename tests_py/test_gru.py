"""The fused GRU gates against torch's unfused expressions (architecture.md §2.7), forward and backward."""

import numpy as np
import pytest

import mipnet
import mipnet.ops as M
from helpers import check_op, rand, require_torch

torch = require_torch()


def reset_torch(zr, hx):
    hid = zr.shape[1] // 2
    return torch.cat([torch.sigmoid(zr[:, hid:]) * hx[:, :hid], hx[:, hid:]], 1)


def update_torch(zr, q, hx, keep_x):
    hid = zr.shape[1] // 2
    z = torch.sigmoid(zr[:, :hid])
    h = (1 - z) * hx[:, :hid] + z * torch.tanh(q)
    return torch.cat([h, hx[:, hid:]], 1) if keep_x else h


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n,hid,x,h,w", [(2, 4, 6, 3, 5), (1, 8, 3, 1, 1)])
def test_gru_reset_matches_torch(n, hid, x, h, w, dtype):
    check_op([rand((n, 2 * hid, h, w), low=-3, high=3), rand((n, hid + x, h, w), seed=1)], reset_torch, M.gru_reset, dtype=dtype)


@pytest.mark.parametrize("keep_x", [False, True])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_gru_update_matches_torch(keep_x, dtype):
    n, hid, x, h, w = 2, 4, 5, 3, 4
    check_op([rand((n, 2 * hid, h, w), low=-3, high=3), rand((n, hid, h, w), seed=1, low=-3, high=3),
              rand((n, hid + x, h, w), seed=2)],
             lambda a, b, c: update_torch(a, b, c, keep_x), lambda a, b, c: M.gru_update(a, b, c, keep_x), dtype=dtype)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("kernel,padding", [((3, 3), (1, 1)), ((1, 5), (0, 2)), ((5, 1), (2, 0))])
def test_gru_candidate_matches_torch(kernel, padding, dtype):
    # conv2d over [sigmoid(r) h, x], the backward rebuilding [r h, x] from zr and hx
    n, hid, x, h, w = 2, 4, 5, 6, 7
    check_op([rand((n, 2 * hid, h, w), low=-3, high=3), rand((n, hid + x, h, w), seed=1),
              rand((3, hid + x, *kernel), seed=2), rand((3,), seed=3)],
             lambda zr, hx, wt, b: torch.nn.functional.conv2d(reset_torch(zr, hx), wt, b, padding=padding),
             lambda zr, hx, wt, b: M.gru_candidate(zr, hx, wt, b, padding), dtype=dtype)


def test_gru_step_matches_torch_conv_gru():
    # the module: stacked z/r convolution + fused gates = torch's three-convolution ConvGRU
    from reference.mipnet_torch import ConvGRU as TorchGRU
    torch.manual_seed(0)
    ref = TorchGRU(4, 6)
    ours = mipnet.model.blocks.ConvGRU(4, 6)
    ours.load_state_dict({k: v.detach().numpy() for k, v in ref.state_dict().items()})
    h, x = rand((2, 4, 5, 6)), rand((2, 6, 5, 6), seed=1)
    want = ref(torch.tensor(h), torch.tensor(x)).detach().numpy()
    got = ours(mipnet.tensor(np.concatenate([h, x], 1))).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


def test_gru_errors_name_op_and_shapes():
    with pytest.raises(RuntimeError, match=r"gru_reset.*\[1, 6, 2, 2\].*\[1, 5, 2, 3\]"):
        M.gru_reset(mipnet.tensor(rand((1, 6, 2, 2))), mipnet.tensor(rand((1, 5, 2, 3))))
    with pytest.raises(RuntimeError, match=r"gru_update.*q=\[1, 2, 2, 2\]"):
        M.gru_update(mipnet.tensor(rand((1, 6, 2, 2))), mipnet.tensor(rand((1, 2, 2, 2))), mipnet.tensor(rand((1, 5, 2, 2))))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_attention_gate_matches_torch(dtype):
    def gate_torch(local, glob, x, y):
        w = torch.sigmoid(local + glob)
        return w * x + (1 - w) * y

    check_op([rand((2, 3, 4, 5), low=-3, high=3), rand((2, 3, 1, 1), seed=1), rand((2, 3, 4, 5), seed=2),
              rand((2, 3, 4, 5), seed=3)], gate_torch, M.attention_gate, dtype=dtype)
