"""gt_sampling: paste people cut from other training frames of the same domain into a frame (SECOND's GT-AUG).

The database of a domain holds, per object, the points inside its box relative to the box centre (one float32 .bin
of (K, 4) [x, y, z, intensity] per object) and db infos {class: [{name, path, frame_id, gt_idx, box3d_lidar,
num_points_in_gt, ...}]}. A frame only receives objects from its own domain's database (its `metadata['source']`),
pasted at their original place; a candidate whose BEV box overlaps any box already in the frame is rejected.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pcdet_memslidar.errors import ConfigError, DataFormatError
from pcdet_memslidar.geometry.boxes import enlarge_box3d, points_in_boxes_mask
from pcdet_memslidar.geometry.iou import boxes_iou_bev


@dataclass
class GtDatabase:
    """The objects one domain offers: `root` (its dataset folder) and db infos {class: [info, ...]}."""

    root: Path
    infos: dict


def parse_class_numbers(entries, what: str) -> dict[str, int]:
    """['Pedestrian:10', ...] -> {'Pedestrian': 10}; ConfigError naming `what` for a malformed entry."""
    numbers = {}
    for entry in entries:
        name, sep, number = str(entry).rpartition(":")
        if not sep or not name or not number.lstrip("-").isdigit():
            raise ConfigError(f"{what}: expected entries like 'Pedestrian:10', got {entry!r}")
        numbers[name] = int(number)
    return numbers


class DataBaseSampler:
    """Samples ground-truth objects into scenes; `databases` maps a source name to its GtDatabase."""

    def __init__(self, sampler_cfg, class_names: list[str], databases: dict[str, GtDatabase]):
        self.class_names = list(class_names)
        self.num_point_features = int(sampler_cfg.NUM_POINT_FEATURES)
        self.remove_extra_width = np.asarray(sampler_cfg.get("REMOVE_EXTRA_WIDTH", [0.0, 0.0, 0.0]), dtype=np.float64)
        self.limit_whole_scene = bool(sampler_cfg.get("LIMIT_WHOLE_SCENE", False))
        self.sample_groups = parse_class_numbers(sampler_cfg.SAMPLE_GROUPS, "gt_sampling SAMPLE_GROUPS")
        min_points = parse_class_numbers(sampler_cfg.get("PREPARE", {}).get("filter_by_min_points", []),
                                         "gt_sampling PREPARE.filter_by_min_points")
        self.databases = {}
        for source, database in databases.items():
            infos = {name: [info for info in database.infos.get(name, [])
                            if info["num_points_in_gt"] >= min_points.get(name, 0)]
                     for name in self.class_names}
            self.databases[source] = GtDatabase(Path(database.root), infos)

    def __call__(self, data_dict: dict, rng: np.random.Generator) -> dict:
        """Add sampled objects to data_dict's points, gt_boxes, gt_names and gt_boxes_mask."""
        source = data_dict["metadata"]["source"]
        if source not in self.databases:
            raise ConfigError(f"gt_sampling has no database for source {source!r} "
                              f"(it has {sorted(self.databases)}): run `memslidar create-infos --cfg ...`")
        database = self.databases[source]
        existing = np.asarray(data_dict["gt_boxes"], dtype=np.float64)[:, :7]
        sampled_infos, sampled_boxes = [], []
        for name, group in self.sample_groups.items():
            count = group - int(np.sum(data_dict["gt_names"] == name)) if self.limit_whole_scene else group
            pool = database.infos.get(name, [])
            if count <= 0 or not pool:
                continue
            candidates = [pool[i] for i in rng.choice(len(pool), size=min(count, len(pool)), replace=False)]
            boxes = np.array([info["box3d_lidar"] for info in candidates], dtype=np.float64).reshape(-1, 7)
            for info, box in zip(candidates, boxes):
                occupied = np.concatenate([existing] + sampled_boxes).reshape(-1, 7)
                if len(occupied) and boxes_iou_bev(box[None], occupied).max() > 0:
                    continue
                sampled_infos.append(info)
                sampled_boxes.append(box[None])
        if not sampled_infos:
            return data_dict
        return self._add_to_scene(data_dict, database.root, sampled_infos, np.concatenate(sampled_boxes))

    def _add_to_scene(self, data_dict: dict, root: Path, infos: list[dict], boxes: np.ndarray) -> dict:
        """Remove scene points inside the (enlarged) sampled boxes, then add the objects' own points."""
        object_points = []
        for info, box in zip(infos, boxes):
            path = root / info["path"]
            if not path.is_file():
                raise DataFormatError(path, "gt database file is missing: re-run `memslidar create-infos --cfg ...`")
            points = np.fromfile(path, dtype=np.float32)
            if points.size % self.num_point_features:
                raise DataFormatError(path, f"size {points.size} is not a multiple of NUM_POINT_FEATURES "
                                            f"{self.num_point_features}: re-run `memslidar create-infos --cfg ...`")
            points = points.reshape(-1, self.num_point_features)
            points[:, :3] += box[:3].astype(np.float32)
            object_points.append(points)
        scene = data_dict["points"]
        inside = points_in_boxes_mask(scene[:, :3], enlarge_box3d(boxes, self.remove_extra_width)).any(axis=1)
        gt_boxes = np.asarray(data_dict["gt_boxes"])
        new_boxes = np.zeros((len(boxes), gt_boxes.shape[1]), dtype=gt_boxes.dtype)
        new_boxes[:, :7] = boxes
        return {
            **data_dict,
            "points": np.concatenate([*object_points, scene[~inside]]).astype(scene.dtype),
            "gt_boxes": np.concatenate([gt_boxes, new_boxes]),
            "gt_names": np.concatenate([data_dict["gt_names"], np.array([info["name"] for info in infos])]),
            "gt_boxes_mask": np.concatenate([data_dict["gt_boxes_mask"], np.ones(len(infos), dtype=bool)]),
        }
