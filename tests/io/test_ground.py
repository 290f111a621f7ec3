"""Ground normalisation: frames scanned at a known mount give the mount back (2 cm, 0.2 deg)."""
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


@pytest.mark.parametrize("text", ["nan,16", "4,inf", "4,16,nan"])
def test_non_finite_mount_text(text):
    with pytest.raises(ValueError, match=rf"--mount '{text}': expected HEIGHT,TILT\[,ROLL\] as finite numbers"):
        parse_mount(text)
