"""Every shipped profile gives most people an anchor at the matched threshold (measured on simulated labels of all
three domains), so a grid whose anchors lie too far apart to learn IoU-0.5 boxes cannot ship again."""
from pathlib import Path

import numpy as np
import pytest
import torch

from pcdet_memslidar.config import load_config
from pcdet_memslidar.grid import check_config_grid
from pcdet_memslidar.io.layout import KittiLayout, read_frame
from pcdet_memslidar.models.target_assigner import matched_share
from pcdet_memslidar.sim.site import get_domain
from pcdet_memslidar.sim.writer import simulate_dataset

CFGS = Path(__file__).resolve().parents[2] / "cfgs"
MIN_SHARE = 0.4  # people with an anchor at BEV IoU >= matched_threshold


@pytest.fixture(scope="module")
def simulated_boxes(tmp_path_factory) -> torch.Tensor:
    """(M, 7) labelled boxes of 12 simulated frames of each domain."""
    boxes = []
    for domain in ("sim", "real", "industrial"):
        root = tmp_path_factory.mktemp(domain)
        simulate_dataset(get_domain(domain), 12, root, seed=3, progress=False)
        layout = KittiLayout(root)
        boxes += [read_frame(layout, frame_id)["gt_boxes"] for frame_id in layout.frame_ids()]
    boxes = np.concatenate(boxes)
    assert len(boxes) > 60
    return torch.from_numpy(boxes)


def _share(cfg, boxes) -> float:
    grid = check_config_grid(cfg)
    return matched_share(cfg.MODEL.DENSE_HEAD.ANCHOR_GENERATOR_CONFIG, grid, cfg.DATA_CONFIG.POINT_CLOUD_RANGE,
                         boxes)["Pedestrian"]


@pytest.mark.parametrize("profile", ["paper", *load_config(CFGS / "m3.yaml").PROFILES])
def test_every_shipped_profile_gives_most_people_a_matched_anchor(profile, simulated_boxes):
    for model in ("m1", "m2", "m3", "m4", "oracle"):
        cfg = load_config(CFGS / f"{model}.yaml", profile=profile)
        share = _share(cfg, simulated_boxes)
        assert share >= MIN_SHARE, f"{model}.yaml, profile {profile}: only {share:.0%} of people have a matched anchor"


def test_anchors_every_1_28_m_fail_the_check(simulated_boxes):
    """The former quick grid (0.16 m voxels, stride-8 head) gave 3-6 % of people a matched anchor."""
    cfg = load_config(CFGS / "m3.yaml", profile="quick")
    step = next(step for step in cfg.DATA_CONFIG.DATA_PROCESSOR if step.NAME == "transform_points_to_voxels")
    step.VOXEL_SIZE = [0.16, 0.16, step.VOXEL_SIZE[2]]
    cfg.DATA_CONFIG.POINT_CLOUD_RANGE = [2.56, -23.04, -0.5, 40.96, 23.04, 2.5]
    step.VOXEL_SIZE[2] = 0.075
    cfg.MODEL.BACKBONE_2D.UPSAMPLE_STRIDES = [1, 2]
    anchor = cfg.MODEL.DENSE_HEAD.ANCHOR_GENERATOR_CONFIG[0]
    anchor.update(feature_map_stride=8, matched_threshold=0.5, unmatched_threshold=0.35)
    assert _share(cfg, simulated_boxes) < 0.1
