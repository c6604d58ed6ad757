/* The laser tracker's sample in one call: flange position of a serial chain of six
 * revolute joints at the joint angles on the master's bus, plus a noise row.
 *
 * Same composition as pinocchio's forward kinematics for the TRUE arm model
 * (cosim/tracking/laser_tracker.py): oMi = oM(i-1) * (jointPlacement_i * R_axis(q_i)), the
 * flange = oM6 * framePlacement; rotations about x/y/z as pinocchio's JointModelRX/RY/RZ,
 * about a general unit axis as its RevoluteUnaligned (toRotationMatrix). Agrees with
 * pinocchio to round-off (tested to 1e-12 m). Compile with -ffp-contract=off.
 */
#include <math.h>

typedef struct {
    double R[6][9];     /* joint placement rotations, row-major */
    double p[6][3];     /* joint placement translations, m */
    double axis[6][3];  /* unit joint axes (joint frame) */
    long long kind[6];  /* 0: x, 1: y, 2: z, 3: general axis */
    double flange[3];   /* flange frame origin in joint 6's frame, m */
    const double *q;    /* the six joint angles, rad (plant outputs on the bus) */
    double *out;        /* three outputs: flange position + noise, m */
} tracker_plan;

static void axis_rotation(long long kind, const double *k, double q, double *M)
{
    const double s = sin(q), c = cos(q);
    if (kind == 0) {
        M[0] = 1.0; M[1] = 0.0; M[2] = 0.0; M[3] = 0.0; M[4] = c; M[5] = -s; M[6] = 0.0; M[7] = s; M[8] = c;
    } else if (kind == 1) {
        M[0] = c; M[1] = 0.0; M[2] = s; M[3] = 0.0; M[4] = 1.0; M[5] = 0.0; M[6] = -s; M[7] = 0.0; M[8] = c;
    } else if (kind == 2) {
        M[0] = c; M[1] = -s; M[2] = 0.0; M[3] = s; M[4] = c; M[5] = 0.0; M[6] = 0.0; M[7] = 0.0; M[8] = 1.0;
    } else {
        const double a = 1.0 - c, x = k[0], y = k[1], z = k[2];
        M[0] = c + a * x * x;     M[1] = a * x * y - s * z; M[2] = a * x * z + s * y;
        M[3] = a * x * y + s * z; M[4] = c + a * y * y;     M[5] = a * y * z - s * x;
        M[6] = a * x * z - s * y; M[7] = a * y * z + s * x; M[8] = c + a * z * z;
    }
}

static void mul33(const double *A, const double *B, double *C)
{
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            C[3 * i + j] = A[3 * i] * B[j] + A[3 * i + 1] * B[3 + j] + A[3 * i + 2] * B[6 + j];
}

static void mulv(const double *A, const double *v, double *out)
{
    for (int i = 0; i < 3; ++i) out[i] = A[3 * i] * v[0] + A[3 * i + 1] * v[1] + A[3 * i + 2] * v[2];
}

/* flange position of the chain at P->q into P->out, plus noise[0..2] (NULL: none) */
void tracker_sample(const tracker_plan *P, const double *noise)
{
    double R[9] = {1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0}, p[3] = {0.0, 0.0, 0.0};
    double Rq[9], local[9], Rn[9], v[3];
    for (int j = 0; j < 6; ++j) {
        axis_rotation(P->kind[j], P->axis[j], P->q[j], Rq);
        mul33(P->R[j], Rq, local);  /* liMi = placement * joint motion */
        mulv(R, P->p[j], v);        /* oMi = oM(i-1) * liMi */
        p[0] += v[0]; p[1] += v[1]; p[2] += v[2];
        mul33(R, local, Rn);
        for (int i = 0; i < 9; ++i) R[i] = Rn[i];
    }
    mulv(R, P->flange, v);
    for (int i = 0; i < 3; ++i) P->out[i] = (v[i] + p[i]) + (noise ? noise[i] : 0.0);
}
