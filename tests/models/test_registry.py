"""The registries of detectors (models.DETECTORS) and dense heads (models.detector.DENSE_HEADS): a part registered
once is built from configs, named in Table 3 and offered by `memslidar reproduce --heads`."""
import pytest
from easydict import EasyDict
from torch import nn

from pcdet_memslidar import cli
from pcdet_memslidar.config import CONFIG_DIR
from pcdet_memslidar.experiments.report import detector_names, table3
from pcdet_memslidar.experiments.reproduce import head_configs
from pcdet_memslidar.models import DETECTORS, build_network, register_detector
from pcdet_memslidar.models.detector import DENSE_HEADS, Detector3DTemplate, register_dense_head


@pytest.fixture
def dummy_parts():
    """A dense head 'DummyHead' (short name 'dummy') and a detector 'DummyNet' (display name 'Dummy') that takes it,
    registered for the test and unregistered after it."""
    @register_dense_head
    class DummyHead(nn.Module):
        short_name = "dummy"
        model_config = "memslidar_models/dummy_person.yaml"

        def __init__(self, model_cfg, input_channels: int, **kwargs):
            super().__init__()
            self.conv_cls = nn.Conv2d(input_channels, 1, 1)

        def forward(self, batch_dict: dict) -> dict:
            return batch_dict

    @register_detector
    class DummyNet(Detector3DTemplate):
        display_name = "Dummy"
        dense_head_names = ("DummyHead",)

        def post_processing(self, batch_dict: dict) -> list[dict]:
            return []

    yield DummyNet, DummyHead
    del DETECTORS["DummyNet"], DENSE_HEADS["DummyHead"]


def test_build_network_builds_a_registered_detector_and_head(dummy_parts, small_model_cfg, fake_dataset, small_range,
                                                             person_voxel):
    detector, head = dummy_parts
    model_cfg = EasyDict(small_model_cfg() | {"NAME": "DummyNet", "DENSE_HEAD": {"NAME": "DummyHead"}})
    model = build_network(model_cfg, 1, fake_dataset(small_range, person_voxel))
    assert type(model) is detector and type(model.dense_head) is head
    assert "dense_head.conv_cls.weight" in model.state_dict()  # OpenPCDet's module names


def test_the_report_names_a_registered_detector(dummy_parts):
    assert detector_names()["DummyNet"] == "Dummy"
    models = {"M1-dummy": {"detector": "DummyNet", "model": "M1", "mean": {"AP3D_R40": 0.5}, "std": {}}}
    assert table3({"models": models, "seeds": [0]})[2].startswith("| M1-dummy (not in the paper) | Dummy | 0.500 |")


def test_reproduce_offers_a_registered_head(dummy_parts):
    assert head_configs()["dummy"] == CONFIG_DIR / "memslidar_models" / "dummy_person.yaml"
    args = cli.build_parser("reproduce").parse_args(["reproduce", "--heads", "anchor", "dummy"])
    assert args.heads == ["anchor", "dummy"]


def test_the_shipped_parts_and_nothing_else_are_registered():
    """Also shows that dummy_parts left nothing behind (this test runs after the ones above)."""
    assert list(DENSE_HEADS) == ["AnchorHeadSingle", "CenterHead"]
    assert detector_names() == {"SECONDNet": "SECOND", "CenterPoint": "CenterPoint",
                                "BackgroundSubtraction": "BackgroundSubtraction"}
    assert head_configs() == {"anchor": CONFIG_DIR / "memslidar_models" / "second_person.yaml",
                              "center": CONFIG_DIR / "memslidar_models" / "centerpoint_person.yaml"}
    with pytest.raises(SystemExit):
        cli.build_parser("reproduce").parse_args(["reproduce", "--heads", "dummy"])
    for head in head_configs().values():
        assert head.is_file(), head


def test_registration_errors_name_the_key_and_the_fix():
    class CenterHead(nn.Module):  # the name of a registered head, another class
        pass

    with pytest.raises(ValueError, match=r"DENSE_HEAD.NAME CenterHead is taken by pcdet_memslidar\.models\.center_head"
                                         r"\.CenterHead: give .*CenterHead another class name"):
        register_dense_head(CenterHead)

    class Unnamed(Detector3DTemplate):
        def post_processing(self, batch_dict: dict) -> list[dict]:
            return []

    with pytest.raises(ValueError, match="Unnamed: set the class attribute display_name"):
        register_detector(Unnamed)
    assert "Unnamed" not in DETECTORS and DENSE_HEADS["CenterHead"] is not CenterHead
