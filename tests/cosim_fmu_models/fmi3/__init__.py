"""FMI 3.0 co-simulation test FMUs written in C (test_model.c + one model file each), built with
the system C compiler against the FMI 3.0 headers shipped in fmpy (``fmpy/c-code``).

``Arrays3``: Float64[3] input/parameter/output, a Float64[2,2] output and a Float32 output.
``Integers3``: an input and an output of each of Int8..UInt64, Boolean and Float32, an Int16[2].
``Ending3``: event mode, an output Clock, a Binary output, and it ends the simulation itself.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import zipfile
from pathlib import Path

import fmpy

HERE = Path(__file__).parent
MODELS = {"Arrays3": "arrays.c", "Integers3": "integers.c", "Ending3": "ending.c"}
HEADERS = ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")


def build_fmi3_test_fmu(model: str, dest_dir: str | Path, model_description: str | None = None) -> Path:
    """Compile and pack ``model`` into ``dest_dir/<model>.fmu`` (cached per directory).

    ``model_description`` replaces the shipped modelDescription.xml (for tests of bad FMUs);
    the FMU is then called ``<model>-custom.fmu`` and always rebuilt.
    """
    dest_dir = Path(dest_dir)
    target = dest_dir / (f"{model}.fmu" if model_description is None else f"{model}-custom.fmu")
    if target.exists() and model_description is None:
        return target
    c_code = Path(fmpy.__file__).parent / "c-code"
    compiler = os.environ.get("CC", "gcc")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        sources = root / "sources"
        sources.mkdir()
        for name in ("test_model.c", "test_model.h", MODELS[model]):
            shutil.copy2(HERE / name, sources / name)
        for name in HEADERS:
            shutil.copy2(c_code / name, sources / name)
        binary = root / "binaries" / fmpy.platform_tuple / f"{model}{fmpy.sharedLibraryExtension}"
        binary.parent.mkdir(parents=True)
        subprocess.run([compiler, "-std=c99", "-O2", "-shared", "-fPIC", "-Wall", "-Wno-unused-parameter",
                        f"-I{sources}", str(sources / "test_model.c"), str(sources / MODELS[model]),
                        "-o", str(binary), "-lm"], check=True, capture_output=True, text=True)
        text = model_description if model_description is not None else (HERE / f"{model}.xml").read_text()
        (root / "modelDescription.xml").write_text(text)
        partial = root / "partial.fmu"
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as zf:
            for path in sorted(root.rglob("*")):
                if path.is_file() and path != partial:
                    zf.write(path, path.relative_to(root).as_posix())
        dest_dir.mkdir(parents=True, exist_ok=True)
        os.replace(partial, target)
    return target
