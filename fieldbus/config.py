"""The fieldbus configuration: defaults from ``powerlink_defaults.toml`` merged with a
scenario's ``[fieldbus]`` table, validated, converted to SI units (seconds).

``FieldbusConfig.from_dict(table)`` is the one entry point; every bad value raises
:class:`~fieldbus.errors.FieldbusConfigError` naming the source, the dotted key, the
value given and what was expected.
"""
from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from decimal import Decimal
from functools import lru_cache
from pathlib import Path
from typing import Any

from fieldbus.asynchronous import AsyncRequest, parse_requests
from fieldbus.errors import FieldbusConfigError
from fieldbus.telegrams import (MAX_LOOKAHEAD, MAX_SETPOINT_BUFFER, RPDO1_LOOKAHEAD_ENTRY, RPDO1_MAX_BYTES,
                                RPDO1_SIGNED)
from fieldbus.timing import check_cycle_budget

DEFAULTS_PATH = Path(__file__).with_name("powerlink_defaults.toml")

#: Microseconds per second.
US_PER_S = 1_000_000


def us_to_s(value: float) -> float:
    """A time in microseconds as seconds, exact for the number as written: the decimal the float
    prints as, divided by 10^6 in decimal, rounded once (400 -> 4e-4, 0.1 -> 1e-7, as the scenario's
    "400 us" and "0.1 us"; multiplying by 1e-6 gives 0.00039999999999999996 and 1.0000000000000001e-07)."""
    return float(Decimal(repr(float(value))) / US_PER_S)

BURST_FRAMES = ("soc", "preq", "pres", "both")
FAULT_KINDS = ("loss", "late", "corrupt")
TOPOLOGIES = ("line", "star")
ABORT_OPTIONS = ("quick_stop", "fault")
MISSING_SETPOINT_POLICIES = ("hold", "extrapolate")


@lru_cache(maxsize=1)
def _defaults_document() -> dict[str, Any]:
    with DEFAULTS_PATH.open("rb") as handle:
        return tomllib.load(handle)


def defaults_table() -> dict[str, dict[str, Any]]:
    """All defaults as ``{dotted_key: {"value", "unit", "source"}}`` (for docs and summaries)."""
    flat: dict[str, dict[str, Any]] = {}

    def walk(prefix: str, table: Mapping[str, Any]) -> None:
        for key, item in table.items():
            dotted = f"{prefix}{key}"
            if isinstance(item, Mapping) and "value" in item:
                flat[dotted] = dict(item)
            elif isinstance(item, Mapping):
                walk(f"{dotted}.", item)

    walk("", _defaults_document())
    return flat


# ----------------------------------------------------------------------------------
# value rules


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: object) -> bool:
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(float(value)))


class _Rules:
    """Checks one value against its rule and raises with the key named."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, given: object, expected: str) -> None:
        raise FieldbusConfigError(self.source, key, given, expected)

    def integer(self, key: str, value: object, low: int | None = None,
                high: int | None = None) -> int:
        if not _is_int(value):
            self.fail(key, value, "an integer")
        assert isinstance(value, int)
        if (low is not None and value < low) or (high is not None and value > high):
            self.fail(key, value, f"an integer in [{low}, {high if high is not None else 'inf'}]")
        return value

    def number(self, key: str, value: object, low: float | None = None,
               high: float | None = None, low_open: bool = False) -> float:
        if not _is_number(value):
            self.fail(key, value, "a finite number")
        number = float(value)  # type: ignore[arg-type]
        if low is not None and (number < low or (low_open and number == low)):
            bound = f"> {low}" if low_open else f">= {low}"
            self.fail(key, value, f"a number {bound}" + (f" and <= {high}" if high is not None else ""))
        if high is not None and number > high:
            self.fail(key, value, f"a number <= {high}")
        return number

    def choice(self, key: str, value: object, choices: tuple[str, ...]) -> str:
        if not isinstance(value, str) or value not in choices:
            self.fail(key, value, "one of " + ", ".join(repr(c) for c in choices))
        assert isinstance(value, str)
        return value

    def boolean(self, key: str, value: object) -> bool:
        if not isinstance(value, bool):
            self.fail(key, value, "true or false")
        return bool(value)


# ----------------------------------------------------------------------------------
# configuration records (SI units)


@dataclass(frozen=True)
class BusConfig:
    """Which python-can bus carries the telegrams."""

    interface: str
    channel: str | int
    receive_timeout_s: float
    options: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class TimingConfig:
    """POWERLINK frame timing; all durations in seconds."""

    bit_rate_bit_s: float
    ethernet_overhead_bytes: int
    min_ethernet_payload_bytes: int
    soc_frame_bytes: int
    soa_frame_bytes: int
    preq_header_bytes: int
    pres_header_bytes: int
    async_frame_bytes: int
    topology: str
    hub_latency_s: float
    cable_delay_s: float
    mn_turnaround_s: float
    cn_response_time_s: float
    pres_timeout_s: float
    soc_jitter_s: float
    response_jitter_s: float
    cn_soc_jitter_range_s: float


@dataclass(frozen=True)
class ThresholdConfig:
    """POWERLINK threshold counters: thresholds in counts, 0 disables."""

    increment: int
    decrement: int
    cn_loss_of_soc: int
    cn_loss_of_preq: int
    cn_crc_error: int
    cn_soc_jitter: int
    mn_loss_of_pres: int
    mn_late_pres: int
    mn_crc_error: int


@dataclass(frozen=True)
class ReactionConfig:
    """What a controlled node does when a counter trips, and on a missing set-point."""

    abort_connection_option: str
    missing_setpoint: str


@dataclass(frozen=True)
class ScalingUnits:
    """Telegram units (the per-joint scaling comes from the caller, see fieldbus.scaling)."""

    torque_units_per_rated: int
    velocity_unit: str
    sync_counter_overflow: int


@dataclass(frozen=True)
class FaultBurst:
    """Deterministic fault on ``frames`` of ``node`` for ``cycles`` cycles from ``start_cycle``."""

    node: int
    start_cycle: int
    cycles: int
    frames: str
    kind: str

    def active(self, cycle: int) -> bool:
        return self.start_cycle <= cycle < self.start_cycle + self.cycles


@dataclass(frozen=True)
class SilentNode:
    """Controlled node ``node`` sends no PRes in cycles [from_cycle, until_cycle)."""

    node: int
    from_cycle: int
    until_cycle: int | None

    def active(self, cycle: int) -> bool:
        return cycle >= self.from_cycle and (self.until_cycle is None or cycle < self.until_cycle)


@dataclass(frozen=True)
class FaultConfig:
    """Fault injection: per-frame probabilities, late delay (s), bursts, silent nodes."""

    loss_probability: float
    late_probability: float
    late_delay_s: float
    corrupt_probability: float
    bursts: tuple[FaultBurst, ...]
    silent_nodes: tuple[SilentNode, ...]

    @property
    def random_enabled(self) -> bool:
        return (self.loss_probability > 0.0 or self.late_probability > 0.0
                or self.corrupt_probability > 0.0)


@dataclass(frozen=True)
class RecordingConfig:
    """How recorded frames reach the python-can Logger."""

    flush_every_cycles: int
    background: bool


@dataclass(frozen=True)
class FieldbusConfig:
    """Complete, validated fieldbus configuration (SI units)."""

    nodes: int
    cycle_time_s: float
    dead_time_cycles: int
    start_time_s: float
    seed: int
    bus: BusConfig
    timing: TimingConfig
    thresholds: ThresholdConfig
    reaction: ReactionConfig
    scaling: ScalingUnits
    faults: FaultConfig
    recording: RecordingConfig
    source: str = "<dict>"
    setpoint_lookahead: int = 0
    setpoint_buffer: int = 0
    #: the scripted SDO/NMT requests of the asynchronous phase (``[[fieldbus.asynchronous]]``)
    asynchronous: tuple[AsyncRequest, ...] = ()

    @property
    def planned_ahead_cycles(self) -> int:
        """Cycles a controller on this bus computes its set-points ahead of the plain
        cyclic synchronous timing: ``setpoint_buffer`` when the drives buffer set-points,
        else ``setpoint_lookahead``."""
        return self.setpoint_buffer or self.setpoint_lookahead

    @property
    def lead_cycles(self) -> int:
        """Cycles from a controller computing a set-point to the drive applying it:
        1 (into the next cycle's PReq) + ``dead_time_cycles`` + :attr:`planned_ahead_cycles`
        (a controller sending set-points ahead computes each that many cycles early)."""
        return 1 + self.dead_time_cycles + self.planned_ahead_cycles

    @property
    def node_ids(self) -> range:
        """CANopen/POWERLINK node ids of the controlled nodes (1..nodes)."""
        return range(1, self.nodes + 1)

    @classmethod
    def from_dict(cls, table: Mapping[str, Any] | None = None,
                  source: str = "<dict>") -> "FieldbusConfig":
        """Build from a ``[fieldbus]`` table (nested dict, bare values); missing keys
        take the defaults of ``powerlink_defaults.toml``."""
        values = _merge(table or {}, source)
        config = _build(values, source)
        # the frame schedule must fit in the cycle (checked with the timing model)
        check_cycle_budget(config)
        return config

    @classmethod
    def from_toml(cls, path: str | Path) -> "FieldbusConfig":
        """Build from the ``[fieldbus]`` table of a scenario TOML file (may be absent)."""
        path = Path(path)
        try:
            with path.open("rb") as handle:
                document = tomllib.load(handle)
        except (OSError, tomllib.TOMLDecodeError) as error:
            raise FieldbusConfigError(str(path), "<file>", str(error),
                                      "a readable TOML file") from error
        table = document.get("fieldbus", {})
        if not isinstance(table, Mapping):
            raise FieldbusConfigError(str(path), "<table>", table, "a [fieldbus] table")
        return cls.from_dict(table, source=str(path))


_EXTRA_KEYS = {"bus.options"}  # keys without a default value


def _merge(table: Mapping[str, Any], source: str) -> dict[str, Any]:
    """Flatten defaults and overlay the user's table; unknown keys are errors."""
    defaults = {key: item["value"] for key, item in defaults_table().items()}
    values = dict(defaults)
    values["bus.options"] = {}
    sections = {key.split(".")[0] for key in defaults if "." in key}

    def walk(prefix: str, user: Mapping[str, Any]) -> None:
        for key, value in user.items():
            if not isinstance(key, str):
                raise FieldbusConfigError(source, f"{prefix}{key!r}", value, "string keys")
            dotted = f"{prefix}{key}"
            if dotted in defaults or dotted in _EXTRA_KEYS:
                values[dotted] = value
            elif not prefix and key in sections:
                if not isinstance(value, Mapping):
                    raise FieldbusConfigError(source, dotted, value, f"a table [fieldbus.{key}]")
                walk(f"{dotted}.", value)
            else:
                known = sorted(k for k in list(defaults) + sorted(_EXTRA_KEYS)
                               if k.startswith(prefix) and k.count(".") == prefix.count("."))
                raise FieldbusConfigError(source, dotted, value,
                                          "a known key: " + ", ".join(known))

    walk("", table)
    return values


def _build(v: dict[str, Any], source: str) -> FieldbusConfig:
    r = _Rules(source)
    nodes = r.integer("nodes", v["nodes"], 1, 127)

    channel = v["bus.channel"]
    if not isinstance(channel, (str, int)) or isinstance(channel, bool):
        r.fail("bus.channel", channel, "a string or integer channel")
    options = v["bus.options"]
    if not isinstance(options, Mapping):
        r.fail("bus.options", options, "a table of extra can.Bus keyword arguments")
    interface = v["bus.interface"]
    if not isinstance(interface, str) or not interface:
        r.fail("bus.interface", interface, "a python-can interface name such as 'simbus', 'virtual', 'udp_multicast'")
    bus = BusConfig(interface=interface, channel=channel,
                    receive_timeout_s=r.number("bus.receive_timeout_s", v["bus.receive_timeout_s"], 0.0, 60.0, low_open=True),
                    options=dict(options))

    def us(key: str, low: float = 0.0, low_open: bool = False) -> float:
        return us_to_s(r.number(key, v[key], low, None, low_open))

    def count(key: str, low: int = 0, high: int | None = None) -> int:
        return r.integer(key, v[key], low, high)

    timing = TimingConfig(
        bit_rate_bit_s=r.number("timing.bit_rate_mbit_s", v["timing.bit_rate_mbit_s"], 0.0, None, low_open=True) * 1e6,
        ethernet_overhead_bytes=count("timing.ethernet_overhead_bytes"),
        min_ethernet_payload_bytes=count("timing.min_ethernet_payload_bytes"),
        soc_frame_bytes=count("timing.soc_frame_bytes", 1),
        soa_frame_bytes=count("timing.soa_frame_bytes", 1),
        preq_header_bytes=count("timing.preq_header_bytes"),
        pres_header_bytes=count("timing.pres_header_bytes"),
        async_frame_bytes=count("timing.async_frame_bytes"),
        topology=r.choice("timing.topology", v["timing.topology"], TOPOLOGIES),
        hub_latency_s=us("timing.hub_latency_us"),
        cable_delay_s=us("timing.cable_delay_us"),
        mn_turnaround_s=us("timing.mn_turnaround_us"),
        cn_response_time_s=us("timing.cn_response_time_us"),
        pres_timeout_s=us("timing.pres_timeout_us", 0.0, low_open=True),
        soc_jitter_s=us("timing.soc_jitter_us"),
        response_jitter_s=us("timing.response_jitter_us"),
        cn_soc_jitter_range_s=us("timing.cn_soc_jitter_range_us", 0.0, low_open=True),
    )
    if timing.response_jitter_s > timing.cn_response_time_s:
        r.fail("timing.response_jitter_us", v["timing.response_jitter_us"],
               f"at most timing.cn_response_time_us = {v['timing.cn_response_time_us']} (responses cannot precede requests)")

    thresholds = ThresholdConfig(
        increment=count("thresholds.increment", 1),
        decrement=count("thresholds.decrement", 0),
        **{name: count(f"thresholds.{name}") for name in (
            "cn_loss_of_soc", "cn_loss_of_preq", "cn_crc_error", "cn_soc_jitter",
            "mn_loss_of_pres", "mn_late_pres", "mn_crc_error")},
    )
    reaction = ReactionConfig(
        abort_connection_option=r.choice("reaction.abort_connection_option",
                                         v["reaction.abort_connection_option"], ABORT_OPTIONS),
        missing_setpoint=r.choice("reaction.missing_setpoint", v["reaction.missing_setpoint"],
                                  MISSING_SETPOINT_POLICIES),
    )
    scaling = ScalingUnits(
        torque_units_per_rated=count("scaling.torque_units_per_rated", 1, 32767),
        velocity_unit=r.choice("scaling.velocity_unit", v["scaling.velocity_unit"], ("counts/s",)),
        sync_counter_overflow=count("scaling.sync_counter_overflow", 2, 240),
    )

    def probability(key: str) -> float:
        return r.number(key, v[key], 0.0, 1.0)

    faults = FaultConfig(
        loss_probability=probability("faults.loss_probability"),
        late_probability=probability("faults.late_probability"),
        late_delay_s=us("faults.late_delay_us"),
        corrupt_probability=probability("faults.corrupt_probability"),
        bursts=tuple(_burst(r, i, item, nodes) for i, item in enumerate(_list(r, "faults.bursts", v["faults.bursts"]))),
        silent_nodes=tuple(_silent(r, i, item, nodes) for i, item in enumerate(_list(r, "faults.silent_nodes", v["faults.silent_nodes"]))),
    )
    if faults.loss_probability + faults.late_probability + faults.corrupt_probability > 1.0:
        r.fail("faults.loss_probability", v["faults.loss_probability"],
               "loss + late + corrupt probabilities summing to at most 1")
    recording = RecordingConfig(
        flush_every_cycles=count("recording.flush_every_cycles", 1),
        background=r.boolean("recording.background", v["recording.background"]),
    )
    return FieldbusConfig(
        nodes=nodes,
        cycle_time_s=us_to_s(r.number("cycle_time_us", v["cycle_time_us"], 0.0, None, low_open=True)),
        dead_time_cycles=r.integer("dead_time_cycles", v["dead_time_cycles"], 1, 10_000),
        start_time_s=r.number("start_time_s", v["start_time_s"]),
        seed=r.integer("seed", v["seed"], 0),
        setpoint_lookahead=_lookahead(r, v["setpoint_lookahead"]),
        setpoint_buffer=_buffer(r, v["setpoint_buffer"], v["setpoint_lookahead"], v["dead_time_cycles"]),
        asynchronous=parse_requests(v["asynchronous"], nodes, r.fail),
        bus=bus, timing=timing, thresholds=thresholds, reaction=reaction,
        scaling=scaling, faults=faults, recording=recording, source=source,
    )


def _lookahead(r: _Rules, value: object) -> int:
    if not _is_int(value) or not 0 <= value <= MAX_LOOKAHEAD:  # type: ignore[operator]
        r.fail("setpoint_lookahead", value,
               f"an integer number of cycles in [0, {MAX_LOOKAHEAD}] (the RPDO1 carries {RPDO1_SIGNED.size} bytes "
               f"+ {RPDO1_LOOKAHEAD_ENTRY.size} per look-ahead cycle in at most {RPDO1_MAX_BYTES} bytes of CAN FD)")
    return int(value)  # type: ignore[arg-type]


def _buffer(r: _Rules, value: object, lookahead: object, dead_time: object) -> int:
    if not _is_int(value) or not 0 <= value <= MAX_SETPOINT_BUFFER:  # type: ignore[operator]
        r.fail("setpoint_buffer", value,
               f"an integer number of cycles in [0, {MAX_SETPOINT_BUFFER}] (0x60C4 sub 1 maximum buffer size; "
               f"the PRes reports the fill in one byte)")
    if value and not (_is_int(lookahead) and 1 <= lookahead):  # type: ignore[operator]
        r.fail("setpoint_buffer", value, "0 with setpoint_lookahead = 0: each PReq refills the buffer with "
                                         "setpoint_lookahead entries (1..4), so set setpoint_lookahead >= 1")
    if value and value < lookahead:  # type: ignore[operator]
        r.fail("setpoint_buffer", value, f"at least setpoint_lookahead = {lookahead} cycles")
    if value and _is_int(dead_time) and value + dead_time > 255:  # type: ignore[operator]
        r.fail("setpoint_buffer", value, f"setpoint_buffer + dead_time_cycles ({dead_time}) <= 255 (the PRes "
                                         f"reports the set-points held in one byte)")
    return int(value)  # type: ignore[arg-type]


def _list(r: _Rules, key: str, value: object) -> list[Any]:
    if not isinstance(value, (list, tuple)):
        r.fail(key, value, "a list of tables")
    return list(value)  # type: ignore[arg-type]


def _table(r: _Rules, key: str, item: object, allowed: set[str], required: set[str]) -> Mapping[str, Any]:
    if not isinstance(item, Mapping):
        r.fail(key, item, "a table")
    assert isinstance(item, Mapping)
    unknown = set(item) - allowed
    if unknown:
        r.fail(f"{key}.{sorted(unknown)[0]}", item[sorted(unknown)[0]], "one of the keys " + ", ".join(sorted(allowed)))
    missing = required - set(item)
    if missing:
        r.fail(f"{key}.{sorted(missing)[0]}", None, "a value (required key)")
    return item


def _burst(r: _Rules, index: int, item: object, nodes: int) -> FaultBurst:
    key = f"faults.bursts[{index}]"
    table = _table(r, key, item, {"node", "start_cycle", "cycles", "frames", "kind"},
                   {"start_cycle", "cycles", "frames"})
    frames = r.choice(f"{key}.frames", table["frames"], BURST_FRAMES)
    if frames == "soc":
        node = r.integer(f"{key}.node", table.get("node", 0), 0, nodes)
    else:
        if "node" not in table:
            r.fail(f"{key}.node", None, f"a node id in [1, {nodes}] for frames = {frames!r}")
        node = r.integer(f"{key}.node", table["node"], 1, nodes)
    return FaultBurst(
        node=node,
        start_cycle=r.integer(f"{key}.start_cycle", table["start_cycle"], 0),
        cycles=r.integer(f"{key}.cycles", table["cycles"], 1),
        frames=frames,
        kind=r.choice(f"{key}.kind", table.get("kind", "loss"), FAULT_KINDS),
    )


def _silent(r: _Rules, index: int, item: object, nodes: int) -> SilentNode:
    key = f"faults.silent_nodes[{index}]"
    table = _table(r, key, item, {"node", "from_cycle", "until_cycle"}, {"node", "from_cycle"})
    start = r.integer(f"{key}.from_cycle", table["from_cycle"], 0)
    until = table.get("until_cycle")
    if until is not None:
        until = r.integer(f"{key}.until_cycle", until, start + 1)
    return SilentNode(node=r.integer(f"{key}.node", table["node"], 1, nodes),
                      from_cycle=start, until_cycle=until)
