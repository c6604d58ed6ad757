"""Settings of the served cell side (``cosim serve``, and the cell process of a paced split run):
addresses, window, polling.

Every default lives here with its unit; ``python -m cosim serve`` options override them.
"""
from __future__ import annotations

from dataclasses import dataclass

#: The cell's UDP address by default (loopback: a controller on the same host).
DEFAULT_CHANNEL = "127.0.0.1:47400"
#: Fraction of the bus cycle the cell waits, after its cycle starts, for the controller's
#: SoC + PReqs of that cycle (s = fraction x cycle). Class value: half the cycle leaves the
#: other half for the plant and drive steps, the tracker and the recorder.
DEFAULT_WINDOW_FRACTION = 0.5
#: Seconds the pacer busy-waits before each cycle's deadline (the kernel wakes a sleeper
#: ~37 µs late median, 155 µs p99 on the 2-core development VM, docs/explanation/timing.md: sleep, then spin).
DEFAULT_SPIN_S = 150e-6
#: Name of the endpoint description written into the results folder before the first cycle.
ENDPOINT_FILE = "hil_endpoint.json"
#: The cell's own interface: one datagram per POWERLINK cycle (fieldbus/udpcycle.py). Any other
#: python-can interface serves the cell frame by frame to a CANopen master (cosim/hil/can_side.py).
UDPCYCLE = "udpcycle"
#: Seconds without a SYNC, after the master's first, that end a run on a python-can bus (the
#: master stopped its SYNC: its session is over). Class value: 100 cycles of a slow CANopen
#: master (10 ms), far beyond any stall of a Python master measured here.
DEFAULT_SYNC_TIMEOUT_S = 1.0


class ServeSettingsError(ValueError):
    """A serve option with a bad value (names the option and what was expected)."""


@dataclass(frozen=True)
class ServeSettings:
    """How the cell side meets its controller.

    channel: the cell's ``host:port`` (a unicast address to bind, or a multicast group).
    peer: the controller's ``host:port``; None = the sender of the first valid datagram.
    accept_from: hosts or ``host:port`` whose datagrams are accepted; others are counted
        as foreign and dropped. None: only the peer's (given or learned), so that another
        program sending to the cell's port cannot inject frames.
    window_fraction: the part of the cycle the cell waits for the controller's frames.
    spin_s: busy-wait before each cycle's deadline, s.
    busy_poll_s: the cell's socket polling while it waits, s (0: sleep in select).
    scheduling: 'fifo' (SCHED_FIFO when granted) or 'normal'; cpu: pin to a CPU or None.
    lock_memory: mlockall the cell's process for the paced loop (no page faults from disk).
    wait_for_controller_s: wait up to this many seconds, after the endpoint description is
        written, for the controller's first datagram and make its arrival cycle 0 (the run then
        lasts stop_time from the controller's start, as a cell whose managing node starts the
        cycle); None: start at once, never wait. On a python-can bus: wait up to this many seconds
        for the master's first SYNC (None: as long as it takes).
    interface: ``udpcycle`` (the cell's own datagrams) or any python-can interface; then the
        cell is six CANopen drives driven by the master's SYNC (cosim/hil/can_side.py) on
        ``can.Bus(interface, channel, bitrate=bitrate, **bus_kwargs)``.
    sync_timeout_s: on a python-can bus, the run ends this long after the master's last SYNC.
    """

    channel: str = DEFAULT_CHANNEL
    peer: str | None = None
    accept_from: tuple[str, ...] | None = None
    window_fraction: float = DEFAULT_WINDOW_FRACTION
    spin_s: float = DEFAULT_SPIN_S
    busy_poll_s: float = 0.0
    scheduling: str = "fifo"
    cpu: str | None = None
    lock_memory: bool = True
    wait_for_controller_s: float | None = None
    interface: str = UDPCYCLE
    bitrate: int | None = None
    bus_kwargs: dict | None = None
    sync_timeout_s: float = DEFAULT_SYNC_TIMEOUT_S

    @property
    def canopen(self) -> bool:
        """True: the cell is a CANopen network on a python-can bus (any interface but udpcycle)."""
        return self.interface != UDPCYCLE

    def __post_init__(self) -> None:
        if not isinstance(self.interface, str) or not self.interface.strip():
            raise ServeSettingsError(f"--interface {self.interface!r}: expected a python-can interface name, e.g. "
                                     f"udp_multicast, virtual, socketcan, pcan (default {UDPCYCLE})")
        if self.bitrate is not None and (isinstance(self.bitrate, bool) or not isinstance(self.bitrate, int)
                                         or not 10_000 <= self.bitrate <= 8_000_000):
            raise ServeSettingsError(f"--bitrate {self.bitrate!r}: expected bit/s in 10000..8000000, e.g. 1000000")
        if not 0.01 <= self.sync_timeout_s <= 3600.0:
            raise ServeSettingsError(f"--sync-timeout {self.sync_timeout_s!r}: expected seconds in [0.01, 3600]")
        if self.canopen:
            if not str(self.channel).strip():
                raise ServeSettingsError(f"--channel {self.channel!r}: expected the channel of interface "
                                         f"{self.interface!r}, e.g. 239.74.163.2 (udp_multicast), can0 (socketcan)")
            return
        for name in ("channel",) + (("peer",) if self.peer is not None else ()):
            value = getattr(self, name)
            host, sep, port = str(value).rpartition(":")
            if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
                raise ServeSettingsError(f"--{name} {value!r}: expected host:port with a port 1..65535, "
                                         f"e.g. 127.0.0.1:47400")
        if not 0.05 <= self.window_fraction <= 0.95:
            raise ServeSettingsError(f"--window {self.window_fraction!r}: expected a fraction of the cycle "
                                     f"in [0.05, 0.95]")
        if not 0.0 <= self.spin_s <= 0.01 or not 0.0 <= self.busy_poll_s <= 0.01:
            raise ServeSettingsError(f"spin {self.spin_s!r} s / busy poll {self.busy_poll_s!r} s: expected "
                                     f"0 .. 0.01 s")
        if self.wait_for_controller_s is not None and not 0.0 < self.wait_for_controller_s <= 3600.0:
            raise ServeSettingsError(f"--wait-for-controller {self.wait_for_controller_s!r}: expected seconds in "
                                     f"(0, 3600]")
        if self.scheduling not in ("fifo", "normal"):
            raise ServeSettingsError(f"--scheduling {self.scheduling!r}: expected 'fifo' or 'normal'")

    def bus_options(self) -> dict:
        """The ``udpcycle`` options of the cell's bus."""
        options: dict = {"latency_samples": 1 << 20, "busy_poll_s": self.busy_poll_s,
                         "peer_only": self.accept_from is None}
        if self.peer is not None:
            options["peer"] = self.peer
        if self.accept_from is not None:
            options["accept_from"] = list(self.accept_from)
        return options

    def as_dict(self) -> dict:
        return {"channel": self.channel, "peer": self.peer,
                "accept_from": None if self.accept_from is None else list(self.accept_from),
                "window_fraction": self.window_fraction, "spin_us": self.spin_s * 1e6,
                "busy_poll_us": self.busy_poll_s * 1e6, "scheduling": self.scheduling, "cpu": self.cpu,
                "lock_memory": self.lock_memory, "wait_for_controller_s": self.wait_for_controller_s,
                "interface": self.interface, "bitrate": self.bitrate, "bus_options": dict(self.bus_kwargs or {}),
                "sync_timeout_s": self.sync_timeout_s}
