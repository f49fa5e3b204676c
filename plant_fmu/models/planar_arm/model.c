/* The arm model: see model.h. The rigid-body algorithms are in arm_dynamics.h. */
#include <complex.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <tgmath.h>

#include "model.h"

#define TWO_PI 6.283185307179586
/* Complex-step size: derivatives are Im(f(x + i h v)) / h, free of cancellation error. */
#define COMPLEX_STEP 1e-30

/* The parameters the rigid-body algorithms read, as views into ModelState.v. */
typedef struct {
    const double *m, *l, *lc, *inertia, *b, *fc, *tau_d, *tau_d_amp, *tau_d_freq;
    double fc_vel, g;
} ChainParams;

#define SCALAR double
#define FN(name) name##_real
#include "arm_dynamics.h"
#undef SCALAR
#undef FN

#define SCALAR double complex
#define FN(name) name##_complex
#include "arm_dynamics.h"
#undef SCALAR
#undef FN

static ChainParams chain_params(const ModelState *s)
{
    const double *v = s->v;
    ChainParams p = {
        &v[VR_m], &v[VR_l], &v[VR_lc], &v[VR_I], &v[VR_b], &v[VR_fc],
        &v[VR_tau_d], &v[VR_tau_d_amp], &v[VR_tau_d_freq], v[VR_fc_vel], v[VR_g],
    };
    return p;
}

void model_reset(ModelState *s)
{
    for (int k = 0; k < N_VARIABLES; k++) s->v[k] = VARIABLES[k].start;
    model_apply_initial_state(s);
}

void model_apply_initial_state(ModelState *s)
{
    memcpy(&s->v[VR_q], &s->v[VR_q0], N_LINKS * sizeof(double));
    memcpy(&s->v[VR_qdot], &s->v[VR_qdot0], N_LINKS * sizeof(double));
    s->outputs_current = 0;
}

int model_check_value(unsigned vr, double value, char *msg, size_t len)
{
    const VariableInfo *var = &VARIABLES[vr];
    const char *rule = NULL;
    switch (var->check) {
    case CHECK_NONE: return 1;
    case CHECK_FINITE: if (!isfinite(value)) rule = "a finite number"; break;
    case CHECK_POSITIVE: if (!(isfinite(value) && value > 0)) rule = "finite and > 0"; break;
    case CHECK_NONNEGATIVE: if (!(isfinite(value) && value >= 0)) rule = "finite and >= 0"; break;
    }
    if (!rule) return 1;
    snprintf(msg, len, "%s = %g is not valid: it must be %s (unit %s)", var->name, value, rule,
             var->unit);
    return 0;
}

int model_check_parameters(const ModelState *s, char *msg, size_t len)
{
    for (unsigned vr = 0; vr < N_VARIABLES; vr++) {
        if (VARIABLES[vr].kind == KIND_PARAMETER && !model_check_value(vr, s->v[vr], msg, len))
            return 0;
    }
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

int model_update_outputs(ModelState *s)
{
    if (s->outputs_current) return 1;
    const ChainParams p = chain_params(s);
    double *v = s->v;
    mass_matrix_real(&p, &v[VR_q], &v[VR_M]);
    v[VR_energy] = energy_real(&p, &v[VR_q], &v[VR_qdot]);
    if (!forward_dynamics_real(&p, v[VR_time], &v[VR_q], &v[VR_qdot], &v[VR_tau], &v[VR_qddot]))
        return 0;
    s->outputs_current = 1;
    return 1;
}

/* x = [q; qdot], dx = [qdot; qdd]. */
static int state_derivative(const ChainParams *p, double t, const double *x, const double *tau,
                            double *dx)
{
    memcpy(dx, &x[N_LINKS], N_LINKS * sizeof(double));
    return forward_dynamics_real(p, t, x, &x[N_LINKS], tau, &dx[N_LINKS]);
}

int model_do_step(ModelState *s, double h, char *msg, size_t len)
{
    const ChainParams p = chain_params(s);
    double *v = s->v;
    const double t0 = v[VR_time], max_step = v[VR_rk4_step];
    int n_sub = (int)ceil(h / max_step - 1e-9);
    if (n_sub < 1) n_sub = 1;
    const double dt = h / n_sub;

    double x[N_STATES], k1[N_STATES], k2[N_STATES], k3[N_STATES], k4[N_STATES], xt[N_STATES];
    memcpy(x, &v[VR_q], sizeof x); /* q and qdot are adjacent in the variable table */
    for (int step = 0; step < n_sub; step++) {
        const double t = t0 + step * dt;
        int ok = state_derivative(&p, t, x, &v[VR_tau], k1);
        for (int i = 0; i < N_STATES; i++) xt[i] = x[i] + 0.5 * dt * k1[i];
        ok = ok && state_derivative(&p, t + 0.5 * dt, xt, &v[VR_tau], k2);
        for (int i = 0; i < N_STATES; i++) xt[i] = x[i] + 0.5 * dt * k2[i];
        ok = ok && state_derivative(&p, t + 0.5 * dt, xt, &v[VR_tau], k3);
        for (int i = 0; i < N_STATES; i++) xt[i] = x[i] + dt * k3[i];
        ok = ok && state_derivative(&p, t + dt, xt, &v[VR_tau], k4);
        if (!ok) {
            snprintf(msg, len, "the inertia matrix became singular at t = %g s", t);
            return 0;
        }
        for (int i = 0; i < N_STATES; i++)
            x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    }
    for (int i = 0; i < N_STATES; i++) {
        if (!isfinite(x[i])) {
            snprintf(msg, len, "%s became non-finite in the step from t = %g s to %g s",
                     VARIABLES[VR_q + i].name, t0, t0 + h);
            return 0;
        }
    }
    memcpy(&v[VR_q], x, sizeof x);
    v[VR_time] = t0 + h;
    s->outputs_current = 0;
    return 1;
}

static int in_group(unsigned vr, unsigned first, unsigned count)
{
    return vr >= first && vr < first + count;
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
