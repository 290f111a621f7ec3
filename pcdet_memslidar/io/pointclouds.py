"""Point-cloud file readers: PCD (ascii, binary, binary_compressed), PLY (ascii, binary), NPY and KITTI BIN.

Every reader returns a file's columns by name, which `cloud_from_fields` turns into a `LoadedCloud`: (N, 4) float32
x, y, z, intensity, the optional per-point time, and how many points were dropped because their coordinates are
NaN / infinite or all zero (a Blickfeld pulse without return): they are removed and counted, never silently.
Truncated or malformed files raise DataFormatError naming the file. The readers are registered with their suffixes
in io.formats, whose read_point_cloud reads a file by its suffix.

PCD and PLY are parsed here (a header plus one numpy view of the body) because the libraries at hand return
zero-padded or shortened clouds from truncated files without an error; LZF (PCD binary_compressed) is decoded
by the `lzf` C extension of python-neo-lzf.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from pcdet_memslidar.errors import DataFormatError

# field names that other tools use for intensity and per-point time, in order of preference
INTENSITY_FIELDS = ("intensity", "reflectivity", "i", "scalar_intensity", "remission")
TIME_FIELDS = ("time", "time_offset", "timestamp", "t", "offset_time")
# seconds per unit of a time field, for the formats whose files do not say it (`--time-unit`)
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
# A frame's points are taken within one scan [s]: a wider spread of their times means the unit given is too large.
MAX_FRAME_SPAN_S = 10.0
# No LiDAR return lies this far [m]: a coordinate beyond it is a damaged file (a PCD binary_compressed body has no
# checksum, so a flipped byte in it decodes to a wrong value) or one not in metres.
MAX_COORDINATE_M = 1000.0


@dataclass
class LoadedCloud:
    """One point cloud read from a file."""

    points: np.ndarray  # (N, 4) float32 x, y, z, intensity (0 where the file has no intensity)
    time: np.ndarray | None  # (N,) float64 per-point time in the file's unit, or None
    dropped: int  # points removed because x, y, z were NaN / infinite or all zero
    has_intensity: bool
    time_unit_s: float | None = None  # seconds per unit of `time` where the format says it (.bfpc: 1), else None

    def time_offsets(self) -> np.ndarray | None:
        """(N,) float32 time of each point [s] from the frame's earliest point, where the unit is known, else None."""
        if self.time is None or self.time_unit_s is None:
            return None
        if len(self.time) == 0:
            return np.zeros(0, np.float32)
        return ((self.time - self.time.min()) * self.time_unit_s).astype(np.float32)


def cloud_from_fields(fields: dict[str, np.ndarray], path: str | Path, time_unit_s: float | None = None
                      ) -> LoadedCloud:
    """Pick x, y, z, intensity and time from named (N,) columns and drop invalid points (counted). time_unit_s:
    seconds per unit of the time column; given, the file must have one, spread over at most MAX_FRAME_SPAN_S."""
    names = {name.lower(): name for name in fields}
    missing = [axis for axis in "xyz" if axis not in names]
    if missing:
        raise DataFormatError(path, f"no field(s) {', '.join(missing)}; the file has {', '.join(fields) or 'none'}")
    xyz = [fields[names[axis]] for axis in "xyz"]  # column by column: reductions over rows of 3 are slow in numpy
    intensity_name = next((names[n] for n in INTENSITY_FIELDS if n in names), None)
    time_name = time_field(fields)
    intensity = fields[intensity_name].astype(np.float32) if intensity_name else np.zeros(len(xyz[0]), np.float32)
    time = fields[time_name].astype(np.float64) if time_name else None
    finite = np.isfinite(xyz[0]) & np.isfinite(xyz[1]) & np.isfinite(xyz[2])
    valid = finite & ((xyz[0] != 0) | (xyz[1] != 0) | (xyz[2] != 0))
    for name, values in ((intensity_name, intensity), (time_name, time)):
        bad = np.flatnonzero(valid & ~np.isfinite(values)) if name else []
        if len(bad):
            raise DataFormatError(path, f"{len(bad)} point(s) with valid x, y, z have a NaN or infinite {name!r}, "
                                        f"the first is point {bad[0]} (counting from 0); fix or drop them")
    beyond = [(column > MAX_COORDINATE_M) | (column < -MAX_COORDINATE_M) for column in xyz]  # abs() of int16 wraps
    far = np.flatnonzero(valid & (beyond[0] | beyond[1] | beyond[2]))
    if len(far):
        first = np.round([float(column[far[0]]) for column in xyz], 1).tolist()
        raise DataFormatError(path, f"{len(far)} point(s) lie beyond {MAX_COORDINATE_M:g} m, the first is point "
                                    f"{far[0]} (counting from 0) at {first} m: no LiDAR return is that far, so the "
                                    "file is damaged (copy it again from the recorder) or not in metres (convert it)")
    kept = int(valid.sum())
    keep = slice(None) if kept == len(valid) else valid
    points = np.empty((kept, 4), np.float32)
    for k, column in enumerate([*xyz, intensity]):
        points[:, k] = column[keep]
    time = time[keep] if time_name else None
    if time_unit_s is not None:
        _check_time_unit(path, fields, time_name, time, time_unit_s)
    return LoadedCloud(points=points, time=time, dropped=len(valid) - kept, has_intensity=intensity_name is not None,
                       time_unit_s=time_unit_s if time_name else None)


def time_field(names: Iterable[str]) -> str | None:
    """The name of the per-point time column among `names`: the first of TIME_FIELDS there (case-insensitive), or
    None."""
    lower = {name.lower(): name for name in names}
    return next((lower[name] for name in TIME_FIELDS if name in lower), None)


def _check_time_unit(path, fields: dict, time_name: str | None, time: np.ndarray | None, time_unit_s: float) -> None:
    """DataFormatError unless the cloud has a time field whose valid points span at most MAX_FRAME_SPAN_S."""
    if time_name is None:
        raise DataFormatError(path, f"a time unit was given (--time-unit) but the file has no time field (one of "
                                    f"{', '.join(TIME_FIELDS)}; it has {', '.join(fields)}): drop --time-unit")
    span_s = float(np.ptp(time)) * time_unit_s if len(time) else 0.0
    if span_s > MAX_FRAME_SPAN_S:
        unit = next((name for name, seconds in TIME_UNITS.items() if seconds == time_unit_s), f"{time_unit_s:g} s")
        smaller = [name for name, seconds in TIME_UNITS.items() if seconds < time_unit_s]
        fix = (f"the recorder writes a smaller unit (try --time-unit {' or '.join(smaller)})" if smaller else
               "these are no times within one frame (check the file's time field)")
        raise DataFormatError(path, f"its points' {time_name!r} spans {span_s:.4g} s in unit {unit}, more than a "
                                    f"frame's {MAX_FRAME_SPAN_S:g} s: {fix}")


# ---------------------------------------------------------------- PCD
_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8",
              ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}


def read_pcd_fields(path: Path) -> dict[str, np.ndarray]:
    """Columns of a PCL .pcd file (DATA ascii, binary or binary_compressed) as {name: (N,) array}."""
    raw = path.read_bytes()
    header: dict[str, list[str]] = {}
    lines: dict[str, int] = {}  # header keyword -> its line number
    offset, line_no = 0, 0
    while "DATA" not in header:
        end = raw.find(b"\n", offset)
        if end < 0:
            raise DataFormatError(path, "PCD header ends before its DATA line; the file is truncated or not a PCD")
        line_no += 1
        words = raw[offset:end].decode("ascii", errors="replace").split()
        offset = end + 1
        if words and not words[0].startswith("#"):
            header[words[0].upper()], lines[words[0].upper()] = words[1:], line_no
    try:
        names = header["FIELDS"]
        sizes = [int(s) for s in header["SIZE"]]
        types = [t.upper() for t in header["TYPE"]]
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(names))]
        encoding = header["DATA"][0].lower()
    except (KeyError, IndexError, ValueError) as error:
        raise DataFormatError(path, f"PCD header lacks or mangles {error}; it needs FIELDS, SIZE, TYPE, POINTS, DATA")
    if min(counts, default=1) < 1:
        raise DataFormatError(path, f"PCD header: COUNT {' '.join(header['COUNT'])} must be >= 1", lines["COUNT"])
    n_points = _pcd_point_count(path, header, lines)
    if not len(names) == len(sizes) == len(types) == len(counts):
        raise DataFormatError(path, "PCD header: FIELDS, SIZE, TYPE and COUNT have different lengths")
    if any((t, s) not in _PCD_TYPES for t, s in zip(types, sizes)):
        raise DataFormatError(path, f"PCD header: unsupported TYPE/SIZE pair in {list(zip(types, sizes))}")
    columns = [(name, _PCD_TYPES[t, s], c) for name, t, s, c in zip(names, types, sizes, counts)]
    dtype = np.dtype([(f"{i}_{name}", "<" + code, (c,)) for i, (name, code, c) in enumerate(columns)])
    body = raw[offset:]

    if encoding == "ascii":
        table = _parse_ascii(path, _text_rows(body), sum(counts), n_points, line_no)
        starts = np.cumsum([0] + counts[:-1])
        return {name: table[:, start].astype(code) for (name, code, count), start in zip(columns, starts)
                if count == 1 and name != "_"}
    if encoding == "binary":
        if len(body) < n_points * dtype.itemsize:
            raise DataFormatError(path, f"binary PCD body has {len(body)} bytes, {n_points} points need "
                                        f"{n_points * dtype.itemsize}: the file is truncated")
        records = np.frombuffer(body, dtype=dtype, count=n_points)
    elif encoding == "binary_compressed":
        records = _decompress_pcd(path, body, dtype, columns, n_points)
    else:
        raise DataFormatError(path, f"unknown PCD DATA encoding {encoding!r}; expected ascii, binary or "
                                    "binary_compressed")
    return {name: records[key][:, 0] for key, (name, _, count) in zip(dtype.names, columns)
            if count == 1 and name != "_"}


def _pcd_point_count(path: Path, header: dict[str, list[str]], lines: dict[str, int]) -> int:
    """POINTS, which must equal WIDTH x HEIGHT when those are given (WIDTH x HEIGHT without POINTS); every count
    a non-negative integer. Errors name the header line."""
    counts = {}
    for key in ("WIDTH", "HEIGHT", "POINTS"):
        if key in header:
            words = header[key]
            if len(words) != 1 or not words[0].isdecimal():
                raise DataFormatError(path, f"PCD header: {key} {' '.join(words)!r} must be one integer >= 0",
                                      lines[key])
            counts[key] = int(words[0])
    if "WIDTH" in counts and "HEIGHT" in counts:
        grid = counts["WIDTH"] * counts["HEIGHT"]
        if counts.setdefault("POINTS", grid) != grid:
            raise DataFormatError(path, f"PCD header: POINTS {counts['POINTS']} differs from WIDTH x HEIGHT = "
                                        f"{counts['WIDTH']} x {counts['HEIGHT']} = {grid}; fix the header so they "
                                        "agree", lines["POINTS"])
    if "POINTS" not in counts:
        raise DataFormatError(path, "PCD header has neither POINTS nor WIDTH and HEIGHT")
    return counts["POINTS"]


def _text_rows(body: bytes) -> list[str]:
    """Non-empty lines of an ascii body."""
    return [line for line in body.decode("ascii", errors="replace").splitlines() if line.strip()]


def _parse_ascii(path: Path, lines: list[str], n_values: int, n_rows: int, first_line: int) -> np.ndarray:
    """(n_rows, n_values) float64 table from the first `n_rows` of `lines`; errors name the file's line."""
    if len(lines) < n_rows:
        raise DataFormatError(path, f"ascii body has {len(lines)} lines, the header promises {n_rows} rows: truncated")
    table = np.empty((n_rows, n_values), np.float64)
    for row, line in enumerate(lines[:n_rows]):
        words = line.split()
        try:
            if len(words) != n_values:
                raise ValueError(f"{len(words)} values, the header declares {n_values}")
            table[row] = [float(w) for w in words]
        except ValueError as error:
            raise DataFormatError(path, f"bad row: {error}", line=first_line + row + 1) from None
    return table


def _decompress_pcd(path: Path, body: bytes, dtype: np.dtype, columns: list, n_points: int) -> np.ndarray:
    """Records of a binary_compressed body: uint32 compressed and raw sizes, then LZF of the column-major data."""
    import lzf

    if len(body) < 8:
        raise DataFormatError(path, "binary_compressed PCD body is shorter than its 8-byte size prefix: truncated")
    compressed_size, raw_size = np.frombuffer(body[:8], "<u4")
    if raw_size != n_points * dtype.itemsize:
        raise DataFormatError(path, f"binary_compressed PCD: uncompressed size {raw_size} does not match "
                                    f"{n_points} points x {dtype.itemsize} bytes")
    if len(body) - 8 < compressed_size:
        raise DataFormatError(path, f"binary_compressed PCD: {len(body) - 8} of {compressed_size} compressed bytes "
                                    "present: the file is truncated")
    try:
        raw = lzf.decompress(body[8:8 + int(compressed_size)], int(raw_size)) if raw_size else b""
    except ValueError:
        raw = None
    if raw is None or len(raw) != raw_size:
        raise DataFormatError(path, "binary_compressed PCD: the LZF data is corrupt")
    records = np.empty(n_points, dtype=dtype)
    start = 0
    for key, (_, code, count) in zip(dtype.names, columns):
        size = n_points * count * np.dtype(code).itemsize
        records[key] = np.frombuffer(raw[start:start + size], "<" + code).reshape(n_points, count)
        start += size
    return records


# ---------------------------------------------------------------- PLY
_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def read_ply_fields(path: Path) -> dict[str, np.ndarray]:
    """Columns of the `vertex` element of a .ply file (ascii or binary) as {name: (N,) array}."""
    raw = path.read_bytes()
    if not raw.startswith(b"ply"):
        raise DataFormatError(path, "not a PLY file: it does not start with 'ply'", line=1)
    end = raw.find(b"end_header")
    if end < 0:
        raise DataFormatError(path, "PLY header has no end_header line: the file is truncated")
    body_start = raw.find(b"\n", end) + 1
    encoding, elements = None, []  # elements: [name, count, [(property, dtype code)]]
    for line_no, line in enumerate(raw[:end].decode("ascii", errors="replace").splitlines(), start=1):
        words = line.split()
        if not words or words[0] in ("ply", "comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) >= 2:
            encoding = words[1]
        elif words[0] == "element" and len(words) == 3:
            if not words[2].isdigit():
                raise DataFormatError(path, f"element {words[1]!r} has count {words[2]!r}: a PLY element count is a "
                                            "whole number >= 0", line_no)
            elements.append([words[1], int(words[2]), []])
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in _PLY_TYPES:
            elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        elif words[0] == "property" and elements and words[1] == "list":
            raise DataFormatError(path, f"list property {words[-1]!r} in element {elements[-1][0]!r} is not "
                                        "supported; keep only the vertex element (a point cloud, not a mesh)", line_no)
        else:
            raise DataFormatError(path, f"unexpected PLY header line {line!r}", line_no)
    if encoding not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise DataFormatError(path, f"unknown PLY format {encoding!r}")
    body, header_lines = raw[body_start:], raw[:body_start].count(b"\n")
    lines = _text_rows(body) if encoding == "ascii" else []
    for name, count, properties in elements:
        if encoding == "ascii":
            table = _parse_ascii(path, lines, len(properties), count, header_lines)
            if name == "vertex":
                return {prop: table[:, i].astype(code) for i, (prop, code) in enumerate(properties)}
            lines, header_lines = lines[count:], header_lines + count
            continue
        order = "<" if encoding == "binary_little_endian" else ">"
        dtype = np.dtype([(prop, order + code) for prop, code in properties])
        if len(body) < count * dtype.itemsize:
            raise DataFormatError(path, f"PLY element {name!r} needs {count * dtype.itemsize} bytes, {len(body)} "
                                        "are left: the file is truncated")
        if name == "vertex":
            records = np.frombuffer(body, dtype=dtype, count=count)
            return {prop: records[prop].astype(code) for prop, code in properties}
        body = body[count * dtype.itemsize:]
    raise DataFormatError(path, "PLY file has no vertex element")


# ---------------------------------------------------------------- NPY and KITTI BIN
def read_npy_fields(path: Path) -> dict[str, np.ndarray]:
    """Columns of a .npy file: a structured array with named fields, or (N, 3|4|5) x, y, z[, intensity[, time]]."""
    try:
        array = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as error:
        raise DataFormatError(path, f"not a readable .npy array ({error})") from None
    if array.dtype.names:
        return {name: array[name].reshape(-1) for name in array.dtype.names if array[name].ndim == 1}
    if array.dtype.kind not in "iuf":
        raise DataFormatError(path, f"array of {array.dtype} values; a point cloud holds numbers (float or integer "
                                    "x, y, z[, intensity[, time]])")
    if array.ndim != 2 or array.shape[1] not in (3, 4, 5):
        raise DataFormatError(path, f"array of shape {array.shape}; expected (N, 3|4|5) x, y, z[, intensity[, time]]")
    return dict(zip(("x", "y", "z", "intensity", "time"), array.T))


def read_bin_fields(path: Path) -> dict[str, np.ndarray]:
    """Columns of a KITTI .bin file: float32 x, y, z, intensity per point."""
    raw = path.read_bytes()
    if raw.startswith(b"\x1f\x8b"):
        raise DataFormatError(path, "a gzip stream, not float32 points: a Blickfeld recording renamed to .bin? Give it "
                                    "its .bfpc name (or --format bfpc)")
    if len(raw) % 16:
        raise DataFormatError(path, f"{len(raw)} bytes is not a multiple of 16 (4 float32 per point): truncated "
                                    "or not a KITTI velodyne file")
    return dict(zip(("x", "y", "z", "intensity"), np.frombuffer(raw, "<f4").reshape(-1, 4).T))
