"""The compiled codec of the fieldbus nodes (``codec.c``): build on first use, load, or None.

``fieldbus.nodes`` runs its per-node and per-frame loops (quantise and pack the PReqs and
PRes payloads, apply the due set-points, digest received PDOs, scale telegram integers
to SI) through this CPython extension when it is available; each function changes
nothing and returns a status when it meets anything unusual, and the nodes then run
their Python code, which stays the reference (identical results, tested in
``tests/fieldbus/test_fast_paths.py``). The fieldbus cycle of six nodes costs
254 000 instructions in Python and 100 000 with the codec (callgrind).

The extension is built against this interpreter's headers and cached by the project's
native layer (:mod:`native`: per-user cache, lock, atomic replacement; ``COSIM_NATIVE=require``
turns a failed build into an error, ``auto`` runs the Python path and says so once).
``FIELDBUS_CODEC=python`` in the environment disables it.
"""
from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path
from types import ModuleType

import native

SOURCE = Path(__file__).with_name("codec.c")
MODULE_NAME = "fieldbus_codec"
CFLAGS = ("-O2", "-shared", "-fPIC", "-std=c99", "-ffp-contract=off", "-fno-strict-aliasing")


def _register_message_types(module: ModuleType) -> None:
    """Let the codec access python-can messages (and the nodes' FastMessage) by slot offset."""
    import can

    from fieldbus.telegrams import FastMessage

    module.register_message_types(can.Message, FastMessage)


def _build_and_load() -> ModuleType:
    library = native.build(MODULE_NAME, [SOURCE], cflags=CFLAGS, python_extension=True)
    module = native.load_extension(MODULE_NAME, library)
    _register_message_types(module)
    return module


@lru_cache(maxsize=1)
def load_codec() -> ModuleType | None:
    """The compiled codec module (built if needed), or None (``FIELDBUS_CODEC=python``,
    ``COSIM_NATIVE=off``, or it cannot be built and ``COSIM_NATIVE`` is not ``require``)."""
    if os.environ.get("FIELDBUS_CODEC", "").lower() == "python":
        return None
    return native.optional("fieldbus codec", _build_and_load)


__all__ = ["load_codec", "SOURCE"]
