/* The spatial chain model: the FMI glue's contract (plant_fmu/fmi/model.h) for a chain read
 * from a URDF. The chain's constants are the generated chain.h; the rigid-body algorithms
 * are in spatial_chain.h. */
#include <complex.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <tgmath.h>

#include "model.h"
#include "chain.h"
#include "rk4.h"
#include "joint_state.h"

/* Complex-step size: derivatives are Im(f(x + i h v)) / h, free of cancellation error. */
#define COMPLEX_STEP 1e-30

#define SCALAR double
#define FN(name) name##_real
#include "spatial_chain.h"
#undef SCALAR
#undef FN

#define SCALAR double complex
#define FN(name) name##_complex
#include "spatial_chain.h"
#undef SCALAR
#undef FN

void model_apply_initial_state(ModelState *s)
{
    start_joints(s);
    s->outputs_current = 0;
}

int model_check_parameters(const ModelState *s, char *msg, size_t len)
{
    for (int i = 0; i < N_LINKS; i++) {
        const double q0 = s->v[VR_q0 + i];
        if (q0 < CHAIN_LOWER[i] || q0 > CHAIN_UPPER[i]) {
            snprintf(msg, len, "%s = %g %s is outside the limits [%g, %g] of joint '%s' (from the "
                     "URDF): give a start position within them", VARIABLES[VR_q0 + i].name, q0,
                     VARIABLES[VR_q0 + i].unit, CHAIN_LOWER[i], CHAIN_UPPER[i], CHAIN_JOINTS[i]);
            return 0;
        }
    }
    return 1;
}

int model_update_outputs(ModelState *s, char *msg, size_t len)
{
    if (s->outputs_current) return 1;
    const ChainParams p = chain_params(s);
    BodyInertia body[N_LINKS];
    body_inertias(p.payload, body);
    double *v = s->v;
    mass_matrix_real(body, &v[VR_q], &v[VR_M]);
    inverse_dynamics_real(body, &v[VR_q], &v[VR_qdot], NULL, &v[VR_h]);
    v[VR_energy] = energy_real(body, &v[VR_q], &v[VR_qdot]);
    if (!forward_dynamics_real(&p, body, &v[VR_q], &v[VR_qdot], &v[VR_tau], &v[VR_qddot])) {
        snprintf(msg, len, "a joint has no inertia about its axis at t = %g s", v[VR_time]);
        return 0;
    }
    s->outputs_current = 1;
    return 1;
}

typedef struct {
    ChainParams chain;
    BodyInertia body[N_LINKS];
    const double *tau;
} StepContext;

/* x = [q; qdot], dx = [qdot; qdd]. */
static int state_derivative(const void *context, double t, const double *x, double *dx)
{
    (void)t;
    const StepContext *c = context;
    memcpy(dx, &x[N_LINKS], N_LINKS * sizeof(double));
    return forward_dynamics_real(&c->chain, c->body, x, &x[N_LINKS], c->tau, &dx[N_LINKS]);
}

/* The longest RK4 sub-step at the start of a communication step: rk4_step, shorter where
 * the fastest joint would move more than rk4_motion in one (RK4's error grows with the
 * motion per sub-step, as (|q̇| dt)^5), down to rk4_step / MOTION_REFINEMENT at most. An arm
 * within its velocity limits never comes near it (Panda, UR5: < 4 rad/s against
 * rk4_motion / rk4_step = 40 rad/s), so its sub-steps, and its results, are rk4_step's. */
#define MOTION_REFINEMENT 8.0

static double sub_step(const double *v)
{
    double fastest = 0.0;
    for (int i = 0; i < N_LINKS; i++) fastest = fmax(fastest, fabs(v[VR_qdot + i]));
    double step = v[VR_rk4_step];
    if (fastest * step > v[VR_rk4_motion]) step = v[VR_rk4_motion] / fastest;
    return fmax(step, v[VR_rk4_step] / MOTION_REFINEMENT);
}

int model_do_step(ModelState *s, double h, char *msg, size_t len)
{
    double *v = s->v;
    StepContext context;
    context.chain = chain_params(s);
    context.tau = &v[VR_tau];
    body_inertias(context.chain.payload, context.body);
    double failed_at;
    int diverged;
    /* q and qdot are adjacent in the variable table: the state vector in place */
    if (!rk4_integrate(state_derivative, &context, v[VR_time], h, sub_step(v), &v[VR_q],
                       &failed_at, &diverged)) {
        rk4_failure(msg, len, diverged, failed_at, &v[VR_qdot], &v[VR_tau], N_LINKS,
                    "rad/s and N.m; m/s and N for a prismatic joint",
                    "a joint lost its inertia about its axis");
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
    BodyInertia body[N_LINKS];
    body_inertias(p.payload, body);
    const double *v = s->v;
    /* x holds q, qdot (adjacent) and tau, perturbed along i * h * seed. */
    double complex x[N_STATES], tau[N_LINKS], qdd[N_LINKS], M[N_LINKS * N_LINKS], h[N_LINKS];
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
    mass_matrix_complex(body, x, M);
    inverse_dynamics_complex(body, x, &x[N_LINKS], NULL, h);
    if (!forward_dynamics_complex(&p, body, x, &x[N_LINKS], tau, qdd)) {
        snprintf(msg, len, "directional derivative: a joint has no inertia about its axis");
        return 0;
    }
    const double complex e = energy_complex(body, x, &x[N_LINKS]);
    for (size_t k = 0; k < n_unknowns; k++) {
        const unsigned vr = unknowns[k];
        double complex value;
        if (in_group(vr, VR_q, N_STATES)) value = x[vr - VR_q];
        else if (in_group(vr, VR_qddot, N_LINKS)) value = qdd[vr - VR_qddot];
        else if (in_group(vr, VR_M, N_LINKS * N_LINKS)) value = M[vr - VR_M];
        else if (in_group(vr, VR_h, N_LINKS)) value = h[vr - VR_h];
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
