"""Modules and layers (``torch.nn``)."""

from . import functional, init, utils
from .layers import BatchNorm2d, Conv2d, InstanceNorm2d, Sequential
from .module import IncompatibleKeys, Module, Parameter

__all__ = ["Module", "Parameter", "IncompatibleKeys", "Conv2d", "BatchNorm2d", "InstanceNorm2d", "Sequential",
           "functional", "init", "utils"]
