/* Internal state of the arm plant (see rx130l_plant.c). Plain data only. */
#ifndef MODEL_STATE_H
#define MODEL_STATE_H

typedef struct {
    double x[12]; /* q[6] (rad), qd[6] (rad/s), joint 1 first */
} ModelState;

#endif
