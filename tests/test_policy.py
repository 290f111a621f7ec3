"""The execution policy: the back end and threads chosen for each situation, handed by the runtime to the
detector; importing the package changes nothing, and the entry points set OpenMP's wait hint before torch loads."""
import logging
import os
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from easydict import EasyDict

from pcdet_memslidar import policy
from pcdet_memslidar.models import build_network
from pcdet_memslidar.models.backbone_3d import VoxelBackBone8x
from pcdet_memslidar.policy import ExecutionPolicy, choose_policy
from pcdet_memslidar.runtime.checkpoint import checkpoint_state, save_checkpoint
from pcdet_memslidar.runtime.experiment import Process
from pcdet_memslidar.runtime.predict import load_detector

OPENMP_VARIABLES = (policy.SPIN_VARIABLE, policy.WAIT_POLICY_VARIABLE, policy.MKL_REPRODUCIBILITY_VARIABLE)


def _run(code: str, **environment: str) -> str:
    """stdout of `code` in a fresh interpreter without OpenMP wait or MKL settings but `environment`."""
    env = {key: value for key, value in os.environ.items() if key not in OPENMP_VARIABLES}
    done = subprocess.run([sys.executable, "-c", code], env={**env, **environment}, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.strip().splitlines()[-1]


def test_importing_the_package_and_the_backbone_changes_neither_the_environment_nor_spconv():
    code = """
import logging, os
before = dict(os.environ)
import pcdet_memslidar, pcdet_memslidar.models.backbone_3d
import spconv.pytorch.functional as functional, spconv.pytorch.ops as ops, torch
backwards = [cls.backward for cls in vars(functional).values()
             if isinstance(cls, type) and issubclass(cls, torch.autograd.Function)]
print(dict(os.environ) == before, any(hasattr(b, "_memslidar_single_thread") for b in backwards),
      ops.get_current_stream.__module__, logging.getLogger("torch.fx._symbolic_trace").filters)
"""
    assert _run(code) == "True False spconv.pytorch.cppcore []"


@pytest.mark.parametrize("given, expected", [({}, "10000"), ({"GOMP_SPINCOUNT": "500"}, "500"),
                                             ({"OMP_WAIT_POLICY": "PASSIVE"}, "unset")])
def test_the_process_policy_shortens_libgomps_spin_unless_the_user_set_it(given, expected):
    """A GOMP_SPINCOUNT overrides OMP_WAIT_POLICY in libgomp, so a user's wait policy must keep it unset."""
    code = ("import os\nfrom pcdet_memslidar.policy import apply_process_policy\napply_process_policy()\n"
            "apply_process_policy()\nprint(os.environ.get('GOMP_SPINCOUNT', 'unset'))")
    assert _run(code, **given) == expected


@pytest.mark.parametrize("given, expected", [({}, "AUTO,STRICT"), ({"MKL_CBWR": "COMPATIBLE"}, "COMPATIBLE")])
def test_the_process_policy_asks_mkl_for_the_same_bits_on_any_thread_count(given, expected):
    """MKL's AVX2 GEMM gave other bits on two threads than on one (MKL_ENABLE_INSTRUCTIONS=AVX2) unless strict."""
    code = ("import os\nfrom pcdet_memslidar.policy import apply_process_policy\napply_process_policy()\n"
            "print(os.environ['MKL_CBWR'])")
    assert _run(code, **given) == expected


@pytest.mark.parametrize("entry_point", ["from pcdet_memslidar.cli import main\ntry:\n    main(['eval', '--help'])\n"
                                         "except SystemExit:\n    pass",
                                         "from pcdet_memslidar.openpcdet import main\nmain(['--help'])"])
def test_the_entry_points_set_the_wait_hint_before_torch_loads(entry_point):
    """libgomp reads GOMP_SPINCOUNT when torch loads it: the `memslidar` command and the OpenPCDet launcher import
    torch only after applying the process policy."""
    code = f"""
import os, sys
import pcdet_memslidar.policy
applied = []
apply = pcdet_memslidar.policy.apply_process_policy
pcdet_memslidar.policy.apply_process_policy = lambda: applied.append("torch" in sys.modules) or apply()
{entry_point}
print(applied, os.environ.get("GOMP_SPINCOUNT"))
"""
    assert _run(code) == "[False] 10000"


@pytest.mark.parametrize("device, threads, expected", [
    ("cpu", 2, ExecutionPolicy("cpu", 2, train_backend="rulebook", infer_backend="rulebook")),
    ("cpu", 1, ExecutionPolicy("cpu", 1, train_backend="spconv", infer_backend="rulebook")),
    ("cuda", 8, ExecutionPolicy("cuda", 8, train_backend="spconv", infer_backend="spconv")),
    ("cuda", 1, ExecutionPolicy("cuda", 1, train_backend="spconv", infer_backend="spconv"))])
def test_each_situation_gets_its_back_end(device, threads, expected):
    """CPU inference: the rulebook; CPU training on more than one thread: the rulebook; on one: spconv; GPU: spconv."""
    assert choose_policy(device, threads) == expected
    assert Process(torch.device(device), threads).policy == expected
    assert (expected.sparse_backend(grad=True), expected.sparse_backend(grad=False)) == (
        expected.train_backend, expected.infer_backend)


def test_the_rulebook_trains_on_the_free_cores_and_infers_on_torchs_threads(monkeypatch):
    monkeypatch.setattr(policy, "free_threads", lambda limit: min(limit, 3))  # 3 cores free
    assert choose_policy("cpu", 8).rulebook_threads(grad=True) == 3
    assert choose_policy("cpu", 2).rulebook_threads(grad=True) == 2
    assert choose_policy("cpu", 8).rulebook_threads(grad=False) is None


def test_a_process_shares_the_cores(monkeypatch):
    monkeypatch.setattr(policy, "available_cores", lambda: 5)
    assert [policy.thread_share(n) for n in (1, 2, 5, 6)] == [5, 2, 1, 1]
    with pytest.raises(ValueError, match="threads 0: a process runs on at least 1 torch thread"):
        choose_policy("cpu", 0)


@pytest.mark.parametrize("threads", [1, 2])
def test_the_runtime_gives_the_detector_its_process_policy(second_model_cfg, tmp_path, threads):
    dataset = SimpleNamespace(point_feature_encoder=SimpleNamespace(num_point_features=4),
                              point_cloud_range=np.array([0.0, -20.48, -0.5, 40.96, 20.48, 3.5], dtype=np.float32),
                              voxel_size=[0.08, 0.08, 0.1], class_names=["Pedestrian"], depth_downsample_factor=None)
    cfg = EasyDict(MODEL=second_model_cfg(), CLASS_NAMES=["Pedestrian"])
    checkpoint = save_checkpoint(checkpoint_state(build_network(cfg.MODEL, 1, dataset)), tmp_path / "model")
    process = Process(torch.device("cpu"), threads)
    model, _ = load_detector(cfg, checkpoint, dataset, process, logging.getLogger("test"))
    assert model.backbone_3d.policy == process.policy == choose_policy("cpu", threads)


def test_a_policy_for_another_device_than_the_input_is_refused_with_the_fix(second_model_cfg):
    backbone = VoxelBackBone8x(second_model_cfg().BACKBONE_3D, input_channels=4, grid_size=[64, 48, 40])
    backbone.policy = choose_policy("cuda", 1)
    batch = {"voxel_features": torch.ones(1, 4), "voxel_coords": torch.zeros(1, 4, dtype=torch.int32),
             "batch_size": 1}
    with pytest.raises(ValueError, match=r"policy is for cuda, its input is on cpu: .*choose_policy\('cpu'"):
        backbone(batch)
