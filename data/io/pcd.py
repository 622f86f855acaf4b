"""PCD (v0.7) reading and writing with numpy.

Written by hand rather than through `open3d.t.io` because Open3D cannot write an empty
cloud (a radar frame with no detection is a valid frame), reorders fields, reads a frame
an order of magnitude slower than numpy, and on a corrupt file only logs a warning and
returns an empty cloud. Here a bad file raises `PcdError` naming the file and what was
wrong, and `binary_compressed` files (PCL, Open3D) are decoded here too (Open3D's tensor
reader aborts the whole process on the padding fields `pcl_ros` writes).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from boomtip.data.io.atomic import atomic_write_bytes

_TYPES = {("F", 4): np.float32, ("F", 8): np.float64, ("I", 1): np.int8, ("I", 2): np.int16, ("I", 4): np.int32,
          ("I", 8): np.int64, ("U", 1): np.uint8, ("U", 2): np.uint16, ("U", 4): np.uint32, ("U", 8): np.uint64}
_CODES = {np.dtype(v): k for k, v in _TYPES.items()}
_HEADER_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")


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


MAX_POINTS = 50_000_000  # a frame of a 128 x 2048 LiDAR at 2 returns is 0.5 M; beyond this is a corrupt header
MAX_FIELD_COUNT = 1 << 16  # values per point in one field (PCL's histograms have a few hundred)


def _ints(path: Path, key: str, vals: list[str], line_no: int) -> list[int]:
    try:
        out = [int(v) for v in vals]
    except ValueError:
        raise PcdError(f"{path}: line {line_no}: {key} must be whole numbers, got {' '.join(vals)!r}") from None
    if any(v < 0 for v in out):
        raise PcdError(f"{path}: line {line_no}: {key} must be >= 0, got {' '.join(vals)!r}")
    return out


def _parse_header(path: Path, raw: bytes) -> tuple[dict[str, list[str]], dict[str, int], int]:
    header: dict[str, list[str]] = {}
    lines: dict[str, int] = {}
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
        if key in header:
            raise PcdError(f"{path}: line {line_no}: {key} given twice")
        header[key], lines[key] = vals, line_no
    for key in ("FIELDS", "SIZE", "TYPE", "POINTS"):
        if key not in header:
            raise PcdError(f"{path}: header has no {key} line")
    return header, lines, pos


def _layout(path: Path, header: dict[str, list[str]], lines: dict[str, int]):
    """The record dtype (padding `_` fields kept under unique names), the kept field names,
    their counts, and the number of points."""
    names = header["FIELDS"]
    if not names:
        raise PcdError(f"{path}: line {lines['FIELDS']}: FIELDS lists no field")
    sizes = _ints(path, "SIZE", header["SIZE"], lines["SIZE"])
    counts = _ints(path, "COUNT", header["COUNT"], lines["COUNT"]) if "COUNT" in header else [1] * len(names)
    if not (len(names) == len(sizes) == len(header["TYPE"]) == len(counts)):
        raise PcdError(f"{path}: FIELDS, SIZE, TYPE and COUNT list different numbers of fields")
    (n_points,) = _ints(path, "POINTS", header["POINTS"][:1] or ["x"], lines["POINTS"])
    if n_points > MAX_POINTS:
        raise PcdError(f"{path}: line {lines['POINTS']}: POINTS {n_points} is beyond {MAX_POINTS} (corrupt header?)")
    fmt, kept, seen = [], [], set()
    for i, (n, size, t, c) in enumerate(zip(names, sizes, header["TYPE"], counts)):
        if (t, size) not in _TYPES:
            raise PcdError(f"{path}: field {n!r}: TYPE {t} SIZE {size} is not a PCD type (F 4/8, I or U 1/2/4/8)")
        if not 1 <= c <= MAX_FIELD_COUNT:
            raise PcdError(f"{path}: field {n!r}: COUNT {c}; expected 1 to {MAX_FIELD_COUNT}")
        pad = n == "_"  # pcl_ros and PCL's PointXYZI pad records with '_' fields
        key = f"__pad{i}" if pad else n
        if not pad and n in seen:
            raise PcdError(f"{path}: field {n!r} appears twice in FIELDS")
        seen.add(key)
        fmt.append((key, _TYPES[(t, size)], (c,)) if c > 1 else (key, _TYPES[(t, size)]))
        if not pad:
            kept.append((n, c))
    for axis in "xyz":
        if axis not in seen:
            raise PcdError(f"{path}: no '{axis}' field; fields are {names}")
        if dict(kept)[axis] != 1:
            raise PcdError(f"{path}: field '{axis}' has COUNT {dict(kept)[axis]}; expected 1")
    try:
        dtype = np.dtype(fmt)
    except (ValueError, OverflowError) as exc:  # a record numpy cannot lay out
        raise PcdError(f"{path}: fields {names} make no record numpy can lay out ({exc})") from None
    return dtype, kept, n_points


def read_pcd(path: str | Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Read a PCD file: points (N,3) float64 and the other fields as arrays (1-D, or (N, COUNT)
    for a field with COUNT > 1). Any malformed input raises PcdError naming the file."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise PcdError(f"{path}: cannot read: {exc.strerror}") from None
    header, lines, pos = _parse_header(path, raw)
    dtype, kept, n_points = _layout(path, header, lines)
    kind = header["DATA"][0] if header["DATA"] else ""
    if kind == "binary":
        need = n_points * dtype.itemsize
        if len(raw) - pos < need:
            raise PcdError(f"{path}: truncated: header says {n_points} points ({need} bytes), file has {len(raw) - pos} data bytes")
        rec = np.frombuffer(raw, dtype=dtype, count=n_points, offset=pos)
    elif kind == "ascii":
        rec = _ascii(path, raw[pos:], dtype, n_points)
    elif kind == "binary_compressed":
        rec = _binary_compressed(path, raw[pos:], dtype, n_points)
    else:
        raise PcdError(f"{path}: DATA {kind!r}: expected ascii, binary or binary_compressed")
    with np.errstate(over="ignore", invalid="ignore"):
        points = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float64)
    fields = {n: np.array(rec[n]) for n, _ in kept if n not in ("x", "y", "z")}
    return points, fields


def _ascii(path: Path, data: bytes, dtype: np.dtype, n_points: int) -> np.ndarray:
    width = sum(int(np.prod(dtype[k].shape or (1,))) for k in dtype.names)
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError as exc:
        raise PcdError(f"{path}: ascii data: byte {exc.start} is not ASCII") from None
    rows = [r for r in text.splitlines() if r.strip()]
    if len(rows) != n_points:
        raise PcdError(f"{path}: header says {n_points} points, ascii data has {len(rows)} rows")
    try:
        table = np.array([[float(v) for v in r.split()] for r in rows], dtype=float) if rows else np.zeros((0, width))
    except ValueError as exc:
        raise PcdError(f"{path}: ascii data does not parse: {exc}") from None
    if table.ndim != 2 or table.shape[1] != width:
        bad = next((i for i, r in enumerate(rows) if len(r.split()) != width), 0)
        raise PcdError(f"{path}: ascii row {bad + 1} has {len(rows[bad].split())} values; FIELDS and COUNT give {width}")
    rec = np.empty(n_points, dtype=dtype)
    col = 0
    with np.errstate(over="ignore", invalid="ignore"):
        for k in dtype.names:
            c = int(np.prod(dtype[k].shape or (1,)))
            vals = table[:, col:col + c]
            if np.issubdtype(dtype[k].base, np.integer):
                info = np.iinfo(dtype[k].base)
                if not np.all(np.isfinite(vals)) or vals.min(initial=0) < info.min or vals.max(initial=0) > info.max:
                    raise PcdError(f"{path}: ascii field {k!r}: a value does not fit {dtype[k].base}")
            rec[k] = vals.reshape(rec[k].shape)
            col += c
    return rec


def _binary_compressed(path: Path, data: bytes, dtype: np.dtype, n_points: int) -> np.ndarray:
    """PCL's layout: two uint32 sizes, then LZF-compressed data stored field by field (every
    point's x, then every y, ...). Decoded here: Open3D's tensor reader aborts the process on
    padding fields and its legacy one drops custom fields."""
    if len(data) < 8:
        raise PcdError(f"{path}: binary_compressed data is shorter than its 8-byte size header")
    comp_size, raw_size = (int(v) for v in np.frombuffer(data[:8], dtype="<u4"))
    need = n_points * dtype.itemsize
    if raw_size != need:
        raise PcdError(f"{path}: binary_compressed: {raw_size} bytes uncompressed, the header's fields need {need}")
    if comp_size > len(data) - 8:
        raise PcdError(f"{path}: truncated: {comp_size} compressed bytes announced, {len(data) - 8} present")
    flat = lzf_decompress(data[8:8 + comp_size], raw_size) if raw_size else b""
    if len(flat) != raw_size:
        raise PcdError(f"{path}: binary_compressed data does not decompress to {raw_size} bytes")
    rec = np.empty(n_points, dtype=dtype)
    off = 0
    for k in dtype.names:
        sub = dtype[k]
        nbytes = n_points * sub.itemsize
        rec[k] = np.frombuffer(flat, dtype=sub.base, count=n_points * int(np.prod(sub.shape or (1,))), offset=off).reshape(rec[k].shape)
        off += nbytes
    return rec


def lzf_decompress(src: bytes, size: int) -> bytes:
    """LZF (liblzf) decompression: the python-lzf extension when installed, else this format's
    few lines by hand (no library in the project's list has it). Raises PcdError on bad data."""
    try:
        import lzf

        out = lzf.decompress(bytes(src), size)
        if out is None:
            raise PcdError("LZF data does not decompress to the announced size")
        return out
    except ImportError:
        pass
    except ValueError as exc:
        raise PcdError(f"LZF data is corrupt: {exc}") from None
    dst = bytearray()
    i, n = 0, len(src)
    while i < n:
        ctrl = src[i]
        i += 1
        if ctrl < 32:  # a literal run of ctrl + 1 bytes
            if i + ctrl + 1 > n:
                raise PcdError("LZF literal run past the end of the data")
            dst += src[i:i + ctrl + 1]
            i += ctrl + 1
        else:  # a back reference
            length = ctrl >> 5
            if length == 7:
                if i >= n:
                    raise PcdError("LZF back reference past the end of the data")
                length += src[i]
                i += 1
            if i >= n:
                raise PcdError("LZF back reference past the end of the data")
            ref = len(dst) - ((ctrl & 0x1F) << 8) - src[i] - 1
            i += 1
            if ref < 0:
                raise PcdError("LZF back reference before the start of the data")
            for k in range(length + 2):  # may overlap itself: byte by byte
                dst.append(dst[ref + k])
        if len(dst) > size:
            raise PcdError("LZF data decompresses beyond the announced size")
    return bytes(dst)
