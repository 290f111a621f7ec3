"""SECOND and CenterPoint under their OpenPCDet names and state-dict layout; runs on CPU and GPU.

Public API:
    build_network(model_cfg, num_class, dataset) -> nn.Module    (model chosen by model_cfg.NAME)
    load_data_to_device(batch_dict, device) -> batch_dict          (numpy arrays -> tensors, in place)
    is_learned(model_cfg) -> bool                                   (False: no weights, no training, no checkpoint)
    DETECTORS: MODEL.NAME -> detector class (its display_name names it in reports); register_detector(cls) adds one
    per-stage registries in models.detector (DENSE_HEADS, register_dense_head)
"""
from __future__ import annotations

import numpy as np
import torch

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.models.background_subtraction import BackgroundSubtraction
from pcdet_memslidar.models.detector import CenterPoint, SECONDNet, register

DETECTORS = {"SECONDNet": SECONDNet, "CenterPoint": CenterPoint, "BackgroundSubtraction": BackgroundSubtraction}
_HOST_KEYS = {"frame_id", "metadata", "calib", "image_shape", "gt_names", "db_flag"}  # left as they are


def register_detector(detector: type[torch.nn.Module]) -> type[torch.nn.Module]:
    """Make `detector` the MODEL.NAME of its class name (a class decorator); it needs a `display_name`, its name in
    reports."""
    if not isinstance(getattr(detector, "display_name", None), str):
        raise ValueError(f"{detector.__qualname__}: set the class attribute display_name (its name in reports, "
                         f"e.g. 'SECOND' for SECONDNet) before registering it")
    return register(DETECTORS, "MODEL.NAME", detector)


def build_network(model_cfg, num_class: int, dataset) -> torch.nn.Module:
    """The detector named by model_cfg.NAME; `dataset` provides point_feature_encoder.num_point_features,
    point_cloud_range (6,), voxel_size (3,) [m] (its grid is checked against model_cfg) and class_names."""
    if model_cfg.get("NAME") not in DETECTORS:
        raise ConfigError(f"MODEL.NAME is {model_cfg.get('NAME')!r}; this package provides {', '.join(DETECTORS)}")
    return DETECTORS[model_cfg.NAME](model_cfg=model_cfg, num_class=num_class, dataset=dataset)


def is_learned(model_cfg) -> bool:
    """Whether model_cfg.NAME's detector has weights to train (BackgroundSubtraction has none)."""
    return getattr(DETECTORS.get(model_cfg.get("NAME")), "learned", True)


def load_data_to_device(batch_dict: dict, device: torch.device | str) -> dict:
    """Numeric numpy arrays -> float32 tensors on `device` (voxel_coords and voxel_num_points as int32);
    strings, frame ids and metadata stay as they are."""
    for key, value in batch_dict.items():
        if key in _HOST_KEYS or not isinstance(value, np.ndarray) or value.dtype.kind not in "biuf":
            continue
        dtype = torch.int32 if key in ("voxel_coords", "voxel_num_points") else torch.float32
        batch_dict[key] = torch.from_numpy(value).to(device=device, dtype=dtype)
    return batch_dict
