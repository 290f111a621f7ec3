"""Sites: what a data set's frames are made of, read from a YAML site file.

A site is a sensor (scan pattern and physics) at a mount over a static world, and the people who walk there. The
static world is a scene (a bundled one by name, and/or primitives with materials) or a background recording of the
empty site, into which simulated people are ray-cast (sim/composite.py). The bundled domains `sim`, `real` and
`industrial` are site files shipped in cfgs/sites/ (`get_domain`); a user's own place is a file like them
(`load_site`). docs/sites.md describes every key; errors name the file, line, key and a close match.

    name: my_hall                                   # data set name (frame metadata 'domain')
    sensor: {pattern: cube1_paper, physics: calibrated}   # presets, or pattern: {hfov_deg: 72, ...}
    mount: {height: 3.2, tilt_deg: 12}              # or `estimate` (from the background's floor)
    scene: industrial_entrance                      # or {base: NAME, primitives: [...]}; or viewpoints: [...]
    background: {recording: empty_hall.bfpc}        # instead of a scene: a real recording of the empty site
                                                    # (a ROS 2 bag with several point-cloud topics: topic: /points)
    walkable: [[2, -4], [9, -4], [9, 4], [2, 4]]    # polygon on the floor [m] people stay inside
    people: {count: [1, 8], behaviours: {walk: 0.5, stand: 0.5}, vest_probability: 0.6}
    distractors: {count: [0, 2], kinds: [box, pallet]}   # with a background: objects that are not people
    frames: 230                                     # frames `memslidar simulate --site` makes by default
"""
from __future__ import annotations

import dataclasses
import difflib
import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from pcdet_memslidar.config import CONFIG_DIR, YamlLoader, parse_yaml
from pcdet_memslidar.errors import ConfigError, DataFormatError
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.geometry.polygon import points_in_polygon
from pcdet_memslidar.io.formats import InputFormat, file_formats, format_of
from pcdet_memslidar.sim.motion import BEHAVIOURS
from pcdet_memslidar.sim.pattern import FRAME_MODES, PATTERNS, PULSE_TYPES, ScanPattern, get_pattern
from pcdet_memslidar.sim.scenes import MATERIALS, PRIMITIVES, SCENES, SceneSpec
from pcdet_memslidar.sim.sensor import SENSORS

SITES_DIR = CONFIG_DIR / "sites"
BUNDLED_SITES = ("sim", "real", "industrial")
LODS = ("fine", "coarse")


@dataclass(frozen=True)
class Viewpoint:
    """A static world (a bundled scene's name or a SceneSpec; None: a background recording) seen from one mount."""

    scene: str | SceneSpec | None
    mount: Mount


@dataclass(frozen=True)
class Background:
    """A recording of the empty site in the sensor frame: a file or a folder of frames of one format
    (background_format).

    frames: (first, stop) indices of the recording's frames to use (None: all); topic: the point-cloud topic of a
    ROS 2 bag (None: its only one)."""

    recording: str
    frames: tuple[int, int] | None = None
    topic: str | None = None


# Site fields left out of Site.to_dict at these values: the fingerprints of sites made before the fields existed stay
_LEFT_OUT_WHEN_DEFAULT = dict(walkable=None, background=None, distractors=(0, 0), distractor_kinds=None)


@dataclass(frozen=True)
class Site:
    """Everything that decides what a data set's frames look like.

    pattern: scan pattern preset name or ScanPattern; sensor: physics preset name; people: (min, max) per frame;
    shapes: body-bank shape indices people are drawn from (None = all); phase_steps: gait phases a body can take
    (None = continuous); behaviours: behaviour -> probability; group_probability: chance that a newly placed person
    walks with a companion side by side; min_separation_m: closest approach of people not in one group during the
    frame; vest_probability: chance of a high-visibility vest; default_frames: frames made unless told otherwise;
    lod: body mesh detail level; time_step_s: pulse-time quantisation of the people's motion (0 = every pulse sees
    its own instant); walkable: polygon ((x, y), ...) [m] on the floor that people's paths stay inside (None:
    anywhere in view); background: a recording of the empty site instead of a scene; distractors: (min, max) objects
    that are not people (sim/distractors.py) composited into each frame of a background site, of distractor_kinds
    (names of distractors.KINDS, None = all).
    """

    name: str
    pattern: str | ScanPattern
    sensor: str
    viewpoints: tuple[Viewpoint, ...]
    people: tuple[int, int]
    shapes: tuple[int, ...] | None
    phase_steps: int | None
    behaviours: tuple[tuple[str, float], ...]
    group_probability: float
    min_separation_m: float
    vest_probability: float
    default_frames: int
    lod: str = "fine"
    time_step_s: float = 0.0
    walkable: tuple[tuple[float, float], ...] | None = None
    background: Background | None = None
    distractors: tuple[int, int] = (0, 0)
    distractor_kinds: tuple[str, ...] | None = None

    def to_dict(self) -> dict:
        """JSON-ready form (used for the fingerprint and the metadata); the keys of a site without a walkable area,
        a background or distractors are those of the bundled domains before site files, so their fingerprints stay."""
        settings = dataclasses.asdict(self)
        if self.background is not None and self.background.topic is None:
            del settings["background"]["topic"]  # the fingerprints of background sites made before bags stay
        return {key: value for key, value in settings.items()
                if not (key in _LEFT_OUT_WHEN_DEFAULT and value == _LEFT_OUT_WHEN_DEFAULT[key])}


# ---------------------------------------------------------------------------------------------------------------
# reading a site file

_KEYS = dict(top=("name", "sensor", "mount", "scene", "viewpoints", "background", "walkable", "people",
                  "distractors", "frames", "simulation"),
             sensor=("pattern", "physics"), mount=("height", "tilt_deg", "roll_deg", "yaw_deg"),
             viewpoint=("scene", "mount"), scene=("base", "primitives", "walk_headings_deg", "walk_x_max"),
             background=("recording", "frames", "topic"),
             people=("count", "shapes", "behaviours", "group_probability", "min_separation_m", "vest_probability",
                     "phase_steps"),
             distractors=("count", "kinds"), simulation=("lod", "time_step_s"),
             pattern=tuple(field.name for field in dataclasses.fields(ScanPattern) if field.name != "name"))


class _SiteFile:
    """Typed access to the YAML nodes of one site file; every error names the file, the line and the key."""

    def __init__(self, path: Path):
        self.path = path
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise ConfigError(f"{path}: site file not found; give the path of a site YAML file (examples: "
                              f"{SITES_DIR})") from None
        except UnicodeDecodeError:
            raise ConfigError(f"{path}: not a UTF-8 text file; a site file is YAML") from None
        parse_yaml(text, str(path))  # syntax errors with their line
        self.root = yaml.compose(text, Loader=YamlLoader)

    def error(self, node, key: str, message: str) -> ConfigError:
        line = f":{node.start_mark.line + 1}" if node is not None else ""
        return ConfigError(f"{self.path}{line}: {key}: {message}")

    def value(self, node):
        """The Python value of a YAML node."""
        return YamlLoader("").construct_document(node)

    def mapping(self, node, key: str, allowed: tuple[str, ...]) -> dict:
        """{name: node} of a mapping; unknown names are refused with a close match."""
        if not isinstance(node, yaml.MappingNode):
            raise self.error(node, key, f"expected a mapping with keys {', '.join(allowed)}")
        found = {}
        for name_node, value in node.value:
            name = str(self.value(name_node))
            if name not in allowed:
                close = difflib.get_close_matches(name, allowed, n=1, cutoff=0.5)
                hint = f"did you mean '{close[0]}'?" if close else f"known keys: {', '.join(allowed)}"
                raise self.error(name_node, f"{key}.{name}" if key else name, f"unknown key; {hint} Fix the spelling "
                                                                              f"or remove the key")
            found[name] = value
        return found

    def number(self, node, key: str, low: float = -np.inf, high: float = np.inf, integer: bool = False):
        value = self.value(node)
        kind = int if integer else (int, float)
        if isinstance(value, bool) or not isinstance(value, kind) or not low <= value <= high:
            what = "an integer" if integer else "a number"
            raise self.error(node, key, f"{value!r} is not {what} in [{low:g}, {high:g}]; fix the value")
        return value if integer else float(value)

    def numbers(self, node, key: str, count: int, low: float = -np.inf, high: float = np.inf,
                integer: bool = False) -> tuple:
        if not isinstance(node, yaml.SequenceNode) or len(node.value) != count:
            raise self.error(node, key, f"expected a list of {count} numbers, e.g. [{', '.join(['1'] * count)}]")
        return tuple(self.number(item, key, low, high, integer) for item in node.value)

    def choice(self, node, key: str, options) -> str:
        value = self.value(node)
        if value not in options:
            close = difflib.get_close_matches(str(value), list(options), n=1, cutoff=0.5)
            hint = f"did you mean '{close[0]}'?" if close else f"choose one of {', '.join(options)}"
            raise self.error(node, key, f"unknown value {value!r}; {hint}")
        return value


def _mount(file: _SiteFile, node, key: str) -> Mount:
    fields = file.mapping(node, key, _KEYS["mount"])
    if "height" not in fields or "tilt_deg" not in fields:
        raise file.error(node, key, "a mount needs height [m] and tilt_deg [deg, > 0 looks down], e.g. "
                                    "{height: 3.2, tilt_deg: 12}")
    limits = dict(height=(0.1, 100.0), tilt_deg=(-90.0, 90.0), roll_deg=(-90.0, 90.0), yaw_deg=(-180.0, 180.0))
    return Mount(**{name: file.number(value, f"{key}.{name}", *limits[name]) for name, value in fields.items()})


def _pattern(file: _SiteFile, node, key: str) -> str | ScanPattern:
    if isinstance(node, yaml.ScalarNode):
        return file.choice(node, key, sorted(PATTERNS))
    fields = file.mapping(node, key, _KEYS["pattern"])
    values = {}
    for name, value in fields.items():
        if name == "frame_mode":
            values[name] = file.choice(value, f"{key}.{name}", FRAME_MODES)
        elif name == "pulse_type":
            values[name] = file.choice(value, f"{key}.{name}", PULSE_TYPES)
        else:
            values[name] = file.number(value, f"{key}.{name}", 0.0, 1e4, integer=name.startswith("lines"))
    missing = [name for name in ("hfov_deg", "vfov_deg", "lines_up", "lines_down", "mirror_frequency_hz",
                                 "angle_spacing_deg") if name not in values]
    if missing:
        raise file.error(node, key, f"a scan pattern needs {', '.join(missing)} (or name a preset: "
                                    f"{', '.join(sorted(PATTERNS))})")
    try:
        return ScanPattern(name=f"{file.path.stem}_pattern", **values)
    except ConfigError as error:
        raise file.error(node, key, str(error)) from None


def _scene(file: _SiteFile, node, key: str, name: str) -> str | SceneSpec:
    if isinstance(node, yaml.ScalarNode):
        return file.choice(node, key, SCENES)
    fields = file.mapping(node, key, _KEYS["scene"])
    base = file.choice(fields["base"], f"{key}.base", SCENES) if "base" in fields else None
    primitives = []
    items = fields.get("primitives")
    for index, item in enumerate(items.value if isinstance(items, yaml.SequenceNode) else []):
        where = f"{key}.primitives[{index}]"
        kind_fields = file.mapping(item, where, tuple(PRIMITIVES))
        if len(kind_fields) != 1:
            raise file.error(item, where, "one primitive per list item, e.g. {box: {centre: [10, 7], size: "
                                          "[2.5, 1.5, 2.0], material: metal}}")
        (kind, parameters), = kind_fields.items()
        _, required, optional = PRIMITIVES[kind]
        given = file.mapping(parameters, f"{where}.{kind}", required + optional)
        missing = [parameter for parameter in required if parameter not in given]
        if missing:
            raise file.error(parameters, f"{where}.{kind}", f"missing {', '.join(missing)}")
        primitives.append((kind, tuple((parameter, _primitive_value(file, value, f"{where}.{kind}.{parameter}"))
                                       for parameter, value in given.items())))
    if items is not None and not isinstance(items, yaml.SequenceNode):
        raise file.error(items, f"{key}.primitives", "expected a list of primitives")
    if base is None and not primitives:
        raise file.error(node, key, "a scene needs a bundled `base` scene or `primitives` (or both)")
    headings = fields.get("walk_headings_deg")
    return SceneSpec(
        name=name, base=base, primitives=tuple(primitives),
        walk_headings_deg=None if headings is None else tuple(
            file.number(item, f"{key}.walk_headings_deg", -360, 360) for item in headings.value),
        walk_x_max=file.number(fields["walk_x_max"], f"{key}.walk_x_max", 0.5, 500) if "walk_x_max" in fields else None)


def _primitive_value(file: _SiteFile, node, key: str):
    """A primitive's parameter: a material name or reflectivity, a flag, a number or a list of numbers."""
    parameter = key.rsplit(".", 1)[1]
    if parameter == "material":
        value = file.value(node)
        return file.choice(node, key, sorted(MATERIALS)) if isinstance(value, str) else file.number(node, key, 0, 1)
    if parameter == "solid":
        value = file.value(node)
        if not isinstance(value, bool):
            raise file.error(node, key, f"{value!r} is not true or false")
        return value
    if parameter == "sides":
        return file.number(node, key, 3, 64, integer=True)
    if isinstance(node, yaml.SequenceNode):
        count = {"size": 3, "levels": len(node.value)}.get(parameter, 2)
        return file.numbers(node, key, count, -1e4, 1e4)
    return file.number(node, key, -1e4, 1e4)


def _people(file: _SiteFile, node, key: str) -> dict:
    fields = file.mapping(node, key, _KEYS["people"]) if node is not None else {}
    count = file.numbers(fields["count"], f"{key}.count", 2, 0, 100, integer=True) if "count" in fields else (1, 4)
    if count[0] > count[1]:
        raise file.error(fields["count"], f"{key}.count", f"{list(count)}: give [min, max] with min <= max")
    behaviours = (("walk", 0.5), ("turn", 0.2), ("stop_and_go", 0.15), ("stand", 0.15))
    if "behaviours" in fields:
        given = file.mapping(fields["behaviours"], f"{key}.behaviours", BEHAVIOURS)
        behaviours = tuple((name, file.number(value, f"{key}.behaviours.{name}", 0, 1))
                           for name, value in given.items())
        if not sum(weight for _, weight in behaviours) > 0:
            raise file.error(fields["behaviours"], f"{key}.behaviours", "the probabilities must not all be 0")
    shapes = None
    if "shapes" in fields and file.value(fields["shapes"]) != "all":
        items = fields["shapes"]
        if not isinstance(items, yaml.SequenceNode) or not items.value:
            raise file.error(items, f"{key}.shapes", "give `all` or a list of body-bank shape indices, e.g. [2, 3]")
        shapes = tuple(file.number(item, f"{key}.shapes", 0, 11, integer=True) for item in items.value)
    phase_steps = fields.get("phase_steps")
    return dict(
        people=count, shapes=shapes, behaviours=behaviours,
        phase_steps=None if phase_steps is None or file.value(phase_steps) is None
        else file.number(phase_steps, f"{key}.phase_steps", 1, 64, integer=True),
        group_probability=file.number(fields["group_probability"], f"{key}.group_probability", 0, 1)
        if "group_probability" in fields else 0.1,
        min_separation_m=file.number(fields["min_separation_m"], f"{key}.min_separation_m", 0.5, 20)
        if "min_separation_m" in fields else 1.0,
        vest_probability=file.number(fields["vest_probability"], f"{key}.vest_probability", 0, 1)
        if "vest_probability" in fields else 0.0)


def _distractors(file: _SiteFile, node, key: str) -> dict:
    from pcdet_memslidar.sim.distractors import KINDS  # here: sim/distractors.py imports this module

    fields = file.mapping(node, key, _KEYS["distractors"])
    if "count" not in fields:
        raise file.error(node, key, "give the distractors per frame as count: [min, max], e.g. {count: [0, 2]}")
    count = file.numbers(fields["count"], f"{key}.count", 2, 0, 20, integer=True)
    if count[0] > count[1]:
        raise file.error(fields["count"], f"{key}.count", f"{list(count)}: give [min, max] with min <= max")
    kinds = fields.get("kinds")
    if kinds is not None and (not isinstance(kinds, yaml.SequenceNode) or not kinds.value):
        raise file.error(kinds, f"{key}.kinds", f"give a list of kinds, e.g. [box, pallet] (known: {', '.join(KINDS)})")
    return dict(distractors=count, distractor_kinds=None if kinds is None else tuple(
        file.choice(item, f"{key}.kinds", tuple(KINDS)) for item in kinds.value))


def _walkable(file: _SiteFile, node, key: str) -> tuple[tuple[float, float], ...]:
    if not isinstance(node, yaml.SequenceNode) or len(node.value) < 3:
        raise file.error(node, key, "expected a polygon of at least 3 [x, y] corners in metres on the floor, e.g. "
                                    "[[2, -4], [9, -4], [9, 4], [2, 4]]")
    corners = tuple(file.numbers(item, key, 2, -500, 500) for item in node.value)
    x, y = np.array(corners).T
    if abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2 < 0.5:
        raise file.error(node, key, "the polygon encloses less than 0.5 m^2: give its corners in order around it")
    return corners


def _background(file: _SiteFile, node, key: str) -> Background:
    fields = file.mapping(node, key, _KEYS["background"])
    if "recording" not in fields:
        raise file.error(node, key, "a background needs `recording`: a recording file or a folder of frames")
    recording = Path(str(file.value(fields["recording"]))).expanduser()
    recording = recording if recording.is_absolute() else (file.path.resolve().parent / recording).resolve()
    if not recording.exists():
        raise file.error(fields["recording"], f"{key}.recording", f"{recording} does not exist; give the path of the "
                                                                   f"recording (relative to the site file)")
    try:
        fmt = background_format(recording)
    except DataFormatError as error:
        raise file.error(fields["recording"], f"{key}.recording", str(error)) from None
    topic = str(file.value(fields["topic"])) if "topic" in fields else None
    if topic is not None and not fmt.topics:
        raise file.error(fields["topic"], f"{key}.topic", f"a {fmt.name} recording has no topics: drop {key}.topic")
    frames = None
    if "frames" in fields:
        frames = file.numbers(fields["frames"], f"{key}.frames", 2, 0, 10 ** 7, integer=True)
        if frames[0] >= frames[1]:
            raise file.error(fields["frames"], f"{key}.frames", f"{list(frames)}: give [first, stop) with first < stop")
    return Background(str(recording), frames, topic)


def background_format(recording: Path) -> InputFormat:
    """The format of a background recording: a file, or a folder of frames, of a format read from files
    (io.formats.file_formats); DataFormatError naming the recording and the formats otherwise."""
    formats = file_formats()
    suffixes = ", ".join(suffix for fmt in formats for suffix in fmt.suffixes)
    return format_of(recording, formats, f"a background is a file or a folder of frames of one format: {suffixes}")


def load_site(path: str | Path, estimate_mount=None) -> Site:
    """The Site of the YAML file `path`; ConfigError naming the file, line, key and fix for anything wrong.

    estimate_mount(Background) -> Mount: called for a background site whose mount is `estimate`."""
    path = Path(path)
    file = _SiteFile(path)
    if not isinstance(file.root, yaml.MappingNode):
        raise ConfigError(f"{path}: a site file is a YAML mapping (name:, sensor:, mount:, scene: ...)")
    top = file.mapping(file.root, "", _KEYS["top"])
    if "name" not in top:
        raise file.error(file.root, "name", "missing: give the site a name (letters, digits, _ and -)")
    name = str(file.value(top["name"]))
    sensor = file.mapping(top["sensor"], "sensor", _KEYS["sensor"]) if "sensor" in top else {}
    pattern = _pattern(file, sensor["pattern"], "sensor.pattern") if "pattern" in sensor else "cube1_paper"
    physics = file.choice(sensor["physics"], "sensor.physics", sorted(SENSORS)) if "physics" in sensor else "calibrated"
    worlds = [key for key in ("scene", "viewpoints", "background") if key in top]
    if len(worlds) != 1:
        raise file.error(file.root, "scene", f"give exactly one of scene (with mount), viewpoints, or background "
                                             f"(with mount); this file has {', '.join(worlds) or 'none'}")
    background = _background(file, top["background"], "background") if "background" in top else None
    if "viewpoints" in top:
        if "mount" in top:
            raise file.error(top["mount"], "mount", "with viewpoints, each viewpoint has its own mount")
        items = top["viewpoints"]
        if not isinstance(items, yaml.SequenceNode) or not items.value:
            raise file.error(items, "viewpoints", "expected a list of {scene: ..., mount: {...}}")
        viewpoints = []
        for index, item in enumerate(items.value):
            fields = file.mapping(item, f"viewpoints[{index}]", _KEYS["viewpoint"])
            if set(fields) != {"scene", "mount"}:
                raise file.error(item, f"viewpoints[{index}]", "a viewpoint needs scene and mount")
            viewpoints.append(Viewpoint(_scene(file, fields["scene"], f"viewpoints[{index}].scene", name),
                                        _mount(file, fields["mount"], f"viewpoints[{index}].mount")))
    else:
        if "mount" not in top:
            raise file.error(file.root, "mount", "missing: give {height: H, tilt_deg: T}"
                                                 + (" or `estimate`" if background else ""))
        estimate = isinstance(top["mount"], yaml.ScalarNode) and file.value(top["mount"]) == "estimate"
        if estimate and background is None:
            raise file.error(top["mount"], "mount", "`estimate` needs a background recording to estimate it from")
        if estimate and estimate_mount is None:
            raise file.error(top["mount"], "mount", "`estimate` is not available here: give {height: H, tilt_deg: T}")
        mount = estimate_mount(background) if estimate else _mount(file, top["mount"], "mount")
        scene = None if background else _scene(file, top["scene"], "scene", name)
        viewpoints = [Viewpoint(scene, mount)]
    walkable = _walkable(file, top["walkable"], "walkable") if "walkable" in top else None
    if "distractors" in top and background is None:
        raise file.error(top["distractors"], "distractors", "only a background site composites distractors into its "
                                                            "recording; in a scene, add such objects to its primitives")
    distractors = _distractors(file, top["distractors"], "distractors") if "distractors" in top else {}
    simulation = file.mapping(top["simulation"], "simulation", _KEYS["simulation"]) if "simulation" in top else {}
    site = Site(
        name=name, pattern=pattern, sensor=physics, viewpoints=tuple(viewpoints),
        **_people(file, top.get("people"), "people"),
        default_frames=file.number(top["frames"], "frames", 1, 10 ** 6, integer=True) if "frames" in top else 100,
        lod=file.choice(simulation["lod"], "simulation.lod", LODS) if "lod" in simulation else "fine",
        time_step_s=file.number(simulation["time_step_s"], "simulation.time_step_s", 0, 10)
        if "time_step_s" in simulation else 0.0,
        walkable=walkable, background=background, **distractors)
    if walkable is not None:
        check_walkable_in_view(site, lambda message: file.error(top["walkable"], "walkable", message))
    return site


def check_walkable_in_view(site: Site, error, min_share: float = 0.5) -> None:
    """Raise error(message) unless at least `min_share` of the walkable polygon lies in the sensor's field of view
    at 1 m above the floor (a person's middle), from every viewpoint."""
    pattern = get_pattern(site.pattern)
    corners = np.array(site.walkable)
    low, high = corners.min(0), corners.max(0)
    grid = np.stack(np.meshgrid(np.linspace(low[0], high[0], 60), np.linspace(low[1], high[1], 60)), -1).reshape(-1, 2)
    inside = grid[points_in_polygon(grid, corners)]
    for viewpoint in site.viewpoints:
        seen = in_field_of_view(np.c_[inside, np.ones(len(inside))], viewpoint.mount, pattern)
        share = seen.mean() if len(seen) else 0.0
        if share < min_share:
            raise error(f"only {100 * share:.0f} % of the walkable area lies in the sensor's field of view (azimuth "
                        f"+-{pattern.hfov_deg / 2:g} deg, elevation +-{pattern.vfov_deg / 2:g} deg at 1 m above the "
                        f"floor, mount {viewpoint.mount.height:g} m / {viewpoint.mount.tilt_deg:g} deg): at least "
                        f"{100 * min_share:.0f} % must be; move the polygon in front of the sensor (x forward, y left)")


def in_field_of_view(points: np.ndarray, mount: Mount, pattern: ScanPattern) -> np.ndarray:
    """(N,) bool: points (N, 3) [m] (ground frame) in front of the sensor within the pattern's azimuth and elevation
    extent."""
    local = mount.ground_to_sensor(points)
    azimuth = np.degrees(np.arctan2(local[:, 1], local[:, 0]))
    elevation = np.degrees(np.arctan2(local[:, 2], np.hypot(local[:, 0], local[:, 1])))
    return (local[:, 0] > 0) & (np.abs(azimuth) <= pattern.hfov_deg / 2) & (np.abs(elevation) <= pattern.vfov_deg / 2)


@functools.lru_cache(maxsize=None)
def get_domain(name: str) -> Site:
    """The bundled site `name` ('sim' | 'real' | 'industrial'), read from cfgs/sites/<name>.yaml."""
    if name not in BUNDLED_SITES:
        raise ConfigError(f"unknown domain '{name}': choose one of {list(BUNDLED_SITES)}, or write a site file")
    return load_site(SITES_DIR / f"{name}.yaml")
