"""Load a user's class named in a scenario: ``"path/to/file.py:ClassName"`` or ``"package.module:ClassName"``.

* ``file.py:ClassName``: the file (relative to the scenario file's folder, or absolute)
  is imported as a module of its own; its folder is put on ``sys.path`` so it can
  import its neighbours. The same file is imported once per process.
* ``package.module:ClassName``: imported with ``importlib`` from ``sys.path`` (an
  installed package, or one on ``PYTHONPATH``).

Every failure (bad spec, missing file, the module raising on import, no such class, not
a class) is a :class:`ScenarioError` at the scenario key that named the class, with the
expected value; the user's own exception text is quoted, no traceback.
"""
from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
import traceback
from pathlib import Path
from types import ModuleType
from typing import Any

from cosim.scenario.errors import ScenarioError
from cosim.scenario.schema import Where

SPEC_FORM = "'path/to/file.py:ClassName' or 'package.module:ClassName'"

_FILE_MODULES: dict[Path, ModuleType] = {}


def is_class_spec(text: Any) -> bool:
    """True when ``text`` has the form of a class spec (``something:Name``)."""
    return isinstance(text, str) and ":" in text and bool(text.rpartition(":")[2].strip())


def class_spec_file(text: Any) -> str | None:
    """The file of a ``"file.py:ClassName"`` spec as written (None for ``"module:ClassName"`` or other values).

    Used by specs that name user classes to tell a sweep which file to ship to its workers
    (``referenced_file``, cosim.scenario.keypath.referenced_files).
    """
    if not is_class_spec(text):
        return None
    target = text.rpartition(":")[0].strip()
    return target if target.endswith(".py") or "/" in target or "\\" in target else None


def with_class_file(text: str, path: str) -> str:
    """``"file.py:ClassName"`` with its file replaced by ``path``."""
    return f"{path}:{text.rpartition(':')[2].strip()}"


def _why(exc: BaseException) -> str:
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if not f.filename.startswith("<frozen")]
    where = f" ({Path(frames[-1].filename).name}, line {frames[-1].lineno})" if frames else ""
    if isinstance(exc, SyntaxError):
        where = f" ({Path(exc.filename or '?').name}, line {exc.lineno})"
    return f"{type(exc).__name__}: {exc}{where}"


def _import_file(path: Path, where: Where, expected: str) -> ModuleType:
    path = path.resolve()
    if path in _FILE_MODULES:
        return _FILE_MODULES[path]
    digest = hashlib.sha1(str(path).encode()).hexdigest()[:10]
    name = f"cosim_user_{path.stem}_{digest}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise where.error(expected, problem=f"{str(path)!r} cannot be imported as a Python module")
    module = importlib.util.module_from_spec(spec)
    folder = str(path.parent)
    if folder not in sys.path:
        sys.path.append(folder)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as exc:  # the user's module: report, no traceback
        sys.modules.pop(name, None)
        raise where.error(expected, problem=f"importing {str(path)!r} failed: {_why(exc)}") from None
    _FILE_MODULES[path] = module
    return module


def load_user_class(spec: str, where: Where, what: str = "class") -> type:
    """The class named by ``spec`` (see module docstring); ScenarioError at ``where`` otherwise.

    ``what`` names the expected thing in messages (e.g. "planner class").
    """
    expected = f"a {what} as {SPEC_FORM}"
    if not is_class_spec(spec):
        raise where.error(expected, spec)
    target, _, attr = spec.rpartition(":")
    target, attr = target.strip(), attr.strip()
    if target.endswith(".py") or "/" in target or "\\" in target:
        path = Path(target).expanduser()
        if not path.is_absolute():
            path = where.base_dir / path
        if not path.is_file():
            raise where.error(expected, spec, problem=f"file {str(path)!r} does not exist")
        module = _import_file(path, where, expected)
        origin = str(path)
    else:
        try:
            module = importlib.import_module(target)
        except ModuleNotFoundError as exc:
            raise where.error(expected, spec, problem=f"no module named {exc.name!r}") from None
        except Exception as exc:
            raise where.error(expected, spec, problem=f"importing module {target!r} failed: {_why(exc)}") from None
        origin = f"module {target!r}"
    obj = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            names = sorted(n for n in vars(module) if isinstance(getattr(module, n), type) and not n.startswith("_"))
            raise where.error(expected, spec, problem=f"{origin} has no {attr!r} (its classes: {names})")
        obj = getattr(obj, part)
    if not isinstance(obj, type):
        raise where.error(expected, spec, problem=f"{attr!r} in {origin} is a {type(obj).__name__}, not a class")
    return obj


def instantiate(cls: type, params: dict[str, Any], where: Where, what: str = "class") -> Any:
    """``cls(**params)``; a ScenarioError at ``where`` when the constructor rejects them or raises."""
    try:
        return cls(**params)
    except ScenarioError:
        raise
    except Exception as exc:
        raise where.error(f"parameters the {what} {cls.__name__} accepts", params,
                          problem=f"{cls.__name__}(**parameters) failed: {_why(exc)}") from None
