"""Build small C helpers of the co-simulation layer once and load them with ctypes.

``load_library(source)`` compiles ``source`` with the system C compiler (``$CC``,
default ``cc``) into ``<repo>/build/cosim_native/`` (or ``$COSIM_BUILD_DIR/cosim_native/``,
else ``~/.cache/rx130l-cosim/cosim_native/``), names the library by a hash of the source
and flags (an edited source is rebuilt), builds atomically (parallel test workers do
not race) and returns the ``ctypes.CDLL``, or None when no compiler is available: the
caller then runs its Python path.
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
from functools import lru_cache
from pathlib import Path

CFLAGS = ("-O2", "-shared", "-fPIC", "-std=c99", "-ffp-contract=off")


def _build_dirs() -> list[Path]:
    dirs = []
    if os.environ.get("COSIM_BUILD_DIR"):
        dirs.append(Path(os.environ["COSIM_BUILD_DIR"]) / "cosim_native")
    dirs.append(Path(__file__).resolve().parents[1] / "build" / "cosim_native")
    dirs.append(Path.home() / ".cache" / "rx130l-cosim" / "cosim_native")
    return dirs


@lru_cache(maxsize=None)
def load_library(source: Path) -> ctypes.CDLL | None:
    """The compiled ``source`` (a C file), built if needed; None without a C compiler."""
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        return None
    source = Path(source)
    digest = hashlib.sha1(source.read_bytes() + compiler.encode() + " ".join(CFLAGS).encode()).hexdigest()[:12]
    for directory in _build_dirs():
        target = directory / f"lib{source.stem}-{digest}.so"
        try:
            if not target.exists():
                directory.mkdir(parents=True, exist_ok=True)
                fd, tmp = tempfile.mkstemp(suffix=".so", dir=directory)
                os.close(fd)
                try:
                    subprocess.run([compiler, *CFLAGS, "-o", tmp, str(source), "-lm"], check=True,
                                   capture_output=True, text=True, timeout=300)
                    os.replace(tmp, target)
                finally:
                    if os.path.exists(tmp):
                        os.unlink(tmp)
            return ctypes.CDLL(str(target))
        except (OSError, subprocess.SubprocessError):
            continue
    return None


__all__ = ["load_library"]
