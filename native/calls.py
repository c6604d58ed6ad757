"""Direct calls of compiled functions by address (``calls.c``), for the loop's per-cycle calls.

A ctypes foreign call costs about 5 000 instructions (argument conversion through
``argtypes``, the libffi frame); :func:`load_calls` gives a CPython extension whose functions
call a function at its address with Python integers for its arguments (one function per C
signature: ``int_p_ll_p``, ``int_p_p_p``, ``int_p_ll_ll_p``), releasing the GIL as ctypes
does. The callers keep their ctypes call as the path when it cannot be built (the same
function with the same arguments either way). :func:`address_of` gives a ctypes function's
address.
"""
from __future__ import annotations

import ctypes
from functools import lru_cache
from pathlib import Path
from types import ModuleType

import native

SOURCE = Path(__file__).with_name("calls.c")
MODULE_NAME = "native_calls"
CFLAGS = ("-O2", "-shared", "-fPIC", "-std=c99")


@lru_cache(maxsize=1)
def load_calls() -> ModuleType | None:
    """The compiled module (built if needed), or None (``COSIM_NATIVE=off``, or it cannot be
    built and ``COSIM_NATIVE`` is not ``require``: the ctypes calls run)."""
    return native.optional("direct calls", lambda: native.load_extension(
        MODULE_NAME, native.build(MODULE_NAME, [SOURCE], cflags=CFLAGS, python_extension=True)),
        instead="ctypes calls run (slower, same results)")


def address_of(function: ctypes._CFuncPtr) -> int:
    """The address of a ctypes function (of a loaded library)."""
    return ctypes.cast(function, ctypes.c_void_p).value


__all__ = ["address_of", "load_calls", "SOURCE"]
