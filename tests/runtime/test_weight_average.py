"""The average of the weights over the training steps (runtime.weight_average, OPTIMIZATION.EMA_DECAY): exact
updates, the training's own steps left unchanged to the bit, checkpoints that hold both states and resume exactly."""
import pytest
import torch
from easydict import EasyDict
from torch.utils.data import DataLoader

from pcdet_memslidar.datasets.synthetic import SyntheticPersonDataset
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.models import build_network
from pcdet_memslidar.runtime.checkpoint import load_params_with_optimizer, read_checkpoint
from pcdet_memslidar.runtime.common import set_random_seed
from pcdet_memslidar.runtime.optimization import build_optimizer, build_scheduler
from pcdet_memslidar.runtime.train_loop import train_model
from pcdet_memslidar.runtime.weight_average import WeightAverage, weight_average


def tiny_model() -> torch.nn.Module:
    model = torch.nn.Sequential(torch.nn.Linear(1, 1), torch.nn.BatchNorm1d(1))
    with torch.no_grad():
        model[0].weight.fill_(1.0)
        model[0].bias.fill_(-4.0)
    return model


def test_update_is_the_exponential_average_with_its_warm_up_and_copies_integer_buffers():
    model = tiny_model()
    average = WeightAverage(model, decay=0.5, steps=10)  # step 11: min(0.5, 12 / 21) = 0.5
    with torch.no_grad():
        model[0].weight.fill_(3.0)
        model[1].num_batches_tracked.fill_(7)
    average.update(model)
    assert average.state["0.weight"].item() == 2.0  # 0.5 * 1 + 0.5 * 3, exactly
    assert average.state["0.bias"].item() == -4.0
    assert average.state["1.num_batches_tracked"].item() == 7
    average.update(model)
    assert average.state["0.weight"].item() == 2.5
    fresh = WeightAverage(tiny_model(), decay=0.999)  # step 1: min(0.999, 2 / 11): the start is mostly forgotten
    fresh.update(model)
    assert fresh.state["0.weight"].item() == pytest.approx(1.0 + (1 - 2 / 11) * 2.0, abs=1e-6)


def test_applied_swaps_the_average_in_and_the_weights_back():
    model = tiny_model()
    average = WeightAverage(model, decay=0.5, steps=10)
    with torch.no_grad():
        model[0].weight.fill_(3.0)
    average.update(model)
    with average.applied(model):
        assert model[0].weight.item() == 2.0
    assert model[0].weight.item() == 3.0


@pytest.mark.parametrize("decay", [0.0, 1.0, 1.5, -0.1])
def test_a_decay_outside_the_open_unit_interval_is_refused(decay):
    with pytest.raises(ConfigError, match="EMA_DECAY must be in \\(0, 1\\)"):
        weight_average(EasyDict(EMA_DECAY=decay), tiny_model(), 0)


def test_no_key_no_average():
    assert weight_average(EasyDict(), tiny_model(), 0) is None


@pytest.fixture(scope="module")
def dataset(small_range, person_voxel):
    return SyntheticPersonDataset(small_range, person_voxel, num_frames=4, seed=7)


@pytest.fixture(scope="module")
def train(small_model_cfg, small_optim_cfg):
    """train(dataset, out_dir, ema, epochs=2, ckpt=None) -> (model, average): the small SECOND under seed 666."""
    def run(dataset, out_dir, ema, epochs=2, ckpt=None):
        set_random_seed(666)
        model = build_network(small_model_cfg(), num_class=1, dataset=dataset)
        optim_cfg = small_optim_cfg()
        optim_cfg.EMA_DECAY = ema
        optimizer = build_optimizer(model, optim_cfg)
        start_iter = start_epoch = 0
        if ckpt is not None:
            start_iter, start_epoch = load_params_with_optimizer(model, ckpt, optimizer)
        loader = DataLoader(dataset, batch_size=2, shuffle=False, collate_fn=dataset.collate_batch)
        scheduler = build_scheduler(optimizer, len(loader), 2, start_iter - 1, optim_cfg)
        average = weight_average(optim_cfg, model, start_iter, ckpt)
        train_model(model, optimizer, loader, scheduler, optim_cfg, start_epoch, epochs, start_iter, 0, None, out_dir,
                    "cpu", use_tqdm_to_record=True, average=average)
        return model, average
    return run


@pytest.mark.slow
def test_averaging_leaves_the_steps_unchanged_and_checkpoints_hold_both_states_and_resume(dataset, tmp_path, train):
    plain, none = train(dataset, tmp_path / "plain", ema=None)
    assert none is None
    model, average = train(dataset, tmp_path / "ema", ema=0.9)
    for (key, a), b in zip(plain.state_dict().items(), model.state_dict().values()):
        assert torch.equal(a, b), key  # reading the weights never changes them
    checkpoint = read_checkpoint(tmp_path / "ema" / "checkpoint_epoch_2.pth")
    assert average.steps == checkpoint["it"] == 4
    for key, value in model.state_dict().items():
        assert torch.equal(checkpoint["training_state"][key], value), key
        assert torch.equal(checkpoint["model_state"][key], average.state[key]), key
    assert not torch.equal(checkpoint["model_state"]["dense_head.conv_cls.weight"],
                           checkpoint["training_state"]["dense_head.conv_cls.weight"])
    # stopped after epoch 1 and resumed from its checkpoint: the same weights and the same average
    train(dataset, tmp_path / "resumed", ema=0.9, epochs=1)
    resumed, resumed_average = train(dataset, tmp_path / "resumed", ema=0.9,
                                     ckpt=tmp_path / "resumed" / "checkpoint_epoch_1.pth")
    for key, value in model.state_dict().items():
        assert torch.allclose(resumed.state_dict()[key].float(), value.float(), rtol=0, atol=1e-6), key
        assert torch.allclose(resumed_average.state[key].float(), average.state[key].float(), rtol=0, atol=1e-6), key
