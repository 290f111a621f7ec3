"""The input-format registry: a format registered once (a text format of `x y z intensity` lines, written here) is
read by `memslidar import`, found by `memslidar detect`'s --format auto, accepted as a site's background and
composited into; the registry's names are the --format choices of import and detect."""
import argparse
from pathlib import Path

import numpy as np
import pytest

from pcdet_memslidar import cli
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.io.formats import FORMATS, InputFormat, list_frames, register_format
from pcdet_memslidar.io.layout import KittiLayout, read_frame
from pcdet_memslidar.monitor.detect import detect_formats, resolve_format
from pcdet_memslidar.sim.composite import composite_frame, read_background
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.site import background_format, load_site

IMPORT_FORMATS = ["bfpc", "pcd", "ply", "npy", "bin", "rosbag2", "cvat-sly", "cvat-kitti-raw"]  # import --format
DETECT_FORMATS = ["auto", "bfpc", "pcd", "ply", "npy", "bin", "rosbag2", "kitti"]  # `memslidar detect --format`


def read_xyz_fields(path: Path) -> dict[str, np.ndarray]:
    """Columns of a .xyz file: one point per line, x y z [m] and intensity."""
    return dict(zip(("x", "y", "z", "intensity"), np.loadtxt(path, ndmin=2).T))


@pytest.fixture
def xyz():
    """The .xyz format, registered for one test."""
    yield register_format(InputFormat("xyz", (".xyz",), read_fields=read_xyz_fields, timed=False))
    del FORMATS["xyz"]


@pytest.fixture
def xyz_frames(tmp_path, real_bfpc) -> tuple[Path, list[np.ndarray]]:
    """A folder of the bundled recording's first two frames (strongest returns) as .xyz files, and those returns."""
    folder = tmp_path / "frames"
    folder.mkdir()
    returns = [frame.points[frame.first_returns()] for frame in real_bfpc.frames[:2]]
    for index, points in enumerate(returns):
        np.savetxt(folder / f"{index}.xyz", points, fmt="%.9g")  # 9 digits: float32 exactly
    (folder / "README.txt").write_text("two frames of cube1_sample_2020.bfpc\n")  # no frame: ignored
    return folder, returns


def format_choices(command: str) -> list[str] | None:
    """The argparse choices of `memslidar <command> --format` (None: checked when the command runs)."""
    parser = argparse.ArgumentParser()
    cli.command_module(command).add_arguments(parser)
    return parser._option_string_actions["--format"].choices


def test_the_registry_names_are_the_format_choices_of_import_and_detect():
    assert format_choices("import") == IMPORT_FORMATS
    assert format_choices("detect") is None and detect_formats() == DETECT_FORMATS
    assert sorted(FORMATS) == sorted({*IMPORT_FORMATS, *DETECT_FORMATS} - {"auto"})


def test_import_reads_a_registered_format_into_the_kitti_layout(tmp_path, xyz, xyz_frames, capsys):
    folder, returns = xyz_frames
    out = tmp_path / "real"
    assert cli.main(["import", "--format", "xyz", "--src", str(folder), "--out", str(out)]) == 0
    assert "imported 2 frames (xyz)" in capsys.readouterr().out
    for index, points in enumerate(returns):
        frame = read_frame(KittiLayout(out), f"{index:06d}")
        np.testing.assert_array_equal(frame["points"], points)  # no mount: stored as they are
        assert frame["metadata"]["source"] == f"{index}.xyz" and "time_offset_file" not in frame["metadata"]
    with pytest.raises(ConfigError, match="--time-unit is for PCD, PLY, NPY and ROSBAG2 clouds: format xyz has no "
                                          "per-point time; drop --time-unit"):
        list_frames("xyz", folder, time_unit_s=1e-6)


def test_detect_resolves_a_file_or_folder_of_a_registered_format(xyz, xyz_frames):
    folder, returns = xyz_frames
    assert "xyz" in detect_formats()
    assert resolve_format(folder, "auto") == "xyz" and resolve_format(folder / "1.xyz", "auto") == "xyz"
    np.testing.assert_array_equal(list_frames("xyz", folder)[1].load().points, returns[1])


def site_file(tmp_path: Path, recording: Path) -> Path:
    path = tmp_path / "room.yaml"
    path.write_text(f"""\
name: room
sensor: {{pattern: cube1_2020, physics: calibrated}}
mount: {{height: 1.6, tilt_deg: 0}}
background: {{recording: {recording}}}
walkable: [[2, -3], [8, -3], [8, 1], [2, 1]]
people: {{count: [1, 1]}}
""")
    return path


def test_a_site_background_of_a_registered_format_is_composited_as_returns_without_pulses(tmp_path, xyz,
                                                                                         xyz_frames):
    folder, returns = xyz_frames
    site = load_site(site_file(tmp_path, folder))
    assert site.background.recording == str(folder) and not background_format(folder).pulses
    frames = read_background(site.background, site.pattern)
    pulses = len(get_pattern("cube1_2020").pulses()[0])
    for frame, points in zip(frames, returns, strict=True):
        assert frame.returned.sum() == len(points) and len(frame.range) >= pulses - 1  # the pattern's pulses added
        np.testing.assert_array_equal(np.sort(frame.points[frame.returned, 0]), np.sort(points[:, 0]))
    composited = composite_frame(site, seed=0, index=1)
    assert composited.metadata["background"] == "1.xyz" and len(composited.metadata["people"]) == 1


def test_a_site_background_of_no_registered_format_is_refused_naming_the_formats(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    (folder / "0.xyz").write_text("5 0 1 10\n")
    with pytest.raises(ConfigError, match=r"room.yaml:4: background.recording: .*frames: cannot tell the format "
                                          r"\(found .xyz\): a background is a file or a folder of frames of one "
                                          r"format: .bfpc, .pcd, .ply, .npy, .bin, .mcap, .db3"):
        load_site(site_file(tmp_path, folder))


def test_a_name_or_suffix_is_registered_once():
    with pytest.raises(ValueError, match="format 'npy' is registered already"):
        register_format(InputFormat("npy", (".np",), read_fields=read_xyz_fields))
    with pytest.raises(ValueError, match="suffix .npy belongs to format 'npy'"):
        register_format(InputFormat("numpy", (".npy",), read_fields=read_xyz_fields))
    assert "numpy" not in FORMATS
