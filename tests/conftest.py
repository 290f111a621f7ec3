"""Test-wide fixtures: the bundled assets (checked by sha256), a full disk, tiny generated MEMS-LiDAR domains and the
SECOND model configs. The process policy is the entry points' (policy.apply_process_policy); torch keeps its default
threads (the machine's cores; CI: 2), so thread bugs show up as they would for users."""
from __future__ import annotations

import errno
import hashlib
import io
import os
from pathlib import Path

import numpy as np
import pytest
from easydict import EasyDict

from pcdet_memslidar import cli, policy
from pcdet_memslidar.io.bfpc import read_bfpc
from pcdet_memslidar.io.layout import KittiLayout, write_frame
from pcdet_memslidar.utils import atomic

policy.apply_process_policy()  # as every entry point does, before torch's first MKL call
REPO = Path(__file__).resolve().parents[1]
REAL_RECORDING_SHA256 = "f2fafd8bf6d63a6e579a8c510985f12c81feed00e783c2edcc6f54ab13a0f492"  # Blickfeld's dump.bfpc


# --- bundled assets and faults --------------------------------------------------------------------------------------

@pytest.fixture(scope="session")
def bundled_asset():
    """bundled_asset(relative, sha256) -> the repository's file at `relative`, after checking that it is there and
    unchanged (the README beside it says where it came from)."""
    def check(relative: str, sha256: str) -> Path:
        path = REPO / relative
        assert path.is_file(), f"missing {path}: restore it from git"
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
        assert digest == sha256, f"{path} changed (sha256 {digest}): restore it from git"
        return path
    return check


@pytest.fixture(scope="session")
def real_recording(bundled_asset) -> Path:
    """The real Cube 1 recording bundled in pcdet_memslidar/assets/blickfeld (its README says where it came from)."""
    return bundled_asset("pcdet_memslidar/assets/blickfeld/cube1_sample_2020.bfpc", REAL_RECORDING_SHA256)


@pytest.fixture(scope="session")
def real_bfpc(real_recording):
    """The real Cube 1 recording, decoded once."""
    return read_bfpc(real_recording)


@pytest.fixture
def full_disk(monkeypatch):
    """Every atomic write fails in write() with ENOSPC and no file name, as a full disk reports it."""
    class FullDisk(io.RawIOBase):
        def writable(self):
            return True

        def write(self, data):
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(atomic, "open", lambda descriptor, mode: os.close(descriptor) or FullDisk(), raising=False)


# --- tiny generated MEMS-LiDAR domains: people-like boxes with points inside, a noisy ground --------------------------

def _people_frame(rng: np.random.Generator, num_people: int, intensity: tuple[float, float]):
    """(N, 4) points and (M, 7) standing-person boxes, at least 1.5 m apart, inside the Cube 1 footprint."""
    boxes = []
    while len(boxes) < num_people:
        x = rng.uniform(6.0, 30.0)
        dz = rng.uniform(1.5, 1.9)
        box = [x, rng.uniform(-0.4, 0.4) * x, dz / 2, rng.uniform(0.5, 0.9), rng.uniform(0.4, 0.7), dz,
               rng.uniform(-np.pi, np.pi)]
        if all(np.hypot(box[0] - b[0], box[1] - b[1]) > 1.5 for b in boxes):
            boxes.append(box)
    boxes = np.array(boxes, dtype=np.float64).reshape(-1, 7)
    clouds = []
    for box in boxes:
        local = rng.uniform(-0.45, 0.45, size=(int(rng.integers(40, 150)), 3)) * box[3:6]
        cos, sin = np.cos(box[6]), np.sin(box[6])
        world = np.column_stack([cos * local[:, 0] - sin * local[:, 1], sin * local[:, 0] + cos * local[:, 1],
                                 local[:, 2]]) + box[:3]
        clouds.append(world)
    ground = np.column_stack([rng.uniform(3.0, 40.0, 400), rng.uniform(-20.0, 20.0, 400), rng.normal(0, 0.02, 400)])
    xyz = np.concatenate(clouds + [ground])
    points = np.column_stack([xyz, rng.uniform(*intensity, len(xyz))]).astype(np.float32)
    return points, boxes


@pytest.fixture(scope="session")
def make_people_frame():
    """make_people_frame(rng, num_people, intensity) -> (points (N, 4), boxes (M, 7))."""
    return _people_frame


@pytest.fixture(scope="session")
def intensity_bands() -> dict:
    """{domain: (low, high)} intensity band of each generated domain: each domain's points carry their own, so tests
    can tell which database a pasted person came from."""
    return {"sim": (0.0, 1.0), "real": (100.0, 101.0), "industrial": (200.0, 201.0)}


@pytest.fixture(scope="session")
def memslidar_data(tmp_path_factory, make_people_frame, intensity_bands) -> Path:
    """DATA_PATH with sim (12 frames), real (12, frame 000002 empty) and industrial (4) plus their infos,
    made by `memslidar create-infos --cfg cfgs/m3.yaml --set PROFILE smoke DATA_CONFIG.DATA_PATH ...`."""
    root = tmp_path_factory.mktemp("memslidar")

    def write_domain(name: str, frames: int, seed: int, empty_frames=()) -> None:
        """`frames` frames 000000... of domain `name` in root/name; frames in `empty_frames` have no people."""
        rng = np.random.default_rng(seed)
        layout = KittiLayout(root / name)
        for index in range(frames):
            points, boxes = make_people_frame(rng, 0 if index in empty_frames else int(rng.integers(1, 5)),
                                              intensity_bands[name])
            write_frame(layout, f"{index:06d}", points, ["Pedestrian"] * len(boxes), boxes, {"domain": name})

    write_domain("sim", 12, seed=1)
    write_domain("real", 12, seed=2, empty_frames=(2,))
    write_domain("industrial", 4, seed=3)
    assert cli.main(["create-infos", "--cfg", str(REPO / "cfgs" / "m3.yaml"), "--set", "PROFILE", "smoke",
                     "DATA_CONFIG.DATA_PATH", str(root)]) == 0
    return root


# --- SECOND model configs (OpenPCDet style) and the grids of the synthetic person frames -----------------------------

def _second_model_cfg(num_filters=(128, 256), upsample_filters=(256, 256), layer_nums=(5, 5)) -> EasyDict:
    return EasyDict({
        "NAME": "SECONDNet",
        "VFE": {"NAME": "MeanVFE"},
        "BACKBONE_3D": {"NAME": "VoxelBackBone8x"},
        "MAP_TO_BEV": {"NAME": "HeightCompression", "NUM_BEV_FEATURES": 256},
        "BACKBONE_2D": {"NAME": "BaseBEVBackbone", "LAYER_NUMS": list(layer_nums), "LAYER_STRIDES": [1, 2],
                        "NUM_FILTERS": list(num_filters), "UPSAMPLE_STRIDES": [1, 2],
                        "NUM_UPSAMPLE_FILTERS": list(upsample_filters)},
        "DENSE_HEAD": {
            "NAME": "AnchorHeadSingle", "CLASS_AGNOSTIC": False, "USE_DIRECTION_CLASSIFIER": True,
            "DIR_OFFSET": 0.78539, "DIR_LIMIT_OFFSET": 0.0, "NUM_DIR_BINS": 2,
            "ANCHOR_GENERATOR_CONFIG": [{
                "class_name": "Pedestrian", "anchor_sizes": [[0.8, 0.6, 1.73]], "anchor_rotations": [0, 1.57],
                "anchor_bottom_heights": [0.0], "align_center": False, "feature_map_stride": 8,
                "matched_threshold": 0.5, "unmatched_threshold": 0.35}],
            "TARGET_ASSIGNER_CONFIG": {"NAME": "AxisAlignedTargetAssigner", "POS_FRACTION": -1.0,
                                       "SAMPLE_SIZE": 512, "NORM_BY_NUM_EXAMPLES": False, "MATCH_HEIGHT": False,
                                       "BOX_CODER": "ResidualCoder"},
            "LOSS_CONFIG": {"LOSS_WEIGHTS": {"cls_weight": 1.0, "loc_weight": 2.0, "dir_weight": 0.2,
                                             "code_weights": [1.0] * 7}},
        },
        "POST_PROCESSING": {"RECALL_THRESH_LIST": [0.3, 0.5, 0.7], "SCORE_THRESH": 0.1, "OUTPUT_RAW_SCORE": False,
                            "EVAL_METRIC": "kitti",
                            "NMS_CONFIG": {"MULTI_CLASSES_NMS": False, "NMS_TYPE": "nms_gpu", "NMS_THRESH": 0.01,
                                           "NMS_PRE_MAXSIZE": 4096, "NMS_POST_MAXSIZE": 500}},
    })


@pytest.fixture(scope="session")
def second_model_cfg():
    """second_model_cfg(num_filters=(128, 256), upsample_filters=(256, 256), layer_nums=(5, 5)) -> OpenPCDet's kitti
    second.yaml MODEL section for the single class Pedestrian (a new EasyDict each call)."""
    return _second_model_cfg


@pytest.fixture(scope="session")
def small_model_cfg(second_model_cfg):
    """small_model_cfg() -> the person SECOND with a narrow, shallow BEV backbone: fast enough for tests on 2 CPU
    cores."""
    return lambda: second_model_cfg(num_filters=(32, 64), upsample_filters=(64, 64), layer_nums=(1, 1))


@pytest.fixture(scope="session")
def small_optim_cfg():
    """small_optim_cfg(lr=0.003) -> OpenPCDet's adam_onecycle OPTIMIZATION section for one epoch, batch 4."""
    def optim_cfg(lr: float = 0.003) -> EasyDict:
        return EasyDict(OPTIMIZER="adam_onecycle", LR=lr, WEIGHT_DECAY=0.0, MOMS=[0.95, 0.85], PCT_START=0.4,
                        DIV_FACTOR=10, GRAD_NORM_CLIP=10, BATCH_SIZE_PER_GPU=4, NUM_EPOCHS=1)
    return optim_cfg


@pytest.fixture(scope="session")
def person_voxel() -> list[float]:
    """The person SECOND's voxel size (m)."""
    return [0.08, 0.08, 0.1]


@pytest.fixture(scope="session")
def small_range() -> list[float]:
    """A small point cloud range: 128 x 128 x 40 voxels of person_voxel."""
    return [0.0, -5.12, -0.5, 10.24, 5.12, 3.5]
