"""The whole M1-M4 reproduction with the smoke profile: data, infos, four trainings, evaluation, figures, report.

One run (module fixture) is checked for complete tables and figures and for numbers that equal what the evaluator
gives on the saved predictions, both through `memslidar eval --json` and from the in-memory detections; the evaluator
itself gives the exact AP of known predictions on the same test set, and the counts are those of the label files.
"""
import contextlib
import io
import json
import logging
import pickle
import re

import pytest

from pcdet_memslidar.cli import main as memslidar
from pcdet_memslidar.evaluation import ap_summary, evaluate
from pcdet_memslidar.evaluation.folders import read_label_folder
from pcdet_memslidar.experiments.publish import blocks, run_kind, store_run, stored_runs
from pcdet_memslidar.experiments.report import table2, table3
from pcdet_memslidar.experiments.reproduce import FINAL_TEST_SEED, MODELS, RUNS, model_config, reproduce
from pcdet_memslidar.experiments.runs import train_detector
from pcdet_memslidar.io.kitti import CLASS_NAME
from pcdet_memslidar.runtime.eval_loop import split_config
from pcdet_memslidar.runtime.predict import predict
from pcdet_memslidar.sim.site import get_domain
from pcdet_memslidar.sim.writer import simulate_dataset

pytestmark = pytest.mark.slow  # minutes of training, simulation or installing: `pytest -m 'not slow'` leaves it out

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


def person_lines(path) -> list[list[str]]:
    """The fields of the person lines of a KITTI label file."""
    return [line.split() for line in path.read_text().splitlines() if line.split()[:1] == [CLASS_NAME]]


def known_predictions(gt_dir, pred_dir) -> tuple[int, int]:
    """Prediction files made from the ground-truth label text: the people of the first half of the frames as labelled
    (score 0.9), the others moved 50 m sideways (camera x; score 0.5), where no labelled box is. Returns (people kept,
    people)."""
    pred_dir.mkdir()
    frames = sorted(gt_dir.glob("*.txt"))
    kept = people = 0
    for index, path in enumerate(frames):
        lines = []
        for fields in person_lines(path):
            people += 1
            if index < len(frames) // 2:
                kept += 1
                lines.append(" ".join(fields + ["0.9"]))
            else:
                lines.append(" ".join(fields[:11] + [f"{float(fields[11]) + 50.0:.2f}"] + fields[12:] + ["0.5"]))
        (pred_dir / path.name).write_text("".join(line + "\n" for line in lines))
    return kept, people


def test_the_evaluator_gives_the_exact_ap_of_known_predictions_on_the_test_set(smoke, tmp_path):
    """All true positives score above all false positives: precision 1 up to recall kept / people, then none, so
    R40 = floor(40 kept / people) / 40 and R11 = (floor(10 kept / people) + 1) / 11, for 3D and BEV alike."""
    _, data, _ = smoke
    gt_dir = data / "industrial" / "training" / "label_2"
    kept, people = known_predictions(gt_dir, tmp_path / "known")
    assert 0 < kept < people
    known = evaluator_json(gt_dir, tmp_path / "known")
    r40, r11 = (40 * kept // people) / 40, (10 * kept // people + 1) / 11
    assert [known[key] for key in ("AP3D_R40", "APBEV_R40", "AP3D_R11", "APBEV_R11")] == pytest.approx(
        [r40, r40, r11, r11], abs=1e-12)
    assert known["num_gt"]["all"] == known["num_dt"]["all"] == people


def test_results_are_the_evaluators_on_the_saved_predictions_counted_from_the_label_files(smoke):
    out, data, _ = smoke
    stored = json.loads((out / "results.json").read_text())
    gt_dir = data / "industrial" / "training" / "label_2"
    people = sum(len(person_lines(path)) for path in gt_dir.glob("*.txt"))
    for model in RUNS:
        run = stored["models"][model]["runs"][0]
        pred_dir = out / run["predictions"]
        assert sorted(path.name for path in pred_dir.glob("*.txt")) == sorted(path.name for path in
                                                                               gt_dir.glob("*.txt"))
        detections = sum(len(person_lines(path)) for path in pred_dir.glob("*.txt"))
        assert run["num_gt"]["all"] == people > 0 and run["num_dt"]["all"] == detections, model
        evaluator = evaluator_json(gt_dir, pred_dir)  # exact on known predictions (the test above)
        for key, value in evaluator.items():
            if key.startswith("AP"):
                assert run["metrics"][key] == value, (model, key)
        assert run["num_gt"] == evaluator["num_gt"] and run["num_dt"] == evaluator["num_dt"]
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
    assert {"data: sim", "data: real", "data: industrial", "data: industrial_seed1", "data: industrial_final", "infos",
            "figures", "train and evaluate 5 models (2 at once)", "untouched test seed"} == set(stages)
    assert sum(stages.values()) <= stored["wall_seconds"]
    assert stored["profile"] == "smoke" and stored["environment"]["libraries"]["torch"]
    assert stored["models"] == json.loads(json.dumps(results["models"]))  # returned == written


def test_the_untouched_seed_is_scored_from_its_own_frames_with_the_same_checkpoints(smoke):
    """Stage 5: every model's final checkpoint predicts the industrial split of FINAL_TEST_SEED (other frames than the
    test split's), its AP is the evaluator's on those predictions, and the report shows that table."""
    out, data, results = smoke
    final = results["final_test"]
    assert final["seed"] == FINAL_TEST_SEED and final["test_domain"] == "industrial"
    final_gt, test_gt = (data / name / "training" / "label_2" for name in ("industrial_final", "industrial"))
    assert sorted(p.name for p in final_gt.iterdir()) == sorted(p.name for p in test_gt.iterdir())
    assert [p.read_text() for p in sorted(final_gt.iterdir())] != [p.read_text() for p in sorted(test_gt.iterdir())]
    assert set(final["models"]) == set(results["models"])
    for model in final["models"].values():
        run, = model["runs"]
        assert "industrial_final" in run["predictions"]
        metrics = evaluator_json(final_gt, out / run["predictions"])
        assert run["metrics"]["AP3D_R40"] == pytest.approx(metrics["AP3D_R40"], abs=1e-9)
    text = (out / "report.md").read_text()
    assert f"seed {FINAL_TEST_SEED}" in text
    assert all(line in text for line in table3(json.loads((out / "results.json").read_text())["final_test"]))


def test_docs_renders_table3_of_the_run_with_its_header(smoke, tmp_path):
    out, _, _ = smoke
    readme = tmp_path / "README.md"
    readme.write_text("<!-- BEGIN GENERATED table3 -->\n<!-- END GENERATED table3 -->\n")
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "results.md").write_text("<!-- BEGIN GENERATED results -->\n<!-- END GENERATED results -->\n")
    store_run(out, tmp_path)
    rendered = blocks(stored_runs(tmp_path))
    stored = json.loads((out / "results.json").read_text())
    assert set(table3(stored)) <= set(rendered["results"])
    assert "commit" in rendered["results"][2] and "pytest smoke" in rendered["results"][2]
    _, name = run_kind(stored)  # smoke_<cpu>_<vector code>: one stored run per CPU
    assert name.startswith("smoke_")
    assert (tmp_path / "docs" / "figures" / f"table3_{name}_ap_intervals.png").read_bytes()[:8] == PNG_MAGIC


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


def test_every_run_records_its_epoch_time_and_the_val_ap_of_its_checkpoint(smoke, tmp_path):
    """The epoch's minutes lie between the training loop's own epoch time (its log; the curve's clock also holds the
    first batch's loading and the checkpoint's saving) and the run's training time; the validation AP is that of the
    epoch's checkpoint on the mix's val split, predicted again from the file (M3: both sources)."""
    out, data, results = smoke
    for model in RUNS:
        run = results["models"][model]["runs"][0]
        curve = run["curve"]
        assert [entry["epoch"] for entry in curve] == [1]
        log = (out / "models" / model / "seed_0" / "log.txt").read_text()
        epoch_seconds = float(re.search(r"epoch 1/1: loss \S+, ([\d.]+) s", log).group(1))
        assert epoch_seconds - 0.1 <= 60 * curve[0]["minutes"] <= run["seconds"]["train"] + 0.03, model  # rounding
    curve = results["models"]["M3"]["runs"][0]["curve"]
    cfg = split_config(model_config("M3", "smoke", data), "val")
    checkpoint = out / "models" / "M3" / "seed_0" / "ckpt" / "checkpoint_epoch_1.pth"
    again = predict(cfg, checkpoint, tmp_path / "val", logging.getLogger("test_smoke"))
    assert (curve[0]["val_AP3D_R40"], curve[0]["val_APBEV_R40"]) == (again["AP3D_R40"], again["APBEV_R40"])
