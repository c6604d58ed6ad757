"""Exit codes of ``python -m cosim`` and the errors that carry them (docs/robustness.md).

Every command returns one of these codes; ``cosim.cli.main`` turns any exception that
escapes a command into a one-line ``error: ...`` message and the matching code (the
traceback only with ``--debug``):

====  =========================================================================
0     ok
1     partial: some sweep variants failed, a benchmark figure is missing
2     bad input: scenario/sweep/CSV file, option value, or an unusable output
      folder (read-only, no permission, a file, locked by another run)
3     failed run: a simulation, a fit or an evaluation failed, or the disk
      filled up; ``summary.json`` says ``failed`` and why
4     completed with verdict ``limit``: a run hit a drive protection limit or a
      plant end stop (``summary.json`` status ``limit``, the first violation)
5     completed with verdict ``fault``: a drive or fieldbus fault reaction not
      caused by a limit, or drives never enabled (status ``fault``)
130   interrupted by SIGINT (Ctrl-C), SIGTERM or SIGHUP; ``summary.json`` says
      ``interrupted`` with the signal and where the run stopped
128+n the run's process was killed by signal n (137 SIGKILL: a user or the
      out-of-memory killer; 139 SIGSEGV); ``python -m cosim`` ends by the same
      signal after its supervisor wrote ``failed`` with the signal and where
      (cosim/commands/supervisor.py); an exit without a status (``_exit()``
      in an in-process FMU) is 3
====  =========================================================================
"""
from __future__ import annotations

import errno
import signal
from pathlib import Path

EXIT_OK = 0
EXIT_PARTIAL = 1
EXIT_INVALID = 2
EXIT_FAILED = 3
EXIT_LIMIT = 4
EXIT_FAULT = 5
EXIT_INTERRUPTED = 130


class CommandError(Exception):
    """A command cannot go on: ``message`` (one line naming file/option/key) and the exit ``code``."""

    def __init__(self, message: str, code: int = EXIT_INVALID) -> None:
        super().__init__(message)
        self.code = code


class InvalidInput(CommandError):
    """Bad input (file, option, key): exit code 2."""

    def __init__(self, message: str) -> None:
        super().__init__(message, EXIT_INVALID)


class RunFailed(CommandError):
    """The run itself failed (fit not converged, implausible result, simulation failure): exit code 3."""

    def __init__(self, message: str) -> None:
        super().__init__(message, EXIT_FAILED)


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM arrived; ``signal_name`` says which (raised by the CLI's signal handler)."""

    def __init__(self, signum: int) -> None:
        self.signum = int(signum)
        self.signal_name = signal.Signals(signum).name
        super().__init__(self.signal_name)


def signal_name_of(exc: BaseException) -> str:
    """``"SIGTERM"`` for an Interrupted, ``"SIGINT"`` for a plain KeyboardInterrupt."""
    return getattr(exc, "signal_name", "SIGINT")


def describe_os_error(exc: OSError, what: str = "") -> str:
    """One line for an OSError: the file(s), the system's words, and a hint for the common causes."""
    files = " -> ".join(str(f) for f in (exc.filename, exc.filename2) if f is not None)
    reason = exc.strerror or str(exc) or type(exc).__name__
    hint = {
        errno.ENOSPC: "the disk is full",
        errno.EDQUOT: "the disk quota is exceeded",
        errno.EROFS: "the file system is read-only",
        errno.EACCES: "no permission",
        errno.EPERM: "no permission",
        errno.ENOTDIR: "a path component is a file, not a folder",
        errno.EEXIST: "it exists already",
        errno.EFBIG: "the file size limit (ulimit -f) is reached",
    }.get(exc.errno or 0, "")
    head = f"{what}: " if what else ""
    text = f"{head}{files + ': ' if files else ''}{reason}"
    if hint and hint.lower() not in reason.lower():
        text += f" ({hint})"
    return text


def is_disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` (or what caused it) is ENOSPC/EDQUOT."""
    seen = 0
    while exc is not None and seen < 8:
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            return True
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return False


def describe_decode_error(exc: UnicodeDecodeError, path: str | Path | None) -> str:
    """One line for a file that is not UTF-8 text."""
    where = f"{path}: " if path is not None else ""
    return (f"{where}not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset {exc.start}); "
            f"expected a UTF-8 encoded file")
