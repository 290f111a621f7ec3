"""The dataset under training and testing: reproducible under a fixed seed without our loader, damaged info files
named with the command that rebuilds them, and errors inside DataLoader workers shown as themselves."""
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from torch._utils import ExceptionWrapper
from torch.utils.data import DataLoader, Dataset

from pcdet_memslidar import cli
from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets import MEMSLidarDataset, build_dataloader
from pcdet_memslidar.datasets.dataset import iterate_batches, worker_error
from pcdet_memslidar.errors import ConfigError, DataFormatError
from pcdet_memslidar.runtime.common import set_random_seed
from pcdet_memslidar.runtime.eval_loop import eval_one_epoch
from pcdet_memslidar.runtime.train_loop import train_model

REPO = Path(__file__).resolve().parents[2]
REBUILD = r"rebuild it with `memslidar create-infos --cfg <the config you train or test with> --force`"


@pytest.fixture
def data(memslidar_data, tmp_path) -> Path:
    """A copy of the made data that a test may damage."""
    return Path(shutil.copytree(memslidar_data, tmp_path / "memslidar"))


def _cfg(data_path: Path):
    return load_config(REPO / "cfgs" / "m3.yaml", ["PROFILE", "smoke", "DATA_CONFIG.DATA_PATH", str(data_path)])


def test_a_fixed_seed_gives_the_same_augmented_samples_without_our_loader(memslidar_data):
    cfg = _cfg(memslidar_data)

    def first_batch(seed: int) -> dict:
        set_random_seed(seed)  # what OpenPCDet's --fix_random_seed does before its build_dataloader
        dataset = MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=True)
        loader = DataLoader(dataset, batch_size=2, shuffle=True, num_workers=0, collate_fn=dataset.collate_batch)
        return next(iter(loader))

    first, again, other = first_batch(666), first_batch(666), first_batch(667)
    for key in ("points", "gt_boxes", "voxels"):
        assert np.array_equal(first[key], again[key]), key
    assert not np.array_equal(first["points"], other["points"])


def test_damaged_info_files_name_the_file_and_the_command_that_rebuilds_them(data, capsys):
    cfg = _cfg(data)
    info = data / "sim" / "memslidar_infos.pkl"
    intact = info.read_bytes()
    info.write_bytes(intact[:len(intact) // 2])
    with pytest.raises(DataFormatError, match=rf"sim/memslidar_infos.pkl: info file of source 'sim' cannot be read "
                                              rf"\(truncated or corrupt: .+\): {REBUILD}"):
        MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=True)
    info.write_bytes(pickle.dumps([1, 2]))
    with pytest.raises(DataFormatError, match=rf"info file of source 'sim' cannot be read \(not what create-infos "
                                              rf"writes: a list\): {REBUILD}"):
        MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=True)
    info.write_bytes(intact)
    (data / "real" / "memslidar_dbinfos.pkl").write_bytes(b"\x80\x04garbage")
    with pytest.raises(DataFormatError, match=rf"real/memslidar_dbinfos.pkl: gt database of source 'real' cannot be "
                                              rf"read \(truncated or corrupt: .+\): {REBUILD}"):
        MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=True)
    # create-infos rebuilds an unreadable info file, and says so
    info.write_bytes(b"")
    capsys.readouterr()
    assert cli.main(["create-infos", "--cfg", str(REPO / "cfgs" / "m3.yaml"), "--set", "PROFILE", "smoke",
                     "DATA_CONFIG.DATA_PATH", str(data)]) == 0
    assert "sim/memslidar_infos.pkl: info file of source 'sim' cannot be read (truncated or corrupt: EOFError: Ran " \
           "out of input)" in capsys.readouterr().out
    assert pickle.loads(info.read_bytes())["infos"]


class _Failing(Dataset):
    """Raises `error` for every sample."""

    def __init__(self, error: Exception):
        self.error = error

    def __len__(self) -> int:
        return 2

    def __getitem__(self, index):
        raise self.error


def test_errors_of_ours_come_out_of_dataloader_workers_as_themselves():
    error = DataFormatError("frames/label.txt", "column 3 is not a number: fix the label", line=7)
    loader = DataLoader(_Failing(error), batch_size=1, num_workers=1)
    with pytest.raises(DataFormatError) as caught:
        list(iterate_batches(loader))
    assert str(caught.value) == "frames/label.txt:7: column 3 is not a number: fix the label"
    assert (caught.value.path, caught.value.line) == (Path("frames/label.txt"), 7)
    with pytest.raises(ConfigError, match="^DATA_CONFIG.X is wrong: fix it$"):
        list(iterate_batches(DataLoader(_Failing(ConfigError("DATA_CONFIG.X is wrong: fix it")), num_workers=1)))
    # a bug keeps torch's worker traceback (a worker here would make torch wait 5 s to end it)
    try:
        raise ZeroDivisionError("a bug")
    except ZeroDivisionError:
        wrapped = ExceptionWrapper(where="in DataLoader worker process 0")
    with pytest.raises(ZeroDivisionError, match="Caught ZeroDivisionError in DataLoader worker process 0") as bug:
        wrapped.reraise()
    assert worker_error(bug.value) is None


def test_a_truncated_point_file_read_by_a_worker_is_named_in_training_and_evaluation(data):
    cfg = _cfg(data)
    truncated = r"velodyne/\d{6}.bin: size \d+ bytes is not a multiple of 16 .*: truncated or not a velodyne .bin file"
    _, test_loader, _ = build_dataloader(cfg.DATA_CONFIG, cfg.CLASS_NAMES, batch_size=2, dist=False, workers=1,
                                         training=False)
    _, train_loader, _ = build_dataloader(cfg.DATA_CONFIG, cfg.CLASS_NAMES, batch_size=2, dist=False, workers=1,
                                          training=True)
    for points in data.glob("*/training/velodyne/*.bin"):  # damaged after the infos were checked
        points.write_bytes(points.read_bytes()[:-3])
    stub = torch.nn.Module()  # the first batch fails before the model is used
    with pytest.raises(DataFormatError, match=f"industrial/training/{truncated}"):
        eval_one_epoch(cfg, stub, test_loader, 1, None, "cpu")
    with pytest.raises(DataFormatError, match=truncated):
        train_model(stub, None, train_loader, None, cfg.OPTIMIZATION, 0, 1, 0, 0, None, data / "ckpt", "cpu")
