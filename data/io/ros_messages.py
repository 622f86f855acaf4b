"""ROS message contents <-> boomtip arrays, as pure functions (no bag, no typestore).

PointCloud2 is decoded with one numpy structured dtype built from its `fields` (offsets,
datatypes, counts, `point_step` padding, `row_step` row padding, endianness): no loop over
points. Imu orientation and body rates map to the MRU log's Euler angles and Euler-angle
rates (R = Rz(yaw) Ry(pitch) Rx(roll), the convention of every boomtip MRU log).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

# sensor_msgs/PointField datatypes
POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
DTYPE_POINTFIELD = {np.dtype(v).str[1:]: k for k, v in POINTFIELD_DTYPES.items()}
# velocity fields radar drivers publish, in the order they are tried
RADAR_VELOCITY_FIELDS = ("range_rate", "doppler", "radial_velocity", "velocity", "v_r", "vr", "v_doppler")
LIDAR_TIME_FIELDS = ("t", "time", "timestamp", "time_offset", "offset_time")


class CloudError(ValueError):
    """A PointCloud2 message is malformed; the message says how."""


def cloud_dtype(fields: list[tuple[str, int, int, int]], point_step: int, big_endian: bool) -> np.dtype:
    """Structured dtype of one point from (name, offset, datatype, count) fields; padding
    fields (named '' or '_') and unknown datatypes are left out."""
    names, formats, offsets = [], [], []
    order = ">" if big_endian else "<"
    for name, offset, datatype, count in fields:
        if not name or name.strip("_") == "" or datatype not in POINTFIELD_DTYPES or name in names:
            continue
        size = np.dtype(POINTFIELD_DTYPES[datatype]).itemsize * max(count, 1)
        if offset < 0 or offset + size > point_step:
            raise CloudError(f"field {name!r} at offset {offset} ({size} bytes) overruns point_step {point_step}")
        names.append(name)
        formats.append((order + POINTFIELD_DTYPES[datatype], (count,)) if count > 1 else order + POINTFIELD_DTYPES[datatype])
        offsets.append(offset)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})


def decode_cloud(fields: list[tuple[str, int, int, int]], data: np.ndarray | bytes, height: int, width: int,
                 point_step: int, row_step: int, big_endian: bool = False) -> np.ndarray:
    """The points of a PointCloud2 as a structured array (height * width,)."""
    if point_step <= 0 or height < 0 or width < 0 or row_step < width * point_step:
        raise CloudError(f"point_step {point_step}, row_step {row_step} for width {width}: inconsistent")
    buf = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.view(np.uint8).ravel()
    if buf.size < height * row_step:
        raise CloudError(f"{buf.size} data bytes for {height} rows of {row_step}: truncated")
    dtype = cloud_dtype(fields, point_step, big_endian)
    if not {"x", "y", "z"} <= set(dtype.names or ()):
        raise CloudError(f"fields {[f[0] for f in fields]}: no x, y, z")
    for name in ("x", "y", "z"):
        sub = dtype.fields[name][0]
        if sub.shape != () or sub.kind != "f":
            raise CloudError(f"field {name!r} is {sub.base.name}{list(sub.shape) or ''}: expected one float (metres) "
                             "per point")
    if height == 0 or width == 0:
        return np.zeros(0, dtype=dtype)
    rows = buf[: height * row_step].reshape(height, row_step)[:, : width * point_step]
    return np.ascontiguousarray(rows).reshape(-1).view(dtype)


def encode_cloud(points: np.ndarray, fields: dict[str, np.ndarray]) -> tuple[list[tuple[str, int, int, int]], bytes, int]:
    """(fields, data, point_step) of an unorganised little-endian PointCloud2: x y z float32,
    then each scalar field in its own dtype."""
    n = len(points)
    columns = {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2]} if n else {k: np.zeros(0) for k in "xyz"}
    columns = {k: np.asarray(v, np.float32) for k, v in columns.items()}
    for name, v in fields.items():
        v = np.asarray(v)
        columns[name] = v if v.dtype.str[1:] in DTYPE_POINTFIELD else v.astype(np.float32)
    dtype = np.dtype([(k, "<" + v.dtype.str[1:]) for k, v in columns.items()])
    arr = np.empty(n, dtype=dtype)
    for k, v in columns.items():
        arr[k] = v
    spec = [(k, dtype.fields[k][1], DTYPE_POINTFIELD[dtype.fields[k][0].str[1:]], 1) for k in dtype.names]
    return spec, arr.tobytes(), dtype.itemsize


def cloud_to_frame(cloud: np.ndarray, sensor: str, velocity_field: str = "", velocity_sign: float = 1.0,
                   stamp_s: float = 0.0) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Points (N,3) float64, sensor frame, and boomtip's per-point fields. Points with a
    non-finite coordinate (an organised cloud's no-returns) are dropped. A radar's velocity
    field becomes `range_rate` (m/s, positive receding) times `velocity_sign`; a LiDAR's time
    field becomes `t`, s from the frame stamp (integer fields are ns, as Ouster's driver writes)."""
    xyz = np.column_stack([cloud["x"], cloud["y"], cloud["z"]]).astype(np.float64)
    keep = np.isfinite(xyz).all(axis=1)
    xyz = xyz[keep]
    names = cloud.dtype.names or ()
    fields: dict[str, np.ndarray] = {}
    if sensor == "lidar":
        for name in ("intensity", "reflectivity", "i"):
            if name in names and cloud[name].ndim == 1:
                fields["intensity"] = cloud[name][keep].astype(np.float32)
                break
        tname = next((n for n in LIDAR_TIME_FIELDS if n in names and cloud[n].ndim == 1), None)
        if tname is not None:
            t = cloud[tname][keep].astype(np.float64)
            med = float(np.nanmedian(t)) if len(t) else 0.0
            # integers are ns (Ouster's driver); so are floats beyond 1e15 (Livox's absolute ns)
            if cloud[tname].dtype.kind in "iu" or med > 1e15:
                t, med = t * 1e-9, med * 1e-9
            if med > 1e6:  # absolute time stamps (s since the epoch)
                t = t - stamp_s
            if len(t) and np.nanmax(np.abs(t)) <= 10.0:  # else not a per-point time offset: left out
                fields["t"] = t.astype(np.float32)
        if "label" in names:
            fields["label"] = cloud["label"][keep]
        return xyz, fields
    vname = velocity_field or next((n for n in RADAR_VELOCITY_FIELDS if n in names), "")
    for name in {vname, "range", "azimuth", "elevation"} & set(names):
        if cloud[name].ndim != 1:
            raise CloudError(f"radar field {name!r} has {cloud[name].shape[1]} values per point; expected one")
    if vname:
        if vname not in names:
            raise CloudError(f"radar velocity field {vname!r} not in the cloud's fields {list(names)}")
        fields["range_rate"] = (velocity_sign * cloud[vname][keep].astype(np.float64)).astype(np.float32)
    rng = np.sqrt(np.einsum("ij,ij->i", xyz, xyz))
    fields["range"] = cloud["range"][keep].astype(np.float32) if "range" in names else rng.astype(np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        fields["azimuth"] = (cloud["azimuth"][keep] if "azimuth" in names else np.arctan2(xyz[:, 1], xyz[:, 0])).astype(np.float32)
        el = np.arcsin(np.clip(xyz[:, 2] / np.where(rng > 0, rng, 1.0), -1, 1))
        fields["elevation"] = (cloud["elevation"][keep] if "elevation" in names else el).astype(np.float32)
    if "label" in names:
        fields["label"] = cloud["label"][keep]
    return xyz, fields


# --- attitude -------------------------------------------------------------------------------

def _euler_rate_matrix(rpy: np.ndarray) -> np.ndarray:
    """(N,3,3) E with body rates w = E @ [roll_dot, pitch_dot, yaw_dot] for R = Rz Ry Rx."""
    r, p = rpy[:, 0], rpy[:, 1]
    sr, cr, sp, cp = np.sin(r), np.cos(r), np.sin(p), np.cos(p)
    E = np.zeros((len(rpy), 3, 3))
    E[:, 0, 0], E[:, 0, 2] = 1.0, -sp
    E[:, 1, 1], E[:, 1, 2] = cr, sr * cp
    E[:, 2, 1], E[:, 2, 2] = -sr, cr * cp
    return E


def imu_from_mru(rpy_rad: np.ndarray, rpy_rate_radps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quaternions (N,4) x y z w and body angular velocities (N,3) of an MRU log."""
    quat = Rotation.from_euler("ZYX", rpy_rad[:, ::-1]).as_quat()
    omega = np.einsum("nij,nj->ni", _euler_rate_matrix(rpy_rad), rpy_rate_radps)
    return quat, omega


def mru_from_imu(quat_xyzw: np.ndarray, omega_body_radps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Euler angles (N,3) roll pitch yaw and their rates (N,3) of Imu orientations and body
    angular velocities; the rates are NaN where pitch is +-90 deg (no Euler rates there)."""
    rpy = Rotation.from_quat(quat_xyzw).as_euler("ZYX")[:, ::-1]
    E = _euler_rate_matrix(rpy)
    ok = np.abs(np.cos(rpy[:, 1])) > 1e-6
    rates = np.full_like(rpy, np.nan)
    if ok.any():
        rates[ok] = np.linalg.solve(E[ok], omega_body_radps[ok][:, :, None])[:, :, 0]
    return rpy, rates
