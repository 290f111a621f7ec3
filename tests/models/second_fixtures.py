"""Shared helpers for the model tests: OpenPCDet-style SECOND configs and synthetic person frames."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from easydict import EasyDict

PERSON_RANGE = [0.0, -20.48, -0.5, 40.96, 20.48, 3.5]
PERSON_VOXEL = [0.08, 0.08, 0.1]


def second_model_cfg(num_filters=(128, 256), upsample_filters=(256, 256), layer_nums=(5, 5)) -> EasyDict:
    """OpenPCDet's kitti second.yaml MODEL section for the single class Pedestrian."""
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


def fake_dataset(point_cloud_range=PERSON_RANGE, voxel_size=PERSON_VOXEL, class_names=("Pedestrian",)):
    """The attributes build_network reads from an OpenPCDet dataset."""
    return SimpleNamespace(point_feature_encoder=SimpleNamespace(num_point_features=4),
                           point_cloud_range=np.asarray(point_cloud_range, dtype=np.float32),
                           voxel_size=list(voxel_size), class_names=list(class_names), depth_downsample_factor=None)


SMALL_RANGE = [0.0, -5.12, -0.5, 10.24, 5.12, 3.5]  # 128 x 128 x 40 voxels of PERSON_VOXEL


def small_model_cfg() -> EasyDict:
    """The person SECOND with a narrow, shallow BEV backbone: fast enough for tests on 2 CPU cores."""
    return second_model_cfg(num_filters=(32, 64), upsample_filters=(64, 64), layer_nums=(1, 1))


def small_optim_cfg(lr: float = 0.003) -> EasyDict:
    return EasyDict(OPTIMIZER="adam_onecycle", LR=lr, WEIGHT_DECAY=0.0, MOMS=[0.95, 0.85], PCT_START=0.4,
                    DIV_FACTOR=10, GRAD_NORM_CLIP=10, BATCH_SIZE_PER_GPU=4, NUM_EPOCHS=1)
