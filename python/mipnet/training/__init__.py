"""Training MIPNet: ``fit`` (the loop behind ``mipnet train``), presets, augmentation, checkpoints, logs."""

from .legacy import TrainConfig, random_crop, train

__all__ = ["TrainConfig", "random_crop", "train"]
