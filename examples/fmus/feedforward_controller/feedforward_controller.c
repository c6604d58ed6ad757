/*
 * feedforward_controller: a controller FMU in C (FMI 2.0 co-simulation), stepped by the cell
 * once per bus cycle (docs/how-to/controller_fmu.md).
 *
 * Cyclic synchronous position (CiA 402 mode 8) with a decoupled feed-forward torque, the
 * classic industrial step between the bare drive cascade and a full model-based controller:
 *     target_position[i] = q_ref[i]
 *     torque_offset[i]   = inertia[i] qdd_ref[i] + viscous[i] qd_ref[i]
 *                          + coulomb[i] tanh(qd_ref[i] / coulomb_velocity)
 * per joint, no coupling, no gravity (the drives' integrators hold the gravity load).
 * The reference inputs are the cell's joint reference at the time the output acts;
 * the cell enables the drives and sends the controlwords (what the FMU does not map).
 *
 * Defaults: the diagonal of the nominal mass matrix (rotor inertia included) at the ISO 9283
 * start pose with the 8 kg tool, and the friction of robot/rx130l_params.toml.
 */
#define MODEL_IDENTIFIER feedforward_controller
#define MODEL_GUID "{a3c9e2d4-7b51-4f0e-8d2a-13001a000002}"
#define N_REAL 49
#define N_INTEGER 0

enum {
    VR_Q_REF = 0,         /* q_ref[1..6]        input, rad */
    VR_QD_REF = 6,        /* qd_ref[1..6]       input, rad/s */
    VR_QDD_REF = 12,      /* qdd_ref[1..6]      input, rad/s2 */
    VR_TARGET = 18,       /* target_position[1..6]  output, rad */
    VR_TORQUE = 24,       /* torque_offset[1..6]    output, N.m */
    VR_INERTIA = 30,      /* inertia[1..6]      parameter, kg.m2 */
    VR_VISCOUS = 36,      /* viscous[1..6]      parameter, N.m.s/rad */
    VR_COULOMB = 42,      /* coulomb[1..6]      parameter, N.m */
    VR_VS = 48            /* coulomb_velocity   parameter, rad/s */
};

static const double REAL_START[N_REAL] = {
    0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,   /* references */
    0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,                     /* outputs */
    27.0, 35.8, 19.9, 0.390, 0.469, 0.0508,                 /* inertia */
    24.0, 17.0, 6.0, 1.7, 2.8, 1.0,                         /* viscous */
    21.0, 25.0, 19.0, 3.7, 4.5, 0.4,                        /* coulomb */
    0.01                                                    /* coulomb_velocity */
};
static const int REAL_IS_INPUT_OR_PARAMETER[N_REAL] = {
    1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1,
    0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
    1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1};
static const int INTEGER_START[1] = {0};
static const int INTEGER_IS_INPUT_OR_PARAMETER[1] = {0};

typedef struct {
    int unused;
} ModelState;

static int model_init(ModelState *s, double *r, int *i, char *msg);
static void model_outputs(ModelState *s, double *r, int *i, double t);
static int model_step(ModelState *s, double *r, int *i, double t, double h, char *msg);

#include "fmi2_cs_template.h"

static void model_outputs(ModelState *s, double *r, int *i, double t)
{
    int j;
    (void)s; (void)i; (void)t;
    for (j = 0; j < 6; j++) {
        double qd = r[VR_QD_REF + j];
        r[VR_TARGET + j] = r[VR_Q_REF + j];
        r[VR_TORQUE + j] = r[VR_INERTIA + j] * r[VR_QDD_REF + j] + r[VR_VISCOUS + j] * qd
                           + r[VR_COULOMB + j] * tanh(qd / r[VR_VS]);
    }
}

static int model_init(ModelState *s, double *r, int *i, char *msg)
{
    int j;
    (void)s; (void)i;
    for (j = 0; j < 6; j++) {
        if (!(r[VR_INERTIA + j] >= 0.0 && r[VR_VISCOUS + j] >= 0.0 && r[VR_COULOMB + j] >= 0.0)) {
            snprintf(msg, 256, "joint %d: inertia, viscous and coulomb must be >= 0", j + 1);
            return 1;
        }
    }
    if (!(r[VR_VS] > 0.0)) { snprintf(msg, 256, "coulomb_velocity = %g rad/s: expected > 0", r[VR_VS]); return 1; }
    return 0;
}

static int model_step(ModelState *s, double *r, int *i, double t, double h, char *msg)
{
    (void)msg;
    model_outputs(s, r, i, t + h);
    return 0;
}
