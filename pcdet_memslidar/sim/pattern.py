"""MEMS scan pattern of the Blickfeld Cube 1: two resonant mirrors tracing a 1:1 Lissajous figure.

Mirror angles at time tau after the start of a frame's up ramp (f the mirror frequency, phi = 2 pi f tau):
    horizontal  theta(tau) = (A_H / 2) cos(phi)
    vertical    psi(tau)   = -r(tau) (vFoV / 2) sin(phi),  r a ramp 0 -> 1 over the up lines, 1 -> 0 over the down lines
Each half mirror period is one scan line, a half-ellipse arc (even lines sweep left -> right below the horizon,
odd lines right -> left above it). The beam leaves the mirror pair at
    azimuth   = theta (1 + k psi)                 (keystone: the horizontal gain grows with the vertical deflection)
    elevation = asin(sin(psi) cos(theta))          (the vertical mirror pitches the horizontal fan)
k couples the two axes and makes the eye-shaped field of view asymmetric: upper lines are wider in azimuth, so
the equal-azimuth pulse grid reaches their ends at a larger vertical deflection than the lower lines'. Pulses fire
at equal azimuth steps inside +-hFoV / 2. fit_pattern (tools/research/recording_stats.py) fits A_H, k, the ramp lead
and f to a real recording; on the Cube 1 recording the model's directions are within 0.08 deg (az) / 0.11 deg (el) rms.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pcdet_memslidar.errors import ConfigError

FRAME_MODES = ("combine_up_down", "up", "down")
PULSE_TYPES = ("equi_horizontal_angle", "interleave")
SAMPLES_PER_LINE = 2048  # mirror phase samples per scan line for inverting azimuth -> firing time


@dataclass(frozen=True)
class ScanPattern:
    """Scan settings and mirror geometry of a MEMS LiDAR (angles in deg, frequency in Hz).

    lines_up / lines_down: scan lines of the rising / falling vertical ramp; frame_mode picks which of them form a
    frame ('combine_up_down' | 'up' | 'down'); pulse_type 'interleave' shifts alternate lines by +-spacing/4.
    horizontal_swing_deg: optical swing A_H of the horizontal mirror; keystone_per_rad: k above;
    ramp_lead_lines: how many lines the vertical ramp runs ahead of the line clock (r(tau) uses tau / T + lead).
    """

    name: str
    hfov_deg: float
    vfov_deg: float
    lines_up: int
    lines_down: int
    mirror_frequency_hz: float
    angle_spacing_deg: float
    frame_mode: str = "combine_up_down"
    pulse_type: str = "equi_horizontal_angle"
    horizontal_swing_deg: float = 80.0
    keystone_per_rad: float = 0.0
    ramp_lead_lines: float = 0.0

    def __post_init__(self):
        if self.frame_mode not in FRAME_MODES:
            raise ConfigError(f"pattern '{self.name}': frame_mode must be one of {FRAME_MODES}, "
                              f"got '{self.frame_mode}'")
        if self.pulse_type not in PULSE_TYPES:
            raise ConfigError(f"pattern '{self.name}': pulse_type must be one of {PULSE_TYPES}, "
                              f"got '{self.pulse_type}'")
        if not 0 < self.hfov_deg < self.horizontal_swing_deg or not 0 < self.vfov_deg < 90:
            raise ConfigError(f"pattern '{self.name}': need 0 < hfov_deg < horizontal_swing_deg "
                              "and 0 < vfov_deg < 90")
        if self.lines_up < 1 or self.lines_down < 1 or self.angle_spacing_deg <= 0 or self.mirror_frequency_hz <= 0:
            raise ConfigError(f"pattern '{self.name}': lines, angle spacing and mirror frequency must be positive")

    @property
    def line_period_s(self) -> float:
        """Duration of one scan line (half a mirror period) [s]."""
        return 0.5 / self.mirror_frequency_hz

    @property
    def lines_per_frame(self) -> int:
        """Scan lines in one frame."""
        return {"combine_up_down": self.lines_up + self.lines_down, "up": self.lines_up,
                "down": self.lines_down}[self.frame_mode]

    @property
    def frame_period_s(self) -> float:
        """Time between frame starts [s]: a frame mode that skips one ramp still waits for it."""
        return (self.lines_up + self.lines_down) * self.line_period_s

    def ramp(self, tau: np.ndarray) -> np.ndarray:
        """Vertical amplitude r in [0, 1] at mirror time tau [s] after the start of the up ramp."""
        lines = np.asarray(tau) / self.line_period_s + self.ramp_lead_lines
        return np.clip(np.minimum(lines / self.lines_up, (self.lines_up + self.lines_down - lines) / self.lines_down),
                       0.0, 1.0)

    def beam_angles(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Azimuth and elevation [rad] (KITTI: azimuth from +x, positive to the left) of the beam at mirror time
        tau (any shape) [s] after the start of the up ramp."""
        phase = 2.0 * np.pi * self.mirror_frequency_hz * np.asarray(tau, dtype=np.float64)
        theta = np.deg2rad(self.horizontal_swing_deg) / 2.0 * np.cos(phase)
        psi = -self.ramp(tau) * np.deg2rad(self.vfov_deg) / 2.0 * np.sin(phase)
        return theta * (1.0 + self.keystone_per_rad * psi), np.arcsin(np.sin(psi) * np.cos(theta))

    def azimuth_grid(self, line: int) -> np.ndarray:
        """(n,) pulse azimuths [rad] of scan line `line`: floor(hFoV / spacing) equal steps centred on 0."""
        count = int(np.floor(self.hfov_deg / self.angle_spacing_deg + 1e-9))
        grid = (np.arange(count) - (count - 1) / 2.0) * self.angle_spacing_deg
        if self.pulse_type == "interleave":
            grid = grid + (0.25 if line % 2 == 0 else -0.25) * self.angle_spacing_deg
        return np.deg2rad(grid[np.abs(grid) <= self.hfov_deg / 2.0])

    def pulses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All pulses of one frame in firing order.

        Returns directions (P, 3) float64 unit vectors in the sensor frame (KITTI axes: x forward, y left, z up),
        time_offset (P,) float64 [s] from the frame's first pulse, line (P,) int64 scan-line index in the frame.
        """
        first = 0 if self.frame_mode in ("combine_up_down", "up") else self.lines_up
        fraction = np.linspace(0.0, 1.0, SAMPLES_PER_LINE)
        taus, lines = [], []
        for line in range(self.lines_per_frame):
            # sample the line's half mirror period, then find the times at which the beam crosses the azimuth grid
            tau = (first + line + fraction) * self.line_period_s
            azimuth, _ = self.beam_angles(tau)
            if azimuth[0] > azimuth[-1]:
                azimuth, tau = azimuth[::-1], tau[::-1]
            grid = self.azimuth_grid(line)
            grid = grid[(grid >= azimuth[0]) & (grid <= azimuth[-1])]
            fire = np.sort(np.interp(grid, azimuth, tau))
            taus.append(fire)
            lines.append(np.full(fire.size, line, dtype=np.int64))
        tau = np.concatenate(taus)
        azimuth, elevation = self.beam_angles(tau)
        cos_el = np.cos(elevation)
        directions = np.stack([cos_el * np.cos(azimuth), cos_el * np.sin(azimuth), np.sin(elevation)], axis=1)
        return directions, tau - tau[0], np.concatenate(lines)


# Mirror geometry of the Cube 1 fitted to pcdet_memslidar/assets/blickfeld/cube1_sample_2020.bfpc (all 10 frames agree
# to 1e-4) with recording_stats.fit_pattern: horizontal swing 79.68 deg (Blickfeld: about 80), keystone 0.977 / rad,
# vertical ramp 0.527 lines ahead of the line clock; mirror frequency 147.33 Hz (frame period 0.1222 s).
CUBE1_GEOMETRY = dict(horizontal_swing_deg=79.68, keystone_per_rad=0.977, ramp_lead_lines=0.527)

PATTERNS = {
    # the paper's setting: 72 x 30 deg, 200 lines (100 up + 100 down), 0.4 deg spacing (36,000 pulses), 250 Hz
    # mirrors (Cube 1 manual: 500 lines/s) -> 0.4 s per frame
    "cube1_paper": ScanPattern(name="cube1_paper", hfov_deg=72.0, vfov_deg=30.0, lines_up=100, lines_down=100,
                               mirror_frequency_hz=250.0, angle_spacing_deg=0.4, **CUBE1_GEOMETRY),
    # the settings stored in the real recording: 72 x 30 deg, 18 + 18 lines, 0.21 deg, equal horizontal angle
    "cube1_2020": ScanPattern(name="cube1_2020", hfov_deg=72.0, vfov_deg=30.0, lines_up=18, lines_down=18,
                              mirror_frequency_hz=147.33, angle_spacing_deg=0.21, **CUBE1_GEOMETRY),
}


def get_pattern(name: str | ScanPattern) -> ScanPattern:
    """The scan pattern preset `name` ('cube1_paper' | 'cube1_2020'), or `name` itself if it is a ScanPattern (a
    site file's own)."""
    if isinstance(name, ScanPattern):
        return name
    if name not in PATTERNS:
        raise ConfigError(f"unknown scan pattern '{name}': choose one of {sorted(PATTERNS)}")
    return PATTERNS[name]
