"""The voxel grid of a config: its cell counts, and the one rule for which grids the detectors take
(VoxelBackBone8x -> HeightCompression -> BaseBEVBackbone -> a dense head: SECOND and CenterPoint alike).

The rule follows from the model's own settings (no torch here, so the config loader, the OpenPCDet launcher, the
datasets and the model all use this one module):
- z: VoxelBackBone8x takes (z + 1, y, x) cells through conv2, conv3 (kernel 3, stride 2, padding 1), conv4 (stride 2,
  no z padding) and conv_out (kernel 3, stride 2 in z only) (`sparse_output_shape`); HeightCompression stacks the
  depth left over into channels, so MAP_TO_BEV.NUM_BEV_FEATURES must be 128 x that depth (256: 40 to 55 z cells).
- x and y: the sparse convs divide by 8 (rounding up) and BaseBEVBackbone by its LAYER_STRIDES; its
  UPSAMPLE_STRIDES bring every level to one stride, the head's (`bev_output_stride`), at which the anchors are laid
  (ANCHOR_GENERATOR_CONFIG feature_map_stride, grid // stride) or the center head's targets are drawn
  (TARGET_ASSIGNER_CONFIG.FEATURE_MAP_STRIDE). x and y must be multiples of 8 x prod(LAYER_STRIDES)
  and of the head's stride, so that no stride rounds and the BEV map has the anchors' size (OpenPCDet issues #634,
  #666, #1162).
- anchors: boxes folded into one form (DATA_PROCESSOR fold_box_headings) take one anchor rotation, 0.
"""
from __future__ import annotations

import math

import numpy as np

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.geometry.boxes import FOLDS

SPARSE_STRIDE = 8  # VoxelBackBone8x's downsampling in x and y
SPARSE_OUTPUT_CHANNELS = 128  # VoxelBackBone8x's output channels, stacked per output z cell by HeightCompression
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
        raise ConfigError(f"POINT_CLOUD_RANGE {_listed(point_cloud_range)} must have max > min and VOXEL_SIZE "
                          f"{_listed(voxel_size)} must be positive")
    cells = span / voxel_size
    rounded = np.round(cells)
    if not np.allclose(cells, rounded, rtol=0, atol=1e-4):
        raise ConfigError(f"POINT_CLOUD_RANGE {_listed(point_cloud_range)} is not a whole number of voxels of "
                          f"{_listed(voxel_size)}: {np.round(cells, 4).tolist()} cells (x, y, z)")
    return rounded.astype(np.int64)


def sparse_output_shape(sparse_shape) -> list[int]:
    """(z, y, x) cells of VoxelBackBone8x's output for an input of `sparse_shape` (z, y, x) cells."""
    z, y, x = sparse_shape
    for _ in range(2):  # conv2, conv3: kernel 3, stride 2, padding 1
        z, y, x = ((n + 2 - 3) // 2 + 1 for n in (z, y, x))
    z, y, x = (z - 3) // 2 + 1, (y + 2 - 3) // 2 + 1, (x + 2 - 3) // 2 + 1  # conv4: no z padding
    return [(z - 3) // 2 + 1, y, x]  # conv_out: kernel (3, 1, 1), stride (2, 1, 1)


def bev_output_stride(backbone_2d_cfg) -> float:
    """Voxels per cell of BaseBEVBackbone's output on VoxelBackBone8x's stride-8 map (the anchors' stride);
    ConfigError when the levels it concatenates are upsampled to different strides."""
    strides = SPARSE_STRIDE * np.cumprod(backbone_2d_cfg.get("LAYER_STRIDES", [1])).astype(np.float64)
    upsample = [float(up) for up in backbone_2d_cfg.get("UPSAMPLE_STRIDES", [])]
    levels = [float(stride / upsample[level] if level < len(upsample) else stride)
              for level, stride in enumerate(strides)]
    if len(set(levels)) > 1:
        raise ConfigError(f"BACKBONE_2D: LAYER_STRIDES {list(backbone_2d_cfg.LAYER_STRIDES)} with UPSAMPLE_STRIDES "
                          f"{upsample} bring its levels to strides {levels}; they must meet at one stride")
    extra = upsample[len(strides):]  # one more upsampling after the concatenation
    return levels[0] / (extra[0] if extra else 1.0)


def check_voxel_grid(model_cfg, point_cloud_range, voxel_size) -> np.ndarray:
    """(3,) int64 cell counts (x, y, z) of `point_cloud_range` in `voxel_size` [m] once the detector of `model_cfg` (its
    MODEL section) is known to take them; ConfigError naming the settings and sizes that would fit otherwise."""
    point_cloud_range = config_numbers(point_cloud_range, 6, RANGE_KEY, RANGE_FORMAT)
    voxel_size = config_numbers(voxel_size, 3, VOXEL_KEY, VOXEL_FORMAT)
    layer_strides = list(model_cfg.BACKBONE_2D.get("LAYER_STRIDES", [1]))
    head_stride = _head_stride(model_cfg)
    multiple = xy_cell_multiple(model_cfg)
    num_bev_features = model_cfg.MAP_TO_BEV.NUM_BEV_FEATURES
    z_cells = _z_cells(num_bev_features)
    try:
        cells = grid_size(point_cloud_range, voxel_size)
    except ConfigError as error:
        raise ConfigError(f"{error}. {_fitting_sizes(point_cloud_range, voxel_size, multiple, z_cells)}") from None
    if z_cells[0] <= cells[2] <= z_cells[1] and not (cells[:2] % multiple).any():
        return cells
    span = point_cloud_range[3:] - point_cloud_range[:3]
    raise ConfigError(
        f"the voxel grid {cells.tolist()} (x, y, z cells of range {_listed(point_cloud_range)}, span "
        f"{np.round(span, 4).tolist()} m, voxel {_listed(voxel_size)}) does not fit the network: z needs "
        f"{z_cells[0]} to {z_cells[1]} cells (MAP_TO_BEV.NUM_BEV_FEATURES {num_bev_features} = "
        f"{SPARSE_OUTPUT_CHANNELS} channels x the depth VoxelBackBone8x leaves) and x, y multiples of {multiple} "
        f"(stride {SPARSE_STRIDE} x BACKBONE_2D.LAYER_STRIDES {layer_strides}, and the head's stride {head_stride}). "
        f"{_fitting_sizes(point_cloud_range, voxel_size, multiple, z_cells)}")


def xy_cell_multiple(model_cfg) -> int:
    """The number that the detector of `model_cfg` (its MODEL section) needs the x and y cell counts to be multiples of:
    stride 8 x BACKBONE_2D.LAYER_STRIDES, and the head's stride."""
    layer_strides = list(model_cfg.BACKBONE_2D.get("LAYER_STRIDES", [1]))
    return math.lcm(SPARSE_STRIDE * int(np.prod(layer_strides)), _head_stride(model_cfg))


def fitted_range(extent_xy, z_range, voxel_xy: float, multiple: int) -> list[float]:
    """POINT_CLOUD_RANGE [x0, y0, z0, x1, y1, z1] [m] of the smallest grid that covers extent_xy (x0, y0, x1, y1)
    [m] with x and y spans of whole multiples of `multiple` voxels of voxel_xy [m], centred on the extent; z_range
    (z0, z1) as given (a site's grid follows its floor and field of view, by the rule of check_voxel_grid)."""
    bounds = []
    for low, high in ((extent_xy[0], extent_xy[2]), (extent_xy[1], extent_xy[3])):
        cells = multiple * max(1, math.ceil((high - low) / voxel_xy / multiple - 1e-9))
        start = round(((low + high) / 2 - cells * voxel_xy / 2) / voxel_xy) * voxel_xy
        bounds.append((round(start, 6), round(start + cells * voxel_xy, 6)))
    (x0, x1), (y0, y1) = bounds
    return [x0, y0, float(z_range[0]), x1, y1, float(z_range[1])]


def check_config_grid(cfg, where: str | None = None) -> np.ndarray | None:
    """Check a config at load: the POINT_CLOUD_RANGE of an experiment or dataset config, and for a model on
    VoxelBackBone8x (SECOND, CenterPoint) its voxel grid (check_voxel_grid). Returns the cell counts (x, y, z), None for
    other configs. Errors start with `where` (default: the config's CFG_FILE)."""
    try:
        return _check_grid(cfg)
    except ConfigError as error:
        where = where or cfg.get("CFG_FILE")
        if where is None:
            raise
        raise ConfigError(f"{where}: {error}") from None


def _check_grid(cfg) -> np.ndarray | None:
    if "DATA_CONFIG" not in cfg and "DATASET" not in cfg:
        return None  # no data to voxelise (a simulator preset, say)
    data_config = cfg.DATA_CONFIG if "DATA_CONFIG" in cfg else cfg
    config_numbers(data_config.get("POINT_CLOUD_RANGE"), 6, RANGE_KEY, RANGE_FORMAT)
    if cfg.get("MODEL", {}).get("BACKBONE_3D", {}).get("NAME") != "VoxelBackBone8x":
        return None
    voxel_size = next((step.VOXEL_SIZE for step in data_config.get("DATA_PROCESSOR", [])
                       if step.NAME == "transform_points_to_voxels"), None)
    if voxel_size is None:
        raise ConfigError("DATA_CONFIG.DATA_PROCESSOR has no transform_points_to_voxels step, which "
                          "VoxelBackBone8x needs")
    _check_folded_anchors(cfg.MODEL, data_config)
    return check_voxel_grid(cfg.MODEL, data_config.POINT_CLOUD_RANGE, voxel_size)


def _check_folded_anchors(model_cfg, data_config) -> None:
    """Boxes folded into one form (DATA_PROCESSOR fold_box_headings, FOLD one of geometry.boxes.FOLDS: headings in
    [-45, 45) or [-90, 90) deg) need one anchor rotation, 0: an anchor turned by a quarter would have to regress
    every box through a quarter turn. ConfigError otherwise, or for another FOLD."""
    folds = [step for step in data_config.get("DATA_PROCESSOR", []) if step.NAME == "fold_box_headings"]
    if not folds:
        return
    for step in folds:
        if step.get("FOLD", FOLDS[0]) not in FOLDS:
            raise ConfigError(f"DATA_PROCESSOR fold_box_headings: FOLD is {step.FOLD!r}; use one of "
                              f"{', '.join(FOLDS)}")
    for anchor in model_cfg.get("DENSE_HEAD", {}).get("ANCHOR_GENERATOR_CONFIG", []):
        if list(anchor["anchor_rotations"]) != [0]:
            raise ConfigError(f"ANCHOR_GENERATOR_CONFIG {anchor['class_name']}: anchor_rotations "
                              f"{list(anchor['anchor_rotations'])} with DATA_PROCESSOR fold_box_headings, which "
                              f"folds every box to a heading in [-45, 45) deg: set anchor_rotations to [0], or remove "
                              f"the fold_box_headings step")


def _head_stride(model_cfg) -> int:
    """Voxels per head cell: BaseBEVBackbone's output stride, which every anchor class's feature_map_stride (anchor
    head) or TARGET_ASSIGNER_CONFIG.FEATURE_MAP_STRIDE (center head) must equal; ConfigError otherwise or when it is
    not a whole number of voxels."""
    backbone_2d = model_cfg.BACKBONE_2D
    stride = bev_output_stride(backbone_2d)
    settings = (f"BACKBONE_2D (LAYER_STRIDES {list(backbone_2d.get('LAYER_STRIDES', [1]))}, UPSAMPLE_STRIDES "
                f"{list(backbone_2d.get('UPSAMPLE_STRIDES', []))})")
    if stride < 1 or stride % 1:
        raise ConfigError(f"{settings} outputs stride {stride:g}: the head needs a whole number of voxels per BEV "
                          f"cell; change UPSAMPLE_STRIDES")
    head = model_cfg.DENSE_HEAD
    declared = [(f"ANCHOR_GENERATOR_CONFIG {anchor['class_name']}: feature_map_stride", anchor["feature_map_stride"])
                for anchor in head.get("ANCHOR_GENERATOR_CONFIG", [])]
    if "FEATURE_MAP_STRIDE" in head.get("TARGET_ASSIGNER_CONFIG", {}):
        declared.append(("DENSE_HEAD.TARGET_ASSIGNER_CONFIG.FEATURE_MAP_STRIDE",
                         head.TARGET_ASSIGNER_CONFIG.FEATURE_MAP_STRIDE))
    for key, value in declared:
        if value != stride:
            raise ConfigError(f"{key} is {value} but {settings} outputs stride {stride:g}: set it to {stride:g} or "
                              f"change UPSAMPLE_STRIDES")
    return int(stride)


def _z_cells(num_bev_features) -> tuple[int, int]:
    """(fewest, most) z cells that VoxelBackBone8x turns into num_bev_features / 128 output cells; ConfigError when
    num_bev_features is no positive multiple of 128."""
    depth = num_bev_features // SPARSE_OUTPUT_CHANNELS if isinstance(num_bev_features, int) else 0
    if depth < 1 or depth * SPARSE_OUTPUT_CHANNELS != num_bev_features:
        raise ConfigError(f"MODEL.MAP_TO_BEV.NUM_BEV_FEATURES is {num_bev_features!r}: HeightCompression stacks "
                          f"VoxelBackBone8x's {SPARSE_OUTPUT_CHANNELS} channels per output z cell, so it must be a "
                          f"positive multiple of {SPARSE_OUTPUT_CHANNELS} (256 for a grid 40 z cells deep)")
    fitting = [z for z in range(1, 16 * depth + 32) if sparse_output_shape([z + 1, 1, 1])[0] == depth]
    return fitting[0], fitting[-1]


def _listed(numbers: np.ndarray) -> list[float]:
    """`numbers` for a message, to 6 significant digits (a float32 range reads as the config wrote it)."""
    return [float(f"{value:.6g}") for value in numbers]


def _fitting_sizes(point_cloud_range: np.ndarray, voxel_size: np.ndarray, multiple: int,
                   z_cells: tuple[int, int]) -> str:
    """Human-readable voxel sizes (for this range) and range ends (for this voxel) that fit: x, y cells a multiple
    of `multiple`, z cells within `z_cells` (fewest, most)."""
    span = point_cloud_range[3:] - point_cloud_range[:3]
    hints = []
    for axis, name in enumerate("xy"):
        cells = max(multiple, multiple * round(span[axis] / voxel_size[axis] / multiple))
        size = span[axis] / cells
        end = point_cloud_range[axis] + cells * voxel_size[axis]
        hints.append(f"{name}: voxel {size:.6g} m ({cells} cells) or {name} max {end:.6g} m ({cells} cells of "
                     f"{voxel_size[axis]:.6g} m)")
    depth = int(np.clip(round(span[2] / voxel_size[2]), *z_cells))
    hints.append(f"z: voxel {span[2] / depth:.6g} m or z max {point_cloud_range[2] + depth * voxel_size[2]:.6g} m "
                 f"({depth} cells; {z_cells[0]} to {z_cells[1]} fit)")
    return "Sizes that fit: " + "; ".join(hints)
