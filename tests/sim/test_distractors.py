"""Distractors (objects that are not people) composited into the bundled real recording (examples/blickfeld_room.yaml):
placement, exact ray casting against them, what they hide, no labels, and frames of sites without them unchanged."""
import dataclasses
import hashlib
from pathlib import Path

import numpy as np
import pytest

from pcdet_memslidar.geometry.polygon import points_in_polygon
from pcdet_memslidar.io import ground
from pcdet_memslidar.sim.composite import (
    DISTRACTOR_RETURN,
    REAL_RETURN,
    background_world,
    composite_frame,
    composite_pulses,
)
from pcdet_memslidar.sim.distractors import (
    CLEARANCE_M,
    KINDS,
    Distractor,
    cast_distractors,
    footprints,
    frame_distractors,
    sample_distractors,
)
from pcdet_memslidar.sim.labels import label_people
from pcdet_memslidar.sim.sensor import get_sensor
from pcdet_memslidar.sim.site import in_field_of_view, load_site

ROOM = Path(__file__).parents[2] / "examples" / "blickfeld_room.yaml"
# the calibrated physics without noise, dropout or mixed pixels: a return lies exactly at its hit
EXACT = dataclasses.replace(get_sensor("calibrated"), range_sigma_m=0.0, range_sigma_per_m=0.0, base_dropout=0.0,
                            power_threshold=0.0, beam_divergence_rad=0.0, mixed_pixel_gap_m=0.0, intensity_jitter=0.0)
# sha256 of points, time offsets and boxes of composite_frame(room, seed, index) before distractors existed
GOLDEN = {(0, 0): "5ffc32feb702c3aebfe07f9ad54990444cd55501e18a6d462727b58843b41316",
          (3, 7): "4e981b4c0c4d7fc0ed6a3c3ff39dd385aea1fbedfd91a279dc385d8e3b841bb4"}


@pytest.fixture(scope="module")
def room():
    site = load_site(ROOM)
    return site, background_world(site)


def on_distractor(points: np.ndarray, distractor: Distractor, tolerance: float = 1e-4) -> np.ndarray:
    """(N,) bool: points (N, 3) [m] inside the distractor's footprint rectangle, from the floor to its top."""
    c, s = np.cos(distractor.yaw), np.sin(distractor.yaw)
    offset = points[:, :2] - np.asarray(distractor.centre)
    along, across = offset @ [c, s], offset @ [-s, c]
    dx, dy, dz = distractor.size
    return ((np.abs(along) <= dx / 2 + tolerance) & (np.abs(across) <= dy / 2 + tolerance)
            & (points[:, 2] >= -tolerance) & (points[:, 2] <= dz + tolerance))


@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_stands_inside_its_footprint_up_to_its_height(kind):
    (_, dx), (_, dy), (_, dz) = KINDS[kind].size
    distractor = Distractor(kind, (3.0, -1.0), (dx, dx if KINDS[kind].cylinder else dy, dz), 0.7, 0.4)
    vertices = np.concatenate([surface.vertices for surface in distractor.surfaces()])
    assert on_distractor(vertices, distractor, 1e-9).all() and vertices[:, 2].max() == pytest.approx(dz)


@pytest.mark.slow
def test_sampling_keeps_distractors_on_the_walkable_floor_in_view_and_clear_of_obstacles_and_each_other(room):
    site, world = room
    polygon, obstacles, kinds = np.array(site.walkable), world.scene.obstacles, set()
    for seed in range(30):
        placed = sample_distractors(np.random.default_rng(seed), 3, site.walkable, obstacles, world.mount, site.pattern)
        for k, distractor in enumerate(placed):
            kinds.add(distractor.kind)
            spec = KINDS[distractor.kind]
            assert points_in_polygon(distractor.corners, polygon).all()
            assert in_field_of_view(np.array([[*distractor.centre, distractor.size[2]]]), world.mount,
                                    world.pattern)[0]
            assert all(low <= value <= high for value, (low, high) in zip(distractor.size, spec.size))
            assert spec.reflectivity[0] <= distractor.reflectivity <= spec.reflectivity[1]
            x0, y0, x1, y1 = distractor.footprint
            others = np.concatenate([obstacles, footprints(placed[:k])])
            assert not ((others[:, 0] < x1 + CLEARANCE_M) & (x0 - CLEARANCE_M < others[:, 2])
                        & (others[:, 1] < y1 + CLEARANCE_M) & (y0 - CLEARANCE_M < others[:, 3])).any()
    assert {"box", "door", "column", "pole"} <= kinds  # an office fits no forklift: it is left out, not squeezed in
    only = sample_distractors(np.random.default_rng(0), 3, site.walkable, obstacles, world.mount, site.pattern,
                              ("pole",))
    assert len(only) == 3 and {d.kind for d in only} == {"pole"}


def test_a_distractor_nearer_than_a_real_return_replaces_it_exactly(room):
    site, world = room
    background, caster = world.frames[0], world.caster(0, 1)
    distractors = frame_distractors(dataclasses.replace(site, distractors=(3, 3)), 0, 0, world.scene.obstacles)
    assert len(distractors) == 3
    distractor_range, _, _ = cast_distractors(distractors, caster.origin, caster.pulse_directions)
    result = composite_pulses(background, caster, [], EXACT, np.random.default_rng(0), world.mount,
                              distractors=distractors)
    nearer = np.flatnonzero(distractor_range < background.range)
    assert np.array_equal(result.hidden, nearer) and background.returned[nearer].sum() > 100
    # every real return behind a distractor is gone, every other one is kept bit for bit
    real = result.person == REAL_RETURN
    assert np.array_equal(result.pulse[real], np.setdiff1d(np.flatnonzero(background.returned), nearer))
    assert result.points[real].tobytes() == ground.normalise_points(background.points[result.pulse[real]],
                                                                    world.mount).tobytes()
    # exact physics: every pulse that hits a distractor returns its hit, on a distractor
    cast = result.person == DISTRACTOR_RETURN
    assert np.array_equal(result.pulse[cast], nearer) and np.all(np.isin(result.person, [REAL_RETURN,
                                                                                          DISTRACTOR_RETURN]))
    distance = np.linalg.norm(result.points[cast, :3].astype(np.float64) - caster.origin, axis=1)
    assert np.abs(distance - distractor_range[nearer]).max() < 1e-5
    assert np.any([on_distractor(result.points[cast, :3], d, 1e-3) for d in distractors], axis=0).all()


def test_people_behind_a_forklift_lose_what_it_hides_and_one_unseen_gets_no_label(room, standing_person):
    site, world = room
    background, caster = world.frames[0], world.caster(0, 1)
    people = [standing_person(7.2, -0.3), standing_person(7.2, -0.8)]  # behind the gap beside its cab, behind the cab
    forklift = Distractor("forklift", (5.2, -0.3), (2.5, 1.2, 2.1), np.pi / 2, 0.4)  # across the line of sight

    def cast(distractors):
        result = composite_pulses(background, caster, people, EXACT, np.random.default_rng(0), world.mount,
                                  distractors=distractors)
        return result, *result.counts(len(people))

    alone, returned_alone, hits_alone = cast([])
    behind, returned, hits = cast([forklift])
    assert np.array_equal(returned_alone, hits_alone) and np.array_equal(returned, hits)  # exact: no dropout
    assert 0 < returned[0] < returned_alone[0] and returned[1] == 0 < returned_alone[1]
    for person in range(2):  # each keeps only pulses it had alone; what it lost ends on the forklift
        kept, had = behind.pulse[behind.person == person], alone.pulse[alone.person == person]
        assert np.isin(kept, had).all()
        assert np.all(behind.hits.person[np.setdiff1d(had, kept)] == DISTRACTOR_RETURN)
    assert np.array_equal(behind.hits.unoccluded, alone.hits.unoccluded)
    boxes, _, records = label_people(caster.bank, site.lod, people, world.pattern.frame_period_s / 2, returned, hits,
                                     behind.hits.unoccluded)
    assert len(boxes) == 1 and records[0]["labelled"] and not records[1]["labelled"]
    assert records[1]["num_points"] == 0 and records[1]["occluded_share"] == 1.0


def test_a_frame_of_distractors_and_nobody_has_no_label(room):
    site, world = room
    alone = dataclasses.replace(site, people=(0, 0), distractors=(2, 3))
    frame = composite_frame(alone, 5, 4)
    assert composite_frame(alone, 5, 4).points.tobytes() == frame.points.tobytes()
    assert len(frame.boxes) == 0 and frame.metadata["people"] == []
    distractors = frame.metadata["distractors"]
    assert 2 <= len(distractors) <= 3 and set(distractors[0]) == {"kind", "centre", "size", "yaw", "reflectivity"}
    real = world.frames[4 % len(world.frames)]
    expected = {row.tobytes() for row in ground.normalise_points(real.points[real.returned], world.mount)}
    new = frame.points[[row.tobytes() not in expected for row in frame.points]]
    assert len(frame.points) - len(new) == real.returned.sum() - frame.metadata["background_returns_hidden"]
    on = np.any([on_distractor(new[:, :3].astype(np.float64),
                               Distractor(d["kind"], tuple(d["centre"]), tuple(d["size"]), d["yaw"], 0.0), 0.05)
                 for d in distractors], axis=0)
    assert len(new) > 50 and on.mean() > 0.9  # the rest: range noise and mixed pixels at their edges


@pytest.mark.parametrize("seed, index", GOLDEN)
def test_a_site_without_distractors_gives_the_frames_it_gave_before(room, seed, index):
    site, _ = room
    assert site.distractors == (0, 0) and "distractors" not in site.to_dict()
    frame = composite_frame(site, seed, index)
    digest = hashlib.sha256(frame.points.tobytes() + frame.time_offset.tobytes() + frame.boxes.tobytes())
    assert digest.hexdigest() == GOLDEN[seed, index] and "distractors" not in frame.metadata
