"""Site files: the bundled domains as site files (unchanged to the byte), a user's own site, and errors that name
the file, line, key and fix."""
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from pcdet_memslidar.cli import main
from pcdet_memslidar.errors import ConfigError, DataFormatError
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.geometry.polygon import points_in_polygon
from pcdet_memslidar.sim.composite import read_background
from pcdet_memslidar.sim.scenes import MATERIALS, SceneSpec, get_scene
from pcdet_memslidar.sim.site import BUNDLED_SITES, get_domain, load_site
from pcdet_memslidar.sim.writer import simulate_dataset

# sha256 of json.dumps(preset.to_dict(), sort_keys=True) of the Python presets that the bundled site files replaced
# (sim/domains.py before site files): the domain part of every fingerprint, so equal hashes mean equal frames
PRESET_SHA256 = {"sim": "22b561f91b40ddb0f87117c5580f89df5c6b96ac1bbed83139eab56e30de56f3",
                 "real": "f60cae4f43d9cfa7e7c52b1ec6e76e0ae4fd74442f6f967aead4380080760df4",
                 "industrial": "5cdf98bd9a28a7b93a3569c58fdd8f8cc85ed67f985fd9ff66a77257be0f3933"}
RECORDING = Path(__file__).parents[2] / "pcdet_memslidar" / "assets" / "blickfeld" / "cube1_sample_2020.bfpc"


@pytest.mark.parametrize("name", BUNDLED_SITES)
def test_bundled_site_files_give_the_presets_they_replaced(name):
    settings = json.dumps(get_domain(name).to_dict(), sort_keys=True)
    assert hashlib.sha256(settings.encode()).hexdigest() == PRESET_SHA256[name]


def write(tmp_path, text: str) -> Path:
    path = tmp_path / "site.yaml"
    path.write_text(text)
    return path


HALL = """\
name: hall
sensor: {pattern: cube1_paper, physics: calibrated}
mount: {height: 3.2, tilt_deg: 12}
scene:
  primitives:
    - {patch: {x: [-5, 40], y: [-20, 20], material: concrete}}
    - {wall: {start: [25, -15], end: [25, 15], height: 5}}
    - {machine: {centre: [12, 4], size: [2.5, 1.5, 2.0]}}
    - {rack: {centre: [14, -8], length: 8.1, yaw_deg: 0}}
    - {pillar: {centre: [8, 0], radius: 0.3, height: 5, material: 0.33}}
walkable: [[4, -10], [22, -10], [22, 10], [4, 10]]
people: {count: [2, 3], behaviours: {walk: 1.0}}
frames: 4
"""


def test_a_users_site_file_simulates_people_on_its_walkable_floor(tmp_path):
    site = load_site(write(tmp_path, HALL))
    assert site.viewpoints[0].mount == Mount(3.2, 12.0) and site.people == (2, 3)
    scene = get_scene(site.viewpoints[0].scene)
    reflectivity = {float(s.reflectivity) for s in scene.surfaces}
    assert {MATERIALS["concrete"], MATERIALS["metal"], MATERIALS["wood"], 0.33} <= reflectivity
    summary = simulate_dataset(site, 4, tmp_path / "out", seed=1, progress=False)
    assert summary["complete"] and summary["written"] == 4
    boxes = []
    for index in range(4):
        metadata = json.loads((tmp_path / "out" / "training" / "metadata" / f"{index:06d}.json").read_text())
        assert metadata["domain"] == "hall" and metadata["scene"] == "hall"
        boxes += [person["box"] for person in metadata["people"]]
    boxes = np.array(boxes)
    assert len(boxes) >= 8 and points_in_polygon(boxes[:, :2], np.array(site.walkable)).all()


def test_a_scene_spec_builds_on_a_bundled_scene():
    spec = SceneSpec("more", base="industrial_entrance", primitives=(("box", (("centre", (5.0, 5.0)),
                                                                                ("size", (1.0, 1.0, 1.0)),
                                                                                ("material", "wood"))),))
    base, more = get_scene("industrial_entrance"), get_scene(spec)
    assert len(more.surfaces) == len(base.surfaces) + 1 and more.walk_x_max == base.walk_x_max
    assert np.array_equal(more.obstacles[-1], [4.5, 4.5, 5.5, 5.5])


ROOM = f"""\
name: room
sensor: {{pattern: cube1_2020}}
mount: {{height: 1.6, tilt_deg: 0}}
background: {{recording: {RECORDING}}}
walkable: [[2, -3], [8, -3], [8, 1], [2, 1]]
"""


def test_a_background_site_reads_its_distractors_and_leaves_them_out_of_its_settings_when_it_has_none(tmp_path):
    plain = load_site(write(tmp_path, ROOM))
    assert plain.distractors == (0, 0) and plain.distractor_kinds is None
    site = load_site(write(tmp_path, ROOM + "distractors: {count: [1, 3], kinds: [pallet, pole]}\n"))
    assert site.distractors == (1, 3) and site.distractor_kinds == ("pallet", "pole")
    settings = site.to_dict()
    assert settings.pop("distractors") == (1, 3) and settings.pop("distractor_kinds") == ("pallet", "pole")
    assert settings == plain.to_dict()  # without distractors: the keys (and fingerprints) of before
    assert load_site(write(tmp_path, ROOM + "distractors: {count: [0, 2]}\n")).distractor_kinds is None


@pytest.mark.parametrize("text, line, message", [
    (HALL.replace("tilt_deg: 12", "tilt_dg: 12"), 3, "mount.tilt_dg: unknown key; did you mean 'tilt_deg'?"),
    (HALL.replace("people:", "peple:"), 12, "peple: unknown key; did you mean 'people'?"),
    (HALL.replace("material: concrete", "material: concret"), 6, "did you mean 'concrete'?"),
    (HALL.replace("{machine: {centre: [12, 4], size: [2.5, 1.5, 2.0]}}", "{machine: {centre: [12, 4]}}"), 8,
     "scene.primitives[2].machine: missing size"),
    (HALL.replace("count: [2, 3]", "count: [3, 2]"), 12, "give [min, max] with min <= max"),
    (HALL.replace("walkable: [[4, -10], [22, -10], [22, 10], [4, 10]]",
                  "walkable: [[-20, -10], [-4, -10], [-4, 10], [-20, 10]]"), 11,
     "only 0 % of the walkable area lies in the sensor's field of view"),
    (HALL.replace("pattern: cube1_paper", "pattern: cube2"), 2, "sensor.pattern: unknown value 'cube2'"),
    (HALL + "background: {recording: nowhere.bfpc}\n", 1, "give exactly one of scene"),
    (HALL + "distractors: {count: [0, 2]}\n", 14, "distractors: only a background site composites distractors"),
    (ROOM + "distractors: {count: [3, 1]}\n", 6, "distractors.count: [3, 1]: give [min, max] with min <= max"),
    (ROOM + "distractors: {kinds: [box]}\n", 6, "distractors: give the distractors per frame as count: [min, max]"),
    (ROOM + "distractors: {count: [0, 2], kind: [box]}\n", 6, "distractors.kind: unknown key; did you mean 'kinds'?"),
    (ROOM + "distractors: {count: [0, 2], kinds: [box, palet]}\n", 6,
     "distractors.kinds: unknown value 'palet'; did you mean 'pallet'?"),
    (ROOM + "distractors: {count: [0, 2], kinds: box}\n", 6, "distractors.kinds: give a list of kinds"),
])
def test_bad_site_files_are_refused_naming_file_line_key_and_fix(tmp_path, text, line, message):
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as error:
        load_site(path)
    assert str(error.value).startswith(f"{path}:{line}: ") and message in str(error.value)


@pytest.mark.slow
def test_a_background_of_another_scan_pattern_is_refused_naming_the_fix(tmp_path):
    path = write(tmp_path, f"""\
name: room
sensor: {{pattern: cube1_paper}}
mount: {{height: 1.6, tilt_deg: 0}}
background: {{recording: {RECORDING}}}
walkable: [[2, -3], [8, -3], [8, 1], [2, 1]]
""")
    site = load_site(path)
    with pytest.raises(DataFormatError) as error:
        read_background(site.background, site.pattern)
    assert str(error.value) == (f"{RECORDING}: recorded with another scan pattern than the site's 'cube1_paper' "
                                f"(lines_up, lines_down, angle_spacing_deg differ): set sensor.pattern to cube1_2020 "
                                f"in the site file")


def test_the_cli_reports_a_bad_site_file_in_one_line(tmp_path, capsys):
    path = write(tmp_path, HALL.replace("frames: 4", "frame: 4"))
    with pytest.raises(SystemExit) as exit_:
        main(["simulate", "--site", str(path), "--out", str(tmp_path / "out")])
    error = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "\n" not in error
    assert error == f"memslidar simulate: error: {path}:13: frame: unknown key; did you mean 'frames'? Fix the " \
                    f"spelling or remove the key"
