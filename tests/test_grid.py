"""Voxel-grid rule: one rule for the config loader, the OpenPCDet launcher and the model."""
import json
import re
from pathlib import Path

import pytest
import yaml
from easydict import EasyDict

from pcdet_memslidar import openpcdet
from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets.synthetic import SyntheticPersonDataset
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.grid import check_config_grid, check_voxel_grid, fitted_range, xy_cell_multiple
from pcdet_memslidar.models import build_network

CFGS = Path(__file__).resolve().parents[1] / "cfgs"
M3 = str((CFGS / "m3.yaml").resolve())
PAPER_RANGE = [2.56, -23.04, -0.5, 40.96, 23.04, 2.5]
PAPER_MODEL = load_config(CFGS / "m3.yaml").MODEL  # stride-8 head, NUM_BEV_FEATURES 256
QUICK_RANGE, QUICK_VOXEL = [2.56, -23.2, 0.1, 40.96, 23.2, 2.5], [0.1, 0.1, 0.06]  # 384 x 464 x 40 cells
ONE_LEVEL_STRIDE_4 = ["MODEL.BACKBONE_2D.LAYER_NUMS", "[1]", "MODEL.BACKBONE_2D.LAYER_STRIDES", "[1]",
                      "MODEL.BACKBONE_2D.NUM_FILTERS", "[64]", "MODEL.BACKBONE_2D.UPSAMPLE_STRIDES", "[2]",
                      "MODEL.BACKBONE_2D.NUM_UPSAMPLE_FILTERS", "[128]"]  # 8 / 2: the quick profile's anchors


def _quick(point_cloud_range, *sets):
    return load_config(CFGS / "m3.yaml", ["PROFILE", "quick", "DATA_CONFIG.POINT_CLOUD_RANGE",
                                          str(point_cloud_range), *sets])


def test_paper_grid_fits_second():
    assert check_voxel_grid(PAPER_MODEL, PAPER_RANGE, [0.08, 0.08, 0.075]).tolist() == [480, 576, 40]
    assert check_voxel_grid(PAPER_MODEL, [2.56, -23.2, -0.5, 40.96, 23.2, 2.5], [0.05, 0.05, 0.075]).tolist() == \
        [768, 928, 40]


def test_grid_rule_refuses_bad_z_and_non_multiple_cells_with_sizes_that_fit():
    with pytest.raises(ConfigError) as error:
        check_voxel_grid(PAPER_MODEL, PAPER_RANGE, [0.08, 0.08, 0.1])  # 3.0 m / 0.1 = 30 z cells
    assert "[480, 576, 30]" in str(error.value)
    assert ("z needs 40 to 55 cells (MAP_TO_BEV.NUM_BEV_FEATURES 256 = 128 channels x the depth VoxelBackBone8x "
            "leaves) and x, y multiples of 16 (stride 8 x BACKBONE_2D.LAYER_STRIDES [1, 2], and the head's stride 8)"
            in str(error.value))
    assert "z: voxel 0.075 m or z max 3.5 m (40 cells; 40 to 55 fit)" in str(error.value)
    with pytest.raises(ConfigError) as error:  # 410 x cells: not a multiple of 16
        check_voxel_grid(PAPER_MODEL, [0, -20.0, -0.5, 41.0, 20.0, 2.5], [0.1, 0.1, 0.075])
    assert "[410, 400, 40]" in str(error.value)
    assert "x: voxel 0.0985577 m (416 cells) or x max 41.6 m (416 cells of 0.1 m)" in str(error.value)
    with pytest.raises(ConfigError, match="not a whole number of voxels"):
        check_voxel_grid(PAPER_MODEL, PAPER_RANGE, [0.07, 0.08, 0.075])
    assert check_voxel_grid(PAPER_MODEL, PAPER_RANGE, [0.075, 0.08, 0.075]).tolist() == [512, 576, 40]
    with pytest.raises(ConfigError, match="NUM_BEV_FEATURES is 300: .* a positive multiple of 128"):
        check_voxel_grid(EasyDict({**PAPER_MODEL, "MAP_TO_BEV": {"NUM_BEV_FEATURES": 300}}), PAPER_RANGE,
                          [0.08, 0.08, 0.075])


@pytest.mark.parametrize("z_cells, fits", [(39, False), (40, True), (41, True), (47, True), (55, True), (56, False)])
def test_config_loader_and_model_give_one_verdict_on_z_cells(z_cells, fits):
    """41-55 z cells: the former loader rule (exactly 40) refused them, the model took them (depth 2 after
    VoxelBackBone8x); now the loader and the model check the one rule and say the same."""
    point_cloud_range = [*QUICK_RANGE[:5], round(QUICK_RANGE[2] + z_cells * QUICK_VOXEL[2], 4)]
    dataset = SyntheticPersonDataset(point_cloud_range, QUICK_VOXEL, num_frames=0)
    if fits:
        cfg = _quick(point_cloud_range)
        assert check_config_grid(cfg).tolist() == [384, 464, z_cells]
        assert build_network(cfg.MODEL, 1, dataset).map_to_bev_module.num_bev_features == 256
        return
    with pytest.raises(ConfigError) as loaded:
        _quick(point_cloud_range)
    assert str(loaded.value).startswith(f"{M3}: the voxel grid [384, 464, {z_cells}]")
    assert "z needs 40 to 55 cells" in str(loaded.value)
    with pytest.raises(ConfigError) as built:
        build_network(load_config(CFGS / "m3.yaml", ["PROFILE", "quick"]).MODEL, 1, dataset)
    assert str(loaded.value) == f"{M3}: {built.value}"


def test_a_stride_4_head_on_one_bev_level_takes_multiples_of_8():
    """LAYER_STRIDES [1] with UPSAMPLE_STRIDES [2]: anchors every 4 voxels; x, y need lcm(8, 4) = 8 (the former
    loader rule: 16). The quick profile's two-level stride-4 head needs 16."""
    narrower = [*QUICK_RANGE[:3], 40.16, *QUICK_RANGE[4:]]  # 376 = 8 x 47 x cells
    assert check_config_grid(_quick(narrower, *ONE_LEVEL_STRIDE_4)).tolist() == [376, 464, 40]
    with pytest.raises(ConfigError) as error:
        _quick(narrower)
    message = str(error.value)
    assert message.startswith(f"{M3}: the voxel grid [376, 464, 40]")
    assert "x, y multiples of 16 (stride 8 x BACKBONE_2D.LAYER_STRIDES [1, 2], and the head's stride 4)" in message
    assert "x: voxel 0.102174 m (368 cells) or x max 39.36 m (368 cells of 0.1 m)" in message
    with pytest.raises(ConfigError, match=re.escape(
            f"{M3}: ANCHOR_GENERATOR_CONFIG Pedestrian: feature_map_stride is 4 but BACKBONE_2D (LAYER_STRIDES [1, 2], "
            f"UPSAMPLE_STRIDES [1, 2]) outputs stride 8: set it to 8 or change UPSAMPLE_STRIDES")):
        _quick(QUICK_RANGE, "MODEL.BACKBONE_2D.UPSAMPLE_STRIDES", "[1, 2]")
    with pytest.raises(ConfigError, match=r"outputs stride 2.66667: the head needs a whole number of voxels"):
        _quick(QUICK_RANGE, "MODEL.BACKBONE_2D.UPSAMPLE_STRIDES", "[3, 6]")


def test_the_openpcdet_launcher_checks_the_same_rule_naming_the_file_and_set(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"_BASE_CONFIG_: {CFGS / 'm3.yaml'}\n"
                   f"DATA_CONFIG:\n    POINT_CLOUD_RANGE: [2.56, -23.2, -0.5, 40.96, 23.2, 4.0]\n")  # 60 z cells
    with pytest.raises(ConfigError, match="^" + re.escape(f"{bad.resolve()}: the voxel grid [768, 928, 60]")):
        openpcdet._cfg_from_yaml_file(bad, EasyDict())
    config = openpcdet._cfg_from_yaml_file(CFGS / "m3.yaml", EasyDict())
    assert config.CFG_FILE == M3 and config.PROFILE == "paper"
    set_list = ["PROFILE", "quick", "DATA_CONFIG.POINT_CLOUD_RANGE", str([*QUICK_RANGE[:5], 3.46])]  # 56 z cells
    with pytest.raises(ConfigError, match="^" + re.escape(f"{M3} with --set {' '.join(set_list)}: the voxel grid "
                                                          f"[384, 464, 56]")):
        openpcdet._profile_aware_cfg_from_list(_set_values)(set_list, config)


def _set_values(cfg_list, config):
    """A stand-in for OpenPCDet's cfg_from_list: sets each KEY to its YAML value."""
    for key, text in zip(cfg_list[0::2], cfg_list[1::2]):
        *parents, leaf = key.split(".")
        node = config
        for part in parents:
            node = node[part]
        node[leaf] = yaml.safe_load(text)


def test_folded_boxes_take_one_anchor_rotation():
    two = ("MODEL.DENSE_HEAD.ANCHOR_GENERATOR_CONFIG", "[{class_name: Pedestrian, anchor_sizes: [[0.8, 0.6, 1.73]], "
           "anchor_rotations: [0, 1.57], anchor_bottom_heights: [0.0], align_center: False, feature_map_stride: 4, "
           "matched_threshold: 0.35, unmatched_threshold: 0.2}]")
    with pytest.raises(ConfigError, match=re.escape(
            f"{M3}: ANCHOR_GENERATOR_CONFIG Pedestrian: anchor_rotations [0, 1.57] with DATA_PROCESSOR "
            f"fold_box_headings, which folds every box to a heading in [-45, 45) deg: set anchor_rotations to [0]")):
        _quick(QUICK_RANGE, *two)
    steps = [step for step in _quick(QUICK_RANGE).DATA_CONFIG.DATA_PROCESSOR if step.NAME != "fold_box_headings"]
    unfolded = json.dumps(steps)  # JSON is YAML
    assert check_config_grid(_quick(QUICK_RANGE, *two, "DATA_CONFIG.DATA_PROCESSOR", unfolded)).tolist() == \
        [384, 464, 40]


def test_a_sites_grid_is_the_smallest_that_covers_it_and_fits_second():
    extent = (1.6, -4.9, 8.6, 1.6)  # a walkable area and its margin [m]
    quick = load_config(CFGS / "m3.yaml", profile="quick")
    assert xy_cell_multiple(quick.MODEL) == 16 and xy_cell_multiple(PAPER_MODEL) == 16
    fitted = fitted_range(extent, (0.1, 2.5), 0.1, 16)
    assert fitted == [1.1, -5.6, 0.1, 9.1, 2.4, 2.5]  # 7.0 x 6.5 m -> 80 x 80 cells, centred (half-even rounding)
    assert check_voxel_grid(quick.MODEL, fitted, [0.1, 0.1, 0.06]).tolist() == [80, 80, 40]
    assert fitted_range(extent, (-0.5, 2.5), 0.05, 16) == [1.5, -5.25, -0.5, 8.7, 1.95, 2.5]  # 144 x 144 cells
    # a 0.1 m area: one multiple (1.6 m) around its centre 0.05, whose start -7.5 voxels rounds half-even to -8
    assert fitted_range((0.0, 0.0, 0.1, 0.1), (0.1, 2.5), 0.1, 16) == [-0.8, -0.8, 0.1, 0.8, 0.8, 2.5]
