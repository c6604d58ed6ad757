"""``udpcycle``: a python-can interface that carries a bus cycle's frames in one UDP datagram.

``can.Bus(interface="udpcycle", channel="239.74.163.9:51000")`` (registered through the
``can.interface`` entry point in pyproject.toml, and by :func:`register` as a fallback)
opens a UDP socket. ``send(msg)`` puts one frame in one datagram, as any python-can
interface does; ``send_many(msgs)`` puts all of them in ONE datagram (the fieldbus
endpoints send a cycle's SoC + PReqs, or a cycle's PRes frames, that way), and
``drain()`` returns everything that has arrived, in order. So a 400 µs POWERLINK cycle
costs one datagram per direction instead of 19 frames.

Addressing (``channel`` = ``"host:port"``):

* a multicast group (224.0.0.0/4): every bus on the group and port sees every datagram
  (loopback included); a bus ignores its own datagrams by their sender id;
* a unicast address: the bus binds there and sends to ``peer="host:port"``; without
  ``peer`` it answers the address of the first accepted datagram (before it, what it
  sends goes nowhere and is counted in ``stats.no_peer``). With ``peer_only=True``
  (what ``cosim serve`` uses) it accepts datagrams only from that peer, given or learned:
  a second program sending to the port is counted as *foreign* and cannot inject frames.

Wire format (version 1, all integers big-endian = network order) — documented in
``fieldbus/README.md`` so a controller in any language can speak it::

    header, 24 bytes:  magic  b"RXCB"        4 bytes
                       version               u8  (1)
                       flags                 u8  (0; reserved)
                       frame count n         u16
                       sender id             u32 (random per bus unless given)
                       sequence              u32 (per sender, +1 per datagram, wraps)
                       send time             u64 (sender's wall clock, ns since the epoch)
    n frames, each:    can id                u32 (bit 31 extended, bit 30 remote, bit 29 error frame)
                       length                u8  (0..64 data bytes)
                       flags                 u8  (bit 0 CAN FD, bit 1 bit-rate switch, bit 2 ESI)
                       reserved              u16 (0)
                       timestamp             f64 (seconds; the sender's frame time)
                       data                  ``length`` bytes

Reception checks every datagram: a wrong magic or version, a frame count that does not
match the length, or a length above 64 is *malformed* (counted, dropped); a datagram
from an address not in ``accept_from`` (or, with ``peer_only``, not the peer) is
*foreign* (counted, dropped). Sequence
numbers per (address, sender id) count *lost* datagrams (gaps), *reordered* ones (older
than the newest seen, not seen before) and *duplicates* (seen before, window of 1024).
:attr:`UdpCycleBus.stats` holds the counters.

Transport fault injection (seeded, on the sending side, for tests and scenarios through
``[fieldbus.bus] options``): ``drop_probability``, ``duplicate_probability``,
``delay_probability`` with ``delay_s`` (a delayed datagram goes out with the first
send or receive call after its due time), ``fault_seed``.
"""
from __future__ import annotations

import ipaddress
import os
import random
import select
import socket
import struct
import sys
import time
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any

import can
from can import BusABC, CanProtocol, Message

from fieldbus.simbus import drain_queue
from fieldbus.telegrams import FastMessage

INTERFACE_NAME = "udpcycle"
MAGIC = b"RXCB"
VERSION = 1
HEADER = struct.Struct(">4sBBHIIQ")
FRAME = struct.Struct(">IBBHd")
MAX_DATA = 64
MAX_DATAGRAM = 65507
ID_EXTENDED = 1 << 31
ID_REMOTE = 1 << 30
ID_ERROR = 1 << 29
ID_MASK = 0x1FFFFFFF
FLAG_FD, FLAG_BRS, FLAG_ESI = 1, 2, 4
_DUPLICATE_WINDOW = 1024


_CMSG_SPACE = socket.CMSG_SPACE(16) if hasattr(socket, "CMSG_SPACE") else 0
#: Linux SO_TIMESTAMPNS (asm-generic and x86: 35; the socket module does not export it)
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35 if sys.platform.startswith("linux") else None)
_TIMESPEC = struct.Struct("@qq")


def _kernel_time_ns(ancillary: list) -> int:
    """Arrival time (ns since the epoch) from SO_TIMESTAMPNS ancillary data, 0 if absent."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(data) >= 16:
            seconds, nanoseconds = _TIMESPEC.unpack_from(data)
            return seconds * 1_000_000_000 + nanoseconds
    return 0


class _SelectPoller:
    """``select.poll``'s ``poll(0)`` for one socket where the OS has no poll (Windows)."""

    def __init__(self, sock: socket.socket) -> None:
        self._sock = sock

    def poll(self, timeout: float = 0) -> list:
        return select.select([self._sock], [], [], 0)[0]


class UdpCycleError(can.CanInitializationError):
    """A udpcycle bus could not be opened (bad address, port in use, bad option)."""


@dataclass
class TransportStats:
    """Counters of one bus (datagrams unless named frames)."""

    sent: int = 0
    frames_sent: int = 0
    received: int = 0
    frames_received: int = 0
    lost: int = 0
    reordered: int = 0
    duplicates: int = 0
    malformed: int = 0
    foreign: int = 0
    injected_drops: int = 0
    injected_duplicates: int = 0
    injected_delays: int = 0
    send_overflows: int = 0
    no_peer: int = 0
    send_errors: int = 0

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


def parse_address(text: Any, what: str) -> tuple[str, int]:
    """``"host:port"`` -> (host, port) with a clear error."""
    if isinstance(text, (tuple, list)) and len(text) == 2:
        host, port = str(text[0]), text[1]
    else:
        host, sep, port = str(text).rpartition(":")
        if not sep or not host:
            raise UdpCycleError(f"udpcycle {what} {text!r}: expected 'host:port', e.g. '127.0.0.1:51000'")
    try:
        port = int(port)
    except (TypeError, ValueError):
        raise UdpCycleError(f"udpcycle {what} {text!r}: expected an integer port 1..65535") from None
    if not 0 < port < 65536:
        raise UdpCycleError(f"udpcycle {what} {text!r}: expected a port 1..65535")
    return host, port


def encode_datagram(msgs: list[Message], sender: int, sequence: int, send_time_ns: int = 0) -> bytes:
    """The wire bytes of one datagram carrying ``msgs``."""
    parts = [HEADER.pack(MAGIC, VERSION, 0, len(msgs), sender & 0xFFFFFFFF, sequence & 0xFFFFFFFF,
                         send_time_ns & 0xFFFFFFFFFFFFFFFF)]
    for msg in msgs:
        data = bytes(msg.data) if msg.data is not None else b""
        if len(data) > MAX_DATA:
            raise ValueError(f"udpcycle: frame 0x{msg.arbitration_id:X} has {len(data)} data bytes, expected <= 64")
        can_id = msg.arbitration_id & ID_MASK
        if msg.is_extended_id:
            can_id |= ID_EXTENDED
        if msg.is_remote_frame:
            can_id |= ID_REMOTE
        if msg.is_error_frame:
            can_id |= ID_ERROR
        flags = (FLAG_FD if msg.is_fd else 0) | (FLAG_BRS if msg.bitrate_switch else 0) | \
                (FLAG_ESI if msg.error_state_indicator else 0)
        parts.append(FRAME.pack(can_id, len(data), flags, 0, float(msg.timestamp or 0.0)))
        parts.append(data)
    return b"".join(parts)


def decode_datagram(payload: bytes) -> tuple[int, int, int, list[Message]]:
    """(sender, sequence, send_time_ns, frames) of a datagram; ValueError if malformed."""
    if len(payload) < HEADER.size:
        raise ValueError(f"{len(payload)} bytes, shorter than the {HEADER.size}-byte header")
    magic, version, _flags, count, sender, sequence, sent_ns = HEADER.unpack_from(payload, 0)
    if magic != MAGIC:
        raise ValueError(f"magic {magic!r}, expected {MAGIC!r}")
    if version != VERSION:
        raise ValueError(f"version {version}, expected {VERSION}")
    offset = HEADER.size
    frames = []
    for _ in range(count):
        if offset + FRAME.size > len(payload):
            raise ValueError(f"truncated: header says {count} frames, bytes end in frame {len(frames) + 1}")
        can_id, length, flags, _reserved, stamp = FRAME.unpack_from(payload, offset)
        offset += FRAME.size
        if length > MAX_DATA:
            raise ValueError(f"frame {len(frames) + 1} length {length}, expected <= {MAX_DATA}")
        if offset + length > len(payload):
            raise ValueError(f"truncated: frame {len(frames) + 1} wants {length} data bytes")
        msg = FastMessage(stamp, can_id & ID_MASK, bytearray(payload[offset:offset + length]),
                          bool(can_id & ID_ERROR))
        if can_id & (ID_EXTENDED | ID_REMOTE) or flags:
            msg.is_extended_id = bool(can_id & ID_EXTENDED)
            msg.is_remote_frame = bool(can_id & ID_REMOTE)
            msg.is_fd = bool(flags & FLAG_FD)
            msg.bitrate_switch = bool(flags & FLAG_BRS)
            msg.error_state_indicator = bool(flags & FLAG_ESI)
        frames.append(msg)
        offset += length
    if offset != len(payload):
        raise ValueError(f"{len(payload) - offset} bytes after the last of {count} frames")
    return sender, sequence, sent_ns, frames


class _SequenceTracker:
    """Loss, reordering and duplicates of one sender's sequence numbers."""

    __slots__ = ("newest", "seen", "order")

    def __init__(self, first: int) -> None:
        self.newest = first
        self.seen = {first}
        self.order: deque[int] = deque([first])

    def judge(self, seq: int, stats: TransportStats) -> bool:
        """Count ``seq``; False for a duplicate (to be dropped)."""
        if seq in self.seen:
            stats.duplicates += 1
            return False
        ahead = (seq - self.newest) & 0xFFFFFFFF
        if 0 < ahead < 0x80000000:
            stats.lost += ahead - 1
            self.newest = seq
        else:  # older than the newest: it was counted lost when the gap opened
            stats.reordered += 1
            stats.lost = max(stats.lost - 1, 0)
        self.seen.add(seq)
        self.order.append(seq)
        if len(self.order) > _DUPLICATE_WINDOW:
            self.seen.discard(self.order.popleft())
        return True


class UdpCycleBus(BusABC):
    """One UDP socket; one datagram per ``send`` (one frame) or ``send_many`` (many).

    Args:
        channel: ``"host:port"``: a multicast group to join, or a unicast address to bind.
        peer: unicast destination ``"host:port"`` (unicast channels only).
        accept_from: addresses (``"host"`` or ``"host:port"``) whose datagrams are
            accepted; others are counted as foreign and dropped. Default: all.
        peer_only: unicast, without ``accept_from``: accept datagrams only from the peer
            (``peer``, or the first sender of a valid datagram when none is given); others
            are counted as foreign and dropped.
        sender_id: this bus's id on the wire (default: random).
        busy_poll_s: in ``recv(timeout)``, spin on the non-blocking socket for up to this
            long before sleeping in ``select`` (lower latency, one core busy).
        interface_address: local interface for multicast (default 127.0.0.1 for
            loopback groups use; "0.0.0.0" lets the kernel choose).
        ttl: multicast time to live (default 1: this host's network only).
        drop_probability, duplicate_probability, delay_probability, delay_s, fault_seed:
            seeded transport fault injection on sent datagrams.
        receive_own_messages: also deliver this bus's own datagrams (multicast).
        latency_samples: keep the one-way latency (ns) of the last this many received
            datagrams in :attr:`latency_ns`: the kernel's arrival time (SO_TIMESTAMPNS)
            minus the sender's send time from the header - meaningful on one host or
            with synchronised clocks. 0 (default): not measured. With it,
            :attr:`oldest_arrival_ns` is the kernel arrival time of the oldest datagram of the last read.
    """

    def __init__(self, channel: Any = None, can_filters: Any = None, *, peer: Any = None,
                 accept_from: Any = None, peer_only: bool = False, sender_id: int | None = None,
                 busy_poll_s: float = 0.0,
                 interface_address: str = "127.0.0.1", ttl: int = 1,
                 drop_probability: float = 0.0, duplicate_probability: float = 0.0,
                 delay_probability: float = 0.0, delay_s: float = 0.0, fault_seed: int = 0,
                 receive_own_messages: bool = False, receive_buffer_bytes: int = 1 << 20,
                 latency_samples: int = 0,
                 **kwargs: object) -> None:
        if channel is None:
            raise UdpCycleError("udpcycle needs channel='host:port' (a multicast group or a local address)")
        host, port = parse_address(channel, "channel")
        for name, p in (("drop_probability", drop_probability), ("duplicate_probability", duplicate_probability),
                        ("delay_probability", delay_probability)):
            if not (isinstance(p, (int, float)) and 0.0 <= p <= 1.0):
                raise UdpCycleError(f"udpcycle option {name}={p!r}: expected a probability 0..1")
        if not (isinstance(delay_s, (int, float)) and 0.0 <= delay_s <= 10.0):
            raise UdpCycleError(f"udpcycle option delay_s={delay_s!r}: expected seconds 0..10")
        try:
            ip = ipaddress.ip_address(socket.gethostbyname(host))
        except (OSError, ValueError) as error:
            raise UdpCycleError(f"udpcycle channel {channel!r}: cannot resolve {host!r} ({error})") from None
        self.multicast = ip.is_multicast
        self.channel_id = f"{ip}:{port}"
        self.channel_info = f"udpcycle {'multicast' if self.multicast else 'unicast'} {self.channel_id}"
        self.receive_own_messages = receive_own_messages
        self._can_protocol = CanProtocol.CAN_FD
        self.sender_id = int(sender_id) if sender_id is not None else int.from_bytes(os.urandom(4), "big")
        self._sequence = 0
        self.stats = TransportStats()
        self.last_send_error = ""
        self._queue: deque[Message] = deque()
        self._trackers: dict[tuple, _SequenceTracker] = {}
        self._busy_poll_s = float(busy_poll_s)
        self._rng = random.Random(fault_seed)
        self._p_drop, self._p_dup, self._p_delay = float(drop_probability), float(duplicate_probability), \
            float(delay_probability)
        self._delay_s = float(delay_s)
        self._held: list[tuple[float, bytes]] = []
        self._accept = None if accept_from is None else self._accept_set(accept_from)
        self._peer_only = bool(peer_only) and accept_from is None
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, int(receive_buffer_bytes))
            if self.multicast:
                self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                if hasattr(socket, "SO_REUSEPORT"):
                    self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
                self._sock.bind(("", port))
                local = socket.inet_aton(interface_address)
                self._sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, socket.inet_aton(str(ip)) + local)
                self._sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, local)
                self._sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, int(ttl))
                self._sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
                self._dest: tuple[str, int] | None = (str(ip), port)
            else:
                self._sock.bind((str(ip), port))
                self._dest = None if peer is None else self._resolve(parse_address(peer, "peer"))
        except OSError as error:
            self._sock.close()
            what = "is in use" if error.errno in (98, 48) else f"cannot be used ({error.strerror or error})"
            raise UdpCycleError(f"udpcycle channel {channel!r}: the address {what}") from None
        self._sock.setblocking(False)
        if hasattr(select, "poll"):  # readiness check of the busy poll (recv_internal)
            self._poller: Any = select.poll()
            self._poller.register(self._sock, select.POLLIN)
        else:
            self._poller = _SelectPoller(self._sock)
        self.latency_ns: deque[int] = deque(maxlen=int(latency_samples))
        #: kernel arrival time (ns since the epoch) of the oldest datagram of the last read that
        #: got any, 0 if not measured: ``time.time_ns() - oldest_arrival_ns`` right after a
        #: ``recv`` is how long the datagram waited for this process
        self.oldest_arrival_ns = 0
        #: kernel arrival time (ns since the epoch) of the newest datagram received so far, 0 if not
        #: measured (a peer that paces itself on the other side's latest frame times from this)
        self.newest_arrival_ns = 0
        self._kernel_stamps = bool(latency_samples) and _SO_TIMESTAMPNS is not None and bool(_CMSG_SPACE)
        if self._kernel_stamps:
            try:
                self._sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
            except OSError:
                self._kernel_stamps = False
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)

    @staticmethod
    def _resolve(address: tuple[str, int]) -> tuple[str, int]:
        try:
            return socket.gethostbyname(address[0]), address[1]
        except OSError as error:
            raise UdpCycleError(f"udpcycle peer {address[0]}:{address[1]}: cannot resolve ({error})") from None

    @staticmethod
    def _accept_set(accept_from: Any) -> set:
        items = [accept_from] if isinstance(accept_from, str) else list(accept_from)
        accepted: set = set()
        for item in items:
            host, sep, port = str(item).rpartition(":")
            if sep and port.isdigit():
                accepted.add((socket.gethostbyname(host), int(port)))
            else:
                accepted.add(socket.gethostbyname(str(item)))
        return accepted

    # ------------------------------------------------------------------ sending
    def send(self, msg: Message, timeout: float | None = None) -> None:
        """One frame in one datagram."""
        self.send_many([msg])

    def send_many(self, msgs: list[Message]) -> None:
        """All ``msgs`` in one datagram (in order)."""
        if self._held:
            self._release_held()
        destination = self._dest
        if destination is None:  # nobody to send to yet (no peer given, nothing received): as on an empty wire
            self.stats.no_peer += 1
            return
        self._sequence = (self._sequence + 1) & 0xFFFFFFFF
        payload = encode_datagram(msgs, self.sender_id, self._sequence, time.time_ns())
        self.stats.frames_sent += len(msgs)
        if self._p_drop or self._p_dup or self._p_delay:
            rng = self._rng
            if rng.random() < self._p_drop:
                self.stats.injected_drops += 1
                return
            if rng.random() < self._p_delay:
                self.stats.injected_delays += 1
                self._held.append((time.monotonic() + self._delay_s, payload))
                return
            if rng.random() < self._p_dup:
                self.stats.injected_duplicates += 1
                self._sendto(payload, destination)
        self._sendto(payload, destination)

    def _sendto(self, payload: bytes, destination: tuple[str, int]) -> None:
        try:
            self._sock.sendto(payload, destination)
        except BlockingIOError:  # socket buffer full: the datagram is lost, as on a wire
            self.stats.send_overflows += 1
            return
        except OSError as error:  # e.g. an unreachable peer: counted, like a frame lost on the wire
            self.stats.send_errors += 1
            self.last_send_error = f"udpcycle send to {destination[0]}:{destination[1]}: {error}"
            return
        self.stats.sent += 1

    def _release_held(self) -> None:
        now = time.monotonic()
        due = [item for item in self._held if item[0] <= now]
        if due and self._dest is not None:
            self._held = [item for item in self._held if item[0] > now]
            for _, payload in due:
                self._sendto(payload, self._dest)

    # ------------------------------------------------------------------ receiving
    def _read_available(self) -> bool:
        """Read every datagram waiting on the socket; True if any frame was queued."""
        got = False
        sock = self._sock
        stamped = self._kernel_stamps
        while True:
            try:
                if stamped:
                    payload, ancillary, _flags, address = sock.recvmsg(MAX_DATAGRAM, _CMSG_SPACE)
                else:
                    payload, address = sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return got
            except OSError:
                return got
            if self._accept is not None and address[0] not in self._accept and address not in self._accept:
                self.stats.foreign += 1
                continue
            if self._peer_only and self._dest is not None and address != self._dest:
                self.stats.foreign += 1
                continue
            try:
                sender, seq, sent_ns, frames = decode_datagram(payload)
            except ValueError:
                self.stats.malformed += 1
                continue
            if sender == self.sender_id and not self.receive_own_messages:
                continue
            if stamped:
                arrived = _kernel_time_ns(ancillary)
                if arrived:
                    if not got:
                        self.oldest_arrival_ns = arrived
                    self.newest_arrival_ns = arrived
                    if sent_ns:
                        self.latency_ns.append(arrived - sent_ns)
            key = (address, sender)
            tracker = self._trackers.get(key)
            if tracker is None:
                self._trackers[key] = _SequenceTracker(seq)
            elif not tracker.judge(seq, self.stats):
                continue
            if not self.multicast and self._dest is None:
                self._dest = address
            self.stats.received += 1
            self.stats.frames_received += len(frames)
            self._queue.extend(frames)
            got = got or bool(frames)

    def _recv_internal(self, timeout: float | None) -> tuple[Message | None, bool]:
        queue = self._queue
        if queue:
            return queue.popleft(), False
        if self._held:
            self._release_held()
        if self._read_available():
            return queue.popleft(), False
        if timeout is not None and timeout <= 0.0:
            return None, False
        deadline = None if timeout is None else time.monotonic() + timeout
        spin_until = time.monotonic() + self._busy_poll_s
        while True:
            now = time.monotonic()
            if now < spin_until and (deadline is None or now < deadline):
                # readiness first: a read of an empty non-blocking socket raises, and building that
                # exception (strerror decoded through the locale) costs several µs per turn
                if self._poller.poll(0) and self._read_available():
                    return queue.popleft(), False
                continue
            wait = None if deadline is None else max(deadline - now, 0.0)
            if self._held:
                wait = 0.0005 if wait is None else min(wait, 0.0005)
                self._release_held()
            ready, _, _ = select.select([self._sock], [], [], wait)
            if ready and self._read_available():
                return queue.popleft(), False
            if deadline is not None and time.monotonic() >= deadline:
                return None, False

    def drain(self) -> list[Message]:
        """Everything that has arrived (in order), filtered like ``recv``; never blocks."""
        if self._held:
            self._release_held()
        self._read_available()
        return drain_queue(self, self._queue)

    def fileno(self) -> int:
        return self._sock.fileno()

    def shutdown(self) -> None:
        if self._held and self._dest is not None:
            for _, payload in self._held:
                try:
                    self._sock.sendto(payload, self._dest)
                except OSError:
                    break
            self._held = []
        self._sock.close()
        super().shutdown()

    @staticmethod
    def _detect_available_configs() -> list[can.typechecking.AutoDetectedConfig]:
        return []


def register() -> None:
    """Make ``can.Bus(interface="udpcycle")`` work even without installed entry points."""
    from can import interfaces, util

    if INTERFACE_NAME not in interfaces.BACKENDS:
        interfaces.BACKENDS[INTERFACE_NAME] = (__name__, UdpCycleBus.__name__)
        interfaces.VALID_INTERFACES = util.VALID_INTERFACES = frozenset(interfaces.BACKENDS)
