"""Fixtures shared by several test modules (helpers without pytest state live in modules beside it)."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from cosim_fmu_models import MODELS, build_test_fmu

# Property tests judge correctness, not the machine's speed: on a loaded 2-core host (CI
# runs two workers next to compiled builds) drawing examples can take seconds, which trips
# hypothesis' "generation is slow" health check and its 200 ms per-example deadline without
# any property failing. The examples and their count stay as they are.
settings.register_profile("cosim", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("cosim")


@pytest.fixture(scope="session")
def pythonfmu_models_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with the pythonfmu test models built once per test process: Integrator.fmu, Sampler.fmu, Faulty.fmu."""
    folder = tmp_path_factory.mktemp("test_fmus")
    for model in MODELS:
        build_test_fmu(model, folder)
    return folder


@pytest.fixture
def fmu_workdir(pythonfmu_models_dir: Path, tmp_path: Path) -> Path:
    """This test's ``tmp_path`` with copies of the test FMUs (scenario files name them by relative path)."""
    for fmu in pythonfmu_models_dir.glob("*.fmu"):
        shutil.copy(fmu, tmp_path / fmu.name)
    return tmp_path


@pytest.fixture(scope="session")
def browser():
    """One headless Chromium (Selenium) for every test of this process that opens a report; FAILS
    (does not skip) when Chromium or chromedriver is missing (tests/browser_support.py)."""
    from browser_support import start_browser

    driver = start_browser()
    try:
        yield driver
    finally:
        driver.quit()
