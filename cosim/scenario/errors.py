"""``ScenarioError``: a scenario file is wrong; names the file, the key path, what was given and expected."""
from __future__ import annotations

from pathlib import Path

_MISSING = object()


class ScenarioError(ValueError):
    """A scenario file failed validation.

    Attributes:
        file: the scenario file (a Path), a label in angle brackets for documents that are
            no file (``"<dict>"``, ``"<string>"``: a str), or None.
        key: key path such as ``fmus[2].parameters.Kp`` (empty for the whole file).
        given: the offending value (or None when a key is missing).
        expected: what was expected, in words.
        problem: what is wrong (``"unknown key"``, ...) or None.
    """

    def __init__(self, file: str | Path | None, key: str, expected: str, given: object = _MISSING,
                 problem: str | None = None) -> None:
        if file is None or (isinstance(file, str) and file.startswith("<") and file.endswith(">")):
            self.file: Path | str | None = file
        else:
            self.file = Path(file)
        self.key = key
        self.expected = expected
        self.problem = problem
        self.given = None if given is _MISSING else given
        where = f"{self.file}" if self.file is not None else "<scenario>"
        if key:
            where += f": {key}"
        text = f"{where}: {problem + '; ' if problem else ''}expected {expected}"
        if given is not _MISSING:
            text += f", got {given!r}"
        super().__init__(text)
