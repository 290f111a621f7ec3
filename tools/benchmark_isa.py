"""How much slower training and inference run when the CPU's vector code is held to AVX2, as on most laptops and
many cloud machines: tools/benchmark_model.py once per setting, each in a fresh process (the settings are read at
import), and the per-stage times side by side with their ratio to the first setting, all from one run.

    python tools/benchmark_isa.py --cfg cfgs/m3.yaml --threads 1        # one training's share of reproduce's cores

The AVX2 setting restricts every library that chooses its vector code at run time: PyTorch's ATen kernels
(ATEN_CPU_CAPABILITY), oneDNN's convolutions (ONEDNN_MAX_CPU_ISA), MKL (MKL_ENABLE_INSTRUCTIONS) and numba's
compiled rulebook (NUMBA_CPU_NAME). It does not reach code compiled ahead of time for a fixed instruction set
(spconv's wheel, numpy's and Open3D's baseline builds), nor cache sizes, memory bandwidth or clock: a real AVX2 CPU
can be slower than the restriction shows.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

SETTINGS = {  # name -> environment of the benchmark process
    "native": {},
    "avx2": {"ATEN_CPU_CAPABILITY": "avx2", "ONEDNN_MAX_CPU_ISA": "AVX2", "MKL_ENABLE_INSTRUCTIONS": "AVX2",
             "NUMBA_CPU_NAME": "haswell"},
}
BENCHMARK = Path(__file__).with_name("benchmark_model.py")


def measure(setting: str, cfg: list[str], threads: int, frames: int, out: Path) -> dict:
    """The first row of benchmark_model.py's JSON results for `setting`, run in a fresh process."""
    result = out / f"{setting}.json"
    command = [sys.executable, str(BENCHMARK), "--cfg", *cfg, "--profiles", "quick", "--threads", str(threads),
               "--frames", str(frames), "--op_kinds", "--output", str(result)]
    subprocess.run(command, check=True, env={**os.environ, **SETTINGS[setting]}, stdout=subprocess.DEVNULL)
    return json.loads(result.read_text())["rows"][0]


def stage_times(row: dict) -> dict[str, float]:
    """{stage: ms} of one benchmark row: inference per module, a training step per phase, both totals, and the
    step's ms per kind of work where the row has them (benchmark_model.py --op_kinds)."""
    return {**{f"infer: {name}": ms for name, ms in row["infer_ms_per_module"].items()},
            "infer: total": row["infer_ms"], **{f"train: {name}": ms for name, ms in row["train_ms_per_phase"].items()},
            "train: step": row["train_step_ms"],
            **{f"train ops: {kind}": ms for kind, ms in row.get("train_ms_per_op_kind", {}).items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cfg", nargs="+", default=["cfgs/m3.yaml"], help="experiment config (quick profile)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (reproduce gives each training 1)")
    parser.add_argument("--frames", type=int, default=20, help="timed frames / steps per setting")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        times = {setting: stage_times(measure(setting, args.cfg, args.threads, args.frames, Path(folder)))
                 for setting in SETTINGS}
    first, *others = SETTINGS
    print(f"| stage | {' | '.join(f'{name} (ms)' for name in SETTINGS)} | "
          f"{' | '.join(f'{name} / {first}' for name in others)} |")
    print("|---|" + "---|" * (2 * len(SETTINGS) - 1))
    for stage, ms in times[first].items():
        ratios = [f"{times[name][stage] / ms:.2f}" if ms > 0 else "n/a" for name in others]
        print(f"| {stage} | {' | '.join(f'{times[name][stage]:.1f}' for name in SETTINGS)} | {' | '.join(ratios)} |")


if __name__ == "__main__":
    main()
