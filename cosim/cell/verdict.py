"""The verdict of a cell run: ``ok``, ``limit``, ``fault`` or ``failed`` (docs/reference/verdicts.md).

Every cell run (each mode of a job, each entry of ``compare``, a served, paced or split run)
is judged here and nowhere else, by :func:`judge`, from what the run itself recorded:

``failed``
    the run itself failed: ``run.failure`` is a simulation error (an FMU failed, a NaN, the
    controller raised or returned an unusable output) - not the controller's own stop after
    a drive or bus fault reaction, which is judged below;
``fault``
    a drive or bus fault reaction that no protection limit caused: a fieldbus threshold
    counter tripped (``fault_reaction`` events in ``run.fieldbus["faults"]``, the node
    faulted on the managing node's side, the communication fault on the drive's side), the
    controller stopped because a drive reported a fault, or the drives never reached
    *Operation enabled*;
``limit``
    a drive protection limit or a plant end stop was hit (``run.protection_events``: torque
    or current limit, I2t, maximum motor speed, software position limit, following error,
    end stop), also when that limit led to a CiA 402 fault reaction;
``ok``
    none of these.

Severity: ``interrupted`` > ``failed`` > ``fault`` > ``limit`` > ``ok``; a job's status is the
most severe verdict of its runs (:func:`most_severe`), and ``python -m cosim`` exits with that
verdict's code (:func:`exit_code`: 0, 4, 5, 3, 130).

A violation is a plain dict (the protection event record of the drives and the plant):
``kind``, ``joint`` (1..6 or None), ``time_s`` (simulated), ``error_code`` (CiA 402 0x603F
text such as ``"0x8611"``, or None), ``value``, ``limit``, ``unit``, ``reaction``
(``"none"``, ``"quick_stop"``, ``"fault"``) and ``detail``; a limit that stays active is one
event (its onset, ``duration_s`` when it ends). Compute-budget events (kind ``budget``)
are warnings, not violations.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

VERDICTS = ("ok", "limit", "fault", "failed")
"""The verdicts of a run, least severe first."""
SEVERITY = {"ok": 0, "limit": 1, "fault": 2, "failed": 3, "interrupted": 4}
"""Rank of each verdict and job status (higher is more severe)."""
MAX_VIOLATIONS = 200
"""Violations kept in a run's record (``violations_total`` counts them all)."""
VIOLATION_KINDS: dict[str, tuple[str, str]] = {
    "torque_limit": ("limit", "a drive clamped the commanded torque at its max torque / max current"),
    "current_limit": ("limit", "a drive clamped the current at its limit"),
    "i2t": ("limit", "a drive's I2t monitoring derated its current limit to the rated current"),
    "speed_limit": ("limit", "a joint ran faster than its drive's max motor speed; the drive's fault reaction "
                             "stops it"),
    "position_limit": ("limit", "a joint left its drive's software position limits; the drive's fault reaction "
                                "stops it"),
    "following_error": ("limit", "a drive's following error stayed beyond its window for its time-out; the "
                                 "drive's fault reaction stops it"),
    "end_stop": ("limit", "a joint of the plant hit its mechanical end stop"),
    "fault_reaction": ("fault", "a fieldbus threshold counter tripped: the managing node reports the node "
                                "faulted, the drive its communication fault"),
    "controller_stop": ("fault", "the controller stopped commanding motion because a drive reported a fault "
                                 "no protection limit caused"),
    "not_enabled": ("fault", "the drives never reached Operation enabled"),
    "failure": ("failed", "the run itself failed: an FMU failed, the controller raised or returned an "
                          "unusable output, the run could not start"),
    "close_error": ("failed", "the user controller's close() raised after the motion"),
    "refused": ("failed", "the run was refused before it started (a plan beyond the robot's limits)"),
}
"""Every ``kind`` of a violation: (the verdict it gives, what happened)."""
LIMIT_KINDS = frozenset(kind for kind, (verdict, _) in VIOLATION_KINDS.items() if verdict == "limit")
"""Protection event kinds of a drive limit or a plant end stop (verdict ``limit``)."""
WARNING_KINDS = frozenset({"budget"})
"""Event kinds that are warnings only (they do not change the verdict)."""
CHRONIC_BUDGET_FRACTION = 0.01
"""Share of controller cycles over their compute budget above which a run gets a budget warning."""
MOTION_STOPPED = "motion stopped"
PROTECTION_CODES = {"0x8611": "following_error", "0x8612": "position_limit", "0x8400": "speed_limit",
                    "0x2310": "i2t"}
"""CiA 402 error codes (0x603F) of the drives' protection limits: a controller stop on a drive fault with
one of these codes is the limit's reaction (verdict ``limit``), also when the run recorded no
protection event for it."""
"""How :class:`cosim.cell.link.FieldbusLink` words the end of a run after the controller stopped."""


@dataclass
class Verdict:
    """The judgement of one run: ``verdict`` (:data:`VERDICTS`), the violations (earliest first,
    at most :data:`MAX_VIOLATIONS`), the earliest one (None when there is none),
    ``violations_total`` (all of them) and ``warnings`` (e.g. compute-budget events)."""

    verdict: str
    violations: list[dict[str, Any]] = field(default_factory=list)
    first_violation: dict[str, Any] | None = None
    violations_total: int = 0
    warnings: list[dict[str, Any]] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.verdict == "ok"

    def fields(self) -> dict[str, Any]:
        """What a run's record in summary.json gets: ``verdict``, ``violations``,
        ``first_violation`` and, when the list was cut, ``violations_total`` and
        ``violations_cut``; ``warnings`` when there are any."""
        out: dict[str, Any] = {"verdict": self.verdict, "violations": list(self.violations),
                               "first_violation": self.first_violation}
        if self.violations_total > len(self.violations):
            out["violations_total"] = self.violations_total
            out["violations_cut"] = True
        if self.warnings:
            out["warnings"] = list(self.warnings)
        return out

    def describe(self) -> str:
        """One line: the verdict and, when not ok, its first violation."""
        if self.first_violation is None:
            return self.verdict
        return f"{self.verdict}: {describe_violation(self.first_violation)}"


def violation(kind: str, time_s: float | None, detail: str, *, joint: int | None = None,
              error_code: str | None = None, value: float | None = None, limit: float | None = None,
              unit: str | None = None, reaction: str = "none") -> dict[str, Any]:
    """A violation record (the protection event record's fields)."""
    return {"kind": kind, "joint": joint, "time_s": None if time_s is None else float(time_s),
            "error_code": error_code, "value": value, "limit": limit, "unit": unit, "reaction": reaction,
            "detail": detail}


def describe_violation(v: dict[str, Any]) -> str:
    """``following_error joint 3 at t = 1.234 s: 0.021 rad (limit 0.01 rad) (0x8611, quick_stop)``."""
    if v.get("kind") == "budget":
        return f"compute budget: {v.get('detail')}"
    if v.get("kind") == "overrun":
        return f"real time: {v.get('detail')}"
    if v.get("kind") == "refused":  # the detail names planner, joint, limit and time
        return str(v.get("detail"))
    parts = [str(v.get("kind") or "violation")]
    if v.get("joint") is not None:
        parts.append(f"joint {v['joint']}")
    if isinstance(v.get("time_s"), (int, float)) and math.isfinite(v["time_s"]):
        parts.append(f"at t = {v['time_s']:.6g} s")
    text = " ".join(parts)
    value, limit, unit = v.get("value"), v.get("limit"), v.get("unit") or ""
    numbers = ""
    if isinstance(value, (int, float)) and isinstance(limit, (int, float)):
        numbers = f"{value:.6g} {unit} (limit {limit:.6g} {unit})".replace(" )", ")").replace("  ", " ")
    extra = [x for x in (v.get("error_code"), None if v.get("reaction") in (None, "none") else v.get("reaction"))
             if x]
    detail = v.get("detail") or ""
    tail = "; ".join(x for x in (numbers, detail) if x)
    return text + (f": {tail}" if tail else "") + (f" ({', '.join(extra)})" if extra else "")


def most_severe(verdicts: Any) -> str:
    """The most severe of ``verdicts`` (names; ``"ok"`` for none)."""
    worst = "ok"
    for v in verdicts:
        if SEVERITY.get(v, SEVERITY["failed"]) > SEVERITY[worst]:
            worst = v if v in SEVERITY else "failed"
    return worst


def exit_code(status: str) -> int:
    """The exit code of a command whose most severe run ended ``status`` (cosim/results/exits.py)."""
    from cosim.results.exits import EXIT_FAILED, EXIT_FAULT, EXIT_INTERRUPTED, EXIT_LIMIT, EXIT_OK

    return {"ok": EXIT_OK, "limit": EXIT_LIMIT, "fault": EXIT_FAULT, "interrupted": EXIT_INTERRUPTED}.get(
        status, EXIT_FAILED)


def _is_controller_stop(failure: Any) -> bool:
    return (getattr(failure, "component", None) == "controller"
            and str(getattr(failure, "reason", "")).startswith(MOTION_STOPPED))


def _bus_faults(fieldbus: dict[str, Any] | None) -> list[dict[str, Any]]:
    """The fieldbus fault reactions of a run's fieldbus summary as violations."""
    out = []
    for e in (fieldbus or {}).get("faults") or ():
        if not isinstance(e, dict) or e.get("event") != "fault_reaction":
            continue
        side = e.get("side")
        node = e.get("node") or None
        reaction = "quick_stop" if side == "mn" else "fault"
        counter, threshold = e.get("counter"), e.get("threshold")
        what = "managing node" if side == "mn" else "controlled node"
        out.append(violation("fault_reaction", e.get("time_s"),
                             f"{what} {e.get('kind')} threshold counter {counter}/{threshold} in cycle "
                             f"{e.get('cycle')}: {e.get('detail')}", joint=node,
                             error_code="0x8100" if side == "cn" else None,
                             value=float(counter) if isinstance(counter, (int, float)) else None,
                             limit=float(threshold) if isinstance(threshold, (int, float)) else None,
                             unit="counts", reaction=reaction))
    return out


def judge(run: Any) -> Verdict:
    """The verdict of a :class:`cosim.cell.run.CellRun` (see the module docstring): from
    ``run.failure``, ``run.protection_events``, the fault reactions in ``run.fieldbus`` and
    whether the drives were ever enabled (``run.drives_enabled_at_s`` where the run knows)."""
    failure = getattr(run, "failure", None)
    events = [dict(e) for e in (getattr(run, "protection_events", None) or ())]
    warnings = [e for e in events if e.get("kind") in WARNING_KINDS]
    limits = [e for e in events if e.get("kind") not in WARNING_KINDS]
    faults = [e for e in limits if e.get("kind") == "fault_reaction"]
    limits = [e for e in limits if e.get("kind") != "fault_reaction"]
    faults += _bus_faults(getattr(run, "fieldbus", None))
    verdict = "ok"
    if limits:
        verdict = "limit"
    if faults:
        verdict = "fault"
    extra: list[dict[str, Any]] = []
    if failure is not None:
        if _is_controller_stop(failure):
            code = _error_code(str(failure.reason))
            if verdict == "ok" and code in PROTECTION_CODES:  # a drive's protection reacted (e.g. 0x8611)
                verdict = "limit"
                extra.append(violation(PROTECTION_CODES[code], failure.time, str(failure.reason), error_code=code,
                                       joint=_drive_of(str(failure.reason)), reaction="quick_stop"))
            elif verdict == "ok":  # the controller stopped on a drive's fault, not on a limit or a bus fault
                verdict = "fault"
                extra.append(violation("controller_stop", failure.time, str(failure.reason), error_code=code,
                                       joint=_drive_of(str(failure.reason)), reaction="quick_stop"))
        else:
            verdict = "failed"
            extra.append(violation("failure", getattr(failure, "time", None),
                                   _first_line(str(getattr(failure, "reason", None) or failure)),
                                   reaction="none"))
    close_error = getattr(run, "controller_close_error", None)
    if close_error:
        verdict = most_severe([verdict, "failed"])
        extra.append(violation("close_error", getattr(run, "reached_s", None), _first_line(str(close_error))))
    if failure is not None:
        pass
    elif getattr(run, "drives_checked", False) and getattr(run, "drives_enabled_at_s", None) is None:
        verdict = most_severe([verdict, "fault"])
        extra.append(violation("not_enabled", getattr(run, "reached_s", None),
                               "the drives never reached Operation enabled (the controller did not enable them)"))
    overrun = overrun_note(run)
    if overrun:  # a paced run whose cycles overran: the likely cause of what went wrong, said where it shows
        for v in extra:
            if v["kind"] in ("controller_stop", "failure", "not_enabled"):
                v["detail"] = f"{v['detail']}: {overrun}"
        if verdict == "ok" or not extra:
            warnings.append(violation("overrun", None, overrun))
    violations = sorted(limits + faults + extra, key=_time_key)
    first = violations[0] if violations else None
    if failure is not None and not _is_controller_stop(failure):
        first = extra[0]  # a failed run names what failed first
    elif close_error and verdict == "failed":
        first = extra[-1]
    return Verdict(verdict, violations[:MAX_VIOLATIONS], first, len(violations), warnings)


def overrun_note(run: Any) -> str | None:
    """For a paced run (``run.pacer``) whose cycles overran their wall deadline in more than
    :data:`CHRONIC_BUDGET_FRACTION` of the cycles: ``"controller overran 99.96 % of cycles (budget
    400 us, controller p99 5012 us)"``, else None."""
    log = getattr(getattr(run, "pacer", None), "log", None)
    count = int(getattr(log, "count", 0) or 0)
    if count <= 0:
        return None
    overruns = int(log.overrun[:count].sum())
    if overruns <= CHRONIC_BUDGET_FRACTION * count:
        return None
    period_us = getattr(run.pacer, "period_ns", 0) * 1e-3
    timing = getattr(run, "controller_timing", None)
    p99 = getattr(timing, "p99_us", None)
    own = f", controller p99 {p99:.4g} us" if isinstance(p99, (int, float)) and math.isfinite(p99) else ""
    return (f"controller overran {100.0 * overruns / count:.4g} % of cycles ({overruns} of {count}; budget "
            f"{period_us:.4g} us per bus cycle{own})")


def budget_warning(timing: Any) -> dict[str, Any] | None:
    """A ``budget`` warning when more than :data:`CHRONIC_BUDGET_FRACTION` of the controller's timed
    cycles (a :class:`controller.TimingSummary`) were over its compute budget, else None: the
    misses as the timing judged them (``deadline_basis``: CPU time in a simulated-time run,
    wall time in a real-time one). A timing without a basis counts its wall-time misses only
    when the CPU time is over the budget too (CPU p99 above it)."""
    cycles = getattr(timing, "cycles", 0) or 0
    misses = getattr(timing, "deadline_misses", 0) or 0
    if cycles <= 0 or misses <= CHRONIC_BUDGET_FRACTION * cycles:
        return None
    budget = getattr(timing, "budget_us", float("nan"))
    cpu_p99 = getattr(timing, "cpu_p99_us", None)
    basis = getattr(timing, "deadline_basis", None)
    if basis is None and isinstance(cpu_p99, (int, float)) and math.isfinite(cpu_p99) and cpu_p99 <= budget:
        return None  # wall-time misses only, and the controller's own CPU time fits: time other processes took
    share = 100.0 * misses / cycles
    p99 = getattr(timing, "p99_us", float("nan"))
    cpu = f", CPU p99 {cpu_p99:.4g} us" if isinstance(cpu_p99, (int, float)) and math.isfinite(cpu_p99) else ""
    clock = {"cpu_time": "CPU time", "wall_time": "wall time"}.get(basis or "", "compute time")
    return violation("budget", None, f"the controller overran its compute budget of {budget:.6g} us in "
                                     f"{misses} of {cycles} cycles ({share:.4g} %, judged on {clock}; wall p99 "
                                     f"{p99:.4g} us{cpu})",
                     value=share, limit=100.0 * CHRONIC_BUDGET_FRACTION, unit="%")


def record(entry: dict[str, Any], run: Any, timing: Any = None) -> Verdict:
    """Judge ``run`` (:func:`judge`), add a chronic compute-budget warning from ``timing`` and put
    the fields into the run's summary record ``entry``; its ``status`` follows the verdict
    (``ok``/``failed`` as before, ``limit``/``fault`` now). Returns the verdict."""
    verdict = judge(run)
    warning = budget_warning(timing)
    if warning is not None:
        verdict.warnings.append(warning)
    apply(entry, verdict)
    entry["status"] = verdict.verdict
    if getattr(run, "controller_close_error", None):
        entry["close_error"] = run.controller_close_error
    return verdict


def _error_code(text: str) -> str | None:
    """The ``0x....`` error code a stop reason quotes (``drive 1 reports Fault, error code 0x8611``)."""
    import re

    found = re.search(r"error code (0x[0-9A-Fa-f]{4})", text)
    return found.group(1).upper().replace("0X", "0x") if found else None


def _drive_of(text: str) -> int | None:
    import re

    found = re.search(r"\bdrive (\d)\b", text)
    return int(found.group(1)) if found else None


def _time_key(v: dict[str, Any]) -> float:
    t = v.get("time_s")
    return float(t) if isinstance(t, (int, float)) and math.isfinite(t) else math.inf


def _first_line(text: str) -> str:
    return text.strip().splitlines()[0] if text.strip() else text


def failed_verdict(reason: str, time_s: float | None = None) -> Verdict:
    """The verdict of a run that could not start or be evaluated (e.g. its controller could not be made)."""
    v = violation("failure", time_s, _first_line(reason))
    return Verdict("failed", [v], v, 1)


def refused_verdict(reason: str) -> Verdict:
    """The verdict of a run refused before it started (a plan beyond the robot's limits): ``failed``."""
    v = violation("refused", None, _first_line(reason))
    return Verdict("failed", [v], v, 1)


def apply(entry: dict[str, Any], verdict: Verdict) -> dict[str, Any]:
    """Put the verdict's fields into a run's summary record (and return it)."""
    entry.update(verdict.fields())
    return entry


def run_line(label: str, entry: dict[str, Any]) -> str:
    """The console line of one run: ``label: verdict[: first violation]``."""
    verdict = entry.get("verdict") or entry.get("status") or "failed"
    first = entry.get("first_violation")
    return f"{label}: {verdict}" + (f": {describe_violation(first)}" if first else "")


__all__ = ["CHRONIC_BUDGET_FRACTION", "VIOLATION_KINDS", "budget_warning", "record", "LIMIT_KINDS", "MAX_VIOLATIONS", "SEVERITY", "VERDICTS", "Verdict", "apply", "describe_violation",
           "exit_code", "failed_verdict", "judge", "most_severe", "refused_verdict", "run_line", "violation"]
