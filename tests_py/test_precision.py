"""float32 accuracy in training mode, against torch's float32 (both measured from float64 results).

Training-mode BatchNorms in the encoder's iAFF normalise a handful of globally pooled values, so a rounding
error in a spatial mean reaches the disparity multiplied many times; ``python -m mipnet.bench precision``
prints the whole network's table. These tests keep the two places where mipnet once lost accuracy: the
spatial mean over a large map (it summed ~10^4 values per lane in float32), and a training-mode encoder
stage at 384x512, which carries that mean.
"""

import numpy as np

import mipnet
from mipnet.autograd import no_grad
from mipnet.bench.precision import batch
from mipnet.tensor import Tensor
from helpers import require_torch

torch = require_torch()
from reference import MIPNetTorch  # noqa: E402


def _mean_abs_error(value: np.ndarray, exact: np.ndarray) -> float:
    return float(np.mean(np.abs(value.astype(np.float64) - exact)))


def test_spatial_mean_of_a_large_map_is_as_accurate_as_torchs():
    # a 1/2-resolution activation map of a 384x512 batch of 4, positive like the ReLU outputs iAFF pools
    x = np.random.default_rng(0).uniform(0.0, 3.0, (4, 64, 192, 256)).astype(np.float32)
    exact = x.astype(np.float64).mean(axis=(2, 3), keepdims=True)
    ours = mipnet.ops.mean(Tensor(x), (2, 3), keepdim=True).numpy()
    theirs = torch.from_numpy(x).mean(dim=(2, 3), keepdim=True).numpy()
    err, torch_err = _mean_abs_error(ours, exact), _mean_abs_error(theirs, exact)
    print(f"\n[precision] spatial mean of (4,64,192,256): mipnet {err:.2e}, torch {torch_err:.2e}")
    assert err <= torch_err


def test_training_mode_encoder_layer1_float32_error_is_at_most_torchs():
    """The encoder's first residual stage in training mode on a 384x512 batch of 2 (4 images): mipnet's and
    torch's float32 outputs against their float64 ones, from the same float64 stem output."""
    torch.manual_seed(0)
    ref = MIPNetTorch()
    state = {k: v.numpy().copy() for k, v in ref.state_dict().items()}
    left, right, *_ = batch(2, 384, 512)
    images = 2 * (np.concatenate([left, right]) / 255) - 1
    layers = {}
    for dtype in (np.float32, np.float64):
        model = mipnet.MIPNet()
        model.load_state_dict(state)
        if dtype == np.float64:
            model.double()
        layers[dtype] = model.train().encoder
    with no_grad():
        stem = layers[np.float64].stem(Tensor(images)).numpy()
        exact = layers[np.float64].layer1(Tensor(stem)).numpy()
        ours = layers[np.float32].layer1(Tensor(stem.astype(np.float32))).numpy()
    ref.train()
    with torch.no_grad():
        theirs = ref.encoder.layer1(torch.tensor(stem, dtype=torch.float32)).numpy()
        theirs_exact = ref.double().encoder.layer1(torch.tensor(stem)).numpy()
    err = _mean_abs_error(ours, exact) / np.mean(np.abs(exact))
    torch_err = _mean_abs_error(theirs, theirs_exact) / np.mean(np.abs(theirs_exact))
    print(f"\n[precision] encoder.layer1 training mode, relative: mipnet {err:.2e}, torch {torch_err:.2e}")
    # measured 0.9-1.1x torch's (mipnet's Winograd 3x3 transforms round about 4x more than a direct
    # convolution, its reductions less); before the blocked f64 spatial mean, 2x
    assert err <= 1.3 * torch_err
