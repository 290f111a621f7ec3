"""OpenPCDet-compatible YAML configs, with paths that work from any working directory.

Semantics (as OpenPCDet's pcdet/config.py): a YAML file becomes an EasyDict; `_BASE_CONFIG_` may appear in any
mapping: the base file is loaded first and the mapping's own keys are merged onto it recursively (mappings merge,
lists and scalars replace); a mapping with `_BASE_CONFIG_` replaces whatever an outer base put under its key.
`cfg_from_list(['A.B', 'VALUE', ...], cfg)` overrides existing (or known, see below) keys with YAML-parsed values.

Our key `_MODEL_CONFIG_` (top level only): a model config whose MODEL, and each profile's MODEL, replace those of
the `_BASE_CONFIG_` whole, before the file's own keys merge on; everything else (data, optimisation, profiles' other
keys) stays the base's. An experiment on another head: `_BASE_CONFIG_: ../m3.yaml` and
`_MODEL_CONFIG_: ../memslidar_models/centerpoint_person.yaml` (cfgs/centerpoint/).

The fix (OpenPCDet #1185): `_BASE_CONFIG_` and `DATA_PATH` values resolve relative to the file that wrote them
first, then to the working directory (`resolve_path`); after loading they hold absolute paths.

Profiles: `PROFILE` (default 'paper') names an entry of `PROFILES: {quick: {...}, smoke: {...}}` whose overrides
`apply_profile` merges onto the config; 'paper' is the config as written unless PROFILES defines it.

Known keys: every key a config file writes must be one of the shipped model configs (SCHEMA_FILES: SECOND and
CenterPoint, with their dataset config; their values are the defaults, so the schema has no second copy of them) or
of OPTIONAL_KEYS; the keys of a profile likewise. A typo fails at load with the file, line and close match. Not
checked: a MODEL section whose NAME no shipped config uses (another OpenPCDet module, with its own keys) and
mappings inside lists.

Public API:
    cfg_from_yaml_file(cfg_file, merge_to=None, model_config=None) -> EasyDict
    cfg_from_list(cfg_list, config) -> None
    merge_new_config(config, new_config, cfg_file=None) -> EasyDict
    apply_profile(config, profile=None) -> EasyDict
    load_config(cfg_file, set_cfgs=None, profile=None, model_config=None) -> EasyDict
                                                  (yaml + profile + --set, names set, grid checked)
    resolve_path(base_file, value) -> Path
    experiment_group(cfg_file) -> str
    log_config_to_file(config, pre='cfg', logger=None) -> None
    cfg: the module-level EasyDict OpenPCDet tools import (ROOT_DIR, LOCAL_RANK)
"""
from __future__ import annotations

import difflib
import functools
import json
import logging
import math
import re
from pathlib import Path

import yaml
from easydict import EasyDict

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.grid import check_config_grid

BASE_KEY = "_BASE_CONFIG_"
MODEL_KEY = "_MODEL_CONFIG_"  # the model config that gives a config its MODEL (module docstring)
PATH_KEYS = ("DATA_PATH", "BACKGROUND_MODEL")  # string values resolved relative to the file that wrote them
DEFAULT_PROFILE = "paper"
_PACKAGE_DIR = Path(__file__).resolve().parent
# A checkout (or editable install) keeps its configs in <repository>/cfgs and writes output/ and data/ there, as
# OpenPCDet does under its cfg.ROOT_DIR; an installed package ships them as pcdet_memslidar/cfgs (pyproject.toml)
# and writes under the working directory.
IN_CHECKOUT = (_PACKAGE_DIR.parent / "pyproject.toml").is_file() and (_PACKAGE_DIR.parent / "cfgs").is_dir()
ROOT_DIR = _PACKAGE_DIR.parent if IN_CHECKOUT else Path.cwd()
CONFIG_DIR = _PACKAGE_DIR.parent / "cfgs" if IN_CHECKOUT else _PACKAGE_DIR / "cfgs"
SCHEMA_FILE = CONFIG_DIR / "memslidar_models" / "second_person.yaml"  # the paper's model, the default everywhere
SCHEMA_FILES = (SCHEMA_FILE, CONFIG_DIR / "memslidar_models" / "centerpoint_person.yaml")
# Keys a config may write beyond SCHEMA_FILES': optional keys whose defaults live in the code that reads them, and
# OpenPCDet's own keys for SECOND (kitti_dataset.yaml, second.yaml, its training loop) that our runtime ignores.
OPTIONAL_KEYS = (
    "DATA_CONFIG.TEST_SOURCE.PATH", "DATA_CONFIG.TEST_SOURCE.DOMAIN", "DATA_CONFIG.TEST_SOURCE.SEED",
    "MODEL.BACKBONE_2D.USE_CONV_FOR_NO_STRIDE", "MODEL.DENSE_HEAD.USE_MULTIHEAD",
    "MODEL.DENSE_HEAD.TARGET_ASSIGNER_CONFIG.BOX_CODER_CONFIG",
    "DATA_CONFIG.INFO_PATH", "DATA_CONFIG.GET_ITEM_LIST", "DATA_CONFIG.FOV_POINTS_ONLY", "OPTIMIZATION.LOSS_SCALE_FP16",
    "PRETRAIN",  # pre-training then fine-tuning (runtime.pretrain; cfgs/m5.yaml)
    "TRACKER",  # tracker parameters of `memslidar detect` (monitor.tracker.TrackerConfig)
    "HOOK",  # OpenPCDet's training hooks (runtime.hooks: DisableAugmentationHook)
    "DATA_CONFIG.BACKGROUND_MODEL",  # a site's background.npz, for the background_depth feature (geometry.background)
    "DATA_CONFIG.FOREGROUND_ONLY",  # the network sees only the returns in front of the background (datasets.dataset)
    "MODEL.BACKGROUND_SUBTRACTION",  # settings of MODEL.NAME BackgroundSubtraction (models.background_subtraction)
    "OPTIMIZATION.EMA_DECAY",  # an average of the weights over the steps (runtime.weight_average)
)


class YamlLoader(yaml.SafeLoader):
    """YAML safe loader that also reads `1e-4` (no dot) as a float, as a reader of a config would expect."""


YamlLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def parse_yaml(text: str, source: str):
    try:
        return yaml.load(text, Loader=YamlLoader)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        problem = getattr(error, "problem", None) or error
        raise ConfigError(f"{source}{line}: invalid YAML ({problem}); fix the syntax") from None


def resolve_path(base_file: str | Path | None, value: str | Path) -> Path:
    """Absolute path of `value`: as is if absolute, else relative to `base_file`'s folder if it exists there,
    else relative to the working directory if it exists there, else relative to `base_file`'s folder (or the
    working directory when `base_file` is None)."""
    value = Path(value).expanduser()
    if value.is_absolute():
        return value
    candidates = [Path.cwd() / value]
    if base_file is not None:
        candidates.insert(0, Path(base_file).resolve().parent / value)
    existing = next((path for path in candidates if path.exists()), candidates[0])
    return existing.resolve()


def _as_in_checkout(cfg_file: Path | None) -> Path | None:
    """Where `cfg_file` would be in a checkout at ROOT_DIR: a shipped config of an installed package resolves its
    DATA_PATH as from <ROOT_DIR>/cfgs, so data lands under the working directory, not in site-packages."""
    if cfg_file is None or IN_CHECKOUT or not Path(cfg_file).resolve().is_relative_to(CONFIG_DIR):
        return cfg_file
    return ROOT_DIR / "cfgs" / Path(cfg_file).resolve().relative_to(CONFIG_DIR)


def _line_of(path: Path, needle: str) -> int | None:
    """1-based number of the first line of `path` that contains `needle`, if any."""
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if needle in line:
            return number
    return None


def _key_line(path: Path, keys: tuple[str, ...]) -> int | None:
    """1-based line of the key at `keys` (a path of mapping keys from the top of the YAML file `path`), if found."""
    node = yaml.compose(path.read_text(encoding="utf-8"), Loader=YamlLoader)
    line = None
    for key in keys:
        if not isinstance(node, yaml.MappingNode):
            return None
        found = next(((k, v) for k, v in node.value if isinstance(k, yaml.ScalarNode) and k.value == key), None)
        if found is None:
            return None
        line, node = found[0].start_mark.line + 1, found[1]
    return line


def _load_yaml_file(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as error:
        line = path.read_bytes()[:error.start].count(b"\n") + 1
        raise ConfigError(f"{path}:{line}: not UTF-8 text (byte {error.object[error.start]:#04x}); save the config "
                          f"as UTF-8") from None
    mapping = parse_yaml(text, str(path))
    if mapping is None:
        return {}
    if not isinstance(mapping, dict):
        raise ConfigError(f"{path}: a config file must be a YAML mapping (KEY: value), got {type(mapping).__name__}")
    return mapping


def _base_file(requester: Path | None, value, chain: tuple[Path, ...], key: str = BASE_KEY) -> Path:
    """Resolve a `key` (_BASE_CONFIG_, _MODEL_CONFIG_) value written in `requester`, checking that it exists and is not
    a cycle."""
    who = str(requester) if requester is not None else "<in-memory config>"
    if not isinstance(value, (str, Path)):
        raise ConfigError(f"{who}: {key} must be a file path, got {value!r}")
    path = resolve_path(requester, value)
    if not path.is_file():
        line = _line_of(requester, str(value)) if requester is not None and requester.is_file() else None
        where = f"{who}:{line}" if line else who
        places = f"{requester.parent} or {Path.cwd()}" if requester is not None else str(Path.cwd())
        raise ConfigError(f"{where}: {key} '{value}' not found (looked relative to {places}); "
                          f"fix the path in {who}")
    if path in chain:
        cycle = " -> ".join(str(p) for p in chain + (path,))
        raise ConfigError(f"{who}: {key} cycle {cycle}; remove one of the includes")
    return path


def _merge(config: dict, new: dict) -> None:
    """Merge expanded `new` into `config`: mappings merge, a mapping with its own base replaces, others replace."""
    for key, value in new.items():
        if isinstance(value, dict) and BASE_KEY not in value and isinstance(config.get(key), dict):
            _merge(config[key], value)
        else:
            config[key] = value


@functools.cache
def _schema() -> EasyDict:
    """The known keys as a tree of mappings: the union of SCHEMA_FILES (with their bases), plus OPTIONAL_KEYS (any
    value). A NAME key holds the set of module names the shipped configs use there."""
    schema = EasyDict()
    for schema_file in SCHEMA_FILES:
        _merge_schema(schema, _expand(_load_yaml_file(schema_file), schema_file, (schema_file,)))
    for dotted in OPTIONAL_KEYS:
        *parents, leaf = dotted.split(".")
        node = functools.reduce(dict.__getitem__, parents, schema)
        node[leaf] = None
    return schema


def _merge_schema(schema: dict, config: dict) -> None:
    """Add the keys of `config` to `schema` (mappings merge; NAME values gather into a set)."""
    for key, value in config.items():
        if key == "NAME":
            schema[key] = schema.get(key, set()) | {value}
        elif isinstance(value, dict):
            _merge_schema(schema.setdefault(key, {}), value)
        else:
            schema[key] = value


def _schema_at(at: tuple[str, ...]) -> dict | None:
    """The schema of the mapping at key path `at` of a config; None where the schema has no mapping."""
    node = _schema()
    for key in at[2:] if at[:1] == ("PROFILES",) else at:  # a profile overrides the config's own keys
        node = node.get(key) if isinstance(node, dict) else None
    return node if isinstance(node, dict) else None


def _check_keys(node: dict, schema: dict | None, path: Path, at: tuple[str, ...], keys: tuple[str, ...] = ()):
    """ConfigError naming `path`:line, the key and its close match for a key of `node` that `schema` lacks.

    node: the mapping at `keys` in the file `path`, which sits at key path `at` of the whole config.
    """
    names = schema.get("NAME") if isinstance(schema, dict) else None
    if schema is None or ((at + keys)[:1] == ("MODEL",) and isinstance(names, set) and "NAME" in node
                          and node["NAME"] not in names):
        return  # no schema here, or another OpenPCDet module with its own keys
    for key, value in node.items():
        if key == BASE_KEY or (key == MODEL_KEY and not at + keys):
            continue
        where = keys + (key,)
        if key not in schema:
            line = _key_line(path, where)
            name = ".".join(at + where)
            hint = _close(key, [option for option in schema if option != BASE_KEY])
            raise ConfigError(f"{path}{f':{line}' if line else ''}: unknown key {name}{hint}"
                              f"{'' if hint.endswith('?') else '.'} Fix the spelling or remove the key")
        if key == "PROFILES" and not at + keys and isinstance(value, dict):  # {profile name: config overrides}
            for profile, overrides in value.items():
                if isinstance(overrides, dict):
                    _check_keys(overrides, _schema(), path, (), where + (profile,))
        elif isinstance(value, dict):
            _check_keys(value, schema[key] if isinstance(schema[key], dict) else None, path, at, where)


def _expand(node: dict, cfg_file: Path | None, chain: tuple[Path, ...], at: tuple[str, ...] | None = None) -> EasyDict:
    """`node` with every `_BASE_CONFIG_` loaded and every path key made absolute (relative to `cfg_file`).

    at: key path of `node` in the whole config, to check the keys of every base file it loads against the schema;
    None: unchecked.
    """
    if BASE_KEY in node:
        base = _base_file(cfg_file, node[BASE_KEY], chain)
        result = _expand_file(base, chain, at)
        result[BASE_KEY] = str(base)
    else:
        result = EasyDict()
    if MODEL_KEY in node:
        _take_model(result, _base_file(cfg_file, node[MODEL_KEY], chain, MODEL_KEY), chain, at)
    own = EasyDict()
    for key, value in node.items():
        if key in (BASE_KEY, MODEL_KEY):
            continue
        if isinstance(value, dict):
            value = _expand(value, cfg_file, chain, None if at is None else at + (key,))
        elif key in PATH_KEYS and isinstance(value, str):
            value = str(resolve_path(_as_in_checkout(cfg_file), value))
        own[key] = value
    _merge(result, own)
    return result


def _expand_file(path: Path, chain: tuple[Path, ...], at: tuple[str, ...] | None) -> EasyDict:
    """The config file `path` expanded (_expand), its keys checked against the schema at key path `at` (None: not)."""
    node = _load_yaml_file(path)
    if at is not None:
        _check_keys(node, _schema_at(at), path, at)
    return _expand(node, path, chain + (path,), at)


def _take_model(config: EasyDict, model_file: Path, chain: tuple[Path, ...], at: tuple[str, ...] | None) -> None:
    """Replace the MODEL of `config` and of each of its profiles by those of the model config `model_file` (its keys
    checked unless `at` is None), recorded as config's _MODEL_CONFIG_. A profile it gives no MODEL loses its own;
    profiles `config` lacks are not added."""
    model = _expand_file(model_file, chain, None if at is None else ())
    if "MODEL" not in model:
        raise ConfigError(f"{model_file}: has no MODEL, so it cannot be a {MODEL_KEY}; name a model config such as "
                          f"cfgs/memslidar_models/centerpoint_person.yaml")
    config.MODEL = model.MODEL
    model_profiles = model.get("PROFILES") or {}
    for name, overrides in (config.get("PROFILES") or {}).items():
        model_overrides = (model_profiles.get(name) or {}).get("MODEL")
        if model_overrides is not None:
            config.PROFILES[name] = overrides = overrides or EasyDict()
            overrides.MODEL = model_overrides
        elif overrides:
            overrides.pop("MODEL", None)
    config[MODEL_KEY] = str(model_file)


def merge_new_config(config: EasyDict, new_config: dict, cfg_file: str | Path | None = None) -> EasyDict:
    """Merge `new_config` (read from `cfg_file`, whose folder anchors its relative paths) into `config`."""
    cfg_file = Path(cfg_file).resolve() if cfg_file is not None else None
    chain = (cfg_file,) if cfg_file is not None else ()
    _merge(config, _expand(new_config, cfg_file, chain))
    return config


def cfg_from_yaml_file(cfg_file: str | Path, merge_to: EasyDict | None = None,
                       model_config: str | Path | None = None) -> EasyDict:
    """Load the YAML config `cfg_file` (with its bases) into `merge_to` (a new EasyDict if None) and return it;
    model_config: a model config whose MODEL replaces the loaded one's, as a file with `_BASE_CONFIG_: cfg_file` and
    `_MODEL_CONFIG_: model_config` would.

    ConfigError for a key the schema does not know (see the module docstring); a dataset config (DATASET, no
    DATA_CONFIG) is checked as a DATA_CONFIG.
    """
    path = Path(cfg_file)
    if not path.is_file():
        raise ConfigError(f"{cfg_file}: config file not found (working directory {Path.cwd()})")
    config = EasyDict() if merge_to is None else merge_to
    mapping = _load_yaml_file(path)
    at = ("DATA_CONFIG",) if "DATASET" in mapping and "DATA_CONFIG" not in mapping else ()
    _check_keys(mapping, _schema_at(at), path, at)
    path = path.resolve()
    expanded = _expand(mapping, path, (path,), at)
    if model_config is not None:
        _take_model(expanded, Path(model_config).resolve(), (path,), at)
    _merge(config, expanded)
    return config


def _close(key: str, options) -> str:
    matches = difflib.get_close_matches(key, [str(option) for option in options], n=3, cutoff=0.5)
    return f"; did you mean {', '.join(matches)}?" if matches else f"; known keys: {', '.join(map(str, options))}"


def _convert(text: str, current, key: str):
    """The YAML value of `text`, converted to the type of the value it replaces."""
    value = parse_yaml(text, f"--set {key}")
    if current is None or value is None or isinstance(current, str):
        return text if isinstance(current, str) else value
    if isinstance(current, bool) or isinstance(value, bool):
        if type(current) is not type(value):
            raise ConfigError(f"--set {key} {text}: expected {type(current).__name__}, got {text!r}")
        return value
    if isinstance(current, (int, float)):
        if isinstance(value, int) or (isinstance(current, float) and isinstance(value, float)):
            return type(current)(value)
        raise ConfigError(f"--set {key} {text}: expected {type(current).__name__}, got {text!r}")
    if isinstance(current, list):
        if isinstance(value, str):  # OpenPCDet's comma form: --set A.LIST 1,2,3
            value = [parse_yaml(item, f"--set {key}") for item in value.split(",")]
        if not isinstance(value, list):
            value = [value]
        return value
    if isinstance(current, dict):
        if isinstance(value, str):  # OpenPCDet's form: --set A.DICT KEY1:V1,KEY2:V2
            pairs = [item.split(":", 1) for item in value.split(",")]
            if any(len(pair) != 2 for pair in pairs):
                raise ConfigError(f"--set {key} {text}: expected a mapping, e.g. '{{KEY: value}}' or KEY:value,...")
            value = {name.strip(): parse_yaml(item, f"--set {key}") for name, item in pairs}
        if not isinstance(value, dict):
            raise ConfigError(f"--set {key} {text}: expected a mapping")
        known = _known_keys(current, tuple(key.split(".")))
        for name in value:
            if name not in known:
                raise ConfigError(f"--set {key}: unknown key {key}.{name}{_close(name, known)}")
        merged = EasyDict(current)
        _merge(merged, EasyDict(value))
        return merged
    return value


def _set_pairs(cfg_list: list[str] | None) -> list[tuple[str, str]]:
    """[(KEY, VALUE), ...] of `--set` items; ConfigError naming the last item when it has no value."""
    cfg_list = list(cfg_list or [])
    if len(cfg_list) % 2:
        last = cfg_list[-1]
        raise ConfigError(f"--set needs KEY VALUE pairs, got an odd number of items {cfg_list}: '{last}' has no "
                          f"value; add one (--set {last} VALUE) or remove it")
    return list(zip(cfg_list[0::2], cfg_list[1::2]))


def _known_keys(node: dict, at: tuple[str, ...]) -> list[str]:
    """The keys of the config mapping `node` at key path `at`, then the schema's other keys there."""
    return list(node) + [key for key in _schema_at(at) or {} if key not in node and key != BASE_KEY]


def cfg_from_list(cfg_list: list[str] | None, config: EasyDict) -> None:
    """Apply `--set` overrides ['A.B', 'VALUE', ...] to keys of `config` (values parsed as YAML); the last key may
    also be one the schema knows and the config leaves out (OPTIONAL_KEYS)."""
    for key, text in _set_pairs(cfg_list):
        if key.startswith("-"):
            raise ConfigError(f"--set {key}: '{key}' looks like an option, but everything after --set is read as "
                              f"KEY VALUE pairs; put {key} before --set")
        node, parts = config, key.split(".")
        for depth, part in enumerate(parts):
            last = depth == len(parts) - 1
            parent = ".".join(parts[:depth]) or "the config"
            if not isinstance(node, dict):
                raise ConfigError(f"--set {key}: {parent} is a {type(node).__name__}, not a mapping: --set replaces it "
                                  f"whole (--set {parent} VALUE)")
            options = _known_keys(node, tuple(parts[:depth])) if last else list(node)
            # inside an optional block (TRACKER, HOOK) any key goes: the block's reader checks it
            inside = any(".".join(parts[:end]) in OPTIONAL_KEYS for end in range(1, depth + 1))
            if not last and part not in node and (inside or ".".join(parts[:depth + 1]) in OPTIONAL_KEYS):
                node[part] = EasyDict()  # an optional block (or a mapping in one) that the config leaves out
                options.append(part)
            if last and inside:
                options.append(part)
            if part not in options:
                raise ConfigError(f"--set {key}: unknown key '{part}' in {parent}{_close(part, options)}")
            if not last:
                node = node[part]
        node[parts[-1]] = _convert(str(text), node.get(parts[-1]), key)


def _check_known(overrides: dict, config: dict, prefix: str, profile: str) -> None:
    for key, value in overrides.items():
        if key not in config:
            raise ConfigError(f"profile '{profile}': unknown key {prefix}{key}{_close(key, config)}")
        if isinstance(value, dict) and BASE_KEY not in value and isinstance(config[key], dict):
            _check_known(value, config[key], f"{prefix}{key}.", profile)


def apply_profile(config: EasyDict, profile: str | None = None) -> EasyDict:
    """Merge config.PROFILES[profile] (default config.PROFILE, else 'paper') onto `config`; sets config.PROFILE."""
    profile = profile or config.get("PROFILE") or DEFAULT_PROFILE
    profiles = config.get("PROFILES") or {}
    if profile not in profiles and profile != DEFAULT_PROFILE:
        known = sorted(set(profiles) | {DEFAULT_PROFILE})
        raise ConfigError(f"unknown profile '{profile}'; known profiles: {', '.join(known)}")
    overrides = profiles.get(profile) or {}
    _check_known(overrides, config, "", profile)
    _merge(config, EasyDict(overrides))
    config.PROFILE = profile
    return config


def profile_settings(config: EasyDict) -> list[str]:
    """'KEY.SUB value' for every leaf that config's active profile sets (list items as KEY[i]), in file order."""
    def leaves(node, key: str):
        if isinstance(node, dict):
            for name, value in node.items():
                yield from leaves(value, f"{key}.{name}" if key else name)
        elif isinstance(node, list) and any(isinstance(item, dict) for item in node):
            for index, item in enumerate(node):
                yield from leaves(item, f"{key}[{index}]")
        else:
            yield f"{key} {json.dumps(node)}"
    return list(leaves((config.get("PROFILES") or {}).get(config.get("PROFILE"), {}), ""))


def experiment_group(cfg_file: str | Path) -> str:
    """OpenPCDet's EXP_GROUP_PATH: the folders after `cfgs/` ('cfgs/memslidar_models/second_person.yaml' ->
    'memslidar_models'); without a `cfgs` folder in the path, the config's parent folder name."""
    parts = Path(cfg_file).resolve().parts[:-1]
    if "cfgs" in parts:
        index = len(parts) - 1 - parts[::-1].index("cfgs")
        return "/".join(parts[index + 1:])
    return parts[-1] if parts else ""


def load_config(cfg_file: str | Path, set_cfgs: list[str] | None = None, profile: str | None = None,
                model_config: str | Path | None = None) -> EasyDict:
    """The full config: YAML (with bases; with the MODEL of `model_config` if given: cfg_from_yaml_file), then the
    profile (`profile`, a --set PROFILE, or the file's PROFILE), then the --set overrides; also sets
    ROOT_DIR, LOCAL_RANK, CFG_FILE, TAG and EXP_GROUP_PATH.

    ConfigError (naming the file) for a POINT_CLOUD_RANGE that is no 6 numbers, for a SECOND model whose voxel
    grid it cannot take (pcdet_memslidar.grid.check_config_grid, with sizes that fit) and for optimisation values
    that cannot train (check_optimization)."""
    pairs = _set_pairs(set_cfgs)
    asked = dict(pairs).get("PROFILE")
    if profile and asked and str(asked) != str(profile):
        raise ConfigError(f"--profile {profile} and --set PROFILE {asked} ask for two profiles: give one of them")
    config = cfg_from_yaml_file(cfg_file, model_config=model_config)
    apply_profile(config, profile or asked)
    cfg_from_list([item for pair in pairs if pair[0] != "PROFILE" for item in pair], config)
    config.ROOT_DIR = cfg.ROOT_DIR
    config.LOCAL_RANK = config.get("LOCAL_RANK", 0)
    config.CFG_FILE = str(Path(cfg_file).resolve())
    config.TAG = Path(cfg_file).stem
    config.EXP_GROUP_PATH = experiment_group(cfg_file)
    check_config_grid(config)
    check_optimization(config)
    return config


def check_optimization(config: EasyDict) -> None:
    """ConfigError naming the config when its OPTIMIZATION has an LR that is no positive finite number, or a
    BATCH_SIZE_PER_GPU or NUM_EPOCHS that is no positive integer (keys it leaves out are not checked here)."""
    optimization = config.get("OPTIMIZATION") or {}
    lr = optimization.get("LR", 1.0)
    if isinstance(lr, bool) or not isinstance(lr, (int, float)) or not math.isfinite(lr) or lr <= 0:
        raise ConfigError(f"{config.CFG_FILE}: OPTIMIZATION.LR is {lr!r}: the learning rate must be a positive finite "
                          f"number; set it in the config, its profile or with --set OPTIMIZATION.LR VALUE")
    for key in ("BATCH_SIZE_PER_GPU", "NUM_EPOCHS"):
        value = optimization.get(key, 1)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ConfigError(f"{config.CFG_FILE}: OPTIMIZATION.{key} is {value!r}: it must be a positive integer; set "
                              f"it to 1 or more (in the config, its profile or --set OPTIMIZATION.{key} N)")


def log_config_to_file(config: dict, pre: str = "cfg", logger: logging.Logger | None = None) -> None:
    """Log every leaf of `config` as 'pre.KEY.SUB: value' (OpenPCDet's training log format)."""
    logger = logger or logging.getLogger(__name__)
    for key, value in config.items():
        if isinstance(value, dict):
            logger.info(f"----------- {key} -----------")
            log_config_to_file(value, pre=f"{pre}.{key}", logger=logger)
        else:
            logger.info(f"{pre}.{key}: {value}")


cfg = EasyDict()
cfg.ROOT_DIR = ROOT_DIR
cfg.LOCAL_RANK = 0
