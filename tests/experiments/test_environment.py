"""results['environment'] says which code ran where: the git commit of this checkout, the CPU's vector extensions."""
import subprocess
from pathlib import Path

import torch

from pcdet_memslidar.experiments.report import run_header, wall_time
from pcdet_memslidar.experiments.results import VECTOR_EXTENSIONS, environment

ROOT = Path(__file__).resolve().parents[2]


def test_the_environment_names_this_checkout_s_commit_and_the_cpu_s_vector_code():
    env = environment()
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    if head:  # a git checkout (CI's clean clone is one)
        assert env["commit"].removesuffix("+dirty") == head
    assert set(env["machine"]["vector_extensions"]) <= VECTOR_EXTENSIONS
    assert env["machine"]["aten_cpu_capability"] == torch.backends.cpu.get_cpu_capability()


def test_the_run_header_reads_results_from_before_the_commit_was_recorded():
    results = {"date": "2026-11-28", "command": "memslidar reproduce",
               "environment": {"machine": {"cpu": "Old CPU", "cores": 2, "gpu": None}}}
    assert run_header(results) == "2026-11-28; Old CPU, 2 cores, GPU: none; commit unknown; `memslidar reproduce`"


def test_the_wall_time_says_how_busy_the_machine_was():
    results = {"wall_seconds": 1488.0, "environment": {"machine": {"load_average_1min": 3.4970703125}}}
    assert wall_time(results) == "24.8 min, 1-min load average 3.5 at the end"


def test_the_wall_time_says_which_trainings_it_leaves_out():
    """A reproduction that read finished models back from its --out did not train them in the time it reports."""
    runs = {"M1": {"runs": [{"seed": 0, "read_back": True}, {"seed": 1}]}, "M2": {"runs": [{"seed": 0}, {"seed": 1}]}}
    results = {"wall_seconds": 324.0, "environment": {"machine": {}}, "models": runs}
    assert wall_time(results) == ("5.4 min (1 of 4 trainings read back from earlier calls in its --out, their time "
                                  "not included)")
    site = {"wall_seconds": 60.0, "environment": {"machine": {}}, "read_back": {"second": True, "background2": True}}
    assert wall_time(site) == ("1.0 min (2 of 2 trainings read back from earlier calls in its --out, their time not "
                               "included)")
    assert wall_time({**site, "read_back": {"second": False}}) == "1.0 min"
