"""``Module`` and ``Parameter`` with torch's habits: registration order, dotted names, state dicts."""

from __future__ import annotations

from collections import OrderedDict
from typing import Any, Iterator, NamedTuple

import numpy as np

from ..errors import ShapeError
from ..tensor import Tensor, _as_float_array


class Parameter(Tensor):
    """A tensor that is a module's learnable weight (``requires_grad`` defaults to True)."""

    __slots__ = ()

    def __init__(self, data: Any, requires_grad: bool = True):
        super().__init__(data.data if isinstance(data, Tensor) else data, requires_grad=requires_grad)

    def __repr__(self) -> str:
        return "Parameter containing:\n" + super().__repr__()


class IncompatibleKeys(NamedTuple):
    """What ``load_state_dict`` found missing from, and unexpected in, a state dict."""

    missing_keys: list[str]
    unexpected_keys: list[str]


class Module:
    """Base class of layers and models (``torch.nn.Module``).

    Parameters, buffers (numpy arrays: BatchNorm running statistics) and sub-modules assigned as
    attributes are registered in assignment order; names join with "." as in torch, so state dicts
    move between mipnet and PyTorch unchanged.
    """

    def __init__(self) -> None:
        object.__setattr__(self, "_parameters", OrderedDict())
        object.__setattr__(self, "_buffers", OrderedDict())
        object.__setattr__(self, "_modules", OrderedDict())
        object.__setattr__(self, "training", True)

    # ---- registration -----------------------------------------------------------------------------
    def __setattr__(self, name: str, value: Any) -> None:
        if isinstance(value, Parameter):
            self._parameters[name] = value
        elif isinstance(value, Module):
            self._modules[name] = value
        elif name in self._buffers:
            self._buffers[name] = value
        else:
            object.__setattr__(self, name, value)

    def __getattr__(self, name: str) -> Any:
        for store in ("_parameters", "_buffers", "_modules"):
            d = self.__dict__.get(store)
            if d is not None and name in d:
                return d[name]
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")

    def register_buffer(self, name: str, array: np.ndarray) -> None:
        """A named array saved in the state dict but not trained (e.g. running statistics)."""
        self._buffers[name] = array

    def add_module(self, name: str, module: "Module") -> None:
        """Registers a sub-module under any name (also Python keywords such as ``global``)."""
        self._modules[name] = module

    # ---- traversal ---------------------------------------------------------------------------------
    def named_modules(self, prefix: str = "") -> Iterator[tuple[str, "Module"]]:
        yield prefix, self
        for name, m in self._modules.items():
            yield from m.named_modules(f"{prefix}.{name}" if prefix else name)

    def modules(self) -> Iterator["Module"]:
        for _, m in self.named_modules():
            yield m

    def children(self) -> Iterator["Module"]:
        yield from self._modules.values()

    def named_parameters(self, prefix: str = "") -> Iterator[tuple[str, Parameter]]:
        for mod_name, m in self.named_modules(prefix):
            for name, p in m._parameters.items():
                yield (f"{mod_name}.{name}" if mod_name else name), p

    def parameters(self) -> Iterator[Parameter]:
        for _, p in self.named_parameters():
            yield p

    def named_buffers(self, prefix: str = "") -> Iterator[tuple[str, np.ndarray]]:
        for mod_name, m in self.named_modules(prefix):
            for name, b in m._buffers.items():
                yield (f"{mod_name}.{name}" if mod_name else name), b

    # ---- state --------------------------------------------------------------------------------------
    def state_dict(self) -> "OrderedDict[str, np.ndarray]":
        """Copies of every parameter and buffer, keyed by dotted name, in torch's order (per module:
        parameters, then buffers; modules depth-first)."""
        out: OrderedDict[str, np.ndarray] = OrderedDict()
        for mod_name, m in self.named_modules():
            pre = f"{mod_name}." if mod_name else ""
            for name, p in m._parameters.items():
                out[pre + name] = p.data.copy()
            for name, b in m._buffers.items():
                out[pre + name] = np.array(b, copy=True)
        return out

    def load_state_dict(self, state_dict: Any, strict: bool = True) -> IncompatibleKeys:
        """Copies arrays (numpy, mipnet or torch tensors) into parameters and buffers by name.

        A leading ``module.`` (``nn.DataParallel``) is stripped, and a dict wrapping the weights under
        ``state_dict`` or ``model`` is unwrapped. Shapes must match. With ``strict`` missing or
        unexpected keys raise ``RuntimeError`` listing them; otherwise they are returned.
        """
        sd = _unwrap_state_dict(state_dict)
        own = self.state_dict()
        missing = [k for k in own if k not in sd]
        unexpected = [k for k in sd if k not in own]
        if strict and (missing or unexpected):
            raise RuntimeError(
                f"Error(s) in loading state_dict for {type(self).__name__}: "
                f"missing keys: {missing}; unexpected keys: {unexpected}")
        targets = dict(self._state_targets())
        for key in own:
            if key not in sd:
                continue
            value = _to_numpy(sd[key])
            kind, module, name = targets[key]
            current = module._parameters[name].data if kind == "param" else module._buffers[name]
            if tuple(value.shape) != tuple(np.shape(current)):
                raise ShapeError(f"load_state_dict: size mismatch for {key}: checkpoint {list(value.shape)}, "
                                 f"model {list(np.shape(current))}")
            if kind == "param":
                module._parameters[name].data = _as_float_array(value.astype(current.dtype, copy=True))
            else:
                module._buffers[name] = np.array(value, dtype=np.asarray(current).dtype, copy=True)
        return IncompatibleKeys(missing, unexpected)

    def _state_targets(self) -> Iterator[tuple[str, tuple[str, "Module", str]]]:
        for mod_name, m in self.named_modules():
            pre = f"{mod_name}." if mod_name else ""
            for name in m._parameters:
                yield pre + name, ("param", m, name)
            for name in m._buffers:
                yield pre + name, ("buffer", m, name)

    # ---- modes and dtypes ----------------------------------------------------------------------------
    def train(self, mode: bool = True) -> "Module":
        for m in self.modules():
            object.__setattr__(m, "training", mode)
        return self

    def eval(self) -> "Module":
        return self.train(False)

    def requires_grad_(self, flag: bool = True) -> "Module":
        for p in self.parameters():
            p.requires_grad = flag
        return self

    def zero_grad(self, set_to_none: bool = True) -> None:
        for p in self.parameters():
            p.grad = None if set_to_none or p.grad is None else p.grad.zero_()

    def _cast(self, dtype: Any) -> "Module":
        for m in self.modules():
            for p in m._parameters.values():
                p.data = p.data.astype(dtype)
                p.grad = None
            for name, b in m._buffers.items():
                if np.issubdtype(np.asarray(b).dtype, np.floating):
                    m._buffers[name] = np.asarray(b).astype(dtype)
        return self

    def double(self) -> "Module":
        """Every floating parameter and buffer to float64."""
        return self._cast(np.float64)

    def float(self) -> "Module":
        """Every floating parameter and buffer to float32."""
        return self._cast(np.float32)

    def num_parameters(self) -> int:
        return int(sum(p.data.size for p in self.parameters()))

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.forward(*args, **kwargs)

    def forward(self, *args: Any, **kwargs: Any) -> Any:
        raise NotImplementedError(f"{type(self).__name__}.forward")

    def extra_repr(self) -> str:
        return ""

    def __repr__(self) -> str:
        lines = [f"{type(self).__name__}({self.extra_repr()}"]
        for name, m in self._modules.items():
            lines.append("  (" + name + "): " + repr(m).replace("\n", "\n  "))
        return "\n".join(lines) + ")" if len(lines) > 1 else lines[0] + ")"


def _to_numpy(v: Any) -> np.ndarray:
    if isinstance(v, Tensor):
        return v.data
    if hasattr(v, "detach") and hasattr(v, "cpu"):  # a torch tensor
        return v.detach().cpu().numpy()
    return np.asarray(v)


def _unwrap_state_dict(sd: Any) -> dict:
    for wrapper in ("state_dict", "model"):
        if isinstance(sd, dict) and wrapper in sd and isinstance(sd[wrapper], dict):
            sd = sd[wrapper]
    if sd and all(k.startswith("module.") for k in sd):
        sd = {k[len("module."):]: v for k, v in sd.items()}
    return dict(sd)
