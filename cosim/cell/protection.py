"""The machine's protection in a cell run: the events of the drives' limits and the plant's end stops,
and the check of the protection parameters a scenario sets.

The servo drives enforce CiA 402 limits (max torque/current with I2t derating, max motor speed,
software position limits, following error window and time; docs/explanation/fmus.md "Protection") and report
them in their ``limit_status`` / ``limit_history`` outputs; the plant reports end-stop contacts
(``end_stop_contacts``, ``end_stop_impact_speed``, ``end_stop_impact_time``,
``end_stop_max_penetration``). The cell records these with every run
(:data:`PROTECTION_SIGNALS`); :func:`protection_events` turns the recording into one event per
onset (the record of the verdict contract, cosim/cell/verdict.py), which
:func:`cosim.execution.run_cell` stores in ``CellRun.protection_events`` in every execution mode.

Resolution: the drives' bits hold what was active at any sample of the last co-simulation step, the
recorder samples them every record period (1 ms by default): an event's ``time_s`` is the first
recorded sample that shows it; a limit that ends and comes back within one record period is one
event; ``limit_history`` catches one that came and went between two samples. End-stop contacts
carry the plant's own onset time and impact speed (interpolated inside its integration sub-step).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from cosim.cell.wiring import DRIVES, PLANT
from fmus.servo_drive.spec import LIMIT_BITS

DRIVE_PROTECTION_OUTPUTS = ("limit_status", "limit_history")
PLANT_PROTECTION_OUTPUTS = ("end_stop_contacts", "end_stop_impact_speed", "end_stop_impact_time",
                            "end_stop_max_penetration")
PROTECTION_SIGNALS: tuple[str, ...] = (
    tuple(f"{d}.{name}" for name in DRIVE_PROTECTION_OUTPUTS for d in DRIVES)
    + tuple(f"{PLANT}.{name}[{k}]" for name in PLANT_PROTECTION_OUTPUTS for k in range(1, len(DRIVES) + 1)))
"""What every cell records for its protection events (where the drive / plant FMU has them)."""

# kind -> (CiA 402 error code in 0x603F or None, unit of value and limit, what it is)
KINDS: dict[str, tuple[str | None, str, str]] = {
    "torque_limit": (None, "N.m", "commanded torque beyond max torque 0x6072 / max current 0x6073: clamped"),
    "i2t": ("0x2310", "A", "I2t: current limit derated to the rated current 0x6075 (warning)"),
    "speed_limit": ("0x8400", "rad/s", "speed beyond max motor speed 0x6080"),
    "position_limit": ("0x8612", "rad", "position outside the software position limits 0x607D"),
    "following_error": ("0x8611", "rad", "following error beyond its window 0x6065"),
}


def sdo_parameter_changes(cell: Any, fieldbus: Mapping[str, Any] | None) -> dict[int, list[tuple[float, str, float]]]:
    """The drive parameters SDO writes changed during the run (``fieldbus.asynchronous`` of the
    run's fieldbus summary; cosim.cell.drive_objects): joint -> [(time from which it acts, s,
    parameter, SI value)], in time order."""
    slot = (fieldbus or {}).get("asynchronous") or {}
    writes = [r for r in slot.get("results", ()) if r.get("service") == "write" and r.get("answer") == "ok"
              and r.get("subindex") == 0 and r.get("index") in ("0x6065", "0x6066")]
    if not writes:
        return {}
    from cosim.cell.drive_objects import TUNABLE_OBJECTS, cell_object_dictionaries

    ods = {od.node: od for od in cell_object_dictionaries(cell.fieldbus)}
    t0, period = cell.fieldbus.start_time_s, cell.fieldbus.cycle_time_s
    out: dict[int, list[tuple[float, str, float]]] = {}
    for r in writes:
        name, scale = TUNABLE_OBJECTS[int(r["index"], 16)]
        factor = ods[r["node"]].rad_per_count if scale == "position" else scale
        out.setdefault(r["node"], []).append((t0 + r["answered_cycle"] * period, name, float(r["value"]) * factor))
    return out


def protection_events(cell: Any, recording: Any, fieldbus: Mapping[str, Any] | None = None) -> list[dict[str, Any]]:
    """The protection events of one run of ``cell`` (a :class:`cosim.cell.description.CellDescription`)
    from its ``recording`` (MemorySink-like: ``columns``, ``data``), earliest first.

    Each is a plain dict: ``kind`` (``torque_limit``, ``i2t``, ``speed_limit``, ``position_limit``,
    ``following_error``, ``end_stop``), ``joint`` (1..6), ``time_s`` (simulated), ``error_code``
    (``"0x8611"`` or None), ``value``, ``limit``, ``unit``, ``reaction`` (``"none"``, or ``"fault"``
    when the drive ran its fault reaction because of it: stop on the fault-reaction ramp, then the
    brake), ``detail``; ``duration_s`` once it has ended (``active_at_end`` True otherwise).
    End stops add ``impact_speed_rad_s``, ``stop_rad``, ``max_penetration_rad`` and ``contacts``.
    ``fieldbus``: the run's fieldbus summary; a following-error window an SDO write changed
    (:func:`sdo_parameter_changes`) is the limit from the cycle it acted.
    """
    if _streamed(recording) and not _may_have_events(recording):
        return []  # nothing to load: the whole recording is read only when a limit or a contact shows
    columns, data = _read(recording)
    if not columns or data is None or len(data) == 0 or "time" not in columns:
        return []
    index = {name: k for k, name in enumerate(columns)}
    time = data[:, index["time"]]
    params = {fmu["name"]: fmu.get("parameters", {}) for fmu in cell.document["fmus"]}
    events: list[dict[str, Any]] = []
    for joint, drive in enumerate(DRIVES, start=1):
        status, history = (index.get(f"{drive}.{name}") for name in DRIVE_PROTECTION_OUTPUTS)
        if status is None or history is None:
            continue
        events += _drive_events(joint, drive, data, index, time, data[:, status].astype(np.int64),
                                data[:, history].astype(np.int64), params.get(drive, {}))
    events += _end_stop_events(data, index, time, params.get(PLANT, {}))
    changes = sdo_parameter_changes(cell, fieldbus) if fieldbus else {}
    for event in events:
        if event["kind"] == "following_error" and event["joint"] in changes:
            for t, name, value in changes[event["joint"]]:
                if name == "following_error_window" and t <= event["time_s"] + 1e-12:
                    event["limit"] = value
    events.sort(key=lambda e: (e["time_s"], e["joint"] or 0))
    return events


def _streamed(recording: Any) -> bool:
    """True for a recording streamed to a file and not loaded (read back in chunks)."""
    return callable(getattr(recording, "chunks", None)) and getattr(recording, "_loaded", None) is None


def _may_have_events(recording: Any) -> bool:
    """Whether a streamed recording can hold a protection event, from one pass over chunks of the
    trigger columns only (bounded memory, whatever the run's length): a drive's ``limit_status``
    non-zero in some sample or its last ``limit_history`` non-zero, or a plant's
    ``end_stop_contacts`` non-zero in some sample (NaN counts as non-zero). False means
    :func:`protection_events` finds none; True, it reads the columns it needs for the events."""
    columns = list(getattr(recording, "columns", None) or [])
    status = [f"{d}.limit_status" for d in DRIVES]
    history = [f"{d}.limit_history" for d in DRIVES]
    contacts = [f"{PLANT}.end_stop_contacts[{k}]" for k in range(1, len(DRIVES) + 1)]
    always = [name for name in status + contacts if name in columns]
    last = [name for name in history if name in columns]
    if not always and not last:
        return False
    tail = None
    for _, block in recording.chunks(always + last):
        if len(block) == 0:
            continue
        if (block[:, :len(always)] != 0).any():
            return True
        tail = block[-1, len(always):]
    return tail is not None and bool((tail != 0).any())


def _read(recording: Any) -> tuple[list[str], np.ndarray | None]:
    """The columns the events need (time, the protection signals, joint angles and speeds, drive
    torques, currents and following errors) of a recording; a streamed file is read in chunks of
    those columns only."""
    columns = list(getattr(recording, "columns", None) or [])
    if not any(name in columns for name in PROTECTION_SIGNALS):
        return [], None
    wanted = [name for name in columns if name == "time" or name in PROTECTION_SIGNALS
              or name.startswith((f"{PLANT}.q[", f"{PLANT}.qd["))
              or name.endswith((".tau_out", ".current_actual", ".following_error"))]
    if _streamed(recording):
        parts = [block for _, block in recording.chunks(wanted)]
        return wanted, (np.concatenate(parts) if parts else np.zeros((0, len(wanted))))
    data = getattr(recording, "data", None)
    if data is None:
        return [], None
    take = [columns.index(name) for name in wanted]
    return wanted, np.asarray(data)[:, take]


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) row of each run of True in ``mask``."""
    if not mask.any():
        return []
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(edges == 1).tolist(), (np.flatnonzero(edges == -1) - 1).tolist()))


def _column(data: np.ndarray, index: Mapping[str, int], name: str) -> np.ndarray | None:
    k = index.get(name)
    return None if k is None else data[:, k]


def _drive_events(joint: int, drive: str, data: np.ndarray, index: Mapping[str, int], time: np.ndarray,
                  status: np.ndarray, history: np.ndarray, p: Mapping[str, Any]) -> list[dict[str, Any]]:
    out = []
    q = _column(data, index, f"{PLANT}.q[{joint}]")
    qd = _column(data, index, f"{PLANT}.qd[{joint}]")
    tau = _column(data, index, f"{drive}.tau_out")
    current = _column(data, index, f"{drive}.current_actual")
    fe = _column(data, index, f"{drive}.following_error")
    n = len(time)
    for kind, bit in LIMIT_BITS.items():
        code, unit, text = KINDS[kind]
        mask, fault_mask = (status >> bit) & 1 == 1, (status >> (bit + 8)) & 1 == 1
        runs = _runs(mask)
        if not runs and (int(history[-1]) >> bit) & 1:  # came and went between two recorded samples
            first = int(np.argmax((history >> bit) & 1 == 1))
            runs = [(first, first)]
        fault_onsets = [a for a, _ in _runs(fault_mask)]
        for a, b in runs:
            faulted = any(a <= f <= b + 1 for f in fault_onsets)
            fault_onsets = [f for f in fault_onsets if not a <= f <= b + 1]
            out.append(_drive_event(kind, joint, time, a, b, n, faulted, code, unit, text, p, q, qd, tau, current, fe))
        for f in fault_onsets:  # a fault whose limit was not in a recorded sample (e.g. shorter than a step)
            out.append(_drive_event(kind, joint, time, f, f, n, True, code, unit, text, p, q, qd, tau, current, fe))
    return out


def _drive_event(kind: str, joint: int, time: np.ndarray, a: int, b: int, n: int, faulted: bool, code: str | None,
                 unit: str, text: str, p: Mapping[str, Any], q, qd, tau, current, fe) -> dict[str, Any]:
    sl = slice(a, b + 1)
    value: float | None = None
    limit: float | None = None
    if kind == "torque_limit":
        n_kt = float(p.get("gear_ratio", math.nan)) * float(p.get("torque_constant", math.nan))
        limit = min(float(p.get("torque_limit", math.inf)), n_kt * float(p.get("current_limit", math.inf)))
        value = float(np.abs(tau[sl]).max()) if tau is not None else None
    elif kind == "i2t":
        limit = float(p["rated_current"]) if "rated_current" in p else None
        value = float(np.abs(current[:b + 1]).max()) if current is not None else None
    elif kind == "speed_limit":
        limit = float(p["max_motor_speed"]) if "max_motor_speed" in p else None
        value = float(np.abs(qd[sl]).max()) if qd is not None else None
    elif kind == "position_limit":
        lo, hi = float(p.get("position_limit_min", -math.inf)), float(p.get("position_limit_max", math.inf))
        if q is not None:
            low, high = float(q[sl].min()), float(q[sl].max())
            value, limit = (high, hi) if high - hi >= lo - low else (low, lo)
    elif kind == "following_error":
        limit = float(p["following_error_window"]) if "following_error_window" in p else None
        value = float(np.abs(fe[sl]).max()) if fe is not None else None
    event: dict[str, Any] = {
        "kind": kind, "joint": joint, "time_s": float(time[a]), "error_code": code if (faulted or kind == "i2t") else None,
        "value": value, "limit": limit, "unit": unit, "reaction": "fault" if faulted else "none",
        "detail": text + ("; fault reaction: stop on the fault-reaction ramp, then the brake" if faulted else "")}
    if b + 1 < n:
        event["duration_s"] = float(time[b + 1] - time[a])
    else:
        event["active_at_end"] = True
    return event


def _end_stop_events(data: np.ndarray, index: Mapping[str, int], time: np.ndarray,
                     p: Mapping[str, Any]) -> list[dict[str, Any]]:
    from robot.parameters import load_parameters

    robot = load_parameters()
    out = []
    for k in range(1, len(DRIVES) + 1):
        contacts, speed, onset, deepest = (_column(data, index, f"{PLANT}.{name}[{k}]")
                                           for name in PLANT_PROTECTION_OUTPUTS)
        if contacts is None or speed is None or onset is None:
            continue
        lower = float(p.get(f"end_stop_lower[{k}]", robot.end_stop_lower[k - 1]))
        upper = float(p.get(f"end_stop_upper[{k}]", robot.end_stop_upper[k - 1]))
        q = _column(data, index, f"{PLANT}.q[{k}]")
        counts = contacts.astype(np.int64)
        rows = np.flatnonzero(np.diff(np.concatenate(([0], counts))) > 0)
        for r in rows.tolist():
            added = int(counts[r] - (counts[r - 1] if r else 0))
            inside = None
            if q is not None:
                beyond = (q[r:] > upper) | (q[r:] < lower)
                inside = int(np.argmin(beyond)) if not beyond.all() else None
            stop = upper if q is not None and q[r] > 0.5 * (lower + upper) else lower
            event: dict[str, Any] = {
                "kind": "end_stop", "joint": k, "time_s": float(onset[r]), "error_code": None,
                "value": float(speed[r]), "limit": None, "unit": "rad/s", "reaction": "none",
                "detail": f"joint {k} hit its {'upper' if stop == upper else 'lower'} mechanical end stop "
                          f"({stop:.4f} rad) at {float(speed[r]):.4g} rad/s",
                "impact_speed_rad_s": float(speed[r]), "stop_rad": stop, "contacts": added,
                "max_penetration_rad": float(deepest[r if inside is None else r + inside]) if deepest is not None
                else None}
            if inside is not None and r + inside < len(time):
                event["duration_s"] = max(0.0, float(time[r + inside]) - float(onset[r]))
            else:
                event["active_at_end"] = True
            out.append(event)
    return out


def check_protection_parameters(doc: Mapping[str, Any], where: Any) -> None:
    """Bad input: a drive or plant protection parameter of the scenario's ``[[fmus]]`` outside what
    the drive and the arm allow (``where``: the scenario's :class:`cosim.scenario.schema.Where`).

    Per drive (its axis' defaults, fmus.servo_drive.params.drive_start_values, with the scenario's
    parameters on top): 0 < ``current_limit`` <= the drive's peak current (robot/rx130l_params.toml
    ``current_limit``); 0 < ``torque_limit`` <= its peak torque gear_ratio * torque_constant * peak
    current; 0 < ``rated_current`` <= ``current_limit``; ``max_motor_speed``, ``peak_current_time``
    > 0; ``following_error_window``, ``following_error_time`` >= 0; 0 <= ``i2t_release`` < 1;
    ``position_limit_min`` < ``position_limit_max``, both within the plant's end stops. Plant:
    ``end_stop_lower[k]`` < ``end_stop_upper[k]``, stiffness and damping >= 0.
    Raises ScenarioError at the key.
    """
    from fmus.servo_drive.params import drive_start_values
    from robot.parameters import load_parameters

    robot = load_parameters()
    fmus = list(doc.get("fmus") or [])
    by_name = {fmu.get("name"): (i, fmu) for i, fmu in enumerate(fmus)}
    plant_i, plant = by_name.get(PLANT, (None, {"parameters": {}}))
    plant_params = plant.get("parameters") or {}

    def at(i: int, key: str) -> Any:
        return (where / "fmus")[i] / "parameters" / key

    lowers, uppers = [], []
    for k in range(1, len(DRIVES) + 1):
        lo = plant_params.get(f"end_stop_lower[{k}]", float(robot.end_stop_lower[k - 1]))
        hi = plant_params.get(f"end_stop_upper[{k}]", float(robot.end_stop_upper[k - 1]))
        for key, value in ((f"end_stop_stiffness[{k}]", None), (f"end_stop_damping[{k}]", None)):
            value = plant_params.get(key)
            if value is not None and not (_number(value) and value >= 0):
                raise at(plant_i, key).error("a number >= 0 (N.m/rad, N.m.s/rad)", value)
        if not (_number(lo) and _number(hi) and lo < hi):
            key = f"end_stop_upper[{k}]" if f"end_stop_upper[{k}]" in plant_params else f"end_stop_lower[{k}]"
            raise at(plant_i, key).error(f"end_stop_lower[{k}] < end_stop_upper[{k}] (rad), got {lo!r} and {hi!r}",
                                         plant_params.get(key))
        lowers.append(float(lo))
        uppers.append(float(hi))
    for axis, drive in enumerate(DRIVES, start=1):
        if drive not in by_name:
            continue
        i, fmu = by_name[drive]
        given = fmu.get("parameters") or {}
        p = {**drive_start_values(axis), **given}
        j = axis - 1
        peak_current = float(robot.current_limit[j])
        n_kt = float(p["gear_ratio"]) * float(p["torque_constant"])

        def need(key: str, ok: bool, expected: str) -> None:
            if not ok:
                raise at(i, key).error(expected, p[key])

        for key in _PROTECTION_KEYS:
            if key in given and not _number(given[key]):
                raise at(i, key).error("a finite number", given[key])
        need("current_limit", 0 < p["current_limit"] <= peak_current,
             f"a max current (0x6073) in (0, {peak_current:g}] A (the drive's peak current, robot/rx130l_params.toml "
             f"current_limit of axis {axis})")
        peak_torque = n_kt * peak_current
        need("torque_limit", 0 < p["torque_limit"] <= peak_torque * (1 + 1e-12),
             f"a max torque (0x6072) in (0, {peak_torque:.6g}] N.m (the drive's peak torque: gear_ratio * "
             f"torque_constant * peak current {peak_current:g} A of axis {axis})")
        need("rated_current", 0 < p["rated_current"] <= p["current_limit"],
             f"a motor rated current (0x6075) in (0, {p['current_limit']:g}] A (at most current_limit)")
        need("peak_current_time", p["peak_current_time"] > 0, "a peak-current time > 0 s (I2t)")
        need("i2t_release", 0 <= p["i2t_release"] < 1, "a fraction in [0, 1) of the I2t threshold")
        need("max_motor_speed", p["max_motor_speed"] > 0, "a max motor speed (0x6080) > 0 rad/s (joint side)")
        need("following_error_window", p["following_error_window"] >= 0,
             "a following error window (0x6065) >= 0 rad (0 switches the supervision off)")
        need("following_error_time", p["following_error_time"] >= 0, "a following error time (0x6066) >= 0 s")
        stops = f"[{lowers[j]:.6g}, {uppers[j]:.6g}] rad (the plant's mechanical end stops of joint {axis})"
        need("position_limit_min", lowers[j] <= p["position_limit_min"] < p["position_limit_max"],
             f"a software position limit (0x607D min) below position_limit_max and within {stops}")
        need("position_limit_max", p["position_limit_max"] <= uppers[j],
             f"a software position limit (0x607D max) within {stops}")


_PROTECTION_KEYS = ("current_limit", "torque_limit", "rated_current", "peak_current_time", "i2t_release",
                    "max_motor_speed", "following_error_window", "following_error_time", "position_limit_min",
                    "position_limit_max")


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def summarize(events: Sequence[Mapping[str, Any]]) -> str:
    """One line naming the first protection event and how many there were ('' for none)."""
    if not events:
        return ""
    e = events[0]
    where = f"joint {e['joint']}" if e.get("joint") else "cell"
    code = f" {e['error_code']}" if e.get("error_code") else ""
    return f"{len(events)} protection event(s), first: {e['kind']}{code} on {where} at {e['time_s']:.4f} s"
