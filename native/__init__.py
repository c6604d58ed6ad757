"""One way to build and load the project's C code (ground floor: imports nothing of ours).

Every compiled helper of the testbed (the master's stepping kernel, the fieldbus codec,
the controller's cycle kernel, the laser tracker's kernel, the PtP node functions) and
the FMU build find the compiler, build, cache, load and report failures here:

* **compiler**: ``$CC`` if set, else ``cc``, else ``gcc`` on the PATH (:func:`compiler`);
* **cache key**: SHA-256 over the artefact's name, its C sources and the headers they
  include from their own folder (or the caller's key for generated code), the compiler's
  path, size and modification time, the flags, the include directories and the Python
  version and ABI (:func:`build`);
* **cache directory**: ``$COSIM_CACHE_DIR``, else ``$XDG_CACHE_HOME/rx130l-cosim/native``,
  else ``~/.cache/rx130l-cosim/native`` — per user, created ``0700``, refused when it is not
  owned by the user or writable by others; when no such directory can be created, a
  fresh private ``mkdtemp`` directory for this process (never a predictable shared
  ``/tmp`` path). Never the installed package's folder (site-packages stays read-only);
* **lock and atomic replacement**: one ``flock`` per artefact name serialises builders
  (pytest-xdist workers, parallel runs); each build happens in a private temporary
  folder inside the cache and is renamed into place, so nobody loads a half-written file;
* **loading**: :func:`load_ctypes` and :func:`load_extension` check that the library and
  its folder belong to the user and are not writable by others before loading;
* **failures**: every problem is a :class:`NativeBuildError` with the command and the
  compiler's output. What happens then is decided by ``$COSIM_NATIVE``:

  - ``auto`` (default): the caller's Python path runs (same results, slower) and
    :func:`fallback` says so once per component on stderr;
  - ``require``: the error propagates (``.ci/run`` sets it, so a missing compiler or a
    broken C file fails the suite instead of silently testing only the Python paths);
  - ``off``: nothing is compiled, the Python paths run silently.
"""
from __future__ import annotations

import ctypes
import fcntl
import hashlib
import importlib.machinery
import importlib.util
import os
import platform
import shutil
import stat
import subprocess
import sys
import sysconfig
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import TypeVar

ENV_MODE = "COSIM_NATIVE"
ENV_CACHE = "COSIM_CACHE_DIR"
MODES = ("auto", "require", "off")
DEFAULT_CFLAGS: tuple[str, ...] = ("-O2", "-shared", "-fPIC", "-std=c99", "-ffp-contract=off")
BUILD_TIMEOUT_S = 900.0
"""Longest compile accepted (the PtP node Hessian at -O0 takes about 10 s)."""

T = TypeVar("T")
_reported: set[str] = set()
_private_tmp: Path | None = None


class NativeBuildError(RuntimeError):
    """Finding the compiler, compiling or loading compiled code failed (the message holds
    the command and the compiler's output)."""


class NotBuiltYet(NativeBuildError):
    """``build(..., cached_only=True)``: the library is not in the cache yet."""


def mode() -> str:
    """``$COSIM_NATIVE``: ``auto`` (default), ``require`` or ``off``."""
    value = os.environ.get(ENV_MODE, "").strip().lower() or "auto"
    if value not in MODES:
        raise NativeBuildError(f"{ENV_MODE}={os.environ[ENV_MODE]!r}: expected one of {', '.join(MODES)}")
    return value


def compiler() -> str | None:
    """Absolute path of the C compiler (``$CC``, else ``cc``, else ``gcc``), or None."""
    cc = os.environ.get("CC", "").strip()
    if cc:
        return shutil.which(cc) or (cc if os.path.isfile(cc) and os.access(cc, os.X_OK) else None)
    return shutil.which("cc") or shutil.which("gcc")


def require_compiler() -> str:
    """:func:`compiler`, or a :class:`NativeBuildError` saying how to get one."""
    cc = compiler()
    if cc is None:
        wanted = os.environ.get("CC") or "cc or gcc"
        raise NativeBuildError(f"no C compiler found ({wanted} not on the PATH): install gcc or set CC")
    return cc


def check_private(path: Path) -> None:
    """Refuse a path not owned by this user or writable by group or others."""
    info = path.stat()
    if info.st_uid != os.getuid():
        raise NativeBuildError(f"{path} belongs to uid {info.st_uid}, not to this user ({os.getuid()}): refused")
    if info.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise NativeBuildError(f"{path} is writable by group or others (mode {stat.filemode(info.st_mode)}): refused")


def cache_root() -> Path:
    """The per-user cache directory of compiled code (created ``0700`` if missing)."""
    global _private_tmp
    configured = os.environ.get(ENV_CACHE)
    if configured:
        root = Path(configured).expanduser()
    else:
        base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        root = Path(base) / "rx130l-cosim" / "native"
    try:
        root.mkdir(parents=True, exist_ok=True, mode=0o700)
        if not os.access(root, os.W_OK):
            raise PermissionError(f"{root} is not writable")
    except OSError as exc:
        if configured:
            raise NativeBuildError(f"{ENV_CACHE}={configured}: cannot use it as the cache of compiled code: {exc}") \
                from None
        if _private_tmp is None:  # unpredictable, private to this user and process
            _private_tmp = Path(tempfile.mkdtemp(prefix="rx130l-cosim-native-"))
        root = _private_tmp
    check_private(root)
    return root


def _compiler_identity(cc: str) -> bytes:
    info = os.stat(cc)
    return f"{os.path.realpath(cc)}:{info.st_size}:{int(info.st_mtime)}".encode()


def run_compiler(command: Sequence[str], what: str, timeout: float = BUILD_TIMEOUT_S) -> None:
    """Run one compiler command; a :class:`NativeBuildError` naming ``what`` if it fails."""
    try:
        result = subprocess.run(list(command), capture_output=True, text=True, timeout=timeout, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise NativeBuildError(f"{what}: could not run the C compiler {command[0]!r}: {exc}") from None
    if result.returncode != 0:
        raise NativeBuildError(f"{what}: compiling failed (exit {result.returncode}): {' '.join(command)}\n"
                               f"{result.stderr[-4000:]}")


def build(name: str, sources: Sequence[Path] = (), *, headers: Sequence[Path] = (),
          generate: Callable[[Path], Sequence[Path]] | None = None, key: bytes = b"",
          cflags: Sequence[str] = DEFAULT_CFLAGS, include_dirs: Sequence[Path | str] = (),
          python_extension: bool = False, cached_only: bool = False) -> Path:
    """Compile ``sources`` (C files) and the files ``generate(folder)`` writes into a shared
    library named ``name`` in the cache, once per cache key; return the library's path.

    ``headers``: files the sources ``#include "..."`` from their own folder: copied next to
    them for the compiler and hashed into the cache key like the sources (an edited header
    rebuilds), not compiled on their own.
    ``generate`` is called only when the library is not cached yet: code generators pass
    their own identity as ``key`` (e.g. a hash of the model and the generator's version)
    so a cached library is found without generating anything. Files ``generate`` writes
    that are not returned (e.g. sparsity patterns) are kept next to the library.
    ``python_extension``: build a CPython extension module against this interpreter's
    headers (the file gets the interpreter's extension suffix). ``cached_only``: return the
    library only when it is in the cache already, else raise :class:`NotBuiltYet` without
    compiling (for a part so long to compile that a run should not wait for it).
    """
    cc = require_compiler()
    includes = [str(p) for p in include_dirs]
    if python_extension:
        python_include = sysconfig.get_paths().get("include", "")
        if not (Path(python_include) / "Python.h").is_file():
            raise NativeBuildError(f"{name}: Python.h not found in {python_include!r} (install the Python "
                                   f"development headers, e.g. python3-dev)")
        includes.append(python_include)
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0] if python_extension else ".so"
    digest = hashlib.sha256()
    for part in (name.encode(), key, _compiler_identity(cc), " ".join(cflags).encode(), "\0".join(includes).encode(),
                 sys.version.encode(), suffix.encode(), platform.machine().encode()):
        digest.update(part + b"\0")
    for source in (*sources, *headers):
        digest.update(Path(source).name.encode() + b"\0" + Path(source).read_bytes() + b"\0")
    root = cache_root()
    target = root / f"{name}-{digest.hexdigest()[:16]}"
    library = target / f"{name}{suffix}"
    if library.is_file():
        return library
    if cached_only:
        raise NotBuiltYet(f"{name} is not built yet (python -m cosim build builds it)")
    with open(root / f".{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if library.is_file():
            return library
        work = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=root))
        try:
            c_files = []
            for source in sources:
                shutil.copy2(source, work / Path(source).name)
                c_files.append(work / Path(source).name)
            for header in headers:
                shutil.copy2(header, work / Path(header).name)
            if generate is not None:
                c_files += [Path(p) for p in generate(work)]
            command = [cc, *cflags, *(f"-I{p}" for p in includes), *map(str, c_files),
                       "-o", str(work / library.name), "-lm"]
            run_compiler(command, f"building {name}")
            if target.exists():  # a stale partial folder (the lock makes this rare): replace it
                shutil.rmtree(target)
            os.rename(work, target)
        finally:
            if work.exists():
                shutil.rmtree(work, ignore_errors=True)
    return library


def load_ctypes(library: Path) -> ctypes.CDLL:
    """``ctypes.CDLL`` of a library built by :func:`build` (owner and mode checked)."""
    library = Path(library)
    check_private(library.parent)
    check_private(library)
    try:
        return ctypes.CDLL(str(library))
    except OSError as exc:
        raise NativeBuildError(f"loading {library} failed: {exc}") from None


def load_extension(module_name: str, library: Path) -> ModuleType:
    """Import the CPython extension ``library`` (built by :func:`build`) as ``module_name``."""
    library = Path(library)
    check_private(library.parent)
    check_private(library)
    try:
        loader = importlib.machinery.ExtensionFileLoader(module_name, str(library))
        spec = importlib.util.spec_from_file_location(module_name, str(library), loader=loader)
        module = importlib.util.module_from_spec(spec)
        loader.exec_module(module)
    except ImportError as exc:
        raise NativeBuildError(f"loading {library} failed: {exc}") from None
    return module


PYTHON_PATH = "the Python path runs (slower, same results)"


def fallback(what: str, error: BaseException, instead: str = PYTHON_PATH) -> None:
    """Decide what a failed build of ``what`` means: raise under ``COSIM_NATIVE=require``,
    otherwise say once (per component and process) what runs ``instead`` (default: the
    Python path)."""
    if mode() == "require":
        if isinstance(error, NativeBuildError):
            raise error
        raise NativeBuildError(f"{what}: {error}") from error
    if what not in _reported:
        _reported.add(what)
        reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        print(f"note: {what}: compiled code unavailable ({reason}); {instead}; "
              f"{ENV_MODE}=require makes this an error", file=sys.stderr)


def optional(what: str, make: Callable[[], T], instead: str = PYTHON_PATH) -> T | None:
    """``make()`` (a build and load), or None when compiled code is off or cannot be built
    (see :func:`fallback`)."""
    if mode() == "off":
        return None
    try:
        return make()
    except (NativeBuildError, OSError) as exc:
        fallback(what, exc, instead)
        return None


def load_library(source: Path, cflags: Sequence[str] = DEFAULT_CFLAGS, what: str | None = None,
                 headers: Sequence[Path] = ()) -> ctypes.CDLL | None:
    """The C file ``source`` (including ``headers``, see :func:`build`) built and loaded with
    ctypes, or None (see :func:`optional`)."""
    source = Path(source)
    return optional(what or f"{source.name}",
                    lambda: load_ctypes(build(source.stem, [source], headers=headers, cflags=cflags)))


__all__ = ["BUILD_TIMEOUT_S", "DEFAULT_CFLAGS", "ENV_CACHE", "ENV_MODE", "MODES", "NativeBuildError", "NotBuiltYet", "build",
           "cache_root", "check_private", "compiler", "fallback", "load_ctypes", "load_extension", "load_library", "mode", "optional",
           "require_compiler", "run_compiler"]
