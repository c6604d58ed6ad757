"""Generate, compile and pack the project's co-simulation FMUs (FMI 2.0, and FMI 3.0 on request).

``ensure_fmus()`` is what the rest of the testbed calls: it returns the paths of
``rx130l_plant.fmu`` and ``servo_drive.fmu`` in ``build/fmus/`` and rebuilds an FMU
only when one of its inputs changed (a SHA-256 stamp over every source, generator and
robot-description file it depends on). Each FMU holds ``modelDescription.xml``,
``sources/`` (all C sources, the generated dynamics, the FMI 2.0 headers: enough to
rebuild it on another platform) and ``binaries/linux64/<id>.so`` built with the system
C compiler (``$CC``, default ``gcc``).

Concurrent callers (e.g. pytest-xdist workers) are serialised by a lock file, and an
FMU is written to a temporary name and renamed, so nobody sees a half-written file.
"""
from __future__ import annotations

import fcntl
import hashlib
import os
import platform
import shutil
import sys
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import fmpy

import native
from fmus.fmi2_spec import FmuSpec

FMUS_DIR: Path = Path(__file__).resolve().parent
REPO_ROOT: Path = FMUS_DIR.parent
DEFAULT_OUT_DIR: Path = REPO_ROOT / "build" / "fmus"
FMI2_HEADERS: tuple[str, ...] = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
FMI3_HEADERS: tuple[str, ...] = ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")
#: FMI versions an FMU is built for: 2 (``build/fmus/<id>.fmu``, what the jobs run) and 3
#: (``build/fmus/fmi3/<id>.fmu``, same model source through fmus/common/fmi3_wrapper.c).
FMI_VERSIONS: tuple[int, ...] = (2, 3)
CFLAGS: tuple[str, ...] = ("-std=c99", "-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-Wall", "-Wextra",
                           "-Wno-unused-parameter", "-DCASADI_SYMBOL_EXPORT=")
# files whose change must trigger a rebuild of every FMU besides each FMU's own inputs
_COMMON_INPUTS: tuple[tuple[Path, str], ...] = (
    (FMUS_DIR, "build.py"), (FMUS_DIR, "fmi2_spec.py"), (FMUS_DIR, "common/*"),
    (REPO_ROOT / "robot", "description.py"), (REPO_ROOT / "robot", "parameters.py"),
    (REPO_ROOT / "robot", "dynamics.py"), (REPO_ROOT / "robot", "symbolic.py"),
    (REPO_ROOT / "robot", "*.urdf"), (REPO_ROOT / "robot", "*.toml"),
)


class FmuBuildError(native.NativeBuildError):
    """Generating, compiling or packing an FMU failed (the message has the compiler output)."""


@dataclass
class FmuRecipe:
    """How to make one FMU: its variable spec, C files, generated C files and the Python
    modules (in ``source_dir``) that generate them."""

    model_identifier: str
    source_dir: Path
    make_spec: Callable[[], FmuSpec]
    generator_modules: tuple[str, ...]
    make_generated: Callable[[], dict[str, str]] = field(default=lambda: {})

    def input_files(self) -> list[Path]:
        files = sorted(p for p in self.source_dir.glob("*") if p.is_file() and p.suffix in (".c", ".h", ".toml"))
        files += [self.source_dir / name for name in self.generator_modules]
        for base, pattern in _COMMON_INPUTS:
            files += sorted(p for p in base.glob(pattern) if p.is_file())
        return files


def _servo_drive_recipe() -> FmuRecipe:
    from fmus.servo_drive.spec import servo_drive_spec

    return FmuRecipe("servo_drive", FMUS_DIR / "servo_drive", servo_drive_spec, ("spec.py", "params.py"))


def _plant_recipe() -> FmuRecipe:
    from fmus.rx130l_plant.codegen import generated_dynamics_sources
    from fmus.rx130l_plant.spec import plant_spec

    return FmuRecipe("rx130l_plant", FMUS_DIR / "rx130l_plant", plant_spec, ("spec.py", "codegen.py"),
                     generated_dynamics_sources)


RECIPES: dict[str, Callable[[], FmuRecipe]] = {
    "rx130l_plant": _plant_recipe,
    "servo_drive": _servo_drive_recipe,
}


def _compiler() -> str:
    """The C compiler of the native layer (:func:`native.compiler`)."""
    cc = native.compiler()
    if cc is None:
        raise FmuBuildError("C compiler not found: install gcc or set $CC")
    return cc


def default_out_dir() -> Path:
    """``build/fmus`` in a source checkout, else ``fmus/`` in the per-user cache of the
    native layer (an installed package never writes into its own folder)."""
    if (REPO_ROOT / "pyproject.toml").is_file() and os.access(REPO_ROOT, os.W_OK):
        return DEFAULT_OUT_DIR
    return native.cache_root() / "fmus"


def _platform_dir() -> str:
    return fmpy.platform  # "linux64" on x86-64 Linux


def input_hash(recipe: FmuRecipe, fmi: int = 2) -> str:
    """SHA-256 over every input of ``recipe`` plus the FMI version, compiler, flags and platform."""
    digest = hashlib.sha256(f"fmi{fmi}".encode() if fmi != 2 else b"")
    for path in recipe.input_files():
        digest.update(str(path.relative_to(REPO_ROOT)).encode())
        digest.update(path.read_bytes())
    c_code = Path(fmpy.__file__).parent / "c-code"
    for name in FMI2_HEADERS + (FMI3_HEADERS if fmi == 3 else ()):
        digest.update((c_code / name).read_bytes())
    if fmi == 3:
        digest.update((FMUS_DIR / "fmi3_spec.py").read_bytes())
    digest.update(" ".join((_compiler(), *CFLAGS, _platform_dir(), sys.platform, platform.machine())).encode())
    return digest.hexdigest()


def _stage_sources(recipe: FmuRecipe, spec: FmuSpec, sources: Path, fmi: int = 2) -> None:
    sources.mkdir(parents=True)
    c_code = Path(fmpy.__file__).parent / "c-code"
    for name in FMI2_HEADERS + (FMI3_HEADERS if fmi == 3 else ()):
        shutil.copy2(c_code / name, sources / name)
    if fmi == 3:
        from fmus.fmi3_spec import fmi3_header

        (sources / "fmi3_variables.h").write_text(fmi3_header(spec))
    for path in sorted((FMUS_DIR / "common").glob("*.[ch]")):
        shutil.copy2(path, sources / path.name)
    for path in sorted(recipe.source_dir.glob("*.[ch]")):
        shutil.copy2(path, sources / path.name)
    (sources / "model_variables.h").write_text(spec.c_header())
    for name, text in recipe.make_generated().items():
        (sources / name).write_text(text)


def compile_binary(sources: Path, c_files: tuple[str, ...], output: Path, defines: tuple[str, ...] = ()) -> None:
    """Compile ``c_files`` (names inside ``sources``) into the shared library ``output``."""
    output.parent.mkdir(parents=True, exist_ok=True)
    command = [_compiler(), *CFLAGS, *defines, f"-I{sources}", *(str(sources / f) for f in c_files), "-o", str(output), "-lm"]
    try:
        native.run_compiler(command, f"compiling {output.name}")
    except native.NativeBuildError as exc:
        raise FmuBuildError(str(exc)) from None


def build_fmu(model_identifier: str, out_dir: str | Path | None = None, force: bool = False,
              fmi: int = 2) -> tuple[Path, bool]:
    """Build one FMU for FMI version ``fmi`` (2 or 3) if its inputs changed; return ``(path, rebuilt)``.

    FMI 3.0 builds go to ``<out>/fmi3/<id>.fmu``: the same model sources compiled with
    ``-DFMU_FMI3`` against fmus/common/fmi3_wrapper.c, the modelDescription rendered by
    fmus/fmi3_spec.py, the binary in ``binaries/<platform tuple>/`` (x86_64-linux).
    """
    if model_identifier not in RECIPES:
        raise ValueError(f"model_identifier = {model_identifier!r}, expected one of {sorted(RECIPES)}")
    if fmi not in FMI_VERSIONS:
        raise ValueError(f"fmi = {fmi!r}, expected one of {FMI_VERSIONS}")
    out = Path(out_dir or default_out_dir())
    if fmi == 3:
        out = out / "fmi3"
    out.mkdir(parents=True, exist_ok=True)
    recipe = RECIPES[model_identifier]()
    target = out / f"{model_identifier}.fmu"
    stamp = out / f"{model_identifier}.stamp"
    with open(out / ".build.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        wanted = input_hash(recipe, fmi)
        if not force and target.is_file() and stamp.is_file() and stamp.read_text().strip() == wanted:
            return target, False
        spec = recipe.make_spec()
        with tempfile.TemporaryDirectory(prefix=f"{model_identifier}-", dir=out) as tmp:
            root = Path(tmp) / "fmu"
            _stage_sources(recipe, spec, root / "sources", fmi)
            if fmi == 3:
                from fmus.fmi3_spec import model_description_xml3

                (root / "modelDescription.xml").write_text(model_description_xml3(spec))
                c_files = tuple("fmi3_wrapper.c" if f == "fmi2_wrapper.c" else f for f in spec.source_files)
                compile_binary(root / "sources", c_files, root / "binaries" / fmpy.platform_tuple
                               / f"{model_identifier}{fmpy.sharedLibraryExtension}", defines=("-DFMU_FMI3",))
            else:
                (root / "modelDescription.xml").write_text(spec.model_description_xml())
                compile_binary(root / "sources", spec.source_files,
                               root / "binaries" / _platform_dir() / f"{model_identifier}.so")
            partial = Path(tmp) / f"{model_identifier}.fmu"
            with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as zf:
                for path in sorted(root.rglob("*")):
                    if path.is_file():
                        zf.write(path, path.relative_to(root).as_posix())
            os.replace(partial, target)
        stamp.write_text(wanted + "\n")
        return target, True


def build_fmus(out_dir: str | Path | None = None, force: bool = False, fmi: int = 2) -> dict[str, tuple[Path, bool]]:
    """Build every FMU for FMI version ``fmi`` whose inputs changed; ``{id: (path, rebuilt)}``."""
    return {name: build_fmu(name, out_dir, force, fmi) for name in RECIPES}


def ensure_fmus(out_dir: str | Path | None = None, fmi: int = 2) -> dict[str, Path]:
    """Paths of all FMUs (``{"rx130l_plant": ..., "servo_drive": ...}``) for FMI version ``fmi``,
    built if missing or stale."""
    return {name: path for name, (path, _) in build_fmus(out_dir, fmi=fmi).items()}
