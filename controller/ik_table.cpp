/* The warm-started IK of controller.joint_reference.CartesianToJoint.solve, knot after knot
 * along a flange reference, compiled: the same pinocchio template code the Python bindings run
 * (forwardKinematics, updateFramePlacement, SE3::actInv, log6, computeFrameJacobian,
 * getFrameClassicalAcceleration, compiled from pinocchio's own headers) and the same LAPACK
 * routines (dgesv, dgetrf, dgetrs: scipy's, passed in as function pointers), in the same order
 * on the same numbers, so the joint table is the Python loop's bit for bit
 * (tests/controller/test_ik_table.py). Whatever the fast path does not accept (more Newton
 * steps, the analytic branches, a joint outside its limits, a singular Jacobian) is handed back
 * to Python at that knot: ik_table_run returns the knot's index and Python solves it.
 *
 * Built by the native layer (native/__init__.py) with -ffp-contract=off (no fused
 * multiply-add: the wheel's pinocchio was compiled for plain x86-64, which has none). */
#include <pinocchio/multibody.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/spatial.hpp>

#include <cmath>
#include <new>

typedef void (*dgesv_t)(int *, int *, double *, int *, int *, double *, int *, int *);
typedef void (*dgetrf_t)(int *, int *, double *, int *, int *, int *);
typedef void (*dgetrs_t)(char *, int *, int *, double *, int *, int *, double *, int *, int *);
typedef double (*ddot_t)(int *, double *, int *, double *, int *);

namespace {

struct Table {
    pinocchio::Model model;
    pinocchio::Data *data = nullptr;
    pinocchio::FrameIndex frame = 0;
    int nv = 0;
    dgesv_t dgesv = nullptr;
    dgetrf_t dgetrf = nullptr;
    dgetrs_t dgetrs = nullptr;
    ddot_t ddot = nullptr;
};

pinocchio::SE3 placement_of(const double *rp) {  // rotation row-major (9), then translation (3)
    Eigen::Matrix3d R;
    R << rp[0], rp[1], rp[2], rp[3], rp[4], rp[5], rp[6], rp[7], rp[8];
    return pinocchio::SE3(R, Eigen::Vector3d(rp[9], rp[10], rp[11]));
}

double dot(Table *t, double *x) {
    int n = 6, one = 1;
    return t->ddot(&n, x, &one, x, &one);
}

}  // namespace

extern "C" {

/* joint_types: 0/1/2 revolute about x/y/z of the joint frame; parents: parent joint index (0:
 * universe); placements: (njoints, 12) joint placements in the parent joint; frame_parent and
 * frame_placement (12): the flange frame. Returns NULL for an unsupported joint type. */
void *ik_table_new(int njoints, const int *joint_types, const int *parents, const double *placements,
                   int frame_parent, const double *frame_placement, void *dgesv, void *dgetrf, void *dgetrs,
                   void *ddot) {
    Table *t = new (std::nothrow) Table();
    if (t == nullptr) return nullptr;
    for (int i = 0; i < njoints; ++i) {
        pinocchio::SE3 M = placement_of(placements + 12 * i);
        std::string name = "joint_" + std::to_string(i + 1);
        switch (joint_types[i]) {
            case 0: t->model.addJoint(parents[i], pinocchio::JointModelRX(), M, name); break;
            case 1: t->model.addJoint(parents[i], pinocchio::JointModelRY(), M, name); break;
            case 2: t->model.addJoint(parents[i], pinocchio::JointModelRZ(), M, name); break;
            default: delete t; return nullptr;
        }
    }
    t->frame = t->model.addFrame(pinocchio::Frame("flange", frame_parent, 0, placement_of(frame_placement),
                                                  pinocchio::OP_FRAME));
    t->data = new pinocchio::Data(t->model);
    t->nv = t->model.nv;
    t->dgesv = (dgesv_t)dgesv;
    t->dgetrf = (dgetrf_t)dgetrf;
    t->dgetrs = (dgetrs_t)dgetrs;
    t->ddot = (ddot_t)ddot;
    return t;
}

void ik_table_free(void *handle) {
    Table *t = (Table *)handle;
    if (t == nullptr) return;
    delete t->data;
    delete t;
}

/* Knots k = start .. n-1: state (6 q, 6 qd, 6 qdd) is the previous knot's solution (updated);
 * rotations (n, 9) row-major, positions (n, 3), twists (n, 6), accelerations (n, 6) the
 * reference; out (3, n, 6): q, qd, qdd. h: knot step (s); tol2, accept2: NumericIK's squared
 * tolerance and acceptance bound; lower/upper: joint limits with their tolerance; singular:
 * smallest Hadamard ratio. Returns n when every knot is done, else the first knot Python must
 * solve (the state is then that of the knot before it). */
long long ik_table_run(void *handle, long long start, long long n, double *state, const double *rotations,
                       const double *positions, const double *twists, const double *accelerations, double *out,
                       double h, double tol2, double accept2, const double *lower, const double *upper,
                       double singular) {
    Table *t = (Table *)handle;
    const pinocchio::Model &model = t->model;
    pinocchio::Data &data = *t->data;
    const int nv = t->nv;
    if (nv != 6) return start;
    typedef pinocchio::Data::Matrix6x Matrix6x;
    Eigen::VectorXd seed(6), q(6), qd(6), zeros = Eigen::VectorXd::Zero(6);
    double *sq = state, *sqd = state + 6, *sqdd = state + 12;
    double *q_out = out, *qd_out = out + 6 * n, *qdd_out = out + 12 * n;
    const double c = 0.5 * h * h;  /* Python: 0.5 * h * h, left to right */
    double err[6], a[36], b[6], lu[36];
    int ipiv[6], info = 0, six = 6, one = 1;
    char trans = 'N';
    for (long long k = start; k < n; ++k) {
        for (int i = 0; i < 6; ++i) {  /* np.multiply(qdd, c, out=seed); seed += q; seed += qd * h */
            double s = sqdd[i] * c;
            s = s + sq[i];
            double v = sqd[i] * h;
            seed[i] = s + v;
        }
        const double *rk = rotations + 9 * k, *pk = positions + 3 * k;
        Eigen::Matrix3d R;
        R << rk[0], rk[1], rk[2], rk[3], rk[4], rk[5], rk[6], rk[7], rk[8];
        const pinocchio::SE3 target(R, Eigen::Vector3d(pk[0], pk[1], pk[2]));
        pinocchio::forwardKinematics(model, data, seed);
        const pinocchio::SE3 oMf = pinocchio::updateFramePlacement(model, data, t->frame);
        const Eigen::Matrix<double, 6, 1> e = pinocchio::log6(oMf.actInv(target)).toVector();
        for (int i = 0; i < 6; ++i) err[i] = e[i];
        const double err2 = dot(t, err);
        bool have = false;
        if (err2 <= tol2) {
            q = seed;
            have = true;
        } else if (err2 <= accept2) {
            Matrix6x J(6, nv);
            J.setZero();
            pinocchio::computeFrameJacobian(model, data, seed, t->frame, pinocchio::LOCAL, J);
            for (int i = 0; i < 36; ++i) a[i] = J.data()[i];  /* column-major, as LAPACK reads it */
            for (int i = 0; i < 6; ++i) b[i] = err[i];
            t->dgesv(&six, &one, a, &six, ipiv, b, &six, &info);
            if (info == 0 && dot(t, b) <= accept2) {
                for (int i = 0; i < 6; ++i) q[i] = seed[i] + b[i];
                have = true;
            }
        }
        if (!have) return k;
        for (int i = 0; i < 6; ++i)
            if (!(lower[i] <= q[i] && q[i] <= upper[i])) return k;
        Matrix6x J(6, nv);
        J.setZero();
        pinocchio::computeFrameJacobian(model, data, q, t->frame, pinocchio::LOCAL_WORLD_ALIGNED, J);
        for (int i = 0; i < 36; ++i) lu[i] = J.data()[i];
        t->dgetrf(&six, &six, lu, &six, ipiv, &info);
        if (info != 0) return k;
        double det = 1.0, norms = 1.0;  /* hadamard_ratio: math.prod left to right */
        for (int i = 0; i < 6; ++i) det = det * lu[i * 6 + i];
        det = std::fabs(det);
        for (int j = 0; j < 6; ++j) {
            double s = 0.0;
            for (int i = 0; i < 6; ++i) s += J(i, j) * J(i, j);
            norms = norms * std::sqrt(s);
        }
        const double ratio = norms > 0.0 ? det / norms : 0.0;
        if (ratio < singular) return k;  /* Python raises SingularConfigurationError there */
        const double *tw = twists + 6 * k, *ac = accelerations + 6 * k;
        for (int i = 0; i < 6; ++i) b[i] = tw[i];
        t->dgetrs(&trans, &six, &one, lu, &six, ipiv, b, &six, &info);
        for (int i = 0; i < 6; ++i) qd[i] = b[i];
        pinocchio::forwardKinematics(model, data, q, qd, zeros);
        const Eigen::Matrix<double, 6, 1> drift =
            pinocchio::getFrameClassicalAcceleration(model, data, t->frame, pinocchio::LOCAL_WORLD_ALIGNED).toVector();
        for (int i = 0; i < 6; ++i) b[i] = ac[i] - drift[i];
        t->dgetrs(&trans, &six, &one, lu, &six, ipiv, b, &six, &info);
        for (int i = 0; i < 6; ++i) {
            q_out[6 * k + i] = sq[i] = q[i];
            qd_out[6 * k + i] = sqd[i] = qd[i];
            qdd_out[6 * k + i] = sqdd[i] = b[i];
        }
    }
    return n;
}

}  /* extern "C" */
