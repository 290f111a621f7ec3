"""Rotated IoU: hard cases with their exact values (turned, collinear, touching, tiny, far-off and flat boxes),
invariances, a shapely cross-check."""
import numpy as np
import pytest
import torch
from shapely.geometry import Polygon

from pcdet_memslidar.geometry.boxes import boxes_to_corners_3d
from pcdet_memslidar.geometry.iou import aligned_iou, boxes_iou3d, boxes_iou_bev

PI = np.pi
PERSON = (0.0, 0.0, 0.9, 0.6, 0.5, 1.8)  # x, y, z_center, dx, dy, dz


def box(*values) -> np.ndarray:
    return np.array([values], dtype=np.float64)


@pytest.mark.parametrize("yaw", [0.0, 0.3, PI / 4])
def test_identical_person_boxes(yaw):
    person = box(*PERSON, yaw)
    assert boxes_iou_bev(person, person)[0, 0] == pytest.approx(1.0, abs=1e-12)
    assert boxes_iou3d(person, person)[0, 0] == pytest.approx(1.0, abs=1e-12)


HARD_CASES = [  # (box a, box b, exact BEV IoU, exact 3D IoU)
    pytest.param(box(*PERSON, PI), box(*PERSON, -PI), 1.0, 1.0, id="yaw +pi vs -pi"),
    pytest.param(box(0, 0, 0, 4, 2, 1, 0), box(0, 0, 0, 4, 2, 1, PI / 2), 1 / 3, 1 / 3, id="4x2 vs rotated 90 deg"),
    pytest.param(box(0, 0, 0, 2, 2, 1, 0), box(0, 0, 0, 2, 2, 1, PI / 4), 1 / np.sqrt(2), 1 / np.sqrt(2),
                 id="2x2 vs rotated 45 deg"),
    pytest.param(box(1, 1, 0, 2, 2, 1, 0), box(2, 1, 0, 2, 2, 1, 0), 1 / 3, 1 / 3, id="shared collinear edges"),
    pytest.param(box(1, 1, 0, 2, 2, 1, 0), box(3, 1, 0, 2, 2, 1, 0), 0.0, 0.0, id="touching"),
    pytest.param(box(1, 1, 0, 2, 2, 1, 0), box(1, 3, 0, 2, 2, 1, PI), 0.0, 0.0, id="touching, turned by pi"),
    pytest.param(box(1, 1, 0, 2, 2, 1, 0), box(3.005, 1, 0, 2, 2, 1, 0), 0.0, 0.0, id="5 mm gap"),
    pytest.param(box(0, 0, 0, 2, 1, 1, 0), box(2 - 1e-4, 0, 0, 2, 1, 1, 0), 1e-4 / (4 - 1e-4), 1e-4 / (4 - 1e-4),
                 id="1e-4 m overlap of 2x1 boxes"),
    pytest.param(box(0, 0, 0, 1e-3, 1e-3, 1e-3, 0.2), box(0, 0, 0, 1e-3, 1e-3, 1e-3, 0.2), 1.0, 1.0,
                 id="identical 1 mm boxes"),
    pytest.param(box(40325, -24932, -254, 0.6, 0.5, 1.8, 0.7), box(40325, -24932, -254, 0.6, 0.5, 1.8, 0.7), 1.0, 1.0,
                 id="identical boxes at huge coordinates"),
    pytest.param(box(*PERSON, 0.7), box(0, 0, 1.8, 0.6, 0.5, 1.8, 0.7), 1.0, 1 / 3, id="z offset of half the height"),
    pytest.param(box(0, 0, 0, 0, 0.5, 1.8, 0.7), box(0, 0, 0, 0, 0.5, 1.8, 0.7), 0.0, 0.0, id="zero-size identical"),
    pytest.param(box(0, 0, 0, 0, 0, 0, 0), box(0, 0, 0, 1, 1, 1, 0), 0.0, 0.0, id="point box in a box"),
    pytest.param(box(0, 0, 0, 1, 1, 0, 0), box(0, 0, 0, 1, 1, 0, 0), 1.0, 0.0, id="flat boxes: 3D volume 0"),
]


@pytest.mark.parametrize("box_a, box_b, expected_bev, expected_3d", HARD_CASES)
def test_hard_cases_exact(box_a, box_b, expected_bev, expected_3d):
    for a, b in ((box_a, box_b), (box_b, box_a)):
        bev, iou3d = boxes_iou_bev(a, b)[0, 0], boxes_iou3d(a, b)[0, 0]
        assert np.isfinite(bev) and np.isfinite(iou3d)
        assert bev == pytest.approx(expected_bev, rel=1e-9, abs=1e-12)
        assert iou3d == pytest.approx(expected_3d, rel=1e-9, abs=1e-12)


def random_boxes(rng, count, spread=2.0):
    return np.column_stack([rng.uniform(-spread, spread, (count, 2)), rng.uniform(0, 1, count),
                            rng.uniform(0.2, 2.0, (count, 3)), rng.uniform(-4, 4, count)])


def test_heading_plus_pi_and_2pi_invariance():
    rng = np.random.default_rng(1)
    a, b = random_boxes(rng, 60), random_boxes(rng, 40)
    reference = boxes_iou3d(a, b)
    assert (reference > 0).sum() > 100
    for shift in (PI, -PI, 2 * PI, -2 * PI, 3 * PI):
        turned = b.copy()
        turned[:, 6] += shift
        np.testing.assert_allclose(boxes_iou3d(a, turned), reference, atol=1e-12)


def test_translation_to_huge_coordinates_keeps_iou():
    rng = np.random.default_rng(2)
    a, b = random_boxes(rng, 30), random_boxes(rng, 30)
    offset = np.array([40325.0, -24932.0, -254.0])
    a_far, b_far = a.copy(), b.copy()
    a_far[:, :3] += offset
    b_far[:, :3] += offset
    np.testing.assert_allclose(boxes_iou3d(a_far, b_far), boxes_iou3d(a, b), atol=1e-9)


def shapely_iou(a, b):
    """Reference: shapely polygon intersection of the footprints, z overlap by hand."""
    corners_a, corners_b = boxes_to_corners_3d(a)[:, :4, :2], boxes_to_corners_3d(b)[:, :4, :2]
    bev, iou3d = np.zeros((len(a), len(b))), np.zeros((len(a), len(b)))
    for i, (ca, ba) in enumerate(zip(corners_a, a)):
        for j, (cb, bb) in enumerate(zip(corners_b, b)):
            inter = Polygon(ca).intersection(Polygon(cb)).area
            bev[i, j] = inter / (ba[3] * ba[4] + bb[3] * bb[4] - inter)
            dz = max(0.0, min(ba[2] + ba[5] / 2, bb[2] + bb[5] / 2) - max(ba[2] - ba[5] / 2, bb[2] - bb[5] / 2))
            volume = inter * dz
            iou3d[i, j] = volume / (np.prod(ba[3:6]) + np.prod(bb[3:6]) - volume)
    return bev, iou3d


def test_random_boxes_match_shapely():
    rng = np.random.default_rng(3)
    a, b = random_boxes(rng, 50), random_boxes(rng, 50)
    # axis-aligned integer boxes: many shared edges and touching corners
    grid_a, grid_b = (np.column_stack([rng.integers(0, 4, (30, 3)), rng.integers(1, 3, (30, 3)),
                                       rng.integers(0, 4, 30) * PI / 2]) for _ in range(2))
    for first, second in ((a, b), (grid_a.astype(float), grid_b.astype(float))):
        bev_ref, iou3d_ref = shapely_iou(first, second)
        np.testing.assert_allclose(boxes_iou_bev(first, second), bev_ref, atol=1e-10)
        np.testing.assert_allclose(boxes_iou3d(first, second), iou3d_ref, atol=1e-10)
        assert (bev_ref > 0).sum() > 50


def test_near_degenerate_pairs_match_shapely():
    """Edges off parallel by 1e-12 .. 1e-6 rad, boxes touching within 1e-9 of their size, thin boxes, sizes from
    1 mm to 10 m, half of them 1e5 m from the origin: the hardest inputs for tolerances."""
    rng = np.random.default_rng(6)
    count = 2000
    a = np.column_stack([rng.uniform(-1, 1, (count, 2)), np.zeros(count), 10 ** rng.uniform(-3, 1, (count, 2)),
                         np.ones(count), rng.uniform(-4, 4, count)])
    b = a.copy()
    kind = np.arange(count) % 3
    turn = kind == 0  # quarter turns, a hair off
    b[turn, 6] += rng.integers(0, 4, turn.sum()) * PI / 2 + rng.choice([0, 1e-12, 1e-10, 1e-9, 1e-8, 1e-6], turn.sum())
    slide = kind == 1  # slid along its own x by half, exactly, or within 1e-9 of its length
    shift = a[slide, 3] * rng.choice([0.5, 1.0, 1.0 + 1e-9, 1.0 - 1e-9], slide.sum())
    b[slide, 0] += shift * np.cos(a[slide, 6])
    b[slide, 1] += shift * np.sin(a[slide, 6])
    thin = kind == 2
    b[thin, 4] *= 1e-6
    b[thin, 6] += rng.choice([0, 1e-9, PI / 2], thin.sum())
    far = rng.uniform(size=count) < 0.5
    offset = rng.uniform(-1e5, 1e5, (count, 2))
    a[far, :2] += offset[far]
    b[far, :2] += offset[far]
    centred_a, centred_b = a.copy(), b.copy()
    centre = (a[:, :2] + b[:, :2]) / 2  # shapely gets the pairs centred: it has no tolerance of its own
    centred_a[:, :2] -= centre
    centred_b[:, :2] -= centre
    bev_ref, _ = shapely_iou_pairs(centred_a, centred_b)
    bev, _ = aligned_iou(a, b)
    np.testing.assert_allclose(bev, bev_ref, atol=1e-8)
    assert 0.3 < (bev_ref > 0).mean() < 1


def shapely_iou_pairs(a, b):
    """shapely_iou of row-aligned pairs."""
    results = [shapely_iou(a[i:i + 1], b[i:i + 1]) for i in range(len(a))]
    return np.array([bev[0, 0] for bev, _ in results]), np.array([iou3d[0, 0] for _, iou3d in results])


def test_matrix_agrees_with_aligned_pairs_and_handles_empty_sets():
    rng = np.random.default_rng(4)
    a, b = random_boxes(rng, 7), random_boxes(rng, 5)
    rows, cols = np.meshgrid(np.arange(7), np.arange(5), indexing="ij")
    bev, iou3d = aligned_iou(a[rows.ravel()], b[cols.ravel()])
    np.testing.assert_allclose(boxes_iou_bev(a, b), bev.reshape(7, 5), atol=1e-15)
    np.testing.assert_allclose(boxes_iou3d(a, b), iou3d.reshape(7, 5), atol=1e-15)
    many = random_boxes(rng, 2500, spread=20.0)  # more rows than one prefilter chunk (1024)
    rows, cols = np.meshgrid(np.arange(2500), np.arange(5), indexing="ij")
    expected = aligned_iou(many[rows.ravel()], b[cols.ravel()])[0].reshape(2500, 5)
    np.testing.assert_allclose(boxes_iou_bev(many, b), expected, atol=1e-15)
    assert (expected > 0).any()
    assert boxes_iou_bev(np.zeros((0, 7)), b).shape == (0, 5)
    assert boxes_iou3d(a, np.zeros((0, 7))).shape == (7, 0)


def test_bad_boxes_raise_clear_errors():
    with pytest.raises(ValueError, match="boxes_a: expected an \\(N, 7\\)"):
        boxes_iou_bev(np.zeros((3, 5)), np.zeros((1, 7)))
    with pytest.raises(ValueError, match="boxes_b: NaN or inf in box rows \\[1\\]"):
        boxes_iou3d(np.zeros((1, 7)), np.array([[0, 0, 0, 1, 1, 1, 0], [0, 0, np.nan, 1, 1, 1, 0]]))
    with pytest.raises(ValueError, match="negative size"):
        boxes_iou3d(box(0, 0, 0, -1, 1, 1, 0), box(0, 0, 0, 1, 1, 1, 0))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
def test_gpu_matches_cpu():
    from pcdet_memslidar.geometry.iou import aligned_iou_torch
    rng = np.random.default_rng(5)
    a, b = torch.from_numpy(random_boxes(rng, 5000)), torch.from_numpy(random_boxes(rng, 5000))
    cpu = aligned_iou_torch(a, b)
    gpu = aligned_iou_torch(a.cuda(), b.cuda())
    for on_cpu, on_gpu in zip(cpu, gpu):
        torch.testing.assert_close(on_gpu.cpu(), on_cpu, atol=1e-12, rtol=0)
