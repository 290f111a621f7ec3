"""Table 2 source counts of the shipped cfgs and the ratio-keeping batch sampler."""
from pathlib import Path

import numpy as np
import pytest
from easydict import EasyDict

from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets.mixing import MixedBatchSampler, source_counts
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.grid import check_config_grid

CFGS = Path(__file__).resolve().parents[2] / "cfgs"


@pytest.mark.parametrize("profile, total, grid", [("paper", 2100, [768, 928, 40]), ("quick", 1200, [384, 464, 40]),
                                                  ("smoke", 20, [384, 464, 40])])
def test_table2_counts_and_grids_of_the_shipped_cfgs(profile, total, grid):
    expected = {"m1": (0.0, 1.0), "m2": (1.0, 0.0), "m3": (0.5, 0.5), "m4": (0.7, 0.3)}
    for name, (sim, real) in expected.items():
        cfg = load_config(CFGS / f"{name}.yaml", ["PROFILE", profile])
        assert check_config_grid(cfg).tolist() == grid
        counts = source_counts(cfg.DATA_CONFIG.MIX)
        assert counts == {"sim": round(sim * total), "real": round(real * total)}
        assert sum(counts.values()) == total
    assert source_counts(load_config(CFGS / "m4.yaml").DATA_CONFIG.MIX) == {"sim": 1470, "real": 630}


def test_counts_round_by_largest_remainder_and_validate():
    mix = EasyDict(TOTAL=10, SOURCES=[{"NAME": "a", "RATIO": 1 / 3}, {"NAME": "b", "RATIO": 1 / 3},
                                      {"NAME": "c", "RATIO": 1 / 3}])
    assert source_counts(mix) == {"a": 4, "b": 3, "c": 3}
    assert source_counts(EasyDict(SOURCES=[{"NAME": "a", "COUNT": 7}, {"NAME": "b", "COUNT": 0}])) == {"a": 7, "b": 0}
    with pytest.raises(ConfigError, match="sum to 1"):
        source_counts(EasyDict(TOTAL=10, SOURCES=[{"NAME": "a", "RATIO": 0.5}, {"NAME": "b", "RATIO": 0.4}]))
    with pytest.raises(ConfigError, match="not both"):
        source_counts(EasyDict(TOTAL=10, SOURCES=[{"NAME": "a", "RATIO": 0.5}, {"NAME": "b", "COUNT": 5}]))


def test_mixed_batches_keep_the_ratio_and_cover_every_sample_once():
    sources = ["sim"] * 70 + ["real"] * 30
    sampler = MixedBatchSampler(sources, batch_size=10, seed=3)
    batches = list(sampler)
    assert len(batches) == len(sampler) == 10
    assert sorted(i for batch in batches for i in batch) == list(range(100))
    assert all(sum(sources[i] == "sim" for i in batch) == 7 for batch in batches)
    sampler.set_epoch(1)
    assert list(sampler) != batches
    ranks = [list(MixedBatchSampler(sources, batch_size=8, num_replicas=2, rank=r)) for r in (0, 1)]
    assert len(ranks[0]) == len(ranks[1]) == 7
    covered = {i for rank in ranks for batch in rank for i in batch}
    assert covered == set(range(100))


def test_mixed_batches_with_uneven_shares_stay_within_one_sample():
    sources = np.array(["sim"] * 7 + ["real"] * 3)
    for batch in MixedBatchSampler(list(sources), batch_size=4, seed=0):
        sim = int((sources[batch] == "sim").sum())
        assert abs(sim - 0.7 * len(batch)) <= 1.0
