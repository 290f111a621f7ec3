"""geometry/box_from_points.py: a box's long side along the main axis of its own points, its centre behind them."""
import numpy as np
import pytest

from pcdet_memslidar.geometry.box_from_points import centre_behind, drift_velocity, fit_boxes_to_points, main_axis


def _line(degrees, centre=(5.0, -2.0), count=21, half_length=0.3):
    direction = np.array([np.cos(np.radians(degrees)), np.sin(np.radians(degrees))])
    return np.linspace(-half_length, half_length, count)[:, None] * direction + centre


@pytest.mark.parametrize("degrees", [0.0, 30.0, 90.0, -60.0])
def test_main_axis_of_points_along_a_line(degrees):
    axis = np.degrees(main_axis(_line(degrees)))
    assert (axis - degrees + 90.0) % 180.0 - 90.0 == pytest.approx(0.0, abs=1e-9)  # a line has no direction


@pytest.mark.parametrize("points", [np.zeros((4, 2)), np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])])
def test_points_as_wide_every_way_have_no_main_axis(points):
    assert main_axis(points + [3.0, 4.0]) is None  # one spot; a square's corners: equal variances


def _with_z(points_xy, z=0.8):
    return np.column_stack([points_xy, np.full(len(points_xy), z)])


def test_a_square_box_gets_its_long_side_along_the_points():
    box = np.array([[5.0, -2.0, 0.8, 0.55, 0.56, 1.7, 0.3, 7.0]])  # dy > dx, an extra column
    oriented, done = fit_boxes_to_points(box, _with_z(_line(120.0)), min_points=5, margin=0.0)
    assert done.tolist() == [True]
    assert oriented[0, 6] == pytest.approx(np.radians(-60.0), abs=1e-12)  # 120 deg is -60 deg for a rectangle
    assert oriented[0, [0, 1, 2, 3, 4, 5, 7]].tolist() == [5.0, -2.0, 0.8, 0.56, 0.55, 1.7, 7.0]


def test_points_along_x_give_heading_zero_whichever_sign_the_eigenvector_has():
    box = np.array([[0.0, 0.0, 0.8, 0.6, 0.6, 1.7, 1.0]])
    oriented, _ = fit_boxes_to_points(box, _with_z(_line(0.0, centre=(0.0, 0.0))), 5, 0.0)
    assert oriented[0, 6] == pytest.approx(0.0, abs=1e-12)


def test_boxes_with_too_few_or_outside_points_or_no_main_axis_keep_their_heading():
    boxes = np.array([[0.0, 0.0, 0.8, 0.6, 0.5, 1.7, 0.4],
                      [10.0, 0.0, 0.8, 0.6, 0.5, 1.7, 0.4],
                      [20.0, 0.0, 0.8, 0.6, 0.5, 1.7, 0.4]])
    points = np.vstack([_with_z(_line(45.0, centre=(0.0, 0.0), count=4)),  # 4 < min_points
                        _with_z(np.zeros((6, 2)) + [10.0, 0.0]),  # one spot
                        _with_z(_line(45.0, centre=(20.0, 0.0)), z=3.0)])  # above the box
    oriented, done = fit_boxes_to_points(boxes, points, 5, 0.1)
    assert done.tolist() == [False, True, False]  # the spot has its points, but no axis
    np.testing.assert_array_equal(oriented, boxes)


def test_the_margin_takes_points_just_beside_the_box():
    box = np.array([[0.0, 0.0, 0.8, 0.4, 0.4, 1.7, 0.0]])
    beside = _with_z(_line(90.0, centre=(0.25, 0.0), half_length=0.15))  # 0.05 m outside the box in x
    assert fit_boxes_to_points(box, beside, 5, 0.0)[1].tolist() == [False]
    oriented, done = fit_boxes_to_points(box, beside, 5, 0.1)
    assert done.tolist() == [True] and abs(oriented[0, 6]) == pytest.approx(np.pi / 2, abs=1e-12)
    assert oriented[0, 6] < 0  # headings in [-pi/2, pi/2)


def test_points_below_min_height_are_left_out():
    box = np.array([[0.0, 0.0, 0.85, 0.6, 0.6, 1.7, 0.0]])  # bottom at z = 0
    legs = _with_z(_line(0.0, centre=(0.0, 0.0)), z=0.3)  # a stride along x
    shoulders = _with_z(_line(90.0, centre=(0.0, 0.0), count=7, half_length=0.2), z=1.4)  # across, along y
    points = np.vstack([legs, shoulders])
    assert fit_boxes_to_points(box, points, 5, 0.0)[0][0, 6] == pytest.approx(0.0, abs=1e-12)  # legs dominate
    oriented, done = fit_boxes_to_points(box, points, 5, 0.0, min_height=0.8)
    assert done.tolist() == [True] and oriented[0, 6] == pytest.approx(-np.pi / 2, abs=1e-12)
    assert oriented[0, 2] == 0.85 and oriented[0, 5] == 1.7  # the box itself is not raised
    assert fit_boxes_to_points(box, points, 5, 0.0, min_height=1.7)[1].tolist() == [False]  # nothing left above


def test_the_window_follows_its_points_off_a_detected_centre_and_drops_the_clutter():
    person = _line(30.0, centre=(5.0, 0.0), count=9, half_length=0.2)  # x from 4.827 to 5.173
    clutter = np.array([[5.62, -0.25]])
    box = np.array([[5.3, 0.0, 0.85, 0.5, 0.5, 1.7, 0.0]])  # 0.3 m off; with the margin x in [4.95, 5.65]
    first_window = np.vstack([person[3:], clutter])  # what the box itself holds: 6 of the person's points, the clutter
    assert abs((np.degrees(main_axis(first_window)) - 30.0 + 90.0) % 180.0 - 90.0) > 50.0  # 53.8 deg off
    # mean (5.144, -0.004): the window holds the whole person and not the clutter; mean (5, 0), where it stays
    oriented, done = fit_boxes_to_points(box, _with_z(np.vstack([person, clutter]), z=1.2), 5, 0.1)
    assert done.tolist() == [True]
    assert oriented[0, 6] == pytest.approx(np.radians(30.0), abs=1e-12)
    assert oriented[0, :2].tolist() == [5.3, 0.0]  # the box keeps its centre


def test_the_centre_lies_the_depth_behind_the_mean_along_the_sensors_ray():
    assert centre_behind(np.array([[3.0, 4.0], [3.0, 4.0]]), 0.5).tolist() == pytest.approx([3.3, 4.4], abs=1e-15)
    assert centre_behind(np.array([[-0.6, 0.0], [0.0, 0.8]]), 0.1).tolist() == pytest.approx([-0.36, 0.48], abs=1e-15)
    assert centre_behind(np.array([[1.0, 0.0], [-1.0, 0.0]]), 0.1).tolist() == [0.0, 0.0]  # on the axis: no ray
    assert centre_behind(np.array([[3.0, 4.0]]), 0.0).tolist() == [3.0, 4.0]


def test_a_box_moves_behind_the_near_side_of_a_person_and_keeps_z_and_sizes():
    near_side = _line(90.0, centre=(8.0, 0.0), count=9, half_length=0.2)  # shoulders across the ray, 8 m out
    box = np.array([[8.12, 0.05, 0.85, 0.5, 0.56, 1.7, 0.0, 3.0]])  # the network's box, near the person
    fitted, done = fit_boxes_to_points(box, _with_z(near_side, z=1.2), 5, 0.1, center_depth=0.08)
    assert done.tolist() == [True]
    assert fitted[0, :2].tolist() == pytest.approx([8.08, 0.0], abs=1e-12)  # the mean (8, 0), 0.08 m further out
    assert fitted[0, 2:].tolist() == pytest.approx([0.85, 0.56, 0.5, 1.7, -np.pi / 2, 3.0], abs=1e-12)
    kept, _ = fit_boxes_to_points(box, _with_z(near_side, z=1.2), 5, 0.1, center_depth=None)
    assert kept[0, :2].tolist() == [8.12, 0.05]  # None: the network's centre


def test_a_box_with_too_few_points_keeps_its_centre():
    box = np.array([[8.0, 0.0, 0.85, 0.5, 0.5, 1.7, 0.0]])
    fitted, done = fit_boxes_to_points(box, _with_z(_line(90.0, centre=(8.0, 0.0), count=4)), 5, 0.1,
                                       center_depth=0.08)
    assert done.tolist() == [False] and fitted.tolist() == box.tolist()


@pytest.mark.parametrize("min_points, margin, min_height, depth, speed", [
    (1, 0.1, 0.0, None, None), (5, -0.1, 0.0, None, None), (5, float("nan"), 0.0, None, None),
    (5, 0.1, -0.5, None, None), (5, 0.1, float("inf"), None, None), (5, 0.1, 0.0, -0.08, None),
    (5, 0.1, 0.0, float("nan"), None), (5, 0.1, 0.0, None, -0.5), (5, 0.1, 0.0, None, float("nan"))])
def test_settings_out_of_range_are_refused(min_points, margin, min_height, depth, speed):
    with pytest.raises(ValueError, match="min_points >= 2 and a margin, min_height, center_depth >= 0 m and "
                                         "min_drift_speed >= 0 m/s"):
        fit_boxes_to_points(np.zeros((0, 7)), np.zeros((0, 3)), min_points, margin, min_height, depth,
                            min_drift_speed=speed)


def test_drift_velocity_of_points_taken_over_time():
    times = np.array([0.0, 0.1, 0.2, 0.3])
    walking = np.stack([2.0 + 1.5 * times, -1.0 + 0.5 * times], axis=1)  # 1.5 m/s in x, 0.5 m/s in y
    assert drift_velocity(walking, times) == pytest.approx([1.5, 0.5], abs=1e-12)
    still = np.array([[2.0, 1.0], [2.1, 1.1], [2.1, 1.1], [2.0, 1.0]])  # a standing person: spread, no drift
    assert drift_velocity(still, times) == pytest.approx([0.0, 0.0], abs=1e-12)
    assert drift_velocity(walking, np.full(4, 0.2)) is None  # taken at one time: no drift shown
    assert drift_velocity(walking[:1], times[:1]) is None


def _walker():
    """A person 8 m out, 0.5 m wide along x, swept over 0.3 s while it walks along y at 1 m/s: 16 points (x, y,
    z) and their times [s]."""
    times = np.repeat([0.0, 0.1, 0.2, 0.3], 4)
    x = 8.0 + np.tile([-0.25, -0.1, 0.1, 0.25], 4)
    return np.stack([x, 1.0 * times, np.full(16, 1.0)], axis=1), times


def test_a_walking_persons_long_side_follows_the_drift_of_its_points():
    points, times = _walker()
    box = np.array([[8.0, 0.15, 0.9, 0.6, 0.6, 1.8, 0.3]])
    by_axis, _ = fit_boxes_to_points(box, points, 5, 0.1)  # no times: the points' main axis, along x
    assert by_axis[0, 6] == pytest.approx(0.0, abs=1e-12)
    by_drift, done = fit_boxes_to_points(box, points, 5, 0.1, times=times, min_drift_speed=0.5)
    assert done.tolist() == [True] and abs(np.cos(by_drift[0, 6])) < 1e-12  # along y, where it walks
    slow, _ = fit_boxes_to_points(box, points, 5, 0.1, times=times, min_drift_speed=1.5)  # it drifts at 1 m/s
    assert slow[0, 6] == pytest.approx(0.0, abs=1e-12)
    off, _ = fit_boxes_to_points(box, points, 5, 0.1, times=times)  # no min_drift_speed: the drift is not used
    assert off[0, 6] == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match="15 time offsets for 16 points"):
        fit_boxes_to_points(box, points, 5, 0.1, times=times[:15], min_drift_speed=0.5)
