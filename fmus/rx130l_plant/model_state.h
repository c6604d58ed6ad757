/* Internal state of the arm plant (see rx130l_plant.c). Plain data only. */
#ifndef MODEL_STATE_H
#define MODEL_STATE_H

/* rx130l_plant.c computes its outputs in Initialization Mode (model_initial_outputs) */
#define MODEL_INITIAL_OUTPUTS 1

typedef struct {
    /* q[6] (rad), qd[6] (rad/s) of the links, then (elastic joints only) the motor
     * angles th[6] (rad) and speeds thd[6] (rad/s) divided by the gear ratios; joint 1 first */
    double x[24];
    /* joint 1..6 and flange placements (rotation row by row, translation) with the
     * geometric_errors folded in: rx130l_plant_geometry(geometric_errors), set at initialisation */
    double placements[84];
} ModelState;

#endif
