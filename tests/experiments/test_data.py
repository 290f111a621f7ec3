"""What data the reproduction asks for, and that imported recordings are used instead of simulated stand-ins."""
import logging

import numpy as np
import pytest

from pcdet_memslidar.datasets.mixing import Source, split_sources
from pcdet_memslidar.errors import ConfigError, OutputError
from pcdet_memslidar.experiments.reproduce import RUNS, frames_needed, model_config, prepare_domain, reproduce
from pcdet_memslidar.experiments.runs import check_run_config, runs_at_once
from pcdet_memslidar.io.layout import KittiLayout, write_frame
from pcdet_memslidar.sim.writer import SETTINGS_FILE


def test_frames_needed_per_profile(tmp_path):
    smoke = frames_needed({model: model_config(model, "smoke", tmp_path) for model in RUNS})
    assert {name: source.count for name, source in smoke.items()} == \
        {"sim": 20, "real": 20, "industrial": 8, "industrial_seed1": 20}
    assert smoke["real"].root == tmp_path / "real"
    oracle = smoke["industrial_seed1"]  # the oracle's training frames: the test domain, another simulation seed
    assert (oracle.root, oracle.domain, oracle.seed) == (tmp_path / "industrial_seed1", "industrial", 1)
    assert (smoke["industrial"].domain, smoke["industrial"].seed) == ("industrial", 0)
    paper = frames_needed({model: model_config(model, "paper", tmp_path) for model in RUNS})
    assert {name: source.count for name, source in paper.items()} == \
        {"sim": 2100, "real": 2100, "industrial": 230, "industrial_seed1": 2100}


def test_test_frames_come_from_the_profiles_and_the_test_split_reads_them_all(tmp_path):
    quick = frames_needed({model: model_config(model, "quick", tmp_path) for model in RUNS})
    assert quick["industrial"].count == 230  # COUNT null: the industrial preset's frames, the paper's split
    smoke = frames_needed({model: model_config(model, "smoke", tmp_path) for model in RUNS})
    assert smoke["industrial"].count == 8  # PROFILES.smoke: DATA_CONFIG.TEST_SOURCE.COUNT
    cfg = model_config("M3", "smoke", tmp_path, ["DATA_CONFIG.TEST_SOURCE.COUNT", "5"])
    assert frames_needed({"M3": cfg})["industrial"].count == 5
    assert split_sources(cfg.DATA_CONFIG, "test", tmp_path)[0].count is None  # every frame of the folder
    cfg = model_config("M3", "smoke", tmp_path, ["DATA_CONFIG.TEST_SOURCE.COUNT", "0"])
    with pytest.raises(ConfigError, match="DATA_CONFIG.TEST_SOURCE.COUNT is 0: give a positive number of frames"):
        frames_needed({"M3": cfg})


def test_one_folder_of_two_domains_is_refused(tmp_path):
    cfgs = {model: model_config(model, "smoke", tmp_path) for model in ("M1", "oracle")}
    cfgs["oracle"].DATA_CONFIG.MIX.SOURCES[0].NAME = "industrial"  # seed 1 frames in the test split's folder
    with pytest.raises(ConfigError, match="give one of them another NAME"):
        frames_needed(cfgs)


def test_overrides_reach_every_model(tmp_path):
    cfg = model_config("M4", "smoke", tmp_path, ["DATA_CONFIG.MIX.TOTAL", "10", "OPTIMIZATION.NUM_EPOCHS", "3"])
    assert cfg.DATA_CONFIG.MIX.TOTAL == 10 and cfg.OPTIMIZATION.NUM_EPOCHS == 3
    assert cfg.DATA_CONFIG.DATA_PATH == str(tmp_path) and cfg.PROFILE == "smoke"


def test_imported_recordings_are_not_overwritten(tmp_path):
    root = tmp_path / "real"
    layout = KittiLayout(root)
    box = np.array([[10.0, 0.0, 0.88, 0.8, 0.6, 1.76, 0.0]])
    for index in range(3):
        points = np.c_[np.random.default_rng(index).uniform(5, 15, (50, 3)), np.ones(50)].astype(np.float32)
        write_frame(layout, f"{index:06d}", points, ["Pedestrian"], box, {"source": "import"})
    before = {path: path.read_bytes() for path in root.rglob("*") if path.is_file()}
    prepare_domain(Source("real", root, 20), logging.getLogger("test"))
    after = {path: path.read_bytes() for path in root.rglob("*") if path.is_file()}
    assert after == before and not (root / SETTINGS_FILE).exists()


def test_run_folder_of_another_config_is_refused(tmp_path):
    run_dir = tmp_path / "models" / "M1" / "seed_0"
    check_run_config(model_config("M1", "smoke", tmp_path), run_dir)
    check_run_config(model_config("M1", "smoke", tmp_path), run_dir)  # same config: reused
    with pytest.raises(ConfigError, match="trained with another config"):
        check_run_config(model_config("M1", "smoke", tmp_path, ["OPTIMIZATION.NUM_EPOCHS", "2"]), run_dir)


def test_out_that_holds_the_data_and_bad_counts_are_refused_before_anything_is_written(tmp_path):
    data = tmp_path / "data"
    with pytest.raises(OutputError, match=rf"--out {tmp_path} contains the input {data}/sim; choose --out outside"):
        reproduce("smoke", 1, tmp_path, data)
    with pytest.raises(OutputError, match=rf"--out {data}/real is the input {data}/real"):
        reproduce("smoke", 1, data / "real", data)
    for seeds, jobs, workers, message in ((0, 1, 0, "--seeds must be >= 1, got 0"), (1, 0, 0, "--jobs must be >= 1"),
                                          (1, 1, -1, r"--workers must be >= 0 \(0: load data in the training")):
        with pytest.raises(ConfigError, match=message):
            reproduce("smoke", seeds, tmp_path / "out", data, workers=workers, jobs=jobs)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("key, value, message", [
    ("OPTIMIZATION.LR", ".nan", r"OPTIMIZATION.LR is nan: the learning rate must be a positive finite number"),
    ("OPTIMIZATION.BATCH_SIZE_PER_GPU", "0", r"OPTIMIZATION.BATCH_SIZE_PER_GPU is 0: it must be a positive integer"),
    ("OPTIMIZATION.NUM_EPOCHS", "-2", r"OPTIMIZATION.NUM_EPOCHS is -2: it must be a positive integer"),
])
def test_reproduce_checks_its_configs_as_train_does(tmp_path, key, value, message):
    with pytest.raises(ConfigError, match=message):
        model_config("M3", "smoke", tmp_path, [key, value])


@pytest.mark.parametrize("runs, jobs, at_once", [(5, 5, 5), (11, 5, 4), (8, 5, 4), (6, 5, 3), (15, 5, 5), (5, 2, 2),
                                                 (1, 5, 1), (7, 1, 1), (12, 12, 12)])
def test_runs_at_once_fills_the_last_wave(runs, jobs, at_once):
    assert runs_at_once(runs, jobs) == at_once
