"""``SspError``: an .ssp archive is malformed, schema-invalid or inconsistent."""
from __future__ import annotations

from pathlib import Path


class SspError(ValueError):
    """An .ssp file is wrong; names the file, the element (or archive member) and what was expected.

    Attributes:
        file: the .ssp archive.
        element: the archive member and XML element (``SystemStructure.ssd: ssd:Connection[3]``).
        expected: what was expected, in words.
    """

    def __init__(self, file: str | Path, element: str, expected: str, problem: str | None = None) -> None:
        self.file = Path(file)
        self.element = element
        self.expected = expected
        self.problem = problem
        text = f"{self.file}: {element}: {problem + '; ' if problem else ''}expected {expected}"
        super().__init__(text)
