"""Voxel-grid rules, Table 2 source counts and the ratio-keeping batch sampler."""
from pathlib import Path

import numpy as np
import pytest
from easydict import EasyDict

from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets.grid import check_config_grid, check_second_grid
from pcdet_memslidar.datasets.mixing import MixedBatchSampler, source_counts
from pcdet_memslidar.errors import ConfigError

CFGS = Path(__file__).resolve().parents[2] / "cfgs"
PAPER_RANGE = [2.56, -23.04, -0.5, 40.96, 23.04, 2.5]


def test_paper_grid_fits_second():
    assert check_second_grid(PAPER_RANGE, [0.08, 0.08, 0.075]).tolist() == [480, 576, 40]
    assert check_second_grid([2.56, -23.2, -0.5, 40.96, 23.2, 2.5], [0.05, 0.05, 0.075]).tolist() == [768, 928, 40]


def test_grid_rules_reject_bad_z_and_non_multiple_cells_with_sizes_that_fit():
    with pytest.raises(ConfigError) as error:
        check_second_grid(PAPER_RANGE, [0.08, 0.08, 0.1])  # 3.0 m / 0.1 = 30 z cells
    assert "[480, 576, 30]" in str(error.value)
    assert "z: voxel 0.075 m or z max 3.5 m (40 cells)" in str(error.value)
    with pytest.raises(ConfigError) as error:
        check_second_grid([0, -20.0, -0.5, 41.0, 20.0, 2.5], [0.1, 0.1, 0.075])  # 410 x cells: not a multiple of 16
    assert "[410, 400, 40]" in str(error.value)
    assert "x: voxel 0.0985577 m (416 cells) or x max 41.6 m (416 cells of 0.1 m)" in str(error.value)
    with pytest.raises(ConfigError, match="not a whole number of voxels"):
        check_second_grid(PAPER_RANGE, [0.07, 0.08, 0.075])
    assert check_second_grid(PAPER_RANGE, [0.075, 0.08, 0.075]).tolist() == [512, 576, 40]


@pytest.mark.parametrize("profile, total, grid", [("paper", 2100, [768, 928, 40]), ("quick", 400, [384, 464, 40]),
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


def test_profile_from_set_and_explicit_set_wins():
    cfg = load_config(CFGS / "m3.yaml", ["OPTIMIZATION.NUM_EPOCHS", "3", "PROFILE", "quick"])
    assert (cfg.PROFILE, cfg.DATA_CONFIG.MIX.TOTAL, cfg.OPTIMIZATION.NUM_EPOCHS) == ("quick", 400, 3)
    paper = load_config(CFGS / "m3.yaml")
    assert (paper.PROFILE, paper.DATA_CONFIG.MIX.TOTAL, paper.OPTIMIZATION.NUM_EPOCHS, paper.OPTIMIZATION.LR) == \
        ("paper", 2100, 120, 1e-3)


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
