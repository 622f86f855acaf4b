"""PCD (v0.7) reading and writing with numpy.

Written by hand rather than through `open3d.t.io` because Open3D cannot write an empty
cloud (a radar frame with no detection is a valid frame), reorders fields, takes ~18 ms to
read a 15k-point frame (numpy: well under 1 ms), and on a corrupt file only logs a warning
and returns an empty cloud. Here a bad file raises `PcdError` naming the file and what was
wrong. `binary_compressed` files (written by PCL/Open3D) are delegated to Open3D.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

_TYPES = {("F", 4): np.float32, ("F", 8): np.float64, ("I", 1): np.int8, ("I", 2): np.int16, ("I", 4): np.int32,
          ("I", 8): np.int64, ("U", 1): np.uint8, ("U", 2): np.uint16, ("U", 4): np.uint32, ("U", 8): np.uint64}
_CODES = {np.dtype(v): k for k, v in _TYPES.items()}
_HEADER_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")


_UMASK = os.umask(0)
os.umask(_UMASK)


class PcdError(ValueError):
    """A PCD file is unreadable; the message names the file and the problem."""


def write_pcd(path: str | Path, points: np.ndarray, fields: dict[str, np.ndarray]) -> None:
    """Write points (N,3) and per-point scalar fields as binary PCD, atomically."""
    points = np.asarray(points)
    n = len(points)
    columns: dict[str, np.ndarray] = {
        "x": points[:, 0].astype(np.float32) if n else np.zeros(0, np.float32),
        "y": points[:, 1].astype(np.float32) if n else np.zeros(0, np.float32),
        "z": points[:, 2].astype(np.float32) if n else np.zeros(0, np.float32),
    }
    for name, values in fields.items():
        v = np.asarray(values).reshape(-1)
        if len(v) != n:
            raise ValueError(f"field {name!r} has {len(v)} values for {n} points")
        columns[name] = v
    dtype = np.dtype([(k, v.dtype) for k, v in columns.items()])
    for k, v in columns.items():
        if v.dtype not in _CODES:
            raise ValueError(f"field {k!r}: dtype {v.dtype} has no PCD type")
    rec = np.empty(n, dtype=dtype)
    for k, v in columns.items():
        rec[k] = v
    header = "\n".join(
        [
            "# .PCD v0.7 - Point Cloud Data file format (boomtip)",
            "VERSION 0.7",
            "FIELDS " + " ".join(columns),
            "SIZE " + " ".join(str(_CODES[v.dtype][1]) for v in columns.values()),
            "TYPE " + " ".join(_CODES[v.dtype][0] for v in columns.values()),
            "COUNT " + " ".join("1" for _ in columns),
            f"WIDTH {n}",
            "HEIGHT 1",
            "VIEWPOINT 0 0 0 1 0 0 0",
            f"POINTS {n}",
            "DATA binary",
        ]
    )
    atomic_write_bytes(Path(path), header.encode() + b"\n" + rec.tobytes())


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write via a temporary file in the same folder and rename, so a reader never sees half a file."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; outputs get the usual permissions
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def read_pcd(path: str | Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Read a PCD file: points (N,3) float64 and the other fields as 1-D arrays."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise PcdError(f"{path}: cannot read: {exc.strerror}") from None
    header: dict[str, list[str]] = {}
    pos = 0
    line_no = 0
    while "DATA" not in header:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise PcdError(f"{path}: header ends before a DATA line (is this a PCD file?)")
        line_no += 1
        try:
            line = raw[pos:end].decode("ascii").strip()
        except UnicodeDecodeError:
            raise PcdError(f"{path}: line {line_no}: header is not ASCII text (is this a PCD file?)") from None
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        if key not in _HEADER_KEYS:
            raise PcdError(f"{path}: line {line_no}: unknown header key {key!r}; expected one of {', '.join(_HEADER_KEYS)}")
        header[key] = vals
    for key in ("FIELDS", "SIZE", "TYPE", "POINTS"):
        if key not in header:
            raise PcdError(f"{path}: header has no {key} line")
    names = header["FIELDS"]
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(names))]
    if not (len(names) == len(header["SIZE"]) == len(header["TYPE"]) == len(counts)):
        raise PcdError(f"{path}: FIELDS, SIZE, TYPE and COUNT list different numbers of fields")
    try:
        dtype = np.dtype(
            [(n, _TYPES[(t, int(s))], (c,)) if c > 1 else (n, _TYPES[(t, int(s))])
             for n, s, t, c in zip(names, header["SIZE"], header["TYPE"], counts)]
        )
        n_points = int(header["POINTS"][0])
    except (KeyError, ValueError) as exc:
        raise PcdError(f"{path}: unsupported field type or count in header ({exc})") from None
    kind = header["DATA"][0] if header["DATA"] else ""
    if kind == "binary":
        need = n_points * dtype.itemsize
        if len(raw) - pos < need:
            raise PcdError(f"{path}: truncated: header says {n_points} points ({need} bytes), file has {len(raw) - pos} data bytes")
        rec = np.frombuffer(raw, dtype=dtype, count=n_points, offset=pos)
    elif kind == "ascii":
        try:
            table = np.loadtxt(raw[pos:].decode("ascii").splitlines(), ndmin=2) if n_points else np.zeros((0, len(names)))
        except ValueError as exc:
            raise PcdError(f"{path}: ascii data does not parse: {exc}") from None
        if table.shape[0] != n_points:
            raise PcdError(f"{path}: header says {n_points} points, ascii data has {table.shape[0]} rows")
        rec = np.empty(n_points, dtype=dtype)
        for i, n in enumerate(names):
            rec[n] = table[:, i]
    elif kind == "binary_compressed":
        return _read_with_open3d(path)
    else:
        raise PcdError(f"{path}: DATA {kind!r}: expected ascii, binary or binary_compressed")
    for axis in "xyz":
        if axis not in names:
            raise PcdError(f"{path}: no '{axis}' field; fields are {names}")
    points = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float64)
    fields = {n: np.array(rec[n]) for n in names if n not in ("x", "y", "z")}
    return points, fields


def _read_with_open3d(path: Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    import open3d as o3d

    pc = o3d.t.io.read_point_cloud(str(path))
    if pc.is_empty():
        raise PcdError(f"{path}: Open3D could not read this binary_compressed PCD")
    points = pc.point.positions.numpy().astype(np.float64)
    fields = {k: pc.point[k].numpy().reshape(len(points), -1).squeeze(-1) for k in pc.point if k != "positions"}
    return points, fields
