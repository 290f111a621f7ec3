"""DatasetTemplate: OpenPCDet's dataset contract without OpenPCDet (numpy augmentation, spconv voxelisation).

A subclass provides __len__, __getitem__ (which builds {points (N, 3+C), gt_names (M,), gt_boxes (M, 7), frame_id,
metadata} and returns prepare_data(...)), evaluation and generate_prediction_dicts.
"""
from __future__ import annotations

import logging
import re
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

from pcdet_memslidar.datasets.processor import DataProcessor, PointFeatureEncoder, take_points
from pcdet_memslidar.errors import ConfigError, DataFormatError, OutputError
from pcdet_memslidar.geometry.background import BackgroundModel

USER_ERRORS = (DataFormatError, ConfigError, OutputError)  # the errors whose message names the file and the fix
BACKGROUND_FEATURE = "background_depth"  # a src feature computed from the site's background model, not stored


class DatasetTemplate(torch.utils.data.Dataset):
    """Holds the point-cloud range, feature encoder, augmentor (training only) and processor of DATA_CONFIG."""

    def __init__(self, dataset_cfg=None, class_names=None, training: bool = True, root_path=None, logger=None):
        self.dataset_cfg = dataset_cfg
        self.training = training
        self.class_names = list(class_names)
        self.logger = logger or logging.getLogger(__name__)
        self.root_path = Path(root_path) if root_path is not None else Path(dataset_cfg.DATA_PATH)
        self.point_cloud_range = np.array(dataset_cfg.POINT_CLOUD_RANGE, dtype=np.float32)
        self.point_feature_encoder = PointFeatureEncoder(dataset_cfg.POINT_FEATURE_ENCODING, self.point_cloud_range)
        self.background = self._background_model(dataset_cfg)
        self.foreground_only = self._foreground_only(dataset_cfg)
        self.data_augmentor = None  # set by the subclass once it knows its gt databases (training only)
        self.data_processor = DataProcessor(dataset_cfg.DATA_PROCESSOR, self.point_cloud_range, training,
                                            self.point_feature_encoder.num_point_features)
        self.grid_size = self.data_processor.grid_size
        self.voxel_size = self.data_processor.voxel_size
        self.depth_downsample_factor = None
        self.total_epochs = 0
        self._merge_all_iters_to_one_epoch = False
        self.rng = np.random.default_rng(torch.initial_seed())  # a fixed torch seed gives reproducible samples
        self._worker_seed = None

    @staticmethod
    def _background_model(dataset_cfg) -> BackgroundModel | None:
        """The site's background model (DATA_CONFIG.BACKGROUND_MODEL, a path; None where not set); ConfigError
        naming the key where src_feature_list names BACKGROUND_FEATURE without it."""
        named = BACKGROUND_FEATURE in dataset_cfg.POINT_FEATURE_ENCODING.src_feature_list
        if not named and not dataset_cfg.get("BACKGROUND_MODEL"):
            return None
        if not dataset_cfg.get("BACKGROUND_MODEL"):
            raise ConfigError(f"POINT_FEATURE_ENCODING.src_feature_list names {BACKGROUND_FEATURE}: set "
                              f"DATA_CONFIG.BACKGROUND_MODEL to the site's background.npz (memslidar site train "
                              f"writes it)")
        return BackgroundModel.load(dataset_cfg.BACKGROUND_MODEL)

    def _foreground_only(self, dataset_cfg) -> bool:
        """DATA_CONFIG.FOREGROUND_ONLY (default False): keep only the points whose background_depth is above 0;
        ConfigError naming the key where the points carry no background_depth."""
        gate = dataset_cfg.get("FOREGROUND_ONLY", False)
        if not isinstance(gate, bool):
            raise ConfigError(f"DATA_CONFIG.FOREGROUND_ONLY is {gate!r}: use True or False")
        if gate and BACKGROUND_FEATURE not in self.point_feature_encoder.src_feature_list:
            raise ConfigError(f"DATA_CONFIG.FOREGROUND_ONLY needs {BACKGROUND_FEATURE} in "
                              f"POINT_FEATURE_ENCODING.src_feature_list (and DATA_CONFIG.BACKGROUND_MODEL)")
        return gate

    def point_features(self, points: np.ndarray) -> np.ndarray:
        """(N, 4) points as stored [x, y, z, intensity] (ground frame) -> (N, len(src_feature_list)): with
        BACKGROUND_FEATURE, each point's background_depth [m] appended (geometry.background). The one place the
        feature is computed: training, test and detect read frames through it."""
        if BACKGROUND_FEATURE not in self.point_feature_encoder.src_feature_list:
            return points
        return np.concatenate([points[:, :4], self.background.depth(points)[:, None]], axis=1).astype(np.float32)

    @property
    def mode(self) -> str:
        return "train" if self.training else "test"

    def reseed(self, seed) -> None:
        """Seed the generator behind augmentation and shuffling (an int, or a sequence of ints). Until then it is
        seeded from torch's seed (torch.initial_seed(): the one set by torch.manual_seed, as OpenPCDet's and our
        set_random_seed do; random otherwise), so any loader with 0 workers gives reproducible samples."""
        self.rng = np.random.default_rng(seed)

    @property
    def generator(self) -> np.random.Generator:
        """The augmentation / shuffling generator. Inside a DataLoader worker it is reseeded from torch's seed of
        that worker (new every epoch), whichever worker_init_fn the loader has (ours or OpenPCDet's)."""
        info = torch.utils.data.get_worker_info()
        if info is not None and self._worker_seed != info.seed:
            self._worker_seed = info.seed
            self.reseed(info.seed)
        return self.rng

    def merge_all_iters_to_one_epoch(self, merge: bool = True, epochs: int | None = None) -> None:
        """Make one pass over the loader cover `epochs` epochs (OpenPCDet's --merge_all_iters_to_one_epoch)."""
        self._merge_all_iters_to_one_epoch = merge
        self.total_epochs = epochs if merge else 0

    def prepare_data(self, data_dict: dict) -> dict | None:
        """Augment (training), keep the trained classes, encode features, mask, shuffle and voxelise.

        Input: points (N, 4), gt_names (M,), gt_boxes (M, 7), frame_id, metadata. Output adds gt_boxes (M, 8)
        float32 with the 1-based class id in column 8, use_lead_xyz, voxels (V, P, C) float32, voxel_coords
        (V, 3) int32 [z, y, x], voxel_num_points (V,) int32; drops gt_names. Returns None for a training frame
        left without boxes (the caller replaces the frame).
        """
        if self.training:
            if "gt_boxes" not in data_dict:
                raise ValueError("training samples need gt_boxes")
            gt_boxes_mask = np.array([name in self.class_names for name in data_dict["gt_names"]], dtype=bool)
            data_dict = self.data_augmentor.forward({**data_dict, "gt_boxes_mask": gt_boxes_mask}, self.generator)
        if data_dict.get("gt_boxes") is not None:
            names = np.asarray(data_dict["gt_names"])
            selected = np.array([name in self.class_names for name in names], dtype=bool)
            classes = np.array([self.class_names.index(name) + 1 for name in names[selected]], dtype=np.float32)
            boxes = np.asarray(data_dict["gt_boxes"], dtype=np.float32).reshape(-1, data_dict["gt_boxes"].shape[-1])
            data_dict["gt_boxes"] = np.concatenate([boxes[selected, :7], classes[:, None]], axis=1)
            data_dict["gt_names"] = names[selected]
        data_dict["points"] = np.asarray(data_dict["points"], dtype=np.float32)
        if self.foreground_only:  # background returns out, with their times
            column = self.point_feature_encoder.src_feature_list.index(BACKGROUND_FEATURE)
            take_points(data_dict, data_dict["points"][:, column] > 0)
        data_dict = self.point_feature_encoder.forward(data_dict)
        data_dict = self.data_processor.forward(data_dict, self.generator)
        if self.training and len(data_dict["gt_boxes"]) == 0:
            return None
        data_dict.pop("gt_names", None)
        return data_dict

    @staticmethod
    def collate_batch(batch_list: list[dict], _unused: bool = False) -> dict:
        """Samples -> one batch_dict with OpenPCDet's keys and dtypes.

        points (sum N, 1+C) and voxel_coords (sum V, 4) get the sample index as first column; voxels,
        voxel_num_points and point_times (sum N,) are concatenated (point_times only where every sample has them);
        gt_boxes are zero-padded to (B, max M, 8) float32; metadata becomes a (B,) object array of dicts; other keys
        are stacked; batch_size is added.
        """
        values = defaultdict(list)
        for sample in batch_list:
            for key, value in sample.items():
                values[key].append(value)
        if len(values.get("point_times", [])) != len(batch_list):  # frames without their points' times in the batch
            values.pop("point_times", None)
        batch = {}
        for key, items in values.items():
            if key in ("voxels", "voxel_num_points", "point_times"):
                batch[key] = np.concatenate(items, axis=0)
            elif key in ("points", "voxel_coords"):
                batch[key] = np.concatenate([np.pad(item, ((0, 0), (1, 0)), constant_values=index)
                                             for index, item in enumerate(items)], axis=0)
            elif key == "gt_boxes":
                padded = np.zeros((len(items), max(len(item) for item in items), items[0].shape[-1]), dtype=np.float32)
                for index, item in enumerate(items):
                    padded[index, :len(item)] = item
                batch[key] = padded
            elif key == "metadata":
                batch[key] = np.empty(len(items), dtype=object)
                batch[key][:] = items
            else:
                batch[key] = np.stack(items, axis=0)
        batch["batch_size"] = len(batch_list)
        return batch


def worker_error(error: Exception) -> Exception | None:
    """The error of ours (USER_ERRORS) that a DataLoader worker raised, rebuilt with its own message from the text
    torch re-raises it as ('Caught DataFormatError in DataLoader worker process 0. Original Traceback ...'); None
    when `error` is anything else."""
    text = str(error)
    header = re.match(r"Caught (\w+) in DataLoader worker process \d+\.\n", text)
    kind = {cls.__name__: cls for cls in USER_ERRORS}.get(header.group(1)) if header else None
    marker = f"\n{kind.__module__}.{kind.__qualname__}: " if kind else ""
    if not marker or marker not in text:
        return None
    message = text[text.rindex(marker) + len(marker):].rstrip("\n")
    if kind is not DataFormatError:
        return kind(message)
    where, _, rest = message.partition(": ")  # DataFormatError's message is '<path>[:<line>]: <what and fix>'
    path_line = re.fullmatch(r"(.+):(\d+)", where)
    return DataFormatError(path_line.group(1), rest, int(path_line.group(2))) if path_line else \
        DataFormatError(where, rest)


def iterate_batches(loader):
    """The batches of `loader`; an error of ours raised inside a DataLoader worker comes out as itself (naming the
    file and the fix) instead of torch's wrapper around the worker's traceback."""
    try:
        yield from loader
    except Exception as error:
        original = worker_error(error)
        if original is None:
            raise
        # torch's frames in these tracebacks hold the loader's iterator in reference cycles; dropping them frees
        # it now, which ends its workers (a garbage collection later would wait 5 s for each)
        chained = error
        while chained is not None:
            chained.__traceback__ = None
            chained = chained.__context__
        raise original from None
