"""Shared by the input-validation tests: what every error about a bad file must say."""
from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path


def assert_names_file_and_fragments(error: BaseException, path: Path, fragments: Iterable[str]) -> None:
    """``error``'s message names ``path`` and holds every fragment; ``error`` is a ValueError."""
    message = str(error)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, (fragment, message)
    assert isinstance(error, ValueError)
