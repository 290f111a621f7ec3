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
RANGE_KEY, RANGE_FORMAT = "DATA_CONFIG.POINT_CLOUD_RANGE", "[x_min, y_min, z_min, x_max, y_max, z_max] in m"
VOXEL_KEY, VOXEL_FORMAT = "VOXEL_SIZE (DATA_CONFIG.DATA_PROCESSOR, transform_points_to_voxels)", "[vx, vy, vz] in m"


def config_numbers(value, count: int, key: str, layout: str) -> np.ndarray:
    """(count,) float64 of a config value that must be `count` finite numbers laid out as `layout`; ConfigError
    naming `key`, the value and the fix otherwise (a scalar, a wrong length, text, NaN)."""
    try:
        numbers = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        numbers = np.zeros(0)
    if numbers.shape != (count,) or not np.isfinite(numbers).all():
        raise ConfigError(f"{key} is {value!r}: it needs {count} finite numbers {layout}; fix it in the config "
                          f"(or --set)")
    return numbers


def grid_size(point_cloud_range, voxel_size) -> np.ndarray:
    """(3,) int64 cell counts (x, y, z) of the range [x0, y0, z0, x1, y1, z1] in voxels (vx, vy, vz) [m].

    ConfigError when the range is empty or not a whole number of voxels.
    """
    point_cloud_range = config_numbers(point_cloud_range, 6, RANGE_KEY, RANGE_FORMAT)
    voxel_size = config_numbers(voxel_size, 3, VOXEL_KEY, VOXEL_FORMAT)
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
    point_cloud_range = config_numbers(point_cloud_range, 6, RANGE_KEY, RANGE_FORMAT)
    voxel_size = config_numbers(voxel_size, 3, VOXEL_KEY, VOXEL_FORMAT)
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
    """Check a config (DATA_CONFIG + MODEL, or a dataset config alone) at load time: POINT_CLOUD_RANGE, and for a
    SECOND-style network its voxel grid (returns the cell counts; None for other networks)."""
    try:
        return _check_grid(cfg)
    except ConfigError as error:
        if "CFG_FILE" not in cfg:
            raise
        raise ConfigError(f"{cfg.CFG_FILE}: {error}") from None


def _check_grid(cfg) -> np.ndarray | None:
    data_config = cfg.DATA_CONFIG if "DATA_CONFIG" in cfg else cfg
    config_numbers(data_config.get("POINT_CLOUD_RANGE"), 6, RANGE_KEY, RANGE_FORMAT)
    if cfg.get("MODEL", {}).get("BACKBONE_3D", {}).get("NAME") != "VoxelBackBone8x":
        return None
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
