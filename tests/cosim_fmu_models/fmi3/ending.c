/* Test FMU "Ending3": integrates its input, ticks an output clock every `period` steps (event mode),
 * publishes a Binary frame, and ends the simulation itself at t_end (terminateSimulation; with
 * discard = true it returns fmi3Discard as well; with early = true it returns early from fmi3DoStep
 * at t_end instead, although the importer did not allow that). */
#include <stddef.h>
#include <string.h>
#include "test_model.h"

struct ModelData {
    double time, t_end, u, z;
    fmi3Boolean discard, early;
    int32_t period, steps, ticks;
    fmi3Clock tick;
    BinaryValue frame;
};

const char *const MODEL_TOKEN = "{5d1c8e2a-0003-4a3b-9c11-a77a1f3e0003}";
const size_t MODEL_DATA_SIZE = sizeof(struct ModelData);
#define V(vr, T, f, s) {vr, T, 1, offsetof(struct ModelData, f), s, #f}
const VarInfo MODEL_VARS[] = {
    V(0, T_FLOAT64, time, SET_NEVER), V(1, T_FLOAT64, t_end, SET_PARAMETER), V(2, T_BOOLEAN, discard, SET_PARAMETER),
    V(3, T_INT32, period, SET_PARAMETER), V(4, T_FLOAT64, u, SET_INPUT), V(5, T_FLOAT64, z, SET_NEVER),
    V(6, T_INT32, ticks, SET_NEVER), V(7, T_CLOCK, tick, SET_NEVER), V(8, T_BINARY, frame, SET_NEVER),
    V(9, T_BOOLEAN, early, SET_PARAMETER),
};
const size_t N_MODEL_VARS = sizeof MODEL_VARS / sizeof MODEL_VARS[0];

static void pack(ModelData *m)
{
    m->frame.size = 8;
    for (int b = 0; b < 4; ++b) {
        m->frame.bytes[b] = (fmi3Byte)((uint32_t)m->steps >> (8 * b));
        m->frame.bytes[4 + b] = (fmi3Byte)((uint32_t)m->ticks >> (8 * b));
    }
}

void model_start(ModelData *m)
{
    m->t_end = 0.35;
    m->discard = 0;
    m->period = 5;
}

int model_initialize(ModelData *m, double t)
{
    if (m->period < 1) return 1;
    m->time = t;
    m->z = 0.0;
    m->steps = m->ticks = 0;
    pack(m);
    return 0;
}

int model_step(ModelData *m, double t, double h, int *event, int *terminate)
{
    m->z += m->u * h;
    m->time = t + h;
    m->steps += 1;
    if (m->steps % m->period == 0) {
        m->ticks += 1;
        m->tick = 1;
        *event = 1;
    }
    pack(m);
    if (m->time >= m->t_end - 1e-12) {
        if (m->early) return 4; /* returns early instead of ending (a master must refuse that) */
        *terminate = 1;
        return m->discard ? 2 : 0;
    }
    return 0;
}

void model_update_discrete(ModelData *m, int *terminate) { (void)m; (void)terminate; }
void model_enter_step_mode(ModelData *m) { m->tick = 0; }
