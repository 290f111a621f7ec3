"""The package installs as a package, not only as a checkout: every subpackage, the configs and the bundled
recording are in the wheel, and a non-editable install runs the main job (smoke profile) from a folder of its own."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # minutes of training, simulation or installing: `pytest -m 'not slow'` leaves it out

REPO = Path(__file__).resolve().parents[1]


def test_a_non_editable_install_runs_the_smoke_reproduction(tmp_path):
    target, work = tmp_path / "site", tmp_path / "work"
    work.mkdir()
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), str(REPO)],
                   check=True, capture_output=True, timeout=300)
    env = dict(os.environ, PYTHONPATH=str(target), TQDM_DISABLE="1")
    code = "import pcdet_memslidar.config as c; print(c.__file__, c.IN_CHECKOUT, c.CONFIG_DIR)"
    where = subprocess.run([sys.executable, "-c", code], cwd=work, env=env, capture_output=True, text=True, check=True)
    assert where.stdout.split() == [str(target / "pcdet_memslidar" / "config.py"), "False",
                                    str(target / "pcdet_memslidar" / "cfgs")]
    packages = {path.parent.relative_to(REPO) for path in (REPO / "pcdet_memslidar").rglob("__init__.py")}
    assert packages and all((target / package / "__init__.py").is_file() for package in packages)
    shipped = {path.relative_to(REPO / "cfgs") for path in (REPO / "cfgs").rglob("*.yaml")}
    assert shipped == {path.relative_to(target / "pcdet_memslidar" / "cfgs")
                       for path in (target / "pcdet_memslidar" / "cfgs").rglob("*.yaml")}
    recording = Path("assets") / "blickfeld" / "cube1_sample_2020.bfpc"  # package data: the demo's input
    assert (target / "pcdet_memslidar" / recording).read_bytes() == (REPO / "pcdet_memslidar" / recording).read_bytes()
    done = subprocess.run([sys.executable, "-m", "pcdet_memslidar.cli", "reproduce", "--profile", "smoke",
                           "--seeds", "1"], cwd=work,
                          env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    results = json.loads((work / "output" / "reproduce" / "smoke" / "results.json").read_text())
    assert set(results["models"]) == {"M1", "M2", "M3", "M4", "oracle"}
    assert (work / "data" / "memslidar" / "industrial" / "simulation.json").is_file()  # data under the working folder
    assert not (target / "data").exists() and not (target / "pcdet_memslidar" / "data").exists()
