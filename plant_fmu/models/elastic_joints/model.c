/* The elastic-joint arm (Spong 1987): the rigid planar chain's links driven through joint
 * springs by motors of their own inertia. Per joint i, link angle q_i, motor angle θ_i
 * (referred to the link side), stiffness k_i, damping d_i, motor inertia J_i:
 *
 *     M(q) q̈ + C(q, q̇) q̇ + G(q) + F(q̇) + τ_d(t) = σ,   J θ̈ + σ = τ,
 *     σ = k (θ − q) + d (θ̇ − q̇)   (the spring and damper torque, per joint).
 *
 * The motor torque τ is the input. As k → ∞ the links follow the motors and the arm is the
 * rigid one with J added to M's diagonal. The contract is plant_fmu/fmi/model.h. */
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

/* The state vector x = [q; qdot; theta; thetadot], adjacent in the variable table. */
#define X_Q 0
#define X_QDOT N_LINKS
#define X_THETA (2 * N_LINKS)
#define X_THETADOT (3 * N_LINKS)

void model_apply_initial_state(ModelState *s)
{
    double *v = s->v;
    for (int i = 0; i < N_LINKS; i++) {
        v[VR_q + i] = v[VR_q0 + i];
        v[VR_qdot + i] = v[VR_qdot0 + i];
        v[VR_theta + i] = v[VR_q0 + i] + v[VR_deflection0 + i];
        v[VR_thetadot + i] = v[VR_qdot0 + i];
    }
    s->outputs_current = 0;
}

int model_check_parameters(const ModelState *s, char *msg, size_t len)
{
    const ChainParams p = chain_params(s);
    double M[N_LINKS * N_LINKS], rhs[N_LINKS] = {0};
    mass_matrix_real(&p, &s->v[VR_q0], M);
    if (!cholesky_solve_real(M, rhs)) {
        snprintf(msg, len, "the links' inertia matrix M(q0) is singular: a link with lc = 0 "
                 "and I = 0 has no inertia about its joint; give it a non-zero lc or I");
        return 0;
    }
    return 1;
}

/* dx of x (double), with v the model's variables (parameters, input tau). */
static int derivative_real(const ChainParams *p, const double *v, double t, const double *x,
                           const double *tau, double *dx)
{
    double spring[N_LINKS];
    for (int i = 0; i < N_LINKS; i++) {
        spring[i] = v[VR_k + i] * (x[X_THETA + i] - x[X_Q + i])
                  + v[VR_d + i] * (x[X_THETADOT + i] - x[X_QDOT + i]);
        dx[X_Q + i] = x[X_QDOT + i];
        dx[X_THETA + i] = x[X_THETADOT + i];
        dx[X_THETADOT + i] = (tau[i] - spring[i]) / v[VR_J + i];
    }
    return forward_dynamics_real(p, t, &x[X_Q], &x[X_QDOT], spring, &dx[X_QDOT]);
}

/* The same in complex arithmetic, for the complex-step derivatives. */
static int derivative_complex(const ChainParams *p, const double *v, double t,
                              const double complex *x, const double complex *tau,
                              double complex *dx)
{
    double complex spring[N_LINKS];
    for (int i = 0; i < N_LINKS; i++) {
        spring[i] = v[VR_k + i] * (x[X_THETA + i] - x[X_Q + i])
                  + v[VR_d + i] * (x[X_THETADOT + i] - x[X_QDOT + i]);
        dx[X_Q + i] = x[X_QDOT + i];
        dx[X_THETA + i] = x[X_THETADOT + i];
        dx[X_THETADOT + i] = (tau[i] - spring[i]) / v[VR_J + i];
    }
    return forward_dynamics_complex(p, t, &x[X_Q], &x[X_QDOT], spring, &dx[X_QDOT]);
}

/* The energy of links, motors and springs, in complex arithmetic (the derivatives). */
static double complex energy(const ChainParams *p, const double *v, const double complex *x)
{
    double complex total = energy_complex(p, &x[X_Q], &x[X_QDOT]);
    for (int i = 0; i < N_LINKS; i++) {
        const double complex stretch = x[X_THETA + i] - x[X_Q + i];
        total += 0.5 * v[VR_J + i] * x[X_THETADOT + i] * x[X_THETADOT + i]
               + 0.5 * v[VR_k + i] * stretch * stretch;
    }
    return total;
}

int model_update_outputs(ModelState *s, char *msg, size_t len)
{
    if (s->outputs_current) return 1;
    const ChainParams p = chain_params(s);
    double *v = s->v, dx[N_STATES];
    mass_matrix_real(&p, &v[VR_q], &v[VR_M]);
    v[VR_energy] = energy_real(&p, &v[VR_q], &v[VR_qdot]);
    for (int i = 0; i < N_LINKS; i++) { /* as energy() below: the motors and the springs */
        const double stretch = v[VR_theta + i] - v[VR_q + i];
        v[VR_energy] += 0.5 * v[VR_J + i] * v[VR_thetadot + i] * v[VR_thetadot + i]
                      + 0.5 * v[VR_k + i] * stretch * stretch;
    }
    if (!derivative_real(&p, v, v[VR_time], &v[VR_q], &v[VR_tau], dx)) {
        snprintf(msg, len, "the links' inertia matrix M(q) is singular at t = %g s", v[VR_time]);
        return 0;
    }
    memcpy(&v[VR_qddot], &dx[X_QDOT], N_LINKS * sizeof(double));
    memcpy(&v[VR_thetaddot], &dx[X_THETADOT], N_LINKS * sizeof(double));
    s->outputs_current = 1;
    return 1;
}

typedef struct {
    ChainParams chain;
    const double *v;
} StepContext;

static int state_derivative(const void *context, double t, const double *x, double *dx)
{
    const StepContext *c = context;
    return derivative_real(&c->chain, c->v, t, x, &c->v[VR_tau], dx);
}

int model_do_step(ModelState *s, double h, char *msg, size_t len)
{
    double *v = s->v;
    const StepContext context = {chain_params(s), v};
    double failed_at;
    int diverged;
    if (!rk4_integrate(state_derivative, &context, v[VR_time], h, v[VR_rk4_step], &v[VR_q],
                       &failed_at, &diverged)) {
        rk4_failure(msg, len, diverged, failed_at, &v[VR_qdot], &v[VR_tau], N_LINKS,
                    "rad/s and N.m", "the links' inertia matrix became singular");
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
    double complex x[N_STATES], tau[N_LINKS], dx[N_STATES], M[N_LINKS * N_LINKS];
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
                     "state (q, qdot, theta, thetadot) or an input (tau)",
                     vr < N_VARIABLES ? VARIABLES[vr].name : "?", vr);
            return 0;
        }
    }
    mass_matrix_complex(&p, &x[X_Q], M);
    if (!derivative_complex(&p, v, v[VR_time], x, tau, dx)) {
        snprintf(msg, len, "directional derivative: the links' inertia matrix is singular");
        return 0;
    }
    const double complex e = energy(&p, v, x);
    for (size_t k = 0; k < n_unknowns; k++) {
        const unsigned vr = unknowns[k];
        double complex value;
        if (in_group(vr, VR_q, N_STATES)) value = x[vr - VR_q];
        else if (in_group(vr, VR_qddot, N_LINKS)) value = dx[X_QDOT + vr - VR_qddot];
        else if (in_group(vr, VR_thetaddot, N_LINKS)) value = dx[X_THETADOT + vr - VR_thetaddot];
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
