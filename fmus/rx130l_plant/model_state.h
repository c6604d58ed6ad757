/* Internal state of the arm plant (see rx130l_plant.c). Plain data only. */
#ifndef MODEL_STATE_H
#define MODEL_STATE_H

/* rx130l_plant.c computes its outputs in Initialization Mode (model_initial_outputs) */
#define MODEL_INITIAL_OUTPUTS 1
/* ... and after a step its accelerations (qdd, the rigid model's tau_gear: one more forward
 * dynamics) only when they are read (model_lazy_outputs) */
#define MODEL_LAZY_OUTPUTS 1

typedef struct {
    /* q[6] (rad), qd[6] (rad/s) of the links, then (elastic joints only) the motor
     * angles th[6] (rad) and speeds thd[6] (rad/s) divided by the gear ratios; joint 1 first */
    double x[24];
    /* joint 1..6 and flange placements (rotation row by row, translation) with the
     * geometric_errors folded in: rx130l_plant_geometry(geometric_errors), set at initialisation */
    double placements[84];
    /* the last step's inputs tau[6], tau_ext[6]: the lazily computed outputs use them */
    double step_inputs[12];
    /* 1: qdd (and the rigid model's tau_gear) are not computed for the current state yet */
    int outputs_stale;
    /* elastic: the qdd output (links at x with step_inputs' tau_ext) holds for the next step's
     * first RK4 stage */
    int link_qdd_valid;
    /* end stops: per joint, in contact at the end of the last sub-step, contacts so far, the
     * last onset's speed (rad/s) and time (s), the largest penetration (rad) */
    int in_contact[6];
    int contacts[6];
    double impact_speed[6];
    double impact_time[6];
    double max_penetration[6];
} ModelState;

#endif
