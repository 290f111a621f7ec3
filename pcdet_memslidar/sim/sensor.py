"""Sensor physics: turns the true range of each pulse into what the LiDAR reports.

`SensorModel.measure` takes, per pulse, the true range of the surface the beam centre hits (inf = no hit), the
cosine of the incidence angle, the surface reflectivity and, where the caster found a second surface inside the
beam footprint (sampled with `beam_divergence_rad`), that surface's range. It returns the measured range, the
intensity as the device reports it (integers 0-511) and a mask of pulses that produced a return.

Presets (`get_sensor`):
- 'calibrated': fitted on the real Cube 1 recording in pcdet_memslidar/assets/blickfeld
  (tools/research/recording_stats.py): Gaussian range noise whose sigma grows slowly with range (median about
  0.8 cm), mixed pixels at edges, dropout = base rate + soft received-power threshold, intensity = reflectivity x
  |cos incidence| nearly flat with range, minimum and maximum range.
- 'carla': the paper's CARLA pipeline (Berens et al. 2022): 5 % of the returns dropped uniformly, range scaled by
  1 + N(0, 0.005), intensity 511 exp(-0.004 d) (CARLA's ray-cast LiDAR), no edge effects.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.utils.compiled import kernel

INTENSITY_MAX = 511


@dataclass(frozen=True)
class SensorModel:
    """Range noise, dropout, intensity and range limits of one LiDAR (all ranges in m).

    range_sigma_m + range_sigma_per_m * r: standard deviation of the additive Gaussian range noise at range r.
    range_scale_sigma: standard deviation of the multiplicative range error (range x (1 + N(0, s))).
    beam_divergence_rad: full divergence angle of the beam; the caster samples sub-rays inside it and reports a
        second surface as `edge_range`.
    mixed_pixel_gap_m: two surfaces inside the footprint closer than this (in range) merge into one echo whose
        range lies uniformly between them; farther apart, the echo of the surface at the beam centre wins.
    base_dropout: probability that a pulse which should return does not, whatever its power.
    power_threshold: received power P = reflectivity x |cos incidence| / range^range_exponent at which half of the
        pulses return; power_softness is the width of that step in natural-log units of P (0 = hard step).
    intensity_mode: 'reflectance' (intensity_scale x reflectivity x |cos| x (range / 5 m)^intensity_range_slope,
        with log-normal jitter intensity_jitter) or 'carla' (511 exp(-0.004 range)).
    """

    name: str
    min_range_m: float
    max_range_m: float
    range_sigma_m: float
    range_sigma_per_m: float
    range_scale_sigma: float
    beam_divergence_rad: float
    mixed_pixel_gap_m: float
    base_dropout: float
    power_threshold: float
    power_softness: float
    range_exponent: float
    intensity_mode: str
    intensity_scale: float
    intensity_range_slope: float
    intensity_jitter: float

    def __post_init__(self):
        if self.intensity_mode not in ("reflectance", "carla"):
            raise ConfigError(f"sensor '{self.name}': intensity_mode must be 'reflectance' or 'carla', "
                              f"got '{self.intensity_mode}'")
        if not 0 <= self.base_dropout < 1 or not 0 < self.min_range_m < self.max_range_m:
            raise ConfigError(f"sensor '{self.name}': need 0 <= base_dropout < 1 and 0 < min_range_m < max_range_m")

    def measure(self, true_range: np.ndarray, cos_incidence: np.ndarray, reflectivity: np.ndarray,
                rng: np.random.Generator, edge_range: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Simulate the echoes of P pulses (the arguments as for `returns`).

        Returns range (P,) float64 [m] (nan where not valid), intensity (P,) float32 integers 0-511 (0 where not
        valid), valid (P,) bool.
        """
        pulse, range_m, intensity = self.returns(true_range, cos_incidence, reflectivity, rng, edge_range)
        measured, values = np.full(len(true_range), np.nan), np.zeros(len(true_range), dtype=np.float32)
        valid = np.zeros(len(true_range), dtype=bool)
        measured[pulse], values[pulse], valid[pulse] = range_m, intensity, True
        return measured, values, valid

    def returns(self, true_range: np.ndarray, cos_incidence: np.ndarray, reflectivity: np.ndarray,
                rng: np.random.Generator, edge_range: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The returns of P pulses.

        true_range (P,) [m], inf where the beam hits nothing; cos_incidence (P,) cosine between beam and surface
        normal (sign ignored); reflectivity (P,) in [0, 1]; edge_range (P,) range of a second surface inside the
        beam footprint, nan where there is none. Draws, in this order, one uniform per mixed pixel, one standard
        normal and one uniform per hit, and one standard normal per return (intensity jitter, 'reflectance' mode
        only), so equal inputs and seeds give equal results.
        Returns pulse (n,) int64 index of each pulse that returned, its range (n,) float64 [m] and its intensity
        (n,) float32 (integers 0-511).
        """
        true_range = np.asarray(true_range, dtype=np.float64)
        hit = np.flatnonzero(np.isfinite(true_range))
        echo = true_range[hit]
        if edge_range is not None and self.mixed_pixel_gap_m > 0:
            edge = np.asarray(edge_range, dtype=np.float64)[hit]
            mixed = np.flatnonzero(np.abs(edge - echo) < self.mixed_pixel_gap_m)  # nan (no edge) compares False
            echo[mixed] += rng.random(len(mixed)) * (edge[mixed] - echo[mixed])
        # a return needs to survive the base dropout and the detection threshold: one uniform decides both
        detection = np.full(len(echo), 1.0 - self.base_dropout)
        if self.power_threshold > 0 or self.intensity_mode == "reflectance":
            cos_abs = np.abs(np.asarray(cos_incidence, dtype=np.float64)[hit])
            reflectivity = np.clip(np.asarray(reflectivity, dtype=np.float64)[hit], 0.0, 1.0)
        if self.power_threshold > 0:
            detection *= self.detection_probability(echo, cos_abs, reflectivity)
        measured = _echo_ranges(echo, rng.standard_normal(len(echo)), rng.random(len(echo)), detection,
                                self.range_sigma_m, self.range_sigma_per_m, self.range_scale_sigma, self.min_range_m,
                                self.max_range_m)
        returned = np.flatnonzero(~np.isnan(measured))
        measured = measured[returned]
        if self.intensity_mode == "carla":
            intensity = self.intensity(measured)
        else:
            intensity = self.intensity(measured, cos_abs[returned], reflectivity[returned],
                                       rng.standard_normal(len(returned)))
        return hit[returned], measured, intensity.astype(np.float32)

    def detection_probability(self, range_m: np.ndarray, cos_abs: np.ndarray, reflectivity: np.ndarray
                              ) -> np.ndarray:
        """(P,) probability that the received power of a hit is above the detector threshold (in numpy, for its
        vector log and tanh rather than a compiled loop's scalar ones)."""
        if self.power_threshold <= 0:
            return np.ones_like(range_m)
        with np.errstate(divide="ignore"):
            log_power = (np.log(reflectivity * cos_abs) - self.range_exponent * np.log(np.maximum(range_m, 1e-3)))
        margin = log_power - np.log(self.power_threshold)
        if self.power_softness <= 0:
            return (margin >= 0).astype(np.float64)
        return 0.5 * (1.0 + np.tanh(margin / (2.0 * self.power_softness)))

    def intensity(self, range_m: np.ndarray, cos_abs: np.ndarray | None = None,
                  reflectivity: np.ndarray | None = None, jitter: np.ndarray | None = None) -> np.ndarray:
        """(P,) float64 integer intensities 0-511 for echoes at range_m; cos_abs, reflectivity and jitter (P,)
        standard normal draws are needed in 'reflectance' mode only."""
        if self.intensity_mode == "carla":
            value = INTENSITY_MAX * np.exp(-0.004 * range_m)
        else:
            relative_range = np.maximum(range_m, self.min_range_m) / 5.0
            value = (self.intensity_scale * reflectivity * cos_abs * relative_range ** self.intensity_range_slope
                     * np.exp(self.intensity_jitter * jitter))
        return np.clip(np.rint(value), 0, INTENSITY_MAX)


@kernel
def _echo_ranges(echo, noise, draw, detection, sigma_m, sigma_per_m, scale_sigma, min_range_m, max_range_m):
    """(n,) measured range [m] of n echoes, nan where the echo does not return.

    echo (n,) [m] true range of each echo; noise (n,) standard normal and draw (n,) uniform [0, 1) draws;
    detection (n,) probability that it returns; the other arguments are SensorModel's fields. An echo returns if
    draw < detection and its measured range lies within [min_range_m, max_range_m]."""
    measured = np.empty(len(echo))
    for i in range(len(echo)):
        e = echo[i]
        sigma = sigma_m + sigma_per_m * e
        if scale_sigma > 0:  # additive and multiplicative error: independent Gaussians, sigmas add in quadrature
            sigma = np.sqrt(sigma * sigma + (scale_sigma * e) * (scale_sigma * e))
        value = e + sigma * noise[i]
        measured[i] = value if draw[i] < detection[i] and min_range_m <= value <= max_range_m else np.nan
    return measured


# Calibrated on pcdet_memslidar/assets/blickfeld/cube1_sample_2020.bfpc: recording_stats.calibrate_sensor(pulse_arrays(
# read_bfpc(...)), intensity_scale=375) gives the range noise line (0.60 cm + 0.039 cm/m: median sigma 0.82 cm),
# the intensity slope and jitter, the minimum range and the dropout (almost no random dropout: pulses miss when
# their received power is near the threshold). mixed_pixel_gap_m (2.5 m) is fitted to the edge tail: replaying the
# recording's scene with recording_stats.replay (seeds 0, 1) gives a p90 temporal range sigma of 4.3-4.7 cm at
# 2.4-2.6 m against the recording's 4.46 cm (2.7 cm at 1 m, 7.0 cm at 5 m), the median staying at 0.87 cm. Not
# determined by that static indoor scene, hence set by hand: intensity_scale (a surface of reflectivity x |cos| =
# 0.4, typical indoors, reads 150 at 5 m, the recording's median), the beam divergence (0.25 deg, about the 0.21 deg
# between neighbouring pulses of a scan line) and max_range_m (a hard cut beyond any scene simulated).
CALIBRATED = SensorModel(
    name="calibrated", min_range_m=1.3, max_range_m=150.0,
    range_sigma_m=0.0060, range_sigma_per_m=0.00039, range_scale_sigma=0.0,
    beam_divergence_rad=float(np.deg2rad(0.25)), mixed_pixel_gap_m=2.5,
    base_dropout=0.0003, power_threshold=9.6e-5, power_softness=0.67, range_exponent=2.0,
    intensity_mode="reflectance", intensity_scale=375.0, intensity_range_slope=-0.28, intensity_jitter=0.056)

CARLA = SensorModel(
    name="carla", min_range_m=0.1, max_range_m=120.0,
    range_sigma_m=0.0, range_sigma_per_m=0.0, range_scale_sigma=0.005,
    beam_divergence_rad=0.0, mixed_pixel_gap_m=0.0,
    base_dropout=0.05, power_threshold=0.0, power_softness=0.0, range_exponent=2.0,
    intensity_mode="carla", intensity_scale=0.0, intensity_range_slope=0.0, intensity_jitter=0.0)

SENSORS = {"calibrated": CALIBRATED, "carla": CARLA}


def get_sensor(name: str) -> SensorModel:
    """The sensor preset `name` ('calibrated' | 'carla')."""
    if name not in SENSORS:
        raise ConfigError(f"unknown sensor preset '{name}': choose one of {sorted(SENSORS)}")
    return SENSORS[name]
