/*
 * RX130L-class arm plant: forward dynamics qdd = fd(q, qd, tau, p, payload) generated
 * by CasADi (rx130l_plant_fd.c, articulated-body algorithm with rotor inertia and
 * viscous + tanh-smoothed Coulomb friction), integrated inside fmi2DoStep with the
 * classical fourth-order Runge-Kutta method. Each communication step h is split into
 * n = ceil(h / integration_step) equal sub-steps; the torque inputs are held constant
 * over the step. Outputs at the end of the step: q, qd and qdd = fd(q, qd, tau).
 * Units: rad, rad/s, rad/s^2, N m; parameters as robot/dynamics.py.
 */
#include <math.h>
#include <string.h>

#include "fmu_instance.h"
#include "rx130l_plant_fd.h"

#define MAX_SUBSTEPS 10000000.0

/* the CasADi payload input [mass, cx, cy, cz] is read straight from the value array */
typedef char payload_is_contiguous[(VR_PAYLOAD_COM == VR_PAYLOAD_MASS + 1) ? 1 : -1];

static int derivative(const Instance *inst, const double x[12], const double tau[6], double dx[12])
{
    const casadi_real *arg[rx130l_plant_fd_SZ_ARG];
    casadi_real *res[rx130l_plant_fd_SZ_RES];
    casadi_int iw[rx130l_plant_fd_SZ_IW + 1];
    casadi_real w[rx130l_plant_fd_SZ_W + 1];
    arg[0] = x;
    arg[1] = x + 6;
    arg[2] = tau;
    arg[3] = &inst->d.r[VR_P];
    arg[4] = &inst->d.r[VR_PAYLOAD_MASS];
    res[0] = dx + 6;
    memcpy(dx, x + 6, 6 * sizeof(double));
    return rx130l_plant_fd(arg, res, iw, w, 0);
}

static int rk4_step(const Instance *inst, double x[12], const double tau[6], double dt)
{
    double k1[12], k2[12], k3[12], k4[12], tmp[12];
    int j, status = 0;
    status |= derivative(inst, x, tau, k1);
    for (j = 0; j < 12; j++) tmp[j] = x[j] + 0.5 * dt * k1[j];
    status |= derivative(inst, tmp, tau, k2);
    for (j = 0; j < 12; j++) tmp[j] = x[j] + 0.5 * dt * k2[j];
    status |= derivative(inst, tmp, tau, k3);
    for (j = 0; j < 12; j++) tmp[j] = x[j] + dt * k3[j];
    status |= derivative(inst, tmp, tau, k4);
    for (j = 0; j < 12; j++) x[j] += dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
    return status;
}

static int write_outputs(Instance *inst)
{
    double dx[12];
    int j;
    int status = derivative(inst, inst->d.s.x, &inst->d.r[VR_TAU], dx);
    for (j = 0; j < 6; j++) {
        inst->d.r[VR_Q + j] = inst->d.s.x[j];
        inst->d.r[VR_QD + j] = inst->d.s.x[6 + j];
        inst->d.r[VR_QDD + j] = dx[6 + j];
    }
    return status;
}

static int state_is_finite(const Instance *inst)
{
    int j;
    for (j = 0; j < 12; j++)
        if (!isfinite(inst->d.s.x[j])) return 0;
    return 1;
}

void model_reset(Instance *inst)
{
    memset(&inst->d.s, 0, sizeof inst->d.s);
}

int model_initialize(Instance *inst)
{
    int j;
    for (j = 0; j < 6; j++) {
        inst->d.s.x[j] = inst->d.r[VR_Q0 + j];
        inst->d.s.x[6 + j] = inst->d.r[VR_QD0 + j];
    }
    if (write_outputs(inst) != 0 || !isfinite(inst->d.r[VR_QDD]) || !isfinite(inst->d.r[VR_QDD + 5])) {
        fmu_log(inst, fmi2Error, "logStatusError",
                "the dynamics are not defined at the initial state with these parameters "
                "(check the link masses and inertias p[1]..p[78])");
        return 1;
    }
    return 0;
}

int model_do_step(Instance *inst, double t, double h)
{
    double tau[6], x[12], n_real, dt;
    long n, k;
    int status = 0;
    n_real = ceil(h / inst->d.r[VR_INTEGRATION_STEP] - 1e-9);
    if (n_real > MAX_SUBSTEPS) {
        fmu_log(inst, fmi2Error, "logStatusError",
                "fmi2DoStep: communicationStepSize=%g s would need %.3g sub-steps of integration_step=%g s "
                "(at most %.0f allowed)", h, n_real, inst->d.r[VR_INTEGRATION_STEP], MAX_SUBSTEPS);
        return MODEL_STEP_REJECTED;
    }
    n = n_real < 1.0 ? 1 : (long)n_real;
    dt = h / (double)n;
    memcpy(tau, &inst->d.r[VR_TAU], sizeof tau);
    memcpy(x, inst->d.s.x, sizeof x);
    for (k = 0; k < n; k++) status |= rk4_step(inst, x, tau, dt);
    memcpy(inst->d.s.x, x, sizeof x);
    if (status != 0 || !state_is_finite(inst)) {
        fmu_log(inst, fmi2Error, "logStatusError",
                "fmi2DoStep: the arm state became non-finite between t=%.9g s and t=%.9g s "
                "(tau = %g %g %g %g %g %g N m)", t, t + h, tau[0], tau[1], tau[2], tau[3], tau[4], tau[5]);
        return MODEL_STEP_FAILED;
    }
    return write_outputs(inst) == 0 ? 0 : MODEL_STEP_FAILED;
}
