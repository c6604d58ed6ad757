"""The results folder of one run: checked usable before anything runs, and locked while it runs.

``open_results_folder(path)`` creates the folder (with its parents), checks that files
can be written in it and takes an exclusive ``flock`` on ``<folder>/.cosim.lock``, so a
second run into the same folder is refused (the lock is released when the run ends, also
when the process is killed: the kernel drops it with the file descriptor). Any problem is
an ``OutputFolderError`` (a ValueError) naming the folder, what is wrong and what to do.
"""
from __future__ import annotations

import errno
import fcntl
import os
from pathlib import Path

LOCK_NAME = ".cosim.lock"


class OutputFolderError(ValueError):
    """The results folder cannot be used (message names it and the cause)."""


class ResultsLock:
    """An exclusive lock on a results folder (context manager; ``release()`` is idempotent)."""

    def __init__(self, folder: Path, fd: int) -> None:
        self.folder = folder
        self._fd: int | None = fd

    def release(self) -> None:
        if self._fd is not None:
            try:
                fcntl.flock(self._fd, fcntl.LOCK_UN)
            finally:
                os.close(self._fd)
                self._fd = None

    def __enter__(self) -> "ResultsLock":
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def _explain(exc: OSError) -> str:
    return {
        errno.EROFS: "the file system is read-only",
        errno.EACCES: "no permission to write there",
        errno.EPERM: "no permission to write there",
        errno.ENOTDIR: "a part of the path is a file, not a folder",
        errno.EEXIST: "a file of that name exists",
        errno.ENOSPC: "the disk is full",
        errno.EDQUOT: "the disk quota is exceeded",
    }.get(exc.errno or 0, exc.strerror or str(exc))


def open_results_folder(path: str | Path, what: str = "--out") -> ResultsLock:
    """Create, check and lock the results folder ``path``; OutputFolderError when it is unusable.

    ``what`` names where the folder came from in the message (``--out``, ``[output] dir``).
    """
    folder = Path(path)
    lead = f"{what} {str(folder)!r}"
    if folder.exists() and not folder.is_dir():
        raise OutputFolderError(f"{lead}: is a file; expected a folder (or a path that does not exist yet)")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputFolderError(f"{lead}: a file of that name exists; expected a folder") from None
    except OSError as exc:
        raise OutputFolderError(f"{lead}: cannot create the folder ({_explain(exc)}); expected a writable "
                                f"location") from None
    lock_path = folder / LOCK_NAME
    try:
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise OutputFolderError(f"{lead}: cannot write in the folder ({_explain(exc)}); expected a writable "
                                f"folder") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        holder = ""
        try:
            holder = os.pread(fd, 64, 0).decode("ascii", "replace").strip()
        except OSError:
            pass
        os.close(fd)
        if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            raise OutputFolderError(f"{lead}: another run is writing into this folder"
                                    f"{f' (process {holder})' if holder else ''}; expected a folder no other run "
                                    f"uses (give another --out, or wait for that run to end)") from None
        raise OutputFolderError(f"{lead}: cannot lock the folder ({_explain(exc)})") from None
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
    except OSError as exc:
        os.close(fd)
        raise OutputFolderError(f"{lead}: cannot write in the folder ({_explain(exc)}); expected a writable "
                                f"folder with free space") from None
    return ResultsLock(folder, fd)


__all__ = ["LOCK_NAME", "OutputFolderError", "ResultsLock", "open_results_folder"]
