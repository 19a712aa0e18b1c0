"""Stereo datasets: readers of the public sets, the one registry of names, generated pairs (planar ones,
natural-statistics scenes, pairs made from real photographs), generated moving-camera stereo videos, real evaluation
pairs and the bundled example."""

from .datasets import (
    ETH3D,
    KITTI,
    ConcatDataset,
    CREStereo,
    Dataset,
    FolderPairs,
    MiddEval3,
    Middlebury2014,
    RepeatDataset,
    SceneFlow,
    StereoDataset,
)
from ..utils.data.dataloader import DataLoader, default_collate
from .example import example_pair
from .photo_pairs import PhotoStereo, make_photo_pair
from .real import REAL_SETS, RealPairs, fetch_real, real_data_dir
from .scenes import GENERATOR_VERSION, SceneStereo, make_scene
from .sequences import SequenceSet, make_sequence
from .synthetic import SyntheticStereo, make_pair, synthetic_underwater_pairs

__all__ = [
    "Dataset",
    "ConcatDataset",
    "RepeatDataset",
    "StereoDataset",
    "SceneFlow",
    "Middlebury2014",
    "MiddEval3",
    "ETH3D",
    "KITTI",
    "CREStereo",
    "FolderPairs",
    "DataLoader",
    "default_collate",
    "SyntheticStereo",
    "make_pair",
    "synthetic_underwater_pairs",
    "SceneStereo",
    "make_scene",
    "SequenceSet",
    "make_sequence",
    "GENERATOR_VERSION",
    "RealPairs",
    "REAL_SETS",
    "fetch_real",
    "real_data_dir",
    "example_pair",
    "PhotoStereo",
    "make_photo_pair",
]
