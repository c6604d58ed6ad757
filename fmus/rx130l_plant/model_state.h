/* Internal state of the arm plant (see rx130l_plant.c). Plain data only. */
#ifndef MODEL_STATE_H
#define MODEL_STATE_H

/* rx130l_plant.c computes its outputs in Initialization Mode (model_initial_outputs) */
#define MODEL_INITIAL_OUTPUTS 1

typedef struct {
    /* q[6] (rad), qd[6] (rad/s) of the links, then (elastic joints only) the motor
     * angles th[6] (rad) and speeds thd[6] (rad/s) divided by the gear ratios; joint 1 first */
    double x[24];
    /* elastic joints: the 78 dynamic parameters with rotor inertia and friction zeroed
     * (they act on the motor side and through f_link) - the link side's ABA parameters */
    double p_link[78];
} ModelState;

#endif
