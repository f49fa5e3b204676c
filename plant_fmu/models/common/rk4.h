/*
 * Fixed-step classical Runge–Kutta for the built-in models: from t0 to t0 + h in equal
 * sub-steps no longer than max_step, landing exactly on t0 + h. Header-only; a model
 * includes it after defining N_STATES.
 */
#ifndef RK4_H
#define RK4_H

#include <math.h>
#include <stdio.h>

/* dx = f(t, x); 0 when it cannot be evaluated (a singular inertia matrix). */
typedef int (*StateDerivative)(const void *context, double t, const double *x, double *dx);

static int rk4_finite(const double *x)
{
    for (int i = 0; i < N_STATES; i++)
        if (!isfinite(x[i])) return 0;
    return 1;
}

/* f at (t, state) into k, or 0 with *failed_at and *diverged (whether the state it was
 * given had become non-finite) set: each stage is checked as it is taken, so that the state
 * judged is the one f failed on. */
#define RK4_STAGE(tt, state, k)                                                            \
    if (!f(context, (tt), (state), (k))) {                                                  \
        *failed_at = t;                                                                     \
        *diverged = !rk4_finite(state);                                                     \
        return 0;                                                                           \
    }

/* x is advanced in place; on failure it is left unchanged, *failed_at holds the time of
 * the sub-step, *diverged whether the state had become non-finite (f failed on such a
 * state, or a sub-step ended in one), and 0 is returned. */
static int rk4_integrate(StateDerivative f, const void *context, double t0, double h,
                         double max_step, double *x, double *failed_at, int *diverged)
{
    int n_sub = (int)ceil(h / max_step - 1e-9);
    if (n_sub < 1) n_sub = 1;
    const double dt = h / n_sub;
    double y[N_STATES], k1[N_STATES], k2[N_STATES], k3[N_STATES], k4[N_STATES], yt[N_STATES];
    for (int i = 0; i < N_STATES; i++) y[i] = x[i];
    for (int step = 0; step < n_sub; step++) {
        const double t = t0 + step * dt;
        RK4_STAGE(t, y, k1)
        for (int i = 0; i < N_STATES; i++) yt[i] = y[i] + 0.5 * dt * k1[i];
        RK4_STAGE(t + 0.5 * dt, yt, k2)
        for (int i = 0; i < N_STATES; i++) yt[i] = y[i] + 0.5 * dt * k2[i];
        RK4_STAGE(t + 0.5 * dt, yt, k3)
        for (int i = 0; i < N_STATES; i++) yt[i] = y[i] + dt * k3[i];
        RK4_STAGE(t + dt, yt, k4)
        for (int i = 0; i < N_STATES; i++)
            y[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        if (!rk4_finite(y)) {
            *failed_at = t;
            *diverged = 1;
            return 0;
        }
    }
    for (int i = 0; i < N_STATES; i++) x[i] = y[i];
    return 1;
}

#undef RK4_STAGE

/* The message of a step that failed at t: a state that diverged within it (non-finite: a
 * torque or a controller's gains too large for the step, not the model) said as such, with
 * the fastest of the n joint velocities qdot and the largest |tau| at the communication
 * step's start (``units``: theirs);
 * else ``singular``, what the model could not evaluate. */
static void rk4_failure(char *msg, size_t len, int diverged, double t, const double *qdot,
                        const double *tau, int n, const char *units, const char *singular)
{
    if (!diverged) {
        snprintf(msg, len, "%s at t = %g s", singular, t);
        return;
    }
    int fastest = 0, largest = 0;
    for (int i = 1; i < n; i++) {
        if (fabs(qdot[i]) > fabs(qdot[fastest])) fastest = i;
        if (fabs(tau[i]) > fabs(tau[largest])) largest = i;
    }
    snprintf(msg, len, "the state diverged at t = %g s: it became non-finite within the step, "
             "which began at qdot[%d] = %g and tau[%d] = %g (%s); a torque or a controller's "
             "gains too large for the plant's step (the model itself is not at fault)", t,
             fastest + 1, qdot[fastest], largest + 1, tau[largest], units);
}

#endif
