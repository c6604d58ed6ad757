"""Job ``calibration``: the simulated geometric-calibration campaign (paper section 3).

Runs :func:`calibration.campaign.run_calibration_campaign` with the
scenario's tables (all optional; defaults and meaning in that module and in
docs/explanation/calibration.md) and puts its summary into ``summary.json``: Table 2 figures
(``uncalibrated``/``calibrated``), identifiable parameters, observation-index ratios
against a linear scan and random selections (per index: ``observation_index_ratios``),
selection time. Files written next to
it: measurements.csv, calibrated.urdf, parameters.json, calibration_residuals.json,
table2.md, table2.png, configurations.png.
"""
from __future__ import annotations

from typing import Any

from cosim.scenario.context import RunContext
from cosim.scenario.loader import SCENARIO_FIELD, Scenario
from cosim.scenario.job_type import JobType
from cosim.scenario.schema import Boolean, Field, Integer, List, Number, String, Table
from calibration.observability import OBSERVATION_INDICES
from calibration.scaling import COLUMN_SCALINGS

TRUE_ROBOT = Table({
    "seed": Field(Integer(min=0), doc="seed of robot.true_robot.make_true_robot (its geometric errors)"),
}, doc="the [true_robot] table")

TRACKER = Table({
    "position_sigma": Field(Number(unit="m", min=0, max=0.01), doc="position noise per axis"),
    "orientation_sigma": Field(Number(unit="rad", min=0, max=0.1), doc="orientation noise (rotation vector)"),
    "measure_orientation": Field(Boolean(), doc="measure orientation as well as position"),
    "noise_seed": Field(Integer(min=0), doc="seed of the simulated tracker noise"),
    "position": Field(List(Number(unit="m"), length=3), doc="camera bar position in base_link"),
    "target": Field(List(Number(unit="m"), length=3), doc="point the cameras look at"),
    "fov_half_angle": Field(Number(unit="rad", gt=0, max=1.5707963267948966),
                            doc="half angle of the cameras' field-of-view cone"),
    "range_min": Field(Number(unit="m", min=0), doc="nearest distance from the camera bar it measures at"),
    "range_max": Field(Number(unit="m", gt=0), doc="farthest distance from the camera bar it measures at"),
    "probe_normal": Field(List(Number(), length=3), doc="LED facing direction in the flange frame"),
    "probe_max_angle": Field(Number(unit="rad", gt=0, max=3.141592653589793),
                             doc="largest angle between probe_normal and the direction to the cameras"),
    "floor_clearance": Field(Number(unit="m"), doc="lowest flange height above the floor (z = 0) for a candidate"),
    "base_keepout_radius": Field(Number(unit="m", min=0),
                                 doc="radius of the cylinder around axis 1 the flange stays out of"),
    "base_keepout_height": Field(Number(unit="m"), doc="height up to which that keep-out cylinder reaches"),
}, doc="the [tracker] table")

CANDIDATES = Table({
    "values_per_axis": Field(Integer(min=2, max=25),
                             doc="grid values per joint axis (limits included) the candidate configurations are cut from"),
    "max_candidates": Field(Integer(min=0), doc="0: keep every visible configuration"),
}, doc="the [candidates] table")

SELECTION = Table({
    "configurations": Field(Integer(min=1), doc="how many measurement configurations to select"),
    "index": Field(String(choices=tuple(OBSERVATION_INDICES)), doc="the observation index the selection maximizes"),
    "restarts": Field(Integer(min=1), doc="restarts of the exchange search from random start sets"),
    "seed": Field(Integer(min=0), doc="seed of the random start sets and of the random baseline draws"),
    "start_size": Field(Integer(min=0), doc="0: default start size"),
    "random_draws": Field(Integer(min=1), doc="random selections drawn as the baseline the optimum is compared with"),
    "scaling": Field(String(choices=COLUMN_SCALINGS), doc="units of the selection problem"),
    "compare_indices": Field(Boolean(), doc="select for every observation index and report the ratios"),
}, doc="the [selection] table")

VALIDATION = Table({
    "poses": Field(Integer(min=1), doc="validation poses, drawn from the visible candidates not selected"),
    "seed": Field(Integer(min=0), doc="seed of the validation pose draw"),
}, doc="the [validation] table")

SECTIONS = {"true_robot": TRUE_ROBOT, "tracker": TRACKER, "candidates": CANDIDATES,
            "selection": SELECTION, "validation": VALIDATION}

SECTION_DOCS = {"true_robot": "the simulated robot whose geometry is calibrated",
                "tracker": "the optical tracker: placement, field of view, probe, noise",
                "candidates": "the grid of candidate measurement configurations",
                "selection": "the choice of optimal measurement configurations",
                "validation": "the poses the calibrated model is checked on"}

SCHEMA = Table({"scenario": SCENARIO_FIELD,
                **{name: Field(spec, doc=SECTION_DOCS[name]) for name, spec in SECTIONS.items()}},
               doc="a calibration scenario document")


def run_calibration_job(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    """Run the campaign into the results folder; return the summary fields."""
    from calibration.campaign import run_calibration_campaign  # heavy: only when this job runs

    config = {name: scenario.data[name] for name in SECTIONS if name in scenario.data}
    return run_calibration_campaign(config, ctx.out_dir, write_summary=False)


JOB = JobType("calibration", run_calibration_job, SCHEMA, None,
              "simulated geometric calibration: optimal tracker configurations, identification, Table 2")
