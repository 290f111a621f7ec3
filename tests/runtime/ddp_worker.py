"""Run by test_ddp.py under torchrun: a few DDP training steps on synthetic frames, then every rank saves its
parameters and the merged order of an evaluation pass.

    python -m torch.distributed.run ... ddp_worker.py SETUP_JSON OUT_DIR

SETUP_JSON holds the test's fixtures: {"point_cloud_range", "voxel_size", "model_cfg", "optim_cfg"}."""
import json
import sys
from pathlib import Path

import torch
from easydict import EasyDict
from torch.utils.data import DataLoader, DistributedSampler

from pcdet_memslidar.datasets.synthetic import SyntheticPersonDataset
from pcdet_memslidar.models import build_network
from pcdet_memslidar.runtime.common import set_random_seed, set_torch_threads
from pcdet_memslidar.runtime.distributed import init_dist_pytorch, local_world_size, merge_results_dist
from pcdet_memslidar.runtime.optimization import build_optimizer, build_scheduler
from pcdet_memslidar.runtime.train_loop import train_model


def main(setup_file: Path, out_dir: Path) -> None:
    setup = json.loads(setup_file.read_text())
    world_size, rank = init_dist_pytorch()
    threads = set_torch_threads(local_world_size())
    set_random_seed(666 + rank)  # different initial weights per rank: DDP must broadcast rank 0's
    dataset = SyntheticPersonDataset(setup["point_cloud_range"], setup["voxel_size"], num_frames=4, seed=11)
    model = build_network(EasyDict(setup["model_cfg"]), num_class=1, dataset=dataset)
    optim_cfg = EasyDict(setup["optim_cfg"])
    sampler = DistributedSampler(dataset, num_replicas=world_size, rank=rank, shuffle=True, seed=0)
    loader = DataLoader(dataset, batch_size=1, sampler=sampler, collate_fn=dataset.collate_batch)
    ddp = torch.nn.parallel.DistributedDataParallel(model)
    optimizer = build_optimizer(ddp, optim_cfg)
    scheduler = build_scheduler(optimizer, len(loader), 2, -1, optim_cfg)
    train_model(ddp, optimizer, loader, scheduler, optim_cfg, 0, 2, 0, rank, None, out_dir / "ckpt", "cpu",
                train_sampler=sampler, use_tqdm_to_record=True)
    frames = [dataset[i]["frame_id"] for i in DistributedSampler(dataset, world_size, rank, shuffle=False)]
    merged = merge_results_dist(frames, len(dataset))
    torch.save({"params": {k: v.detach() for k, v in model.named_parameters()}, "seen": frames,
                "merged": merged, "threads": threads, "world_size": world_size,
                "global_step": int(model.global_step)}, out_dir / f"rank{rank}.pt")
    torch.distributed.destroy_process_group()


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
