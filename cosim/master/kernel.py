"""Build and bind the native stepping kernel (``kernel.c``).

The kernel is compiled once with the system C compiler (``$CC``, default ``cc``) into
``<repo>/build/cosim_kernel/`` (or ``$COSIM_BUILD_DIR/cosim_kernel/``; falls back to
``~/.cache/rx130l-cosim/`` when the repository is read-only). The file name carries a
hash of the source so an edited kernel is rebuilt; the build is atomic, so parallel
test workers do not race. ``load_kernel()`` returns None when no compiler is
available and the master then uses the pure-Python engine.
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
from ctypes import POINTER, Structure, c_double, c_int, c_longlong, c_uint, c_void_p
from functools import lru_cache
from pathlib import Path

SOURCE = Path(__file__).with_name("kernel.c")

#: Failure kinds reported by the kernel (``cosim_failure.what``).
FAIL_SET, FAIL_STEP, FAIL_GET, FAIL_NONFINITE, FAIL_ENDED = 1, 2, 3, 4, 5
#: The FMI 3.0 adapter (fmi3_adapter.c), built the same way into its own library.
ADAPTER_SOURCE = Path(__file__).with_name("fmi3_adapter.c")

LongArray3 = c_longlong * 3
PtrArray3 = c_void_p * 3


class CSlave(Structure):
    """Mirror of ``cosim_slave`` in kernel.c (one FMU instance of a plan)."""

    _fields_ = [
        ("component", c_void_p),
        ("do_step", c_void_p),
        ("set_real", c_void_p),
        ("set_integer", c_void_p),
        ("set_boolean", c_void_p),
        ("get_real", c_void_p),
        ("get_integer", c_void_p),
        ("get_boolean", c_void_p),
        ("step_ticks", c_longlong),
        ("n_in", LongArray3),
        ("vr_in", PtrArray3),
        ("in_offset", LongArray3),
        ("n_out", LongArray3),
        ("vr_out", PtrArray3),
        ("out_offset", LongArray3),
        ("n_check", c_longlong),
        ("n_gather", LongArray3),
        ("gather_dst", PtrArray3),
        ("gather_src", PtrArray3),
    ]


class CPlan(Structure):
    """Mirror of ``cosim_plan`` in kernel.c."""

    _fields_ = [
        ("n_slaves", c_longlong),
        ("slaves", POINTER(CSlave)),
        ("real_bus", c_void_p),
        ("int_bus", c_void_p),
        ("bool_bus", c_void_p),
        ("start_time", c_double),
        ("base_step", c_double),
        ("gauss_seidel", c_int),
        ("step_seconds", c_void_p),
        ("stop_at", c_void_p),
    ]


class CFailure(Structure):
    """Mirror of ``cosim_failure`` in kernel.c."""

    _fields_ = [
        ("slave", c_longlong),
        ("tick", c_longlong),
        ("what", c_int),
        ("status", c_int),
        ("variable", c_longlong),
    ]


def _build_dirs() -> list[Path]:
    dirs = []
    if os.environ.get("COSIM_BUILD_DIR"):
        dirs.append(Path(os.environ["COSIM_BUILD_DIR"]) / "cosim_kernel")
    dirs.append(Path(__file__).resolve().parents[2] / "build" / "cosim_kernel")
    dirs.append(Path.home() / ".cache" / "rx130l-cosim" / "cosim_kernel")
    return dirs


def _compile(target: Path, source: Path = SOURCE) -> None:
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        raise OSError("no C compiler found (set CC)")
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=target.parent)
    os.close(fd)
    try:
        subprocess.run([compiler, "-O2", "-shared", "-fPIC", "-std=c99", "-o", tmp, str(source), "-lm"],
                       check=True, capture_output=True, text=True)
        os.replace(tmp, target)
    except subprocess.CalledProcessError as exc:
        raise OSError(f"compiling {source} failed:\n{exc.stderr}") from exc
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _load(source: Path, stem: str) -> ctypes.CDLL | None:
    digest = hashlib.sha1(source.read_bytes()).hexdigest()[:12]
    name = f"{stem}-{digest}.so"
    for directory in _build_dirs():
        target = directory / name
        try:
            if not target.exists():
                _compile(target, source)
            return ctypes.CDLL(str(target))
        except OSError:
            continue
    return None


@lru_cache(maxsize=1)
def load_kernel() -> ctypes.CDLL | None:
    """Return the compiled kernel library (building it if needed), or None if it cannot be built."""
    lib = _load(SOURCE, "libcosimkernel")
    if lib is not None:
        lib.cosim_advance.argtypes = [POINTER(CPlan), c_longlong, c_longlong, POINTER(CFailure)]
        lib.cosim_advance.restype = c_int
    return lib


@lru_cache(maxsize=1)
def load_fmi3_adapter() -> ctypes.CDLL | None:
    """Return the compiled FMI 3.0 adapter library (fmi3_adapter.c), or None if it cannot be built."""
    return _load(ADAPTER_SOURCE, "libcosimfmi3")


def address_of(array) -> int:
    """Address of a numpy array's data (kept alive by the caller)."""
    return int(array.ctypes.data)


__all__ = ["CFailure", "CPlan", "CSlave", "FAIL_ENDED", "FAIL_GET", "FAIL_NONFINITE", "FAIL_SET", "FAIL_STEP",
           "load_fmi3_adapter", "load_kernel", "address_of", "c_uint"]
