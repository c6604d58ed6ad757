"""Text files the project reads, and users bring (trajectory, measurement and record CSV files,
results written as CSV): UTF-8, with or without a byte-order mark.

Spreadsheet programs write one at the start of a UTF-8 CSV file (Excel's "CSV UTF-8", LibreOffice
with "Unicode (UTF-8)" on Windows); without this reader it would end up in the first column's
name (``'\\ufefft'`` instead of ``'t'``). Every CSV reader of the project opens files through
:func:`open_text`, so each accepts what the others accept.
"""
from __future__ import annotations

import csv
from pathlib import Path
from typing import TextIO

ENCODING = "utf-8-sig"
"""UTF-8; a byte-order mark at the start is read and dropped (none is written)."""


def open_text(path: str | Path) -> TextIO:
    """``path`` opened for reading as UTF-8 text (byte-order mark dropped; ``newline=""`` as the
    :mod:`csv` module wants). OSError / UnicodeDecodeError (on reading) as ``open`` raises them."""
    return open(path, encoding=ENCODING, newline="")


def read_text(path: str | Path) -> str:
    """The whole text of ``path`` (:func:`open_text`; line ends kept as in the file)."""
    with open_text(path) as handle:
        return handle.read()


def csv_rows(path: str | Path) -> list[list[str]]:
    """Every row of the CSV file ``path`` as a list of cells (:func:`open_text`, :func:`csv.reader`)."""
    with open_text(path) as handle:
        return list(csv.reader(handle))
