"""POWERLINK cycle timing in simulated time.

One cycle k starts with the SoC at ``t_k = start_time + k * cycle_time`` (plus the MN's
SoC jitter). Then, node after node, the MN sends a PReq (unicast) and the addressed
CN answers with a PRes; after the last PRes the MN sends the SoA, one asynchronous
frame follows, and the network idles until the next SoC::

    SoC | PReq1 PRes1 | PReq2 PRes2 | ... | PReqN PResN | SoA | async | idle

Every frame's wire time is its size at the bit rate: Ethernet overhead (preamble,
MAC header, FCS, inter-frame gap) plus the POWERLINK payload padded to the Ethernet
minimum. A frame to or from node n passes ``hops(n)`` repeating hubs and cable
segments (line topology: n; star: 1). The MN sends a PReq ``mn_turnaround`` after
the previous PRes has fully arrived (or after the PRes timeout ran out); a CN answers
``cn_response_time`` (+ jitter) after its PReq has fully arrived.

Timestamps: a frame's simulated timestamp is the time its first bit leaves the
sender; for a frame delayed in the network (fault "late") the delay is added, as a
capture next to the receiver would see it.

Set-point and sampling instants of the co-simulation stay on the nominal grid t_k
(the FMUs are stepped at fixed communication points); the SoC jitter (sub-µs) only
moves frame timestamps and the SoC-jitter check of the CNs.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from fieldbus.errors import FieldbusConfigError
from fieldbus.telegrams import PRES_PAYLOAD_BYTES, rpdo1_length

if TYPE_CHECKING:  # annotations only: fieldbus.config imports this module for its cycle-budget check
    from fieldbus.config import FieldbusConfig, TimingConfig
    from fieldbus.faults import CycleFaults

BLOCK_CYCLES = 1024  # cycles of jitter generated per numpy call

# frame index within a cycle: 0 = SoC, n = PReq of node n, N + n = PRes of node n
SOC_INDEX = 0


def wire_time(timing: "TimingConfig", powerlink_bytes: int) -> float:
    """Seconds one Ethernet frame with ``powerlink_bytes`` after the MAC header occupies
    the wire (padded to the minimum payload, plus preamble, header, FCS, gap)."""
    payload = max(powerlink_bytes, timing.min_ethernet_payload_bytes)
    return (payload + timing.ethernet_overhead_bytes) * 8.0 / timing.bit_rate_bit_s


def propagation_delay(timing: "TimingConfig", node: int) -> float:
    """Seconds between the MN and node ``node`` through hubs and cables (one way)."""
    hops = node if timing.topology == "line" else 1
    cables = node if timing.topology == "line" else 2
    return hops * timing.hub_latency_s + cables * timing.cable_delay_s


@dataclass(frozen=True)
class CycleLayout:
    """Static frame timing of one cycle (seconds), without jitter or faults."""

    cycle_time: float
    wire_soc: float
    wire_preq: float
    wire_pres: float
    wire_soa: float
    wire_async: float
    propagation: tuple[float, ...]  # index = node id, [0] = 0
    mn_turnaround: float
    cn_response: float
    pres_timeout: float
    nominal_soc_to_preq: tuple[float, ...]  # index = node id: PReq start offset from SoC
    nominal_soc_to_pres: tuple[float, ...]  # index = node id: PRes start offset from SoC
    nominal_end_of_isochronous: float  # last PRes fully at the MN
    nominal_end_of_async: float  # SoA, async frame done
    worst_case_end_of_async: float  # every PRes at max jitter or timed out, max SoC jitter

    @classmethod
    def from_config(cls, config: "FieldbusConfig") -> "CycleLayout":
        t = config.timing
        nodes = config.nodes
        wire_soc = wire_time(t, t.soc_frame_bytes)
        # the PReq's PDO payload: the RPDO1, longer with a set-point look-ahead
        wire_preq = wire_time(t, t.preq_header_bytes + rpdo1_length(getattr(config, "setpoint_lookahead", 0)))
        wire_pres = wire_time(t, t.pres_header_bytes + PRES_PAYLOAD_BYTES)
        wire_soa = wire_time(t, t.soa_frame_bytes)
        wire_async = wire_time(t, t.async_frame_bytes)
        prop = (0.0,) + tuple(propagation_delay(t, n) for n in range(1, nodes + 1))
        preq = [0.0] * (nodes + 1)
        pres = [0.0] * (nodes + 1)
        mn_free = wire_soc
        worst = t.soc_jitter_s + wire_soc
        for n in range(1, nodes + 1):
            preq[n] = mn_free + t.mn_turnaround_s
            pres[n] = preq[n] + wire_preq + prop[n] + t.cn_response_time_s
            mn_free = pres[n] + prop[n] + wire_pres
            answered = (t.mn_turnaround_s + wire_preq + 2 * prop[n] + t.cn_response_time_s
                        + t.response_jitter_s + wire_pres)
            timed_out = t.mn_turnaround_s + wire_preq + t.pres_timeout_s
            worst += max(answered, timed_out)
        async_tail = t.mn_turnaround_s + wire_soa + t.cn_response_time_s + wire_async + max(prop)
        return cls(
            cycle_time=config.cycle_time_s, wire_soc=wire_soc, wire_preq=wire_preq,
            wire_pres=wire_pres, wire_soa=wire_soa, wire_async=wire_async, propagation=prop,
            mn_turnaround=t.mn_turnaround_s, cn_response=t.cn_response_time_s,
            pres_timeout=t.pres_timeout_s,
            nominal_soc_to_preq=tuple(preq), nominal_soc_to_pres=tuple(pres),
            nominal_end_of_isochronous=mn_free, nominal_end_of_async=mn_free + async_tail,
            worst_case_end_of_async=worst + async_tail,
        )


def check_cycle_budget(config: "FieldbusConfig") -> CycleLayout:
    """Raise :class:`FieldbusConfigError` when the worst-case frame schedule (every PRes
    at maximum jitter or timed out, plus SoA and the asynchronous frame) does not fit
    into the cycle time."""
    layout = CycleLayout.from_config(config)
    if layout.worst_case_end_of_async > config.cycle_time_s:
        raise FieldbusConfigError(
            config.source, "cycle_time_us", config.cycle_time_s * 1e6,
            f"at least {layout.worst_case_end_of_async * 1e6:.1f} us: the worst-case schedule "
            f"of {config.nodes} nodes (SoC, PReq/PRes or PRes timeout per node, SoA, "
            f"{config.timing.async_frame_bytes}-byte async frame) does not fit")
    return layout


class CycleSchedule:
    """Simulated timestamps of all frames of any cycle, deterministic in (config, seed, k).

    ``timestamps(k)`` returns a list ``[soc, preq_1..preq_N, pres_1..pres_N]`` of frame
    start times in seconds; for cycles without faults it is read from a precomputed
    block (one numpy call per ``BLOCK_CYCLES`` cycles). ``faulty_timestamps`` recomputes
    one cycle frame by frame when faults change the sequence (lost or late frames,
    PRes timeouts); an entry is ``None`` for a frame that is not sent.
    """

    def __init__(self, config: "FieldbusConfig", layout: CycleLayout | None = None) -> None:
        self.config = config
        self.layout = layout or CycleLayout.from_config(config)
        self.nodes = config.nodes
        self._block_index = -1
        self._rows: list[list[float]] = []
        self._jitter: np.ndarray = np.zeros((0, 0))

    def nominal_soc_time(self, cycle: int) -> float:
        """t_k: the nominal SoC time of ``cycle`` (s), where set-points apply and actuals latch."""
        return self.config.start_time_s + cycle * self.config.cycle_time_s

    def _load_block(self, block: int) -> None:
        cfg = self.config
        t = cfg.timing
        lay = self.layout
        n_nodes = self.nodes
        rng = np.random.default_rng((cfg.seed, 1, block))
        unit = rng.uniform(-1.0, 1.0, size=(BLOCK_CYCLES, n_nodes + 1))
        jitter = unit * np.array([t.soc_jitter_s] + [t.response_jitter_s] * n_nodes)
        cycles = np.arange(block * BLOCK_CYCLES, (block + 1) * BLOCK_CYCLES)
        soc = cfg.start_time_s + cycles * cfg.cycle_time_s + jitter[:, 0]
        rows = np.empty((BLOCK_CYCLES, 2 * n_nodes + 1))
        rows[:, 0] = soc
        mn_free = soc + lay.wire_soc
        for n in range(1, n_nodes + 1):
            preq = mn_free + lay.mn_turnaround
            pres = preq + lay.wire_preq + lay.propagation[n] + lay.cn_response + jitter[:, n]
            rows[:, n] = preq
            rows[:, n_nodes + n] = pres
            mn_free = pres + lay.propagation[n] + lay.wire_pres
        self._rows = rows.tolist()
        self._jitter = jitter
        self._block_index = block

    def timestamps(self, cycle: int) -> list[float]:
        """Frame start times of a fault-free ``cycle``: [soc, preq_1..N, pres_1..N] (s)."""
        block, row = divmod(cycle, BLOCK_CYCLES)
        if block != self._block_index:
            self._load_block(block)
        return self._rows[row]

    def faulty_timestamps(self, cycle: int, faults: "CycleFaults") -> list[float | None]:
        """Frame SEND times of ``cycle`` with ``faults`` applied.

        The SoC and every PReq are always sent (the medium may lose them); a PRes entry
        is None when the CN sends nothing: its PReq was lost or corrupted, or the node is
        silent. A lost PRes is sent and lost by the medium. Without an answer in time
        the MN waits for the PRes timeout before its next PReq. A late PReq or PRes is
        delayed ``late_delay`` in the network (the sender's time is returned here; the
        medium adds the delay to the frame's timestamp); the CN answers a late PReq
        after it arrived, and a PRes reaching the MN after the timeout is recorded but
        the MN has moved on. A late SoC means the MN started the cycle late: the SoC
        and everything after it move by ``late_delay``.
        """
        block, row = divmod(cycle, BLOCK_CYCLES)
        if block != self._block_index:
            self._load_block(block)
        jitter = self._jitter[row]
        lay = self.layout
        late = self.config.faults.late_delay_s
        n_nodes = self.nodes
        kinds = faults.kinds
        out: list[float | None] = [None] * (2 * n_nodes + 1)
        soc = self.nominal_soc_time(cycle) + float(jitter[0]) + (late if kinds.get(SOC_INDEX) == "late" else 0.0)
        out[0] = soc
        mn_free = soc + lay.wire_soc
        for n in range(1, n_nodes + 1):
            preq = mn_free + lay.mn_turnaround
            preq_kind = kinds.get(n)
            pres_kind = kinds.get(n_nodes + n)
            out[n] = preq
            deadline = preq + lay.wire_preq + lay.pres_timeout
            if preq_kind in ("loss", "corrupt") or pres_kind == "silent":
                mn_free = deadline
                continue
            preq_delay = late if preq_kind == "late" else 0.0
            pres = (preq + preq_delay + lay.wire_preq + lay.propagation[n] + lay.cn_response
                    + float(jitter[n]))
            out[n_nodes + n] = pres
            at_mn = pres + (late if pres_kind == "late" else 0.0) + lay.propagation[n]
            mn_free = deadline if (pres_kind == "loss" or at_mn > deadline) else at_mn + lay.wire_pres
        return out
