"""Two-process DDP (gloo) under torchrun: both ranks end with identical weights, each saw its own shard."""
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch

WORKER = Path(__file__).with_name("ddp_worker.py")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_two_process_gloo_training_keeps_ranks_identical(tmp_path, small_model_cfg, small_optim_cfg, small_range,
                                                          person_voxel):
    setup = tmp_path / "setup.json"
    setup.write_text(json.dumps({"point_cloud_range": small_range, "voxel_size": person_voxel,
                                 "model_cfg": small_model_cfg(), "optim_cfg": small_optim_cfg()}))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "CUDA_VISIBLE_DEVICES": ""}
    command = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "--master_addr", "127.0.0.1",
               "--master_port", str(_free_port()), str(WORKER), str(setup), str(tmp_path)]
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=170)
    assert done.returncode == 0, done.stderr[-3000:]
    rank0, rank1 = (torch.load(tmp_path / f"rank{r}.pt", weights_only=True) for r in (0, 1))
    assert rank0["world_size"] == rank1["world_size"] == 2
    assert rank0["threads"] == max(1, len(os.sched_getaffinity(0)) // 2)
    assert rank0["global_step"] == rank1["global_step"] == 4  # 2 epochs x 2 frames per rank, batch 1
    for name, value in rank0["params"].items():
        assert torch.equal(value, rank1["params"][name]), name
    assert set(rank0["seen"]).isdisjoint(rank1["seen"])  # sharded
    assert rank0["merged"] == rank1["merged"] == ["000000", "000001", "000002", "000003"]
    assert (tmp_path / "ckpt" / "checkpoint_epoch_2.pth").is_file()  # written by rank 0 only
