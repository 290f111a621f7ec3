"""Ground normalisation: frames scanned at a known mount give the mount back (2 cm, 0.2 deg); the floor, not the
larger desk plane above it, is the ground, also on the bundled real office recording."""
import numpy as np
import pytest

from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io.ground import estimate_ground, mount_from_plane, normalise_points, parse_mount


@pytest.mark.parametrize("mount", [Mount(4.0, 16.0), Mount(5.0, 23.0, roll_deg=1.5), Mount(2.5, 8.0, roll_deg=-2.0)])
def test_known_mount_is_recovered(scan_room, mount):
    estimate = estimate_ground(scan_room(mount, seed=1))
    assert abs(estimate.mount.height - mount.height) < 0.02
    assert abs(estimate.mount.tilt_deg - mount.tilt_deg) < 0.2
    assert abs(estimate.mount.roll_deg - mount.roll_deg) < 0.2
    assert estimate.rms < 0.015 and estimate.inliers > 3000


def test_normalised_floor_is_at_zero(scan_room):
    mount = Mount(4.0, 16.0)
    points = normalise_points(scan_room(mount, seed=2), mount)
    floor = points[(points[:, 0] > 9.0) & (points[:, 0] < 11.5)]  # behind the boxes, before the wall: floor only
    assert len(floor) > 1000
    assert abs(np.median(floor[:, 2])) < 0.005 and points.dtype == np.float32


def test_floor_below_larger_desk_plane_is_the_ground():
    """Desk tops 0.8 m above the floor hold three times its points, a wall stands behind both and 60 points lie in
    a pit below the floor (too few to count): the floor is the ground."""
    mount = Mount(1.6, 4.0, roll_deg=-1.5)
    rng = np.random.default_rng(3)

    def patch(count, x, y, z):
        return np.column_stack([rng.uniform(*x, count), rng.uniform(*y, count), rng.uniform(*z, count)])

    room = np.concatenate([patch(6000, (2.0, 6.0), (-3.0, 3.0), (0.8, 0.8)),  # desk tops
                           patch(2000, (6.0, 9.0), (-3.0, 3.0), (0.0, 0.0)),  # the floor seen behind them
                           patch(4000, (9.0, 9.0), (-4.0, 4.0), (0.0, 2.5)),  # back wall
                           patch(60, (7.0, 7.5), (0.0, 0.5), (-0.5, -0.5))])  # pit
    points = mount.ground_to_sensor(room + rng.normal(0.0, 0.005, room.shape))
    estimate = estimate_ground(points)
    assert abs(estimate.mount.height - 1.6) < 0.01
    assert abs(estimate.mount.tilt_deg - 4.0) < 0.2 and abs(estimate.mount.roll_deg + 1.5) < 0.2
    assert 2000 <= estimate.inliers < 2300  # the floor and the foot of the wall, not the desk tops


def test_real_office_floor_is_the_ground(real_bfpc):
    """The bundled recording: desk tops 0.8 m below a roughly level sensor, the floor only seen near the back wall
    (x 7-8.5 m); normalised, those floor returns lie at z = 0."""
    points = np.concatenate([frame.points for frame in real_bfpc.frames[:5]])
    estimate = estimate_ground(points)
    assert 1.4 < estimate.mount.height < 1.8 and abs(estimate.mount.tilt_deg) < 5.0
    ground = normalise_points(points, estimate.mount)
    floor = ground[(np.abs(ground[:, 2]) < 0.1) & (ground[:, 0] > 7.0)]
    assert len(floor) > 400 and abs(np.median(floor[:, 2])) < 0.03


def test_plane_to_mount_inverts_the_mount():
    mount = Mount(3.2, 31.0, roll_deg=-4.0)
    up_in_sensor = mount.rotation.T @ np.array([0.0, 0.0, 1.0])
    recovered = mount_from_plane(up_in_sensor, mount.height)
    np.testing.assert_allclose([recovered.height, recovered.tilt_deg, recovered.roll_deg], [3.2, 31.0, -4.0])


def test_no_ground_and_bad_mount_text():
    rng = np.random.default_rng(0)
    wall = np.column_stack([np.full(2000, 6.0), rng.uniform(-3, 3, 2000), rng.uniform(-2, 2, 2000)])
    with pytest.raises(ValueError, match="no ground plane"):
        estimate_ground(wall)
    assert parse_mount("4,16") == Mount(4.0, 16.0)
    with pytest.raises(ValueError, match="HEIGHT,TILT"):
        parse_mount("4")


@pytest.mark.parametrize("text", ["nan,16", "4,inf", "4,16,nan", "4,400", "4,16,-91"])
def test_non_finite_mount_text(text):
    with pytest.raises(ValueError, match=rf"--mount '{text}': expected HEIGHT,TILT\[,ROLL\] as finite numbers"):
        parse_mount(text)
