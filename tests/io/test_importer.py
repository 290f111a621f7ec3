"""`memslidar import` on the real Cube 1 recording and on bad input (nothing half-written); it never replaces its
input or what it did not write; file-system errors and bad arguments are one clear line; leftovers of a killed
import are removed by the next one."""
import gzip
import json
import subprocess

import numpy as np
import pytest

from pcdet_memslidar import cli
from pcdet_memslidar.config import SCHEMA_FILE, load_config
from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io.bfpc import read_bfpc
from pcdet_memslidar.io.importer import import_dataset
from pcdet_memslidar.io.kitti import read_point_times
from pcdet_memslidar.io.layout import KittiLayout, read_frame

PULSES_PER_FRAME = 12_312


@pytest.fixture(scope="module")
def recording(real_recording):
    return read_bfpc(real_recording)


@pytest.mark.slow
def test_real_recording_imports_with_a_given_mount(tmp_path, real_recording, recording):
    mount = Mount(2.0, 10.0)
    report = import_dataset("bfpc", real_recording, tmp_path / "real", mount=mount)
    assert report["frames"] == 10 and report["frames_without_labels"] == 10 and report["boxes"] == 0
    assert (report["train_frames"], report["val_frames"]) == (7, 3)
    assert report["point_cloud_range"] == load_config(SCHEMA_FILE).DATA_CONFIG.POINT_CLOUD_RANGE  # the detector's
    for entry in report["per_frame"]:
        assert entry["points"] + entry["dropped_invalid_points"] == PULSES_PER_FRAME
    assert report["dropped_invalid_points"] == sum((~f.returned).sum() for f in recording.frames)
    frame = read_frame(KittiLayout(tmp_path / "real"), "000003")
    expected = mount.sensor_to_ground(recording.frames[3].points[:, :3])
    np.testing.assert_allclose(frame["points"][:, :3], expected, atol=1e-5)
    np.testing.assert_array_equal(frame["points"][:, 3], recording.frames[3].points[:, 3])
    assert len(frame["metadata"]["point_time"]) == len(frame["points"]) and frame["metadata"]["source"].endswith("#3")
    assert 0.0 <= min(frame["metadata"]["point_time"]) and max(frame["metadata"]["point_time"]) < 0.125
    # the times in seconds from the frame's first point, as simulated frames keep them (the box step's drift)
    assert frame["metadata"]["time_offset_file"] == "training/time_offset/000003.bin"
    times = read_point_times(KittiLayout(tmp_path / "real").time_offset("000003"), len(frame["points"]))
    pulse_times = recording.frames[3].time_offset[recording.frames[3].return_pulse[recording.frames[3].first_returns()]]
    np.testing.assert_array_equal(times, (pulse_times - pulse_times.min()).astype(np.float32))


def test_cli_estimates_the_ground_and_refuses_to_overwrite(tmp_path, scan_room, capsys):
    mount = Mount(4.0, 16.0, roll_deg=0.5)
    (tmp_path / "clouds").mkdir()
    for seed in range(3):
        np.save(tmp_path / "clouds" / f"frame_{seed}.npy", scan_room(mount, seed))
    out = tmp_path / "real"
    args = ["import", "--format", "npy", "--src", str(tmp_path / "clouds"), "--out", str(out), "--estimate-ground"]
    assert cli.main(args) == 0
    estimate = json.loads((out / "import_report.json").read_text())["mount"]
    assert estimate["source"].startswith("estimated") and "ground plane" in capsys.readouterr().out
    assert abs(estimate["height"] - 4.0) < 0.02 and abs(estimate["tilt_deg"] - 16.0) < 0.2
    assert abs(estimate["roll_deg"] - 0.5) < 0.2
    floor = read_frame(KittiLayout(out), "000001")["points"]
    floor = floor[(floor[:, 0] > 9.0) & (floor[:, 0] < 11.5)]
    assert abs(np.median(floor[:, 2])) < 0.01
    assert cli.main(args) == 2 and "--overwrite" in capsys.readouterr().err


def test_cli_refuses_to_estimate_the_ground_without_a_floor_in_view(tmp_path, capsys):
    """Five frames of a level sensor's upper half of view, a wall 6 m ahead and no floor: exit 1, one error line
    naming the frames the estimate used and --mount (then the command's usual note), nothing written."""
    rng = np.random.default_rng(0)
    src, out = tmp_path / "clouds", tmp_path / "real"
    src.mkdir()
    for i in range(6):
        wall = np.column_stack([np.full(3000, 6.0), rng.uniform(-3.0, 3.0, 3000), rng.uniform(0.0, 2.0, 3000)])
        np.save(src / f"frame_{i}.npy", np.column_stack([wall + rng.normal(0.0, 0.01, wall.shape), np.ones(3000)]))
    code, error = _import(capsys, src, out, "--estimate-ground")
    assert code == 1 and not out.exists()
    line, note = error.splitlines()
    assert line.startswith("error: frame_0.npy to frame_4.npy: --estimate-ground: the plane found is not a floor")
    assert line.endswith("pass --mount H,TILT[,ROLL] (metres, degrees) instead")
    assert note == f"(nothing was written to {out})"


def test_corrupt_gzip_and_truncated_protobuf_write_nothing(tmp_path, real_recording, capsys):
    data = real_recording.read_bytes()
    corrupt = tmp_path / "corrupt.bfpc"
    corrupt.write_bytes(data[:5000] + bytes(b ^ 0x5A for b in data[5000:9000]) + data[9000:])
    truncated = tmp_path / "truncated.bfpc"
    truncated.write_bytes(gzip.compress(gzip.decompress(data)[:1_000_000]))
    for source, message in ((corrupt, "gzip"), (truncated, "truncated")):
        out = tmp_path / f"out_{source.stem}"
        assert cli.main(["import", "--format", "bfpc", "--src", str(source), "--out", str(out)]) == 1
        error = capsys.readouterr().err
        assert str(source) in error and message in error and not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary folder left behind


def test_failed_reimport_keeps_the_previous_dataset(tmp_path):
    clouds = tmp_path / "clouds"
    clouds.mkdir()
    for i in range(3):
        np.save(clouds / f"{i}.npy", np.array([[5.0, 0.0, -2.0, 10.0 * i]]))
    out = tmp_path / "real"
    assert import_dataset("npy", clouds, out, mount=Mount(2.0, 0.0))["frames"] == 3
    np.save(clouds / "3.npy", np.zeros((2, 7)))  # a bad frame after three good ones
    with pytest.raises(ValueError, match=r"3\.npy"):
        import_dataset("npy", clouds, out, mount=Mount(2.0, 0.0))
    assert KittiLayout(out).frame_ids() == ["000000", "000001", "000002"]
    np.testing.assert_allclose(read_frame(KittiLayout(out), "000002")["points"], [[5.0, 0.0, 0.0, 20.0]])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clouds", "real"]


@pytest.fixture
def clouds(tmp_path):
    """A folder of two .npy clouds."""
    folder = tmp_path / "clouds"
    folder.mkdir()
    for i in range(2):
        np.save(folder / f"{i}.npy", np.array([[5.0, 0.0, 1.0, 10.0 * i]]))
    return folder


def _import(capsys, src, out, *extra) -> tuple[int, str]:
    """Exit code and stderr of `memslidar import --format npy --src SRC --out OUT EXTRA`."""
    try:
        code = cli.main(["import", "--format", "npy", "--src", str(src), "--out", str(out), *extra])
    except SystemExit as exit_:
        code = exit_.code
    return code, capsys.readouterr().err


def test_out_that_is_or_holds_the_source_is_refused_and_the_source_kept(clouds, capsys):
    before = {p.name: p.read_bytes() for p in clouds.iterdir()}
    for src, message in ((clouds / "0.npy", f"--out {clouds} contains the input {clouds / '0.npy'}"),
                         (clouds, f"--out {clouds} is the input {clouds}")):
        code, error = _import(capsys, src, clouds, "--overwrite")
        assert code == 2 and f"{message}; choose --out outside every input" in error
    assert {p.name: p.read_bytes() for p in clouds.iterdir()} == before


def test_a_folder_or_file_it_did_not_write_is_refused_and_its_own_output_replaced(tmp_path, clouds, capsys):
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    (tmp_path / "file").write_text("mine")
    for out, message in ((user, f"{user} holds files that memslidar import did not write"),
                         (tmp_path / "file", f"{tmp_path / 'file'} is a file")):
        code, error = _import(capsys, clouds, out, "--overwrite")
        assert code == 2 and message in error and "choose a new folder, or move or delete it yourself" in error
    assert list(user.iterdir()) == [user / "notes.txt"] and (user / "notes.txt").read_text() == "mine"
    assert (tmp_path / "file").read_text() == "mine"

    out = tmp_path / "real"
    assert _import(capsys, clouds, out)[0] == 0
    np.save(clouds / "2.npy", np.array([[6.0, 0.0, 1.0, 1.0]]))
    code, error = _import(capsys, clouds, out)
    assert code == 2 and f"--out {out} holds an earlier import; pass --overwrite" in error
    assert _import(capsys, clouds, out, "--overwrite")[0] == 0
    assert KittiLayout(out).frame_ids() == ["000000", "000001", "000002"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clouds", "file", "real", "user"]


def test_a_full_disk_is_one_line_naming_the_output(tmp_path, clouds, capsys, full_disk):
    out = tmp_path / "real"
    code, error = _import(capsys, clouds, out)
    assert code == 2 and "Traceback" not in error
    assert error.splitlines()[-1].startswith(f"memslidar import: error: {out}/training/")  # not the hidden temporary
    assert "No space left on device; free space on that disk" in error
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clouds"]


def test_the_temporary_folder_of_a_killed_import_is_removed_by_the_next(tmp_path, clouds):
    child = subprocess.Popen(["true"])
    child.wait()  # its pid now names no process, as after kill -9
    leftover = tmp_path / f".real.{child.pid}.0.tmp"
    (leftover / "training" / "velodyne").mkdir(parents=True)
    import_dataset("npy", clouds, tmp_path / "real", mount=Mount(2.0, 0.0))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clouds", "real"]


def test_nan_intensity_names_the_source_file(tmp_path, clouds):
    np.save(clouds / "1.npy", np.array([[5.0, 0.0, 1.0, 1.0], [6.0, 0.0, 1.0, np.nan]]))
    with pytest.raises(DataFormatError, match=rf"^{clouds / '1.npy'}: 1 point\(s\) with valid x, y, z have a NaN or "
                                              r"infinite 'intensity', the first is point 1 \(counting from 0\)"):
        import_dataset("npy", clouds, tmp_path / "real")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clouds"]


@pytest.mark.parametrize("mount", ["nan,16", "4,inf"])
def test_a_non_finite_mount_is_an_argument_error(tmp_path, clouds, capsys, mount):
    code, error = _import(capsys, clouds, tmp_path / "real", "--mount", mount)
    assert code == 2 and f"argument --mount: --mount '{mount}': expected HEIGHT,TILT[,ROLL] as finite numbers" in error
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clouds"]


def test_time_unit_writes_the_time_offsets_of_npy_clouds_and_is_refused_where_it_cannot_apply(tmp_path, clouds,
                                                                                            capsys):
    np.save(clouds / "1.npy", np.array([[5.0, 0.0, 1.0, 3.0, 2_000], [6.0, 0.0, 1.0, 4.0, 52_000]]))  # [us]
    out = tmp_path / "real"
    code, error = _import(capsys, clouds, out, "--mount", "2,0", "--time-unit", "us")
    assert code == 1 and "0.npy: a time unit was given (--time-unit) but the file has no time field" in error
    assert not out.exists()
    np.save(clouds / "0.npy", np.array([[5.0, 0.0, 1.0, 3.0, 7]]))
    assert _import(capsys, clouds, out, "--mount", "2,0", "--time-unit", "us")[0] == 0
    layout = KittiLayout(out)
    assert read_point_times(layout.time_offset("000001"), 2).tolist() == [0.0, np.float32(0.05)]
    assert read_point_times(layout.time_offset("000000"), 1).tolist() == [0.0]
    code, error = _import(capsys, clouds, out, "--time-unit", "minutes")
    assert code == 2 and "argument --time-unit: unknown time unit 'minutes': use one of s, ms, us, ns" in error
    bfpc = cli.main(["import", "--format", "bfpc", "--src", str(clouds), "--out", str(tmp_path / "b"), "--time-unit",
                     "s"])
    assert bfpc == 1 and capsys.readouterr().err.startswith(
        "error: --time-unit is for PCD, PLY, NPY and ROSBAG2 clouds: format bfpc records the unit of its point times; "
        "drop --time-unit")
