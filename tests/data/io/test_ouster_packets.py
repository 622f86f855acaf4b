"""The pcap reader (`data/io/pcap.py`) and the Ouster packet decoder (`data/io/ouster_packets.py`)
on synthetic bytes: both pcap magics and byte orders, IPv4 fragments in any order, link types,
cut and corrupt files, packets of the wrong size or port, the frame batcher's rules; and against
ouster-sdk (a test-only reference, skipped without it) on every decoded UDP profile and on the
shipped captures."""

from __future__ import annotations

import json
import random
import struct
from pathlib import Path

import numpy as np
import pytest

from boomtip.data.io.ouster_metadata import PIXEL_LAYOUTS, parse_metadata
from boomtip.data.io.ouster_packets import (COLUMN_VALID, FrameBatcher, frame_id_difference, index_capture, lidar_frames,
                                            lidar_packets_per_frame, packet_header, packet_layout)
from boomtip.data.io.pcap import (PCAP_MAGIC_MICROSECONDS, PCAP_MAGIC_NANOSECONDS, Ipv4Reassembler, PcapError,
                                  ipv4_fragment, pcap_header, pcap_records, udp_headers, udp_packets)

REAL = Path(__file__).resolve().parents[1] / "real" / "ouster"
CAPTURES = ("OS-1-128_v2.3.0_1024x10_lb_n3", "OS-2-128-U1_v2.3.0_1024x10", "OS-1-32-G_v2.1.1_1024x10")
ETHERNET_MTU_PAYLOAD = 1480  # IPv4 payload bytes per fragment on a 1500-byte MTU (a multiple of 8)


# --- synthetic captures -------------------------------------------------------------------

def ipv4(payload: bytes, ident: int, offset_bytes: int = 0, more: bool = False, protocol: int = 17) -> bytes:
    flags = (0x2000 if more else 0) | (offset_bytes // 8)
    return struct.pack("!BBHHHBBH4s4s", 0x45, 0, 20 + len(payload), ident, flags, 64, protocol, 0,
                       bytes([10, 0, 0, 2]), bytes([10, 0, 0, 1])) + payload


def udp_fragments(payload: bytes, dst_port: int, ident: int, mtu_payload: int = ETHERNET_MTU_PAYLOAD) -> list[bytes]:
    """A UDP datagram as the IPv4 packets a sender fragments it into."""
    datagram = struct.pack("!HHHH", 7502, dst_port, 8 + len(payload), 0) + payload
    pieces = range(0, len(datagram), mtu_payload)
    return [ipv4(datagram[at: at + mtu_payload], ident, at, at + mtu_payload < len(datagram)) for at in pieces]


def ethernet(packet: bytes, vlan: bool = False) -> bytes:
    tag = struct.pack("!HH", 0x8100, 7) if vlan else b""
    return b"\x02" * 6 + b"\x04" * 6 + tag + struct.pack("!H", 0x0800) + packet


def pcap_bytes(frames: list[tuple[int, int, bytes]], magic: int = PCAP_MAGIC_MICROSECONDS, order: str = "<",
               link_type: int = 1) -> bytes:
    """A libpcap file of (seconds, sub-second ticks, link frame) records."""
    out = [struct.pack(order + "IHHiIII", magic, 2, 4, 0, 0, 262144, link_type)]
    for seconds, ticks, frame in frames:
        out.append(struct.pack(order + "IIII", seconds, ticks, len(frame), len(frame)) + frame)
    return b"".join(out)


def read_udp(path: Path) -> list:
    with open(path, "rb") as fh:
        return list(udp_packets(fh, pcap_header(fh.read(24))))


# --- pcap, IPv4, UDP ------------------------------------------------------------------------

@pytest.mark.parametrize("magic, ticks", [(PCAP_MAGIC_MICROSECONDS, 350_216), (PCAP_MAGIC_NANOSECONDS, 350_216_123)])
@pytest.mark.parametrize("order", ["<", ">"])
def test_both_magics_in_either_byte_order_give_the_records_and_their_times(tmp_path, magic, ticks, order):
    payloads = [b"first", b"second datagram"]
    records = [(1650410295 + i, ticks, ethernet(udp_fragments(p, 7502, i)[0])) for i, p in enumerate(payloads)]
    path = tmp_path / "x.pcap"
    path.write_bytes(pcap_bytes(records, magic, order))
    packets = read_udp(path)
    assert [bytes(p.payload) for p in packets] == payloads and {p.destination_port for p in packets} == {7502}
    per_s, tick_s = (1_000_000, 1e-6) if magic == PCAP_MAGIC_MICROSECONDS else (1_000_000_000, 1e-9)
    # ticks counted as one integer, then scaled: ouster-sdk's index (integer microseconds) * 1e-6
    assert [p.capture_time_s for p in packets] == [(s * per_s + ticks) * tick_s for s, _, _ in records]


def test_fragments_reassemble_in_any_order_with_duplicates_and_another_datagram_between(tmp_path):
    big, other = bytes(range(256)) * 35, b"\xab" * 3000  # 8960 and 3000 bytes: 7 and 3 fragments
    first, second = udp_fragments(big, 7502, ident=11), udp_fragments(other, 7502, ident=12)
    arrival = first[:] + second[:] + [first[2], second[0]]  # two duplicates
    random.Random(3).shuffle(arrival)
    path = tmp_path / "x.pcap"
    path.write_bytes(pcap_bytes([(100, i, ethernet(p)) for i, p in enumerate(arrival)]))
    got = [bytes(p.payload) for p in read_udp(path)]
    assert sorted(got, key=len) == [other, big]  # each once, whole


def test_a_datagram_missing_a_fragment_never_comes_out_and_is_given_up():
    fragments = [ipv4_fragment(memoryview(p)) for p in udp_fragments(b"\x01" * 5000, 7502, ident=5)]
    reassembler = Ipv4Reassembler(timeout_s=2.0)
    assert [reassembler.add(f, 0.0) for f in fragments[:1] + fragments[2:]] == [None] * 3
    whole = reassembler.add(ipv4_fragment(memoryview(ipv4(b"x" * 8, ident=6))), 3.0)  # unfragmented: straight through
    assert bytes(whole) == b"x" * 8
    assert reassembler.add(fragments[1], 3.0) is None and reassembler.dropped == 1  # the old ones timed out


@pytest.mark.parametrize("link_type, wrap", [
    (1, lambda p: ethernet(p, vlan=True)),
    (113, lambda p: struct.pack("!HHH8sH", 0, 1, 6, b"\x02" * 8, 0x0800) + p),  # Linux cooked capture
    (276, lambda p: struct.pack("!HHIHBB8s", 0x0800, 0, 2, 1, 0, 6, b"\x02" * 8) + p),  # Linux cooked capture v2
    (101, lambda p: p),  # raw IP
])
def test_link_types(tmp_path, link_type, wrap):
    path = tmp_path / "x.pcap"
    arp = b"\x02" * 12 + struct.pack("!H", 0x0806) + b"\x00" * 28
    frames = [wrap(p) for p in udp_fragments(b"payload" * 400, 7503, 1)] + ([arp] if link_type == 1 else [])
    path.write_bytes(pcap_bytes([(1, i, f) for i, f in enumerate(frames)], link_type=link_type))
    assert [(p.destination_port, bytes(p.payload)) for p in read_udp(path)] == [(7503, b"payload" * 400)]


def test_a_cut_file_gives_the_records_before_the_cut_then_says_where(tmp_path):
    whole = pcap_bytes([(1, i, ethernet(ipv4(b"u" * 8 + bytes(100), i))) for i in range(3)])
    record_bytes = 16 + 14 + 20 + 108
    for cut, where in [(24 + 2 * record_bytes + 50, r"cut inside the record at byte 340 \(34 of 142 bytes\)"),
                       (24 + 2 * record_bytes + 9, r"cut inside the record header at byte 340")]:
        path = tmp_path / "cut.pcap"
        path.write_bytes(whole[:cut])
        with open(path, "rb") as fh:
            records = pcap_records(fh, pcap_header(fh.read(24)))
            assert [r.file_offset for r in (next(records), next(records))] == [24, 24 + record_bytes]
            with pytest.raises(PcapError, match=where):
                next(records)


def test_corrupt_and_foreign_files_are_refused_with_what_was_expected(tmp_path):
    good = pcap_bytes([(1, 0, ethernet(ipv4(b"u" * 8, 1)))])
    corrupt = good[:24 + 8] + struct.pack("<I", 0xFFFF0000) + good[24 + 12:]
    path = tmp_path / "x.pcap"
    path.write_bytes(corrupt)
    with open(path, "rb") as fh, pytest.raises(PcapError, match="claims 4294901760 bytes: a corrupt record header"):
        list(pcap_records(fh, pcap_header(fh.read(24))))
    with pytest.raises(PcapError, match="a pcapng file"):
        pcap_header(bytes.fromhex("0a0d0d0a") + bytes(20))
    with pytest.raises(PcapError, match="not a libpcap file"):
        pcap_header(b"PK\x03\x04" + bytes(20))
    with pytest.raises(PcapError, match=r"link type 105: expected one of Ethernet \(1\)"):
        pcap_header(good[:20] + struct.pack("<I", 105))
    with pytest.raises(PcapError, match="shorter than a pcap file header"):
        pcap_header(good[:10])


def test_the_header_pass_reads_port_size_and_prefix_from_first_fragments_only(tmp_path):
    payload = bytes(range(200)) * 40
    path = tmp_path / "x.pcap"
    path.write_bytes(pcap_bytes([(7, i, ethernet(p)) for i, p in enumerate(udp_fragments(payload, 7502, 9))]))
    with open(path, "rb") as fh:
        headers = list(udp_headers(fh, pcap_header(fh.read(24)), 12))
    assert [(h.destination_port, h.payload_bytes, bytes(h.payload_prefix)) for h in headers] == [(7502, 8000, payload[:12])]


# --- lidar packets and frames -------------------------------------------------------------------

def shipped_metadata(name: str) -> dict:
    return json.loads((REAL / f"{name}.json").read_text())


def test_frame_ids_wrap_and_a_wrapping_column_window_counts_its_packets():
    assert frame_id_difference(65535, 0) == 1 and frame_id_difference(0, 65535) == -1 and frame_id_difference(5, 5) == 0
    meta = parse_metadata(shipped_metadata(CAPTURES[2]))
    assert lidar_packets_per_frame(meta) == 64
    window = parse_metadata({**shipped_metadata(CAPTURES[2]), "data_format": {
        **shipped_metadata(CAPTURES[2])["data_format"], "column_window": [1000, 40]}})
    assert lidar_packets_per_frame(window) == 5  # packets 62, 63 and 0, 1, 2


def lidar_packet(meta, layout, frame_id: int, first_column: int, seed: int = 0, valid=True, init_id=None) -> bytes:
    """One lidar packet with ranges and reflectivity from `seed`, columns from `first_column`."""
    rng = np.random.default_rng(seed)
    packet = np.zeros(1, layout.dtype)
    columns = packet["columns"][0]
    columns["measurement_id"] = first_column + np.arange(meta.columns_per_packet)
    columns["timestamp_ns"] = 10**12 + 97_656 * columns["measurement_id"].astype(np.uint64)
    columns["status"] = np.where(valid, 0xFFFF_FFFF if layout.legacy else 0x1, 0)
    columns["pixels"]["range_word"] = rng.integers(0, 2**16, columns["pixels"].shape)
    columns["pixels"]["reflectivity"] = rng.integers(0, 256, columns["pixels"].shape)
    raw = bytearray(packet.tobytes())
    if layout.legacy:
        column_bytes = layout.dtype["columns"].base.itemsize
        for c in range(meta.columns_per_packet):
            struct.pack_into("<H", raw, c * column_bytes + 10, frame_id)
    else:
        struct.pack_into("<HHQ", raw, 0, 1, frame_id, (meta.init_id if init_id is None else init_id) | meta.prod_sn << 24)
    return bytes(raw)


def frame_packets(meta, layout, frame_id: int, seed: int = 0) -> list[bytes]:
    cpp = meta.columns_per_packet
    return [lidar_packet(meta, layout, frame_id, p * cpp, seed + p) for p in range(meta.columns_per_frame // cpp)]


@pytest.fixture
def os1_32():
    meta = parse_metadata(shipped_metadata(CAPTURES[2]))
    return meta, packet_layout(meta)


def test_a_frame_of_fragmented_packets_with_a_wrong_port_and_a_wrong_size(tmp_path, os1_32):
    meta, layout = os1_32
    records, ident = [], 0
    packets = frame_packets(meta, layout, 100) + frame_packets(meta, layout, 101)

    def add(payload, port):
        nonlocal ident
        ident += 1
        records.extend((1, len(records), ethernet(f)) for f in udp_fragments(payload, port, ident))

    for i, packet in enumerate(packets):
        add(packet, 7502)
        add(packet, 7503)  # a lidar-sized packet on another port: not this sensor's lidar stream
        if i == 70:
            records.pop(-3)  # a fragment of the other port's copy lost: it never completes, and nothing notices
    add(packets[5][:-4], 7502)  # frame 100's packet 5 again, cut: dropped for its size, not batched
    path = tmp_path / "x.pcap"
    path.write_bytes(pcap_bytes(records))
    scans = list(lidar_frames(path, meta, layout, 7502))
    assert [(s.frame_id, s.complete, s.packets) for s in scans] == [(100, True, 64), (101, True, 64)]
    assert scans[0].dropped == {} and scans[1].dropped == {}  # the cut copy came after the last frame
    index = index_capture(path, meta, layout)
    assert index.udp_port_lidar == 7502 and len(index.frame_capture_time_s) == 2
    assert index.packet_sizes[7502][layout.packet_bytes] == 128 and index.packet_sizes[7502][layout.packet_bytes - 4] == 1

    # the wrong-size packet inside frame 100 instead of its own packet 5: that frame is incomplete
    records.clear()
    for i, packet in enumerate(packets):
        add(packet[:-4] if i == 5 else packet, 7502)
    path.write_bytes(pcap_bytes(records))
    scans = list(lidar_frames(path, meta, layout, 7502))
    assert [(s.frame_id, s.complete) for s in scans] == [(100, False), (101, True)]
    assert scans[0].dropped == {f"not {layout.packet_bytes} bytes": 1}
    assert np.count_nonzero(scans[0].column_status & COLUMN_VALID) == 1024 - 16
    assert not scans[0].range_mm[:, 80:96].any() and scans[0].range_mm[:, 96:].any()


def test_without_a_port_in_the_metadata_the_port_of_the_lidar_sized_packets_is_read(tmp_path, os1_32):
    meta, layout = os1_32
    assert meta.udp_port_lidar is None  # the shipped firmware 2.1 metadata names no port
    records = [(1, i, ethernet(f)) for i, p in enumerate(frame_packets(meta, layout, 3)) for f in udp_fragments(p, 7510, i)]
    path = tmp_path / "x.pcap"
    path.write_bytes(pcap_bytes(records))
    index = index_capture(path, meta, layout)
    assert index.udp_port_lidar == 7510 and len(index.frame_capture_time_s) == 1
    assert [s.complete for s in lidar_frames(path, meta, layout, index.udp_port_lidar)] == [True]


def test_a_cut_capture_ends_the_frame_in_progress_with_its_reason(tmp_path, os1_32):
    meta, layout = os1_32
    records = [(1, i, ethernet(ipv4(struct.pack("!HHHH", 1, 7502, 8 + len(p), 0) + p, i)))
               for i, p in enumerate(frame_packets(meta, layout, 1) + frame_packets(meta, layout, 2))]
    raw = pcap_bytes(records)
    path = tmp_path / "x.pcap"
    path.write_bytes(raw[: len(raw) - 100 * len(records[0][2]) // 2])  # in the middle of frame 2
    scans = list(lidar_frames(path, meta, layout, 7502))
    assert [(s.frame_id, s.complete, s.read_error is None) for s in scans] == [(1, True, True), (2, False, False)]
    assert "cut inside the record" in scans[1].read_error
    assert len(index_capture(path, meta, layout).frame_capture_time_s) == 2
    path.write_bytes(raw[: 24 + 64 * (16 + len(records[0][2])) + 5])  # just after frame 1: nothing in progress
    frames = lidar_frames(path, meta, layout, 7502)
    assert next(frames).complete
    with pytest.raises(PcapError, match="cut inside the record header"):
        next(frames)


def batch(batcher, layout, packets) -> list:
    return [s for p in packets for s in batcher.add(packet_header(layout, p), p, 0.0)]


def summary(scans) -> list[tuple[int, bool, int]]:
    return [(s.frame_id, s.complete, s.packets) for s in scans]


def test_the_batcher_releases_frames_by_ouster_sdks_rules(os1_32):
    meta, layout = os1_32
    a, b, c = (frame_packets(meta, layout, f, seed=10 * f) for f in (65534, 65535, 0))  # the frame id wraps
    batcher = FrameBatcher(meta, layout)
    # a in any order, its last packet after two of b (held, not dropped); a late packet of a is dropped
    order = a[:40] + a[41:] + b[:2] + [a[40]] + b[2:] + [a[7]] + c
    scans = batch(batcher, layout, order)
    assert summary(scans) == [(65534, True, 64), (65535, True, 64), (0, True, 64)]
    assert [s.dropped for s in scans] == [{}, {}, {"late, of a finished frame": 1}] and batcher.finish() == []
    # four packets of the next frame waiting: the frame is released without its missing packet
    batcher = FrameBatcher(meta, layout)
    assert summary(batch(batcher, layout, a[:63] + b[:4])) == [(65534, False, 63)]
    assert summary(batcher.finish()) == [(65535, False, 4)]


def test_a_new_init_id_releases_the_frame_and_other_sensors_packets_are_dropped(tmp_path):
    meta = parse_metadata(shipped_metadata(CAPTURES[0]))
    layout = packet_layout(meta)
    cpp = meta.columns_per_packet
    packets = [lidar_packet(meta, layout, 9, p * cpp, p) for p in range(64)]
    stranger = lidar_packet(meta, layout, 9, 5 * cpp, init_id=meta.init_id + 1)
    path = tmp_path / "x.pcap"
    records = [(1, i, ethernet(f)) for i, p in enumerate(packets[:5] + [stranger] + packets[5:])
               for f in udp_fragments(p, 7502, i)]
    path.write_bytes(pcap_bytes(records))
    scans = list(lidar_frames(path, meta, layout, 7502))
    assert [(s.complete, s.dropped) for s in scans] == [(True, {"another sensor's init id or serial number": 1})]

    restarted = parse_metadata({**shipped_metadata(CAPTURES[0]), "initialization_id": 0})  # ids not checked
    batcher = FrameBatcher(restarted, layout)
    reinit = [lidar_packet(meta, layout, 2, p * cpp, init_id=77) for p in range(3)]
    assert summary(batch(batcher, layout, packets[:10] + reinit)) == [(9, False, 10)]
    assert [(s.frame_id, s.packets) for s in batcher.finish()] == [(2, 3)]


# --- against ouster-sdk (a test-only reference) -------------------------------------------------

@pytest.mark.parametrize("profile", sorted(PIXEL_LAYOUTS))
def test_every_decoded_profile_batches_as_ouster_sdk(profile):
    core = pytest.importorskip("ouster.sdk").core
    doc = shipped_metadata(CAPTURES[1])
    doc["data_format"]["udp_profile_lidar"] = profile
    meta, info = parse_metadata(doc), core.SensorInfo(json.dumps(doc))
    layout = packet_layout(meta)
    packet_format = core.PacketFormat(info)
    assert layout.packet_bytes == packet_format.lidar_packet_size
    rng = np.random.default_rng(7)
    sdk_batcher, sdk_frame, batcher = core.FrameBatcher(info), core.LidarFrame(info), FrameBatcher(meta, layout)
    sdk_done, done = False, []
    for k, p in enumerate(rng.permutation(meta.columns_per_frame // meta.columns_per_packet)):
        raw = bytearray(rng.integers(0, 256, layout.packet_bytes, dtype=np.uint8).tobytes())  # every bit random
        columns = np.frombuffer(raw, layout.dtype)["columns"][0].copy()
        columns["measurement_id"] = p * meta.columns_per_packet + np.arange(meta.columns_per_packet)
        columns["status"] |= (rng.random(meta.columns_per_packet) < 0.9).astype(columns["status"].dtype)  # some invalid
        at = 0 if layout.legacy else 32
        raw[at: at + columns.nbytes] = columns.tobytes()
        if layout.legacy:
            for c in range(meta.columns_per_packet):
                struct.pack_into("<H", raw, c * columns.dtype.itemsize + 10, 7)
        else:
            struct.pack_into("<HHQ", raw, 0, 1, 7, meta.init_id | meta.prod_sn << 24)
        packet = core.LidarPacket(packet_format)
        packet.buf[:] = np.frombuffer(bytes(raw), np.uint8)
        packet.host_timestamp = 1 + k
        sdk_done |= sdk_batcher.batch(packet, sdk_frame)
        done += batcher.add(packet_header(layout, bytes(raw)), bytes(raw), 0.0)
    assert sdk_done and len(done) == 1
    scan = done[0]
    np.testing.assert_array_equal(scan.range_mm, sdk_frame.field(core.ChanField.RANGE))
    np.testing.assert_array_equal(scan.reflectivity, sdk_frame.field(core.ChanField.REFLECTIVITY))
    np.testing.assert_array_equal(scan.column_timestamp_ns, sdk_frame.timestamp)
    np.testing.assert_array_equal(scan.column_status, sdk_frame.status)
    assert scan.complete == sdk_frame.complete(info.format.column_window) is False


@pytest.mark.parametrize("name", CAPTURES)
def test_the_shipped_captures_decode_as_ouster_sdk(name):
    sdk = pytest.importorskip("ouster.sdk")
    pcap, metadata_json = REAL / f"{name}.pcap", REAL / f"{name}.json"
    meta = parse_metadata(shipped_metadata(name))
    layout = packet_layout(meta)
    index = index_capture(pcap, meta, layout)
    reference = sdk.open_source(str(pcap), meta=[str(metadata_json)], sensor_idx=0, index=True)
    try:
        sdk_index_s = np.asarray(reference.individual_index[0], dtype=np.float64)[:, 0] * 1e-6  # microseconds
        sdk_scans = [s for frame_set in reference for s in frame_set.valid_frames()]
    finally:
        reference.close()
    np.testing.assert_array_equal(index.frame_capture_time_s, sdk_index_s)
    scans = list(lidar_frames(pcap, meta, layout, index.udp_port_lidar))
    assert len(scans) == len(sdk_scans) == len(sdk_index_s) == {"OS-1-128": 3}.get(name[:8], 1)
    window = reference.sensor_info[0].format.column_window
    for scan, sdk_scan in zip(scans, sdk_scans):
        assert scan.frame_id == sdk_scan.frame_id and scan.complete == sdk_scan.complete(window) is True
        np.testing.assert_array_equal(scan.range_mm, sdk_scan.field(sdk.core.ChanField.RANGE))
        np.testing.assert_array_equal(scan.reflectivity, sdk_scan.field(sdk.core.ChanField.REFLECTIVITY))
        np.testing.assert_array_equal(scan.column_timestamp_ns, sdk_scan.timestamp)
        np.testing.assert_array_equal(scan.column_status, sdk_scan.status)
