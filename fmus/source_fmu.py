"""A user's FMI 2.0 co-simulation FMU built from C source: a folder with ``modelDescription.xml`` and ``*.c``.

``build_source_fmu(folder)`` compiles every ``*.c`` of the folder into one shared library
(the system C compiler through :mod:`native`: ``$CC``, else ``cc``/``gcc``; include
paths: the folder, its parent folder and fmpy's FMI 2.0 headers), packs it with the
``modelDescription.xml`` and the sources (``sources/``) into ``<modelIdentifier>.fmu`` in
the per-user build cache, checks it with ``fmpy.validate_fmu`` and returns its path. A
second call with unchanged files (C sources, headers of the folder and its parent, the
model description) returns the cached FMU without compiling.

The equivalent by hand (Linux, from the folder)::

    gcc -std=c99 -O2 -shared -fPIC -I. -I.. -I$(python -c "import fmpy, os; print(os.path.dirname(fmpy.__file__))")/c-code \\
        *.c -o binaries/linux64/<modelIdentifier>.so
    zip -r <modelIdentifier>.fmu modelDescription.xml binaries sources
"""
from __future__ import annotations

import hashlib
import platform
import shutil
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import native

CFLAGS: tuple[str, ...] = ("-std=c99", "-O2", "-shared", "-fPIC", "-Wall", "-Wno-unused-function")


class SourceFmuError(ValueError):
    """The folder is not an FMU source folder, or compiling, packing or validating failed."""


def _platform_dir() -> str:
    system = {"Linux": "linux", "Darwin": "darwin", "Windows": "win"}.get(platform.system(), platform.system().lower())
    return f"{system}64" if platform.architecture()[0] == "64bit" else f"{system}32"


def model_identifier(folder: Path) -> str:
    """The co-simulation ``modelIdentifier`` of the folder's ``modelDescription.xml``."""
    xml = folder / "modelDescription.xml"
    if not xml.is_file():
        raise SourceFmuError(f"{str(folder)!r}: no modelDescription.xml (an FMU source folder holds "
                             "modelDescription.xml and the C files)")
    try:
        root = ET.parse(xml).getroot()
    except ET.ParseError as exc:
        raise SourceFmuError(f"{str(xml)!r}: not well-formed XML: {exc}") from None
    if root.get("fmiVersion") != "2.0":
        raise SourceFmuError(f"{str(xml)!r}: fmiVersion = {root.get('fmiVersion')!r}, expected '2.0'")
    cs = root.find("CoSimulation")
    if cs is None or not cs.get("modelIdentifier"):
        raise SourceFmuError(f"{str(xml)!r}: no <CoSimulation modelIdentifier=...> (a co-simulation FMU is needed)")
    return str(cs.get("modelIdentifier"))


def build_source_fmu(folder: str | Path) -> Path:
    """Build (or find in the cache) the FMU of the source folder ``folder``; return the .fmu path."""
    import fmpy

    folder = Path(folder).resolve()
    if not folder.is_dir():
        raise SourceFmuError(f"{str(folder)!r}: not a folder (expected a folder with modelDescription.xml and *.c)")
    identifier = model_identifier(folder)
    c_files = sorted(folder.glob("*.c"))
    if not c_files:
        raise SourceFmuError(f"{str(folder)!r}: no C files")
    headers = sorted(folder.glob("*.h")) + sorted(folder.parent.glob("*.h"))
    key = hashlib.sha256()
    for path in [folder / "modelDescription.xml", *headers]:
        key.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    c_code = Path(fmpy.__file__).parent / "c-code"
    try:
        library = native.build(identifier, c_files, key=key.digest(), cflags=CFLAGS,
                               include_dirs=(folder, folder.parent, c_code))
    except native.NativeBuildError as exc:
        raise SourceFmuError(f"{str(folder)!r}: compiling failed: {exc}") from None
    fmu = library.parent / f"{identifier}.fmu"
    if fmu.is_file() and fmu.stat().st_mtime >= library.stat().st_mtime:
        return fmu
    work = Path(tempfile.mkdtemp(prefix=f".{identifier}-fmu-", dir=library.parent))
    try:
        tmp = work / f"{identifier}.fmu"
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
            z.write(folder / "modelDescription.xml", "modelDescription.xml")
            z.write(library, f"binaries/{_platform_dir()}/{identifier}{library.suffix}")
            for path in [*c_files, *headers]:
                z.write(path, f"sources/{path.name}")
        from fmpy.validation import validate_fmu

        problems = validate_fmu(str(tmp))
        if problems:
            raise SourceFmuError(f"{str(folder)!r}: the FMU does not validate: " + "; ".join(problems))
        tmp.replace(fmu)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return fmu
