"""A small FMI 2.0 co-simulation FMU written in C, built here with the system compiler, that
misbehaves on purpose: the honest way to test a segfault, abort(), _exit() or a hang in
fmi2DoStep (a Python FMU cannot crash its host like native code does), and an FMU that ends
the simulation itself (fmi2Discard + fmi2Terminated, fmi2LastSuccessfulTime).

Variables: ``y`` (output, Real) = the time reached, ``u`` (input, Real), ``echo`` (output)
= ``u``, parameters ``mode`` (Integer) and ``fail_time`` (Real, s). From the first step that
would pass ``fail_time``, ``mode`` chooses: 0 nothing, 1 end the simulation (fmi2Discard,
fmi2Terminated true, last successful time = fail_time, y = fail_time), 2 dereference NULL
(SIGSEGV), 3 abort() (SIGABRT), 4 _exit(3), 5 hang (sleep for ever).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import zipfile
from pathlib import Path

import fmpy

MODEL = "Misbehave"
GUID = "{5b0f7e3e-9f0e-4f7a-9b7e-2d1c0a51c0de}"

MODEL_DESCRIPTION = f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="{MODEL}" guid="{GUID}" generationTool="rx130l-cosim tests"
  numberOfEventIndicators="0" variableNamingConvention="flat">
  <CoSimulation modelIdentifier="{MODEL}" canHandleVariableCommunicationStepSize="true"/>
  <ModelVariables>
    <ScalarVariable name="y" valueReference="0" causality="output" variability="continuous" initial="exact">
      <Real start="0"/></ScalarVariable>
    <ScalarVariable name="u" valueReference="1" causality="input" variability="continuous"><Real start="0"/>
      </ScalarVariable>
    <ScalarVariable name="echo" valueReference="2" causality="output" variability="continuous" initial="calculated">
      <Real/></ScalarVariable>
    <ScalarVariable name="fail_time" valueReference="3" causality="parameter" variability="fixed" initial="exact">
      <Real start="1"/></ScalarVariable>
    <ScalarVariable name="mode" valueReference="4" causality="parameter" variability="fixed" initial="exact">
      <Integer start="0"/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs><Unknown index="1" dependencies=""/><Unknown index="3" dependencies="2"/></Outputs>
    <InitialUnknowns><Unknown index="3" dependencies="2"/></InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""

SOURCE = r"""
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "fmi2Functions.h"

typedef struct { double r[4]; int mode; double t; double last_ok; int terminated; } Inst;

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean l, size_t n, const fmi2String cat[]) { return fmi2OK; }
fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String loc,
                              const fmi2CallbackFunctions *f, fmi2Boolean vis, fmi2Boolean log) {
    Inst *m = calloc(1, sizeof(Inst)); m->r[3] = 1.0; return m; }
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tol, fmi2Real tv, fmi2Real t0, fmi2Boolean st,
                               fmi2Real stop) { ((Inst *)c)->t = t0; ((Inst *)c)->r[0] = t0; return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    Inst *m = c; m->r[2] = m->r[1];
    for (size_t i = 0; i < n; ++i) { if (vr[i] > 3) return fmi2Error; v[i] = m->r[vr[i]]; } return fmi2OK; }
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    for (size_t i = 0; i < n; ++i) { if (vr[i] != 4) return fmi2Error; v[i] = ((Inst *)c)->mode; } return fmi2OK; }
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    Inst *m = c;
    for (size_t i = 0; i < n; ++i) { if (vr[i] != 1 && vr[i] != 3) return fmi2Error; m->r[vr[i]] = v[i]; }
    return fmi2OK; }
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    for (size_t i = 0; i < n; ++i) { if (vr[i] != 4) return fmi2Error; ((Inst *)c)->mode = v[i]; } return fmi2OK; }
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) {
    return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) { return fmi2Error; }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) { return fmi2Error; }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) {
    return fmi2Error; }
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
    const fmi2ValueReference z[], size_t nz, const fmi2Real dv[], fmi2Real dz[]) { return fmi2Error; }
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
    const fmi2Integer o[], const fmi2Real v[]) { return fmi2Error; }
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
    const fmi2Integer o[], fmi2Real v[]) { return fmi2Error; }
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSet) {
    Inst *m = c;
    if (m->terminated) return fmi2Error;
    if (m->mode && t + h >= m->r[3] - 1e-12) {
        switch (m->mode) {
        case 1: m->last_ok = m->r[3]; m->r[0] = m->r[3]; m->t = m->r[3]; m->terminated = 1; return fmi2Discard;
        case 2: { volatile double *p = NULL; *p = 1.0; break; }
        case 3: abort();
        case 4: _exit(3);
        case 5: for (;;) pause();
        }
    }
    m->t = t + h; m->r[0] = m->t; m->last_ok = m->t; return fmi2OK; }
fmi2Status fmi2CancelStep(fmi2Component c) { return fmi2Error; }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v) { return fmi2Discard; }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v) {
    if (s != fmi2LastSuccessfulTime) return fmi2Discard; *v = ((Inst *)c)->last_ok; return fmi2OK; }
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v) { return fmi2Discard; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) {
    if (s != fmi2Terminated) return fmi2Discard; *v = ((Inst *)c)->terminated; return fmi2OK; }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v) { return fmi2Discard; }
"""


def build_misbehave_fmu(out_dir: Path) -> Path:
    """Compile and pack Misbehave.fmu into ``out_dir``; returns its path."""
    out_dir = Path(out_dir)
    work = out_dir / "misbehave-build"
    shutil.rmtree(work, ignore_errors=True)
    (work / "binaries" / "linux64").mkdir(parents=True)
    (work / "modelDescription.xml").write_text(MODEL_DESCRIPTION, encoding="utf-8")
    source = work / f"{MODEL}.c"
    source.write_text(SOURCE, encoding="utf-8")
    headers = Path(fmpy.__file__).parent / "c-code"
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") or "gcc"
    library = work / "binaries" / "linux64" / f"{MODEL}.so"
    subprocess.run([compiler, "-shared", "-fPIC", "-O1", "-I", str(headers), "-o", str(library), str(source)],
                   check=True, capture_output=True)
    fmu = out_dir / f"{MODEL}.fmu"
    with zipfile.ZipFile(fmu, "w") as archive:
        archive.write(work / "modelDescription.xml", "modelDescription.xml")
        archive.write(library, f"binaries/linux64/{MODEL}.so")
        archive.write(source, f"sources/{MODEL}.c")
    shutil.rmtree(work, ignore_errors=True)
    return fmu
