"""``report.html``: one self-contained, offline HTML view of one or more results folders.

:func:`write_report` reads what a run left (``summary.json``, the ``tcp_``, ``timeseries_``
and ``controller_`` time series of each mode or entry, the CAN logs' EMCY frames, the robot's
URDF) and writes one HTML file with Plotly's offline bundle inlined (the ``plotly`` package's
``plotly.min.js``; nothing is downloaded when the file is opened): the summary with units,
the arm in 3D replaying the run on a timeline, the programmed and actual TCP path coloured
by the TCP error (log scale), limit and bus events, and linked plots of :data:`PANELS` on the
same timeline. ``python -m cosim view`` calls it; every run writes one unless
``[results] report = false`` (:func:`write_run_report`).

What is plotted comes from :mod:`cosim.results.panels`, the description the PNG figures read.
Each curve is embedded twice: its :func:`~cosim.results.panels.envelope` over the whole run
(the first minimum and maximum of each of :data:`OVERVIEW_COLUMNS` columns: every peak kept),
drawn when the report opens, and, within :data:`FULL_VALUES_BUDGET`, every sample
(zlib-deflated, decoded by the browser's own ``DecompressionStream`` when a zoom needs it).
The TCP error is always embedded whole (float64); other curves whole as float32 while the
budget lasts, in the order of :data:`PANELS`; the report names any curve it holds only decimated.

Bad input: :class:`ReportError` (a ValueError: one line, ``cosim view`` exits 2) when the folder
is missing, empty or holds no run; a file that cannot be read (a corrupt Parquet file, a bad
``summary.json``) is left out and named in the report's notes; a run still going (status
``running``) is shown as far as it got, and the report says so.
"""
from __future__ import annotations

import base64
import importlib.util
import datetime as _dt
import json
import math
import re
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cosim.results.panels import PANELS, TAB_RGB, colour_of, envelope_index, joint_names, label_of

REPORT_NAME = "report.html"
#: Columns of the overview of each curve (min and max in each: <= 2 points per column).
OVERVIEW_COLUMNS = 2000
#: Samples of all curves embedded at full resolution (beyond the TCP error, always whole).
#: 2 million float32 values: about 10 MB deflated and base64-coded at most.
FULL_VALUES_BUDGET = 2_000_000
#: Poses of the arm embedded per run for the 3D replay (evenly spaced in the rows).
ARM_FRAMES = 4000
#: Points of each 3D path (the TCP error's peaks and evenly spaced ones).
PATH_POINTS = 1500
#: Where the EMCY frames are (CiA 301: 0x080 + node id).
EMCY_IDS = (0x081, 0x0FF)
SOURCES = ("tcp", "timeseries", "controller", "lateness")
#: zlib level of the embedded full-resolution arrays: 1 is about 3x faster to write than 6 for
#: a few per cent more bytes (float samples hardly compress either way).
ZLIB_LEVEL = 1
SOURCE_TIME = {"tcp": ("t", "time"), "timeseries": ("time", "t"), "controller": ("t", "time"), "lateness": ("t",)}
_SERIES_FILE = re.compile(r"^(tcp|timeseries|controller|lateness)_(.+?)\.(parquet|csv|parquet\.partial)$")


#: The robot description files (robot/: the one place for them; read as files here, no pinocchio).
ROBOT_DIR = Path(importlib.util.find_spec("robot").origin).parent
URDF_FILE = "rx130l.urdf"
PARAMS_FILE = "rx130l_params.toml"


class ReportError(ValueError):
    """A folder no report can be made of (one line; ``cosim view`` exits 2)."""


@dataclass
class Run:
    """One mode or entry of one results folder."""

    name: str
    folder: Path
    entry: dict[str, Any]
    files: dict[str, Path] = field(default_factory=dict)


# ------------------------------------------------------------------------------- reading
def read_summary(folder: Path, notes: list[str]) -> dict[str, Any] | None:
    path = folder / "summary.json"
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        notes.append(f"{path.name}: not readable ({type(exc).__name__}: {_first_line(exc)}): no summary shown")
        return None
    if not isinstance(data, dict):
        notes.append(f"{path.name}: not a JSON object: no summary shown")
        return None
    return data


def find_runs(folder: Path, summary: dict[str, Any] | None) -> list[Run]:
    """The modes/entries of a folder: those in the summary (``modes``/``entries``) in its order, then
    any other whose time series are in the folder (a mode still running)."""
    runs: dict[str, Run] = {}
    for key in ("modes", "entries"):
        table = (summary or {}).get(key)
        if isinstance(table, dict):
            for name, entry in table.items():
                if isinstance(entry, dict):
                    runs.setdefault(name, Run(name, folder, entry))
    found: dict[str, dict[str, Path]] = {}
    for path in sorted(folder.iterdir()):
        m = _SERIES_FILE.match(path.name)
        if m:
            kind, name, suffix = m.groups()
            files = found.setdefault(name, {})
            if kind not in files or suffix == "parquet":  # the final file over its stream
                files[kind] = path
    for name, files in found.items():
        runs.setdefault(name, Run(name, folder, {})).files.update(files)
    for run in runs.values():
        for kind, stored in (run.entry.get("files") or {}).items():
            if kind in SOURCES and isinstance(stored, str) and kind not in run.files:
                from cosim.results.timeseries import resolve_series

                path = resolve_series(folder / Path(stored).name)
                if path.exists():
                    run.files[kind] = path
    return [r for r in runs.values() if r.files or r.entry]


def _read_columns(path: Path, wanted: list[str], notes: list[str], label: str) -> dict[str, np.ndarray]:
    """``wanted`` columns (those the file has) of a time series, chunk by chunk; {} and a note when
    the file cannot be read."""
    from cosim.results.timeseries import iter_series, series_columns

    try:
        present = series_columns(path)
        take = [c for c in wanted if c in present]
        if not take:
            return {}
        blocks = [block for _, block in iter_series(path, take)]
    except Exception as exc:  # noqa: BLE001 - a corrupt or truncated file: name it, show the rest
        notes.append(f"{label}: {path.name} not readable ({type(exc).__name__}: {_first_line(exc)}): "
                     f"its curves are missing")
        return {}
    data = np.concatenate(blocks) if blocks else np.zeros((0, len(take)))
    if path.name.endswith(".partial"):
        notes.append(f"{label}: {path.name} is the stream of a run still going or stopped (every complete batch "
                     f"shown, {len(data)} rows)")
    return {c: data[:, k] for k, c in enumerate(take)}


def _emcy_events(path: Path, notes: list[str], label: str) -> list[dict[str, Any]]:
    """EMCY frames of a columnar CAN log (``can_<run>.parquet``, any format the project's reader
    reads): time, node, error code."""
    try:
        import pyarrow.parquet as pq

        from fieldbus.canlog import read_frames

        ids = pq.ParquetFile(path).read(columns=["id"]).column("id").to_numpy()
        if not np.any((ids >= EMCY_IDS[0]) & (ids <= EMCY_IDS[1])):
            return []  # no EMCY frame: the frames' times are not needed
        log = read_frames(path)
        frames = log.frames
        hit = np.flatnonzero((frames["id"] >= EMCY_IDS[0]) & (frames["id"] <= EMCY_IDS[1]) & (frames["error"] == 0))
        times = log.timestamps
        events: list[dict[str, Any]] = []
        for i in hit[:200]:
            node = int(frames["id"][i]) - 0x80
            data = frames["data"][i]
            code = int(data[0]) | (int(data[1]) << 8) if int(frames["length"][i]) >= 2 else None
            events.append({"kind": "emcy", "time_s": float(times[i]), "joint": node,
                           "error_code": None if code is None else f"0x{code:04X}",
                           "detail": f"EMCY node {node}" + ("" if code is None else f" error code 0x{code:04X}")})
        if hit.size > 200:
            notes.append(f"{label}: {hit.size} EMCY frames, the first 200 shown")
        return events
    except Exception as exc:  # noqa: BLE001
        notes.append(f"{label}: {path.name} not readable ({type(exc).__name__}: {_first_line(exc)}): bus events missing")
        return []


def _entry_events(entry: dict[str, Any], summary: dict[str, Any] | None, name: str) -> list[dict[str, Any]]:
    """Limit/fault events of a run from its summary entry (``violations``, ``first_violation``,
    ``protection_events``, fault ``trips``; its failure or stop) as plain records with ``time_s``."""
    events: list[dict[str, Any]] = []
    seen: set[tuple] = set()
    for key in ("violations", "protection_events", "trips", "events"):
        for item in entry.get(key) or []:
            if isinstance(item, dict) and isinstance(item.get("time_s"), (int, float)):
                ident = (item.get("kind"), item.get("joint"), item.get("time_s"))
                if ident not in seen:
                    seen.add(ident)
                    events.append({**{k: v for k, v in item.items() if _plain(v)}, "kind": str(item.get("kind", key))})
    first = entry.get("first_violation")
    if isinstance(first, dict) and isinstance(first.get("time_s"), (int, float)):
        ident = (first.get("kind"), first.get("joint"), first.get("time_s"))
        if ident not in seen:
            events.append({**{k: v for k, v in first.items() if _plain(v)}, "kind": str(first.get("kind", "limit"))})
    mine = summary is not None and (summary.get("mode") == name or summary.get("failed_in") == name)
    bus = entry.get("fieldbus") if isinstance(entry.get("fieldbus"), dict) else {}
    if not bus.get("faults") and summary is not None and summary.get("mode") == name:
        bus = summary.get("fieldbus") if isinstance(summary.get("fieldbus"), dict) else {}
    events += _bus_events(bus.get("faults"))
    stopped = summary.get("stopped_at_s") if mine else None
    if isinstance(stopped, (int, float)):
        events.append({"kind": "stopped", "time_s": float(stopped),
                       "detail": f"run {summary.get('status')} here: {_first_line(summary.get('reason') or '')}"})
    elif isinstance(entry.get("stopped_at_s"), (int, float)) and _stopped_early(entry):
        # the mode/entry's own stop (a drive's fault reaction, a controller's stop): where the motion ended
        events.append({"kind": "stopped", "time_s": float(entry["stopped_at_s"]),
                       "detail": f"{name} {entry.get('verdict') or entry.get('status')}: motion stopped here"
                                 + (f": {_first_line(entry.get('stop_reason'))}" if entry.get("stop_reason") else "")})
    return events


#: What each event of a run's fieldbus record (``fieldbus.faults`` in summary.json) is called in the
#: report; ``fault_reaction`` is left out (it is a violation, listed with the others).
BUS_EVENT_KINDS = {"injected": "lost frame", "error": "bus counter", "threshold_reached": "bus threshold"}
#: Bus events listed per run, at most (the first ones).
BUS_EVENTS_MAX = 200


def _bus_events(faults: Any) -> list[dict[str, Any]]:
    """The fieldbus record's lost frames, error counter steps and thresholds reached as events."""
    out = []
    for e in faults if isinstance(faults, list) else ():
        if not (isinstance(e, dict) and e.get("event") in BUS_EVENT_KINDS and isinstance(e.get("time_s"), (int, float))):
            continue
        counted = isinstance(e.get("threshold"), (int, float)) and e["threshold"] >= 0
        out.append({"kind": BUS_EVENT_KINDS[e["event"]], "time_s": float(e["time_s"]), "joint": e.get("node"),
                    "value": e.get("counter") if counted else None, "limit": e.get("threshold") if counted else None,
                    "unit": "counts" if counted else None,
                    "detail": f"{e.get('side')} {e.get('kind')} in cycle {e.get('cycle')}: {e.get('detail') or ''}".strip()})
        if len(out) >= BUS_EVENTS_MAX:
            break
    return out


def _stopped_early(entry: dict[str, Any]) -> bool:
    """Whether a mode/entry ended badly (a verdict or status other than ok: limit, fault, failed, ...);
    a run cut short by its stop time is not one."""
    return (entry.get("verdict") or entry.get("status")) not in (None, "ok")


def _plain(value: Any) -> bool:
    return value is None or isinstance(value, (str, int, float, bool))


# ------------------------------------------------------------------------------- encoding
def _pack(values: np.ndarray, dtype: str = "f4", deflate: bool = False) -> dict[str, Any]:
    """An array as base64 little-endian ``dtype`` (``f4``/``f8``), optionally zlib-deflated; deflated
    arrays are byte-shuffled first (byte k of every value, then byte k + 1: the sign, exponent and
    high mantissa bytes of neighbouring samples repeat, so they deflate 15-25 % smaller; the values
    are the same bits)."""
    array = np.ascontiguousarray(values, dtype="<" + dtype)
    if deflate:
        shuffled = array.view(np.uint8).reshape(-1, array.itemsize).T.tobytes()
        raw = zlib.compress(shuffled, ZLIB_LEVEL)
    else:
        raw = array.tobytes()
    return {"dtype": dtype, "n": int(values.size), "z": deflate, "shuffle": deflate,
            "b64": base64.b64encode(raw).decode("ascii")}


def _pack_time(t: np.ndarray) -> dict[str, Any]:
    """A time column, exactly: ``t0 + k * dt`` (float64, as numpy and JavaScript both compute it) plus
    each sample's residual (zero or a few ulps: deflates to almost nothing), when that gives ``t``
    bit for bit; else the values themselves."""
    n = int(t.size)
    if n > 2 and np.all(np.isfinite(t)):
        dt = float((t[-1] - t[0]) / (n - 1))
        uniform = t[0] + np.arange(n, dtype=np.float64) * dt
        residual = t - uniform
        if np.array_equal(uniform + residual, t):
            return {**_pack(residual, "f8", deflate=True), "uniform": [float(t[0]), dt]}
    return _pack(t, "f8", deflate=True)


#: Sides of each link's cylinder in the 3D view (2 * sides + 2 vertices per link: few, so a
#: scrub moves a few hundred vertices).
SOLID_SIDES = 16
#: Radius of each link's cylinder in the 3D view, m, where the URDF gives the link no collision or
#: visual geometry (rx130l.urdf gives none). Source: a display assumption sized by eye to the
#: RX130L's proportions (heavy base and shoulder, slimmer arm, wrist and flange): not a datasheet
#: figure and not a collision model. A link not named here gets :data:`DEFAULT_LINK_RADIUS_M`.
LINK_RADIUS_M = {"base_link": 0.16, "link_1": 0.13, "link_2": 0.09, "link_3": 0.08, "link_4": 0.065,
                 "link_5": 0.05, "link_6": 0.04}
#: Radius, m, of the cylinder of a link neither the URDF nor :data:`LINK_RADIUS_M` sizes (display assumption).
DEFAULT_LINK_RADIUS_M = 0.05


def _urdf_chain(urdf: Path | None = None) -> dict[str, Any]:
    """The arm's joint chain from the robot's URDF (origins, rpy, axes) and its links' solids
    (:func:`link_solids`) for the 3D view."""
    import xml.etree.ElementTree as ET

    urdf = ROBOT_DIR / URDF_FILE if urdf is None else Path(urdf)
    root = ET.parse(urdf).getroot()
    joints = {j.get("name"): j for j in root.findall("joint")}
    by_parent = {j.find("parent").get("link"): j for j in joints.values()}
    chain, link = [], "base_link"
    while link in by_parent:
        joint = by_parent[link]
        origin = joint.find("origin")
        axis = joint.find("axis")
        chain.append({"name": joint.get("name"), "type": joint.get("type"), "parent": link,
                      "xyz": [float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()],
                      "rpy": [float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()],
                      "axis": [float(v) for v in (axis.get("xyz", "0 0 1") if axis is not None else "0 0 1").split()]})
        link = joint.find("child").get("link")
    links = {lk.get("name"): lk for lk in root.findall("link")}
    return {"robot": root.get("name"), "file": urdf.name, "chain": chain, "solids": link_solids(chain, links)}


def _link_radius(link: Any) -> tuple[float, str]:
    """A link's cylinder radius (m) and where it comes from: the URDF's collision, else visual,
    geometry (a cylinder's or sphere's radius; a box's half larger cross-section side, x or y), else
    :data:`LINK_RADIUS_M` (a mesh is not loaded: its link gets the table's radius too)."""
    name = link.get("name") if link is not None else None
    for kind in ("collision", "visual"):
        for element in (link.findall(kind) if link is not None else ()):
            for shape in element.findall("geometry/*"):
                if shape.tag in ("cylinder", "sphere") and shape.get("radius"):
                    return float(shape.get("radius")), f"URDF {kind} {shape.tag}"
                if shape.tag == "box" and shape.get("size"):
                    x, y, _ = (float(v) for v in shape.get("size").split())
                    return max(x, y) / 2, f"URDF {kind} box"
    if name in LINK_RADIUS_M:
        return LINK_RADIUS_M[name], "report.py LINK_RADIUS_M"
    return DEFAULT_LINK_RADIUS_M, "report.py DEFAULT_LINK_RADIUS_M"


def link_solids(chain: list[dict[str, Any]], links: dict[str, Any]) -> dict[str, Any]:
    """Each link as a cylinder in its own frame, from its origin to the next joint's origin, with
    :data:`SOLID_SIDES` sides: vertex 0 is the link frame's origin, vertex 1 the next joint's, then
    the ring around vertex 0 and the ring around vertex 1 (the ring starts on the link frame's x
    axis, so it turns with the link). The page moves each link's vertices by its frame's pose at
    the cursor; ``i``/``j``/``k`` are the triangles of one link (the same for every link)."""
    n = SOLID_SIDES
    out = []
    for index, joint in enumerate(chain):
        end = np.array(joint["xyz"], dtype=float)
        length = float(np.linalg.norm(end))
        if length < 1e-9:
            continue  # two frames at one point: no solid between them
        u = end / length
        ref = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        v1 = ref - ref.dot(u) * u
        v1 /= np.linalg.norm(v1)
        v2 = np.cross(u, v1)
        radius, source = _link_radius(links.get(joint["parent"]))
        angle = 2 * np.pi * np.arange(n) / n
        ring = radius * (np.cos(angle)[:, None] * v1 + np.sin(angle)[:, None] * v2)
        vertices = np.vstack([np.zeros(3), end, ring, end + ring])
        out.append({"link": joint["parent"], "joint": joint["name"], "chain_index": index, "radius_m": radius, "radius_from": source,
                    "vertices": [float(v) for v in vertices.ravel()]})
    a = 2 + np.arange(n)
    b = 2 + (np.arange(n) + 1) % n
    c, d = a + n, b + n
    faces = np.vstack([np.column_stack([a, b, d]), np.column_stack([a, d, c]),
                       np.column_stack([np.zeros(n, int), b, a]), np.column_stack([np.ones(n, int), c, d])])
    return {"sides": n, "per_link": 2 * n + 2, "links": out,
            "i": faces[:, 0].tolist(), "j": faces[:, 1].tolist(), "k": faces[:, 2].tolist()}


def _current_limits() -> dict[str, Any] | None:
    """The drives' peak current limits from the robot's parameter file (read as TOML: importing
    ``robot.parameters`` would import pinocchio), with the file's unit and source."""
    import tomllib

    try:
        doc = tomllib.loads((ROBOT_DIR / PARAMS_FILE).read_text(encoding="utf-8"))
        entry = doc["drive_train"]["current_limit"]
        return {"value": [float(v) for v in entry["value"]], "unit": entry.get("unit", "A"),
                "source": f"{PARAMS_FILE} [drive_train] current_limit"}
    except (OSError, KeyError, TypeError, ValueError):
        return None


class _Budget:
    def __init__(self, values: int) -> None:
        self.left = values

    def take(self, n: int) -> bool:
        if n <= self.left:
            self.left -= n
            return True
        return False


def _run_data(run: Run, label: str, colour: str, summary: dict[str, Any] | None, notes: list[str],
              budget: _Budget) -> dict[str, Any]:
    """The embedded data of one run: its curves (overview + full), arm poses, 3D paths and events."""
    wanted: dict[str, list[str]] = {s: [*SOURCE_TIME[s]] for s in SOURCES}
    for panel in PANELS:
        for series in panel.series:
            names = [joint_names(series.column, j) for j in panel.joints] if panel.joints else [series.column]
            wanted[series.source] += names + ([panel.limit_column] if panel.limit_column else [])
    wanted["tcp"] += [f"{a}_{w}" for w in ("programmed", "measured") for a in "xyz"]
    wanted["timeseries"] += [f"plant.q[{j}]" for j in range(1, 7)]
    columns: dict[str, dict[str, np.ndarray]] = {}
    for source in SOURCES:
        if source in run.files:
            columns[source] = _read_columns(run.files[source], list(dict.fromkeys(wanted[source])), notes,
                                            f"{label}")
    out: dict[str, Any] = {"name": run.name, "label": label, "colour": TAB_RGB.get(colour, colour),
                           "partial": any(p.name.endswith(".partial") for p in run.files.values()),
                           "times": {}, "series": {}}
    times: dict[str, np.ndarray] = {}
    for source, cols in columns.items():
        t = next((cols[c] for c in SOURCE_TIME[source] if c in cols), None)
        if t is not None and t.size:
            times[source] = t
            out["times"][source] = {"full": _pack_time(t), "t0": float(t[0]), "t1": float(t[-1]),
                                    "n": int(t.size)}
    for panel in PANELS:
        curves = []
        for series in panel.series:
            t = times.get(series.source)
            if t is None:
                continue
            for j in (panel.joints or (None,)):
                column = joint_names(series.column, j) if j else series.column
                values = columns.get(series.source, {}).get(column)
                if values is None:
                    continue
                y = values * series.scale if series.scale != 1.0 else values
                index = envelope_index(t, y, OVERVIEW_COLUMNS, finite_only=True)
                index = np.arange(t.size) if index is None else index
                whole = panel.key == "tcp_error"
                full = None
                if whole or budget.take(int(y.size)):
                    full = _pack(y, "f8" if whole else "f4", deflate=True)
                limit = None
                if panel.limit_column and panel.limit_column in columns.get(series.source, {}):
                    finite = columns[series.source][panel.limit_column]
                    finite = finite[np.isfinite(finite)]
                    limit = float(finite[0] * series.scale) if finite.size else None
                curves.append({"joint": j, "label": joint_names(series.label, j) if j else series.label,
                               "source": series.source, "column": column, "limit": limit,
                               "ox": _pack(t[index], "f8"), "oy": _pack(y[index], "f8" if whole else "f4"), "full": full})
        if curves:
            out["series"][panel.key] = curves
    ts = columns.get("timeseries", {})
    if "timeseries" in times and all(f"plant.q[{j}]" in ts for j in range(1, 7)):
        t = times["timeseries"]
        pick = np.unique(np.linspace(0, t.size - 1, min(t.size, ARM_FRAMES)).astype(np.int64))
        q = np.column_stack([ts[f"plant.q[{j}]"][pick] for j in range(1, 7)])
        ok = np.isfinite(q).all(axis=1)
        out["arm"] = {"t": _pack(t[pick][ok], "f8"), "q": _pack(q[ok].ravel(), "f8")}  # exact: the solids are the FK of q
    tcp = columns.get("tcp", {})
    if "tcp" in times and all(f"{a}_measured" in tcp for a in "xyz"):
        t = times["tcp"]
        err = tcp.get("tcp_error_mm", np.full(t.size, np.nan))
        measured = np.column_stack([tcp[f"{a}_measured"] for a in "xyz"])
        index = envelope_index(t, err, PATH_POINTS // 2, finite_only=True)
        even = np.linspace(0, t.size - 1, min(t.size, PATH_POINTS)).astype(np.int64)
        pick = np.unique(np.concatenate([even, index if index is not None else np.arange(t.size)]))
        pick = pick[np.isfinite(measured[pick]).all(axis=1)]
        out["path"] = {"t": _pack(t[pick], "f8"), "measured": _pack(measured[pick].ravel(), "f4"),
                       "err": _pack(err[pick], "f4")}
        if all(f"{a}_programmed" in tcp for a in "xyz"):
            programmed = np.column_stack([tcp[f"{a}_programmed"] for a in "xyz"])
            ok = np.isfinite(programmed[even]).all(axis=1)
            out["path"]["programmed"] = _pack(programmed[even][ok].ravel(), "f4")
    can = run.folder / f"can_{run.name}.parquet"
    out["bus_events"] = _emcy_events(can, notes, label) if can.exists() else []
    return out


# ------------------------------------------------------------------------------- the report
KEY_FIGURES: tuple[tuple[str, str, str], ...] = (
    ("verdict", "verdict", ""), ("status", "status", ""),
    ("tcp_error_max_mm", "max TCP error", "mm"), ("tcp_error_rms_mm", "RMS TCP error", "mm"),
    ("tcp_error_max_noise_free_mm", "max TCP error, noise-free", "mm"),
    ("path_accuracy_AT_mm", "ISO 9283 path accuracy AT", "mm"),
    ("tcp_path_error_max_mm", "max error to the programmed path", "mm"),
    ("joint_lag_max_rad", "max lag per joint", "rad"),
    ("residual_vibration.peak_mm", "residual vibration peak", "mm"),
    ("residual_vibration.settling_time_s", "settling time", "s"),
    ("cycle_wall_us.p50", "controller compute p50 (wall)", "us"),
    ("cycle_wall_us.p99", "controller compute p99 (wall)", "us"),
    ("cycle_wall_us.max", "controller compute max (wall)", "us"),
    ("cycle_compute_cpu_us.p99", "controller compute p99 (CPU)", "us"),
    ("deadline_misses", "deadline misses", "cycles"),
    ("path_completed", "path completed", ""), ("stop_reason", "stop reason", ""),
    ("sim_time_s", "simulated", "s"), ("violations_total", "violations", ""),
    ("fieldbus.frames_dropped", "frames dropped", "frames"),
)
"""The figures shown per mode/entry: (dotted key in the entry, label, unit)."""
TIMING_KEYS = ("realtime", "hil", "split", "timing", "serve", "execution")
"""Summary sections shown as the timing report (paced, split and served runs)."""


def _dig(entry: Any, key: str) -> Any:
    for part in key.split("."):
        if not isinstance(entry, dict) or part not in entry:
            return None
        entry = entry[part]
    return entry


def _clean(value: Any) -> Any:
    """JSON-safe (NaN/inf as strings, as summary.json writes them? no: as null with the text kept)."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def _check_folder(folder: Path) -> None:
    if not folder.exists():
        raise ReportError(f"{folder}: no such folder (expected a results folder with summary.json)")
    if not folder.is_dir():
        raise ReportError(f"{folder}: not a folder (expected a results folder with summary.json)")
    if not any(folder.iterdir()):
        raise ReportError(f"{folder}: empty folder (expected a results folder with summary.json)")


def _labels(folders: list[Path], runs_by_folder: list[list[Run]]) -> list[list[tuple[str, str]]]:
    """(label, matplotlib colour) of every run: the mode's name and colour for one folder;
    ``<folder>/<mode>`` and colours in turn for several."""
    if len(folders) == 1:  # a compare entry <controller>__<trajectory> in its controller's colour
        names = [r.name for r in runs_by_folder[0]]
        bases = list(dict.fromkeys(n.split("__")[0] for n in names))
        others = [n for n in bases if n not in ("standard", "standard_speed_ff", "model_based", "model_based_elastic")]
        return [[(n, colour_of(n.split("__")[0], others)) for n in names]]
    labels = [f"{f.name}/{r.name}" for f, found in zip(folders, runs_by_folder) for r in found]
    return [[(f"{f.name}/{r.name}", colour_of(f"{f.name}/{r.name}", labels)) for r in found]
            for f, found in zip(folders, runs_by_folder)]


def collect(folders: list[Path]) -> dict[str, Any]:
    """Everything the report shows, as JSON-ready data (ReportError on a folder that holds no run):
    the time series part (:func:`collect_series`) and the summary part (``light``, :func:`collect_light`)."""
    data = collect_series(folders)
    data["light"] = collect_light(folders)
    return data


def collect_series(folders: list[Path]) -> dict[str, Any]:
    """The part of the report read from the time series and CAN logs (the slow part; it does not
    change when summary.json gets its final status)."""
    folders = [Path(f) for f in folders]
    notes: list[str] = []
    budget = _Budget(FULL_VALUES_BUDGET)
    runs: list[dict[str, Any]] = []
    found_all = []
    for folder in folders:
        _check_folder(folder)
        summary = read_summary(folder, [])
        found = find_runs(folder, summary)
        if summary is None and not found and not (folder / "summary.json").exists():
            raise ReportError(f"{folder}: not a results folder (no summary.json and no time series "
                              f"tcp_/timeseries_/controller_*.parquet)")
        found_all.append(found)
    for folder, found, labels in zip(folders, found_all, _labels(folders, found_all)):
        folder_notes: list[str] = []
        for run, (label, colour) in zip(found, labels):
            runs.append({**_run_data(run, label, colour, None, folder_notes, budget),
                         "folder": str(folder), "title": label_of(run.name)})
        notes += [f"{folder.name}: {n}" if len(folders) > 1 else n for n in folder_notes]
    decimated = [f"{r['label']}: {c['label']} ({p.title})" for r in runs for p in PANELS
                 for c in r["series"].get(p.key, []) if c["full"] is None]
    if decimated:
        notes.append(f"{len(decimated)} curves are embedded decimated only (min and max per 1/{OVERVIEW_COLUMNS} of "
                     f"the run; the full-resolution budget of {FULL_VALUES_BUDGET:,} values was spent): "
                     + "; ".join(decimated[:8]) + (" ..." if len(decimated) > 8 else ""))
    return {"format": "rx130l-cosim report 1", "generated": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "runs": runs, "notes": notes,
            "panels": [{"key": p.key, "title": p.title, "ylabel": p.ylabel, "unit": p.unit, "log": p.log,
                        "joints": list(p.joints), "limit": p.limit, "limit_label": p.limit_label} for p in PANELS],
            "limits": {"current_limit": _current_limits()},
            "urdf": _urdf_chain(), "key_figures": [list(k) for k in KEY_FIGURES], "timing_keys": list(TIMING_KEYS),
            "overview_columns": OVERVIEW_COLUMNS}


def collect_light(folders: list[Path]) -> dict[str, Any]:
    """The part of the report read from summary.json (and compare.json): the summaries, what the
    status means (notes), each run's status and its limit/fault events (``run_events`` by label)."""
    folders = [Path(f) for f in folders]
    sources, notes, events, statuses = [], [], {}, {}
    found_all, summaries, all_notes = [], [], []
    for folder in folders:
        folder_notes: list[str] = []
        summary = read_summary(folder, folder_notes)
        found_all.append(find_runs(folder, summary))
        summaries.append(summary)
        all_notes.append(folder_notes)
    for folder, summary, found, labels, folder_notes in zip(folders, summaries, found_all,
                                                           _labels(folders, found_all), all_notes):
        if summary is None and not folder_notes:
            folder_notes.append("summary.json missing: only the time series are shown")
        folder_notes += status_notes(summary)
        if not found:
            folder_notes.append("no time series in the folder: summary only")
        verdicts = (summary or {}).get("verdicts") if isinstance((summary or {}).get("verdicts"), dict) else {}
        for run, (label, _) in zip(found, labels):
            judged = verdicts.get(run.name) if isinstance(verdicts.get(run.name), dict) else {}
            entry = {**run.entry, **({"first_violation": judged["first_violation"]}
                                     if judged.get("first_violation") and not run.entry.get("first_violation") else {})}
            events[label] = sorted(_entry_events(entry, summary, run.name), key=lambda e: e["time_s"])
            statuses[label] = (judged.get("verdict") or run.entry.get("verdict") or run.entry.get("status")
                               or ("running" if (summary or {}).get("status") == "running" else None))
        sources.append({"folder": str(folder), "name": folder.name, "summary": _clean(summary) if summary else None,
                        "notes": folder_notes, "compare": _compare_table(folder, summary),
                        "figures": _figures(folder)})
        notes += [f"{folder.name}: {n}" if len(folders) > 1 else n for n in folder_notes]
    return {"sources": sources, "notes": notes, "run_events": events, "run_status": statuses}


#: The run's PNG figures embedded in the report (e.g. the lateness histogram of a paced run), at most.
FIGURES_MAX_BYTES = 4_000_000


def _figures(folder: Path) -> list[dict[str, str]]:
    """The folder's PNG figures (name, base64), smallest first, up to :data:`FIGURES_MAX_BYTES` in all."""
    out, used = [], 0
    for path in sorted(folder.glob("*.png"), key=lambda p: (p.stat().st_size, p.name)):
        size = path.stat().st_size
        if used + size > FIGURES_MAX_BYTES:
            continue
        used += size
        out.append({"name": path.name, "b64": base64.b64encode(path.read_bytes()).decode("ascii")})
    return sorted(out, key=lambda f: f["name"])


def status_notes(summary: dict[str, Any] | None) -> list[str]:
    """What a summary's status says about the report: a run still going, or one that ended badly and where."""
    if not summary:
        return []
    status = summary.get("status")
    if status == "running":
        return [f"the run is still going (status 'running', {float(summary.get('sim_time_s') or 0):.3g} s simulated "
                f"when summary.json was last written): showing what is there so far"]
    if status in ("failed", "interrupted", "limit", "fault"):
        where = summary.get("stopped_at_s")
        first = summary.get("first_violation") if isinstance(summary.get("first_violation"), dict) else None
        return [f"the run ended '{status}'" + (f" at t = {where:.6g} s" if isinstance(where, (int, float)) else "")
                + (f" in {summary.get('mode') or summary.get('failed_in')}"
                   if summary.get("mode") or summary.get("failed_in") else "")
                + (f": {_first_line(summary.get('reason'))}" if summary.get("reason") else "")
                + (f"; first violation: {first.get('kind')} axis {first.get('joint')} at t = {first.get('time_s')} s"
                   if first else "")] + _entry_stops(summary)
    return []


def _entry_stops(summary: dict[str, Any]) -> list[str]:
    """Where each mode/entry that ended early stopped, and why (its ``stopped_at_s``, ``stop_reason``)."""
    out = []
    for key in ("modes", "entries"):
        table = summary.get(key)
        for name, entry in (table.items() if isinstance(table, dict) else ()):
            if isinstance(entry, dict) and isinstance(entry.get("stopped_at_s"), (int, float)) and _stopped_early(entry):
                out.append(f"{name}: {entry.get('verdict') or entry.get('status')}, the motion stopped at "
                           f"t = {entry['stopped_at_s']:.6g} s"
                           + (f": {_first_line(entry['stop_reason'])}" if entry.get("stop_reason") else ""))
    return out


def _compare_table(folder: Path, summary: dict[str, Any] | None) -> dict[str, Any] | None:
    path = folder / "compare.json"
    if path.exists():
        try:
            return _clean(json.loads(path.read_text(encoding="utf-8")))
        except (OSError, ValueError):
            pass
    if summary and isinstance(summary.get("table"), list) and summary["table"]:
        return {"rank_by": summary.get("rank_by"), "rows": _clean(summary["table"]), "columns": None}
    return None


def _asset(name: str) -> str:
    return (Path(__file__).with_name("report_assets") / name).read_text(encoding="utf-8")


def plotly_bundle() -> str:
    """Plotly's offline bundle as the ``plotly`` package ships it (MIT licence, its header kept)."""
    try:
        import plotly
    except ImportError:
        raise ReportError("the report needs the 'plotly' package (pip install plotly): its offline bundle "
                          "plotly.min.js is inlined in report.html") from None
    return (Path(plotly.__file__).parent / "package_data" / "plotly.min.js").read_text(encoding="utf-8")


def report_title(light: dict[str, Any]) -> str:
    return "cosim report: " + ", ".join(
        f"{s['summary'].get('scenario', s['name']) if s['summary'] else s['name']}" for s in light["sources"])


def render(data: dict[str, Any]) -> str:
    """The HTML text of a report of ``data`` (:func:`collect`)."""
    payload = json.dumps(data, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
    title = report_title(data["light"])
    parts = {"TITLE": _escape(title), "CSS": _asset("report.css"),
             "PLOTLY": plotly_bundle().replace("</script", "<\\/script"), "DATA": payload, "APP": _asset("report.js")}
    return re.sub(r"\{\{(TITLE|CSS|PLOTLY|DATA|APP)\}\}", lambda m: parts[m.group(1)], _asset("report.html"))


def write_report(folders: list[Path] | Path, out: Path | None = None) -> Path:
    """Write the report of one or more results folders (default: ``<folder>/report.html`` for one
    folder); return its path. ReportError on a folder that holds no run."""
    folders = [Path(folders)] if isinstance(folders, (str, Path)) else [Path(f) for f in folders]
    if not folders:
        raise ReportError("no results folder given")
    data = collect(folders)
    if out is None:
        out = folders[0] / REPORT_NAME if len(folders) == 1 else Path("report.html")
    out = Path(out)
    text = render(data)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(out)
    return out


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _first_line(value: Any) -> str:
    text = str(value).strip()
    return text.splitlines()[0] if text else type(value).__name__


# ------------------------------------------------------------------------------- written by a run
#: The placeholder of the summary part in a prepared report (:func:`prepare`).
LIGHT_TOKEN = '"@@cosim-report-summary@@"'
TITLE_TOKEN = "@@cosim-report-title@@"
PART_SUFFIX = ".part"
ENV = "COSIM_REPORT"
"""``0``: runs write no report.html (as ``[results] report = false``)."""
_background: dict[Path, int] = {}


def prepare(folder: Path) -> Path:
    """Write ``report.html.part``: the report with its time-series part and a placeholder for the
    summary part, which :func:`finish` fills in once summary.json has its final status."""
    folder = Path(folder)
    data = collect_series([folder])
    data["light"] = "@@cosim-report-summary@@"
    parts = {"TITLE": TITLE_TOKEN, "CSS": _asset("report.css"),
             "PLOTLY": plotly_bundle().replace("</script", "<\\/script"),
             "DATA": json.dumps(data, separators=(",", ":"), allow_nan=False).replace("</", "<\\/"),
             "APP": _asset("report.js")}
    text = re.sub(r"\{\{(TITLE|CSS|PLOTLY|DATA|APP)\}\}", lambda m: parts[m.group(1)], _asset("report.html"))
    part = folder / (REPORT_NAME + PART_SUFFIX)
    part.write_text(text, encoding="utf-8")
    return part


def start(folder: Path) -> int | None:
    """:func:`prepare` in a forked process (a run's files are all written; the job still draws its
    figures and finishes summary.json meanwhile); its pid, or None when it cannot fork here (other
    threads, one core): :func:`finish` then writes the whole report."""
    import os
    import sys
    import threading

    from cosim.results.figure_process import usable_cores

    folder = Path(folder)
    if not hasattr(os, "fork") or threading.active_count() > 1 or usable_cores() < 2 or folder in _background:
        return None
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            import signal

            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            prepare(folder)
            code = 0
        except BaseException:  # noqa: BLE001 - the parent writes the report itself then
            code = 1
        finally:
            os._exit(code)
    _background[folder] = pid
    return pid


def cancel(folder: Path) -> None:
    """End a :func:`start`-ed process of ``folder`` (if any) and remove what it wrote."""
    import os
    import signal

    pid = _background.pop(Path(folder), None)
    if pid is not None:
        try:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        except (ProcessLookupError, ChildProcessError):
            pass
    (Path(folder) / (REPORT_NAME + PART_SUFFIX)).unlink(missing_ok=True)


FILL_IN_CHUNK = 1 << 20
"""Characters of the prepared report read at a time by :func:`_fill_in`."""


def _fill_in(source: Path, target: Path, tokens: dict[str, tuple[str, int]]) -> None:
    """Copy the text file ``source`` to ``target`` replacing the first ``count`` occurrences of each
    token by its text (``tokens``: token -> (text, count); replaced text is not searched again),
    :data:`FILL_IN_CHUNK` characters at a time: the memory it takes does not grow with the report,
    whose time series grow with the run (a whole copy of it and two replaced copies were held)."""
    left = {token: count for token, (_, count) in tokens.items() if count > 0}
    keep = max(map(len, tokens), default=1) - 1  # a token cut by a chunk's end starts in the last keep characters
    with open(source, encoding="utf-8") as reader, open(target, "w", encoding="utf-8") as writer:
        held, done = "", False
        while not done:
            chunk = reader.read(FILL_IN_CHUNK)
            done = not chunk
            held += chunk
            while left:
                hits = [(held.find(token), token) for token in left]
                hits = [(at, token) for at, token in hits if at >= 0]
                if not hits:
                    break
                at, token = min(hits)
                writer.write(held[:at])
                writer.write(tokens[token][0])
                held = held[at + len(token):]
                left[token] -= 1
                if not left[token]:
                    del left[token]
            cut = len(held) if done or not left else max(len(held) - keep, 0)
            writer.write(held[:cut])
            held = held[cut:]


def finish(folder: Path) -> Path:
    """Write ``folder/report.html``: the prepared part (waiting for the process of :func:`start`)
    with the summary part filled in, or the whole report when nothing was prepared."""
    import os

    folder = Path(folder)
    part = folder / (REPORT_NAME + PART_SUFFIX)
    pid = _background.pop(folder, None)
    ok = False
    if pid is not None:
        try:
            _, status = os.waitpid(pid, 0)
            ok = os.waitstatus_to_exitcode(status) == 0
        except ChildProcessError:
            ok = False
    out = folder / REPORT_NAME
    if ok and part.exists():
        light = collect_light([folder])
        payload = json.dumps(light, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
        tmp = out.with_name(out.name + ".tmp")
        _fill_in(part, tmp, {TITLE_TOKEN: (_escape(report_title(light)), 2), LIGHT_TOKEN: (payload, 1)})
        tmp.replace(out)
        part.unlink(missing_ok=True)
        return out
    part.unlink(missing_ok=True)
    return write_report([folder], out)


def wanted(document: dict[str, Any] | None) -> bool:
    """Whether a run of this scenario document writes report.html: ``[results] report`` (default
    true) unless ``$COSIM_REPORT`` is ``0``."""
    import os

    if os.environ.get(ENV, "").strip() == "0":
        return False
    results = (document or {}).get("results")
    return not (isinstance(results, dict) and results.get("report") is False)
