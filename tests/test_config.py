"""Configs: OpenPCDet semantics, paths that work from any working directory, --set, profiles."""
from pathlib import Path

import pytest
import yaml

from pcdet_memslidar.config import (
    apply_profile,
    cfg_from_list,
    cfg_from_yaml_file,
    experiment_group,
    load_config,
    merge_new_config,
    resolve_path,
)
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.experiments import reproduce

CFGS = Path(__file__).resolve().parents[1] / "cfgs"


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


@pytest.fixture
def project(tmp_path, monkeypatch):
    """A cfgs/ tree with a dataset config, a base model config and a child; the working directory is elsewhere."""
    root = tmp_path / "project"
    _write(root / "cfgs/dataset_configs/ds.yaml", """
DATASET: MEMSLidarDataset
DATA_PATH: ../../data/sim
POINT_CLOUD_RANGE: [0, -20.48, -0.5, 40.96, 20.48, 3.5]
DATA_SPLIT: {train: train, test: val}
""")
    _write(root / "cfgs/models/base.yaml", """
CLASS_NAMES: [Pedestrian]
DATA_CONFIG:
    _BASE_CONFIG_: ../dataset_configs/ds.yaml
    DATA_SPLIT: {test: test}
OPTIMIZATION:
    LR: 1e-4
    NUM_EPOCHS: 120
    BATCH_SIZE_PER_GPU: 4
    DECAY_STEP_LIST: [35, 45]
    LR_WARMUP: false
PROFILE: paper
PROFILES:
    quick: {OPTIMIZATION: {NUM_EPOCHS: 2, DECAY_STEP_LIST: [1]}}
    smoke: {OPTIMIZATION: {NUM_EPOCHS: 1, BATCH_SIZE_PER_GPU: 1}}
""")
    _write(root / "cfgs/models/m1.yaml", """
_BASE_CONFIG_: base.yaml
DATA_CONFIG:
    POINT_CLOUD_RANGE: [0, -10, -0.5, 20, 10, 3.5]
OPTIMIZATION:
    NUM_EPOCHS: 80
""")
    (root / "data/sim").mkdir(parents=True)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    return root


def test_nested_bases_load_from_another_working_directory(project):
    cfg = cfg_from_yaml_file(project / "cfgs/models/m1.yaml")
    assert cfg.CLASS_NAMES == ["Pedestrian"]
    assert cfg.DATA_CONFIG.DATASET == "MEMSLidarDataset"
    # the child's list replaces the base's list, the base's dict merges key by key
    assert cfg.DATA_CONFIG.POINT_CLOUD_RANGE == [0, -10, -0.5, 20, 10, 3.5]
    assert cfg.DATA_CONFIG.DATA_SPLIT == {"train": "train", "test": "test"}
    assert cfg.OPTIMIZATION == {"LR": 1e-4, "NUM_EPOCHS": 80, "BATCH_SIZE_PER_GPU": 4,
                                "DECAY_STEP_LIST": [35, 45], "LR_WARMUP": False}
    assert isinstance(cfg.OPTIMIZATION.LR, float)
    # DATA_PATH is relative to the dataset config that wrote it, not to the working directory
    assert cfg.DATA_CONFIG.DATA_PATH == str((project / "data/sim").resolve())
    assert cfg.DATA_CONFIG._BASE_CONFIG_ == str((project / "cfgs/dataset_configs/ds.yaml").resolve())


def test_base_and_data_path_fall_back_to_the_working_directory(project, monkeypatch):
    monkeypatch.chdir(project)  # OpenPCDet-style paths, relative to the working directory
    _write(project / "cfgs/models/cwd.yaml", """
DATA_CONFIG:
    _BASE_CONFIG_: cfgs/dataset_configs/ds.yaml
    DATA_PATH: data/sim
""")
    cfg = cfg_from_yaml_file("cfgs/models/cwd.yaml")
    assert cfg.DATA_CONFIG.DATASET == "MEMSLidarDataset"
    assert cfg.DATA_CONFIG.DATA_PATH == str((project / "data/sim").resolve())


def test_dict_with_its_own_base_replaces_what_an_outer_base_put_there(project):
    # OpenPCDet: a mapping with _BASE_CONFIG_ starts from its base, not from the outer base's mapping
    _write(project / "cfgs/models/rebase.yaml", """
_BASE_CONFIG_: base.yaml
DATA_CONFIG:
    _BASE_CONFIG_: ../dataset_configs/ds.yaml
    MIX: {TOTAL: 7}
""")
    cfg = cfg_from_yaml_file(project / "cfgs/models/rebase.yaml")
    assert cfg.DATA_CONFIG.DATA_SPLIT == {"train": "train", "test": "val"}
    assert cfg.DATA_CONFIG.MIX == {"TOTAL": 7}


def test_missing_base_names_the_file_and_line_that_asked_for_it(project):
    child = _write(project / "cfgs/models/broken.yaml",
                   "CLASS_NAMES: [Pedestrian]\nDATA_CONFIG:\n    _BASE_CONFIG_: nope/ds.yaml\n")
    with pytest.raises(ConfigError, match=r"broken\.yaml:3: _BASE_CONFIG_ 'nope/ds\.yaml' not found"):
        cfg_from_yaml_file(child)


def test_base_cycle_and_missing_file_and_bad_yaml(project):
    _write(project / "cfgs/a.yaml", "_BASE_CONFIG_: b.yaml\n")
    _write(project / "cfgs/b.yaml", "_BASE_CONFIG_: a.yaml\n")
    with pytest.raises(ConfigError, match="cycle"):
        cfg_from_yaml_file(project / "cfgs/a.yaml")
    with pytest.raises(ConfigError, match="absent.yaml: config file not found"):
        cfg_from_yaml_file(project / "absent.yaml")
    bad = _write(project / "cfgs/bad.yaml", "A: 1\nB: [1, 2\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml:\d+: invalid YAML"):
        cfg_from_yaml_file(bad)


def test_set_parses_yaml_values(project):
    cfg = cfg_from_yaml_file(project / "cfgs/models/m1.yaml")
    cfg_from_list(["OPTIMIZATION.LR", "3e-3", "OPTIMIZATION.NUM_EPOCHS", "7",
                   "OPTIMIZATION.BATCH_SIZE_PER_GPU", "2", "OPTIMIZATION.DECAY_STEP_LIST", "[5, 6, 7]",
                   "DATA_CONFIG.POINT_CLOUD_RANGE", "0,-5,-1,10,5,3", "OPTIMIZATION.LR_WARMUP", "true",
                   "DATA_CONFIG.DATASET", "123", "DATA_CONFIG.DATA_SPLIT", "test:val"], cfg)
    assert cfg.OPTIMIZATION.LR == 3e-3 and isinstance(cfg.OPTIMIZATION.LR, float)
    assert cfg.OPTIMIZATION.NUM_EPOCHS == 7
    assert cfg.OPTIMIZATION.DECAY_STEP_LIST == [5, 6, 7]
    assert cfg.DATA_CONFIG.POINT_CLOUD_RANGE == [0, -5, -1, 10, 5, 3]
    assert cfg.OPTIMIZATION.LR_WARMUP is True
    assert cfg.DATA_CONFIG.DATASET == "123"  # a string key stays a string
    assert cfg.DATA_CONFIG.DATA_SPLIT == {"train": "train", "test": "val"}
    cfg_from_list(["OPTIMIZATION.LR", "1"], cfg)  # an int where a float was: widened
    assert cfg.OPTIMIZATION.LR == 1.0 and isinstance(cfg.OPTIMIZATION.LR, float)


def test_set_errors_name_the_key_and_close_matches(project):
    cfg = cfg_from_yaml_file(project / "cfgs/models/m1.yaml")
    with pytest.raises(ConfigError, match="unknown key 'NUM_EPOCH' in OPTIMIZATION; did you mean NUM_EPOCHS"):
        cfg_from_list(["OPTIMIZATION.NUM_EPOCH", "3"], cfg)
    with pytest.raises(ConfigError, match="unknown key 'OPTIMISATION' in the config; did you mean OPTIMIZATION"):
        cfg_from_list(["OPTIMISATION.LR", "3"], cfg)
    with pytest.raises(ConfigError, match="odd number"):
        cfg_from_list(["OPTIMIZATION.LR"], cfg)
    with pytest.raises(ConfigError, match="expected int"):
        cfg_from_list(["OPTIMIZATION.NUM_EPOCHS", "2.5"], cfg)
    with pytest.raises(ConfigError, match="expected bool"):
        cfg_from_list(["OPTIMIZATION.LR_WARMUP", "1"], cfg)


def test_profiles(project):
    path = project / "cfgs/models/m1.yaml"
    assert load_config(path).OPTIMIZATION.NUM_EPOCHS == 80  # paper: the config as written
    quick = load_config(path, ["PROFILE", "quick"])
    assert (quick.PROFILE, quick.OPTIMIZATION.NUM_EPOCHS, quick.OPTIMIZATION.DECAY_STEP_LIST) == ("quick", 2, [1])
    # --set wins over the profile, whatever their order on the command line
    smoke = load_config(path, ["OPTIMIZATION.NUM_EPOCHS", "5", "PROFILE", "smoke"])
    assert (smoke.OPTIMIZATION.NUM_EPOCHS, smoke.OPTIMIZATION.BATCH_SIZE_PER_GPU) == (5, 1)
    assert load_config(path, profile="smoke").OPTIMIZATION.NUM_EPOCHS == 1
    with pytest.raises(ConfigError, match="unknown profile 'fast'; known profiles: paper, quick, smoke"):
        load_config(path, ["PROFILE", "fast"])
    cfg = cfg_from_yaml_file(path)
    cfg.PROFILES.quick.OPTIMIZATION.NUM_EPOCS = 3
    with pytest.raises(ConfigError, match="profile 'quick': unknown key OPTIMIZATION.NUM_EPOCS; did you mean"):
        apply_profile(cfg, "quick")


def test_experiment_names_and_resolve_path(project, tmp_path):
    cfg = load_config(project / "cfgs/models/m1.yaml")
    assert (cfg.TAG, cfg.EXP_GROUP_PATH, cfg.LOCAL_RANK) == ("m1", "models", 0)
    assert cfg.CFG_FILE == str((project / "cfgs/models/m1.yaml").resolve())
    assert experiment_group("/x/cfgs/memslidar_models/sub/m2.yaml") == "memslidar_models/sub"
    assert experiment_group("/x/configs/m2.yaml") == "configs"
    assert resolve_path(project / "cfgs/x.yaml", "/abs/path") == Path("/abs/path")
    assert resolve_path(project / "cfgs/x.yaml", "new/dir") == (project / "cfgs/new/dir").resolve()
    assert resolve_path(None, "new") == (Path.cwd() / "new").resolve()


def test_merge_new_config_resolves_bases_relative_to_the_given_file(project):
    cfg = merge_new_config(cfg_from_yaml_file(project / "cfgs/dataset_configs/ds.yaml"),
                           {"_BASE_CONFIG_": "models/base.yaml", "NEW": [1]}, cfg_file=project / "cfgs/x.yaml")
    assert cfg.NEW == [1] and cfg.OPTIMIZATION.NUM_EPOCHS == 120 and cfg.DATASET == "MEMSLidarDataset"


def test_unknown_keys_in_a_file_fail_at_load_with_file_line_and_close_match(project):
    typo = _write(project / "cfgs/models/typo.yaml", "_BASE_CONFIG_: base.yaml\nOPTIMIZATION: {LRR: 0.5}\n")
    with pytest.raises(ConfigError, match=r"typo\.yaml:2: unknown key OPTIMIZATION\.LRR; did you mean LR, LR_WARMUP\? "
                                          r"Fix the spelling or remove the key$"):
        load_config(typo)
    top = _write(project / "cfgs/models/top.yaml", "_BASE_CONFIG_: base.yaml\n\nOPTIMISATION:\n    LR: 0.5\n")
    with pytest.raises(ConfigError, match=r"top\.yaml:3: unknown key OPTIMISATION; did you mean OPTIMIZATION, "
                                          r"PRETRAIN\?"):
        load_config(top)
    nested = _write(project / "cfgs/models/nested.yaml", "MODEL:\n    DENSE_HEAD:\n        NUM_DIR_BIN: 2\n")
    with pytest.raises(ConfigError, match=r"nested\.yaml:3: unknown key MODEL\.DENSE_HEAD\.NUM_DIR_BIN; did you mean "
                                          r"NUM_DIR_BINS, NUM_HM_CONV\?"):  # keys of both shipped heads
        cfg_from_yaml_file(nested)
    in_profile = _write(project / "cfgs/models/profile.yaml",
                        "_BASE_CONFIG_: base.yaml\nPROFILES:\n    fast: {OPTIMIZATION: {NUM_EPOCH: 1}}\n")
    with pytest.raises(ConfigError, match=r"profile\.yaml:3: unknown key PROFILES\.fast\.OPTIMIZATION\.NUM_EPOCH; "
                                          r"did you mean NUM_EPOCHS, WARMUP_EPOCH\?"):
        load_config(in_profile)  # checked even when another profile is used
    no_match = _write(project / "cfgs/models/none.yaml", "_BASE_CONFIG_: base.yaml\nMODEL: {XYZ: 1}\n")
    with pytest.raises(ConfigError, match=r"none\.yaml:2: unknown key MODEL\.XYZ; known keys: NAME, VFE, .*"
                                          r"POST_PROCESSING, BACKGROUND_SUBTRACTION\. Fix the spelling or remove the "
                                          r"key$"):
        load_config(no_match)


def test_unknown_key_in_a_base_file_names_the_base_file(project):
    _write(project / "cfgs/dataset_configs/ds.yaml", "DATASET: MEMSLidarDataset\nMIX:\n    TOTALS: 5\n")
    with pytest.raises(ConfigError, match=r"ds\.yaml:3: unknown key DATA_CONFIG\.MIX\.TOTALS; did you mean TOTAL\?"):
        load_config(project / "cfgs/models/m1.yaml")
    with pytest.raises(ConfigError, match=r"ds\.yaml:3: unknown key DATA_CONFIG\.MIX\.TOTALS"):
        cfg_from_yaml_file(project / "cfgs/dataset_configs/ds.yaml")  # a dataset config alone: checked as DATA_CONFIG


def test_shipped_configs_and_openpcdet_second_keys_load(project):
    for path in sorted(CFGS.rglob("*.yaml")):
        if path.parent.name == "sites":
            continue  # site files, not detector configs (tests/sim/test_site.py)
        for profile in load_config(path).get("PROFILES") or ["paper"]:
            load_config(path, profile=profile)
    # keys of OpenPCDet's own SECOND configs that our runtime does not read, and optional keys
    openpcdet = _write(project / "cfgs/models/openpcdet.yaml", """
DATA_CONFIG:
    _BASE_CONFIG_: ../dataset_configs/ds.yaml
    INFO_PATH: {train: [infos_train.pkl], test: [infos_val.pkl]}
    FOV_POINTS_ONLY: True
    GET_ITEM_LIST: [points]
    TEST_SOURCE: {NAME: industrial_seed1, DOMAIN: industrial, SEED: 1, PATH: elsewhere}
MODEL:
    BACKBONE_2D: {USE_CONV_FOR_NO_STRIDE: False}
    DENSE_HEAD:
        USE_MULTIHEAD: False
        TARGET_ASSIGNER_CONFIG: {BOX_CODER_CONFIG: {}}
OPTIMIZATION: {LOSS_SCALE_FP16: 4.0}
""")
    assert load_config(openpcdet).OPTIMIZATION.LOSS_SCALE_FP16 == 4.0
    # another OpenPCDet module has its own keys: not checked against SECOND's
    pillars = _write(project / "cfgs/models/pillars.yaml", "MODEL:\n    VFE: {NAME: PillarVFE, WITH_DISTANCE: False}\n")
    assert cfg_from_yaml_file(pillars).MODEL.VFE.WITH_DISTANCE is False


def test_set_key_without_a_value_is_an_error(project):
    path = project / "cfgs/models/m1.yaml"
    message = (r"--set needs KEY VALUE pairs, got an odd number of items \['PROFILE', 'smoke', 'OPTIMIZATION\.LR'\]: "
               r"'OPTIMIZATION\.LR' has no value; add one \(--set OPTIMIZATION\.LR VALUE\) or remove it")
    with pytest.raises(ConfigError, match=message):
        load_config(path, ["PROFILE", "smoke", "OPTIMIZATION.LR"])


def test_profile_from_set_and_explicit_set_wins():
    cfg = load_config(CFGS / "m3.yaml", ["OPTIMIZATION.NUM_EPOCHS", "3", "PROFILE", "quick"])
    assert (cfg.PROFILE, cfg.DATA_CONFIG.MIX.TOTAL, cfg.OPTIMIZATION.NUM_EPOCHS) == ("quick", 1200, 3)
    paper = load_config(CFGS / "m3.yaml")
    assert (paper.PROFILE, paper.DATA_CONFIG.MIX.TOTAL, paper.OPTIMIZATION.NUM_EPOCHS, paper.OPTIMIZATION.LR) == \
        ("paper", 2100, 120, 1e-3)


def test_a_config_that_is_not_utf8_is_refused_naming_its_line(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("CLASS_NAMES: ['Pedestrian']\n# Gr\u00f6\u00dfe\n".encode("latin-1"))
    with pytest.raises(ConfigError) as error:
        cfg_from_yaml_file(path)
    assert str(error.value) == f"{path}:2: not UTF-8 text (byte 0xf6); save the config as UTF-8"


def test_two_different_profiles_are_refused():
    with pytest.raises(ConfigError, match="--profile smoke and --set PROFILE paper ask for two profiles"):
        load_config(CFGS / "m3.yaml", ["PROFILE", "paper"], profile="smoke")
    assert load_config(CFGS / "m3.yaml", ["PROFILE", "smoke"], profile="smoke").PROFILE == "smoke"


def test_set_reaches_into_an_optional_block_and_names_a_list_it_cannot_index():
    config = load_config(CFGS / "m3.yaml", ["TRACKER.MAX_DISTANCE", "2"])
    assert config.TRACKER == {"MAX_DISTANCE": 2}
    hook = "HOOK.DisableAugmentationHook."  # mappings inside an optional block are made as --set reaches them
    config = load_config(CFGS / "m3.yaml", [hook + "DISABLE_AUG_LIST", "[gt_sampling]", hook + "NUM_LAST_EPOCHS", "1"])
    assert config.HOOK == {"DisableAugmentationHook": {"DISABLE_AUG_LIST": ["gt_sampling"], "NUM_LAST_EPOCHS": 1}}
    with pytest.raises(ConfigError, match="unknown key 'HOOKS'"):
        load_config(CFGS / "m3.yaml", ["HOOKS.DisableAugmentationHook.NUM_LAST_EPOCHS", "1"])
    with pytest.raises(ConfigError) as error:
        load_config(CFGS / "m3.yaml", ["DATA_CONFIG.DATA_PROCESSOR.0.NAME", "x"])
    assert str(error.value) == ("--set DATA_CONFIG.DATA_PROCESSOR.0.NAME: DATA_CONFIG.DATA_PROCESSOR is a list, not a "
                                "mapping: --set replaces it whole (--set DATA_CONFIG.DATA_PROCESSOR VALUE)")


def test_model_config_replaces_the_model_and_each_profiles_model_whole(project):
    models = project / "cfgs/models"
    _write(models / "second.yaml", """
_BASE_CONFIG_: base.yaml
MODEL: {NAME: SECONDNet, DENSE_HEAD: {NAME: AnchorHeadSingle, NUM_DIR_BINS: 2}}
PROFILES:
    quick: {MODEL: {DENSE_HEAD: {NUM_DIR_BINS: 4}}}
""")
    center = _write(models / "center.yaml", """
CLASS_NAMES: [Car]
MODEL: {NAME: CenterPoint, DENSE_HEAD: {NAME: CenterHead, NUM_HM_CONV: 2}}
OPTIMIZATION: {LR: 0.5}
PROFILES:
    smoke: {MODEL: {DENSE_HEAD: {NUM_HM_CONV: 1}}}
""")
    _write(models / "experiment.yaml", "_BASE_CONFIG_: second.yaml\n_MODEL_CONFIG_: center.yaml\n"
                                       "MODEL: {POST_PROCESSING: {SCORE_THRESH: 0.2}}\n")
    cfg = cfg_from_yaml_file(models / "experiment.yaml")
    head = {"NAME": "CenterPoint", "DENSE_HEAD": {"NAME": "CenterHead", "NUM_HM_CONV": 2}}
    assert cfg.MODEL == {**head, "POST_PROCESSING": {"SCORE_THRESH": 0.2}}  # the file's own keys merge on
    assert cfg._MODEL_CONFIG_ == str(center.resolve())
    assert (cfg.CLASS_NAMES, cfg.OPTIMIZATION.LR) == (["Pedestrian"], 1e-4)  # the rest is the base's
    assert cfg.PROFILES == {"quick": {"OPTIMIZATION": {"NUM_EPOCHS": 2, "DECAY_STEP_LIST": [1]}},
                            "smoke": {"OPTIMIZATION": {"NUM_EPOCHS": 1, "BATCH_SIZE_PER_GPU": 1},
                                      "MODEL": {"DENSE_HEAD": {"NUM_HM_CONV": 1}}}}
    assert apply_profile(cfg, "smoke").MODEL.DENSE_HEAD.NUM_HM_CONV == 1
    assert cfg_from_yaml_file(models / "second.yaml", model_config=center).MODEL == head  # as the key


def test_model_config_errors_name_the_file_and_the_fix(project):
    models = project / "cfgs/models"
    missing = _write(models / "missing.yaml", "_BASE_CONFIG_: base.yaml\n_MODEL_CONFIG_: nope.yaml\n")
    with pytest.raises(ConfigError, match=r"missing\.yaml:2: _MODEL_CONFIG_ 'nope\.yaml' not found .* fix the path"):
        cfg_from_yaml_file(missing)
    no_model = _write(models / "no_model.yaml", "_BASE_CONFIG_: m1.yaml\n_MODEL_CONFIG_: base.yaml\n")
    with pytest.raises(ConfigError, match=r"base\.yaml: has no MODEL, so it cannot be a _MODEL_CONFIG_; name a model "
                                          r"config such as cfgs/memslidar_models/centerpoint_person\.yaml"):
        cfg_from_yaml_file(no_model)
    nested = _write(models / "nested.yaml", "_BASE_CONFIG_: base.yaml\nOPTIMIZATION: {_MODEL_CONFIG_: base.yaml}\n")
    with pytest.raises(ConfigError, match=r"nested\.yaml:2: unknown key OPTIMIZATION\._MODEL_CONFIG_"):
        cfg_from_yaml_file(nested)


BOOKKEEPING = ("_BASE_CONFIG_", "_MODEL_CONFIG_", "CFG_FILE", "TAG", "EXP_GROUP_PATH")  # where a config came from


@pytest.mark.parametrize("experiment", ["m1", "m2", "m3", "m4", "m5", "oracle"])
@pytest.mark.parametrize("profile", ["paper", "quick", "smoke"])
def test_each_center_head_experiment_loads_as_the_copy_it_replaced(tmp_path, experiment, profile):
    """cfgs/centerpoint/<experiment>.yaml (cfgs/<experiment>.yaml with the center model) and reproduce's center head
    load as the copy did: centerpoint_person.yaml with cfgs/<experiment>.yaml's own keys (data, PRETRAIN)."""
    own = yaml.safe_load((CFGS / f"{experiment}.yaml").read_text())
    own["_BASE_CONFIG_"] = str(CFGS / "memslidar_models" / "centerpoint_person.yaml")
    copy = load_config(_write(tmp_path / "copy.yaml", yaml.safe_dump(own, sort_keys=False)), profile=profile)
    center = load_config(CFGS / "centerpoint" / f"{experiment}.yaml", profile=profile)
    composed = reproduce.model_config(experiment, profile, None, head="center")
    for config in (center, composed):
        assert [item for item in config.items() if item[0] not in BOOKKEEPING] == \
            [item for item in copy.items() if item[0] not in BOOKKEEPING]  # key order too


@pytest.mark.parametrize("profile", ["paper", "quick", "smoke"])
def test_the_center_model_differs_from_seconds_in_the_head_only(profile):
    second = load_config(CFGS / "memslidar_models" / "second_person.yaml", profile=profile).MODEL
    center = load_config(CFGS / "memslidar_models" / "centerpoint_person.yaml", profile=profile).MODEL
    for section in ("VFE", "BACKBONE_3D", "MAP_TO_BEV", "BACKBONE_2D"):
        assert second[section] == center[section], section
    stride = center.DENSE_HEAD.TARGET_ASSIGNER_CONFIG.FEATURE_MAP_STRIDE
    assert [anchor["feature_map_stride"] for anchor in second.DENSE_HEAD.ANCHOR_GENERATOR_CONFIG] == [stride]
