"""Data processing after augmentation, each step chosen by NAME from DATA_PROCESSOR (OpenPCDet's names):
range masking, point shuffling and voxelisation with spconv's PointToVoxel (coords in z, y, x); and ours,
fold_box_headings (ground-truth boxes as the same rectangles in a canonical form, FOLD quarter or half)."""
from __future__ import annotations

import numpy as np
import torch

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.geometry.boxes import FOLDS, boxes_to_corners_3d, fold_box_headings
from pcdet_memslidar.grid import grid_size


def mask_points_by_range(points: np.ndarray, limit_range: np.ndarray) -> np.ndarray:
    """(N,) bool: points (N, 3+) inside [x0, y0, z0, x1, y1, z1] (bounds included)."""
    return ((points[:, :3] >= limit_range[:3]) & (points[:, :3] <= limit_range[3:6])).all(axis=1)


def take_points(data_dict: dict, selection: np.ndarray) -> None:
    """Keep the points picked by `selection` (a mask or indices), and their point_times where the frame has them."""
    for key in ("points", "point_times"):
        if key in data_dict:
            data_dict[key] = data_dict[key][selection]


def mask_boxes_outside_range(boxes: np.ndarray, limit_range: np.ndarray, min_num_corners: int = 1) -> np.ndarray:
    """(M,) bool: boxes (M, 7+) with at least `min_num_corners` corners inside the range (OpenPCDet's rule)."""
    if len(boxes) == 0:
        return np.zeros(0, dtype=bool)
    corners = boxes_to_corners_3d(boxes[:, :7])
    inside = ((corners >= limit_range[:3]) & (corners <= limit_range[3:6])).all(axis=2)
    return inside.sum(axis=1) >= min_num_corners


class VoxelGenerator:
    """spconv PointToVoxel on the CPU, returning numpy copies (spconv reuses its output buffers)."""

    def __init__(self, voxel_size, point_cloud_range, num_point_features: int, max_num_points_per_voxel: int,
                 max_num_voxels: int):
        from spconv.pytorch.utils import PointToVoxel
        self._generator = PointToVoxel(vsize_xyz=list(map(float, voxel_size)),
                                       coors_range_xyz=list(map(float, point_cloud_range)),
                                       num_point_features=num_point_features, max_num_voxels=max_num_voxels,
                                       max_num_points_per_voxel=max_num_points_per_voxel, device=torch.device("cpu"))

    def generate(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, C) float32 points -> voxels (V, P, C) float32, coords (V, 3) int32 [z, y, x], num_points (V,) int32."""
        voxels, coords, num_points = self._generator(torch.from_numpy(np.ascontiguousarray(points, dtype=np.float32)))
        return voxels.numpy().copy(), coords.numpy().copy(), num_points.numpy().copy()


class DataProcessor:
    """Runs the DATA_PROCESSOR steps; `mode` is 'train' or 'test' (selects per-mode settings)."""

    def __init__(self, processor_configs, point_cloud_range, training: bool, num_point_features: int):
        self.point_cloud_range = np.asarray(point_cloud_range, dtype=np.float32)
        self.training = training
        self.mode = "train" if training else "test"
        self.num_point_features = num_point_features
        self.grid_size = self.voxel_size = None
        self.queue = []
        for config in processor_configs:
            build = getattr(self, f"_build_{config.NAME}", None)
            if build is None:
                known = sorted(name[len("_build_"):] for name in dir(self) if name.startswith("_build_"))
                raise ConfigError(f"DATA_PROCESSOR: unknown step {config.NAME!r}; known: {known}")
            self.queue.append(build(config))

    def forward(self, data_dict: dict, rng: np.random.Generator) -> dict:
        """Apply every step to data_dict (points (N, C), optional gt_boxes (M, 8) and gt_names (M,))."""
        for step in self.queue:
            data_dict = step(data_dict, rng)
        return data_dict

    def _build_mask_points_and_boxes_outside_range(self, config):
        remove_outside_boxes = bool(config.get("REMOVE_OUTSIDE_BOXES", True))

        def mask(data_dict, rng):
            take_points(data_dict, mask_points_by_range(data_dict["points"], self.point_cloud_range))
            if data_dict.get("gt_boxes") is not None and remove_outside_boxes and self.training:
                keep = mask_boxes_outside_range(data_dict["gt_boxes"], self.point_cloud_range)
                data_dict["gt_boxes"] = data_dict["gt_boxes"][keep]
                if "gt_names" in data_dict:
                    data_dict["gt_names"] = data_dict["gt_names"][keep]
            return data_dict
        return mask

    def _build_fold_box_headings(self, config):
        form = config.get("FOLD", FOLDS[0])  # checked at load (grid.check_config_grid)

        def fold(data_dict, rng):
            if data_dict.get("gt_boxes") is not None:
                data_dict["gt_boxes"] = fold_box_headings(data_dict["gt_boxes"], form)
            return data_dict
        return fold

    def _build_shuffle_points(self, config):
        enabled = bool(config.SHUFFLE_ENABLED[self.mode])

        def shuffle(data_dict, rng):
            if enabled:
                take_points(data_dict, rng.permutation(len(data_dict["points"])))
            return data_dict
        return shuffle

    def _build_transform_points_to_voxels(self, config):
        self.voxel_size = np.asarray(config.VOXEL_SIZE, dtype=np.float32)
        self.grid_size = grid_size(self.point_cloud_range, config.VOXEL_SIZE)
        generator = VoxelGenerator(config.VOXEL_SIZE, self.point_cloud_range, self.num_point_features,
                                   int(config.MAX_POINTS_PER_VOXEL), int(config.MAX_NUMBER_OF_VOXELS[self.mode]))

        def voxelize(data_dict, rng):
            voxels, coords, num_points = generator.generate(data_dict["points"])
            data_dict.update(voxels=voxels, voxel_coords=coords, voxel_num_points=num_points)
            return data_dict
        return voxelize
