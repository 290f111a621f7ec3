"""Compose a training set from named sources (Table 2: M1-M4) and keep the sim/real ratio inside batches.

Config (DATA_CONFIG.MIX):
    MIX: {TOTAL: 2100, VAL_FRACTION: 0.3, SPLIT_SEED: 0, BALANCE_BATCHES: False,
          SOURCES: [{NAME: sim, RATIO: 0.5}, {NAME: real, RATIO: 0.5, PATH: optional/folder}]}
A source gives RATIO (of TOTAL) or COUNT (frames); a simulated source may name the simulator's DOMAIN preset
(default: its NAME) and the simulation SEED (default 0) that `memslidar reproduce` makes its frames with. Each
source takes its first `count` frames in sorted id order (so adding frames never changes which ones are taken),
split 70/30 by io.layout.stable_split. DATA_CONFIG.TEST_SOURCE {NAME, PATH?, DOMAIN?, SEED?, COUNT} is read whole;
its COUNT is how many frames `memslidar reproduce` simulates of it (null: the domain's site file's number).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pcdet_memslidar.errors import ConfigError, DataFormatError
from pcdet_memslidar.io.layout import stable_split
from pcdet_memslidar.sim.site import BUNDLED_SITES

BUNDLED_DOMAINS = BUNDLED_SITES


@dataclass(frozen=True)
class Source:
    """One named source: its dataset folder (KITTI layout), how many of its frames it gives (None: all), and the
    simulator domain and seed that make its frames when it is simulated."""

    name: str
    root: Path
    count: int | None
    domain: str = ""
    seed: int = 0

    def __post_init__(self):
        if not self.domain:
            object.__setattr__(self, "domain", self.name)


def check_seed(seed, key: str) -> int:
    """`seed` if it is a non-negative integer, else ConfigError naming the config `key`, the value and the fix."""
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"{key} is {seed!r}: a seed must be a non-negative integer (0, 1, ...); fix it in the config "
                          f"(or --set)")
    return seed


def check_count(count, key: str) -> int | None:
    """`count` if it is None or a positive integer, else ConfigError naming the config `key`, the value and the
    fix."""
    if count is not None and (isinstance(count, bool) or not isinstance(count, int) or count < 1):
        raise ConfigError(f"{key} is {count!r}: give a positive number of frames, or null; fix it in the config, its "
                          f"profile (or --set)")
    return count


def split_settings(mix_cfg) -> tuple[float, int]:
    """(VAL_FRACTION, SPLIT_SEED) of DATA_CONFIG.MIX, defaults (0.3, 0): how stable_split cuts each source."""
    seed = check_seed(mix_cfg.get("SPLIT_SEED", 0), "DATA_CONFIG.MIX.SPLIT_SEED")
    return float(mix_cfg.get("VAL_FRACTION", 0.3)), seed


def _source(entry, data_path: Path, count: int | None, key: str) -> Source:
    """The Source of the MIX.SOURCES or TEST_SOURCE entry {NAME, PATH?, DOMAIN?, SEED?} at config `key`."""
    if not isinstance(entry, dict) or not entry.get("NAME"):
        raise ConfigError(f"{key} is {entry!r}: a source needs a NAME, e.g. {{NAME: industrial}}")
    seed = check_seed(entry.get("SEED", 0), f"{key}.SEED (source '{entry.NAME}')")
    return Source(entry.NAME, data_path / entry.get("PATH", entry.NAME), count, entry.get("DOMAIN", entry.NAME), seed)


def source_counts(mix_cfg) -> dict[str, int]:
    """{source name: frames} from RATIO (largest-remainder rounding so the counts sum to TOTAL) or COUNT."""
    sources = list(mix_cfg.get("SOURCES") or [])
    if not sources:
        raise ConfigError("DATA_CONFIG.MIX.SOURCES is empty: name at least one source, e.g. {NAME: real, RATIO: 1.0}")
    names = [source.get("NAME") for source in sources]
    if None in names or len(set(names)) != len(names):
        raise ConfigError(f"DATA_CONFIG.MIX.SOURCES: every source needs a unique NAME, got {names}")
    with_ratio = ["RATIO" in source for source in sources]
    if any("RATIO" in source and "COUNT" in source for source in sources) or (any(with_ratio) and not all(with_ratio)):
        raise ConfigError("DATA_CONFIG.MIX.SOURCES: give every source a RATIO (of TOTAL) or every source a COUNT, "
                          f"not both; got {[dict(source) for source in sources]}")
    if not all(with_ratio):
        counts = {source.NAME: int(source.COUNT) for source in sources}
        if min(counts.values()) < 0:
            raise ConfigError(f"DATA_CONFIG.MIX.SOURCES: COUNT must be >= 0, got {counts}")
        return counts
    total = int(mix_cfg.get("TOTAL", 0))
    ratios = np.array([float(source.RATIO) for source in sources])
    if total <= 0 or (ratios < 0).any() or not math.isclose(ratios.sum(), 1.0, abs_tol=1e-6):
        raise ConfigError(f"DATA_CONFIG.MIX: TOTAL must be > 0 and the RATIOs >= 0 and sum to 1; got TOTAL {total}, "
                          f"RATIOs {dict(zip(names, ratios.tolist()))}")
    exact = ratios * total
    counts = np.floor(exact + 1e-9).astype(np.int64)
    for index in np.argsort(-(exact - counts), kind="stable")[: total - counts.sum()]:
        counts[index] += 1
    return dict(zip(names, counts.tolist()))


def resolve_sources(mix_cfg, data_path: Path) -> list[Source]:
    """The mix's sources with their folders (PATH, relative to DATA_PATH, else DATA_PATH/<NAME>) and counts."""
    counts = source_counts(mix_cfg)
    return [_source(source, data_path, counts[source.NAME], f"DATA_CONFIG.MIX.SOURCES[{index}]")
            for index, source in enumerate(mix_cfg.SOURCES)]


def split_sources(data_cfg, split: str, data_path: Path) -> list[Source]:
    """Sources of a split: 'train' / 'val' read the MIX sources with frames, 'test' reads all of TEST_SOURCE."""
    if split in ("train", "val"):
        return [source for source in resolve_sources(data_cfg.MIX, data_path) if source.count > 0]
    if split == "test":
        return [_source(data_cfg.get("TEST_SOURCE"), data_path, None, "DATA_CONFIG.TEST_SOURCE")]
    raise ConfigError(f"DATA_CONFIG.DATA_SPLIT: unknown split {split!r}; use train, val (the mix) or test "
                      f"(DATA_CONFIG.TEST_SOURCE)")


def make_frames_command(source: Source, frames: int | None) -> str:
    """The command that creates `frames` frames (None: the domain's site file's number) of `source` in its folder."""
    importing = f"`memslidar import --format <format> --src <recordings> --out {source.root}`"
    if source.domain in BUNDLED_DOMAINS:
        count = "" if frames is None else f" --frames {frames}"
        return (f"`memslidar simulate --domain {source.domain}{count} --out {source.root} --seed {source.seed}` "
                f"(or bring recordings: {importing})")
    return f"{importing} with {'annotated frames' if frames is None else f'at least {frames} annotated frames'}"


def select_frames(source: Source, frame_ids: list[str], where: Path) -> list[str]:
    """The first `source.count` (None: all) of the sorted frame ids; DataFormatError naming `where` if too few."""
    frame_ids = sorted(frame_ids)
    if source.count is None:
        return frame_ids
    if len(frame_ids) < source.count:
        command = make_frames_command(source, source.count)
        raise DataFormatError(where, f"source '{source.name}' has {len(frame_ids)} frames but the mix needs "
                                     f"{source.count}: make them with {command}, then re-run "
                                     f"`memslidar create-infos --cfg <your cfg>`")
    return frame_ids[: source.count]


def split_frames(frame_ids: list[str], split: str, val_fraction: float, seed: int) -> list[str]:
    """The 'train' or 'val' part of frame_ids (stable_split), or all of them for any other split name."""
    if split not in ("train", "val"):
        return sorted(frame_ids)
    train, val = stable_split(frame_ids, val_fraction=val_fraction, seed=seed)
    return train if split == "train" else val


def source_split(source: Source, frame_ids: list[str], split: str, data_cfg, where: Path) -> list[str]:
    """The frames of `source` (its ids `frame_ids`) that `split` reads: the source's first `count` frames
    (select_frames; DataFormatError naming `where` if too few), then the split's part of them (split_frames with
    the MIX's split_settings)."""
    val_fraction, seed = split_settings(data_cfg.MIX)
    return split_frames(select_frames(source, frame_ids, where), split, val_fraction, seed)


class MixedBatchSampler(torch.utils.data.Sampler):
    """Batches whose share of each source matches the mix: every sample once per epoch, sources interleaved.

    Each source's indices are shuffled (seed + epoch), sample k of a source with n samples gets the key
    (k + 0.5) / n, and all samples in key order are cut into batches, so every batch holds each source in
    proportion to its size, within one sample. With num_replicas > 1 each rank takes every num_replicas-th batch
    (the list is padded by repeating its start so all ranks get the same number of batches).
    """

    def __init__(self, sources: list[str], batch_size: int, seed: int = 0, drop_last: bool = False,
                 num_replicas: int = 1, rank: int = 0):
        self.sources = np.asarray(sources)
        self.batch_size, self.seed, self.drop_last = int(batch_size), int(seed), drop_last
        self.num_replicas, self.rank = int(num_replicas), int(rank)
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def _all_batches(self) -> list[list[int]]:
        rng = np.random.default_rng([self.seed, self.epoch])
        keys, indices = [], []
        for name in np.unique(self.sources):
            members = rng.permutation(np.flatnonzero(self.sources == name))
            keys.append((np.arange(len(members)) + 0.5) / len(members))
            indices.append(members)
        order = np.concatenate(indices)[np.argsort(np.concatenate(keys), kind="stable")]
        batches = [order[i:i + self.batch_size].tolist() for i in range(0, len(order), self.batch_size)]
        if self.drop_last and batches and len(batches[-1]) < self.batch_size:
            batches.pop()
        return batches

    def __iter__(self):
        batches = self._all_batches()
        if self.num_replicas > 1:
            per_rank = math.ceil(len(batches) / self.num_replicas)
            padded = [batches[i % len(batches)] for i in range(per_rank * self.num_replicas)]
            batches = padded[self.rank::self.num_replicas]
        return iter(batches)

    def __len__(self) -> int:
        batches = len(self.sources) / self.batch_size
        return math.ceil((math.floor(batches) if self.drop_last else math.ceil(batches)) / self.num_replicas)
