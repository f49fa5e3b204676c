/* FMI 3.0 Co-Simulation and Model Exchange, translated onto fmu_instance.h. */
#include "fmi3Functions.h"
#include "fmu_instance.h"

#define INST ((Instance *)instance)
#define STATUS(call) ((fmi3Status)(call))

static void log_fmi3(const Instance *inst, Status status, const char *category,
                     const char *message)
{
    fmi3LogMessageCallback logger = (fmi3LogMessageCallback)inst->log_message;
    if (logger) logger(inst->environment, (fmi3Status)status, category, message);
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[])
{
    (void)nCategories;
    (void)categories;
    INST->logging_on = loggingOn;
    return fmi3OK;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage)
{
    (void)resourcePath;
    (void)visible;
    return instance_new(instanceName, instantiationToken, 0, loggingOn, log_fmi3,
                        instanceEnvironment, NULL, (void (*)(void))logMessage);
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate)
{
    (void)resourcePath;
    (void)visible;
    (void)eventModeUsed;
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;
    return instance_new(instanceName, instantiationToken, 1, loggingOn, log_fmi3,
                        instanceEnvironment, NULL, (void (*)(void))logMessage);
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption)
{
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    (void)clockUpdate;
    (void)lockPreemption;
    (void)unlockPreemption;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "Scheduled Execution is not supported: use Co-Simulation or Model Exchange");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) { instance_free(INST); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    return STATUS(instance_enter_initialization(INST, startTime));
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance)
{
    return STATUS(instance_exit_initialization(INST));
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance)
{
    (void)instance;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance instance) { return STATUS(instance_terminate(INST)); }
fmi3Status fmi3Reset(fmi3Instance instance) { return STATUS(instance_reset(INST)); }

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues)
{
    if (nValues != nValueReferences) /* all variables are scalars */
        return STATUS(instance_error(INST, "fmi3GetFloat64: %zu values for %zu scalar "
                                     "variables", nValues, nValueReferences));
    return STATUS(instance_get_float64(INST, valueReferences, nValueReferences, values));
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues)
{
    if (nValues != nValueReferences)
        return STATUS(instance_error(INST, "fmi3SetFloat64: %zu values for %zu scalar "
                                     "variables", nValues, nValueReferences));
    return STATUS(instance_set_float64(INST, valueReferences, nValueReferences, values));
}

/* Features this FMU does not have: variables of other types, binaries, clocks, configuration
 * mode, variable dependencies. FMI fixes each signature, so the parameters after the instance
 * are spelled out here; by definition they go unused. */
#if defined(__GNUC__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wunused-parameter"
#endif

/* Refused, with a logged message naming the call. */
#define UNSUPPORTED(function, ...)                                                            \
    fmi3Status function(fmi3Instance instance, __VA_ARGS__)                                   \
    {                                                                                         \
        return STATUS(instance_unsupported(INST, #function));                                 \
    }
#define UNSUPPORTED_MODE(function)                                                            \
    fmi3Status function(fmi3Instance instance)                                                \
    {                                                                                         \
        return STATUS(instance_unsupported(INST, #function));                                 \
    }
/* Variables of a type this FMU has none of: asking for none is a valid no-op. */
#define NO_VARIABLES(function, ...)                                                           \
    fmi3Status function(fmi3Instance instance, const fmi3ValueReference valueReferences[],    \
                        size_t nValueReferences, __VA_ARGS__)                                 \
    {                                                                                         \
        return nValueReferences == 0 ? fmi3OK                                                 \
                                     : STATUS(instance_unsupported(INST, #function));         \
    }

NO_VARIABLES(fmi3GetFloat32, fmi3Float32 values[], size_t nValues)
NO_VARIABLES(fmi3GetInt8, fmi3Int8 values[], size_t nValues)
NO_VARIABLES(fmi3GetUInt8, fmi3UInt8 values[], size_t nValues)
NO_VARIABLES(fmi3GetInt16, fmi3Int16 values[], size_t nValues)
NO_VARIABLES(fmi3GetUInt16, fmi3UInt16 values[], size_t nValues)
NO_VARIABLES(fmi3GetInt32, fmi3Int32 values[], size_t nValues)
NO_VARIABLES(fmi3GetUInt32, fmi3UInt32 values[], size_t nValues)
NO_VARIABLES(fmi3GetInt64, fmi3Int64 values[], size_t nValues)
NO_VARIABLES(fmi3GetUInt64, fmi3UInt64 values[], size_t nValues)
NO_VARIABLES(fmi3GetBoolean, fmi3Boolean values[], size_t nValues)
NO_VARIABLES(fmi3GetString, fmi3String values[], size_t nValues)
NO_VARIABLES(fmi3GetBinary, size_t valueSizes[], fmi3Binary values[], size_t nValues)
NO_VARIABLES(fmi3SetFloat32, const fmi3Float32 values[], size_t nValues)
NO_VARIABLES(fmi3SetInt8, const fmi3Int8 values[], size_t nValues)
NO_VARIABLES(fmi3SetUInt8, const fmi3UInt8 values[], size_t nValues)
NO_VARIABLES(fmi3SetInt16, const fmi3Int16 values[], size_t nValues)
NO_VARIABLES(fmi3SetUInt16, const fmi3UInt16 values[], size_t nValues)
NO_VARIABLES(fmi3SetInt32, const fmi3Int32 values[], size_t nValues)
NO_VARIABLES(fmi3SetUInt32, const fmi3UInt32 values[], size_t nValues)
NO_VARIABLES(fmi3SetInt64, const fmi3Int64 values[], size_t nValues)
NO_VARIABLES(fmi3SetUInt64, const fmi3UInt64 values[], size_t nValues)
NO_VARIABLES(fmi3SetBoolean, const fmi3Boolean values[], size_t nValues)
NO_VARIABLES(fmi3SetString, const fmi3String values[], size_t nValues)
NO_VARIABLES(fmi3SetBinary, const size_t valueSizes[], const fmi3Binary values[],
             size_t nValues)

UNSUPPORTED(fmi3GetClock, const fmi3ValueReference valueReferences[], size_t nValueReferences,
            fmi3Clock values[])
UNSUPPORTED(fmi3SetClock, const fmi3ValueReference valueReferences[], size_t nValueReferences,
            const fmi3Clock values[])
UNSUPPORTED(fmi3GetIntervalDecimal, const fmi3ValueReference valueReferences[],
            size_t nValueReferences, fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
UNSUPPORTED(fmi3GetIntervalFraction, const fmi3ValueReference valueReferences[],
            size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
            fmi3IntervalQualifier qualifiers[])
UNSUPPORTED(fmi3GetShiftDecimal, const fmi3ValueReference valueReferences[],
            size_t nValueReferences, fmi3Float64 shifts[])
UNSUPPORTED(fmi3GetShiftFraction, const fmi3ValueReference valueReferences[],
            size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[])
UNSUPPORTED(fmi3SetIntervalDecimal, const fmi3ValueReference valueReferences[],
            size_t nValueReferences, const fmi3Float64 intervals[])
UNSUPPORTED(fmi3SetIntervalFraction, const fmi3ValueReference valueReferences[],
            size_t nValueReferences, const fmi3UInt64 counters[],
            const fmi3UInt64 resolutions[])
UNSUPPORTED(fmi3SetShiftDecimal, const fmi3ValueReference valueReferences[],
            size_t nValueReferences, const fmi3Float64 shifts[])
UNSUPPORTED(fmi3SetShiftFraction, const fmi3ValueReference valueReferences[],
            size_t nValueReferences, const fmi3UInt64 counters[],
            const fmi3UInt64 resolutions[])
UNSUPPORTED(fmi3ActivateModelPartition, fmi3ValueReference clockReference,
            fmi3Float64 activationTime)
UNSUPPORTED(fmi3GetNumberOfVariableDependencies, fmi3ValueReference valueReference,
            size_t *nDependencies)
UNSUPPORTED(fmi3GetVariableDependencies, fmi3ValueReference dependent,
            size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
            size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
            size_t nDependencies)
UNSUPPORTED_MODE(fmi3EnterConfigurationMode)
UNSUPPORTED_MODE(fmi3ExitConfigurationMode)

#if defined(__GNUC__)
#pragma GCC diagnostic pop
#endif

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance)
{
    (void)instance;
    return fmi3OK;
}

/* FMU state */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    return STATUS(instance_get_state(INST, FMUState));
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState)
{
    return STATUS(instance_set_state(INST, FMUState));
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    return STATUS(instance_free_state(INST, FMUState));
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size)
{
    (void)instance;
    (void)FMUState;
    *size = instance_serialized_size();
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size)
{
    return STATUS(instance_serialize(INST, FMUState, serializedState, size));
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState)
{
    return STATUS(instance_deserialize(INST, serializedState, size, FMUState));
}

/* Derivatives */

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[],
                                        size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity)
{
    if (nSeed != nKnowns || nSensitivity != nUnknowns)
        return STATUS(instance_error(INST, "fmi3GetDirectionalDerivative: nSeed must equal "
                                     "nKnowns and nSensitivity nUnknowns (scalar variables)"));
    return STATUS(instance_directional_derivative(INST, unknowns, nUnknowns, knowns, nKnowns,
                                                  seed, sensitivity));
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns;
    (void)nUnknowns;
    (void)knowns;
    (void)nKnowns;
    (void)seed;
    (void)nSeed;
    (void)sensitivity;
    (void)nSensitivity;
    return STATUS(instance_unsupported(INST, "fmi3GetAdjointDerivative"));
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[],
                                    fmi3Float64 values[], size_t nValues)
{
    (void)valueReferences;
    (void)orders;
    (void)values;
    (void)nValues;
    return nValueReferences == 0 ? fmi3OK
                                 : STATUS(instance_unsupported(INST, "fmi3GetOutputDerivatives"));
}

/* Model Exchange */

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance)
{
    (void)instance;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation)
{
    (void)instance;
    (void)noSetFMUStatePriorToCurrentPoint;
    *enterEventMode = fmi3False;
    *terminateSimulation = fmi3False;
    return fmi3OK;
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime)
{
    (void)instance;
    *discreteStatesNeedUpdate = fmi3False;
    *terminateSimulation = fmi3False;
    *nominalsOfContinuousStatesChanged = fmi3False;
    *valuesOfContinuousStatesChanged = fmi3False;
    *nextEventTimeDefined = fmi3False;
    *nextEventTime = 0.0;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time)
{
    return STATUS(instance_set_time(INST, time));
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates)
{
    return STATUS(instance_set_states(INST, continuousStates, nContinuousStates));
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates)
{
    return STATUS(instance_get_derivatives(INST, derivatives, nContinuousStates));
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators)
{
    (void)eventIndicators;
    return nEventIndicators == 0 ? fmi3OK
                                 : STATUS(instance_unsupported(INST, "fmi3GetEventIndicators"));
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates)
{
    return STATUS(instance_get_states(INST, continuousStates, nContinuousStates));
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates)
{
    return STATUS(instance_get_nominals(INST, nominals, nContinuousStates));
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators)
{
    (void)instance;
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates)
{
    (void)instance;
    *nContinuousStates = N_STATES;
    return fmi3OK;
}

/* Co-Simulation */

fmi3Status fmi3EnterStepMode(fmi3Instance instance)
{
    (void)instance;
    return fmi3OK;
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    const fmi3Status status =
        STATUS(instance_do_step(INST, currentCommunicationPoint, communicationStepSize));
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = INST->state.v[VR_time];
    return status;
}
