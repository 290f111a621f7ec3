"""Build pcdet_memslidar/assets/body_bank.npz, the bank of posed human bodies the simulator ships with.

Run once (needs `pip install anny`, which is not a runtime dependency; its first load builds a ~1 GB cache and
takes minutes):  python tools/research/build_body_bank.py [--out pcdet_memslidar/assets/body_bank.npz]

The bank holds, for 12 adult body shapes (2 sexes x stature 5th / 50th / 95th percentile x slim / heavy build,
REFERENCE section 4) and 4 mesh detail levels of the anny body model (CC0 MakeHuman assets), the rest-pose
vertices of every shape and, for a walking gait cycle sampled at GAIT_PHASES phases plus a standing pose, one
rigid transform per body part. At run time a part's rest vertices moved by its transform give the posed body;
the transforms are least-squares (Kabsch) fits of anny's linear-blend-skinned vertices, and the fit error is
stored (`rigid_fit_error_m`). Triangles that straddle two parts belong to both, so bent joints overlap
instead of opening cracks.

Body frame: x forward (facing direction), y left, z up, origin on the ground below the pelvis.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from pcdet_memslidar.utils.atomic import atomic_path

GAIT_PHASES = 32
LODS = {"coarse": "notoes_collapse3pc", "medium": "notoes_collapse5pc", "fine": "notoes_collapse10pc",
        "full": "notoes"}
FIT_LOD = "fine"  # the detail level whose skinned vertices the part transforms are fitted to

# body part -> anny bones (prefix match, '.L' / '.R' appended for sided parts)
PARTS = {
    "torso": ["root", "pelvis", "spine", "clavicle", "shoulder01"],
    "head": ["neck", "head", "eye"],
    "upperarm.L": ["upperarm"], "forearm.L": ["lowerarm", "wrist", "finger", "metacarpal"],
    "upperarm.R": ["upperarm"], "forearm.R": ["lowerarm", "wrist", "finger", "metacarpal"],
    "thigh.L": ["upperleg"], "shin.L": ["lowerleg"], "foot.L": ["foot", "toe"],
    "thigh.R": ["upperleg"], "shin.R": ["lowerleg"], "foot.R": ["foot", "toe"],
}
MATERIALS = ("skin", "upper_clothing", "lower_clothing", "shoes")
MATERIAL_OF_BONE = [("wrist", 0), ("finger", 0), ("metacarpal", 0), ("neck", 0), ("head", 0), ("eye", 0),
                    ("foot", 3), ("toe", 3), ("upperleg", 2), ("lowerleg", 2), ("pelvis", 2), ("root", 2)]

# (sex, stature [m], anny gender): adult stature 5th / 50th / 95th percentiles, REFERENCE section 4
STATURES = [("male", 1.63), ("male", 1.74), ("male", 1.86), ("female", 1.51), ("female", 1.61), ("female", 1.71)]
BUILDS = {"slim": 0.3, "heavy": 0.75}  # anny weight parameter
GENDER = {"male": 0.0, "female": 1.0}
ADULT_AGE = 0.75  # anny age anchors: 2/3 = young adult, 1 = old


def _rotation(axis: str, degrees: float) -> torch.Tensor:
    a = np.deg2rad(degrees)
    c, s = np.cos(a), np.sin(a)
    matrix = {"x": [[1, 0, 0], [0, c, -s], [0, s, c]], "y": [[c, 0, s], [0, 1, 0], [-s, 0, c]],
              "z": [[c, -s, 0], [s, c, 0], [0, 0, 1]]}[axis]
    return torch.tensor(matrix, dtype=torch.float64)


def _periodic_bump(phase: float, centre: float, width: float) -> float:
    """Gaussian bump on the unit circle of gait phase."""
    distance = (phase - centre + 0.5) % 1.0 - 0.5
    return float(np.exp(-(distance / width) ** 2))


def joint_angles(phase: float | None) -> dict[str, tuple[float, float, float]]:
    """Sagittal joint angles [deg] (flexion > 0) of the left side at gait `phase` (0 = left heel strike; None =
    standing): hip +30 / -20, knee peak 60 in swing, ankle plantar flexion at toe-off, arm swing opposite the leg."""
    if phase is None:
        return dict(hip=0.0, knee=3.0, ankle=0.0, shoulder=0.0, elbow=10.0)
    return dict(hip=5.0 + 25.0 * np.cos(2 * np.pi * phase),
                knee=4.0 + 14.0 * _periodic_bump(phase, 0.12, 0.08) + 56.0 * _periodic_bump(phase, 0.72, 0.11),
                ankle=-15.0 * _periodic_bump(phase, 0.62, 0.07) + 6.0 * _periodic_bump(phase, 0.45, 0.1),
                shoulder=-15.0 * np.cos(2 * np.pi * phase), elbow=18.0 + 10.0 * np.cos(2 * np.pi * phase))


def pose_parameters(phase: float | None) -> dict[str, torch.Tensor]:
    """anny 'local-ref' pose: one 4x4 per bone, rotations about the reference axes (anny: x left, -y forward).

    A rotation about +x by a negative angle swings a limb forward."""
    pose = {}
    for side, shift, sign in (("L", 0.0, 1.0), ("R", 0.5, -1.0)):
        angles = joint_angles(None if phase is None else (phase + shift) % 1.0)
        rotations = {
            "upperleg01": _rotation("x", -angles["hip"]),
            "lowerleg01": _rotation("x", angles["knee"]),
            "foot": _rotation("x", -angles["ankle"]),
            # lower the arm from anny's A-pose (arms out and forward) to the side of the body, then swing it
            "upperarm01": _rotation("x", 12.0 - angles["shoulder"]) @ _rotation("y", sign * 38.0),
            "lowerarm01": _rotation("x", -angles["elbow"]),
        }
        for bone, rotation in rotations.items():
            matrix = torch.eye(4, dtype=torch.float64)
            matrix[:3, :3] = rotation
            pose[f"{bone}.{side}"] = matrix[None]
    return pose


def to_body_frame(vertices: np.ndarray) -> np.ndarray:
    """(V, 3) anny coordinates (x left, y backward, z up) -> body frame (x forward, y left, z up)."""
    return np.stack([-vertices[:, 1], vertices[:, 0], vertices[:, 2]], axis=1)


def vertex_labels(model) -> tuple[np.ndarray, np.ndarray]:
    """(V,) part index and (V,) material index of every vertex, from its skinning weights."""
    bones = model.bone_labels
    part_of_bone = np.full(len(bones), -1)
    material_of_bone = np.full(len(bones), 1)
    for index, bone in enumerate(bones):
        side = bone[-2:] if bone[-2:] in (".L", ".R") else ""
        for part_index, (part, prefixes) in enumerate(PARTS.items()):
            sided = "." in part
            if (bool(side) and part.endswith(side) if sided else True) and any(bone.startswith(p) for p in prefixes):
                part_of_bone[index] = part_index
        material_of_bone[index] = next((m for prefix, m in MATERIAL_OF_BONE if bone.startswith(prefix)), 1)
    if (part_of_bone < 0).any():
        raise RuntimeError(f"bones without a part: {[b for b, p in zip(bones, part_of_bone) if p < 0]}")
    weights = model.vertex_bone_weights.numpy()
    indices = model.vertex_bone_indices.numpy()
    part_weight = np.zeros((weights.shape[0], len(PARTS)))
    material_weight = np.zeros((weights.shape[0], len(MATERIALS)))
    rows = np.arange(weights.shape[0])[:, None].repeat(weights.shape[1], 1)
    np.add.at(part_weight, (rows, part_of_bone[indices]), weights)
    np.add.at(material_weight, (rows, material_of_bone[indices]), weights)
    return part_weight.argmax(1), material_weight.argmax(1)


def part_triangles(faces: np.ndarray, vertex_part: np.ndarray, vertex_material: np.ndarray):
    """Each triangle listed once per part owning one of its vertices: (T', 3) faces, (T',) part, (T',) material."""
    rows, parts = [], []
    for part in range(len(PARTS)):
        owned = (vertex_part[faces] == part).any(axis=1)
        rows.append(np.flatnonzero(owned))
        parts.append(np.full(owned.sum(), part))
    rows, parts = np.concatenate(rows), np.concatenate(parts)
    return faces[rows], parts, vertex_material[faces[rows, 0]]


def kabsch(rest: np.ndarray, posed: np.ndarray) -> np.ndarray:
    """(3, 4) rigid transform [R | t] minimising |R rest + t - posed|^2 for (n, 3) point sets."""
    rest_mean, posed_mean = rest.mean(0), posed.mean(0)
    u, _, vt = np.linalg.svd((rest - rest_mean).T @ (posed - posed_mean))
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rotation = vt.T @ flip @ u.T
    return np.hstack([rotation, (posed_mean - rotation @ rest_mean)[:, None]])


def stature_height_parameter(model, sex: str, stature: float, weight: float) -> float:
    """anny `height` parameter giving `stature` [m] (bisection on the rest mesh)."""
    low, high = 0.0, 1.0
    for _ in range(30):
        middle = 0.5 * (low + high)
        vertices = model(phenotype_kwargs=dict(gender=GENDER[sex], age=ADULT_AGE, weight=weight, height=middle))
        z = vertices["vertices"][0, :, 2]
        low, high = (middle, high) if float(z.max() - z.min()) < stature else (low, middle)
    return 0.5 * (low + high)


def build(out: Path) -> None:
    import anny

    torch.set_num_threads(1)
    models = {lod: anny.Anny(topology=topology) for lod, topology in LODS.items()}
    poses = [pose_parameters(phase) for phase in np.arange(GAIT_PHASES) / GAIT_PHASES] + [pose_parameters(None)]
    shapes = [(sex, stature, build_name) for sex, stature in STATURES for build_name in BUILDS]
    arrays: dict[str, np.ndarray] = {}
    labels = {lod: vertex_labels(model) for lod, model in models.items()}
    for lod, model in models.items():
        faces, parts, materials = part_triangles(model.get_triangular_faces().numpy(), *labels[lod])
        arrays[f"{lod}_triangles"] = faces.astype(np.uint16)
        arrays[f"{lod}_triangle_part"] = parts.astype(np.uint8)
        arrays[f"{lod}_triangle_material"] = materials.astype(np.uint8)

    transforms = np.zeros((len(shapes), len(poses), len(PARTS), 3, 4))
    fit_error = []
    rest = {lod: [] for lod in LODS}
    shape_params = []
    for shape_index, (sex, stature, build_name) in enumerate(shapes):
        phenotype = dict(gender=GENDER[sex], age=ADULT_AGE, weight=BUILDS[build_name],
                         height=stature_height_parameter(models[FIT_LOD], sex, stature, BUILDS[build_name]))
        shape_params.append([phenotype[k] for k in ("gender", "age", "weight", "height")])
        posed = [to_body_frame(models[FIT_LOD](pose_parameters=pose, phenotype_kwargs=phenotype)["vertices"][0]
                               .numpy()) for pose in poses]
        rest_fit = to_body_frame(models[FIT_LOD](phenotype_kwargs=phenotype)["vertices"][0].numpy())
        ground = posed[-1][:, 2].min()  # the standing pose's lowest vertex defines the rest frame's ground
        rest_fit[:, 2] -= ground
        for lod, model in models.items():
            vertices = to_body_frame(model(phenotype_kwargs=phenotype)["vertices"][0].numpy())
            vertices[:, 2] -= ground
            rest[lod].append(vertices)
        part_of_vertex = labels[FIT_LOD][0]
        for pose_index, vertices in enumerate(posed):
            vertices = vertices.copy()
            vertices[:, 2] -= vertices[:, 2].min()  # every pose stands on the ground: the body bobs while walking
            for part in range(len(PARTS)):
                mask = part_of_vertex == part
                transform = kabsch(rest_fit[mask], vertices[mask])
                transforms[shape_index, pose_index, part] = transform
                fitted = rest_fit[mask] @ transform[:, :3].T + transform[:, 3]
                fit_error.append(np.linalg.norm(fitted - vertices[mask], axis=1))
        print(f"shape {shape_index}: {sex} {stature} m {build_name}", flush=True)
    fit_error = np.concatenate(fit_error)

    arrays.update(
        part_names=np.array(list(PARTS)), material_names=np.array(MATERIALS), lod_names=np.array(list(LODS)),
        shape_sex=np.array([s[0] for s in shapes]), shape_stature_m=np.array([s[1] for s in shapes], np.float32),
        shape_build=np.array([s[2] for s in shapes]), shape_anny_parameters=np.array(shape_params, np.float32),
        gait_phases=np.int64(GAIT_PHASES), transforms=transforms.astype(np.float32),
        rigid_fit_error_m=np.percentile(fit_error, [50, 90, 99, 100]).astype(np.float32))
    for lod in LODS:
        arrays[f"{lod}_rest_vertices"] = np.stack(rest[lod]).astype(np.float16)
    with atomic_path(out) as tmp:
        with open(tmp, "wb") as handle:
            np.savez_compressed(handle, **arrays)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB); rigid fit error p50/p90/p99/max [m]: "
          f"{arrays['rigid_fit_error_m']}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).resolve().parents[2] / "pcdet_memslidar" / "assets" / "body_bank.npz")
    build(parser.parse_args().out)


if __name__ == "__main__":
    main()
