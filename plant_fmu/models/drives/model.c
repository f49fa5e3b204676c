/* The drives: per joint a DC motor under current control behind a gear (see __init__.py).
 *
 *     i_cmd = sat(u / (N kt), i_max),   T di/dt = i_cmd - i   (T = 0: i = i_cmd),
 *     tau = N kt i,                      J_reflected = J N^2.
 *
 * The lag is integrated exactly over each step (the command is held over it). The contract
 * is plant_fmu/fmi/model.h. */
#include <math.h>
#include <stdio.h>

#include "model.h"
#include "value_references.h"

/* The current drive i is commanded, clipped at its limit (A). */
static double commanded_current(const double *v, int i)
{
    const double wanted = v[VR_tau_cmd + i] / (v[VR_N + i] * v[VR_kt + i]);
    return fmin(fmax(wanted, -v[VR_i_max + i]), v[VR_i_max + i]);
}

/* Whether drive i's current is its command's within the instant (ideal, or clipped). */
static int follows_command(const double *v, int i)
{
    return v[VR_T + i] == 0.0;
}

void model_apply_initial_state(ModelState *s)
{
    /* settled on the command it is given while it initialises */
    for (int i = 0; i < N_LINKS; i++) s->v[VR_i_lag + i] = commanded_current(s->v, i);
    s->outputs_current = 0;
}

int model_check_parameters(const ModelState *s, char *msg, size_t len)
{
    (void)s, (void)msg, (void)len; /* every parameter is checked by its table entry */
    return 1;
}

int model_update_outputs(ModelState *s, char *msg, size_t len)
{
    (void)msg, (void)len;
    if (s->outputs_current) return 1;
    double *v = s->v;
    for (int i = 0; i < N_LINKS; i++) {
        const double command = commanded_current(v, i);
        const int ideal = follows_command(v, i);
        v[VR_current + i] = ideal ? command : v[VR_i_lag + i];
        v[VR_tau + i] = v[VR_N + i] * v[VR_kt + i] * v[VR_current + i];
        v[VR_J_reflected + i] = v[VR_J + i] * v[VR_N + i] * v[VR_N + i];
        v[VR_der_i_lag + i] = ideal ? 0.0 : (command - v[VR_i_lag + i]) / v[VR_T + i];
    }
    s->outputs_current = 1;
    return 1;
}

int model_do_step(ModelState *s, double h, char *msg, size_t len)
{
    (void)msg, (void)len;
    double *v = s->v;
    for (int i = 0; i < N_LINKS; i++) {
        const double command = commanded_current(v, i);
        v[VR_i_lag + i] = follows_command(v, i)
            ? command
            : command + (v[VR_i_lag + i] - command) * exp(-h / v[VR_T + i]);
    }
    v[VR_time] += h;
    s->outputs_current = 0;
    return 1;
}

/* The slope of drive i's clipped command current in its command: 1 / (N kt) inside the
 * limit, 0 at or beyond it (the kink given the side the command is on). */
static double command_slope(const double *v, int i)
{
    const double scale = 1.0 / (v[VR_N + i] * v[VR_kt + i]);
    return fabs(v[VR_tau_cmd + i] * scale) < v[VR_i_max + i] ? scale : 0.0;
}

int model_directional_derivative(const ModelState *s, const unsigned *unknowns, size_t n_unknowns,
                                 const unsigned *knowns, size_t n_knowns, const double *seed,
                                 double *sensitivity, char *msg, size_t len)
{
    const double *v = s->v;
    double d_command[N_LINKS] = {0}, d_lag[N_LINKS] = {0};
    for (size_t k = 0; k < n_knowns; k++) {
        const unsigned vr = knowns[k];
        if (in_group(vr, VR_tau_cmd, N_LINKS)) d_command[vr - VR_tau_cmd] += seed[k];
        else if (in_group(vr, VR_i_lag, N_LINKS)) d_lag[vr - VR_i_lag] += seed[k];
        else {
            snprintf(msg, len, "directional derivative: known %s (value reference %u) is not a "
                     "state (i_lag) or an input (tau_cmd)",
                     vr < N_VARIABLES ? VARIABLES[vr].name : "?", vr);
            return 0;
        }
    }
    /* Per joint, the changes of the clipped command current, the delivered current and the
     * lag's rate. */
    double d_clipped[N_LINKS], d_current[N_LINKS], d_rate[N_LINKS];
    for (int i = 0; i < N_LINKS; i++) {
        d_clipped[i] = command_slope(v, i) * d_command[i];
        const int ideal = follows_command(v, i);
        d_current[i] = ideal ? d_clipped[i] : d_lag[i];
        d_rate[i] = ideal ? 0.0 : (d_clipped[i] - d_lag[i]) / v[VR_T + i];
    }
    for (size_t k = 0; k < n_unknowns; k++) {
        const unsigned vr = unknowns[k];
        if (in_group(vr, VR_current, N_LINKS)) sensitivity[k] = d_current[vr - VR_current];
        else if (in_group(vr, VR_tau, N_LINKS)) {
            const int i = vr - VR_tau;
            sensitivity[k] = v[VR_N + i] * v[VR_kt + i] * d_current[i];
        } else if (in_group(vr, VR_der_i_lag, N_LINKS)) sensitivity[k] = d_rate[vr - VR_der_i_lag];
        else if (in_group(vr, VR_i_lag, N_LINKS)) sensitivity[k] = d_lag[vr - VR_i_lag];
        else if (in_group(vr, VR_J_reflected, N_LINKS)) sensitivity[k] = 0.0;
        else {
            snprintf(msg, len, "directional derivative: unknown %s (value reference %u) is not a "
                     "state, derivative or output",
                     vr < N_VARIABLES ? VARIABLES[vr].name : "?", vr);
            return 0;
        }
    }
    return 1;
}
