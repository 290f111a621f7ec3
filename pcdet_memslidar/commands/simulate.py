"""`memslidar simulate`: generate a bundled domain (sim | real | industrial) or a site file's frames as a
KITTI-layout dataset, or one sequence of consecutive frames for tracking (sim.writer); a site with a background
recording gets simulated people composited into its real frames (sim.composite)."""
from __future__ import annotations

import argparse
from pathlib import Path

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.sim.composite import estimate_background_mount, read_background
from pcdet_memslidar.sim.site import BUNDLED_SITES, get_domain, load_site
from pcdet_memslidar.sim.writer import parse_shard, simulate_dataset, simulate_sequence_dataset
from pcdet_memslidar.utils.cores import available_cores


def add_arguments(parser: argparse.ArgumentParser) -> None:
    world = parser.add_mutually_exclusive_group(required=True)
    world.add_argument("--domain", choices=BUNDLED_SITES, help="a bundled domain (its site file in cfgs/sites/)")
    world.add_argument("--site", type=Path, help="a site file (YAML: sensor, mount, scene or background, walkable "
                                                 "area, people; docs/sites.md)")
    parser.add_argument("--frames", type=int, default=None, help="number of frames (default: the site's)")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: data/memslidar/<site name>)")
    parser.add_argument("--seed", type=int, default=0, help="dataset seed; same seed -> byte-identical files")
    parser.add_argument("--workers", type=int, default=available_cores(),
                        help="worker processes (default: the cores this process may use, here %(default)s); each "
                             "takes about 2 s to start; 1 = in this process, two frames at a time in threads")
    parser.add_argument("--shard", default="0/1", help="I/N: make only frames with index %% N == I")
    parser.add_argument("--sequence", type=int, default=None, metavar="N",
                        help="instead: one sequence of N consecutive frames of the same people and viewpoint (for "
                             "tracking; metadata person_ids), made in this process")


def run(args: argparse.Namespace) -> int:
    preset = get_domain(args.domain) if args.domain else load_site(args.site, estimate_background_mount)
    if preset.background is not None:
        read_background(preset.background, preset.pattern)  # refused now if it does not fit the site's pattern
        mount = preset.viewpoints[0].mount
        print(f"people composited into {preset.background.recording} at mount height {mount.height:.3f} m, tilt "
              f"{mount.tilt_deg:.2f} deg, roll {mount.roll_deg:.2f} deg (`memslidar site check --site {args.site}` "
              f"draws its floor)")
    if args.sequence is not None:
        if args.frames is not None or args.shard != "0/1":
            raise ConfigError("--sequence N makes N frames in order: leave out --frames and --shard")
        out = args.out or Path("data") / "memslidar" / f"{preset.name}_sequence_{args.seed}"
        summary = simulate_sequence_dataset(preset, args.sequence, out, seed=args.seed)
        print(f"{out}: a sequence of {summary['written']} frames, {summary['people']} people; fingerprint "
              f"{summary['fingerprint']}")
        return 0
    frames = preset.default_frames if args.frames is None else args.frames
    out = args.out or Path("data") / "memslidar" / preset.name
    summary = simulate_dataset(preset, frames, out, seed=args.seed, workers=args.workers,
                               shard=parse_shard(args.shard))
    state = "complete, ImageSets written" if summary["complete"] else "incomplete (other shards pending)"
    remade = f" ({summary['remade']} of them damaged, made again)" if summary["remade"] else ""
    print(f"{out}: {summary['written']} frames written{remade}, {summary['skipped']} already there; {state}; "
          f"fingerprint {summary['fingerprint']}")
    return 0
