"""`memslidar eval` on KITTI label folders: table, JSON, missing / extra prediction files, bad prediction files."""
import json
from pathlib import Path

import numpy as np
import pytest

from pcdet_memslidar.cli import main
from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.evaluation.folders import evaluate_folders
from pcdet_memslidar.geometry.calibration import Calibration
from pcdet_memslidar.io.kitti import label_from_boxes, write_label

pytestmark = pytest.mark.filterwarnings("ignore:no ground-truth 'Pedestrian' boxes in the")


def people(*xy):
    return np.array([[x, y, 0.9, 0.6, 0.5, 1.8, 0.3] for x, y in xy], dtype=np.float64)


def write(path: Path, boxes, scores=None):
    write_label(path, label_from_boxes(["Pedestrian"] * len(boxes), boxes, Calibration.virtual(), scores))


@pytest.fixture
def folders(tmp_path):
    gt, pred = tmp_path / "gt", tmp_path / "pred"
    write(gt / "000000.txt", people((5, 1), (12, -2)))
    write(gt / "000001.txt", people((25, 3)))
    write(gt / "000002.txt", people((8, 0)))  # no prediction file: a frame without detections
    write(pred / "000000.txt", people((5, 1), (12, -2), (14, 5)), np.array([0.9, 0.8, 0.7]))
    write(pred / "000001.txt", people((25, 3)), np.array([0.6]))
    write(pred / "000099.txt", people((1, 1)), np.array([0.5]))  # no ground truth: skipped
    return gt, pred


def test_json_output_and_frame_counts(folders, capsys):
    gt, pred = folders
    assert main(["eval", "--gt", str(gt), "--pred", str(pred), "--json"]) == 0
    captured = capsys.readouterr()
    values = json.loads(captured.out)
    # 4 people; scores 0.9 hit, 0.8 hit, 0.7 miss, 0.6 hit: (recall, precision) = (1/4, 1), (2/4, 1), (2/4, 2/3),
    # (3/4, 3/4): 20 of the 40 recall positions get 1, the next 10 get 3/4, the last 10 are never reached
    assert values["AP3D_R40"] == pytest.approx((20 + 10 * 0.75) / 40, abs=1e-12)
    assert values["APBEV_R11"] == pytest.approx((6 + 2 * 0.75) / 11, abs=1e-12)
    assert values["AP3D_R40_0-10m"] == pytest.approx(0.5, abs=1e-12)  # 1 of the 2 people within 10 m
    assert values["AP3D_R40_20+m"] == 1.0
    assert values["num_gt"] == {"all": 4, "0-10m": 2, "10-20m": 1, "20+m": 1}
    assert (values["frames"], values["missing_predictions"], values["predictions_without_gt"]) == (3, 1, 1)
    assert "1 without a prediction file" in captured.err


def test_table_output(folders, capsys):
    gt, pred = folders
    assert main(["eval", "--gt", str(gt), "--pred", str(pred)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["range", "#gt", "#det", "AP3D_R40", "AP3D_R11", "APBEV_R40", "APBEV_R11"]
    assert lines[1].split()[:4] == ["all", "4", "4", "0.6875"]


def test_predictions_without_scores_are_rejected(folders, capsys):
    gt, pred = folders
    write(pred / "000001.txt", people((25, 3)))
    with pytest.raises(SystemExit) as exit_info:
        main(["eval", "--gt", str(gt), "--pred", str(pred)])
    assert exit_info.value.code == 2
    assert "000001.txt: prediction labels need a 16th column" in capsys.readouterr().err
    with pytest.raises(DataFormatError, match=r"000001.txt: prediction labels need a 16th column"):
        evaluate_folders(gt, pred)


def test_missing_folder_is_named(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["eval", "--gt", str(tmp_path / "nope"), "--pred", str(tmp_path)])
    assert exit_info.value.code == 2
    assert "nope: label folder not found" in capsys.readouterr().err


def test_pedestrian_in_another_case_is_an_error_naming_file_and_line(folders, capsys):
    gt, pred = folders
    write_label(gt / "000001.txt", label_from_boxes(["Pedestrian", "pedestrian"], people((25, 3), (30, 0)),
                                                    Calibration.virtual()))
    with pytest.raises(SystemExit) as exit_info:
        main(["eval", "--gt", str(gt), "--pred", str(pred)])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.strip() == (
        f"memslidar eval: error: {gt / '000001.txt'}:2: class 'pedestrian' is not 'Pedestrian' (class names are "
        f"case-sensitive), so its objects would not count; rename it to Pedestrian")
    write(gt / "000001.txt", people((25, 3)))
    write_label(pred / "000000.txt", label_from_boxes(["PEDESTRIAN"], people((5, 1)), Calibration.virtual(), [0.9]))
    with pytest.raises(DataFormatError, match=r"pred/000000\.txt:1: class 'PEDESTRIAN' is not 'Pedestrian'"):
        evaluate_folders(gt, pred)


def test_other_classes_are_left_out_and_unknown_ones_are_reported(folders, capsys):
    gt, pred = folders
    names = ["Car", "Person", "Pedestrian", "DontCare", "Person"]
    write_label(gt / "000001.txt", label_from_boxes(names, people((40, 9), (30, 0), (25, 3), (35, -9), (31, 4)),
                                                    Calibration.virtual()))
    assert main(["eval", "--gt", str(gt), "--pred", str(pred), "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["num_gt"]["all"] == 4  # as before: only the Pedestrian objects count
    assert captured.err.splitlines()[0] == (
        f"warning: {gt / '000001.txt'}:2: class 'Person' is not evaluated (only Pedestrian is): 2 object(s) in 1 "
        f"file(s) of {gt} left out; rename them to Pedestrian if they are people")
    assert "Car" not in captured.err and "DontCare" not in captured.err


def test_a_byte_order_mark_keeps_the_first_box(folders, capsys):
    gt, pred = folders
    path = gt / "000000.txt"
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())  # "UTF-8 with BOM", as some editors save
    assert main(["eval", "--gt", str(gt), "--pred", str(pred), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["num_gt"]["all"] == 4
