"""SSP 1.0 export and import: ``python -m cosim export-ssp`` writes the cell's FMUs,
connections and parameter values (SSD + SSV + FMUs, valid against the SSP 1.0 XSDs that
ship with fmpy, loadable by fmpy's own SSP reader), and an ``[[fmus]]``-style scenario
naming the .ssp as its ``system`` runs the same system as the scenario it came from."""
from __future__ import annotations

import json
import os
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy.ssp.ssd import read_ssd

from cosim.cli import main
from cosim.cell import wiring as robot_cell
from cosim.results import read_csv
from cosim.ssp import PARAMETER_SET, SspError, load_ssp

REPO = Path(__file__).resolve().parents[3]


def _cell_scenario(tmp_path: Path) -> Path:
    """Plant + six drives with the cell's FMU-to-FMU connections, bus inputs held at their start values."""
    fmus = ['[[fmus]]\nname = "plant"\nbuiltin = "rx130l_plant"\n[fmus.parameters]\n'
            '"q0[2]" = -0.3\n"q0[3]" = 1.2\n"q0[5]" = 0.6\npayload_mass = 5.0\nintegration_step = 1e-4\n']
    for axis, d in enumerate(robot_cell.DRIVES, start=1):
        fmus.append(f'[[fmus]]\nname = "{d}"\nbuiltin = "servo_drive"\n[fmus.parameters]\n'
                    f'position_kv = {20.0 + axis}\n')
    connections = [c for c in robot_cell.cell_connections() if not c.startswith("bus.")]
    path = tmp_path / "cell_fmus.toml"
    path.write_text(f"""connections = {json.dumps(connections)}

[scenario]
name = "cell_fmus"
job = "fmus"

[simulation]
stop_time = 0.2
macro_step = "100 us"

{chr(10).join(fmus)}
[record]
period = "1 ms"
signals = ["plant.q[*]", "plant.qd[*]", "drive*.tau_out", "drive*.statusword"]
""")
    return path


def _from_ssp(tmp_path: Path, ssp: Path, name: str = "from_ssp.toml") -> Path:
    path = tmp_path / name
    path.write_text(f"""system = "{ssp.as_posix()}"

[scenario]
name = "from_ssp"
job = "fmus"

[simulation]
stop_time = 0.2
macro_step = "100 us"

[record]
period = "1 ms"
signals = ["plant.q[*]", "plant.qd[*]", "drive*.tau_out", "drive*.statusword"]
""")
    return path


@pytest.fixture(scope="module")
def iso_ssp(tmp_path_factory):
    out = tmp_path_factory.mktemp("ssp") / "iso9283.ssp"
    assert main(["export-ssp", str(REPO / "scenarios" / "iso9283.toml"), str(out)]) == 0
    return out


def _documented(pattern: str) -> int:
    """A figure the how-to page docs/how-to/ssp.md states (the number before ``pattern``)."""
    text = (REPO / "docs" / "how-to" / "ssp.md").read_text()
    found = re.findall(r"(\d+) " + pattern, " ".join(text.split()))
    assert found, pattern
    return int(found[-1])


def test_export_of_the_main_job_is_valid_and_loads_in_fmpy(iso_ssp):
    ssd = read_ssd(str(iso_ssp), validate=True)  # fmpy's SSP reader, schema validation on
    assert [e.name for e in ssd.system.elements] == ["plant", *robot_cell.DRIVES]
    # the cell's generated wiring: 18 FMU-to-FMU connections; 8 bus inputs per drive (CiA 402 modes 8/9/10)
    # are FMU inputs annotated with the master variable that drives them, not SSD connections
    system = load_ssp(iso_ssp)
    assert len(ssd.system.connections) == len(system.connections) == 18 and len(system.inputs_connections) == 48
    assert all(c.startElement for c in ssd.system.connections)  # every connection joins two components
    assert all("Python controller" in by and "CiA 402" in by for _, by in system.system_inputs.values())
    assert sorted(system.system_inputs) == sorted(c.split(" -> ")[0] for c in system.inputs_connections)
    assert "bus.controlword[3] -> drive3.controlword" in system.inputs_connections
    bad = _rewrite(iso_ssp, iso_ssp.with_name("bad_master_variable.ssp"), "SystemStructure.ssd",
                   lambda t: t.replace('masterVariable="bus.controlword[2]"', 'masterVariable="plant.controlword[2]"'))
    with pytest.raises(SspError, match=r"<ssd:Connector name='controlword'> \(line \d+\): 'plant.controlword\[2\]' on "
                       r"kind 'input'; expected masterVariable = 'owner.name' \(not a component\)"):
        load_ssp(bad)
    # what the docs say is what the export holds
    assert _documented("components and") == len(ssd.system.elements)
    assert _documented("connections between them") == len(system.connections)
    assert _documented("inputs, 8 per drive") == len(system.inputs_connections)
    # one parameter set name for all components (Ecos applies one named set to the whole system)
    with zipfile.ZipFile(iso_ssp) as zf:
        names = {m: re.search(rb'<ssv:ParameterSet [^>]*name="([^"]+)"', zf.read(m)).group(1).decode()
                 for m in zf.namelist() if m.endswith(".ssv")}
        assert len(names) == 7 and set(names.values()) == {PARAMETER_SET}
        # extracted members are readable by all, like the archive itself (the umask's mode for a new file)
        assert all((i.external_attr >> 16) & 0o777 == 0o644 for i in zf.infolist())
    umask = os.umask(0)
    os.umask(umask)
    assert iso_ssp.stat().st_mode & 0o777 == 0o666 & ~umask
    params = {f["name"]: f["parameters"] for f in system.fmus}
    # the cell's values: the seeded true robot for the plant, each axis's drive parameters
    assert len([k for k in params["plant"] if k.startswith("p[")]) == 78 and params["plant"]["payload_mass"] == 8.0
    assert "position_kv" in params["drive3"] and params["drive1"] != params["drive3"]
    members = zipfile.ZipFile(iso_ssp).namelist()
    assert "resources/rx130l_plant.fmu" in members and members.count("resources/servo_drive.fmu") == 1


def test_ssp_system_runs_like_the_scenario_it_came_from(tmp_path):
    scenario = _cell_scenario(tmp_path)
    ssp = tmp_path / "cell.ssp"
    assert main(["export-ssp", str(scenario), str(ssp)]) == 0
    assert main(["run", str(scenario), "--out", str(tmp_path / "a"), "--quiet"]) == 0
    assert main(["run", str(_from_ssp(tmp_path, ssp)), "--out", str(tmp_path / "b"), "--quiet"]) == 0
    ca, a = read_csv(tmp_path / "a" / "timeseries.csv")
    cb, b = read_csv(tmp_path / "b" / "timeseries.csv")
    assert ca == cb and a.shape == b.shape == (201, len(ca))
    assert np.array_equal(a, b)
    # "100 us" is 1e-4 exactly: the archive's step, and a run with the step written as a number, are the same
    assert load_ssp(ssp).macro_step == 1e-4
    plain = _from_ssp(tmp_path, ssp, "plain.toml")
    plain.write_text(plain.read_text().replace('macro_step = "100 us"', "macro_step = 1e-4"))
    assert main(["run", str(plain), "--out", str(tmp_path / "c"), "--quiet"]) == 0
    cc, c = read_csv(tmp_path / "c" / "timeseries.csv")
    assert cc == ca and np.array_equal(a, c)
    # the run names the archive and each FMU's path inside it (not the temporary folder it was extracted to)
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert summary["system"] == str(ssp.resolve())
    assert summary["fmus"] == {"plant": "resources/rx130l_plant.fmu",
                               **{d: "resources/servo_drive.fmu" for d in robot_cell.DRIVES}}
    # drives disabled (controlword held at 0): the brakes hold the arm, which settles by ~8e-5 rad
    assert np.ptp(a[:, ca.index("plant.q[2]")]) > 1e-5
    system = load_ssp(ssp)
    assert {f["name"]: f["parameters"].get("position_kv") for f in system.fmus if f["name"] != "plant"} == {
        d: 20.0 + k for k, d in enumerate(robot_cell.DRIVES, start=1)}


def _rewrite(src: Path, dst: Path, member: str, edit) -> Path:
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for item in zin.namelist():
            data = zin.read(item)
            if item == member:
                data = edit(data.decode()).encode()
            if data is not None:
                zout.writestr(item, data)
    return dst


def test_system_input_connectors_of_another_writer_are_read(tmp_path):
    """SSP 1.0's own way to say 'the system drives this input': a system connector and a connection
    without startElement (what another tool may write; our export annotates the FMU input instead)."""
    ssp = tmp_path / "cell.ssp"
    assert main(["export-ssp", str(_cell_scenario(tmp_path)), str(ssp)]) == 0
    assert load_ssp(ssp).system_inputs == {}  # an fmus scenario: no master variables

    def edit(text: str) -> str:
        text = text.replace("<ssd:Elements>", '<ssd:Connectors><ssd:Connector name="cw" kind="input"><ssc:Integer/>'
                            "</ssd:Connector></ssd:Connectors><ssd:Elements>", 1)
        return text.replace("</ssd:Connections>", '<ssd:Connection startConnector="cw" endElement="drive2" '
                            'endConnector="controlword"/></ssd:Connections>', 1)

    system = load_ssp(_rewrite(ssp, tmp_path / "other.ssp", "SystemStructure.ssd", edit))
    assert system.system_inputs == {"cw": ("Integer", "")} and system.inputs_connections == ["cw -> drive2.controlword"]
    assert len(system.connections) == 18


@pytest.mark.parametrize("member, edit, words", [
    ("SystemStructure.ssd", lambda t: t.replace(' version="1.0"', "", 1),
     ["SystemStructure.ssd line 2", "valid against the SSP 1.0 schema", "version"]),
    ("SystemStructure.ssd", lambda t: t.replace("</ssd:System>", "<ssd:Bogus/></ssd:System>"),
     ["SystemStructure.ssd line", "valid against the SSP 1.0 schema", "Bogus"]),
    ("SystemStructure.ssd", lambda t: t.replace("<ssd:Elements>", "<ssd:Elements", 1), ["well-formed XML"]),
    ("SystemStructure.ssd", lambda t: t.replace('source="resources/servo_drive.fmu"', 'source="resources/nope.fmu"', 1),
     ["<ssd:Component name='drive1'>", "'resources/nope.fmu' is not in the archive"]),
    ("SystemStructure.ssd", lambda t: t.replace('endConnector="tau[1]"', 'endConnector="tau[9]"', 1),
     ["<ssd:Connection>", "plant.tau[9] is not a variable of a component"]),
    ("resources/drive2.ssv", lambda t: t.replace('name="position_kv"', 'name="position_kvv"'),
     ["resources/drive2.ssv: <ssv:Parameter name='position_kvv'>", "no variable 'position_kvv'"]),
    ("resources/plant.ssv", lambda t: t.replace('<ssv:Real value="5.0"/>', '<ssv:Real value="heavy"/>'),
     ["resources/plant.ssv line", "valid against the SSP 1.0 schema", "heavy"]),
])
def test_bad_ssp_gives_a_clear_error(tmp_path, capsys, member, edit, words):
    scenario = _cell_scenario(tmp_path)
    good = tmp_path / "cell.ssp"
    assert main(["export-ssp", str(scenario), str(good)]) == 0
    bad = _rewrite(good, tmp_path / "bad.ssp", member, edit)
    with pytest.raises(SspError) as info:
        load_ssp(bad)
    for w in words:
        assert w in str(info.value), (w, str(info.value))
    assert str(bad) in str(info.value)
    assert main(["run", str(_from_ssp(tmp_path, bad)), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "from_ssp.toml: system:" in err and words[-1] in err


def test_not_an_archive_and_system_with_fmus(tmp_path, capsys):
    junk = tmp_path / "junk.ssp"
    junk.write_text("not a zip")
    with pytest.raises(SspError, match="junk.ssp: archive: .*expected a ZIP archive"):
        load_ssp(junk)
    ssp = tmp_path / "cell.ssp"
    assert main(["export-ssp", str(_cell_scenario(tmp_path)), str(ssp)]) == 0
    both = _from_ssp(tmp_path, ssp, "both.toml")
    both.write_text(both.read_text() + '\n[[fmus]]\nname = "extra"\nbuiltin = "servo_drive"\n')
    assert main(["run", str(both), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert "both.toml: system: both given; expected either system = 'file.ssp' or [[fmus]] tables" in \
        capsys.readouterr().err
    assert main(["export-ssp", str(_cell_scenario(tmp_path)), str(tmp_path / "x.zip")]) == 2
