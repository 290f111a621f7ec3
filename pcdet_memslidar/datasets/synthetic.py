"""A tiny in-memory person dataset with OpenPCDet's dataset contract, for tests and benchmarks without data.

Each frame: a flat ground (z = 0) sampled sparsely, a few upright person-sized boxes whose visible surface (the
half facing the sensor at the origin) is sampled with points, and a little clutter. Deterministic by seed.
"""
from __future__ import annotations

import numpy as np
from torch.utils.data import Dataset

from pcdet_memslidar.datasets.dataset import DatasetTemplate
from pcdet_memslidar.datasets.processor.data_processor import VoxelGenerator
from pcdet_memslidar.geometry.boxes import rotate_points_along_z
from pcdet_memslidar.grid import grid_size
from pcdet_memslidar.io.kitti import CLASS_NAME


def person_points(box: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count, 3) points on the sensor-facing half of an elliptic cylinder inscribed in box (7,)."""
    facing = np.arctan2(-box[1], -box[0]) - box[6]  # direction to the sensor in the box frame
    angle = facing + rng.uniform(-np.pi / 2, np.pi / 2, count)
    local = np.stack([0.5 * box[3] * np.cos(angle), 0.5 * box[4] * np.sin(angle),
                      rng.uniform(-0.5, 0.5, count) * box[5]], axis=1)
    return rotate_points_along_z(local, box[6]) + box[:3]


class SyntheticPersonDataset(Dataset):
    """`num_frames` frames of 1-3 people (frame i seeded by seed + i), voxelised as OpenPCDet batches.

    OpenPCDet's dataset attributes: class_names, point_cloud_range, voxel_size, grid_size,
    point_feature_encoder.num_point_features (4: x, y, z, intensity).
    """

    collate_batch = staticmethod(DatasetTemplate.collate_batch)  # the batches of MEMSLidarDataset

    class _Encoder:
        num_point_features = 4

    def __init__(self, point_cloud_range, voxel_size, num_frames: int = 8, seed: int = 0, training: bool = True,
                 max_points_per_voxel: int = 5, max_voxels: int = 40000, empty_frames: tuple[int, ...] = (),
                 no_box_frames: tuple[int, ...] = ()):
        self.class_names = [CLASS_NAME]
        self.point_cloud_range = np.asarray(point_cloud_range, dtype=np.float32)
        self.voxel_size = list(voxel_size)
        self.grid_size = grid_size(self.point_cloud_range, voxel_size)
        self.point_feature_encoder = self._Encoder()
        self.training = training
        self.voxel_generator = VoxelGenerator(voxel_size, self.point_cloud_range, 4, max_points_per_voxel, max_voxels)
        self.frames = [self._make_frame(index, seed + index, index in empty_frames, index in no_box_frames)
                       for index in range(num_frames)]

    def _make_frame(self, index: int, seed: int, empty: bool, no_boxes: bool) -> dict:
        rng = np.random.default_rng(seed)
        x0, y0, _, x1, y1, _ = self.point_cloud_range.tolist()
        boxes = []
        while not no_boxes and len(boxes) < rng.integers(1, 4):
            centre = rng.uniform([x0 + 1.5, y0 + 1.5], [x1 - 1.5, y1 - 1.5])
            if all(np.hypot(*(centre - b[:2])) > 1.2 for b in boxes):
                size = rng.uniform([0.5, 0.4, 1.55], [0.7, 0.6, 1.9])
                boxes.append(np.array([*centre, size[2] / 2, *size, rng.uniform(-np.pi, np.pi)]))
        boxes = np.array(boxes, dtype=np.float32).reshape(-1, 7)
        ground = np.column_stack([rng.uniform(x0, x1, 600), rng.uniform(y0, y1, 600), rng.normal(0.02, 0.01, 600)])
        clutter = np.column_stack([rng.uniform(x0, x1, 40), rng.uniform(y0, y1, 40), rng.uniform(0.0, 0.3, 40)])
        people = [person_points(box, 250, rng) for box in boxes]
        points = np.concatenate([ground, clutter, *people]).astype(np.float32)
        points = np.column_stack([points, rng.uniform(0, 1, len(points))]).astype(np.float32)
        if empty:
            points = points[:0]
        return {"frame_id": f"{index:06d}", "points": points, "gt_boxes": boxes,
                "gt_names": np.array([CLASS_NAME] * len(boxes))}

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, index: int) -> dict:
        """Frame `index` as DatasetTemplate.prepare_data gives one: points (N, 4), gt_boxes (M, 8) with class 1,
        voxels, voxel_coords (V, 3) [z, y, x], voxel_num_points, frame_id."""
        frame = self.frames[index]
        voxels, coords, num_points = self.voxel_generator.generate(frame["points"])
        gt_boxes = np.column_stack([frame["gt_boxes"], np.ones(len(frame["gt_boxes"]), np.float32)])
        return {"frame_id": frame["frame_id"], "points": frame["points"], "gt_boxes": gt_boxes.astype(np.float32),
                "voxels": voxels, "voxel_coords": coords, "voxel_num_points": num_points}

    def generate_prediction_dicts(self, batch_dict: dict, pred_dicts: list[dict], class_names, output_path=None):
        """Per frame {name, score, boxes_lidar, pred_labels, frame_id} numpy annotations (OpenPCDet's format)."""
        annos = []
        for index, pred in enumerate(pred_dicts):
            labels = pred["pred_labels"].cpu().numpy()
            annos.append({"name": np.array(class_names)[labels - 1], "score": pred["pred_scores"].cpu().numpy(),
                          "boxes_lidar": pred["pred_boxes"].cpu().numpy(), "pred_labels": labels,
                          "frame_id": batch_dict["frame_id"][index]})
        return annos

    def aligned_annos(self, det_annos: list[dict]) -> tuple[list[dict], list[dict]]:
        """(ground truth of the frames of det_annos, det_annos), frame by frame."""
        by_id = {frame["frame_id"]: frame for frame in self.frames}
        gt_annos = [{"name": by_id[d["frame_id"]]["gt_names"], "boxes_lidar": by_id[d["frame_id"]]["gt_boxes"]}
                    for d in det_annos]
        return gt_annos, det_annos

    def evaluation(self, det_annos: list[dict], class_names, **kwargs) -> tuple[str, dict]:
        """AP of the Pedestrian class at IoU 0.5 (pcdet_memslidar.evaluation) -> (report text, scalars)."""
        from pcdet_memslidar.evaluation import evaluate, format_results

        result = evaluate(*self.aligned_annos(det_annos))
        return format_results(result), result
