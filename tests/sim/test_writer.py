"""The dataset writer: determinism, shards, resume, fingerprint, refused arguments and folders."""
import numpy as np
import pytest

from pcdet_memslidar.errors import ConfigError, DataFormatError, OutputError
from pcdet_memslidar.io.layout import KittiLayout, read_frame
from pcdet_memslidar.sim.site import get_domain
from pcdet_memslidar.sim.writer import simulate_dataset


def _files(root):
    return {p.relative_to(root): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.slow
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


def test_a_sequence_is_written_whole_with_person_ids(tmp_path):
    import json

    from pcdet_memslidar import cli
    out = tmp_path / "sequence"
    assert cli.main(["simulate", "--domain", "industrial", "--sequence", "3", "--seed", "1001", "--out", str(out)]) == 0
    layout = KittiLayout(out)
    assert layout.frame_ids() == ["000000", "000001", "000002"]
    settings = json.loads((out / "simulation.json").read_text())
    assert (settings["sequence_length"], settings["seed"]) == (3, 1001)
    for frame_id in layout.frame_ids():
        metadata = json.loads(layout.metadata(frame_id).read_text())
        assert len(metadata["person_ids"]) == len(read_frame(layout, frame_id)["gt_boxes"])
    with pytest.raises(ConfigError, match="leave out --frames"):
        cli.command_module("simulate").run(cli.build_parser("simulate").parse_args(
            ["simulate", "--domain", "industrial", "--sequence", "3", "--frames", "5"]))
