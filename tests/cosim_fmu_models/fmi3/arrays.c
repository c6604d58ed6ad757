/* Test FMU "Arrays3": y[i](t+h) = y[i](t) + k[i] * u[i](t) * h with arrays, a 2x2 output and a Float32 sum. */
#include <stddef.h>
#include "test_model.h"

struct ModelData {
    double u[3], k[3], y[3], y0, M[2][2], time;
    float total;
};

const char *const MODEL_TOKEN = "{5d1c8e2a-0001-4a3b-9c11-a77a1f3e0001}";
const size_t MODEL_DATA_SIZE = sizeof(struct ModelData);
const VarInfo MODEL_VARS[] = {
    {0, T_FLOAT64, 1, offsetof(struct ModelData, time), SET_NEVER, "time"},
    {1, T_FLOAT64, 3, offsetof(struct ModelData, u), SET_INPUT, "u"},
    {2, T_FLOAT64, 3, offsetof(struct ModelData, k), SET_PARAMETER, "k"},
    {3, T_FLOAT64, 3, offsetof(struct ModelData, y), SET_NEVER, "y"},
    {4, T_FLOAT32, 1, offsetof(struct ModelData, total), SET_NEVER, "total"},
    {5, T_FLOAT64, 4, offsetof(struct ModelData, M), SET_NEVER, "M"},
    {6, T_FLOAT64, 1, offsetof(struct ModelData, y0), SET_PARAMETER, "y0"},
};
const size_t N_MODEL_VARS = sizeof MODEL_VARS / sizeof MODEL_VARS[0];

static void outputs(ModelData *m, double t)
{
    m->time = t;
    m->total = (float)(m->y[0] + m->y[1] + m->y[2]);
    m->M[0][0] = m->y[0];
    m->M[0][1] = m->y[1];
    m->M[1][0] = m->y[2];
    m->M[1][1] = t;
}

void model_start(ModelData *m)
{
    for (int i = 0; i < 3; ++i) { m->u[i] = 0.0; m->k[i] = (double)(i + 1); }
    m->y0 = 0.5;
}

int model_initialize(ModelData *m, double t)
{
    for (int i = 0; i < 3; ++i) m->y[i] = m->y0;
    outputs(m, t);
    return 0;
}

int model_step(ModelData *m, double t, double h, int *event, int *terminate)
{
    (void)event; (void)terminate;
    for (int i = 0; i < 3; ++i) m->y[i] += m->k[i] * m->u[i] * h;
    outputs(m, t + h);
    return 0;
}

void model_update_discrete(ModelData *m, int *terminate) { (void)m; (void)terminate; }
void model_enter_step_mode(ModelData *m) { (void)m; }
