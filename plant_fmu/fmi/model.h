/*
 * The arm model: start values, parameter checks, Co-Simulation integration (RK4),
 * outputs and directional derivatives. Independent of the FMI version; the FMI glue
 * (fmu_instance.c, fmi2.c, fmi3.c) calls only what is declared here.
 */
#ifndef MODEL_H
#define MODEL_H

#include <stddef.h>
#include "variables.h"

#define N_STATES (2 * N_LINKS)

/* Everything that makes up the FMU state: get/set/serialize copy this struct. */
typedef struct {
    double v[N_VARIABLES]; /* every variable by value reference; v[VR_time] is time */
    int outputs_current;   /* M, energy and der(qdot) are up to date with v */
} ModelState;

/* Start values of every variable; states from q0, qdot0. */
void model_reset(ModelState *s);

/* States q, qdot from the parameters q0, qdot0. */
void model_apply_initial_state(ModelState *s);

/* 1 if `value` is allowed for variable `vr`; else 0 and a message naming it. */
int model_check_value(unsigned vr, double value, char *msg, size_t len);

/* 1 if all parameters are valid and M(q0) is positive definite; else 0 and a message. */
int model_check_parameters(const ModelState *s, char *msg, size_t len);

/* Bring M, energy and der(qdot) up to date with the state and inputs. 0 if M is singular. */
int model_update_outputs(ModelState *s);

/* Integrate from time to time + h with fixed RK4 sub-steps no longer than rk4_step,
 * landing exactly on time + h. On failure the state is left unchanged, 0 is returned
 * and msg says why. */
int model_do_step(ModelState *s, double h, char *msg, size_t len);

/* sensitivity = d(unknowns)/d(knowns) * seed, knowns being states q, qdot or inputs tau
 * and unknowns any of q, qdot, der(qdot), M, energy, tau. Complex-step, exact to round-off. */
int model_directional_derivative(const ModelState *s, const unsigned *unknowns, size_t n_unknowns,
                                 const unsigned *knowns, size_t n_knowns, const double *seed,
                                 double *sensitivity, char *msg, size_t len);

#endif
