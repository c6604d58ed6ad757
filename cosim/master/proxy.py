"""Out-of-process FMUs: one FMI 2.0 FMU instance served by a child process, like libcosim's proxy-fmu.

An FMU's native code runs in the master's process by default, so a crash in it (a NULL
dereference, ``abort()``, ``_exit()``) kills the whole run and a hang in ``fmi2DoStep`` hangs
it. ``ProxyFmu`` loads the FMU in a child process instead (as an :class:`fmus.fmu.Fmu` there)
and talks to it over a socket pair; the master and both engines see the same
:class:`~fmus.fmu.Fmu` interface (``ProxyFmu`` is a subclass whose per-step "function
pointers" are ctypes callbacks that forward the call):

* fmi2Set* calls are buffered and sent with the next fmi2DoStep, whose reply carries the
  outputs the master read after the previous step (one round trip per step);
* a child that dies (any signal, any exit) or does not answer a step within
  ``step_timeout_s`` (then it is killed) makes the call return fmi2Fatal, and the
  ``SimulationError`` names the component, the simulated time and the signal or timeout;
  everything recorded up to that communication point is flushed as for any failure;
* the child ignores SIGINT/SIGTERM (Ctrl-C reaches the whole process group): an interrupt
  is the parent's to handle, which then shuts the child down;
* the FMU's log messages are forwarded as they are logged, so the last ones before a crash
  are kept.

Cost: one socket round trip per step (the outputs come back with the step's reply);
benchmarks/bench_out_of_process.py measures what it costs per step. FMI 3.0 FMUs run in process only.
"""
from __future__ import annotations

import ctypes
import multiprocessing.connection
import os
import pickle
import signal
import socket
import subprocess
import sys
import time
from ctypes import c_double, c_int, c_void_p

from cosim.master.errors import MasterConfigError, SimulationError
from fmus.fmu import VALUE_CTYPE, VALUE_TYPES, Fmu
from fmus.instance import SET_T, STEP_T

#: Default longest wall time one fmi2DoStep (and one Set/Get round trip) may take out of process, s.
#: A real-time-capable model steps in microseconds to milliseconds; 60 s only catches hangs.
DEFAULT_STEP_TIMEOUT_S = 60.0
#: Longest wall time for loading, instantiating and initializing the FMU in the child, s.
LIFECYCLE_TIMEOUT_S = 120.0
#: Wall time the child gets to terminate and free the instance before it is killed, s.
SHUTDOWN_TIMEOUT_S = 5.0

_FATAL = 4
_ERROR = 3
_DTYPES = VALUE_CTYPE
_TYPE_NAME = VALUE_TYPES
_TYPE_CODE = {name: code for code, name in enumerate(_TYPE_NAME)}


class ChildGone(RuntimeError):
    """The FMU's process died or was killed (``status`` 4 = fatal, for Fmu.call)."""

    status = _FATAL


# ----------------------------------------------------------------------------------------- child side
def _ignore_interrupts() -> None:
    """In the child before it execs Python: SIGINT/SIGTERM ignored (Python keeps an inherited SIG_IGN)."""
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_IGN)


def _child_main() -> None:
    """Entry point of the child process: ``-c ... FD FMU_PATH NAME LOGGING``."""
    fd, fmu_path, name, logging_on = sys.argv[1:5]
    conn = multiprocessing.connection.Connection(int(fd))
    try:
        _serve(conn, fmu_path, name, logging_on == "1")
    finally:
        conn.close()


def _serve(conn, fmu_path: str, name: str, debug_logging: bool) -> None:
    """Child process: instantiate the FMU and answer requests until ``exit`` or the pipe closes."""
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_IGN)

    def forward(text: str) -> None:
        try:
            conn.send_bytes(b"L" + text.encode())
        except OSError:
            pass

    def reply(obj) -> None:
        conn.send_bytes(b"P" + pickle.dumps(obj))

    try:
        fmu = Fmu(fmu_path, name, debug_logging=debug_logging, on_message=forward)
        fmu.instantiate()
    except (SimulationError, OSError, ValueError) as exc:
        reason = exc.reason if isinstance(exc, SimulationError) else str(exc)
        reply(("error", reason, getattr(exc, "status", _ERROR)))
        return
    slave = fmu.slave
    handle = fmu.component
    set_fn = [getattr(slave.dll, f"fmi2Set{t}") for t in _TYPE_NAME]
    get_fn = [getattr(slave.dll, f"fmi2Get{t}") for t in _TYPE_NAME]
    do_step = slave.dll.fmi2DoStep
    reply(("ready",))
    while True:
        try:
            request = conn.recv_bytes()
        except (EOFError, OSError):
            break
        op = request[:1]
        if op in (b"D", b"S"):  # [D|S][t h][n_sets][per set: code, n, vrs, values]; S: no step
            t, h, n_sets = _STEP_HEAD.unpack_from(request, 1)
            offset = 1 + _STEP_HEAD.size
            status = 0
            for _ in range(n_sets):
                code, n = _SET_HEAD.unpack_from(request, offset)
                offset += _SET_HEAD.size
                vrs = (ctypes.c_uint32 * n).from_buffer_copy(request, offset)
                offset += 4 * n
                size = ctypes.sizeof(_DTYPES[_TYPE_NAME[code]]) * n
                values = (_DTYPES[_TYPE_NAME[code]] * n).from_buffer_copy(request, offset)
                offset += size
                s = set_fn[code](handle, vrs, ctypes.c_size_t(n), values)
                if s > 1:
                    status = s
                    break
            if status <= 1 and op == b"D":
                status = do_step(handle, c_double(t), c_double(h), c_int(1))
            out = [b"R", _STATUS_ONLY.pack(status)]
            if op == b"D" and status <= 1:  # the outputs the parent will ask for next (its last pattern)
                (n_gets,) = _COUNT.unpack_from(request, offset)
                offset += _COUNT.size
                for _ in range(n_gets):
                    code, n = _SET_HEAD.unpack_from(request, offset)
                    offset += _SET_HEAD.size
                    vrs = (ctypes.c_uint32 * n).from_buffer_copy(request, offset)
                    offset += 4 * n
                    values = (_DTYPES[_TYPE_NAME[code]] * n)()
                    out.append(_STATUS_ONLY.pack(get_fn[code](handle, vrs, ctypes.c_size_t(n), values)))
                    out.append(bytes(values))
            conn.send_bytes(b"".join(out))
        elif op == b"G":  # [G][code n][vrs] -> [status][values]
            code, n = _SET_HEAD.unpack_from(request, 1)
            vrs = (ctypes.c_uint32 * n).from_buffer_copy(request, 1 + _SET_HEAD.size)
            values = (_DTYPES[_TYPE_NAME[code]] * n)()
            status = get_fn[code](handle, vrs, ctypes.c_size_t(n), values)
            conn.send_bytes(b"R" + _STATUS_ONLY.pack(status) + bytes(values))
        elif op == b"C":  # a pickled lifecycle call (method name, args)
            method, args = pickle.loads(request[1:])
            if method == "exit":
                reply(("ok", None))
                break
            if method == "freeInstance":  # through the Fmu, which then knows it is freed
                fmu.close(terminate=False)
                reply(("ok", None))
                continue
            try:
                reply(("ok", getattr(slave, method)(*args)))
            except Exception as exc:  # noqa: BLE001 - reported to the parent
                reply(("error", f"{exc}", getattr(exc, "status", _ERROR)))
    conn.close()


import struct  # noqa: E402 - beside the formats it defines

_STEP_HEAD = struct.Struct("<ddI")
_SET_HEAD = struct.Struct("<BI")
_STATUS_ONLY = struct.Struct("<i")
_COUNT = struct.Struct("<I")


# ----------------------------------------------------------------------------------------- parent side
class _RemoteSlave:
    """The fmpy lifecycle calls Fmu makes (``slave.setupExperiment(...)`` ...), forwarded."""

    def __init__(self, proxy: "ProxyFmu") -> None:
        self._proxy = proxy

    def __getattr__(self, method: str):
        def call(*args):
            return self._proxy.remote_call(method, args)
        return call


class _RemoteError(RuntimeError):
    def __init__(self, text: str, status: int) -> None:
        super().__init__(text)
        self.status = status


class ProxyFmu(Fmu):
    """An FMI 2.0 FMU instance in a child process (see the module docstring).

    Args: as :class:`~fmus.fmu.Fmu` (path, name, start values, ``debug_logging``, ``log_capacity``),
    plus ``step_timeout_s``: the longest wall time (s) a step or a Set/Get round trip may take
    before the child is killed (default :data:`DEFAULT_STEP_TIMEOUT_S`).
    """

    out_of_process = True

    def __init__(self, path, name, start_values=None, *, debug_logging: bool = False, log_capacity: int = 50,
                 step_timeout_s: float | None = None) -> None:
        super().__init__(path, name, start_values, debug_logging=debug_logging, log_capacity=log_capacity)
        if self.fmi3:
            raise MasterConfigError(f"FMU '{name}' ({self.path.name}): out-of-process execution supports FMI 2.0 "
                                    f"co-simulation FMUs; run this FMI 3.0 FMU in process")
        timeout = DEFAULT_STEP_TIMEOUT_S if step_timeout_s is None else float(step_timeout_s)
        if not timeout > 0:
            raise MasterConfigError(f"step timeout of FMU '{name}': expected a positive number of seconds, "
                                    f"got {step_timeout_s!r}")
        self.step_timeout_s = timeout
        self.crash: str | None = None
        self.process = None
        self._conn = None
        self._pending: list[bytes] = []
        self._pending_sets = 0
        self._interrupt: BaseException | None = None
        self.round_trips = 0
        self._busy = False
        # fmi2Get* requests seen since the last step, sent with the next step so that its reply carries
        # the values (one round trip per step); valid until the next set or step
        self._pattern: list[bytes] = []
        self._seen: list[bytes] = []
        self._cache: dict[bytes, tuple[int, bytes]] = {}

    # ------------------------------------------------------------------ process
    def instantiate(self, stop_at_address: int | None = None) -> None:
        # a plain subprocess over a socket pair, not multiprocessing: a Dask worker (a daemonic
        # process) may not start multiprocessing children, and the FMU needs none of its machinery
        parent_socket, child_socket = socket.socketpair()
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([p for p in sys.path if p] + [env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        try:
            self.process = subprocess.Popen(
                [sys.executable, "-c", "from cosim.master.proxy import _child_main; _child_main()",
                 str(child_socket.fileno()), str(self.path), self.name, "1" if self.debug_logging else "0"],
                pass_fds=(child_socket.fileno(),), env=env, preexec_fn=_ignore_interrupts, close_fds=True)
        finally:
            child_socket.close()
        self._conn = multiprocessing.connection.Connection(parent_socket.detach())
        reply = self._receive(LIFECYCLE_TIMEOUT_S, "loading and instantiating the FMU", 0.0)
        if reply[0] == "error":
            raise self.error(0.0, reply[1])
        self.slave = _RemoteSlave(self)
        self.component = 1  # a non-NULL handle: the callbacks know their instance
        self._callbacks_keep = [STEP_T(self._do_step)] + [SET_T(self._make_set(t)) for t in _TYPE_NAME] + \
            [SET_T(self._make_get(t)) for t in _TYPE_NAME]
        addresses = [ctypes.cast(cb, c_void_p).value for cb in self._callbacks_keep]
        self._bind({"DoStep": addresses[0], **{f"Set{t}": addresses[1 + i] for i, t in enumerate(_TYPE_NAME)},
                    **{f"Get{t}": addresses[4 + i] for i, t in enumerate(_TYPE_NAME)}})

    def _describe_death(self) -> str:
        process = self.process
        try:
            code = process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            code = None
        if code is None:
            return "its process stopped answering"
        if code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = f"signal {-code}"
            return f"its process died with {name} (signal {-code})"
        return f"its process exited with code {code}"

    def _kill(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            try:
                self.process.wait(timeout=5.0)
            except subprocess.TimeoutExpired:  # pragma: no cover - a process that survives SIGKILL
                pass

    def _receive(self, timeout_s: float, what: str, t: float):
        """The next reply (forwarding log messages); ChildGone when the child died or timed out."""
        conn = self._conn
        deadline = time.monotonic() + timeout_s
        self._busy = True  # a request is out: until its reply, the child may be stuck in the FMU
        while True:
            remaining = deadline - time.monotonic()
            try:
                ready = conn.poll(max(remaining, 0.0))
            except (EOFError, OSError):
                ready = True
            if not ready:
                self._kill()
                self.crash = f"no answer within the step timeout of {timeout_s:g} s: the FMU hangs (its process was killed)"
                self.failed_fatally = True
                raise ChildGone(self.crash)
            try:
                message = conn.recv_bytes()
            except (EOFError, OSError):
                self.crash = self._describe_death()
                self.failed_fatally = True
                raise ChildGone(self.crash) from None
            tag = message[:1]
            if tag == b"L":
                self.messages.append(message[1:].decode("utf-8", "replace"))
                continue
            self._busy = False
            if tag == b"P":
                return pickle.loads(message[1:])
            return message[1:]

    def _receive_bytes(self, timeout_s: float, what: str, t: float) -> bytes:
        reply = self._receive(timeout_s, what, t)
        if not isinstance(reply, bytes):  # pragma: no cover - protocol error
            raise ChildGone(f"unexpected reply {reply!r} to {what}")
        return reply

    def remote_call(self, method: str, args: tuple):
        """A lifecycle call in the child; raises like fmpy (an exception with ``status``)."""
        if self._busy:  # an interrupted request is still being served (the FMU hangs or is slow)
            raise ChildGone("the FMU's process is still busy with an interrupted call")
        if self.crash is not None:
            raise ChildGone(self.crash)
        self._flush_sets()
        self._conn.send_bytes(b"C" + pickle.dumps((method, args)))
        reply = self._receive(max(LIFECYCLE_TIMEOUT_S, self.step_timeout_s), f"{method}()", 0.0)
        if reply[0] == "error":
            raise _RemoteError(reply[1], reply[2])
        return reply[1]

    # ------------------------------------------------------------------ per-step callbacks
    def _make_set(self, bus_type: str):
        code = _TYPE_CODE[bus_type]
        size = ctypes.sizeof(_DTYPES[bus_type])

        def set_values(handle, vrs, n, values) -> int:
            self._cache.clear()
            self._pending.append(_SET_HEAD.pack(code, n) + ctypes.string_at(vrs, 4 * n)
                                 + ctypes.string_at(values, size * n))
            self._pending_sets += 1
            return 0
        return set_values

    def _make_get(self, bus_type: str):
        code = _TYPE_CODE[bus_type]
        size = ctypes.sizeof(_DTYPES[bus_type])

        def get_values(handle, vrs, n, values) -> int:
            if self.crash is not None:
                return _FATAL
            key = _SET_HEAD.pack(code, n) + ctypes.string_at(vrs, 4 * n)
            if key not in self._seen:
                self._seen.append(key)
            cached = self._cache.pop(key, None)
            if cached is not None:
                ctypes.memmove(values, cached[1], size * n)
                return cached[0]
            try:
                self._flush_sets()
                self._conn.send_bytes(b"G" + _SET_HEAD.pack(code, n) + ctypes.string_at(vrs, 4 * n))
                reply = self._receive_bytes(self.step_timeout_s, f"fmi2Get{bus_type}", 0.0)
            except ChildGone:
                return _FATAL
            except _RemoteError as exc:
                return exc.status
            except KeyboardInterrupt as exc:
                self._interrupt = exc
                return _ERROR
            except OSError:
                self.crash = self._describe_death()
                return _FATAL
            self.round_trips += 1
            status = _STATUS_ONLY.unpack_from(reply)[0]
            ctypes.memmove(values, reply[_STATUS_ONLY.size:_STATUS_ONLY.size + size * n], size * n)
            return status
        return get_values

    def _flush_sets(self) -> None:
        """Send buffered sets not followed by a step (initialization mode, before a Get or a lifecycle
        call) as a batch without a step."""
        if not self._pending:
            return
        body = b"".join(self._pending)
        n = self._pending_sets
        self._pending, self._pending_sets = [], 0
        self._conn.send_bytes(b"S" + _STEP_HEAD.pack(0.0, 0.0, n) + body)
        reply = self._receive_bytes(self.step_timeout_s, "fmi2Set*", 0.0)
        status = _STATUS_ONLY.unpack_from(reply)[0]
        if status > 1:
            raise _RemoteError(f"fmi2Set* returned status {status}", status)

    def _do_step(self, handle, t, h, no_set) -> int:
        if self.crash is not None:
            return _FATAL
        body = b"".join(self._pending)
        n = self._pending_sets
        self._pending, self._pending_sets = [], 0
        if self._seen:
            self._pattern, self._seen = self._seen, []
        pattern = self._pattern
        self._cache.clear()
        what = f"fmi2DoStep(t={t:.9g} s, h={h:.9g} s)"
        try:
            self._conn.send_bytes(b"".join([b"D", _STEP_HEAD.pack(t, h, n), body, _COUNT.pack(len(pattern)),
                                            *pattern]))
            reply = self._receive_bytes(self.step_timeout_s, what, t)
        except ChildGone:
            return _FATAL
        except KeyboardInterrupt as exc:  # returned to the engine as an error, re-raised by error()
            self._interrupt = exc
            return _ERROR
        except OSError:
            self.crash = self._describe_death()
            self.failed_fatally = True
            return _FATAL
        self.round_trips += 1
        status = _STATUS_ONLY.unpack_from(reply)[0]
        if status <= 1 and pattern:
            offset = _STATUS_ONLY.size
            for key in pattern:
                code, count = _SET_HEAD.unpack_from(key)
                size = ctypes.sizeof(_DTYPES[_TYPE_NAME[code]]) * count
                get_status = _STATUS_ONLY.unpack_from(reply, offset)[0]
                offset += _STATUS_ONLY.size
                self._cache[key] = (get_status, reply[offset:offset + size])
                offset += size
        return status

    # ------------------------------------------------------------------ errors and shutdown
    def error(self, time: float, reason: str):
        """As Fmu.error, naming the crash or timeout; an interrupt caught inside a forwarded
        call is handed back (the engine raises it) instead of being reported as an FMU failure."""
        if self._interrupt is not None:
            interrupt, self._interrupt = self._interrupt, None
            return interrupt
        if self.crash is not None:
            reason = f"{reason}: {self.crash}"
        return SimulationError(self.name, time, reason, self.messages,
                               "" if self.debug_logging else "the FMU logged nothing before; debug_logging=True "
                                                             "turns its logging on")

    def close(self, terminate: bool) -> None:
        """fmi2Terminate and fmi2FreeInstance in the child (when healthy), then end the child; never raises."""
        if self.process is None:
            return
        if self.crash is None and self.slave is not None and not self._busy:
            self.step_timeout_s = min(self.step_timeout_s, SHUTDOWN_TIMEOUT_S)
            try:
                super().close(terminate)
            except Exception:  # noqa: BLE001 - shutting down anyway
                pass
            try:
                self._conn.send_bytes(b"C" + pickle.dumps(("exit", ())))
                self._receive(SHUTDOWN_TIMEOUT_S, "exit", 0.0)
            except Exception:  # noqa: BLE001
                pass
        self.slave = None
        if not self._busy:  # a child still inside an interrupted call is killed at once
            try:
                self.process.wait(timeout=SHUTDOWN_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                pass
        self._kill()
        try:
            self._conn.close()
        except OSError:
            pass
        self.process = None


__all__ = ["ChildGone", "DEFAULT_STEP_TIMEOUT_S", "LIFECYCLE_TIMEOUT_S", "ProxyFmu", "SHUTDOWN_TIMEOUT_S"]
