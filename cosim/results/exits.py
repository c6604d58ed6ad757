"""Exit codes of ``python -m cosim`` and the errors that carry them.

Every command returns one of the codes of :data:`EXIT_CODES`; ``cosim.cli.main`` turns any
exception that escapes a command into a one-line ``error: ...`` message and the matching code
(the traceback only with ``--debug``). :data:`EXIT_CODES` is the one description of the codes:
the command-line help and the docs page docs/reference/verdicts.md are generated from it.
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

#: (code, short name, when, what ``summary.json`` says): the documentation of every exit code
#: (the command-line help's epilog and docs/reference/verdicts.md are generated from it).
EXIT_CODES: tuple[tuple[str, str, str, str], ...] = (
    (str(EXIT_OK), "ok", "the command did what it was asked; every run it made has verdict `ok`",
     "`status: \"ok\"`"),
    (str(EXIT_PARTIAL), "partly failed",
     "some variants of a `sweep` failed (the others are written), or a figure of `bench` is missing",
     "`sweep.json` per variant"),
    (str(EXIT_INVALID), "bad input",
     "a scenario, sweep or CSV file, a key or an option value is wrong, or the results folder is unusable "
     "(read-only, no permission, a file, locked by another run); nothing ran",
     "not written"),
    (str(EXIT_FAILED), "failed run",
     "a run failed (an FMU failed or crashed, the controller raised, the disk filled up), a fit of `calibrate` "
     "or `identify` did not converge or is implausible, or the run's process exited without writing its status",
     "`status: \"failed\"`, `reason`, `stopped_at_s`"),
    (str(EXIT_LIMIT), "limit",
     "the runs completed, and the most severe verdict is `limit`: a drive protection limit or a plant end stop "
     "was hit",
     "`status: \"limit\"`, `reason`, `first_violation`"),
    (str(EXIT_FAULT), "fault",
     "the runs completed, and the most severe verdict is `fault`: a drive or fieldbus fault reaction no limit "
     "caused, or the drives never enabled",
     "`status: \"fault\"`, `reason`, `first_violation`"),
    (str(EXIT_INTERRUPTED), "interrupted",
     "SIGINT (Ctrl-C), SIGTERM or SIGHUP: the command stopped, flushed what it had and wrote its final status",
     "`status: \"interrupted\"`, `signal`, `stopped_at_s`"),
    ("128 + n", "killed",
     "the run's process was killed by signal n (137: SIGKILL, by a user or the out-of-memory killer; 139: a "
     "segmentation fault in native code); `python -m cosim` ends by the same signal",
     "`status: \"failed\"`, `signal`, written by the crash guard or the supervisor"),
)


def exit_codes_line() -> str:
    """``0 ok, 1 partly failed, ...``: every exit code with its short name, on one line."""
    return ", ".join(f"{code} {name}" for code, name, _, _ in EXIT_CODES)


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
