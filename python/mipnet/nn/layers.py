"""Layers with torch.nn's names, arguments and parameter names."""

from __future__ import annotations

import numpy as np

from .. import ops
from ..errors import ArgumentError, ShapeError
from ..tensor import Tensor
from . import init
from .module import Module, Parameter


class Conv2d(Module):
    """2-D convolution (``torch.nn.Conv2d``) with torch's default initialisation."""

    def __init__(self, in_channels: int, out_channels: int, kernel_size, stride=1, padding=0, bias: bool = True):
        super().__init__()
        kh, kw = ops._common.pair(kernel_size, "kernel_size", "Conv2d")
        self.in_channels, self.out_channels = in_channels, out_channels
        self.kernel_size, self.stride, self.padding = (kh, kw), stride, padding
        self.weight = Parameter(np.zeros((out_channels, in_channels, kh, kw), np.float32))
        self.bias = Parameter(np.zeros(out_channels, np.float32)) if bias else None
        init.conv_default_(self.weight, self.bias)

    def forward(self, x: Tensor) -> Tensor:
        return ops.conv2d(x, self.weight, self.bias, self.stride, self.padding)

    def forward_relu(self, x: Tensor) -> Tensor:
        """ReLU(self(x)) as one op: the ReLU runs in the convolution's epilogue, with no extra pass."""
        return ops.conv2d_relu(x, self.weight, self.bias, self.stride, self.padding)

    def extra_repr(self) -> str:
        return f"{self.in_channels}, {self.out_channels}, kernel_size={self.kernel_size}, stride={self.stride}, padding={self.padding}"


class BatchNorm2d(Module):
    """Batch normalisation over (N, H, W) per channel (``torch.nn.BatchNorm2d``, affine, tracking stats)."""

    def __init__(self, num_features: int, eps: float = 1e-5, momentum: float = 0.1):
        super().__init__()
        self.num_features, self.eps, self.momentum = num_features, eps, momentum
        self.weight = Parameter(np.ones(num_features, np.float32))
        self.bias = Parameter(np.zeros(num_features, np.float32))
        self.register_buffer("running_mean", np.zeros(num_features, np.float32))
        self.register_buffer("running_var", np.ones(num_features, np.float32))
        self.register_buffer("num_batches_tracked", np.zeros((), np.int64))

    def forward(self, x: Tensor) -> Tensor:
        if self.training:
            self._buffers["num_batches_tracked"] = self.num_batches_tracked + 1
        return ops.batch_norm(x, self.running_mean, self.running_var, self.weight, self.bias,
                              training=self.training, momentum=self.momentum, eps=self.eps)

    def folded(self, conv: Conv2d) -> tuple[Tensor, Tensor]:
        """The weight and bias of one convolution equal to ``self(conv(x))`` in eval mode, where this
        normalisation is the affine map y = s·(x − μ) + β per channel, s = γ / sqrt(σ² + eps):
        W' = s·W (per output channel) and b' = s·(b − μ) + β. Built from Tensor ops, so gradients
        reach W, b, γ and β as through the two layers."""
        if self.training:
            raise ArgumentError("BatchNorm2d.folded: only an eval-mode normalisation (running statistics) folds "
                               "into a convolution")
        if conv.out_channels != self.num_features:
            raise ShapeError(f"BatchNorm2d.folded: a convolution with {conv.out_channels} output channels "
                               f"into a normalisation of {self.num_features}")
        dtype = self.weight.data.dtype
        inv_std = (1.0 / np.sqrt(self.running_var.astype(np.float64) + self.eps)).astype(dtype)
        scale = self.weight * inv_std
        weight = conv.weight * scale.reshape(-1, 1, 1, 1)
        shift = -self.running_mean.astype(dtype) if conv.bias is None else conv.bias - self.running_mean.astype(dtype)
        return weight, scale * shift + self.bias

    def extra_repr(self) -> str:
        return f"{self.num_features}, eps={self.eps}, momentum={self.momentum}"


class InstanceNorm2d(Module):
    """Instance normalisation without affine parameters or running stats (``torch.nn.InstanceNorm2d``)."""

    def __init__(self, num_features: int, eps: float = 1e-5):
        super().__init__()
        self.num_features, self.eps = num_features, eps

    def forward(self, x: Tensor) -> Tensor:
        return ops.instance_norm(x, eps=self.eps)

    def extra_repr(self) -> str:
        return f"{self.num_features}, eps={self.eps}"


class Sequential(Module):
    """Modules applied in order, registered as "0", "1", ... (``torch.nn.Sequential``)."""

    def __init__(self, *modules: Module):
        super().__init__()
        for i, m in enumerate(modules):
            self.add_module(str(i), m)

    def forward(self, x):
        for m in self._modules.values():
            x = m(x)
        return x

    def __getitem__(self, i: int) -> Module:
        return list(self._modules.values())[i]

    def __len__(self) -> int:
        return len(self._modules)
