/*
 * A tiny table-driven FMI 3.0 co-simulation framework for the master's test FMUs.
 *
 * Each test model (arrays.c, integers.c, ending.c) defines its data struct `ModelData`,
 * the table MODEL_VARS of its variables (value reference, type, element count, offset in
 * ModelData, who may set it) and the model_* functions below; test_model.c implements
 * the FMI 3.0 API on top (mode checks, get/set by type, event mode, clocks, binaries).
 */
#ifndef TEST_MODEL_H
#define TEST_MODEL_H

#include <stddef.h>
#include "fmi3Functions.h"

typedef enum { T_FLOAT32, T_FLOAT64, T_INT8, T_UINT8, T_INT16, T_UINT16, T_INT32, T_UINT32, T_INT64,
               T_UINT64, T_BOOLEAN, T_BINARY, T_CLOCK } VarType;

enum { SET_NEVER = 0, SET_INPUT = 1, SET_PARAMETER = 2 };

typedef struct {
    fmi3ValueReference vr;
    VarType type;
    size_t count;   /* array elements (1 for a scalar) */
    size_t offset;  /* offsetof(ModelData, field); a Binary is a BinaryValue */
    int settable;
    const char *name;
} VarInfo;

#define BINARY_CAPACITY 64
typedef struct {
    size_t size;
    fmi3Byte bytes[BINARY_CAPACITY];
} BinaryValue;

typedef struct ModelData ModelData;

extern const VarInfo MODEL_VARS[];
extern const size_t N_MODEL_VARS;
extern const size_t MODEL_DATA_SIZE;
extern const char *const MODEL_TOKEN;

/* start values */
void model_start(ModelData *m);
/* leaving initialization mode: outputs at the start time; 0 on success */
int model_initialize(ModelData *m, double t);
/* one step t -> t + h; set *event when a clock ticks (event mode wanted), *terminate
 * to end the simulation; return 0 (OK), 2 (Discard), 3 (Error) or 4 (return early at t + h/2) */
int model_step(ModelData *m, double t, double h, int *event, int *terminate);
/* event mode: fmi3UpdateDiscreteStates; set *terminate to end */
void model_update_discrete(ModelData *m, int *terminate);
/* after the event iteration (fmi3EnterStepMode): deactivate clocks */
void model_enter_step_mode(ModelData *m);

#endif
