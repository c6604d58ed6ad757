"""Small test models built into FMI 2.0 co-simulation FMUs with pythonfmu (a third-party exporter)."""
from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).parent
MODELS = ("integrator", "sampler", "faulty", "interrupter")


def build_test_fmu(model: str, dest_dir: Path) -> Path:
    """Build tests/cosim_fmu_models/<model>.py into ``dest_dir/<Model>.fmu`` (cached per directory)."""
    from pythonfmu.builder import FmuBuilder

    target = Path(dest_dir) / f"{model.capitalize()}.fmu"
    if not target.exists():
        built = FmuBuilder.build_FMU(HERE / f"{model}.py", dest=dest_dir)
        if Path(built) != target:
            Path(built).rename(target)
    return target
