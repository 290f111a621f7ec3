"""Compositing simulated people into a real recording: the shadow, pulses without a return, untouched pulses, the
pulse directions and determinism, on a hand-made background with exact answers and on the bundled recording."""
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io import ground
from pcdet_memslidar.io.bfpc import read_bfpc
from pcdet_memslidar.sim.bodies import load_body_bank
from pcdet_memslidar.sim.caster import Caster
from pcdet_memslidar.sim.composite import (
    BackgroundFrame,
    composite_frame,
    composite_pulses,
    estimate_background_mount,
    obstacle_cells,
    read_background,
)
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.people import BODY_RADIUS_M, Person
from pcdet_memslidar.sim.sensor import get_sensor
from pcdet_memslidar.sim.site import Background, load_site

RECORDING = Path(__file__).parents[2] / "pcdet_memslidar" / "assets" / "blickfeld" / "cube1_sample_2020.bfpc"
MOUNT = Mount(1.6, 0.0)
WALL_X, WALL_TOP = 6.0, 1.0  # a wall 6 m ahead, 1 m high; nothing else returns (no floor, no ceiling)
# the calibrated physics without noise, dropout or mixed pixels: a person's return lies exactly at its hit
EXACT = dataclasses.replace(get_sensor("calibrated"), range_sigma_m=0.0, range_sigma_per_m=0.0, base_dropout=0.0,
                            power_threshold=0.0, beam_divergence_rad=0.0, mixed_pixel_gap_m=0.0, intensity_jitter=0.0)


def wall_background() -> BackgroundFrame:
    """The cube1_2020 pattern's pulses against the wall: returns where a pulse meets it, none elsewhere."""
    directions, time_offset, _ = get_pattern("cube1_2020").pulses()
    along = MOUNT.directions_to_ground(directions)
    with np.errstate(divide="ignore"):
        t = np.where(along[:, 0] > 0, WALL_X / along[:, 0], np.inf)
    z = MOUNT.height + t * along[:, 2]
    ranges = np.where((z >= 0) & (z <= WALL_TOP), t, np.inf)
    points = np.full((len(ranges), 4), np.nan, dtype=np.float32)
    hit = np.isfinite(ranges)
    points[hit, :3] = directions[hit] * ranges[hit, None]
    points[hit, 3] = 150.0
    return BackgroundFrame("wall#0", directions, time_offset, ranges, points, 0.0)


def cast(background: BackgroundFrame, people: list[Person], ranges=None):
    caster = Caster(background.range if ranges is None else ranges, MOUNT, background.directions,
                    background.time_offset, get_pattern("cube1_2020").frame_period_s, load_body_bank(), lod="fine")
    return caster, composite_pulses(background, caster, people, EXACT, np.random.default_rng(0), MOUNT)


@pytest.fixture(scope="module")
def wall_case(standing_person):
    background = wall_background()
    people = [standing_person(4.0, 0.0)]
    caster, result = cast(background, people)
    _, alone = cast(background, people, np.full(len(background.range), np.inf))  # the person in an empty world
    return background, caster, result, alone.hits


def test_a_person_in_front_of_a_wall_removes_exactly_the_wall_returns_in_its_shadow(wall_case):
    background, _, result, alone = wall_case
    on_person = alone.person >= 0
    shadow = np.flatnonzero(on_person & (alone.range < background.range))  # nearer than the wall, or no wall there
    assert np.array_equal(result.hidden, shadow)
    hidden_wall = np.flatnonzero(background.returned & np.isin(np.arange(len(background.range)), shadow))
    assert len(hidden_wall) > 50  # the body below the wall's top hides wall returns
    real = result.pulse[result.person < 0]
    assert np.array_equal(real, np.setdiff1d(np.flatnonzero(background.returned), hidden_wall))
    assert len(np.intersect1d(real, shadow)) == 0


def test_a_pulse_without_a_real_return_gets_the_persons_hit(wall_case):
    background, _, result, alone = wall_case
    above_wall = result.hidden[~background.returned[result.hidden]]  # the head and shoulders above the wall's top
    assert len(above_wall) > 20
    on_person = result.pulse[result.person >= 0]
    assert np.array_equal(on_person, result.hidden)  # no noise, no dropout: every hidden pulse returns the person
    assert np.isin(above_wall, on_person).all()


def test_untouched_pulses_keep_their_real_return_bit_for_bit(wall_case):
    background, _, result, _ = wall_case
    real = result.person < 0
    expected = ground.normalise_points(background.points[result.pulse[real]], MOUNT)
    assert result.points[real].tobytes() == expected.tobytes()
    assert result.time_offset[real].tobytes() == background.time_offset[result.pulse[real]].astype(np.float32).tobytes()
    assert np.all(np.diff(result.pulse) > 0)  # one point per pulse, in pulse order


def test_composited_person_points_lie_on_their_pulses_directions(wall_case):
    background, caster, result, alone = wall_case
    person = result.person >= 0
    offset = result.points[person, :3].astype(np.float64) - MOUNT.origin
    distance = np.linalg.norm(offset, axis=1)
    direction = caster.directions[result.pulse[person]]
    assert np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", offset / distance[:, None], direction), -1, 1))).max() \
        < 1e-4
    assert np.abs(distance - alone.range[result.pulse[person]]).max() < 1e-5  # exact physics: the hit itself


def background_site(tmp_path, frames="[0, 3]"):
    path = tmp_path / "room.yaml"
    path.write_text(f"""\
name: room
sensor: {{pattern: cube1_2020, physics: calibrated}}
mount: {{height: 1.6, tilt_deg: 0}}
background: {{recording: {RECORDING}, frames: {frames}}}
walkable: [[2, -3], [8, -3], [8, 1], [2, 1]]
people: {{count: [2, 3]}}
""")
    return load_site(path)


@pytest.mark.slow
def test_a_composited_frame_of_the_bundled_recording_keeps_the_rest_of_its_real_frame(tmp_path):
    site = background_site(tmp_path)
    frame = composite_frame(site, seed=4, index=5)
    real = read_bfpc(RECORDING).frames[5 % 3]
    assert frame.metadata["background"] == "cube1_sample_2020.bfpc#2" and len(frame.boxes) >= 1
    expected = ground.normalise_points(real.points[real.first_returns()], MOUNT)
    kept = (frame.points[:, None, :] == expected[None]).all(axis=2).any(axis=1)
    hidden = frame.metadata["background_returns_hidden"]
    assert kept.sum() == len(expected) - hidden and hidden > 0  # every real return is there but those hidden
    people_points = sum(person["num_points"] for person in frame.metadata["people"])
    assert len(frame.points) == kept.sum() + people_points


def test_the_same_seed_gives_the_same_bytes(tmp_path):
    site = background_site(tmp_path)
    first, again, other = (composite_frame(site, seed, 1) for seed in (7, 7, 8))
    assert first.points.tobytes() == again.points.tobytes() and first.metadata == again.metadata
    assert first.points.tobytes() != other.points.tobytes()


@pytest.mark.slow
def test_people_stay_clear_of_what_the_background_shows_standing_on_the_floor(tmp_path):
    site = background_site(tmp_path, frames="[0, 10]")
    cells = obstacle_cells(read_background(site.background, site.pattern), MOUNT)
    assert len(cells) > 20
    clearance = BODY_RADIUS_M - 0.15  # a box centre lies within 0.15 m of the body's path
    for index in range(6):
        for person in composite_frame(site, 0, index).metadata["people"]:
            x, y = person["box"][:2]
            assert not ((cells[:, 0] - clearance < x) & (x < cells[:, 2] + clearance) & (cells[:, 1] - clearance < y)
                        & (y < cells[:, 3] + clearance)).any()


@pytest.mark.slow
def test_a_folder_of_point_clouds_keeps_every_return_along_its_own_direction(tmp_path):
    recording = read_bfpc(RECORDING)
    folder = tmp_path / "frames"
    folder.mkdir()
    for index, frame in enumerate(recording.frames[:2]):
        np.save(folder / f"{index:03d}.npy", frame.points[frame.first_returns()])
    frames = read_background(Background(str(folder)), "cube1_2020")
    for frame, real in zip(frames, recording.frames[:2]):
        returns = real.points[real.first_returns()]
        assert frame.returned.sum() == len(returns) and frame.unmatched == 0
        assert np.array_equal(np.sort(frame.points[frame.returned, 0]), np.sort(returns[:, 0]))
        assert len(frame.range) >= get_pattern("cube1_2020").pulses()[0].shape[0] - 1  # pattern pulses kept
        assert np.all(np.diff(frame.time_offset) >= 0)


@pytest.mark.slow
def test_mount_estimate_takes_the_recordings_floor(tmp_path):
    path = tmp_path / "estimated.yaml"
    path.write_text(f"""\
name: room
sensor: {{pattern: cube1_2020}}
mount: estimate
background: {{recording: {RECORDING}}}
walkable: [[2, -3], [8, -3], [8, 1], [2, 1]]
""")
    mount = load_site(path, estimate_background_mount).viewpoints[0].mount
    assert 1.5 < mount.height < 1.75 and abs(mount.tilt_deg) < 2.0  # the floor 1.6 m below, not the desks at 0.8 m
    with pytest.raises(ConfigError, match=r"estimated\.yaml:3: mount: `estimate` is not available here"):
        load_site(path)
