"""Labels, domain presets and the dataset writer (determinism, shards, resume, fingerprint)."""
import dataclasses

import numpy as np
import pytest

from pcdet_memslidar.errors import ConfigError, DataFormatError, OutputError
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io.kitti import MIN_BOX_POINTS
from pcdet_memslidar.io.layout import KittiLayout, read_frame
from pcdet_memslidar.sim.bodies import load_body_bank
from pcdet_memslidar.sim.domains import DOMAINS, get_domain
from pcdet_memslidar.sim.frame import get_caster, render, simulate_frame
from pcdet_memslidar.sim.labels import person_boxes
from pcdet_memslidar.sim.motion import make_trajectory
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.people import Person, sample_people
from pcdet_memslidar.sim.scenes import get_scene
from pcdet_memslidar.sim.sensor import get_sensor
from pcdet_memslidar.sim.writer import simulate_dataset

PATTERN = get_pattern("cube1_paper")


def standing_person(x, y, heading=np.pi / 2, shape=2):
    trajectory = make_trajectory("stand", np.random.default_rng(0), np.array([x, y]), heading, 1.3, 1.44,
                                 PATTERN.frame_period_s)
    return Person(shape, trajectory, np.full(4, 0.5), "stand", 0, False)


def test_person_at_fov_edge_is_labelled_only_with_5_or_more_points():
    bank = load_body_bank()
    caster = get_caster("pathway", Mount(4.0, 16.0), "cube1_paper", "carla", "fine", 1)
    edge_y = -10.0 * np.tan(np.deg2rad(PATTERN.hfov_deg / 2))  # right FoV edge at x = 10 m
    counts = []
    for index, y in enumerate(edge_y + np.arange(0.6, -0.8, -0.05)):
        person = standing_person(10.0, y)
        points, _, boxes, names, records = render(caster, [person], get_sensor("carla"),
                                                  np.random.default_rng(index), bank, "fine", 0.2)
        count = records[0]["num_points"]
        counts.append(count)
        assert records[0]["labelled"] == (count >= MIN_BOX_POINTS) == (len(boxes) == 1)
        assert list(names) == ["Pedestrian"] * len(boxes)
    counts = np.array(counts)
    assert counts[0] > 20 and counts[-1] == 0  # inside the FoV, then outside it
    assert np.any((counts > 0) & (counts < MIN_BOX_POINTS))  # a sliver of a person: hit but not labelled


def test_zero_people_gives_an_empty_label_and_the_static_world():
    preset = dataclasses.replace(get_domain("real"), people=(0, 0))
    frame = simulate_frame(preset, seed=0, index=0, threads=1)
    assert frame.boxes.shape == (0, 7) and len(frame.names) == 0 and frame.metadata["people"] == []
    assert len(frame.points) > 20000 and np.isfinite(frame.points).all()


def test_box_is_the_posed_body_at_mid_frame_heading_along_travel():
    bank = load_body_bank()
    trajectory = make_trajectory("walk", np.random.default_rng(0), np.array([12.0, 1.0]), 0.7, 1.4, 1.44,
                                 PATTERN.frame_period_s)
    person = Person(4, trajectory, np.full(4, 0.5), "walk", 0, False)
    box = person_boxes(bank, "fine", [person], PATTERN.frame_period_s / 2)[0]
    assert box[6] == pytest.approx(0.7)
    assert box[2] - box[5] / 2 == pytest.approx(0.0, abs=1e-3)  # feet on the ground
    assert box[5] == pytest.approx(bank.shape_stature_m[4], abs=0.05)  # 1.86 m tall
    assert 0.3 < box[3] < 1.2 and 0.4 < box[4] < 0.8
    assert np.hypot(box[0] - 12.0, box[1] - 1.0) < 0.3


@pytest.mark.parametrize("name", sorted(DOMAINS))
def test_domain_presets_have_their_documented_properties(name):
    preset = get_domain(name)
    assert preset.pattern == "cube1_paper"
    if name == "sim":
        assert preset.sensor == "carla" and len({v.scene for v in preset.viewpoints}) == 4
        assert preset.people == (3, 10) and len(preset.shapes) == 4 and preset.phase_steps == 8
    elif name == "real":
        assert preset.sensor == "calibrated" and preset.viewpoints[0].mount == Mount(4.0, 16.0)
        assert len(preset.viewpoints) == 1 and preset.people == (1, 4) and preset.min_separation_m >= 1.5
    else:
        assert preset.sensor == "calibrated" and preset.viewpoints[0].mount == Mount(5.0, 23.0)
        assert preset.viewpoints[0].scene == "industrial_entrance" and preset.people == (1, 8)
        assert preset.default_frames == 230
    bank = load_body_bank()
    scene = get_scene(preset.viewpoints[0].scene)
    shapes = set()
    for index in range(20):
        people = sample_people(np.random.default_rng(index), preset, scene, preset.viewpoints[0].mount,
                               PATTERN.hfov_deg, PATTERN.vfov_deg, PATTERN.frame_period_s, bank)
        assert preset.people[0] - 1 <= len(people) <= preset.people[1]
        frame = (people[0].trajectory.times >= 0) & (people[0].trajectory.times <= PATTERN.frame_period_s)
        for i, a in enumerate(people):
            shapes.add(a.shape)
            for b in people[i + 1:]:
                gap = np.linalg.norm(a.trajectory.xy[frame] - b.trajectory.xy[frame], axis=1).min()
                assert gap >= (0.6 if a.group == b.group else preset.min_separation_m)
    assert shapes <= set(preset.shapes or range(bank.num_shapes))
    frame = simulate_frame(preset, seed=1, index=0, threads=1)
    assert frame.metadata["sensor"] == preset.sensor and len(frame.time_offset) == len(frame.points)
    assert np.all(frame.time_offset >= 0) and np.all(frame.time_offset <= PATTERN.frame_period_s)
    for record, box in zip([r for r in frame.metadata["people"] if r["labelled"]], frame.boxes):
        assert record["num_points"] >= MIN_BOX_POINTS and np.allclose(record["box"], box, atol=1e-5)


def _files(root):
    return {p.relative_to(root): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_gives_byte_identical_files_whatever_workers_and_shards(tmp_path):
    preset = get_domain("real")
    simulate_dataset(preset, 4, tmp_path / "a", seed=7, workers=2, progress=False)
    for shard in ((1, 2), (0, 2)):
        summary = simulate_dataset(preset, 4, tmp_path / "b", seed=7, shard=shard, progress=False)
    assert summary["complete"] and summary["written"] == 2
    a, b = _files(tmp_path / "a"), _files(tmp_path / "b")
    assert a.keys() == b.keys() and all(a[k] == b[k] for k in a)
    assert any(k.parts[0] == "ImageSets" for k in a)
    frame = read_frame(KittiLayout(tmp_path / "a"), "000003")
    offsets = np.fromfile(tmp_path / "a" / frame["metadata"]["time_offset_file"], dtype="<f4")
    assert len(offsets) == len(frame["points"]) and frame["metadata"]["fingerprint"] == summary["fingerprint"]

    # resume: a missing frame is made again, identical; the rest is skipped
    (tmp_path / "b" / "training" / "velodyne" / "000002.bin").unlink()
    summary = simulate_dataset(preset, 4, tmp_path / "b", seed=7, progress=False)
    assert (summary["written"], summary["skipped"], summary["remade"]) == (1, 3, 0)
    assert _files(tmp_path / "b") == a
    # resume checks what it skips: damaged frames are made again, identical
    training = tmp_path / "b" / "training"
    velodyne = training / "velodyne" / "000000.bin"
    velodyne.write_bytes(velodyne.read_bytes()[:-5])  # truncated mid-point
    (training / "label_2" / "000001.txt").unlink()
    (training / "metadata" / "000002.json").write_text('{"fingerprint": "')  # cut-off JSON
    offsets = training / "time_offset" / "000003.bin"
    offsets.write_bytes(offsets.read_bytes()[:-16])  # fewer time offsets than points
    summary = simulate_dataset(preset, 4, tmp_path / "b", seed=7, progress=False)
    assert (summary["written"], summary["skipped"], summary["remade"]) == (4, 0, 4)
    assert _files(tmp_path / "b") == a
    # other settings into the same folder: refused, naming the file
    with pytest.raises(DataFormatError, match="simulation.json.*other settings"):
        simulate_dataset(preset, 4, tmp_path / "b", seed=8, progress=False)
    with pytest.raises(ConfigError, match="--workers must be at least 1"):
        simulate_dataset(preset, 4, tmp_path / "c", workers=0, progress=False)
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("frames, seed, message", [
    (0, 0, "--frames must be between 1 and 1,000,000 (frame ids have six digits), got 0"),
    (-3, 0, "--frames must be between 1 and 1,000,000 (frame ids have six digits), got -3"),
    (10 ** 12, 0, "--frames must be between 1 and 1,000,000 (frame ids have six digits), got 1000000000000"),
    (4, -1, "--seed must be a non-negative integer, got -1"),
])
def test_frames_and_seed_out_of_range_are_refused_before_anything_is_written(tmp_path, frames, seed, message):
    with pytest.raises(ConfigError) as error:
        simulate_dataset(get_domain("real"), frames, tmp_path / "out", seed=seed, progress=False)
    assert str(error.value) == message and not (tmp_path / "out").exists()


def test_a_folder_of_files_simulate_did_not_make_is_left_untouched(tmp_path):
    (tmp_path / "mine" / "training").mkdir(parents=True)
    (tmp_path / "mine" / "notes.txt").write_text("keep me")
    with pytest.raises(OutputError, match=r"mine holds files that `memslidar simulate` did not make \(no simulation"
                                          r"\.json\); choose another --out, or move them away yourself"):
        simulate_dataset(get_domain("real"), 2, tmp_path / "mine", progress=False)
    assert sorted(p.name for p in (tmp_path / "mine").rglob("*")) == ["notes.txt", "training"]
