"""The native layer (`native/`): one compiler, a cache keyed by source, compiler, flags
and Python, private cache folders, and COSIM_NATIVE deciding whether a failed build is
an error (require), a note said once (auto) or skipped (off)."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

import native
from fieldbus import codec

ROOT = Path(__file__).resolve().parents[2]
C_SOURCE = "double twice(double x) { return 2.0 * x; }\n"


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("COSIM_CACHE_DIR", str(folder))
    monkeypatch.delenv("COSIM_NATIVE", raising=False)
    monkeypatch.setattr(native, "_reported", set())
    return folder


def _env(cache: Path, **extra: str) -> dict:
    env = dict(os.environ, COSIM_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT))
    env.pop("FIELDBUS_CODEC", None)
    env.pop("COSIM_NATIVE", None)  # .ci/run sets require; each case here says what it wants
    env.update(extra)
    return env


def test_build_load_and_cache_hit(cache, tmp_path):
    source = tmp_path / "twice.c"
    source.write_text(C_SOURCE)
    library = native.build("twice", [source])
    assert library.parent.parent == cache and oct(cache.stat().st_mode & 0o777) == "0o700"
    lib = native.load_ctypes(library)
    lib.twice.restype, lib.twice.argtypes = native.ctypes.c_double, [native.ctypes.c_double]
    assert lib.twice(21.0) == 42.0
    stamp = library.stat().st_mtime_ns
    assert native.build("twice", [source]) == library and library.stat().st_mtime_ns == stamp  # cached
    assert native.build("twice", [source], cflags=("-O1", "-shared", "-fPIC")) != library  # flags in the key
    source.write_text(C_SOURCE + "int unused;\n")
    assert native.build("twice", [source]) != library  # source in the key
    assert not list(cache.glob(".twice-*"))  # no temporary build folder left behind


def test_a_header_is_compiled_with_its_source_and_in_the_key(cache, tmp_path):
    src, inc = tmp_path / "src", tmp_path / "inc"  # the header in another folder: build puts it next to the source
    src.mkdir()
    inc.mkdir()
    header = inc / "factor.h"
    header.write_text("#define FACTOR 2.0\n")
    source = src / "scaled.c"
    source.write_text('#include "factor.h"\ndouble scaled(double x) { return FACTOR * x; }\n')

    def scaled(library: Path) -> float:
        lib = native.load_ctypes(library)
        lib.scaled.restype, lib.scaled.argtypes = native.ctypes.c_double, [native.ctypes.c_double]
        return lib.scaled(21.0)

    first = native.build("scaled", [source], headers=[header])
    assert scaled(first) == 42.0
    assert native.build("scaled", [source], headers=[header]) == first  # cached
    header.write_text("#define FACTOR 3.0\n")
    second = native.build("scaled", [source], headers=[header])
    assert second != first and scaled(second) == 63.0  # the header is in the key
    with pytest.raises(native.NativeBuildError, match="factor.h"):
        native.build("scaled", [source])  # without it the compiler does not find it


def test_generated_sources_and_side_files_build_once(cache):
    calls = []

    def generate(folder: Path) -> list[Path]:
        calls.append(folder)
        (folder / "twice.c").write_text(C_SOURCE)
        (folder / "twice.so.meta").write_text("kept")
        return [folder / "twice.c"]

    first = native.build("gen", generate=generate, key=b"v1")
    assert native.build("gen", generate=generate, key=b"v1") == first and len(calls) == 1
    assert (first.parent / "twice.so.meta").read_text() == "kept"
    assert native.build("gen", generate=generate, key=b"v2") != first and len(calls) == 2


def test_a_cache_writable_by_others_or_a_library_of_another_mode_is_refused(cache, tmp_path):
    source = tmp_path / "twice.c"
    source.write_text(C_SOURCE)
    library = native.build("twice", [source])
    library.chmod(0o666)
    with pytest.raises(native.NativeBuildError, match="writable by group or others"):
        native.load_ctypes(library)
    cache.chmod(0o777)
    with pytest.raises(native.NativeBuildError, match="writable by group or others"):
        native.cache_root()


def test_default_cache_is_per_user_not_shared_tmp(monkeypatch, tmp_path):
    monkeypatch.delenv("COSIM_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert native.cache_root() == tmp_path / "xdg" / "rx130l-cosim" / "native"


def test_broken_c_file_fails_loudly_under_require(cache, tmp_path):
    broken = tmp_path / "codec.c"
    broken.write_text(codec.SOURCE.read_text() + "\nthis is not C;\n")
    program = (f"from pathlib import Path\nimport fieldbus.codec as c\nc.SOURCE = Path({str(broken)!r})\n"
               "print('codec', c.load_codec())\n")
    done = subprocess.run([sys.executable, "-c", program], env=_env(cache, COSIM_NATIVE="require"),
                          capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode != 0
    assert "NativeBuildError" in done.stderr and "building fieldbus_codec" in done.stderr
    assert "this is not C" in done.stderr  # the compiler's own message
    # without the variable: the Python path runs and says so once
    program += "print('again', c.load_codec.__wrapped__())\n"
    done = subprocess.run([sys.executable, "-c", program], env=_env(cache), capture_output=True, text=True,
                          cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "codec None" in done.stdout and "again None" in done.stdout
    assert done.stderr.count("fieldbus codec: compiled code unavailable") == 1
    assert "the Python path runs" in done.stderr


def test_missing_compiler(cache, tmp_path, monkeypatch, capsys):
    source = tmp_path / "twice.c"
    source.write_text(C_SOURCE)
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    assert native.load_library(source, what="twice") is None
    assert native.load_library(source, what="twice") is None
    assert capsys.readouterr().err.count("no C compiler found") == 1
    monkeypatch.setenv("COSIM_NATIVE", "require")
    with pytest.raises(native.NativeBuildError, match="no C compiler found"):
        native.load_library(source, what="twice")
    monkeypatch.setenv("COSIM_NATIVE", "off")
    assert native.load_library(source, what="twice") is None and capsys.readouterr().err == ""
    monkeypatch.setenv("COSIM_NATIVE", "sometimes")
    with pytest.raises(native.NativeBuildError, match="expected one of auto, require, off"):
        native.mode()


def test_helpers_build_through_the_native_layer():
    """No helper keeps its own compiler search or build folder."""
    for path in ("cosim/master/kernel.py", "fieldbus/codec.py", "controller/compiled_cycle.py",
                 "planners/ptp_nodes.py", "cosim/tracking/laser_tracker.py", "fmus/build.py"):
        text = (ROOT / path).read_text()
        assert "native" in text, path
        assert "shutil.which" not in text and 'environ.get("CC"' not in text and "subprocess.run" not in text, path
