"""The whole M1-M4 reproduction with the smoke profile: data, infos, four trainings, evaluation, figures, report.

One run (module fixture) is checked for complete tables and figures and for numbers that equal what the evaluator
gives on the saved predictions, both through `memslidar eval --json` and from the in-memory detections.
"""
import contextlib
import io
import json
import logging
import pickle

import pytest

from pcdet_memslidar.cli import main as memslidar
from pcdet_memslidar.evaluation import ap_summary, evaluate
from pcdet_memslidar.evaluation.folders import read_label_folder
from pcdet_memslidar.experiments.report import table2, table3
from pcdet_memslidar.experiments.reproduce import MODELS, RUNS, model_config, reproduce
from pcdet_memslidar.experiments.runs import train_detector
from pcdet_memslidar.sim.site import get_domain
from pcdet_memslidar.sim.writer import simulate_dataset

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SMOKE_COUNTS = {"M1": (0, 20), "M2": (20, 0), "M3": (10, 10), "M4": (14, 6)}  # Table 2 at TOTAL 20: sim, real


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    out, data = tmp_path_factory.mktemp("reproduce"), tmp_path_factory.mktemp("data")
    results = reproduce("smoke", seeds=1, out=out, data_root=data, workers=0, command="pytest smoke", jobs=2)
    return out, data, results


def evaluator_json(gt_dir, pred_dir) -> dict:
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert memslidar(["eval", "--gt", str(gt_dir), "--pred", str(pred_dir), "--json"]) == 0
    return json.loads(stdout.getvalue())


def test_results_equal_the_evaluators_json(smoke):
    out, data, _ = smoke
    stored = json.loads((out / "results.json").read_text())
    gt_dir = data / "industrial" / "training" / "label_2"
    num_gt = sum(len(anno["name"]) for anno in read_label_folder(gt_dir, with_score=False).values())
    for model in RUNS:
        run = stored["models"][model]["runs"][0]
        pred_dir = out / run["predictions"]
        assert len(list(pred_dir.glob("*.txt"))) == stored["data"]["industrial"]["frames"]  # one file per frame
        evaluator = evaluator_json(gt_dir, pred_dir)
        for key, value in evaluator.items():
            if key.startswith("AP"):
                assert run["metrics"][key] == value, (model, key)
        assert run["num_gt"] == evaluator["num_gt"] and run["num_gt"]["all"] == num_gt > 0
        assert stored["models"][model]["mean"]["AP3D_R40"] == run["metrics"]["AP3D_R40"]
        assert run["metrics"]["ms_per_frame"] > 0


def test_saved_predictions_match_the_in_memory_detections(smoke):
    out, data, _ = smoke
    stored = json.loads((out / "results.json").read_text())
    gt = read_label_folder(data / "industrial" / "training" / "label_2", with_score=False)
    for model in RUNS:
        det_annos = pickle.loads((out / "models" / model / "seed_0" / "eval" / "result.pkl").read_bytes())
        by_frame = {anno["frame_id"].split("/")[-1]: anno for anno in det_annos}
        assert set(by_frame) == set(gt)
        result = evaluate([gt[frame] for frame in sorted(gt)], [by_frame[frame] for frame in sorted(gt)])
        for key, value in ap_summary(result).items():
            expected = stored["models"][model]["runs"][0]["metrics"][key]
            assert (value is None and expected is None) or value == pytest.approx(expected, abs=1e-6), (model, key)


def test_table2_counts_as_built(smoke):
    _, _, results = smoke
    for model, (sim, real) in SMOKE_COUNTS.items():
        counts = results["models"][model]["counts"]
        assert (counts["sim"]["frames"], counts["real"]["frames"]) == (sim, real)
        for source in counts.values():
            assert source["train"] + source["val"] == source["frames"]
            if source["frames"] % 10 == 0:  # the stable split is exactly 70/30 in every block of 10 frames
                assert source["val"] == 3 * source["frames"] // 10


def test_report_complete_and_consistent(smoke):
    out, data, results = smoke
    text = (out / "report.md").read_text()
    stored = json.loads((out / "results.json").read_text())
    for line in table2(stored) + table3(stored):  # the tables as rendered from results.json are in the report
        assert line in text
    for model in RUNS:
        label = model if model in MODELS else f"{model} (not in the paper)"
        assert f"| {label} | SECOND | {stored['models'][model]['mean']['AP3D_R40']:.3f}" in text  # then its interval
    for name in ("fig3_examples.png", "pr_curves.png", "ap_vs_time.png", "training_curves.png"):
        assert f"]({name})" in text
        assert (out / name).read_bytes()[:8] == PNG_MAGIC
    examples = stored["example_frames"]
    assert [entry["role"] for entry in examples] == ["easy", "deviating", "crowded"]
    assert len({entry["frame_id"] for entry in examples}) == 3
    assert all((data / "industrial" / "training" / "velodyne" / f"{e['frame_id']}.bin").is_file() for e in examples)
    stages = stored["stages"]
    assert {"data: sim", "data: real", "data: industrial", "data: industrial_seed1", "infos", "figures",
            "train and evaluate 5 models (2 at once)"} == set(stages)
    assert sum(stages.values()) <= stored["wall_seconds"]
    assert stored["profile"] == "smoke" and stored["environment"]["libraries"]["torch"]
    assert stored["models"] == json.loads(json.dumps(results["models"]))  # returned == written


def test_second_run_reuses_data_and_models(smoke):
    out, data, _ = smoke
    frames = len(list((data / "industrial" / "training" / "velodyne").glob("*.bin")))
    again = simulate_dataset(get_domain("industrial"), frames, data / "industrial", seed=0, progress=False)
    assert again["written"] == 0 and again["skipped"] == frames
    checkpoint = out / "models" / "M1" / "seed_0" / "ckpt" / "checkpoint_epoch_1.pth"
    before = checkpoint.stat().st_mtime_ns
    cfg = model_config("M1", "smoke", data)
    logger = logging.getLogger("test_smoke")
    assert train_detector(cfg, out / "models" / "M1" / "seed_0", seed=0, workers=0, logger=logger) == checkpoint
    assert checkpoint.stat().st_mtime_ns == before


def test_every_run_records_its_convergence_curve(smoke):
    _, _, results = smoke
    for model in RUNS:
        curve = results["models"][model]["runs"][0]["curve"]
        assert [entry["epoch"] for entry in curve] == [1]
        assert curve[0]["minutes"] > 0 and curve[0]["loss"] > 0 and 0 <= curve[0]["val_AP3D_R40"] <= 1
