"""mipnet.optim and mipnet.optim.lr_scheduler show only their API: not numpy, math or typing names."""

import typing

import mipnet.optim
import mipnet.optim.lr_scheduler


def test_dir_and_all_are_the_api():
    api = ["AdamW", "OneCycleLR", "Optimizer", "SGD", "clip_grad_norm_", "lr_scheduler"]
    assert sorted(mipnet.optim.__all__) == api and dir(mipnet.optim) == api
    assert mipnet.optim.lr_scheduler.__all__ == ["OneCycleLR"] and dir(mipnet.optim.lr_scheduler) == ["OneCycleLR"]
    namespace: dict = {}
    exec("from mipnet.optim import *", namespace)
    assert {"np", "math", "Any", "Iterable"}.isdisjoint(namespace) and set(api) <= set(namespace)


def test_the_scheduler_annotation_resolves_to_the_optimizer():
    hints = typing.get_type_hints(mipnet.optim.lr_scheduler.OneCycleLR.__init__)
    assert hints["optimizer"] is mipnet.optim.Optimizer
