"""Bootstrap intervals of AP over the test frames: exact against evaluate() (all-ones and duplicated frames), an
enumerable two-frame case, identical and perfect models, determinism, bad inputs."""
import numpy as np
import pytest

from pcdet_memslidar.evaluation import evaluate
from pcdet_memslidar.evaluation.bootstrap import (
    ap_interval,
    bootstrap_ap,
    difference_interval,
    frame_matches,
    percentile_interval,
    resample_counts,
    weighted_ap,
)

pytestmark = pytest.mark.filterwarnings("ignore:no ground-truth 'Pedestrian' boxes in the")  # empty bins: expected
KEYS = {("3D", "R40"): "AP3D_R40", ("3D", "R11"): "AP3D_R11", ("BEV", "R40"): "APBEV_R40",
        ("BEV", "R11"): "APBEV_R11"}


def person(x, y, z=0.9):
    return [x, y, z, 0.6, 0.5, 1.8, 0.0]


def anno(boxes, scores=None):
    boxes = np.array(boxes, dtype=np.float64).reshape(-1, 7)
    result = {"name": np.array(["Pedestrian"] * len(boxes)), "boxes_lidar": boxes}
    return result if scores is None else result | {"score": np.array(scores, dtype=np.float64)}


def random_scene(frames=12, seed=0):
    """Frames of 0-4 people; detections: jittered hits (some above, some below IoU 0.5 in 3D or BEV), duplicates and
    clutter, scores on a 0.1 grid so that ties cross frames."""
    rng = np.random.default_rng(seed)
    gt, dt = [], []
    for _ in range(frames):
        people = [person(*rng.uniform(3, 30, 2)) for _ in range(rng.integers(0, 5))]
        near = [np.add(people[i], rng.normal(0, 1, 7) * [0.12, 0.12, 0.2, 0, 0, 0, 0])
                for i in rng.integers(0, max(len(people), 1), 2 * len(people))]
        boxes = near + [person(*rng.uniform(3, 30, 2)) for _ in range(rng.integers(0, 3))]
        gt.append(anno(people))
        dt.append(anno(boxes, np.round(rng.uniform(0, 1, len(boxes)), 1)))
    return gt, dt


def test_all_ones_counts_reproduce_evaluate_exactly():
    gt, dt = random_scene()
    expected, matches = evaluate(gt, dt), frame_matches(gt, dt)
    assert 0 < expected["AP3D_R40"] < expected["APBEV_R40"] < 1  # a case with misses, false positives, 3D != BEV
    for (kind, positions), key in KEYS.items():
        assert weighted_ap(matches[kind], np.ones(len(gt), dtype=np.int64))[positions] == expected[key], key
        samples = bootstrap_ap([matches[kind]], np.ones((3, len(gt)), dtype=np.int64))
        assert samples[positions].tolist() == [expected[key]] * 3, key


def test_frame_counts_equal_evaluate_on_duplicated_frames():
    gt, dt = random_scene(seed=1)
    matches = frame_matches(gt, dt)
    for counts in resample_counts(len(gt), resamples=20, seed=3):
        repeated = [frame for frame, count in enumerate(counts) for _ in range(count)]
        expected = evaluate([gt[frame] for frame in repeated], [dt[frame] for frame in repeated])
        for (kind, positions), key in KEYS.items():
            assert weighted_ap(matches[kind], counts)[positions] == expected[key], (counts, key)


# Two frames of one person each. Model a: frame 0 found (0.9), frame 1 a false positive (0.8) and its person missed.
# Resamples (frame 0 twice, once each, frame 1 twice) have probability 1/4, 1/2, 1/4 and AP R40 1, 1/2, 0.
GT = [anno([person(5, 0)]), anno([person(8, 2)])]
MODEL_A = [anno([person(5, 0)], [0.9]), anno([person(15, -5)], [0.8])]
# Model b, the mirror image: frame 1 found (0.9), a false positive (0.8) in frame 0: AP R40 0, 1/2, 1.
MODEL_B = [anno([person(15, -5)], [0.8]), anno([person(8, 2)], [0.9])]


def test_two_frames_hand_computed():
    a = frame_matches(GT, MODEL_A)["3D"]
    for counts, ap_r40, ap_r11 in (([2, 0], 1.0, 1.0), ([1, 1], 0.5, 6 / 11), ([0, 2], 0.0, 0.0)):
        assert weighted_ap(a, np.array(counts)) == {"R40": ap_r40, "R11": pytest.approx(ap_r11, abs=1e-15)}
    counts = resample_counts(2, resamples=1000, seed=0)
    samples = bootstrap_ap([a], counts)["R40"]
    assert set(samples.tolist()) == {0.0, 0.5, 1.0}
    np.testing.assert_array_equal(samples, 1.0 - counts[:, 1] / 2)  # AP = share of frame 0
    assert abs(np.mean(samples == 0.5) - 0.5) < 0.05 and abs(np.mean(samples == 1.0) - 0.25) < 0.05
    assert ap_interval([a]) == (0.0, 1.0)  # both ends hold a quarter of the resamples, far more than 2.5 %
    assert ap_interval([a], level=0.4) == (0.5, 0.5)  # quantiles 0.3 and 0.7 both fall on AP 1/2
    b = frame_matches(GT, MODEL_B)["3D"]
    assert difference_interval([a], [b]) == (-1.0, 1.0)  # a - b: 1, 0, -1 with 1/4, 1/2, 1/4
    assert difference_interval([a], [b], level=0.4) == (0.0, 0.0)
    # seeds of one model: each resample averages a and b (AP 1/2 whatever the frames)
    assert ap_interval([a, b]) == (0.5, 0.5)


def test_identical_models_differ_by_exactly_zero_and_a_perfect_detector_has_ap_one():
    gt, dt = random_scene(seed=2)
    gt = [frame if len(frame["name"]) else anno([person(4, 4)]) for frame in gt]  # ground truth in every frame
    matches, perfect = frame_matches(gt, dt), frame_matches(gt, [frame | {"score": np.ones(len(frame["name"]))}
                                                                 for frame in gt])
    for kind in ("3D", "BEV"):
        for positions in ("R40", "R11"):
            assert difference_interval([matches[kind]], [matches[kind]], positions, resamples=200) == (0.0, 0.0)
            assert ap_interval([perfect[kind]], positions, resamples=200) == (1.0, 1.0)
        low, high = ap_interval([matches[kind]], resamples=200)
        assert 0 < low < evaluate(gt, dt)[KEYS[kind, "R40"]] < high < 1


def test_seed_draws_widen_the_interval_to_the_spread_of_the_seeds():
    """Two seeds of one model, one perfect (AP 1 on any frames) and one blind (AP 0): frames alone give exactly 0.5;
    drawing 2 of the 2 seeds gives 0, 0.5 or 1 with probabilities 1/4, 1/2, 1/4, so the 95 % interval is [0, 1]."""
    gt = [anno([person(4, 4)]), anno([person(6, 2), person(9, -3)]), anno([person(12, 5)])]
    perfect = frame_matches(gt, [frame | {"score": np.ones(len(frame["name"]))} for frame in gt])["3D"]
    blind = frame_matches(gt, [anno([], []) for _ in gt])["3D"]
    counts = resample_counts(3, resamples=1000)
    assert set(bootstrap_ap([perfect, blind], counts)["R40"]) == {0.5}
    seed_counts = resample_counts(2, resamples=1000, seed=1)
    values = bootstrap_ap([perfect, blind], counts, seed_counts)["R40"]
    assert set(values) == {0.0, 0.5, 1.0}
    assert np.array_equal(values, seed_counts[:, 0] / 2)
    assert percentile_interval(values) == (0.0, 1.0)
    assert np.array_equal(resample_counts(1, resamples=5), np.ones((5, 1)))  # one seed: the frames only
    with pytest.raises(ValueError, match="seed counts of shape"):
        bootstrap_ap([perfect, blind], counts, seed_counts[:, :1])


def test_deterministic_for_a_seed():
    gt, dt = random_scene(seed=4)
    runs = [frame_matches(gt, dt)["BEV"]]
    np.testing.assert_array_equal(resample_counts(12, 50, seed=7), resample_counts(12, 50, seed=7))
    assert not np.array_equal(resample_counts(12, 50, seed=7), resample_counts(12, 50, seed=8))
    assert resample_counts(12, 50).sum(axis=1).tolist() == [12] * 50
    assert ap_interval(runs, resamples=100, seed=5) == ap_interval(runs, resamples=100, seed=5)


def test_bad_inputs_raise_one_line():
    gt, dt = random_scene(frames=3)
    three = frame_matches(gt, dt)["3D"]
    two = frame_matches(gt[:2], dt[:2])["3D"]
    with pytest.raises(ValueError, match=r"^bootstrap: the runs cover \[2, 3\] frames; score every run on the same "
                                         r"test frames$"):
        difference_interval([three], [two])
    with pytest.raises(ValueError, match="different ground truth per frame"):
        ap_interval([three, frame_matches(gt[::-1], dt[::-1])["3D"]])
    with pytest.raises(ValueError, match="^bootstrap: resamples must be at least 1, got 0$"):
        ap_interval([three], resamples=0)
    for level in (0.0, 1.0, 95):
        with pytest.raises(ValueError, match=rf"^bootstrap: the confidence level must be inside \(0, 1\), got "
                                             rf"{level}$"):
            ap_interval([three], level=level)
    with pytest.raises(ValueError, match="^bootstrap: 2 frame counts for 3 frames$"):
        weighted_ap(three, np.array([1, 1]))
    with pytest.raises(ValueError, match="^bootstrap: no runs given$"):
        ap_interval([])
    assert np.isnan(percentile_interval(np.array([0.5, np.nan]))).all()  # a resample without ground truth
