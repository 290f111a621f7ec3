"""`memslidar docs`: generated blocks are replaced exactly, the rest of a page is kept, runs are stored once."""
import json

import pytest

from pcdet_memslidar.cli import main as memslidar
from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.experiments.publish import STORE, fill_blocks, run_kind, strip_blocks
from pcdet_memslidar.experiments.report import cpu_table

PAGE = "# Title\n\nprose before\n<!-- BEGIN GENERATED sites -->\nold table\n<!-- END GENERATED sites -->\nprose after\n"


def site_results(site: str) -> dict:
    entry = {"AP3D_R40": 0.5, "APBEV_R40": 0.5, "interval": {"AP3D_R40": [0.4, 0.6], "APBEV_R40": [0.4, 0.6]}}
    alarms = {"frames": 3, "seconds": 0.366, "detections_per_frame": 0.0, "detections_per_minute": 0.0,
              "confirmed_tracks": 0, "frames_per_s": 20.0}
    return {"site": site, "date": "2026-11-28T10:00:00+00:00", "command": f"memslidar site train --site {site}.yaml",
            "wall_seconds": 600.0, "environment": {"commit": "0123456789abcdef", "machine": {
                "cpu": "Some CPU", "cores": 2, "gpu": None}},
            "scores": {"second": {"test": entry, "pairs": entry, "test_distractors": entry}},
            "false_alarms": {"empty": {"second": alarms}, "distractors": {"second": alarms}}}


def test_a_block_is_replaced_and_the_prose_around_it_kept():
    text = fill_blocks(PAGE, {"sites": ["| a |", "| b |"]}, "README.md")
    assert text == PAGE.replace("old table\n", "| a |\n| b |\n")
    assert strip_blocks(text) == "# Title\n\nprose before\n\nprose after\n"


def test_an_unknown_block_is_refused_naming_the_page():
    with pytest.raises(DataFormatError, match="README.md.*unknown generated block 'nonsense'"):
        fill_blocks(PAGE.replace("sites", "nonsense"), {"sites": []}, "README.md")


def test_docs_stores_a_site_run_and_renders_its_table_into_both_pages(tmp_path):
    root, run = tmp_path / "repo", tmp_path / "output" / "site" / "room"
    (root / "docs").mkdir(parents=True)
    run.mkdir(parents=True)
    (root / "README.md").write_text(PAGE)
    (root / "docs" / "results.md").write_text("<!-- BEGIN GENERATED results -->\n<!-- END GENERATED results -->\n")
    (run / "results.json").write_text(json.dumps(site_results("room")))
    assert memslidar(["docs", "--root", str(root), "--add", str(run)]) == 0
    assert json.loads((root / STORE / "site_room.json").read_text()) == site_results("room")
    readme = (root / "README.md").read_text()
    assert ("- room: 2026-11-28T10:00:00+00:00; Some CPU, 2 cores, GPU: none; commit 0123456789abcdef; `memslidar "
            "site train --site room.yaml`; 10.0 min") in readme
    assert "| room | SECOND | 0.500 [0.400, 0.600] |" in readme and "old table" not in readme
    assert "### room" in (root / "docs" / "results.md").read_text()
    before = {path: path.read_text() for path in (root / "README.md", root / "docs" / "results.md")}
    assert memslidar(["docs", "--root", str(root)]) == 0  # from the store alone: the same pages
    assert {path: path.read_text() for path in before} == before


def test_a_folder_without_results_is_refused_in_one_line_naming_it(tmp_path, capsys):
    (tmp_path / "README.md").write_text(PAGE)
    with pytest.raises(SystemExit) as exit_info:
        memslidar(["docs", "--root", str(tmp_path), "--add", str(tmp_path / "empty_run")])
    assert exit_info.value.code == 2
    message = capsys.readouterr().err
    assert message.count("\n") == 1 and "empty_run: no results.json here" in message
    assert (tmp_path / "README.md").read_text() == PAGE


def reproduction(cpu: str, vector_code: str, means: dict, seeds: int = 3) -> dict:
    models = {name: {"mean": {"AP3D_R40": mean}, "std": {"AP3D_R40": 0.01}} for name, mean in means.items()}
    return {"profile": "quick", "test_domain": "industrial", "models": models, "seeds": list(range(seeds)),
            "command": "memslidar reproduce --profile quick --seeds 3", "date": "2026-11-28T10:00:00+00:00",
            "environment": {"commit": "abc", "machine": {"cpu": cpu, "aten_cpu_capability": vector_code}}}


def test_a_reproduction_is_stored_once_per_cpu_and_vector_code():
    assert run_kind(reproduction("Intel(R) Xeon(R) Processor", "AVX512", {})) == (
        "reproduce", "quick_intel_r_xeon_r_processor_avx512")
    assert run_kind(reproduction("Intel(R) Xeon(R) Processor", "AVX2", {})) == (
        "reproduce", "quick_intel_r_xeon_r_processor_avx2")


def test_the_cpu_table_gives_each_model_s_seed_mean_per_row_and_the_spread_between_rows():
    lines = cpu_table([reproduction("CPU A", "AVX512", {"M1": 0.60, "M2": 0.31}),
                       reproduction("CPU A", "AVX2", {"M1": 0.62, "M2": 0.39})])
    assert lines[0] == "| CPU | torch vector code | commit | command | seeds | M1 | M2 |"
    assert lines[2].endswith("| 3 | 0.600 ± 0.010 | 0.310 ± 0.010 |") and "| AVX512 |" in lines[2]
    assert lines[4] == "| **spread between the rows** |  |  |  |  | 0.020 | 0.080 |"
    assert len(cpu_table([reproduction("CPU A", "AVX512", {"M1": 0.60})])) == 3  # one row: no spread
