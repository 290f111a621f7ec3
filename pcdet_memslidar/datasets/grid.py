"""Voxel-grid rules of SECOND: which point-cloud range / voxel size pairs the network can take.

VoxelBackBone8x turns 41 z cells into 2 (so z range / voxel = 40, the sparse shape adds one cell); the anchor
generator uses grid // 8 while the strided sparse convs round up, and BaseBEVBackbone halves and doubles the BEV
map once more, so the x and y cell counts must be multiples of 16 (OpenPCDet issues #634, #666, #1162).
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError

Z_CELLS = 40
XY_MULTIPLE = 16


def grid_size(point_cloud_range, voxel_size) -> np.ndarray:
    """(3,) int64 cell counts (x, y, z) of the range [x0, y0, z0, x1, y1, z1] in voxels (vx, vy, vz) [m].

    ConfigError when the range is empty or not a whole number of voxels.
    """
    point_cloud_range = np.asarray(point_cloud_range, dtype=np.float64)
    voxel_size = np.asarray(voxel_size, dtype=np.float64)
    if point_cloud_range.shape != (6,) or voxel_size.shape != (3,):
        raise ConfigError(f"POINT_CLOUD_RANGE needs 6 numbers and VOXEL_SIZE 3, got {point_cloud_range.tolist()} "
                          f"and {voxel_size.tolist()}")
    span = point_cloud_range[3:] - point_cloud_range[:3]
    if (span <= 0).any() or (voxel_size <= 0).any():
        raise ConfigError(f"POINT_CLOUD_RANGE {point_cloud_range.tolist()} must have max > min and VOXEL_SIZE "
                          f"{voxel_size.tolist()} must be positive")
    cells = span / voxel_size
    rounded = np.round(cells)
    if not np.allclose(cells, rounded, rtol=0, atol=1e-4):
        raise ConfigError(f"POINT_CLOUD_RANGE {point_cloud_range.tolist()} is not a whole number of voxels of "
                          f"{voxel_size.tolist()}: {np.round(cells, 4).tolist()} cells (x, y, z)")
    return rounded.astype(np.int64)


def check_second_grid(point_cloud_range, voxel_size) -> np.ndarray:
    """(3,) cell counts (x, y, z) after checking SECOND's rules; ConfigError with sizes that would fit otherwise."""
    point_cloud_range = np.asarray(point_cloud_range, dtype=np.float64)
    voxel_size = np.asarray(voxel_size, dtype=np.float64)
    span = point_cloud_range[3:] - point_cloud_range[:3]
    try:
        cells = grid_size(point_cloud_range, voxel_size)
    except ConfigError as error:
        raise ConfigError(f"{error}. {_fitting_sizes(point_cloud_range, voxel_size)}") from None
    if cells[2] == Z_CELLS and cells[0] % XY_MULTIPLE == 0 and cells[1] % XY_MULTIPLE == 0:
        return cells
    raise ConfigError(
        f"the voxel grid {cells.tolist()} (x, y, z cells of range {point_cloud_range.tolist()}, span "
        f"{np.round(span, 4).tolist()} m, voxel {voxel_size.tolist()}) does not fit SECOND: z must have exactly "
        f"{Z_CELLS} cells and x, y multiples of {XY_MULTIPLE}. {_fitting_sizes(point_cloud_range, voxel_size)}")


def check_config_grid(cfg) -> np.ndarray | None:
    """Check a full config (DATA_CONFIG + MODEL) at load time; None when the model is not a SECOND-style network."""
    model = cfg.get("MODEL", {})
    if model.get("BACKBONE_3D", {}).get("NAME") != "VoxelBackBone8x":
        return None
    data_config = cfg.DATA_CONFIG
    voxel_size = next((step.VOXEL_SIZE for step in data_config.DATA_PROCESSOR
                       if step.NAME == "transform_points_to_voxels"), None)
    if voxel_size is None:
        raise ConfigError("DATA_CONFIG.DATA_PROCESSOR has no transform_points_to_voxels step, which SECOND needs")
    return check_second_grid(data_config.POINT_CLOUD_RANGE, voxel_size)


def _fitting_sizes(point_cloud_range: np.ndarray, voxel_size: np.ndarray) -> str:
    """Human-readable voxel sizes (for this range) and range ends (for this voxel) that satisfy the rules."""
    span = point_cloud_range[3:] - point_cloud_range[:3]
    hints = []
    for axis, name in enumerate("xy"):
        cells = max(XY_MULTIPLE, XY_MULTIPLE * round(span[axis] / voxel_size[axis] / XY_MULTIPLE))
        size = span[axis] / cells
        end = point_cloud_range[axis] + cells * voxel_size[axis]
        hints.append(f"{name}: voxel {size:.6g} m ({cells} cells) or {name} max {end:.6g} m ({cells} cells of "
                     f"{voxel_size[axis]:.6g} m)")
    hints.append(f"z: voxel {span[2] / Z_CELLS:.6g} m or z max {point_cloud_range[2] + Z_CELLS * voxel_size[2]:.6g} m "
                 f"({Z_CELLS} cells)")
    return "Sizes that fit: " + "; ".join(hints)
