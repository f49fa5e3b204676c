/* The FMI-version independent instance: see fmu_instance.h. It knows no model: what it
 * needs of one is in model.h and the model's generated variables.h. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu_instance.h"

#define MESSAGE_LENGTH 512

static void vlog(const Instance *inst, Status status, const char *category, const char *format,
                 va_list args)
{
    if (!inst || !inst->log) return;
    char message[MESSAGE_LENGTH];
    vsnprintf(message, sizeof message, format, args);
    inst->log(inst, status, category, message);
}

Status instance_error(const Instance *inst, const char *format, ...)
{
    va_list args;
    va_start(args, format);
    vlog(inst, STATUS_ERROR, "logStatusError", format, args); /* errors are always logged */
    va_end(args);
    return STATUS_ERROR;
}

void instance_event(const Instance *inst, const char *format, ...)
{
    if (!inst->logging_on) return;
    va_list args;
    va_start(args, format);
    vlog(inst, STATUS_OK, "logEvents", format, args);
    va_end(args);
}

/* Every variable at its start value, then the states from their initial values. */
static void reset_state(ModelState *s)
{
    for (int k = 0; k < N_VARIABLES; k++) s->v[k] = VARIABLES[k].start;
    model_apply_initial_state(s);
}

/* 1 if `value` is allowed for variable `vr` by its table entry; else 0 and a message. */
static int check_value(unsigned vr, double value, char *msg, size_t len)
{
    const VariableInfo *var = &VARIABLES[vr];
    const char *rule = NULL;
    switch (var->check) {
    case CHECK_NONE: return 1;
    case CHECK_FINITE: if (!isfinite(value)) rule = "a finite number"; break;
    case CHECK_POSITIVE: if (!(isfinite(value) && value > 0)) rule = "finite and > 0"; break;
    case CHECK_NONNEGATIVE: if (!(isfinite(value) && value >= 0)) rule = "finite and >= 0"; break;
    case CHECK_LIMIT: if (!(value > 0)) rule = "> 0 (inf: no limit)"; break;
    }
    if (!rule) return 1;
    snprintf(msg, len, "%s = %g is not valid: it must be %s (unit %s)", var->name, value, rule,
             var->unit);
    return 0;
}

Instance *instance_new(const char *name, const char *token, int is_cosimulation, int logging_on,
                       LogFunction log, void *environment, const void *callbacks,
                       void (*log_message)(void))
{
    Instance probe = {.name = (char *)(name ? name : MODEL_IDENTIFIER_STRING), .log = log,
                      .environment = environment, .callbacks = callbacks,
                      .log_message = log_message};
    if (!token || strcmp(token, INSTANTIATION_TOKEN) != 0) {
        instance_error(&probe, "instantiation token %s does not match this binary's %s: the "
                       "modelDescription.xml and the binary come from different builds",
                       token ? token : "(null)", INSTANTIATION_TOKEN);
        return NULL;
    }
    Instance *inst = calloc(1, sizeof *inst);
    if (!inst) return NULL;
    inst->name = malloc(strlen(probe.name) + 1);
    if (!inst->name) {
        free(inst);
        return NULL;
    }
    strcpy(inst->name, probe.name);
    inst->is_cosimulation = is_cosimulation;
    inst->logging_on = logging_on;
    inst->log = log;
    inst->environment = environment;
    inst->callbacks = callbacks;
    inst->log_message = log_message;
    inst->mode = MODE_INSTANTIATED;
    reset_state(&inst->state);
    return inst;
}

void instance_free(Instance *inst)
{
    if (!inst) return;
    free(inst->name);
    free(inst);
}

Status instance_enter_initialization(Instance *inst, double start_time)
{
    if (inst->mode != MODE_INSTANTIATED)
        return instance_error(inst, "enter initialization mode: only allowed after instantiate "
                              "or reset");
    inst->mode = MODE_INITIALIZATION;
    inst->start_time = start_time;
    inst->state.v[VR_time] = start_time;
    model_apply_initial_state(&inst->state);
    return STATUS_OK;
}

Status instance_exit_initialization(Instance *inst)
{
    char msg[MESSAGE_LENGTH];
    if (inst->mode != MODE_INITIALIZATION)
        return instance_error(inst, "exit initialization mode: not in initialization mode");
    for (unsigned vr = 0; vr < N_VARIABLES; vr++) {
        if (VARIABLES[vr].kind == KIND_PARAMETER && !check_value(vr, inst->state.v[vr], msg,
                                                                  sizeof msg))
            return instance_error(inst, "%s", msg);
    }
    if (!model_check_parameters(&inst->state, msg, sizeof msg)) return instance_error(inst, "%s", msg);
    model_apply_initial_state(&inst->state);
    inst->mode = MODE_RUNNING;
    instance_event(inst, "initialized at t = %g s", inst->state.v[VR_time]);
    return STATUS_OK;
}

Status instance_terminate(Instance *inst)
{
    inst->mode = MODE_TERMINATED;
    return STATUS_OK;
}

Status instance_reset(Instance *inst)
{
    reset_state(&inst->state);
    inst->mode = MODE_INSTANTIATED;
    return STATUS_OK;
}

Status instance_get_float64(Instance *inst, const unsigned *vr, size_t n, double *value)
{
    char msg[MESSAGE_LENGTH];
    int outputs_needed = 0;
    for (size_t k = 0; k < n; k++) {
        if (vr[k] >= N_VARIABLES)
            return instance_error(inst, "get: value reference %u does not exist (0..%d)", vr[k],
                                  N_VARIABLES - 1);
        outputs_needed |= VARIABLES[vr[k]].computed; /* computed on demand */
    }
    if (outputs_needed && !model_update_outputs(&inst->state, msg, sizeof msg))
        return instance_error(inst, "%s", msg);
    for (size_t k = 0; k < n; k++) value[k] = inst->state.v[vr[k]];
    return STATUS_OK;
}

Status instance_set_float64(Instance *inst, const unsigned *vr, size_t n, const double *value)
{
    char msg[MESSAGE_LENGTH];
    for (size_t k = 0; k < n; k++) { /* check everything before changing anything */
        if (vr[k] >= N_VARIABLES)
            return instance_error(inst, "set: value reference %u does not exist (0..%d)", vr[k],
                                  N_VARIABLES - 1);
        const VariableInfo *var = &VARIABLES[vr[k]];
        if (var->kind == KIND_PARAMETER) {
            if (inst->mode != MODE_INSTANTIATED && inst->mode != MODE_INITIALIZATION)
                return instance_error(inst, "set: %s is a fixed parameter and can only be set "
                                      "before initialization ends", var->name);
        } else if (var->kind != KIND_INPUT) {
            return instance_error(inst, "set: %s is not a parameter or an input and cannot be set",
                                  var->name);
        }
        if (!check_value(vr[k], value[k], msg, sizeof msg))
            return instance_error(inst, "set: %s", msg);
    }
    int parameters_changed = 0;
    for (size_t k = 0; k < n; k++) {
        inst->state.v[vr[k]] = value[k];
        parameters_changed |= VARIABLES[vr[k]].kind == KIND_PARAMETER;
    }
    if (parameters_changed) model_apply_initial_state(&inst->state);
    inst->state.outputs_current = 0;
    return STATUS_OK;
}

Status instance_do_step(Instance *inst, double current_time, double step)
{
    char msg[MESSAGE_LENGTH];
    if (inst->mode != MODE_RUNNING)
        return instance_error(inst, "doStep: not in step mode (initialize first)");
    if (!(step > 0) || !isfinite(step))
        return instance_error(inst, "doStep: step size %g s must be finite and > 0", step);
    const double time = inst->state.v[VR_time];
    if (fabs(current_time - time) > 1e-9 * (1.0 + fabs(time)))
        return instance_error(inst, "doStep: communication point %.17g s is not the FMU's "
                              "time %.17g s", current_time, time);
    const ModelState before = inst->state;
    inst->state.v[VR_time] = current_time; /* land exactly where the importer says */
    if (!model_do_step(&inst->state, step, msg, sizeof msg)) {
        inst->state = before;
        return instance_error(inst, "doStep: %s", msg);
    }
    for (int i = 0; i < N_STATES; i++) {
        if (!isfinite(inst->state.v[STATE_VRS[i]])) {
            const char *name = VARIABLES[STATE_VRS[i]].name;
            inst->state = before;
            return instance_error(inst, "doStep: %s became non-finite in the step from t = %g s "
                                  "to %g s", name, current_time, current_time + step);
        }
    }
    return STATUS_OK;
}

Status instance_set_time(Instance *inst, double time)
{
    inst->state.v[VR_time] = time;
    inst->state.outputs_current = 0;
    return STATUS_OK;
}

static Status check_state_count(Instance *inst, size_t n, const char *function)
{
    if (n != N_STATES)
        return instance_error(inst, "%s: %zu states requested, the model has %d", function, n,
                              N_STATES);
    return STATUS_OK;
}

Status instance_set_states(Instance *inst, const double *x, size_t n)
{
    if (check_state_count(inst, n, "set continuous states")) return STATUS_ERROR;
    for (size_t i = 0; i < n; i++)
        if (!isfinite(x[i]))
            return instance_error(inst, "set continuous states: %s = %g is not finite",
                                  VARIABLES[STATE_VRS[i]].name, x[i]);
    for (size_t i = 0; i < n; i++) inst->state.v[STATE_VRS[i]] = x[i];
    inst->state.outputs_current = 0;
    return STATUS_OK;
}

Status instance_get_states(Instance *inst, double *x, size_t n)
{
    if (check_state_count(inst, n, "get continuous states")) return STATUS_ERROR;
    for (size_t i = 0; i < n; i++) x[i] = inst->state.v[STATE_VRS[i]];
    return STATUS_OK;
}

Status instance_get_derivatives(Instance *inst, double *dx, size_t n)
{
    if (check_state_count(inst, n, "get derivatives")) return STATUS_ERROR;
    char msg[MESSAGE_LENGTH];
    if (!model_update_outputs(&inst->state, msg, sizeof msg))
        return instance_error(inst, "get derivatives: %s", msg);
    for (size_t i = 0; i < n; i++) dx[i] = inst->state.v[DERIVATIVE_VRS[i]];
    return STATUS_OK;
}

Status instance_get_nominals(Instance *inst, double *nominals, size_t n)
{
    if (check_state_count(inst, n, "get nominals")) return STATUS_ERROR;
    for (size_t i = 0; i < n; i++) nominals[i] = 1.0;
    return STATUS_OK;
}

Status instance_directional_derivative(Instance *inst, const unsigned *unknowns, size_t n_unknowns,
                                       const unsigned *knowns, size_t n_knowns,
                                       const double *seed, double *sensitivity)
{
    char msg[MESSAGE_LENGTH];
    if (!model_directional_derivative(&inst->state, unknowns, n_unknowns, knowns, n_knowns, seed,
                                      sensitivity, msg, sizeof msg))
        return instance_error(inst, "%s", msg);
    return STATUS_OK;
}

Status instance_get_state(Instance *inst, void **state)
{
    if (!*state) *state = malloc(sizeof(ModelState));
    if (!*state) return instance_error(inst, "get FMU state: out of memory");
    memcpy(*state, &inst->state, sizeof(ModelState));
    return STATUS_OK;
}

Status instance_set_state(Instance *inst, const void *state)
{
    if (!state) return instance_error(inst, "set FMU state: the state is NULL");
    memcpy(&inst->state, state, sizeof(ModelState));
    return STATUS_OK;
}

Status instance_free_state(Instance *inst, void **state)
{
    (void)inst;
    free(*state);
    *state = NULL;
    return STATUS_OK;
}

size_t instance_serialized_size(void)
{
    return sizeof(SerializedHeader) + sizeof(ModelState);
}

Status instance_serialize(Instance *inst, const void *state, unsigned char *bytes, size_t size)
{
    if (size < instance_serialized_size())
        return instance_error(inst, "serialize FMU state: buffer of %zu bytes, %zu needed", size,
                              instance_serialized_size());
    SerializedHeader header = {{0}, sizeof(ModelState)};
    strncpy(header.token, INSTANTIATION_TOKEN, sizeof header.token - 1);
    memcpy(bytes, &header, sizeof header);
    memcpy(bytes + sizeof header, state, sizeof(ModelState));
    return STATUS_OK;
}

Status instance_deserialize(Instance *inst, const unsigned char *bytes, size_t size, void **state)
{
    SerializedHeader header;
    if (size != instance_serialized_size())
        return instance_error(inst, "deserialize FMU state: %zu bytes, expected %zu", size,
                              instance_serialized_size());
    memcpy(&header, bytes, sizeof header);
    if (strncmp(header.token, INSTANTIATION_TOKEN, sizeof header.token) != 0 ||
        header.state_size != sizeof(ModelState))
        return instance_error(inst, "deserialize FMU state: the bytes come from another build");
    if (!*state) *state = malloc(sizeof(ModelState));
    if (!*state) return instance_error(inst, "deserialize FMU state: out of memory");
    memcpy(*state, bytes + sizeof header, sizeof(ModelState));
    return STATUS_OK;
}

Status instance_unsupported(const Instance *inst, const char *function)
{
    return instance_error(inst, "%s is not supported: this FMU has only Float64 variables and no "
                          "events or clocks", function);
}
