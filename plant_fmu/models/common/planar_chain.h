/*
 * Rigid-body algorithms for a planar serial chain of N_LINKS revolute joints, shared by the
 * built-in models (the rigid arm, and the elastic-joint arm's links).
 *
 * Written once for a generic scalar so that the same code runs in `double` (simulation)
 * and in `double complex` (complex-step directional derivatives, exact to round-off).
 * A model includes this file twice with SCALAR and FN(name) defined, after <tgmath.h>,
 * which makes cos/sin/tanh/sqrt type-generic.
 *
 * Geometry: joint 1 sits at the origin; q[0] is link 1's angle from the horizontal (x)
 * axis and q[i] the angle of link i+1 relative to link i. Gravity g acts along -y.
 * Link i has mass m, length l, centre of mass at distance lc along the link and
 * rotational inertia I about its centre of mass.
 */

#ifndef PLANAR_CHAIN_PARAMS
#define PLANAR_CHAIN_PARAMS
/* The parameters the algorithms read, as views into the model's variables. drive_inertia:
 * what drives add to each joint's inertia (M's diagonal), or NULL for none. */
typedef struct {
    const double *m, *l, *lc, *inertia, *b, *fc, *tau_d, *tau_d_amp, *tau_d_freq;
    double fc_vel, g;
    const double *drive_inertia;
} ChainParams;

/* The chain's parameters of a model whose variable table has the rigid arm's link
 * parameters (m, l, lc, I, b, fc, tau_d, tau_d_amp, tau_d_freq, fc_vel, g), and the drives'
 * inertia input Jm where it has one. */
static ChainParams chain_params(const ModelState *s)
{
    const double *v = s->v;
#ifdef VR_Jm
    const double *drive_inertia = &v[VR_Jm];
#else
    const double *drive_inertia = NULL;
#endif
    ChainParams p = {
        &v[VR_m], &v[VR_l], &v[VR_lc], &v[VR_I], &v[VR_b], &v[VR_fc],
        &v[VR_tau_d], &v[VR_tau_d_amp], &v[VR_tau_d_freq], v[VR_fc_vel], v[VR_g],
        drive_inertia,
    };
    return p;
}
#endif

/* Recursive Newton–Euler: tau = M(q) qdd + C(q, qd) qd + G(q).
 * qdd may be NULL (zero acceleration): then tau is the bias force C qd + G. */
static void FN(inverse_dynamics)(const ChainParams *p, const SCALAR *q, const SCALAR *qd,
                                 const SCALAR *qdd, SCALAR *tau)
{
    SCALAR ux[N_LINKS], uy[N_LINKS], alpha[N_LINKS], fx[N_LINKS], fy[N_LINKS];
    SCALAR theta = 0, omega = 0, alpha_abs = 0;
    /* Acceleration of joint i. The base accelerating upward by g stands in for gravity. */
    SCALAR ax = 0, ay = p->g;

    for (int i = 0; i < N_LINKS; i++) {
        theta += q[i];
        omega += qd[i];
        if (qdd) alpha_abs += qdd[i];
        ux[i] = cos(theta);
        uy[i] = sin(theta);
        alpha[i] = alpha_abs;
        const SCALAR w2 = omega * omega;
        /* a_c = a_joint + alpha x r - omega^2 r, with r = lc u: net force on link i. */
        fx[i] = p->m[i] * (ax - alpha_abs * p->lc[i] * uy[i] - w2 * p->lc[i] * ux[i]);
        fy[i] = p->m[i] * (ay + alpha_abs * p->lc[i] * ux[i] - w2 * p->lc[i] * uy[i]);
        ax += -alpha_abs * p->l[i] * uy[i] - w2 * p->l[i] * ux[i];
        ay += alpha_abs * p->l[i] * ux[i] - w2 * p->l[i] * uy[i];
    }

    /* Backward pass: force f and moment n that link i-1 exerts on link i at joint i. */
    SCALAR f_next_x = 0, f_next_y = 0, n_next = 0;
    for (int i = N_LINKS - 1; i >= 0; i--) {
        n_next = n_next + p->inertia[i] * alpha[i]
               + p->lc[i] * (ux[i] * fy[i] - uy[i] * fx[i])
               + p->l[i] * (ux[i] * f_next_y - uy[i] * f_next_x);
        f_next_x += fx[i];
        f_next_y += fy[i];
        tau[i] = n_next;
    }
}

/* Composite-rigid-body algorithm: the joint-space inertia matrix M(q), row-major.
 * Sweeping from the tip, body j..n is lumped into a composite with mass mc, first
 * moment h about joint j and inertia J about joint j; then for i <= j
 * M[i][j] = J_j + (p_j - p_i) . h_j. A drive's reflected rotor inertia, which turns with
 * its joint alone, adds to M[j][j] (with none, M is the links' own to the last bit). */
static void FN(mass_matrix)(const ChainParams *p, const SCALAR *q, SCALAR *M)
{
    SCALAR px[N_LINKS + 1], py[N_LINKS + 1], cx[N_LINKS], cy[N_LINKS];
    SCALAR theta = 0;
    px[0] = 0;
    py[0] = 0;
    for (int i = 0; i < N_LINKS; i++) {
        theta += q[i];
        const SCALAR ux = cos(theta), uy = sin(theta);
        cx[i] = px[i] + p->lc[i] * ux;
        cy[i] = py[i] + p->lc[i] * uy;
        px[i + 1] = px[i] + p->l[i] * ux;
        py[i + 1] = py[i] + p->l[i] * uy;
    }

    SCALAR mc = 0, hx = 0, hy = 0, J = 0; /* composite j+1..n about joint j+1 */
    for (int j = N_LINKS - 1; j >= 0; j--) {
        const SCALAR dx = px[j + 1] - px[j], dy = py[j + 1] - py[j];
        const SCALAR rx = cx[j] - px[j], ry = cy[j] - py[j];
        /* Shift the composite from joint j+1 to joint j (parallel axis), add link j. */
        J = J + 2 * (dx * hx + dy * hy) + mc * (dx * dx + dy * dy)
          + p->inertia[j] + p->m[j] * (rx * rx + ry * ry);
        hx = hx + mc * dx + p->m[j] * rx;
        hy = hy + mc * dy + p->m[j] * ry;
        mc += p->m[j];
        for (int i = 0; i <= j; i++) {
            const SCALAR Mij = J + (px[j] - px[i]) * hx + (py[j] - py[i]) * hy;
            M[i * N_LINKS + j] = Mij;
            M[j * N_LINKS + i] = Mij;
        }
    }
    if (p->drive_inertia)
        for (int j = 0; j < N_LINKS; j++) M[j * N_LINKS + j] += p->drive_inertia[j];
}

/* Solve A x = b in place (b becomes x) by Cholesky, A symmetric positive definite.
 * No conjugation: for the complex step A is complex-symmetric, not Hermitian.
 * Returns 0 when A is not positive definite. */
static int FN(cholesky_solve)(SCALAR *A, SCALAR *b)
{
    for (int j = 0; j < N_LINKS; j++) {
        SCALAR d = A[j * N_LINKS + j];
        for (int k = 0; k < j; k++) d -= A[j * N_LINKS + k] * A[j * N_LINKS + k];
        if (!(creal(d) > 0)) return 0;
        d = sqrt(d);
        A[j * N_LINKS + j] = d;
        for (int i = j + 1; i < N_LINKS; i++) {
            SCALAR s = A[i * N_LINKS + j];
            for (int k = 0; k < j; k++) s -= A[i * N_LINKS + k] * A[j * N_LINKS + k];
            A[i * N_LINKS + j] = s / d;
        }
    }
    for (int i = 0; i < N_LINKS; i++) { /* L y = b */
        for (int k = 0; k < i; k++) b[i] -= A[i * N_LINKS + k] * b[k];
        b[i] /= A[i * N_LINKS + i];
    }
    for (int i = N_LINKS - 1; i >= 0; i--) { /* L^T x = y */
        for (int k = i + 1; k < N_LINKS; k++) b[i] -= A[k * N_LINKS + i] * b[k];
        b[i] /= A[i * N_LINKS + i];
    }
    return 1;
}

/* Forward dynamics of (1): qdd = M^-1 (tau - C qd - G - F(qd) - tau_d(t)).
 * Returns 0 when M(q) is singular. */
static int FN(forward_dynamics)(const ChainParams *p, double t, const SCALAR *q,
                                const SCALAR *qd, const SCALAR *tau, SCALAR *qdd)
{
    SCALAR M[N_LINKS * N_LINKS];
    FN(mass_matrix)(p, q, M);
    FN(inverse_dynamics)(p, q, qd, NULL, qdd);
    for (int i = 0; i < N_LINKS; i++) {
        const SCALAR friction = p->b[i] * qd[i] + p->fc[i] * tanh(qd[i] / p->fc_vel);
        const double disturbance =
            p->tau_d[i] + p->tau_d_amp[i] * sin(TWO_PI * p->tau_d_freq[i] * t);
        qdd[i] = tau[i] - qdd[i] - friction - disturbance;
    }
    return FN(cholesky_solve)(M, qdd);
}

/* Kinetic plus potential energy; zero potential at y = 0. */
static SCALAR FN(energy)(const ChainParams *p, const SCALAR *q, const SCALAR *qd)
{
    SCALAR M[N_LINKS * N_LINKS];
    FN(mass_matrix)(p, q, M);
    SCALAR kinetic = 0, potential = 0, theta = 0, y = 0;
    for (int i = 0; i < N_LINKS; i++) {
        for (int j = 0; j < N_LINKS; j++) kinetic += 0.5 * qd[i] * M[i * N_LINKS + j] * qd[j];
        theta += q[i];
        potential += p->m[i] * p->g * (y + p->lc[i] * sin(theta));
        y += p->l[i] * sin(theta);
    }
    return kinetic + potential;
}
