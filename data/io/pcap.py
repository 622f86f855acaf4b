"""libpcap captures as a stream of UDP datagrams, with the standard library only.

The file and record headers (microsecond or nanosecond time stamps, either byte order), the
link layer (Ethernet with VLAN tags, Linux cooked capture v1 and v2, raw IPv4), IPv4 with
fragment reassembly (an Ouster lidar packet is larger than the usual 1500-byte MTU, so a
capture may hold it as fragments) and UDP. Records are read one at a time: a capture is never
held in memory whole. A cut or corrupt record ends the stream with a `PcapError` after the
records before it.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from typing import BinaryIO, Iterator, NamedTuple

PCAP_MAGIC_MICROSECONDS = 0xA1B2C3D4
PCAP_MAGIC_NANOSECONDS = 0xA1B23C4D
PCAPNG_MAGIC = 0x0A0D0D0A  # the section header block type; the same in either byte order
FILE_HEADER_BYTES = 24
RECORD_HEADER_BYTES = 16
# no link frame carrying an IPv4 datagram (at most 65,535 bytes) comes near this: a longer record
# is a corrupt length field, and reading on would lose the record boundaries
MAX_RECORD_BYTES = 262_144

LINKTYPE_ETHERNET = 1
LINKTYPE_RAW = 101
LINKTYPE_LINUX_SLL = 113
LINKTYPE_LINUX_SLL2 = 276
LINK_TYPES = {LINKTYPE_ETHERNET: "Ethernet", LINKTYPE_RAW: "raw IPv4", LINKTYPE_LINUX_SLL: "Linux cooked capture",
              LINKTYPE_LINUX_SLL2: "Linux cooked capture v2"}
ETHERNET_HEADER_BYTES = 14
VLAN_TAG_BYTES = 4
SLL_HEADER_BYTES = 16
SLL2_HEADER_BYTES = 20
ETHERTYPE_IPV4 = 0x0800
ETHERTYPES_VLAN = (0x8100, 0x88A8)

IPV4_MIN_HEADER_BYTES = 20
IPPROTO_UDP = 17
IP_MORE_FRAGMENTS = 0x2000
IP_FRAGMENT_OFFSET_MASK = 0x1FFF  # in units of 8 bytes
UDP_HEADER_BYTES = 8
# datagrams waiting for fragments: one that has waited longer (libtins, which ouster-sdk uses,
# waits 2 s) or that is the oldest of too many lost a fragment and is given up
FRAGMENT_TIMEOUT_S = 2.0
MAX_PENDING_DATAGRAMS = 64
# link header (Ethernet with two VLAN tags: 22) + the longest IPv4 header (60) + UDP (8), rounded up
HEADERS_PREFIX_BYTES = 96


class PcapError(ValueError):
    """A capture that cannot be read on: not a libpcap file, a cut record, a corrupt length."""


@dataclass(frozen=True)
class PcapHeader:
    byte_order: str  # "<" or ">": the writer's, told by the magic number
    seconds_per_tick: float  # of the records' sub-second field: 1e-6 or 1e-9
    link_type: int
    snap_length: int


class PcapRecord(NamedTuple):
    capture_time_s: float
    data: memoryview  # the captured bytes, or their first `prefix_bytes`
    captured_bytes: int
    file_offset: int  # of the record header


class Ipv4Fragment(NamedTuple):
    datagram_key: tuple  # source, destination, protocol, identification: the datagram it belongs to
    protocol: int
    offset_bytes: int
    more_fragments: bool
    payload: memoryview


class UdpPacket(NamedTuple):
    capture_time_s: float
    destination_port: int
    payload: memoryview


class UdpHeader(NamedTuple):
    capture_time_s: float
    destination_port: int
    payload_bytes: int  # the whole datagram's, from the UDP length field
    payload_prefix: memoryview  # as much of the payload as the first fragment's prefix holds
    file_offset: int


def pcap_header(raw: bytes) -> PcapHeader:
    """The libpcap file header: byte order and time-stamp resolution from the magic number."""
    if len(raw) < FILE_HEADER_BYTES:
        raise PcapError(f"{len(raw)} bytes: shorter than a pcap file header ({FILE_HEADER_BYTES} bytes)")
    for order in "<>":
        magic, = struct.unpack_from(order + "I", raw)
        if magic in (PCAP_MAGIC_MICROSECONDS, PCAP_MAGIC_NANOSECONDS):
            break
    else:
        if magic == PCAPNG_MAGIC:
            raise PcapError("a pcapng file; save it as libpcap (e.g. `editcap -F pcap IN.pcapng OUT.pcap`)")
        raise PcapError(f"magic number {raw[:4].hex()}: not a libpcap file (expected a1b2c3d4 or a1b23c4d)")
    snap_length, link_field = struct.unpack_from(order + "II", raw, 16)
    link_type = link_field & 0x0FFFFFFF  # the upper bits may carry the FCS length
    if link_type not in LINK_TYPES:
        known = ", ".join(f"{name} ({n})" for n, name in LINK_TYPES.items())
        raise PcapError(f"link type {link_type}: expected one of {known}")
    return PcapHeader(order, 1e-6 if magic == PCAP_MAGIC_MICROSECONDS else 1e-9, link_type, snap_length)


def pcap_records(fh: BinaryIO, header: PcapHeader, prefix_bytes: int | None = None) -> Iterator[PcapRecord]:
    """The records after the file header, read one at a time; with `prefix_bytes`, only that
    many bytes of each (the rest is skipped by a seek, for a pass over the headers)."""
    file_bytes = os.fstat(fh.fileno()).st_size
    unpack = struct.Struct(header.byte_order + "IIII").unpack
    ticks_per_s = round(1.0 / header.seconds_per_tick)
    offset = fh.tell()
    while True:
        raw = fh.read(RECORD_HEADER_BYTES)
        if len(raw) < RECORD_HEADER_BYTES:
            if raw:
                raise PcapError(f"cut inside the record header at byte {offset} "
                                f"({len(raw)} of {RECORD_HEADER_BYTES} bytes)")
            return
        seconds, ticks, captured, _original = unpack(raw)
        if captured > MAX_RECORD_BYTES:
            raise PcapError(f"the record at byte {offset} claims {captured} bytes: a corrupt record header")
        end = offset + RECORD_HEADER_BYTES + captured
        if end > file_bytes:
            raise PcapError(f"cut inside the record at byte {offset} ({file_bytes - offset - RECORD_HEADER_BYTES} "
                            f"of {captured} bytes)")
        # as an integer count of ticks first, so a time is the same float however it is read
        t_s = (seconds * ticks_per_s + ticks) * header.seconds_per_tick
        if prefix_bytes is None or prefix_bytes >= captured:
            data = fh.read(captured)
        else:
            data = fh.read(prefix_bytes)
            fh.seek(end)
        yield PcapRecord(t_s, memoryview(data), captured, offset)
        offset = end


def link_ipv4(link_type: int, frame: memoryview) -> memoryview | None:
    """The IPv4 packet inside a link frame; None for anything else (ARP, IPv6, ...)."""
    if link_type == LINKTYPE_ETHERNET:
        at = ETHERNET_HEADER_BYTES
        if len(frame) < at:
            return None
        ethertype = (frame[at - 2] << 8) | frame[at - 1]
        while ethertype in ETHERTYPES_VLAN and len(frame) >= at + VLAN_TAG_BYTES:
            ethertype = (frame[at + 2] << 8) | frame[at + 3]
            at += VLAN_TAG_BYTES
    elif link_type == LINKTYPE_LINUX_SLL:
        at = SLL_HEADER_BYTES
        ethertype = (frame[14] << 8) | frame[15] if len(frame) >= at else None
    elif link_type == LINKTYPE_LINUX_SLL2:
        at = SLL2_HEADER_BYTES
        ethertype = (frame[0] << 8) | frame[1] if len(frame) >= at else None
    else:  # raw IP: IPv4 or IPv6, told by the version nibble
        at, ethertype = 0, ETHERTYPE_IPV4 if len(frame) and frame[0] >> 4 == 4 else None
    return frame[at:] if ethertype == ETHERTYPE_IPV4 else None


_IPV4 = struct.Struct("!BxHHHxB2x4s4s")


def ipv4_fragment(packet: memoryview, whole: bool = True) -> Ipv4Fragment | None:
    """An IPv4 packet's header fields and payload (trailing link padding cut by the total
    length); None if it is no IPv4 or is cut short. `whole=False` accepts a packet cut by a
    header-prefix read and gives as much of its payload as there is."""
    if len(packet) < IPV4_MIN_HEADER_BYTES:
        return None
    version_ihl, total_bytes, ident, flags_offset, protocol, source, destination = _IPV4.unpack_from(packet)
    header_bytes = (version_ihl & 0x0F) * 4
    if version_ihl >> 4 != 4 or header_bytes < IPV4_MIN_HEADER_BYTES or total_bytes < header_bytes:
        return None
    if whole and total_bytes > len(packet):
        return None
    return Ipv4Fragment((source, destination, protocol, ident), protocol,
                        (flags_offset & IP_FRAGMENT_OFFSET_MASK) * 8, bool(flags_offset & IP_MORE_FRAGMENTS),
                        packet[header_bytes:total_bytes])


@dataclass
class _Pending:
    first_s: float  # capture time of its first fragment to arrive
    parts: dict[int, memoryview]  # payload pieces by offset
    total_bytes: int | None = None  # known once the last fragment (no more-fragments flag) is in


class Ipv4Reassembler:
    """Fragments back into datagrams, in any order of arrival; a datagram that does not
    complete within `FRAGMENT_TIMEOUT_S`, or the oldest of more than `max_pending`, is dropped."""

    def __init__(self, max_pending: int = MAX_PENDING_DATAGRAMS, timeout_s: float = FRAGMENT_TIMEOUT_S) -> None:
        self.max_pending, self.timeout_s = max_pending, timeout_s
        self._pending: dict[tuple, _Pending] = {}
        self.dropped = 0  # datagrams given up

    def add(self, fragment: Ipv4Fragment, capture_time_s: float) -> memoryview | None:
        """The whole datagram's payload once `fragment` completes it, else None."""
        if fragment.offset_bytes == 0 and not fragment.more_fragments:
            return fragment.payload  # not fragmented: the common case costs a test
        self._expire(capture_time_s)
        entry = self._pending.get(fragment.datagram_key)
        if entry is None:
            entry = self._pending[fragment.datagram_key] = _Pending(capture_time_s, {})
        entry.parts[fragment.offset_bytes] = fragment.payload  # a duplicate replaces the earlier copy
        if not fragment.more_fragments:
            entry.total_bytes = fragment.offset_bytes + len(fragment.payload)
        if entry.total_bytes is None:
            return None
        offsets = sorted(entry.parts)
        covered = 0
        for at in offsets:
            if at > covered:
                return None  # a gap: a fragment still to come
            covered = max(covered, at + len(entry.parts[at]))
        if covered < entry.total_bytes:
            return None
        datagram = bytearray(entry.total_bytes)
        for at in offsets:
            piece = entry.parts[at][: max(0, entry.total_bytes - at)]
            datagram[at: at + len(piece)] = piece
        del self._pending[fragment.datagram_key]
        return memoryview(datagram)

    def _expire(self, now_s: float) -> None:
        while self._pending:
            key, oldest = next(iter(self._pending.items()))
            if now_s - oldest.first_s <= self.timeout_s and len(self._pending) < self.max_pending:
                return
            del self._pending[key]
            self.dropped += 1


def udp_datagram(datagram: memoryview) -> tuple[int, int, memoryview] | None:
    """Source port, destination port and payload of a UDP datagram; None if cut short."""
    if len(datagram) < UDP_HEADER_BYTES:
        return None
    source_port, destination_port, udp_bytes = struct.unpack_from("!HHH", datagram)
    if udp_bytes < UDP_HEADER_BYTES or udp_bytes > len(datagram):
        return None
    return source_port, destination_port, datagram[UDP_HEADER_BYTES:udp_bytes]


def udp_packets(fh: BinaryIO, header: PcapHeader) -> Iterator[UdpPacket]:
    """The capture's UDP datagrams over IPv4, fragments reassembled, in order of completion."""
    reassembler = Ipv4Reassembler()
    for record in pcap_records(fh, header):
        packet = link_ipv4(header.link_type, record.data)
        fragment = ipv4_fragment(packet) if packet is not None else None
        if fragment is None or fragment.protocol != IPPROTO_UDP:
            continue
        datagram = reassembler.add(fragment, record.capture_time_s)
        udp = udp_datagram(datagram) if datagram is not None else None
        if udp is not None:
            yield UdpPacket(record.capture_time_s, udp[1], udp[2])


def udp_headers(fh: BinaryIO, header: PcapHeader, payload_prefix_bytes: int) -> Iterator[UdpHeader]:
    """A cheap pass: each UDP datagram's port, size and first payload bytes, read from its
    first fragment without reading the rest of the record (or the other fragments)."""
    for record in pcap_records(fh, header, HEADERS_PREFIX_BYTES + payload_prefix_bytes):
        packet = link_ipv4(header.link_type, record.data)
        fragment = ipv4_fragment(packet, whole=False) if packet is not None else None
        if fragment is None or fragment.protocol != IPPROTO_UDP or fragment.offset_bytes != 0:
            continue
        if len(fragment.payload) < UDP_HEADER_BYTES:
            continue
        _, destination_port, udp_bytes = struct.unpack_from("!HHH", fragment.payload)
        if udp_bytes < UDP_HEADER_BYTES:
            continue
        yield UdpHeader(record.capture_time_s, destination_port, udp_bytes - UDP_HEADER_BYTES,
                        fragment.payload[UDP_HEADER_BYTES:UDP_HEADER_BYTES + payload_prefix_bytes], record.file_offset)
