"""Build and bind the native stepping kernel (``kernel.c``).

The kernel is built and cached by the project's native layer (:mod:`native`: the
per-user cache, one lock, atomic replacement, ``$COSIM_NATIVE``). ``load_kernel()``
returns None when it cannot be built (``COSIM_NATIVE=require`` makes that an error) and
the master then uses the pure-Python engine.
"""
from __future__ import annotations

import ctypes
from ctypes import POINTER, Structure, c_double, c_int, c_longlong, c_uint, c_void_p
from functools import lru_cache
from pathlib import Path

import native

SOURCE = Path(__file__).with_name("kernel.c")

#: Failure kinds reported by the kernel (``cosim_failure.what``).
FAIL_SET, FAIL_STEP, FAIL_GET, FAIL_NONFINITE, FAIL_ENDED = 1, 2, 3, 4, 5

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


class CRefreshSet(Structure):
    """Mirror of ``cosim_refresh_set`` in kernel.c."""

    _fields_ = [
        ("plan", POINTER(CPlan)),
        ("slaves", c_void_p),
        ("n", c_longlong),
    ]


CFLAGS = ("-O2", "-shared", "-fPIC", "-std=c99")


@lru_cache(maxsize=1)
def load_kernel() -> ctypes.CDLL | None:
    """Return the compiled kernel library (building it if needed), or None if it cannot be built."""
    lib = native.load_library(SOURCE, CFLAGS, what="co-simulation master kernel")
    if lib is None:
        return None
    lib.cosim_advance.argtypes = [POINTER(CPlan), c_longlong, c_longlong, POINTER(CFailure)]
    lib.cosim_advance.restype = c_int
    lib.cosim_refresh.argtypes = [POINTER(CRefreshSet), c_longlong, POINTER(CFailure)]
    lib.cosim_refresh.restype = c_int
    return lib


def address_of(array) -> int:
    """Address of a numpy array's data (kept alive by the caller)."""
    return int(array.ctypes.data)


__all__ = ["CFailure", "CPlan", "CRefreshSet", "CSlave", "FAIL_ENDED", "FAIL_GET", "FAIL_NONFINITE", "FAIL_SET", "FAIL_STEP",
           "load_kernel", "address_of", "c_uint"]
