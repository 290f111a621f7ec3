"""Box corners, points in boxes, heading wrapping and folding, LiDAR <-> KITTI camera boxes."""
import numpy as np
import pytest
import torch

from pcdet_memslidar.geometry.boxes import (
    boxes_camera_to_lidar,
    boxes_lidar_to_camera,
    boxes_to_corners_3d,
    enlarge_box3d,
    fold_box_headings,
    limit_period,
    normalize_heading,
    points_in_boxes_mask,
    rotate_points_along_z,
)
from pcdet_memslidar.geometry.calibration import Calibration


def test_corners_of_a_turned_box():
    corners = boxes_to_corners_3d(np.array([[10.0, 5.0, 1.0, 4.0, 2.0, 2.0, np.pi / 2]]))
    assert corners.shape == (1, 8, 3)
    # corner 0 is (+dx/2, +dy/2, -dz/2) in the box frame; a quarter turn maps (2, 1) to (-1, 2)
    np.testing.assert_allclose(corners[0, 0], [9.0, 7.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(corners[0, 4], [9.0, 7.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(corners[0].mean(axis=0), [10.0, 5.0, 1.0], atol=1e-12)


def test_points_in_boxes_local_frame():
    boxes = np.array([[0.0, 0.0, 1.0, 4.0, 1.0, 2.0, np.pi / 2], [5.0, 0.0, 0.5, 1.0, 1.0, 1.0, 0.0]])
    points = np.array([
        [0.0, 1.9, 1.0],   # inside the first box: its length runs along y after the quarter turn
        [1.9, 0.0, 1.0],   # outside: only 0.5 m of width along x
        [0.0, 0.0, 2.0],   # on the top face: boundary counts as inside
        [5.4, 0.4, 0.9],   # inside the second box
        [5.0, 0.0, 1.01],  # above the second box
    ])
    expected = np.array([[1, 0], [0, 0], [1, 0], [0, 1], [0, 0]], dtype=bool)
    np.testing.assert_array_equal(points_in_boxes_mask(points, boxes), expected)


def test_limit_period_numpy_and_torch():
    angles = np.array([-np.pi, np.pi, 3 * np.pi / 2, -7.0, 0.2])
    wrapped = normalize_heading(angles)
    np.testing.assert_allclose(wrapped, [-np.pi, -np.pi, -np.pi / 2, -7.0 + 2 * np.pi, 0.2], atol=1e-12)
    assert ((wrapped >= -np.pi) & (wrapped < np.pi)).all()
    wrapped_torch = limit_period(torch.tensor([3.5], dtype=torch.float64), offset=0, period=np.pi)
    np.testing.assert_allclose(wrapped_torch.numpy(), [3.5 - np.pi])


def test_rotate_points_keeps_extra_columns():
    rotated = rotate_points_along_z(np.array([[1.0, 0.0, 3.0, 0.7]]), np.pi / 2)
    np.testing.assert_allclose(rotated, [[0.0, 1.0, 3.0, 0.7]], atol=1e-12)


def test_enlarge_box3d():
    grown = enlarge_box3d(np.array([[1.0, 2.0, 3.0, 1.0, 1.0, 2.0, 0.5]]), (0.2, 0.4, 0.0))
    np.testing.assert_allclose(grown, [[1.0, 2.0, 3.0, 1.2, 1.4, 2.0, 0.5]])


def test_camera_round_trip_and_kitti_convention():
    calib = Calibration.virtual()
    boxes = np.array([[8.0, 2.0, 0.9, 0.6, 0.5, 1.8, 0.3], [15.0, -4.0, 0.85, 0.7, 0.6, 1.7, -2.9]])
    camera = boxes_lidar_to_camera(boxes, calib)
    # virtual camera: camera x = -lidar y, camera y = -lidar z (bottom centre), camera z = lidar x
    np.testing.assert_allclose(camera[0, :3], [-2.0, 0.0, 8.0], atol=1e-12)
    np.testing.assert_allclose(camera[0, 3:6], [0.6, 1.8, 0.5])  # l, h, w
    np.testing.assert_allclose(camera[0, 6], -0.3 - np.pi / 2)
    np.testing.assert_allclose(boxes_camera_to_lidar(camera, calib), boxes, atol=1e-12)


def test_bad_box_shape_names_the_problem():
    with pytest.raises(ValueError, match=r"expected an \(N, 7\) array"):
        boxes_to_corners_3d(np.zeros(7))


def test_fold_box_headings_exact_values_at_the_quarter_turns():
    # heading -> (folded heading, dx, dy) of a 0.75 x 0.5 box; +-pi/4 both go to -pi/4 (into [-pi/4, pi/4))
    cases = [
        (0.0, 0.0, 0.75, 0.5),
        (np.pi / 2, 0.0, 0.5, 0.75),
        (-np.pi / 2, 0.0, 0.5, 0.75),
        (np.pi, 0.0, 0.75, 0.5),
        (-np.pi, 0.0, 0.75, 0.5),
        (np.pi / 4, -np.pi / 4, 0.5, 0.75),
        (-np.pi / 4, -np.pi / 4, 0.75, 0.5),
        (3 * np.pi / 4, -np.pi / 4, 0.75, 0.5),
        (0.25, 0.25, 0.75, 0.5),
        (1.75, 1.75 - np.pi / 2, 0.5, 0.75),
        (-2.0, -2.0 + np.pi / 2, 0.5, 0.75),
        (1000 * np.pi + 0.25, 0.25, 0.75, 0.5),
    ]
    boxes = np.array([[1.0, 2.0, 0.9, 0.75, 0.5, 1.8, heading, 7.0] for heading, *_ in cases])
    folded = fold_box_headings(boxes)
    expected = np.array([[heading, dx, dy] for _, heading, dx, dy in cases])
    np.testing.assert_allclose(folded[:, [6, 3, 4]], expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(folded[:, [0, 1, 2, 5, 7]], boxes[:, [0, 1, 2, 5, 7]])  # centre, height, class kept
    assert boxes[1, 6] == np.pi / 2  # the input is not changed


def test_half_fold_puts_the_long_side_first_exact_values():
    # (dx, dy, heading) -> (folded heading, dx, dy): the long side first, its direction in [-pi/2, pi/2)
    cases = [
        (0.75, 0.5, 0.0, 0.0, 0.75, 0.5),
        (0.75, 0.5, np.pi, 0.0, 0.75, 0.5),
        (0.75, 0.5, np.pi / 2, -np.pi / 2, 0.75, 0.5),  # +pi/2 goes to -pi/2
        (0.5, 0.75, 0.0, -np.pi / 2, 0.75, 0.5),  # the long side along y
        (0.5, 0.75, 0.3, 0.3 - np.pi / 2, 0.75, 0.5),
        (0.5, 0.75, -0.3, np.pi / 2 - 0.3, 0.75, 0.5),
        (0.75, 0.5, 1.2, 1.2, 0.75, 0.5),  # no quarter-turn jump at 45 deg
        (0.75, 0.5, -2.0, np.pi - 2.0, 0.75, 0.5),
        (0.6, 0.6, 0.25, 0.25, 0.6, 0.6),  # a square keeps its sides
    ]
    boxes = np.array([[1.0, 2.0, 0.9, dx, dy, 1.8, heading, 7.0] for dx, dy, heading, *_ in cases])
    folded = fold_box_headings(boxes, "half")
    expected = np.array([[heading, dx, dy] for *_, heading, dx, dy in cases])
    np.testing.assert_allclose(folded[:, [6, 3, 4]], expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(folded[:, [0, 1, 2, 5, 7]], boxes[:, [0, 1, 2, 5, 7]])
    with pytest.raises(ValueError, match="fold 'third': use one of quarter, half"):
        fold_box_headings(boxes, "third")


@pytest.mark.parametrize("fold, limit", [("quarter", np.pi / 4), ("half", np.pi / 2)])
def test_folded_boxes_are_the_same_rectangles(fold, limit):
    rng = np.random.default_rng(0)
    boxes = np.column_stack([rng.uniform(-20, 20, (500, 3)), rng.uniform(0.2, 1.0, (500, 3)),
                             rng.uniform(-10, 10, 500)]).astype(np.float32)
    folded = fold_box_headings(boxes, fold)
    assert folded.dtype == np.float32
    assert (np.abs(folded[:, 6]) <= np.float32(limit)).all()
    # the same 8 corners, in another order: compare each corner with its nearest one of the folded box
    corners, corners_folded = boxes_to_corners_3d(boxes), boxes_to_corners_3d(folded)
    gaps = np.linalg.norm(corners[:, :, None] - corners_folded[:, None], axis=3).min(axis=2)
    assert gaps.max() < 1e-5
    assert fold_box_headings(np.zeros((0, 8), np.float32), fold).shape == (0, 8)
