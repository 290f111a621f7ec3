"""Sensor presets: the CARLA preset against its definition, the calibrated one against its physics."""
import dataclasses

import numpy as np
import pytest

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.sim.sensor import get_sensor

COUNT = 100_000


def test_carla_drop_rate_and_range_noise_match_definition():
    sensor = get_sensor("carla")
    true_range = np.linspace(2.0, 60.0, COUNT)
    measured, intensity, valid = sensor.measure(true_range, np.full(COUNT, 0.3), np.full(COUNT, 0.05),
                                                np.random.default_rng(0))
    drop = 1.0 - valid.mean()
    assert abs(drop - 0.05) < 4 * np.sqrt(0.05 * 0.95 / COUNT)  # uniform 5 %, blind to reflectivity and angle
    relative = measured[valid] / true_range[valid] - 1.0
    assert abs(relative.mean()) < 4 * 0.005 / np.sqrt(valid.sum())
    assert relative.std() == pytest.approx(0.005, rel=0.02)  # range x (1 + N(0, 0.005))
    np.testing.assert_array_equal(intensity[valid], np.rint(511 * np.exp(-0.004 * measured[valid])))
    assert np.isnan(measured[~valid]).all() and (intensity[~valid] == 0).all()


def test_carla_has_no_edge_effect():
    sensor = get_sensor("carla")
    plain = sensor.measure(np.full(1000, 10.0), np.ones(1000), np.ones(1000), np.random.default_rng(1))
    edged = sensor.measure(np.full(1000, 10.0), np.ones(1000), np.ones(1000), np.random.default_rng(1),
                           edge_range=np.full(1000, 10.3))
    np.testing.assert_array_equal(plain[0], edged[0])


def test_calibrated_noise_misses_and_intensity():
    sensor = get_sensor("calibrated")
    true_range = np.full(COUNT, 10.0)
    true_range[:1000] = np.inf  # no surface
    true_range[1000:2000] = 1.0  # closer than the minimum range
    measured, intensity, valid = sensor.measure(true_range, np.full(COUNT, 0.8), np.full(COUNT, 0.5),
                                                np.random.default_rng(2))
    assert not valid[:2000].any() and np.isnan(measured[:2000]).all()
    assert valid[2000:].mean() > 0.99  # strong echo at 10 m: only the small base dropout
    sigma = np.std(measured[valid] - 10.0)
    assert sigma == pytest.approx(sensor.range_sigma_m + 10.0 * sensor.range_sigma_per_m, rel=0.03)
    assert intensity.dtype == np.float32 and (intensity == np.rint(intensity)).all()
    assert 0 <= intensity.min() and intensity.max() <= 511
    expected = sensor.intensity_scale * 0.4 * 2.0 ** sensor.intensity_range_slope
    assert np.median(intensity[valid]) == pytest.approx(expected, rel=0.02)


def test_calibrated_dropout_follows_received_power():
    sensor = get_sensor("calibrated")
    ones = np.ones(COUNT)
    near = sensor.measure(np.full(COUNT, 5.0), ones, np.full(COUNT, 0.1), np.random.default_rng(3))[2].mean()
    far = sensor.measure(np.full(COUNT, 40.0), ones, np.full(COUNT, 0.1), np.random.default_rng(3))[2].mean()
    grazing = sensor.measure(np.full(COUNT, 5.0), np.full(COUNT, 0.02), np.full(COUNT, 0.1),
                             np.random.default_rng(3))[2].mean()
    assert near > 0.99 and far < 0.5 and grazing < near


def test_mixed_pixels_lie_between_the_two_surfaces():
    sensor = dataclasses.replace(get_sensor("calibrated"), range_sigma_m=0.0, range_sigma_per_m=0.0)
    measured, _, valid = sensor.measure(np.full(1000, 8.0), np.ones(1000), np.ones(1000), np.random.default_rng(4),
                                        edge_range=np.where(np.arange(1000) < 500, 8.5, 20.0))
    mixed = measured[:500][valid[:500]]
    assert mixed.min() >= 8.0 and mixed.max() <= 8.5 and mixed.std() > 0.1
    np.testing.assert_array_equal(measured[500:][valid[500:]], 8.0)  # too far apart to merge: centre surface


def test_returns_are_the_valid_pulses_of_measure():
    sensor = get_sensor("calibrated")
    args = (np.where(np.arange(2000) % 7 == 0, np.inf, np.linspace(0.5, 90, 2000)), np.full(2000, 0.6),
            np.full(2000, 0.2), np.random.default_rng(5), np.where(np.arange(2000) % 5 == 0, 30.0, np.nan))
    measured, intensity, valid = sensor.measure(*args[:3], np.random.default_rng(5), args[4])
    pulse, range_m, values = sensor.returns(*args)
    np.testing.assert_array_equal(pulse, np.flatnonzero(valid))
    np.testing.assert_array_equal(range_m, measured[valid])
    np.testing.assert_array_equal(values, intensity[valid])
    assert 0.3 < valid.mean() < 0.9 and values.dtype == np.float32


def test_same_seed_same_result_and_unknown_preset():
    sensor = get_sensor("calibrated")
    args = (np.linspace(2, 30, 500), np.full(500, 0.7), np.full(500, 0.3))
    first = sensor.measure(*args, np.random.default_rng(7))
    second = sensor.measure(*args, np.random.default_rng(7))
    for a, b in zip(first, second):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ConfigError, match="unknown sensor preset 'lidar'"):
        get_sensor("lidar")


def test_detection_threshold_and_range_limits_are_exact_at_their_edges():
    """Hard cases with exact answers (no noise, no dropout, a hard power step): the received power at 2 m of a
    white surface seen head-on is 1 / 2^2 = 0.25, exactly the threshold, so it returns (margin 0 in natural logs);
    a hair farther, at zero reflectivity (log 0 = -inf) or at grazing incidence (cos 0) it does not; a NaN or inf
    true range is no hit; ranges exactly at the minimum and maximum are kept."""
    sensor = dataclasses.replace(get_sensor("calibrated"), range_sigma_m=0.0, range_sigma_per_m=0.0, base_dropout=0.0,
                                 power_threshold=0.25, power_softness=0.0, range_exponent=2.0, intensity_jitter=0.0,
                                 min_range_m=1.3, max_range_m=150.0)
    true_range = np.array([2.0, 2.0000001, 2.0, 2.0, np.nan, np.inf, 1.3])
    reflectivity = np.array([1.0, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0])
    cos_incidence = np.array([1.0, 1.0, 1.0, 0.0, 1.0, 1.0, -1.0])  # the sign of cos is ignored
    with np.errstate(all="raise"):
        pulse, range_m, intensity = sensor.returns(true_range, cos_incidence, reflectivity, np.random.default_rng(0))
    np.testing.assert_array_equal(pulse, [0, 6])
    np.testing.assert_array_equal(range_m, [2.0, 1.3])
    expected = [round(375.0 * (2.0 / 5.0) ** -0.28), round(375.0 * (1.3 / 5.0) ** -0.28)]  # 485; 547 clips to 511
    np.testing.assert_array_equal(intensity, [expected[0], min(expected[1], 511)])

    limits = dataclasses.replace(sensor, power_threshold=0.0)
    true_range = np.array([1.3, np.nextafter(1.3, 0.0), 150.0, np.nextafter(150.0, np.inf)])
    pulse, range_m, _ = limits.returns(true_range, np.ones(4), np.ones(4), np.random.default_rng(0))
    np.testing.assert_array_equal(pulse, [0, 2])
    np.testing.assert_array_equal(range_m, [1.3, 150.0])
