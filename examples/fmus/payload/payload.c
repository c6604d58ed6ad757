/*
 * payload: the weight of a part gripped by the robot, as joint torques for the plant's
 * external-torque input (docs/how-to/fmu_in_cell.md).
 *
 * A point mass `mass` (kg) at `com` (m, in the flange frame tool0) hangs on the flange
 * from `pick_time` to `release_time` (s). Its weight F = (0, 0, -mass * gravity) in
 * base_link acts on joint i as the generalized force
 *     tau[i] = a_i . ((p_c - p_i) x F)        (= J_c^T F, J_c the Jacobian of the mass point)
 * with a_i, p_i the axis and a point of joint i and p_c the mass point, from the arm's
 * forward kinematics: the RX130L structure of robot/rx130l.urdf (joint axes z, y, y, z,
 * y, z; pure z offsets `link_offset[1..7]` from base_link to joint 1, ..., joint 6 to tool0).
 * Quasi-static: the part's inertia and the Coriolis terms are neglected.
 *
 * Connections: plant.q[i] -> payload.q[i], payload.tau[i] -> plant.tau_ext[i].
 * Build: a scenario's [[fmus]] source = "fmus/payload", or fmus.source_fmu.build_source_fmu (docs/how-to/fmu_in_cell.md).
 */
#define MODEL_IDENTIFIER payload
#define MODEL_GUID "{5b1f0a52-9a1e-4c0d-9d1e-13001a000001}"
#define N_REAL 27
#define N_INTEGER 0

/* value references (Real): the order of modelDescription.xml */
enum {
    VR_Q = 0,              /* q[1..6]            input, rad */
    VR_TAU = 6,            /* tau[1..6]          output, N.m (on the joints, for plant.tau_ext) */
    VR_MASS = 12,          /* mass               parameter, kg */
    VR_COM = 13,           /* com[1..3]          parameter, m in tool0 */
    VR_PICK = 16,          /* pick_time          parameter, s */
    VR_RELEASE = 17,       /* release_time       parameter, s */
    VR_GRAVITY = 18,       /* gravity            parameter, m/s2 */
    VR_OFFSET = 19,        /* link_offset[1..7]  parameter, m */
    VR_LOAD = 26           /* load_mass          output, kg (the mass hanging on the flange now) */
};

static const double REAL_START[N_REAL] = {
    0, 0, 0, 0, 0, 0,                     /* q */
    0, 0, 0, 0, 0, 0,                     /* tau */
    5.0, 0.0, 0.0, 0.1,                   /* mass, com */
    0.0, 1e30, 9.81,                      /* pick_time, release_time, gravity */
    0.30, 0.25, 0.625, 0.50, 0.425, 0.080, 0.030,   /* link_offset: robot/rx130l.urdf */
    0.0                                   /* load_mass */
};
static const int REAL_IS_INPUT_OR_PARAMETER[N_REAL] = {
    1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0};
static const int INTEGER_START[1] = {0};
static const int INTEGER_IS_INPUT_OR_PARAMETER[1] = {0};

typedef struct {
    int unused;
} ModelState;

static int model_init(ModelState *s, double *r, int *i, char *msg);
static void model_outputs(ModelState *s, double *r, int *i, double t);
static int model_step(ModelState *s, double *r, int *i, double t, double h, char *msg);

#include "fmi2_cs_template.h"

static const char AXIS[6] = {'z', 'y', 'y', 'z', 'y', 'z'};

/* R <- R * Rot(axis, angle) */
static void rotate(double R[3][3], char axis, double angle)
{
    double c = cos(angle), s = sin(angle), out[3][3];
    int r;
    for (r = 0; r < 3; r++) {
        if (axis == 'z') {
            out[r][0] = R[r][0] * c + R[r][1] * s;
            out[r][1] = -R[r][0] * s + R[r][1] * c;
            out[r][2] = R[r][2];
        } else { /* y */
            out[r][0] = R[r][0] * c - R[r][2] * s;
            out[r][1] = R[r][1];
            out[r][2] = R[r][0] * s + R[r][2] * c;
        }
    }
    memcpy(R, out, sizeof out);
}

static void model_outputs(ModelState *s, double *r, int *i, double t)
{
    double R[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}, p[3] = {0, 0, 0}, pj[6][3], aj[6][3], pc[3], F[3];
    double mass = (t >= r[VR_PICK] && t < r[VR_RELEASE]) ? r[VR_MASS] : 0.0;
    int j, k;
    (void)s; (void)i;
    for (j = 0; j < 6; j++) {
        for (k = 0; k < 3; k++) p[k] += R[k][2] * r[VR_OFFSET + j];     /* translate along local z */
        for (k = 0; k < 3; k++) {
            pj[j][k] = p[k];
            aj[j][k] = AXIS[j] == 'z' ? R[k][2] : R[k][1];
        }
        rotate(R, AXIS[j], r[VR_Q + j]);
    }
    for (k = 0; k < 3; k++) p[k] += R[k][2] * r[VR_OFFSET + 6];         /* tool0 */
    for (k = 0; k < 3; k++) pc[k] = p[k] + R[k][0] * r[VR_COM] + R[k][1] * r[VR_COM + 1] + R[k][2] * r[VR_COM + 2];
    F[0] = 0.0; F[1] = 0.0; F[2] = -mass * r[VR_GRAVITY];
    for (j = 0; j < 6; j++) {
        double d[3] = {pc[0] - pj[j][0], pc[1] - pj[j][1], pc[2] - pj[j][2]};
        double m[3] = {d[1] * F[2] - d[2] * F[1], d[2] * F[0] - d[0] * F[2], d[0] * F[1] - d[1] * F[0]};
        r[VR_TAU + j] = aj[j][0] * m[0] + aj[j][1] * m[1] + aj[j][2] * m[2];
    }
    r[VR_LOAD] = mass;
}

static int model_init(ModelState *s, double *r, int *i, char *msg)
{
    (void)s; (void)i;
    if (!(r[VR_MASS] >= 0.0)) { snprintf(msg, 256, "mass = %g kg: expected >= 0", r[VR_MASS]); return 1; }
    if (!(r[VR_RELEASE] > r[VR_PICK])) {
        snprintf(msg, 256, "release_time = %g s: expected after pick_time = %g s", r[VR_RELEASE], r[VR_PICK]);
        return 1;
    }
    return 0;
}

static int model_step(ModelState *s, double *r, int *i, double t, double h, char *msg)
{
    (void)msg;
    model_outputs(s, r, i, t + h);
    return 0;
}
