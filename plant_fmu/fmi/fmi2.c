/* FMI 2.0 Co-Simulation and Model Exchange, translated onto fmu_instance.h. */
#include <string.h>

#include "fmi2Functions.h"
#include "fmu_instance.h"

#define INST ((Instance *)c)
#define STATUS(call) ((fmi2Status)(call))

static void log_fmi2(const Instance *inst, Status status, const char *category,
                     const char *message)
{
    const fmi2CallbackFunctions *cb = inst->callbacks;
    if (cb && cb->logger)
        cb->logger(inst->environment, inst->name, (fmi2Status)status, category, "%s", message);
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[])
{
    (void)nCategories;
    (void)categories;
    INST->logging_on = loggingOn;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn)
{
    (void)fmuResourceLocation;
    (void)visible;
    return instance_new(instanceName, fmuGUID, fmuType == fmi2CoSimulation, loggingOn, log_fmi2,
                        functions ? functions->componentEnvironment : NULL, functions, NULL);
}

void fmi2FreeInstance(fmi2Component c) { instance_free(INST); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    INST->start_time = startTime;
    INST->state.v[VR_time] = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    return STATUS(instance_enter_initialization(INST, INST->start_time));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    return STATUS(instance_exit_initialization(INST));
}

fmi2Status fmi2Terminate(fmi2Component c) { return STATUS(instance_terminate(INST)); }
fmi2Status fmi2Reset(fmi2Component c) { return STATUS(instance_reset(INST)); }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[])
{
    return STATUS(instance_get_float64(INST, vr, nvr, value));
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[])
{
    return STATUS(instance_set_float64(INST, vr, nvr, value));
}

/* Integer, Boolean and String: this FMU has none. Zero references is a valid no-op. */
#define NO_VARIABLES_OF_TYPE(function, type)                                              \
    fmi2Status function(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, type value) \
    {                                                                                     \
        (void)vr;                                                                         \
        (void)value;                                                                      \
        return nvr == 0 ? fmi2OK : STATUS(instance_unsupported(INST, #function));         \
    }
NO_VARIABLES_OF_TYPE(fmi2GetInteger, fmi2Integer *)
NO_VARIABLES_OF_TYPE(fmi2GetBoolean, fmi2Boolean *)
NO_VARIABLES_OF_TYPE(fmi2GetString, fmi2String *)
NO_VARIABLES_OF_TYPE(fmi2SetInteger, const fmi2Integer *)
NO_VARIABLES_OF_TYPE(fmi2SetBoolean, const fmi2Boolean *)
NO_VARIABLES_OF_TYPE(fmi2SetString, const fmi2String *)

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    return STATUS(instance_get_state(INST, FMUstate));
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate)
{
    return STATUS(instance_set_state(INST, FMUstate));
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    return STATUS(instance_free_state(INST, FMUstate));
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size)
{
    (void)c;
    (void)FMUstate;
    *size = instance_serialized_size();
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size)
{
    return STATUS(instance_serialize(INST, FMUstate, (unsigned char *)serializedState, size));
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate)
{
    return STATUS(instance_deserialize(INST, (const unsigned char *)serializedState, size,
                                       FMUstate));
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[])
{
    return STATUS(instance_directional_derivative(INST, vUnknown_ref, nUnknown, vKnown_ref, nKnown,
                                                  dvKnown, dvUnknown));
}

/* Model Exchange */

fmi2Status fmi2EnterEventMode(fmi2Component c)
{
    (void)c;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo)
{
    (void)c;
    memset(eventInfo, 0, sizeof *eventInfo); /* no events: nothing ever changes discretely */
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c)
{
    (void)c;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation)
{
    (void)c;
    (void)noSetFMUStatePriorToCurrentPoint;
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) { return STATUS(instance_set_time(INST, time)); }

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx)
{
    return STATUS(instance_set_states(INST, x, nx));
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx)
{
    return STATUS(instance_get_derivatives(INST, derivatives, nx));
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni)
{
    (void)eventIndicators;
    return ni == 0 ? fmi2OK : STATUS(instance_unsupported(INST, "fmi2GetEventIndicators"));
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx)
{
    return STATUS(instance_get_states(INST, x, nx));
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx)
{
    return STATUS(instance_get_nominals(INST, x_nominal, nx));
}

/* Co-Simulation */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr;
    (void)order;
    (void)value;
    return nvr == 0 ? fmi2OK
                    : STATUS(instance_unsupported(INST, "fmi2SetRealInputDerivatives"));
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    (void)vr;
    (void)order;
    (void)value;
    return nvr == 0 ? fmi2OK
                    : STATUS(instance_unsupported(INST, "fmi2GetRealOutputDerivatives"));
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    return STATUS(instance_do_step(INST, currentCommunicationPoint, communicationStepSize));
}

fmi2Status fmi2CancelStep(fmi2Component c) { return STATUS(instance_unsupported(INST, "fmi2CancelStep")); }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    (void)s;
    (void)value;
    return STATUS(instance_unsupported(INST, "fmi2GetStatus"));
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    if (s == fmi2LastSuccessfulTime) {
        *value = INST->state.v[VR_time];
        return fmi2OK;
    }
    return STATUS(instance_unsupported(INST, "fmi2GetRealStatus"));
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)s;
    (void)value;
    return STATUS(instance_unsupported(INST, "fmi2GetIntegerStatus"));
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    (void)s;
    (void)value;
    return STATUS(instance_unsupported(INST, "fmi2GetBooleanStatus"));
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    (void)s;
    (void)value;
    return STATUS(instance_unsupported(INST, "fmi2GetStringStatus"));
}
