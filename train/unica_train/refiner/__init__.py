"""The splat refiner: its network (model.py), what it sees and makes of a frame's splats
(frames.py), a run's config (config.py), its training (training.py) and evaluation
(evaluation.py); `python -m unica_train.refiner` trains it (__main__.py)."""

from .config import RefinerTrainConfig, held_out_keys, train_config
from .evaluation import composite, evaluate, evaluate_bundle
from .frames import Frames, apply, drawn_level, features, frame_inputs, refined
from .model import (FEATURES, ORDERS, OUTPUTS, Block, Refiner, RefinerConfig, flops, from_bundle, hilbert, parameter_count,
                    patch_attention,
                    pool_groups, quantise, segment_mean, serialise, state_from, z_order)
from .training import add_to_bundle, frame_generator, init_from_bundle, train



__all__ = [
    "Block",
    "FEATURES",
    "Frames",
    "ORDERS",
    "OUTPUTS",
    "Refiner",
    "RefinerConfig",
    "RefinerTrainConfig",
    "add_to_bundle",
    "apply",
    "composite",
    "drawn_level",
    "evaluate",
    "evaluate_bundle",
    "features",
    "flops",
    "frame_generator",
    "frame_inputs",
    "from_bundle",
    "held_out_keys",
    "hilbert",
    "init_from_bundle",
    "parameter_count",
    "patch_attention",
    "pool_groups",
    "quantise",
    "refined",
    "segment_mean",
    "serialise",
    "state_from",
    "train",
    "train_config",
    "z_order",
]
