"""The PCD reader under fuzzing: random bytes, valid headers with random data, mutated header
tokens and structured ascii raise nothing but PcdError (fixed seed and budget); the layouts
real tools write (PCL padding, COUNT > 1, binary_compressed with any fields) are read."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from boomtip.data.io.pcd import PcdError, lzf_decompress, read_pcd, write_pcd

FUZZ = settings(max_examples=250, derandomize=True, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _read_bytes(tmp_path, data: bytes):
    p = tmp_path / "f.pcd"
    p.write_bytes(data)
    try:
        read_pcd(p)
    except PcdError:
        pass


def _header(fields, sizes, types, counts, n, kind):
    return ("VERSION 0.7\nFIELDS " + " ".join(fields) + "\nSIZE " + " ".join(map(str, sizes)) + "\nTYPE " + " ".join(types)
            + "\nCOUNT " + " ".join(map(str, counts)) + f"\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {kind}\n").encode()


@FUZZ
@given(st.binary(max_size=400))
def test_random_bytes(tmp_path, data):
    _read_bytes(tmp_path, data)


FIELD = st.tuples(st.sampled_from(["_", "intensity", "rgb", "t", "x"]), st.sampled_from([(4, "F"), (8, "F"), (1, "U"),
                  (2, "U"), (4, "I"), (3, "F"), (4, "Q")]), st.integers(0, 3))


@FUZZ
@given(st.lists(FIELD, max_size=4), st.integers(0, 40), st.sampled_from(["binary", "ascii", "binary_compressed", "foo"]),
       st.binary(max_size=600))
def test_valid_looking_headers_with_random_data(tmp_path, extra, n, kind, payload):
    """x y z first (so the data paths are reached), then random fields, sizes, types, counts."""
    fields = ["x", "y", "z"] + [f for f, _, _ in extra]
    sizes = [4, 4, 4] + [s for _, (s, _), _ in extra]
    types = ["F", "F", "F"] + [t for _, (_, t), _ in extra]
    counts = [1, 1, 1] + [c for _, _, c in extra]
    _read_bytes(tmp_path, _header(fields, sizes, types, counts, n, kind) + payload)


@FUZZ
@given(st.integers(0, 9), st.sampled_from(["", "-1", "1.5", "abc", "99999999999", "0", "2 2", "nan"]))
def test_mutated_header_tokens(tmp_path, line, token):
    lines = _header(["x", "y", "z", "intensity"], [4, 4, 4, 4], ["F"] * 4, [1] * 4, 3, "ascii").decode().splitlines()
    key = lines[line].split()[0]
    lines[line] = f"{key} {token}"
    data = "\n".join(lines) + "\n" + "1 2 3 4\n5 6 7 8\n9 10 11 12\n"
    _read_bytes(tmp_path, data.encode())


@FUZZ
@given(st.lists(st.lists(st.sampled_from(["1", "-2.5", "1e400", "nan", "x", "", "3e38", "1e9"]), max_size=6), max_size=6))
def test_structured_ascii(tmp_path, rows):
    body = "\n".join(" ".join(r) for r in rows)
    _read_bytes(tmp_path, _header(["x", "y", "z", "label"], [4, 4, 4, 2], ["F", "F", "F", "U"], [1] * 4, len(rows), "ascii")
                + body.encode() + b"\n")


def test_pcl_padding_and_count_fields_are_read(tmp_path):
    """pcl_ros bag_to_pcd's PointXYZI: x y z _ intensity _ _ _ with 4-byte pads; a COUNT-3 normal."""
    n = 5
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("p0", "<u4"), ("intensity", "<f4"), ("p1", "<u4", (3,)),
                   ("normal", "<f4", (3,))])
    rec = np.zeros(n, dt)
    rec["x"], rec["intensity"], rec["normal"] = np.arange(n), 10 + np.arange(n), np.ones((n, 3))
    head = _header(["x", "y", "z", "_", "intensity", "_", "normal"], [4, 4, 4, 4, 4, 4, 4], ["F", "F", "F", "U", "F", "U", "F"],
                   [1, 1, 1, 1, 1, 3, 3], n, "binary")
    (tmp_path / "pad.pcd").write_bytes(head + rec.tobytes())
    pts, fields = read_pcd(tmp_path / "pad.pcd")
    np.testing.assert_array_equal(pts[:, 0], np.arange(n))
    assert set(fields) == {"intensity", "normal"} and fields["normal"].shape == (n, 3)
    np.testing.assert_array_equal(fields["intensity"], 10 + np.arange(n))


@pytest.mark.parametrize("attrs", [{"intensity": 1}, {"colors": 3}, {"normals": 3}])
def test_open3d_binary_compressed_with_any_fields(tmp_path, attrs):
    o3d = pytest.importorskip("open3d")
    rng = np.random.default_rng(1)
    pc = o3d.t.geometry.PointCloud()
    xyz = rng.random((700, 3)).astype(np.float32)
    pc.point.positions = o3d.core.Tensor(xyz)
    for k, c in attrs.items():
        pc.point[k] = o3d.core.Tensor(rng.random((700, c)).astype(np.float32))
    o3d.t.io.write_point_cloud(str(tmp_path / "c.pcd"), pc, compressed=True)
    assert b"binary_compressed" in (tmp_path / "c.pcd").read_bytes()[:400]
    pts, fields = read_pcd(tmp_path / "c.pcd")
    np.testing.assert_array_equal(pts, xyz.astype(np.float64))
    (name, _), = attrs.items()
    ref = pc.point[name].numpy()
    if name == "colors":  # PCL packs them into one uint32 rgb field
        rgb = fields["rgb"].astype(np.uint32)
        got = np.column_stack([(rgb >> 16) & 255, (rgb >> 8) & 255, rgb & 255]) / 255.0
        np.testing.assert_allclose(got, ref, atol=1 / 255 + 1e-6)
    else:  # the attribute's values, field by field (normal_x, normal_y, normal_z / intensity)
        got = np.column_stack([fields[k] for k in sorted(fields)])
        np.testing.assert_allclose(got, ref, rtol=1e-6)


def test_the_fallback_lzf_matches_the_extension():
    lzf = pytest.importorskip("lzf")
    import builtins
    import sys

    data = np.random.default_rng(2).integers(0, 4, 20000).astype(np.uint8).tobytes() * 3
    comp = lzf.compress(data)
    saved = sys.modules.pop("lzf")
    real_import = builtins.__import__

    def no_lzf(name, *a, **k):
        if name == "lzf":
            raise ImportError("hidden")
        return real_import(name, *a, **k)

    builtins.__import__ = no_lzf
    try:
        assert lzf_decompress(comp, len(data)) == data
        with pytest.raises(PcdError):
            lzf_decompress(comp[: len(comp) // 2] + b"\xff\xff", len(data))
    finally:
        builtins.__import__ = real_import
        sys.modules["lzf"] = saved


def test_our_own_frames_round_trip(tmp_path):
    pts = np.random.default_rng(0).normal(size=(50, 3))
    write_pcd(tmp_path / "a.pcd", pts, {"intensity": np.ones(50, np.float32), "label": np.arange(50, dtype=np.uint16)})
    back, fields = read_pcd(tmp_path / "a.pcd")
    np.testing.assert_allclose(back, pts.astype(np.float32))
    assert fields["label"].dtype == np.uint16


def test_a_huge_count_on_any_field_is_a_clear_error(tmp_path):
    """A COUNT numpy cannot lay out as a record (on a field beside x y z) is the file's error,
    which the loaders turn into a missing frame, never a traceback."""
    from boomtip.data.io.pcd import MAX_FIELD_COUNT, PcdError, read_pcd

    p = tmp_path / "huge.pcd"
    p.write_bytes(b"VERSION .7\nFIELDS x y z i\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1000000000000\nWIDTH 1\n"
                  b"HEIGHT 1\nPOINTS 1\nDATA binary\n" + bytes(16))
    with pytest.raises(PcdError, match=f"field 'i': COUNT 1000000000000; expected 1 to {MAX_FIELD_COUNT}"):
        read_pcd(p)
