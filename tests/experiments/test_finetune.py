"""M5: pre-training on sim, then fine-tuning on real (runtime.pretrain), in the config, the trainer and the report."""
import json

import pytest

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.experiments.reproduce import model_config, reproduce
from pcdet_memslidar.runtime import train_loop
from pcdet_memslidar.runtime.pretrain import split_stages

pytestmark = pytest.mark.slow  # minutes of training, simulation or installing: `pytest -m 'not slow'` leaves it out


def test_stages_share_the_epochs_and_scale_the_fine_tuning_lr(tmp_path):
    cfg = model_config("M5", "quick", tmp_path, ["PRETRAIN.FINETUNE_LR_SCALE", "0.5"])  # 2 epochs, LR 0.002
    pretraining, finetuning = split_stages(cfg)
    assert [entry.NAME for entry in pretraining.DATA_CONFIG.MIX.SOURCES] == ["sim"]
    assert [entry.NAME for entry in finetuning.DATA_CONFIG.MIX.SOURCES] == ["real"]
    assert (pretraining.OPTIMIZATION.NUM_EPOCHS, finetuning.OPTIMIZATION.NUM_EPOCHS) == (1, 1)
    assert (pretraining.OPTIMIZATION.LR, finetuning.OPTIMIZATION.LR) == (0.002, 0.001)
    assert "PRETRAIN" not in pretraining and "PRETRAIN" not in finetuning and "PRETRAIN" in cfg
    assert cfg.OPTIMIZATION.NUM_EPOCHS == 2  # the config itself is unchanged
    m3 = model_config("M3", "quick", tmp_path)
    assert split_stages(m3) == (None, m3)


def test_too_few_epochs_to_split_name_the_fix(tmp_path):
    with pytest.raises(ConfigError, match=r"m5.yaml: PRETRAIN.EPOCH_SHARE 0.5 of 1 epochs leaves 0 for pre-training "
                                          r"and 1 for fine-tuning; both need at least one: raise "
                                          r"OPTIMIZATION.NUM_EPOCHS \(e.g. --set OPTIMIZATION.NUM_EPOCHS 2\)"):
        split_stages(model_config("M5", "smoke", tmp_path))  # smoke: 1 epoch


def test_m5_fine_tunes_from_its_pretraining_and_gets_a_table3_row(tmp_path, monkeypatch):
    loaded = []
    real_load = train_loop.load_params_from_file

    def spy(model, filename, *args, **kwargs):
        loaded.append(filename)
        return real_load(model, filename, *args, **kwargs)

    monkeypatch.setattr(train_loop, "load_params_from_file", spy)
    out, data = tmp_path / "out", tmp_path / "data"
    results = reproduce("smoke", seeds=1, out=out, data_root=data, jobs=1, models=("M5", "M3"),
                        set_cfgs=["OPTIMIZATION.NUM_EPOCHS", "2"])
    assert list(results["models"]) == ["M3", "M5"]  # Table 3's order, whatever the order asked
    run_dir = out / "models" / "M5" / "seed_0"
    assert loaded == [run_dir / "pretrain" / "ckpt" / "checkpoint_epoch_1.pth"]  # stage 2 starts from stage 1
    assert (run_dir / "ckpt" / "checkpoint_epoch_1.pth").is_file()  # the fine-tuning stage's one epoch
    assert [entry["epoch"] for entry in results["models"]["M5"]["runs"][0]["curve"]] == [1, 2]
    counts = results["models"]["M5"]["counts"]
    assert (counts["sim (pre-training)"]["frames"], counts["real"]["frames"]) == (20, 20)
    text = (out / "report.md").read_text()
    assert "| M5 (not in the paper) | SECOND |" in text
    assert "- M5: `sim (pre-training)` 20 frames (14 train / 6 val), `real` 20 frames (14 train / 6 val)" in text
    m5, m3 = (results["models"][name]["mean"]["AP3D_R40"] for name in ("M5", "M3"))
    assert f"Pre-training on sim and fine-tuning on real (M5, {m5:.3f}) is " in text and f"(M3, {m3:.3f})" in text
    assert "The paper's order cannot be checked" in text
    assert json.loads((out / "results.json").read_text())["models"]["M5"]["cfg"] == "cfgs/m5.yaml"


def test_unknown_models_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="--models M6: choose from M1 M2 M3 M4 M5 oracle"):
        reproduce("smoke", seeds=1, out=tmp_path / "out", data_root=tmp_path / "data", models=("M6",))
