"""Figures on hand-made results (no training): example frames chosen by their rule, valid PNGs."""
import numpy as np
import pytest

from pcdet_memslidar.evaluation.figures import (
    choose_example_frames,
    close_people,
    labels_below,
    plot_ap_vs_time,
    plot_example_frames,
    plot_frame,
    plot_pr_curves,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def person(x, y, heading=0.0):
    return [x, y, 0.88, 0.8, 0.6, 1.76, heading]


def test_close_people_counts():
    assert close_people(np.array([person(10, 0)])) == 0
    assert close_people(np.array([person(10, 0), person(10, 1.0), person(20, 5)])) == 2


def test_example_frames_chosen_by_their_documented_rule():
    easy = np.array([person(12, 0)])
    deviating = np.array([person(15, 3), person(22, -4)])
    crowded = np.array([person(18, 0), person(18, 0.9), person(18.9, 0.4), person(17.2, 0.5)])
    gt = [deviating, easy, crowded]
    exact = [{"boxes_lidar": boxes, "score": np.ones(len(boxes))} for boxes in gt]
    shifted = [dict(exact[0], boxes_lidar=deviating + [0.35, 0, 0, 0, 0, 0, 0]), exact[1], exact[2]]
    chosen = choose_example_frames(gt, {"M1": shifted, "M2": shifted, "M3": exact, "M4": exact})
    assert [(e.role, e.index) for e in chosen] == [("easy", 1), ("deviating", 0), ("crowded", 2)]
    assert "4 of 4 people" in chosen[2].why and "4 (model, person) pairs" in chosen[1].why
    # predictions below the score threshold count as missing
    faint = [dict(anno, score=np.full(len(anno["score"]), 0.05)) for anno in exact]
    assert [e.index for e in choose_example_frames(gt, {"M1": faint})] == [1, 0, 2]


@pytest.mark.slow
def test_figures_are_written(tmp_path):
    rng = np.random.default_rng(0)
    boxes = np.array([person(12, 0), person(14, 1)])
    points = np.c_[rng.uniform(5, 20, (500, 2)), rng.uniform(0, 2, 500), rng.uniform(0, 1, 500)]
    annos = [{"boxes_lidar": boxes + 0.1, "score": np.array([0.9, 0.2])}]
    curve = {"recall": np.array([0.5, 1.0]), "precision": np.array([1.0, 0.5])}
    paths = [
        plot_example_frames(tmp_path / "ex.png", [{"points": points, "gt_boxes": boxes, "title": "t"}],
                            {"M1": annos, "M2": annos}),
        plot_pr_curves(tmp_path / "pr.png", {"M1": {"3D": curve, "BEV": curve}}, {"M1": {"3D": 0.7, "BEV": None}}),
        plot_ap_vs_time(tmp_path / "t.png", [{"name": "M1", "ms_per_frame": 100.0, "ap": 0.5, "group": "run"},
                                             {"name": "x", "ms_per_frame": 50.0, "ap": None, "group": "bench"}]),
        plot_frame(tmp_path / "f.png", points, boxes, "frame", predictions=boxes + 0.1),
        plot_frame(tmp_path / "empty.png", np.zeros((0, 4)), np.zeros((0, 7)), "no points, no people"),
    ]
    for path in paths:
        assert path.read_bytes()[:8] == PNG_MAGIC and path.stat().st_size > 5000
    # no temporary files left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.png", "ex.png", "f.png", "pr.png", "t.png"]


def test_the_lower_of_two_close_points_gets_its_label_below():
    """The reproduction's M3 / M4 case: 0.4 ms and 0.02 AP apart on a 43 ms axis; M2 and M1 stand alone."""
    entries = [{"ms_per_frame": ms, "ap": ap} for ms, ap in
               [(114.9, 0.331), (114.5, 0.312), (127.1, 0.246), (139.5, 0.254), (157.0, 0.494)]]
    assert labels_below(entries) == [False, True, False, False, False]
    # equal points: neither is higher, both labels stay above; 0.05 AP apart is close, 0.0625 is not
    assert labels_below([{"ms_per_frame": 1.0, "ap": 0.5}] * 2) == [False, False]
    assert labels_below([{"ms_per_frame": 1.0, "ap": 0.25}, {"ms_per_frame": 1.0, "ap": 0.3125}]) == [False, False]
    assert labels_below([{"ms_per_frame": 1.0, "ap": 0.25}, {"ms_per_frame": 1.0, "ap": 0.3}]) == [True, False]
