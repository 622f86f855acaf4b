"""The pcap reader (`data/io/pcap.py`) on synthetic bytes: both pcap magics and byte orders,
IPv4 fragments in any order, link types, cut and corrupt files."""

from __future__ import annotations

import random
import struct
from pathlib import Path

import pytest

from boomtip.data.io.pcap import (PCAP_MAGIC_MICROSECONDS, PCAP_MAGIC_NANOSECONDS, Ipv4Reassembler, PcapError,
                                  ipv4_fragment, pcap_header, pcap_records, udp_headers, udp_packets)

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
