/* Test FMU "Integers3": one input and one output of every FMI 3.0 integer type, Boolean and Float32.
 * Each output is its input plus the number of steps taken, computed in the variable's own type. */
#include <stddef.h>
#include <stdint.h>
#include "test_model.h"

struct ModelData {
    double time, sum;
    int8_t i8, o_i8;
    uint8_t u8, o_u8;
    int16_t i16, o_i16, iv[2];
    uint16_t u16, o_u16;
    int32_t i32, o_i32, count;
    uint32_t u32, o_u32;
    int64_t i64, o_i64;
    uint64_t u64, o_u64;
    fmi3Boolean b, nb;
    float x, o_x;
};

const char *const MODEL_TOKEN = "{5d1c8e2a-0002-4a3b-9c11-a77a1f3e0002}";
const size_t MODEL_DATA_SIZE = sizeof(struct ModelData);
#define V(vr, T, f, s) {vr, T, 1, offsetof(struct ModelData, f), s, #f}
const VarInfo MODEL_VARS[] = {
    V(0, T_FLOAT64, time, SET_NEVER),
    V(1, T_INT8, i8, SET_INPUT), V(2, T_UINT8, u8, SET_INPUT), V(3, T_INT16, i16, SET_INPUT),
    V(4, T_UINT16, u16, SET_INPUT), V(5, T_INT32, i32, SET_INPUT), V(6, T_UINT32, u32, SET_INPUT),
    V(7, T_INT64, i64, SET_INPUT), V(8, T_UINT64, u64, SET_INPUT), V(9, T_BOOLEAN, b, SET_INPUT),
    V(10, T_FLOAT32, x, SET_INPUT),
    V(11, T_INT8, o_i8, SET_NEVER), V(12, T_UINT8, o_u8, SET_NEVER), V(13, T_INT16, o_i16, SET_NEVER),
    V(14, T_UINT16, o_u16, SET_NEVER), V(15, T_INT32, o_i32, SET_NEVER), V(16, T_UINT32, o_u32, SET_NEVER),
    V(17, T_INT64, o_i64, SET_NEVER), V(18, T_UINT64, o_u64, SET_NEVER),
    V(21, T_INT32, count, SET_NEVER), V(22, T_FLOAT64, sum, SET_NEVER), V(23, T_BOOLEAN, nb, SET_NEVER),
    V(24, T_FLOAT32, o_x, SET_NEVER),
    {25, T_INT16, 2, offsetof(struct ModelData, iv), SET_NEVER, "iv"},
};
const size_t N_MODEL_VARS = sizeof MODEL_VARS / sizeof MODEL_VARS[0];

static void outputs(ModelData *m, double t)
{
    int32_t n = m->count;
    m->time = t;
    m->o_i8 = (int8_t)(m->i8 + n);
    m->o_u8 = (uint8_t)(m->u8 + n);
    m->o_i16 = (int16_t)(m->i16 + n);
    m->o_u16 = (uint16_t)(m->u16 + n);
    m->o_i32 = m->i32 + n;
    m->o_u32 = m->u32 + (uint32_t)n;
    m->o_i64 = m->i64 + n;
    m->o_u64 = m->u64 + (uint64_t)n;
    m->nb = !m->b;
    m->o_x = 2.0f * m->x;
    m->iv[0] = (int16_t)n;
    m->iv[1] = (int16_t)-n;
    m->sum = (double)m->i8 + m->u8 + m->i16 + m->u16 + m->i32 + (double)m->u32 + (double)m->i64 + (double)m->u64
             + (m->b ? 1.0 : 0.0) + (double)m->x;
}

void model_start(ModelData *m) { (void)m; }

int model_initialize(ModelData *m, double t)
{
    m->count = 0;
    outputs(m, t);
    return 0;
}

int model_step(ModelData *m, double t, double h, int *event, int *terminate)
{
    (void)event; (void)terminate;
    m->count += 1;
    outputs(m, t + h);
    return 0;
}

void model_update_discrete(ModelData *m, int *terminate) { (void)m; (void)terminate; }
void model_enter_step_mode(ModelData *m) { (void)m; }
