"""Domain presets: what the `sim`, `real` and `industrial` data sets are made of (DESIGN.md, "three bundled data
domains").

- sim: the paper's CARLA pipeline: 'carla' sensor (5 % uniform drop, 0.5 % range scale, no intensity physics),
  4 public scenes seen from 4 different mounts, 3-10 people, a reduced body set (4 median-stature shapes) and
  pose set (8 gait phases), many groups and close passes.
- real: stand-in for the paper's real recordings: 'calibrated' sensor, one viewpoint (4 m, 16 deg tilt) over one
  crossing, 1-4 people, all 12 body shapes, continuous gait, few groups and no close passes (>= 1.5 m apart).
- industrial: the unseen evaluation split: 'calibrated' sensor, 5 m / 23 deg over a factory entrance with
  machines, racks, pallets, a forklift and doors, 1-8 people, many in high-visibility vests; about 230 frames.
All use the paper's 'cube1_paper' scan pattern (72 x 30 deg, 200 lines, 0.4 s frames).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.geometry.mount import Mount


@dataclass(frozen=True)
class Viewpoint:
    """A static world seen from one sensor mount."""

    scene: str
    mount: Mount


@dataclass(frozen=True)
class DomainPreset:
    """Everything that decides what a domain's frames look like.

    people: (min, max) people per frame; shapes: body-bank shape indices people are drawn from (None = all);
    phase_steps: gait phases a body can take (None = continuous); behaviours: behaviour -> probability;
    group_probability: chance that a newly placed person walks with a companion side by side;
    min_separation_m: closest approach of people not in one group during the frame; vest_probability: chance of
    a high-visibility vest; lod: body mesh detail level; time_step_s: pulse-time quantisation of the people's
    motion (0 = every pulse sees its own instant).
    """

    name: str
    pattern: str
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

    def to_dict(self) -> dict:
        """JSON-ready form (used for the fingerprint and the metadata)."""
        return dataclasses.asdict(self)


DOMAINS = {
    "sim": DomainPreset(
        name="sim", pattern="cube1_paper", sensor="carla",
        viewpoints=(Viewpoint("crossing_across", Mount(4.5, 18.0)), Viewpoint("crossing_ahead", Mount(5.0, 20.0)),
                    Viewpoint("intersection", Mount(6.0, 22.0)), Viewpoint("pathway", Mount(3.5, 14.0))),
        people=(3, 10), shapes=(2, 3, 8, 9), phase_steps=8,
        behaviours=(("walk", 0.6), ("turn", 0.1), ("stop_and_go", 0.1), ("stand", 0.2)),
        group_probability=0.3, min_separation_m=0.7, vest_probability=0.0, default_frames=2100),
    "real": DomainPreset(
        name="real", pattern="cube1_paper", sensor="calibrated",
        viewpoints=(Viewpoint("crossing_across", Mount(4.0, 16.0)),),
        people=(1, 4), shapes=None, phase_steps=None,
        behaviours=(("walk", 0.5), ("turn", 0.2), ("stop_and_go", 0.15), ("stand", 0.15)),
        group_probability=0.1, min_separation_m=1.5, vest_probability=0.05, default_frames=2100),
    "industrial": DomainPreset(
        name="industrial", pattern="cube1_paper", sensor="calibrated",
        viewpoints=(Viewpoint("industrial_entrance", Mount(5.0, 23.0)),),
        people=(1, 8), shapes=None, phase_steps=None,
        behaviours=(("walk", 0.5), ("turn", 0.15), ("stop_and_go", 0.15), ("stand", 0.2)),
        group_probability=0.15, min_separation_m=0.8, vest_probability=0.6, default_frames=230),
}


def get_domain(name: str) -> DomainPreset:
    """The domain preset `name` ('sim' | 'real' | 'industrial')."""
    if name not in DOMAINS:
        raise ConfigError(f"unknown domain '{name}': choose one of {sorted(DOMAINS)}")
    return DOMAINS[name]
