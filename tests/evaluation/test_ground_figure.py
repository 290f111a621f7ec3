"""The ground check figure: a mount's evidence (side and top view of the normalised points) as a PNG."""
import numpy as np

from pcdet_memslidar.evaluation.figures import plot_ground_check
from pcdet_memslidar.geometry.mount import Mount


def test_ground_check_writes_a_png(tmp_path):
    mount = Mount(1.6, 4.0, roll_deg=-1.5)
    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.uniform(2, 9, 500), rng.uniform(-3, 3, 500), np.zeros(500)])
    wall = np.column_stack([np.full(300, 9.0), rng.uniform(-3, 3, 300), rng.uniform(0, 2.5, 300)])
    points = np.column_stack([mount.ground_to_sensor(np.concatenate([floor, wall])), np.full(800, 100.0)])
    path = plot_ground_check(tmp_path / "check" / "ground_check.png", points, mount, "synthetic room")
    assert path == tmp_path / "check" / "ground_check.png"
    assert path.stat().st_size > 0 and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
