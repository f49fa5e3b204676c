/*
 * The contract between a model and the FMI glue (fmu_instance.c, fmi2.c, fmi3.c), which
 * knows no model: what it needs of one is here and in the model's generated variables.h
 * (plant_fmu/description.py, from the model's one variable table):
 *
 *   N_VARIABLES, the VARIABLES table (name, unit, kind, value check, start, and whether
 *   model_update_outputs computes it), VR_time, N_STATES with STATE_VRS and DERIVATIVE_VRS
 *   (the continuous states and their derivatives, in order), MODEL_IDENTIFIER_STRING and
 *   INSTANTIATION_TOKEN.
 *
 * A model (plant_fmu/models/<name>/model.c) implements the functions below; the glue sets
 * start values, checks every value against the table, and copies states and derivatives.
 */
#ifndef MODEL_H
#define MODEL_H

#include <stddef.h>
#include "variables.h"

/* Everything that makes up the FMU state: get/set/serialize copy this struct. */
typedef struct {
    double v[N_VARIABLES]; /* every variable by value reference; v[VR_time] is time */
    int outputs_current;   /* the computed variables are up to date with v */
} ModelState;

/* The states from their initial-value parameters (after a reset or a parameter change). */
void model_apply_initial_state(ModelState *s);

/* 1 if the parameters, each already within its table's range, make a valid model; else 0
 * and a message saying why and what to change. */
int model_check_parameters(const ModelState *s, char *msg, size_t len);

/* Bring the computed variables (outputs and derivatives) up to date with the states and
 * inputs. 0 and a message if they cannot be computed. */
int model_update_outputs(ModelState *s, char *msg, size_t len);

/* Integrate from time to time + h, landing exactly on time + h. On failure the state is
 * left unchanged, 0 is returned and msg says why. */
int model_do_step(ModelState *s, double h, char *msg, size_t len);

/* sensitivity = d(unknowns)/d(knowns) * seed, knowns being states or inputs. 0 and a
 * message for a known or unknown the model cannot differentiate. */
int model_directional_derivative(const ModelState *s, const unsigned *unknowns, size_t n_unknowns,
                                 const unsigned *knowns, size_t n_knowns, const double *seed,
                                 double *sensitivity, char *msg, size_t len);

#endif
