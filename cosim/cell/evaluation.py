"""Evaluation of a cell run along a programmed TCP path (the ISO 9283 path of the main job and of
the identification job's validation): the controller log, the recorded joint angles and the
tracker's measurement turned into TCP errors, ISO 9283 path accuracy, joint lags and the
run's summary entry."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from controller import Controller, ControllerLog
from cosim.cell.run import CellRun
from cosim.tracking.metrics import TrackingResult, desired_joints, evaluate
from cosim.scenario.context import RunContext

DEFINITIONS = {
    "tcp_error": "|measured - commanded| of the flange position, commanded = TRUE kinematics at the joint "
                 "set-points q_d(t) the drives apply (pure dynamic tracking error, paper Figure 2b)",
    "tcp_error_noise_free": "as tcp_error with the true flange instead of the tracker reading (no noise)",
    "tcp_path_error": "|measured - programmed| (programmed = desired Cartesian path): tcp_error plus the "
                      "geometric error of the controller's kinematic model",
    "path_accuracy_AT": "EN ISO 9283 AT per segment: max distance of a measured point to the commanded path in "
                        "the plane normal to the path (one run, no averaging over repetitions)",
    "joint_lag": "q_d(t) - q(t) per joint, rad (paper Figure 2a)",
    "window": "from the motion start (drives apply trajectory time 0) to the end of the trajectory",
    "cycle_wall_us": "wall time of the controller's own work per cycle (interpolation, IK, derivatives, "
                     "feed-forward), perf_counter_ns: includes the time other processes took the core (the main "
                     "job's modes run as sibling processes on shared cores)",
    "cycle_compute_cpu_us": "the same as thread CPU time (thread_time_ns): the controller's own computation",
    "deadline_misses": "cycles whose compute time exceeded compute_budget, judged on deadline_basis: the CPU time "
                       "in a simulated-time run, the wall time in a real-time (paced, served) run",
}


SERIES_UNITS = (("t_apply", "s"), ("tau_ff", "N.m"), ("qdd_d", "rad/s2"), ("qd_d", "rad/s"), ("q_d", "rad"),
                ("q_obs", "rad"), ("target", "rad"), ("compute_us", "us"), ("lag", "rad"), ("arc_length", "m"),
                ("x_", "m"), ("y_", "m"), ("z_", "m"), ("q", "rad"), ("t", "s"), ("tau", "s"))
"""Units of the controller log and TCP series columns by name prefix (first match; ``*_mm`` are mm)."""


def series_units(columns) -> dict[str, str]:
    """Units of the columns of ``controller_<mode>`` and ``tcp_<mode>`` (see :data:`SERIES_UNITS`)."""
    units = {}
    for name in columns:
        if name.endswith("_mm"):
            units[name] = "mm"
            continue
        for prefix, unit in SERIES_UNITS:
            if name == prefix or (name.startswith(prefix) and (prefix.endswith("_") or name[len(prefix):].isdigit()
                                                               or prefix in ("t_apply", "compute_us", "arc_length"))):
                units[name] = unit
                break
    return units


EVAL_CHUNK_ROWS = 8192
"""Recorded rows evaluated at once (8 s at 1 ms): the evaluation's memory is this chunk, the
motion window's rows (bounded by the path's duration, not by the run's length) and
:data:`RESIDUAL_FIGURE_S` of residual-vibration samples."""
RESIDUAL_FIGURE_S = 10.0
"""Longest stretch after the motion's end (s) whose noise-free TCP error is kept in the
:class:`TrackingResult` for figures; the residual-vibration metrics use the whole stretch."""
SETPOINT_COLUMNS = (["t_apply"] + [f"{g}{j}" for g in ("q_d", "qd_d", "qdd_d") for j in range(1, 7)]
                    + ["ik_iterations"])


def recording_chunks(rec: Any, columns: list[str], rows: int = EVAL_CHUNK_ROWS):
    """``columns`` of a cell run's recording (a streamed :class:`SeriesFile` or, for paced and
    split runs, a MemorySink) chunk by chunk: float64 blocks of at most ``rows`` rows."""
    if hasattr(rec, "chunks"):
        for _, block in rec.chunks(columns, rows):
            yield block
        return
    names, data = rec.columns, rec.data
    take = [names.index(c) for c in columns]
    for begin in range(0, len(data), rows):
        yield data[begin:begin + rows][:, take]


def _last_time(rec: Any) -> float | None:
    """Time of the recording's last row (None: no rows), without reading the whole file."""
    if hasattr(rec, "chunks"):
        from cosim.results.timeseries import last_row, resolve_series

        if not resolve_series(rec.path).exists():
            return None
        row = last_row(rec.path, [rec.columns[0]])
        return None if row is None else float(row[0])
    data = rec.data
    return float(data[-1, 0]) if len(data) else None


class SetpointStream:
    """The controller log's set-points read forward from its file for the recording's chunks in
    time order: :meth:`desired` gives ``q_d`` at a chunk's times exactly as
    :func:`cosim.tracking.metrics.desired_joints` over the whole log would (each time
    gets the same pair of cycles), holding only the cycles from the chunk's start onwards."""

    def __init__(self, path: Any) -> None:
        from cosim.results.timeseries import iter_series

        self._chunks = iter_series(path, SETPOINT_COLUMNS)
        self.t = np.zeros(0)
        self.q, self.qd, self.qdd = (np.zeros((0, 6)) for _ in range(3))
        self.done = False
        self.rows = 0
        self.ik_max = -np.inf
        self._ik_seen = False

    def _read(self) -> None:
        try:
            _, block = next(self._chunks)
        except StopIteration:
            self.done = True
            return
        self.rows += len(block)
        ik = block[:, 19]
        if np.isfinite(ik).any():
            self.ik_max = max(self.ik_max, float(np.nanmax(ik)))
            self._ik_seen = True
        ok = np.isfinite(block[:, 1:7]).all(axis=1)
        block = block[ok]
        self.t = np.concatenate([self.t, block[:, 0]])
        self.q = np.concatenate([self.q, block[:, 1:7]])
        self.qd = np.concatenate([self.qd, block[:, 7:13]])
        self.qdd = np.concatenate([self.qdd, block[:, 13:19]])

    def desired(self, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        """q_d (m, 6) at the times ``t`` (ascending, after the previous call's); ``q`` when the
        log has no set-point at all."""
        from cosim.tracking.metrics import desired_joints

        t_max = float(t[-1])
        while not self.done and (not self.t.size or self.t[-1] <= t_max):
            self._read()
        if not self.t.size:
            return q.copy()
        lo = max(int(np.searchsorted(self.t, t[0], side="right")) - 1, 0)
        hi = min(int(np.searchsorted(self.t, t_max, side="right")) + 1, self.t.size)
        q_d = desired_joints(t, self.t[lo:hi], self.q[lo:hi], self.qd[lo:hi], self.qdd[lo:hi])
        self.t, self.q, self.qd, self.qdd = self.t[lo:], self.q[lo:], self.qd[lo:], self.qdd[lo:]
        return q_d

    def finish(self) -> float | None:
        """Read the rest of the log; the largest IK iteration count (None: no rows)."""
        while not self.done:
            self._read()
            self.t, self.q, self.qd, self.qdd = self.t[-2:], self.q[-2:], self.qd[-2:], self.qdd[-2:]
        if not self.rows:
            return None
        return self.ik_max if self._ik_seen else float("nan")


class ResidualStream:
    """The residual vibration after the motion's end (``t >= t_end``) from the noise-free TCP
    error vectors given chunk by chunk, with the same numbers as
    :func:`cosim.tracking.metrics.residual_vibration` over all of them: the vectors go to
    an unnamed temporary file in ``folder`` (24 bytes per sample, removed when closed) and are
    read back in chunks once the final pose (the last ``FINAL_POSE_WINDOW_S``) is known."""

    def __init__(self, t_end: float, folder: Path, band: float) -> None:
        import tempfile

        self.t_end, self.band = t_end, band
        self._file = tempfile.TemporaryFile(dir=folder, prefix=".residual-")
        self.count = 0
        self.t_last = -np.inf

    def add(self, t: np.ndarray, error: np.ndarray) -> None:
        after = t >= self.t_end - 1e-9
        if after.any():
            rows = np.column_stack([t[after], error[after]])
            self._file.write(rows.tobytes())
            self.count += rows.shape[0]
            self.t_last = float(rows[-1, 0])

    def _rows(self, begin: int = 0, chunk: int = EVAL_CHUNK_ROWS):
        self._file.flush()
        self._file.seek(begin * 32)
        while True:
            raw = self._file.read(chunk * 32)
            if not raw:
                return
            yield np.frombuffer(raw, dtype=np.float64).reshape(-1, 4)

    def _tail(self, keep) -> np.ndarray:
        """The rows for which ``keep(t)`` holds, searched from the end (they are the last ones)."""
        begin = self.count
        step = 1024
        while begin > 0:
            begin = max(0, begin - step)
            self._file.flush()
            self._file.seek(begin * 32)
            first = np.frombuffer(self._file.read(32), dtype=np.float64)
            if not keep(first[0]):
                break
            step *= 2
        rows = np.concatenate(list(self._rows(begin)))
        return np.ascontiguousarray(rows[keep(rows[:, 0])][:, 1:])

    def result(self) -> tuple[dict[str, float], np.ndarray, np.ndarray]:
        """(the residual-vibration metrics, seconds after t_end and noise-free error norm (m)
        of its first :data:`RESIDUAL_FIGURE_S`) and close the temporary file."""
        from cosim.tracking.metrics import FINAL_POSE_WINDOW_S

        nan = float("nan")
        try:
            if self.count == 0:
                return ({"peak_mm": nan, "settling_time_s": nan, "static_offset_mm": nan,
                         "band_mm": self.band * 1e3, "window_s": 0.0}, np.zeros(0), np.zeros(0))
            last = self.t_last
            final = self._tail(lambda x: x >= last - FINAL_POSE_WINDOW_S).mean(axis=0)
            r_last = last - self.t_end
            figure_final = self._tail(lambda x: (x - self.t_end) >= r_last - FINAL_POSE_WINDOW_S).mean(axis=0)
            peak, last_out, after_out, seen = -np.inf, None, None, 0
            fig_t, fig_e = [], []
            for rows in self._rows():
                ta, ea = rows[:, 0], np.ascontiguousarray(rows[:, 1:])
                distance = np.linalg.norm(ea - final, axis=1)
                peak = max(peak, float(distance.max()))
                if last_out is not None and after_out is None:
                    after_out = float(ta[0])
                outside = np.flatnonzero(distance > self.band)
                if outside.size:
                    k = int(outside[-1])
                    last_out = float(ta[k])
                    after_out = float(ta[k + 1]) if k + 1 < ta.size else None
                rt = ta - self.t_end
                near = rt <= RESIDUAL_FIGURE_S
                if near.any():
                    fig_t.append(rt[near])
                    fig_e.append(np.linalg.norm(ea[near] - figure_final, axis=1))
                seen += ta.size
            if self.count < 2:
                residual = {"peak_mm": nan, "settling_time_s": nan, "static_offset_mm": nan,
                            "band_mm": self.band * 1e3, "window_s": 0.0}
            else:
                if last_out is None:
                    settling = 0.0
                elif last_out >= last - FINAL_POSE_WINDOW_S:
                    settling = nan
                else:
                    settling = float(after_out - self.t_end)
                residual = {"peak_mm": float(peak * 1e3), "settling_time_s": settling,
                            "static_offset_mm": float(np.linalg.norm(final) * 1e3), "band_mm": self.band * 1e3,
                            "window_s": float(last - self.t_end)}
            return residual, np.concatenate(fig_t), np.concatenate(fig_e)
        finally:
            self._file.close()


def controller_log_columns(ctx: RunContext, name: str, cell: CellRun, controller: Any) -> dict[str, np.ndarray]:
    """The built-in controller's whole log as columns: read back from the file the run streamed
    (``cell.controller_record``), or - paced and split runs keep it in memory - written now as
    ``name`` and returned. Holds the whole log: for runs whose length the trajectory bounds."""
    from cosim.results.timeseries import read_series

    path = _controller_file(ctx, name, cell, controller)
    names, data = read_series(path)
    return {n: data[:, i] for i, n in enumerate(names)}


def _controller_file(ctx: RunContext, name: str, cell: CellRun, controller: Any) -> Path:
    """The controller log's file: the one streamed during the run, else written now from memory."""
    streamed = getattr(cell, "controller_record", None)
    if streamed is not None:
        return Path(streamed)
    from controller.controller import LOG_COLUMNS, LOG_KINDS

    log = controller.log.columns()
    if list(log) != list(LOG_COLUMNS):  # not the built-in log's layout: as it is
        return ctx.path(ctx.write_series(name, log, series_units(log)))
    sink = ctx.series_sink(name, series_units(log))  # as the streamed log
    sink.open(list(LOG_COLUMNS), list(LOG_KINDS))
    try:
        rows = len(log[LOG_COLUMNS[0]])
        for start in range(0, rows, EVAL_CHUNK_ROWS):
            sink.write(np.column_stack([log[c][start:start + EVAL_CHUNK_ROWS] for c in LOG_COLUMNS]))
    finally:
        sink.close()
    return ctx.path(ctx.series_name(name))


def evaluate_run(ctx: RunContext, mode: str, cell: CellRun, controller: Any, reference, path, true_robot,
                 kinematic_model: Any = None, q_start: Any = None,
                 port_timing: Any = None) -> tuple[dict[str, Any], TrackingResult]:
    """Post-process one run of the ISO 9283 path on the cell (also after a failure): the
    controller log ``controller_<mode>`` (streamed by the run; written now if it stayed in
    memory), ``tcp_<mode>`` (Parquet, or CSV on request; programmed, commanded and measured
    TCP in m, base_link; TCP and path errors in mm; joint set-points and lag errors in rad),
    and return (the summary entry of the run, the tracking result).

    The recording and the controller log are read back chunk by chunk
    (:data:`EVAL_CHUNK_ROWS`) and ``tcp_<mode>`` streams out the same way: memory holds one
    chunk, the motion window's samples (bounded by the path's duration) and at most
    :data:`RESIDUAL_FIGURE_S` of the stretch after the motion, whatever the run's length.
    The figures equal those of one pass over whole arrays, bit for bit.

    ``mode`` names the run in the file names; ``reference`` is the controller's TCP
    trajectory, ``path`` the planners.iso9283 test path, ``true_robot`` the plant's robot
    (its kinematics turn joint angles into the commanded and true flange positions).

    For a user's controller (not :class:`controller.Controller`) the joint set-points are the
    reference's IK with ``kinematic_model`` from ``q_start``, aligned at the controller's
    ``motion_start_s``; its compute times are ``port_timing`` (the cell's
    :meth:`controller.port.ControllerPort.timing`)."""
    from cosim.results.timeseries import release_memory
    from cosim.tracking.metrics import VIBRATION_BAND_M
    from robot.kinematics import FlangeKinematics

    builtin = isinstance(controller, Controller) or isinstance(getattr(controller, "log", None), ControllerLog)
    rec = cell.recording
    cols = list(rec.columns)
    wanted = ([cols[0]] + [f"plant.q[{i}]" for i in range(1, 7)] + ["tracker.x", "tracker.y", "tracker.z"]
              if cols else [])
    start = getattr(controller, "motion_start_s", None)
    t_last = _last_time(rec) if cols else None
    t_end = (start + path.duration) if start is not None else -1.0
    window = (start if start is not None else np.inf, min(t_end, t_last if t_last is not None else -1.0))
    controller_file = None
    setpoints = None
    if builtin:
        controller_file = _controller_file(ctx, f"controller_{mode}", cell, controller)
        setpoints = SetpointStream(controller_file)
        controller_file = controller_file.name
    user_ik = None
    true_kinematics = FlangeKinematics(true_robot.kinematic_model())
    residual = ResidualStream(window[1], ctx.out_dir, VIBRATION_BAND_M)
    tcp_columns = (["t", "tau", "segment", "arc_length"]
                   + [f"{axis}_{name}" for name in ("programmed", "commanded", "measured") for axis in "xyz"]
                   + ["tcp_error_mm", "path_error_mm"] + [f"{g}{j}" for g in ("q_d", "q", "lag") for j in range(1, 7)])
    tcp_sink = ctx.series_sink(f"tcp_{mode}", series_units(tcp_columns))  # every column stored (derived ones too)
    tcp_sink.open(tcp_columns, ["Integer" if c == "segment" else "Real" for c in tcp_columns])
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "q", "measured", "q_d", "commanded", "programmed",
                                                          "segment", "arc_length", "actual")}
    rows = 0
    try:
        for block in (recording_chunks(rec, wanted) if cols else ()):
            t = block[:, 0]
            q = block[:, 1:7]
            measured = block[:, 7:10]
            if builtin:
                q_d = setpoints.desired(t, q)
            else:  # a user's controller: the reference's joint motion through the controller's IK, offline
                if user_ik is None:
                    user_ik = _ReferenceJoints(start, reference, kinematic_model, q_start, t)
                q_d = user_ik.joints(t)
            commanded = true_kinematics.positions(q_d)
            actual = true_kinematics.positions(q)
            tau = np.clip(t - (start if start is not None else np.inf), 0.0, path.duration)
            programmed = reference.positions(reference.t_start + tau)
            segment, arc_length = path.progress(tau)
            tcp_sink.write(np.column_stack([t, tau, segment.astype(float), arc_length, programmed, commanded,
                                            measured, np.linalg.norm(measured - commanded, axis=1) * 1e3,
                                            np.linalg.norm(measured - programmed, axis=1) * 1e3, q_d, q, q_d - q]))
            tcp_sink.flush()
            inside = (t >= window[0] - 1e-9) & (t <= window[1] + 1e-9)
            if inside.any():
                for key, arr in (("t", t), ("q", q), ("measured", measured), ("q_d", q_d), ("commanded", commanded),
                                 ("programmed", programmed), ("segment", segment), ("arc_length", arc_length),
                                 ("actual", actual)):
                    parts[key].append(arr[inside])
            residual.add(t, actual - commanded)
            rows += t.size
            release_memory()
    finally:
        tcp_sink.close()
        residual_fields = residual.result()
    whole = {k: (np.concatenate(v) if v else None) for k, v in parts.items()}
    if whole["t"] is None:
        empty3 = np.zeros((0, 3))
        whole = {"t": np.zeros(0), "q": np.zeros((0, 6)), "measured": empty3, "q_d": np.zeros((0, 6)),
                 "commanded": empty3, "programmed": empty3, "segment": np.zeros(0, dtype=int),
                 "arc_length": np.zeros(0), "actual": empty3}
    result = evaluate(whole["t"], whole["q"], whole["measured"], whole["q_d"], whole["commanded"],
                      whole["programmed"], whole["segment"], window, whole["arc_length"], whole["actual"])
    result.residual, result.residual_t, result.residual_error = residual_fields
    tcp_file = ctx.series_name(f"tcp_{mode}")
    ik_max = setpoints.finish() if setpoints is not None else None
    timing = controller.timing() if builtin else port_timing
    if timing is not None:
        timing = timing.judged_on(deadline_basis(cell))
    entry: dict[str, Any] = {
        "status": "ok" if cell.failure is None else "failed",
        **result.metrics(path.segment_names),
        **timing_fields(timing),
        "controller_cycles_timed": None if timing is None else timing.cycles,
        "sim_time_s": cell.reached_s,
        "loop_wall_time_s": cell.loop_wall_time_s,
        "loop_realtime_factor": cell.reached_s / cell.loop_wall_time_s if cell.loop_wall_time_s > 0 else None,
        "engine": cell.engine,
        "motion_start_s": start,
        "enabled_at_s": getattr(controller, "enabled_at_s", None),
        "path_completed": bool(start is not None and rows and t_last >= t_end - 1e-9),
        "stop_reason": getattr(controller, "stop_reason", None),
        "fieldbus": {k: cell.fieldbus[k] for k in ("cycles_run", "frames_sent", "frames_dropped", "frames_recorded",
                                                   "log_path", "dead_time_cycles", "node_fault", "comm_fault",
                                                   "scaling_saturations", "event_tally")}
        | ({"asynchronous": cell.fieldbus["asynchronous"]}  # SDO/NMT in the asynchronous slot (when any)
           if (cell.fieldbus.get("asynchronous") or {}).get("requests") else {}),
        "files": {"timeseries": ctx.series_name(f"timeseries_{mode}"), "controller": controller_file if builtin else _record_name(cell),
                  "tcp": tcp_file, "can_log": Path(cell.fieldbus["log_path"]).name
                  if cell.fieldbus.get("log_path") else None},
    }
    external = getattr(cell, "external_controller", None)
    if external is not None:  # cosim serve: the controller was another program; the job's did not run
        entry = served_entry(entry, external)
    elif builtin:
        entry.update(controller_phase=controller.phase.name.lower(),
                     ik_iterations_max=ik_max,
                     compiled_kernel=controller.kernel_note, kernel_cycles=controller.kernel_cycles,
                     fallback_cycles=controller.fallback_cycles)
    else:
        entry["controller"] = type(controller).__name__
        entry["contract_overhead_us"] = getattr(cell, "port_overhead", None)
        if start is None:
            entry["note"] = ("the controller gives no motion_start_s: the reference is not aligned with the run, "
                             "tracking figures are not evaluated")
    if cell.failure is not None:
        entry["failure"] = str(cell.failure)
    stopped_at = getattr(controller, "stopped_at_s", None)
    if stopped_at is not None:
        entry["stopped_at_s"] = stopped_at
    elif cell.failure is not None and cell.failure.component == "controller":
        entry["stopped_at_s"] = cell.failure.time
    from cosim.cell.verdict import record

    record(entry, cell, timing)  # verdict, violations, first_violation (cosim/cell/verdict.py)
    if hasattr(ctx, "note_verdict"):
        ctx.note_verdict(mode, entry)
    return entry, result


#: Keys of a run's summary entry that describe the job's own controller or the tracking of the
#: job's reference; a served run's (cosim serve) controller is another program, so they do not apply.
SERVED_DROPPED = ("tcp_error_max_mm", "tcp_error_rms_mm", "path_accuracy_AT_mm", "path_accuracy_AT_per_segment_mm",
                  "joint_lag_max_rad", "tcp_error_max_noise_free_mm", "tcp_error_rms_noise_free_mm",
                  "tcp_path_error_max_mm", "tcp_path_error_rms_mm", "path_accuracy_AT_vs_programmed_mm",
                  "residual_vibration", "tcp_error_spectrum_peak_hz", "tcp_error_spectrum_peak_mm",
                  "evaluated_samples", "evaluated_from_s", "evaluated_to_s", "cycle_compute_us",
                  "cycle_compute_cpu_us", "cycle_wall_us", "deadline_misses", "compute_budget_us",
                  "controller_cycles_timed", "drive_speed_feedforward", "torque_feedforward", "path_completed",
                  "stop_reason", "motion_start_s", "enabled_at_s")


def served_entry(entry: dict[str, Any], external: dict[str, Any]) -> dict[str, Any]:
    """The summary entry of a served run (``cosim serve``): what the external controller did as
    the drives saw it (:meth:`cosim.execution.cell_side.CellSideLink.controller_run`: when all drives
    were enabled, when the applied targets moved, whether they were enabled at the end) in place
    of the job controller's fields and the tracking of the job's reference, which the external
    controller is not known to follow (its TCP is in the tcp file all the same)."""
    kept = {k: v for k, v in entry.items() if k not in SERVED_DROPPED}
    return {"status": kept.pop("status"), "controller": "external (cosim serve)", **external,
            "tracking": "not evaluated: the external controller's motion is not the job's reference",
            **kept}


def deadline_basis(cell: Any) -> str:
    """The clock a run's controller deadline misses are judged on: ``"wall_time"`` for a
    real-time run (paced or served: the cycle waits for the wall clock), ``"cpu_time"`` for a
    simulated-time run (nothing waits for the wall clock, and wall time holds the time sibling
    processes took the core)."""
    return "wall_time" if getattr(cell, "pacer", None) is not None else "cpu_time"


def timing_fields(timing: Any) -> dict[str, Any]:
    """A run's controller timing for summary.json (None values without a timing):
    ``cycle_wall_us`` {p50, p99, max, mean}, ``cycle_compute_cpu_us`` {p50, p99, max},
    ``deadline_misses`` (judged on ``deadline_basis``), ``cycles_over_budget_wall`` and
    ``cycles_over_budget_cpu``, ``compute_budget_us`` (their definitions: :data:`DEFINITIONS`)."""
    if timing is None:
        return {"cycle_wall_us": None, "cycle_compute_cpu_us": None, "deadline_misses": None, "deadline_basis": None,
                "cycles_over_budget_wall": None, "cycles_over_budget_cpu": None, "compute_budget_us": None}
    return {"cycle_wall_us": {"p50": timing.p50_us, "p99": timing.p99_us, "max": timing.max_us, "mean": timing.mean_us},
            "cycle_compute_cpu_us": {"p50": timing.cpu_p50_us, "p99": timing.cpu_p99_us, "max": timing.cpu_max_us},
            "deadline_misses": timing.deadline_misses, "deadline_basis": timing.deadline_basis,
            "cycles_over_budget_wall": timing.wall_over_budget, "cycles_over_budget_cpu": timing.cpu_over_budget,
            "compute_budget_us": timing.budget_us}


def _record_name(cell: CellRun) -> str | None:
    """The file name of a user controller's command log (``CellRun.controller_record``), None without one."""
    record = getattr(cell, "controller_record", None)
    return Path(record).name if record is not None else None


class _ReferenceJoints:
    """The joint motion (rad) of a TCP ``reference`` at the recording's times, chunk by chunk,
    with trajectory time 0 at ``start`` (s): the IK of ``kinematic_model`` along it, warm started
    from ``q_start`` and across the chunks; the step ``dt`` is the median sample spacing of the
    first chunk (``first_t``)."""

    def __init__(self, start: float | None, reference: Any, kinematic_model: Any, q_start: Any,
                 first_t: np.ndarray) -> None:
        from controller import CartesianToJoint, JointTrajectory

        self.start, self.reference, self.q_start = start, reference, q_start
        self.joint = isinstance(reference, JointTrajectory)
        self.dt = float(np.median(np.diff(first_t))) if first_t.size > 1 else 1e-3
        self.ik = None
        if start is not None and not self.joint:
            self.ik = CartesianToJoint(kinematic_model)
            self.ik.reset(np.asarray(q_start, dtype=float))

    def joints(self, t: np.ndarray) -> np.ndarray:
        reference = self.reference
        if self.start is None:
            return np.tile(np.asarray(self.q_start, dtype=float), (t.size, 1))
        tau = np.clip(t - self.start, 0.0, reference.duration)
        if self.joint:
            return np.array([reference.sample(reference.t_start + x).q for x in tau])
        out = np.empty((t.size, 6))
        for k, x in enumerate(tau):
            sample = reference.sample(reference.t_start + x)
            out[k] = self.ik.solve(sample.target, sample.twist, sample.acceleration, self.dt)[0]
        return out
