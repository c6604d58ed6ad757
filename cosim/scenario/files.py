"""Scenario files on disk: reading a TOML file with errors that name it, and the installed copy of the
project's ``scenarios/``.

The floor under both the loader (:mod:`cosim.scenario.loader`) and the ``extends`` resolution
(:mod:`cosim.scenario.inherit`), which read files and find installed scenarios without calling each other.
"""
from __future__ import annotations

import site
import sys
import tomllib
from pathlib import Path
from typing import Any

from cosim.scenario.errors import ScenarioError


def read_toml_file(path: Path, kind: str) -> dict[str, Any]:
    """Parse the TOML file ``path``; ScenarioError naming the file if it is missing or not valid TOML.

    ``kind`` names what the file should be in the error ("scenario" -> "an existing scenario .toml file").
    """
    if not path.is_file():
        raise ScenarioError(path, "", f"an existing {kind} .toml file", problem="file not found")
    try:
        with open(path, "rb") as f:
            raw = f.read()
    except OSError as exc:
        raise ScenarioError(path, "", f"a readable {kind} .toml file", problem=exc.strerror or str(exc)) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(path, "", f"a UTF-8 encoded {kind} .toml file",
                            problem=f"not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(path, "", "valid TOML", problem=str(exc)) from None


PACKAGED_SCENARIOS = Path("share") / "rx130l-cosim" / "scenarios"
"""Where an installed package (``pip install .`` or the wheel) puts the project's
``scenarios/*.toml``, below the installation prefix (pyproject ``data-files``)."""


def packaged_scenarios_dir() -> Path | None:
    """The installed copy of ``scenarios/`` (venv or system prefix, then the user base), or None."""
    for prefix in (sys.prefix, site.getuserbase(), sys.base_prefix):
        folder = Path(prefix) / PACKAGED_SCENARIOS
        if folder.is_dir():
            return folder
    return None


__all__ = ["PACKAGED_SCENARIOS", "packaged_scenarios_dir", "read_toml_file"]
