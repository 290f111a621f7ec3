"""MEMSLidarDataset: the mixed sim/real training set, its validation part and the industrial test split.

DATA_SPLIT[mode] picks what is read: 'train' / 'val' are the 70 / 30 parts of every MIX source (Table 2 counts),
'test' is every frame of TEST_SOURCE. Frames come from each source's KITTI-layout folder through its info file
(`memslidar create-infos`). A sample's frame_id is '<source>/<frame id>'; metadata = {'source', 'frame_id'}.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from pcdet_memslidar.datasets.augmentor import DataAugmentor, GtDatabase
from pcdet_memslidar.datasets.dataset import DatasetTemplate
from pcdet_memslidar.datasets.infos import load_db_infos, load_domain_infos
from pcdet_memslidar.datasets.mixing import make_frames_command, source_split, split_sources
from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.geometry.calibration import Calibration
from pcdet_memslidar.io import kitti
from pcdet_memslidar.io.layout import KittiLayout

MAX_REPLACEMENTS = 100  # training frames left without boxes are replaced by random others, at most this often


def _template_bases() -> tuple[type, ...]:
    """Our DatasetTemplate, plus OpenPCDet's when an installed OpenPCDet provides it (so isinstance checks hold)."""
    if importlib.util.find_spec("pcdet") is None:
        return (DatasetTemplate,)
    try:
        from pcdet.datasets.dataset import DatasetTemplate as PcdetDatasetTemplate
    except (ImportError, OSError):  # an OpenPCDet checkout whose compiled ops do not load: ours alone
        return (DatasetTemplate,)
    return (DatasetTemplate, PcdetDatasetTemplate)


class MEMSLidarDataset(*_template_bases()):
    """OpenPCDet dataset over data/memslidar/<source>/ folders; see the module docstring for the splits."""

    def __init__(self, dataset_cfg, class_names, training: bool = True, root_path=None, logger=None):
        DatasetTemplate.__init__(self, dataset_cfg=dataset_cfg, class_names=class_names, training=training,
                                 root_path=root_path, logger=logger)
        self.split = dataset_cfg.DATA_SPLIT[self.mode]
        self.sources = split_sources(dataset_cfg, self.split, self.root_path)
        self.infos, databases = [], {}
        for source in self.sources:
            self._check_folder(source)
            domain_infos = load_domain_infos(source)
            frame_ids = set(source_split(source, [info["frame_id"] for info in domain_infos], self.split, dataset_cfg,
                                         source.root))
            infos = [{**info, "source": source.name, "root": source.root}
                     for info in domain_infos if info["frame_id"] in frame_ids]
            for info in infos:  # a 'pedestrian' box would silently be background
                kitti.check_class_case(KittiLayout(source.root).label(info["frame_id"]), info["annos"]["name"],
                                       self.class_names)
            self.infos += infos
            if training:
                databases[source.name] = self._gt_database(source, frame_ids)
        if training:
            self._check_has_boxes()
            self.data_augmentor = DataAugmentor(dataset_cfg.DATA_AUGMENTOR, self.class_names, databases)
        self.logger.info(f"MEMSLidarDataset {self.split}: {len(self.infos)} frames from "
                         f"{', '.join(f'{s.name} ({self.source_counts().get(s.name, 0)})' for s in self.sources)}")

    def _check_folder(self, source) -> None:
        """DataFormatError naming the folder, the config key and the fixes when `source`'s folder is missing."""
        if source.root.is_dir():
            return
        key = "DATA_CONFIG.TEST_SOURCE" if self.split == "test" else "DATA_CONFIG.MIX.SOURCES"
        folders = sorted(path.name for path in self.root_path.iterdir() if path.is_dir()) \
            if self.root_path.is_dir() else []
        raise DataFormatError(source.root, f"folder of source '{source.name}' ({key}, split '{self.split}') not "
                                           f"found; DATA_PATH {self.root_path} holds {folders or 'no folders'}: fix "
                                           f"the source's NAME or PATH, or make its frames with "
                                           f"{make_frames_command(source, source.count)}")

    @staticmethod
    def _gt_database(source, frame_ids: set[str]) -> GtDatabase:
        """The source's gt database restricted to the objects of this split's frames."""
        db_infos = load_db_infos(source)
        return GtDatabase(source.root, {name: [info for info in infos if info["frame_id"] in frame_ids]
                                        for name, infos in db_infos.items()})

    def _check_has_boxes(self) -> None:
        boxes = sum(int(np.isin(info["annos"]["name"], self.class_names).sum()) for info in self.infos)
        if boxes == 0:
            names = sorted({str(name) for info in self.infos for name in info["annos"]["name"]})
            raise DataFormatError(self.root_path, f"split '{self.split}' ({len(self.infos)} frames from "
                                                  f"{[s.name for s in self.sources]}) has no box of the classes "
                                                  f"{self.class_names} (label names found: {names}); label people "
                                                  f"as Pedestrian or fix CLASS_NAMES")

    def source_counts(self) -> dict[str, int]:
        """{source name: frames of this split}."""
        names, counts = np.unique([info["source"] for info in self.infos], return_counts=True)
        return dict(zip(names.tolist(), counts.tolist()))

    @property
    def sample_sources(self) -> list[str]:
        """(len,) source name of every frame, in index order (for MixedBatchSampler)."""
        return [info["source"] for info in self.infos]

    def __len__(self) -> int:
        if self._merge_all_iters_to_one_epoch:
            return len(self.infos) * self.total_epochs
        return len(self.infos)

    def __getitem__(self, index: int) -> dict:
        """The prepared sample of frame `index`; in training a frame left without boxes is replaced by another."""
        index = index % len(self.infos)
        for _ in range(MAX_REPLACEMENTS + 1):
            data_dict = self.prepare_data(self.get_frame(index))
            if data_dict is not None:
                return data_dict
            index = int(self.generator.integers(len(self.infos)))
        raise RuntimeError(f"{MAX_REPLACEMENTS + 1} training frames in a row had no box left after augmentation "
                           f"and POINT_CLOUD_RANGE cropping: check that the range covers the labelled people")

    def get_frame(self, index: int) -> dict:
        """Raw input of frame `index`: points (N, 4+) float32 (point_features), gt_names (M,), gt_boxes (M, 7),
        frame_id, metadata; in testing also point_times (N,) float32 [s] where the frame keeps its time offsets (the
        box step's drift)."""
        info = self.infos[index]
        layout = KittiLayout(info["root"])
        frame = {
            "points": self.point_features(kitti.read_points(layout.velodyne(info["frame_id"]))),
            "gt_names": np.asarray(info["annos"]["name"]),
            "gt_boxes": np.asarray(info["annos"]["gt_boxes_lidar"], dtype=np.float32).reshape(-1, 7),
            "frame_id": f"{info['source']}/{info['frame_id']}",
            "metadata": {"source": info["source"], "frame_id": info["frame_id"]},
        }
        times = layout.time_offset(info["frame_id"])
        if not self.training and times.is_file():
            frame["point_times"] = kitti.read_point_times(times, len(frame["points"]))
        return frame

    def gt_annos(self) -> list[dict]:
        """Ground truth of every frame: {frame_id, name (M,), boxes_lidar (M, 7)}."""
        return [{"frame_id": f"{info['source']}/{info['frame_id']}", "name": np.asarray(info["annos"]["name"]),
                 "boxes_lidar": np.asarray(info["annos"]["gt_boxes_lidar"], dtype=np.float64).reshape(-1, 7)}
                for info in self.infos]

    def aligned_annos(self, det_annos: list[dict]) -> tuple[list[dict], list[dict]]:
        """(gt_annos(), det_annos in the same frame order, an empty anno for a frame without detections);
        ValueError for detections of frames that are not in this split."""
        gt_annos = self.gt_annos()
        by_frame = {str(anno["frame_id"]): anno for anno in det_annos}
        unknown = sorted(set(by_frame) - {anno["frame_id"] for anno in gt_annos})
        if unknown:
            raise ValueError(f"detections for frames not in split '{self.split}': {unknown[:5]}")
        empty = {"name": np.zeros(0, dtype=str), "score": np.zeros(0), "boxes_lidar": np.zeros((0, 7))}
        return gt_annos, [by_frame.get(anno["frame_id"], empty) for anno in gt_annos]

    def evaluation(self, det_annos: list[dict], class_names, **kwargs) -> tuple[str, dict]:
        """AP (3D / BEV IoU 0.5, R40 / R11, per distance bin) of det_annos against this split's ground truth.

        det_annos: generate_prediction_dicts output, any order (frames without detections may be left out).
        Returns (a table per class, {key: float}) with the evaluator's keys (AP3D_R40, ..., num_gt, num_dt),
        prefixed with '<class>/' when there is more than one class.
        """
        from pcdet_memslidar.evaluation import evaluate, format_results
        gt_annos, dt_annos = self.aligned_annos(det_annos)
        texts, scalars = [], {}
        for class_name in class_names:
            result = evaluate(gt_annos, dt_annos, class_name=class_name)
            prefix = f"{class_name}/" if len(class_names) > 1 else ""
            texts.append(f"{class_name} ({self.split}, {len(gt_annos)} frames)\n{format_results(result)}")
            scalars.update({f"{prefix}{key}": float(value) for key, value in result.items() if key.startswith("AP")})
            scalars[f"{prefix}num_gt"] = float(result["num_gt"]["all"])
            scalars[f"{prefix}num_dt"] = float(result["num_dt"]["all"])
        return "\n".join(texts), scalars

    def generate_prediction_dicts(self, batch_dict: dict, pred_dicts: list[dict], class_names,
                                  output_path=None) -> list[dict]:
        """Model outputs -> annos {frame_id, name, score, boxes_lidar, pred_labels}; with output_path, also KITTI
        label_2 files with scores at output_path/<source>/<frame id>.txt."""
        annos = []
        names_table = np.array(list(class_names))
        for index, pred in enumerate(pred_dicts):
            scores = _to_numpy(pred["pred_scores"]).astype(np.float64)
            boxes = _to_numpy(pred["pred_boxes"]).astype(np.float64).reshape(-1, 7)
            labels = _to_numpy(pred["pred_labels"]).astype(np.int64)
            anno = {"frame_id": str(batch_dict["frame_id"][index]), "name": names_table[labels - 1],
                    "score": scores, "boxes_lidar": boxes, "pred_labels": labels}
            annos.append(anno)
            if output_path is not None:
                label = kitti.label_from_boxes(anno["name"], boxes, Calibration.virtual(), scores=scores)
                kitti.write_label(Path(output_path) / f"{anno['frame_id']}.txt", label)
        return annos


def _to_numpy(value) -> np.ndarray:
    return value.detach().cpu().numpy() if hasattr(value, "detach") else np.asarray(value)
