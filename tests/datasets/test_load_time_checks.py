"""`memslidar train` refuses bad configs, options and splits before its first training step, with the key, the bad
value and the fix: a wrong TEST_SOURCE, POINT_CLOUD_RANGE, batch size, learning rate, epochs and seeds."""
import re
from pathlib import Path

import pytest

from pcdet_memslidar import cli
from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets import MEMSLidarDataset
from pcdet_memslidar.datasets.mixing import split_sources
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.runtime import train as train_tool

CFGS = Path(__file__).resolve().parents[2] / "cfgs"


def _train_error(capsys, output: Path, *arguments: str) -> str:
    """The error line of a `memslidar train` that must exit 2 before writing anything under `output`."""
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["train", "--cfg", str(CFGS / "m3.yaml"), "--output_dir", str(output), "--workers", "0",
                  *arguments])
    assert exit_info.value.code == 2
    assert not output.exists()
    return capsys.readouterr().err.strip()


def test_a_wrong_test_source_fails_before_the_first_training_step(memslidar_data, tmp_path, monkeypatch, capsys):
    def train_model(*args, **kwargs):
        raise AssertionError("training started before the test split was checked")

    monkeypatch.setattr(train_tool, "train_model", train_model)
    output = tmp_path / "output"
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["train", "--cfg", str(CFGS / "m3.yaml"), "--output_dir", str(output), "--workers", "0", "--set",
                  "PROFILE", "smoke", "DATA_CONFIG.DATA_PATH", str(memslidar_data),
                  "DATA_CONFIG.TEST_SOURCE.NAME", "industrail"])
    assert exit_info.value.code == 2
    source = memslidar_data / "industrail"
    assert capsys.readouterr().err.strip().splitlines()[-1] == (  # after the log lines
        f"memslidar train: error: {source}: folder of source 'industrail' (DATA_CONFIG.TEST_SOURCE, split 'test') "
        f"not found; DATA_PATH {memslidar_data} holds ['industrial', 'real', 'sim']: fix the source's NAME or PATH, "
        f"or make its frames with `memslidar import --format <format> --src <recordings> --out {source}` with "
        f"annotated frames")
    assert not list(output.rglob("*.pth"))


def test_point_cloud_range_must_be_six_numbers(tmp_path, capsys):
    scalar = tmp_path / "scalar.yaml"
    scalar.write_text(f"_BASE_CONFIG_: {CFGS / 'm3.yaml'}\nDATA_CONFIG:\n    POINT_CLOUD_RANGE: 5\n")
    with pytest.raises(SystemExit):
        cli.main(["train", "--cfg", str(scalar), "--output_dir", str(tmp_path / "output")])
    assert capsys.readouterr().err.strip() == (
        f"memslidar train: error: {scalar.resolve()}: DATA_CONFIG.POINT_CLOUD_RANGE is 5: it needs 6 finite numbers "
        f"[x_min, y_min, z_min, x_max, y_max, z_max] in m; fix it in the config (or --set)")
    assert not (tmp_path / "output").exists()
    error = _train_error(capsys, tmp_path / "output", "--set", "DATA_CONFIG.POINT_CLOUD_RANGE", "[0, -10, 0, 40, 10]")
    assert error.endswith("m3.yaml: DATA_CONFIG.POINT_CLOUD_RANGE is [0, -10, 0, 40, 10]: it needs 6 finite numbers "
                          "[x_min, y_min, z_min, x_max, y_max, z_max] in m; fix it in the config (or --set)")


@pytest.mark.parametrize("arguments, message", [
    (["--batch_size", "0"], "--batch-size 0: must be a positive integer; pass 1 or more, or leave it out to use "
                            "OPTIMIZATION.BATCH_SIZE_PER_GPU of the config"),
    (["--batch_size", "-2"], "--batch-size -2: must be a positive integer"),
    (["--set", "OPTIMIZATION.BATCH_SIZE_PER_GPU", "0"],
     "m3.yaml: OPTIMIZATION.BATCH_SIZE_PER_GPU is 0: it must be a positive integer; set it to 1 or more (in the "
     "config, its profile or --set OPTIMIZATION.BATCH_SIZE_PER_GPU N)"),
    (["--epochs", "0"], "--epochs 0: must be a positive integer; pass 1 or more, or leave it out to use "
                        "OPTIMIZATION.NUM_EPOCHS of the config"),
    (["--set", "OPTIMIZATION.LR", "-0.001"],
     "m3.yaml: OPTIMIZATION.LR is -0.001: the learning rate must be a positive finite number; set it in the config, "
     "its profile or with --set OPTIMIZATION.LR VALUE"),
    (["--set", "OPTIMIZATION.LR", ".nan"], "m3.yaml: OPTIMIZATION.LR is nan: the learning rate must be a positive"),
    (["--set", "PROFILE", "smoke", "OPTIMIZATION.LR"],
     "--set needs KEY VALUE pairs, got an odd number of items ['PROFILE', 'smoke', 'OPTIMIZATION.LR']: "
     "'OPTIMIZATION.LR' has no value; add one (--set OPTIMIZATION.LR VALUE) or remove it"),
    (["--set", "PROFILE", "smoke", "--seed", "-1"],
     "--set --seed: '--seed' looks like an option, but everything after --set is read as KEY VALUE pairs; put "
     "--seed before --set"),
])
def test_bad_batch_size_learning_rate_epochs_and_set_fail_before_any_output(tmp_path, capsys, arguments, message):
    error = _train_error(capsys, tmp_path / "output", *arguments)
    assert error.startswith("memslidar train: error: ") and message in error


def test_train_and_test_have_no_seed_option(tmp_path, capsys):
    for command in ("train", "test"):
        with pytest.raises(SystemExit) as exit_info:
            cli.main([command, "--cfg", str(CFGS / "m3.yaml"), "--seed", "-1"])
        assert exit_info.value.code == 2
        assert "unrecognized arguments: --seed -1" in capsys.readouterr().err


def test_seeds_of_the_mix_must_be_non_negative_integers(memslidar_data):
    cfg = load_config(CFGS / "m3.yaml", ["PROFILE", "smoke", "DATA_CONFIG.DATA_PATH", str(memslidar_data),
                                         "DATA_CONFIG.MIX.SPLIT_SEED", "-1"])
    with pytest.raises(ConfigError, match=re.escape("DATA_CONFIG.MIX.SPLIT_SEED is -1: a seed must be a non-negative "
                                                    "integer (0, 1, ...); fix it in the config (or --set)")):
        MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=True)
    sources = "[{NAME: industrial_seed1, SEED: -1, RATIO: 1}]"
    cfg = load_config(CFGS / "oracle.yaml", ["DATA_CONFIG.MIX.SOURCES", sources, "DATA_CONFIG.TEST_SOURCE.SEED", "1.5"])
    with pytest.raises(ConfigError, match=re.escape("DATA_CONFIG.MIX.SOURCES[0].SEED (source 'industrial_seed1') is "
                                                    "-1: a seed must be a non-negative integer")):
        split_sources(cfg.DATA_CONFIG, "train", memslidar_data)
    with pytest.raises(ConfigError, match=re.escape("DATA_CONFIG.TEST_SOURCE.SEED (source 'industrial') is 1.5")):
        split_sources(cfg.DATA_CONFIG, "test", memslidar_data)


def test_an_unknown_box_fold_fails_naming_the_choices(memslidar_data, tmp_path, capsys):
    steps = ("[{NAME: fold_box_headings, FOLD: third}, {NAME: transform_points_to_voxels, "
             "VOXEL_SIZE: [0.1, 0.1, 0.06], MAX_POINTS_PER_VOXEL: 5, "
             "MAX_NUMBER_OF_VOXELS: {train: 40000, test: 40000}}]")
    error = _train_error(capsys, tmp_path / "output", "--set", "PROFILE", "smoke", "DATA_CONFIG.DATA_PATH",
                         str(memslidar_data), "DATA_CONFIG.DATA_PROCESSOR", steps)
    assert error.splitlines()[-1].endswith(
        "DATA_PROCESSOR fold_box_headings: FOLD is 'third'; use one of quarter, half")
