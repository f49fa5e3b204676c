/* The arm model: the FMI glue's contract (plant_fmu/fmi/model.h) for a planar serial chain.
 * The rigid-body algorithms are in planar_chain.h. */
#include <complex.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <tgmath.h>

#include "model.h"
#include "rk4.h"
#include "joint_state.h"

#define TWO_PI 6.283185307179586
/* Complex-step size: derivatives are Im(f(x + i h v)) / h, free of cancellation error. */
#define COMPLEX_STEP 1e-30

#define SCALAR double
#define FN(name) name##_real
#include "planar_chain.h"
#undef SCALAR
#undef FN

#define SCALAR double complex
#define FN(name) name##_complex
#include "planar_chain.h"
#undef SCALAR
#undef FN

void model_apply_initial_state(ModelState *s)
{
    start_joints(s);
    s->outputs_current = 0;
}

int model_check_parameters(const ModelState *s, char *msg, size_t len)
{
    const ChainParams p = chain_params(s);
    double M[N_LINKS * N_LINKS], rhs[N_LINKS] = {0};
    mass_matrix_real(&p, &s->v[VR_q0], M);
    if (!cholesky_solve_real(M, rhs)) {
        snprintf(msg, len, "the inertia matrix M(q0) is singular: a link with lc = 0 and I = 0 "
                 "has no inertia about its joint; give it a non-zero lc or I");
        return 0;
    }
    return 1;
}

int model_update_outputs(ModelState *s, char *msg, size_t len)
{
    if (s->outputs_current) return 1;
    const ChainParams p = chain_params(s);
    double *v = s->v;
    mass_matrix_real(&p, &v[VR_q], &v[VR_M]);
    v[VR_energy] = energy_real(&p, &v[VR_q], &v[VR_qdot]);
    if (!forward_dynamics_real(&p, v[VR_time], &v[VR_q], &v[VR_qdot], &v[VR_tau], &v[VR_qddot])) {
        snprintf(msg, len, "the inertia matrix M(q) is singular at t = %g s", v[VR_time]);
        return 0;
    }
    s->outputs_current = 1;
    return 1;
}

typedef struct {
    ChainParams chain;
    const double *tau;
} StepContext;

/* x = [q; qdot], dx = [qdot; qdd]. */
static int state_derivative(const void *context, double t, const double *x, double *dx)
{
    const StepContext *c = context;
    memcpy(dx, &x[N_LINKS], N_LINKS * sizeof(double));
    return forward_dynamics_real(&c->chain, t, x, &x[N_LINKS], c->tau, &dx[N_LINKS]);
}

int model_do_step(ModelState *s, double h, char *msg, size_t len)
{
    double *v = s->v;
    const StepContext context = {chain_params(s), &v[VR_tau]};
    double failed_at;
    int diverged;
    /* q and qdot are adjacent in the variable table: the state vector in place */
    if (!rk4_integrate(state_derivative, &context, v[VR_time], h, v[VR_rk4_step], &v[VR_q],
                       &failed_at, &diverged)) {
        rk4_failure(msg, len, diverged, failed_at, &v[VR_qdot], &v[VR_tau], N_LINKS,
                    "rad/s and N.m", "the inertia matrix became singular");
        return 0;
    }
    v[VR_time] += h;
    s->outputs_current = 0;
    return 1;
}

int model_directional_derivative(const ModelState *s, const unsigned *unknowns, size_t n_unknowns,
                                 const unsigned *knowns, size_t n_knowns, const double *seed,
                                 double *sensitivity, char *msg, size_t len)
{
    const ChainParams p = chain_params(s);
    const double *v = s->v;
    /* x holds q, qdot (adjacent) and tau, perturbed along i * h * seed. */
    double complex x[N_STATES], tau[N_LINKS], qdd[N_LINKS], M[N_LINKS * N_LINKS];
    for (int i = 0; i < N_STATES; i++) x[i] = v[VR_q + i];
    for (int i = 0; i < N_LINKS; i++) tau[i] = v[VR_tau + i];
    for (size_t k = 0; k < n_knowns; k++) {
        const unsigned vr = knowns[k];
        if (in_group(vr, VR_q, N_STATES)) {
            x[vr - VR_q] += I * COMPLEX_STEP * seed[k];
        } else if (in_group(vr, VR_tau, N_LINKS)) {
            tau[vr - VR_tau] += I * COMPLEX_STEP * seed[k];
        } else {
            snprintf(msg, len, "directional derivative: known %s (value reference %u) is not a "
                     "state (q, qdot) or an input (tau)",
                     vr < N_VARIABLES ? VARIABLES[vr].name : "?", vr);
            return 0;
        }
    }
    mass_matrix_complex(&p, x, M);
    if (!forward_dynamics_complex(&p, v[VR_time], x, &x[N_LINKS], tau, qdd)) {
        snprintf(msg, len, "directional derivative: the inertia matrix is singular");
        return 0;
    }
    const double complex e = energy_complex(&p, x, &x[N_LINKS]);
    for (size_t k = 0; k < n_unknowns; k++) {
        const unsigned vr = unknowns[k];
        double complex value;
        if (in_group(vr, VR_q, N_STATES)) value = x[vr - VR_q];
        else if (in_group(vr, VR_qddot, N_LINKS)) value = qdd[vr - VR_qddot];
        else if (in_group(vr, VR_M, N_LINKS * N_LINKS)) value = M[vr - VR_M];
        else if (in_group(vr, VR_tau, N_LINKS)) value = tau[vr - VR_tau];
        else if (vr == VR_energy) value = e;
        else {
            snprintf(msg, len, "directional derivative: unknown %s (value reference %u) is not a "
                     "state, derivative or output",
                     vr < N_VARIABLES ? VARIABLES[vr].name : "?", vr);
            return 0;
        }
        sensitivity[k] = cimag(value) / COMPLEX_STEP;
    }
    return 1;
}
