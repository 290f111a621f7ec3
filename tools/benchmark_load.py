"""Speed under load: the quick model's inference (ms/frame) and training step (ms) alone on the machine and with
busy processes beside it, as shipped and with other OpenMP settings, measured in one run.

    python tools/benchmark_load.py                       # 3 busy processes, quick profile of cfgs/m3.yaml
    python tools/benchmark_load.py --busy 1 3 --frames 20

An edge box shares its cores. OpenMP threads (torch's and numba's share one libgomp pool) wait for each other at
the end of every parallel region; libgomp's default lets a waiting thread spin, which on a busy machine takes the
core from the very thread it waits for. As shipped, the entry points shorten that spin
(policy.apply_process_policy), inference takes only the cores no other process is using
(runtime.common.threads_giving_way), and the commands ask Linux for a short time slice
(utils.cores.shorten_time_slice). Each setting runs in a fresh process (libgomp reads its settings when it
loads), first idle, then with the busy processes (pure-Python loops) started by this script; ratios are loaded /
idle of the same setting. Prints a Markdown table; JSON to output/benchmark/load_benchmark.json.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from pcdet_memslidar.policy import apply_process_policy
from pcdet_memslidar.utils.atomic import write_text
from pcdet_memslidar.utils.cores import available_cores, shorten_time_slice

SETTINGS = {  # name -> (environment of the measured process (None removes a variable), inference threads give way)
    "as shipped: GOMP_SPINCOUNT 10000, inference threads give way, short slice": (
        {"OMP_WAIT_POLICY": None, "GOMP_SPINCOUNT": None, "MEMSLIDAR_SLICE_US": None}, True),
    "as shipped, but the kernel's time slice": (
        {"OMP_WAIT_POLICY": None, "GOMP_SPINCOUNT": None, "MEMSLIDAR_SLICE_US": "0"}, True),
    "before: libgomp's default spin count, fixed threads": (
        {"OMP_WAIT_POLICY": None, "GOMP_SPINCOUNT": "300000", "MEMSLIDAR_SLICE_US": "0"}, False),
    "OMP_WAIT_POLICY=PASSIVE, fixed threads": (
        {"OMP_WAIT_POLICY": "PASSIVE", "GOMP_SPINCOUNT": None, "MEMSLIDAR_SLICE_US": "0"}, False),
    "GOMP_SPINCOUNT 10000, fixed threads": (
        {"OMP_WAIT_POLICY": None, "GOMP_SPINCOUNT": None, "MEMSLIDAR_SLICE_US": "0"}, False),
    "GOMP_SPINCOUNT 1000, fixed threads": (
        {"OMP_WAIT_POLICY": None, "GOMP_SPINCOUNT": "1000", "MEMSLIDAR_SLICE_US": "0"}, False),
    "GOMP_SPINCOUNT 1000, inference threads give way": (
        {"OMP_WAIT_POLICY": None, "GOMP_SPINCOUNT": "1000", "MEMSLIDAR_SLICE_US": "0"}, True),
}
BUSY = "while True:\n    pass\n"


def measure(args) -> dict:
    """In this process: {'infer_ms', 'train_step_ms', 'threads'} of the config's model (random weights, seed 0):
    medians over frames (batch size 1, threads giving way before each frame with --give-way, as `memslidar detect`
    and `test` do) and over training steps (threads fixed: the training's results depend on them)."""
    import numpy as np
    import torch

    from benchmark_model import frames_for, time_train_step
    from pcdet_memslidar.config import load_config
    from pcdet_memslidar.models import build_network, load_data_to_device
    from pcdet_memslidar.runtime.common import get_device, set_random_seed, threads_giving_way

    torch.set_num_threads(args.threads)
    shorten_time_slice()  # as `memslidar train`, `test` and `detect` do; MEMSLIDAR_SLICE_US=0 keeps the kernel's
    cfg = load_config(args.cfg, profile=args.profile)
    device = get_device()
    dataset, _ = frames_for(cfg, training=False, count=args.frames + args.warmup)
    set_random_seed(0)
    model = build_network(cfg.MODEL, len(cfg.CLASS_NAMES), dataset).to(device)
    model.eval()
    times, threads = [], []
    with threads_giving_way() as give_way, torch.no_grad():
        for index in range(args.warmup + args.frames):
            batch = load_data_to_device(dataset.collate_batch([dataset[index % len(dataset)]]), device)
            threads.append(give_way() if args.give_way else torch.get_num_threads())
            start = time.perf_counter()
            model(batch)
            times.append((time.perf_counter() - start) * 1000)
    train_set, _ = frames_for(cfg, training=True, count=2 * args.steps + 2)
    model.train()
    step_ms, _ = time_train_step(model, train_set, cfg, 2, args.steps, device)
    return {"infer_ms": float(np.median(times[args.warmup:])), "train_step_ms": step_ms,
            "threads": float(np.mean(threads[args.warmup:]))}


def run_setting(env_changes: dict, give_way: bool, args) -> dict:
    """measure() in a fresh process with `env_changes` applied to this environment."""
    env = {**os.environ}
    for key, value in env_changes.items():
        env.pop(key, None) if value is None else env.__setitem__(key, value)
    command = [sys.executable, __file__, "--child", "--cfg", args.cfg, "--profile", args.profile, "--threads",
               str(args.threads), "--frames", str(args.frames), "--warmup", str(args.warmup), "--steps",
               str(args.steps), *(["--give-way"] if give_way else [])]
    done = subprocess.run(command, env=env, capture_output=True, text=True, check=False)
    if done.returncode:
        raise RuntimeError(f"measuring failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cfg", default="cfgs/m3.yaml")
    parser.add_argument("--profile", default="quick")
    parser.add_argument("--busy", type=int, nargs="+", default=[3], help="busy processes beside it (default 3)")
    parser.add_argument("--threads", type=int, default=available_cores(),
                        help="torch threads (default: the free cores)")
    parser.add_argument("--frames", type=int, default=20, help="timed frames (median)")
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--steps", type=int, default=6, help="timed training steps of 2 frames (median)")
    parser.add_argument("--output", default="output/benchmark/load_benchmark.json")
    parser.add_argument("--settings", nargs="+", choices=list(SETTINGS), default=list(SETTINGS),
                        metavar="SETTING", help="the settings to measure (default: all)")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--give-way", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        apply_process_policy()  # as shipped, unless the setting's environment chose otherwise; before torch loads
        print(json.dumps(measure(args)))
        return 0
    rows = []
    for name in args.settings:
        env_changes, give_way = SETTINGS[name]
        idle = run_setting(env_changes, give_way, args)
        row = {"setting": name, "idle": idle}
        for busy in args.busy:
            load = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(busy)]
            try:
                row[f"busy_{busy}"] = run_setting(env_changes, give_way, args)
            finally:
                for process in load:
                    process.kill()
                    process.wait()
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    cores = available_cores()
    print(f"\n{cores} cores, {args.threads} torch threads, {args.cfg} profile {args.profile}; median of {args.frames} "
          f"frames / {args.steps} steps; ratio = loaded / idle of the same setting\n")
    header = ["setting", "idle infer ms", "idle step ms"]
    for busy in args.busy:
        header += [f"{busy} busy: infer ms (ratio)", f"{busy} busy: step ms (ratio)"]
    print("| " + " | ".join(header) + " |\n|" + "---|" * len(header))
    for row in rows:
        cells = [row["setting"], f"{row['idle']['infer_ms']:.1f}", f"{row['idle']['train_step_ms']:.0f}"]
        for busy in args.busy:
            loaded = row[f"busy_{busy}"]
            for key, digits in (("infer_ms", 1), ("train_step_ms", 0)):
                cells.append(f"{loaded[key]:.{digits}f} ({loaded[key] / row['idle'][key]:.1f}x)")
        print("| " + " | ".join(cells) + " |")
    summary = {"cores": cores, "threads": args.threads, "cfg": args.cfg, "profile": args.profile, "rows": rows}
    write_text(Path(args.output), json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
