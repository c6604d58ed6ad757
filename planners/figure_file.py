"""Writing the planners' matplotlib figures to PNG files (Agg backend, no display)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

os.environ.setdefault("MPLBACKEND", "Agg")

FIGURE_DPI = 120
"""Resolution of the planners' PNG figures [dots per inch]."""


def save_figure(fig: Any, path: str | Path) -> Path:
    """Lay out ``fig`` (a matplotlib Figure), write it to ``path`` (parent folders created), close it; return the path."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=FIGURE_DPI)
    plt.close(fig)
    return path
