/*
 * What FMI 2.0 and FMI 3.0 share: an instance with a mode, a logger, checked get/set of
 * Float64 variables by value reference, stepping, and FMU state handling. fmi2.c and
 * fmi3.c translate their API onto these calls; the model is behind model.h.
 */
#ifndef FMU_INSTANCE_H
#define FMU_INSTANCE_H

#include <stddef.h>
#include "model.h"

/* Same numbering as fmi2Status and fmi3Status. */
typedef enum { STATUS_OK, STATUS_WARNING, STATUS_DISCARD, STATUS_ERROR, STATUS_FATAL } Status;

typedef enum {
    MODE_INSTANTIATED,
    MODE_INITIALIZATION,
    MODE_RUNNING, /* step mode (CS) or event/continuous-time mode (ME) */
    MODE_TERMINATED,
} Mode;

typedef struct Instance Instance;

/* Forwards one formatted message to the importer's logger (FMI-version specific). */
typedef void (*LogFunction)(const Instance *inst, Status status, const char *category,
                            const char *message);

struct Instance {
    ModelState state;
    char *name;
    int is_cosimulation;
    int logging_on;
    Mode mode;
    double start_time;
    LogFunction log;
    void *environment;             /* the importer's environment pointer */
    const void *callbacks;         /* FMI 2: the importer's fmi2CallbackFunctions */
    void (*log_message)(void);     /* FMI 3: the importer's logMessage, cast back by fmi3.c */
};

/* Serialized FMU state: this header, then the ModelState bytes. */
typedef struct {
    char token[64];
    size_t state_size;
} SerializedHeader;

Instance *instance_new(const char *name, const char *token, int is_cosimulation, int logging_on,
                       LogFunction log, void *environment, const void *callbacks,
                       void (*log_message)(void));
void instance_free(Instance *inst);

Status instance_error(const Instance *inst, const char *format, ...);
void instance_event(const Instance *inst, const char *format, ...);

Status instance_enter_initialization(Instance *inst, double start_time);
Status instance_exit_initialization(Instance *inst);
Status instance_terminate(Instance *inst);
Status instance_reset(Instance *inst);

Status instance_get_float64(Instance *inst, const unsigned *vr, size_t n, double *value);
Status instance_set_float64(Instance *inst, const unsigned *vr, size_t n, const double *value);

Status instance_do_step(Instance *inst, double current_time, double step);

Status instance_set_time(Instance *inst, double time);
Status instance_set_states(Instance *inst, const double *x, size_t n);
Status instance_get_states(Instance *inst, double *x, size_t n);
Status instance_get_derivatives(Instance *inst, double *dx, size_t n);
Status instance_get_nominals(Instance *inst, double *nominals, size_t n);

Status instance_directional_derivative(Instance *inst, const unsigned *unknowns, size_t n_unknowns,
                                       const unsigned *knowns, size_t n_knowns,
                                       const double *seed, double *sensitivity);

Status instance_get_state(Instance *inst, void **state);
Status instance_set_state(Instance *inst, const void *state);
Status instance_free_state(Instance *inst, void **state);
size_t instance_serialized_size(void);
Status instance_serialize(Instance *inst, const void *state, unsigned char *bytes, size_t size);
Status instance_deserialize(Instance *inst, const unsigned char *bytes, size_t size, void **state);

/* Returned by the functions of types and features this FMU does not have. */
Status instance_unsupported(const Instance *inst, const char *function);

#endif
