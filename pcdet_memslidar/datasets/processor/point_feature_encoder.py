"""Point feature encoding (OpenPCDet's POINT_FEATURE_ENCODING): choose and order the per-point features."""
from __future__ import annotations

import numpy as np

from pcdet_memslidar.errors import ConfigError


class PointFeatureEncoder:
    """absolute_coordinates_encoding: (N, len(src_feature_list)) -> (N, len(used_feature_list)), x, y, z first."""

    def __init__(self, config, point_cloud_range=None):
        self.point_encoding_config = config
        self.point_cloud_range = point_cloud_range
        self.used_feature_list = list(config.used_feature_list)
        self.src_feature_list = list(config.src_feature_list)
        if config.encoding_type != "absolute_coordinates_encoding":
            raise ConfigError(f"POINT_FEATURE_ENCODING.encoding_type {config.encoding_type!r} is not supported; "
                              f"use absolute_coordinates_encoding")
        if self.used_feature_list[:3] != ["x", "y", "z"] or self.src_feature_list[:3] != ["x", "y", "z"]:
            raise ConfigError("POINT_FEATURE_ENCODING: used_feature_list and src_feature_list must start with "
                              f"x, y, z; got {self.used_feature_list} and {self.src_feature_list}")
        missing = [name for name in self.used_feature_list if name not in self.src_feature_list]
        if missing:
            raise ConfigError(f"POINT_FEATURE_ENCODING: used features {missing} are not in src_feature_list "
                              f"{self.src_feature_list}")
        self.columns = [self.src_feature_list.index(name) for name in self.used_feature_list]

    @property
    def num_point_features(self) -> int:
        return len(self.used_feature_list)

    def forward(self, data_dict: dict) -> dict:
        """Select the used columns of data_dict['points']; sets use_lead_xyz = True."""
        points = data_dict["points"]
        if points.shape[1] != len(self.src_feature_list):
            raise ValueError(f"points have {points.shape[1]} columns but src_feature_list names "
                             f"{len(self.src_feature_list)}: {self.src_feature_list}")
        data_dict["points"] = np.ascontiguousarray(points[:, self.columns])
        data_dict["use_lead_xyz"] = True
        return data_dict
