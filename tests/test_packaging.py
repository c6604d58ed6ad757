"""What a non-editable install needs: every C file and data file of the packages is
package data, the project's scenarios are installed and found from any folder.
(.ci/run builds the wheel, installs it into a fresh venv and runs the main job from
outside the source tree.)"""
import fnmatch
import sys
import tomllib
from pathlib import Path

from cosim.scenario import loader

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def _packaged(path: Path) -> bool:
    package = path.relative_to(ROOT).parts[0]
    inside = path.relative_to(ROOT / package).as_posix()
    patterns = PYPROJECT["tool"]["setuptools"]["package-data"].get(package, [])
    return any(fnmatch.fnmatch(inside, p) or fnmatch.fnmatch(inside, p.replace("**/", "")) for p in patterns)


def test_every_c_header_and_data_file_of_a_package_is_package_data():
    include = PYPROJECT["tool"]["setuptools"]["packages"]["find"]["include"]
    packages = [p.rstrip("*") for p in include]
    assert "native" in packages
    missing = [str(p.relative_to(ROOT)) for package in packages for p in (ROOT / package).rglob("*")
               if p.suffix in (".c", ".cpp", ".h", ".hpp", ".toml", ".urdf") and "__pycache__" not in p.parts and not _packaged(p)]
    assert not missing, f"not shipped by a non-editable install: {missing}"


def test_scenarios_are_installed_data_files():
    data = PYPROJECT["tool"]["setuptools"]["data-files"]
    assert data[loader.PACKAGED_SCENARIOS.as_posix()] == ["scenarios/*.toml"]


def test_installed_scenarios_are_found_from_any_folder(tmp_path, monkeypatch):
    folder = tmp_path / loader.PACKAGED_SCENARIOS
    folder.mkdir(parents=True)
    (folder / "iso9283.toml").write_text("# installed copy\n")
    monkeypatch.setattr(sys, "prefix", str(tmp_path))
    monkeypatch.chdir(tmp_path)
    for given in ("scenarios/iso9283.toml", "iso9283.toml", "iso9283"):
        assert loader.resolve_path(given) == folder / "iso9283.toml"
    (tmp_path / "scenarios").mkdir()
    (tmp_path / "scenarios" / "iso9283.toml").write_text("# the user's own\n")
    assert loader.resolve_path("scenarios/iso9283.toml") == Path("scenarios/iso9283.toml")  # a local file wins
    assert loader.resolve_path("other/iso9283.toml") == Path("other/iso9283.toml")  # no guessing elsewhere
    assert loader.resolve_path("scenarios/missing.toml") == Path("scenarios/missing.toml")


def test_the_cli_and_the_api_find_installed_scenarios(tmp_path, monkeypatch):
    """``cosim run scenarios/iso9283.toml`` outside a checkout: the CLI and the API resolve it."""
    import cosim

    folder = tmp_path / loader.PACKAGED_SCENARIOS
    folder.mkdir(parents=True)
    (folder / "plant_drop.toml").write_bytes((ROOT / "scenarios" / "plant_drop.toml").read_bytes())
    monkeypatch.setattr(sys, "prefix", str(tmp_path))
    monkeypatch.chdir(tmp_path)
    assert cosim.load_scenario("scenarios/plant_drop.toml").path == folder / "plant_drop.toml"
    assert loader.load_scenario("plant_drop").path == folder / "plant_drop.toml"
