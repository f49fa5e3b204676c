/*
 * Rigid-body algorithms for a spatial chain (a tree, parents before children) of N_LINKS
 * revolute or prismatic joints, after Featherstone, "Rigid Body Dynamics Algorithms" (2008):
 * the articulated-body algorithm for the forward dynamics (Table 7.1), the composite-rigid-
 * body algorithm for M(q) (Table 6.2) and recursive Newton-Euler for the bias h(q, qd)
 * (Table 5.1). Nothing here knows a robot: the chain's constants are the generated chain.h
 * (plant_fmu/models/spatial_chain/__init__.py, from the URDF reader's Chain table).
 *
 * Written once for a generic scalar, as planar_chain.h, so that the same code runs in
 * `double` (simulation) and in `double complex` (complex-step directional derivatives).
 * A model includes this file twice with SCALAR and FN(name) defined, after <tgmath.h>.
 *
 * Spatial vectors are [angular; linear] in the body's frame: motion (omega; v of the frame
 * origin), force (n about the origin; f). The transform from a parent body to body i is
 * (E, r): E rotates parent coordinates into body coordinates, r is body i's origin in the
 * parent's coordinates. Gravity enters as the base accelerating at -gravity.
 */

#ifndef SPATIAL_CHAIN_COMMON
#define SPATIAL_CHAIN_COMMON
/* The parameters the algorithms read, as views into the model's variables. */
typedef struct {
    const double *b, *fc, *fc_vel, *tau_d;
    double payload;
} ChainParams;

static ChainParams chain_params(const ModelState *s)
{
    const double *v = s->v;
    ChainParams p = {&v[VR_b], &v[VR_fc], &v[VR_fc_vel], &v[VR_tau_d], v[VR_payload]};
    return p;
}

/* A body's spatial inertia about its frame's origin: mass m, first moment h = m c and
 * rotational inertia about the origin Ibar = Ic + m (c.c 1 - c c^T), row-major. */
typedef struct {
    double m, h[3], ibar[9];
} BodyInertia;

/* Each body from chain.h, the payload (a point mass at the tip frame's origin) added to the
 * last body. */
static void body_inertias(double payload, BodyInertia *body)
{
    for (int i = 0; i < N_LINKS; i++) {
        const double m = CHAIN_MASS[i], *c = CHAIN_COM[i];
        BodyInertia *b = &body[i];
        b->m = m;
        const double cc = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
        for (int k = 0; k < 3; k++) {
            b->h[k] = m * c[k];
            for (int l = 0; l < 3; l++)
                b->ibar[3 * k + l] = CHAIN_INERTIA[i][3 * k + l] + m * ((k == l) * cc - c[k] * c[l]);
        }
    }
    BodyInertia *b = &body[N_LINKS - 1];
    const double *p = CHAIN_TIP_TRANSLATION, pp = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
    b->m += payload;
    for (int k = 0; k < 3; k++) {
        b->h[k] += payload * p[k];
        for (int l = 0; l < 3; l++) b->ibar[3 * k + l] += payload * ((k == l) * pp - p[k] * p[l]);
    }
}
#endif

/* a x b */
static inline void FN(cross)(const SCALAR *a, const SCALAR *b, SCALAR *out)
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

/* The transform parent -> body i at joint position q: the placement R, t then the joint's
 * motion. Revolute, by Rodrigues: R Rot(a, q) = R + sin q (R K) + (1 - cos q) (R K^2),
 * K = [a]x, with R K and R K^2 from chain.h; prismatic: origin t + (R a) q. */
static inline void FN(joint_transform)(int i, SCALAR q, SCALAR *E, SCALAR *r)
{
    const double *R = CHAIN_ROTATION[i], *t = CHAIN_TRANSLATION[i];
    if (CHAIN_KIND[i] == 0) {
        const double *RK = CHAIN_ROTATION_K[i], *RKK = CHAIN_ROTATION_KK[i];
        const SCALAR s = sin(q), c1 = 1 - cos(q);
        for (int k = 0; k < 3; k++) {
            r[k] = t[k];
            for (int l = 0; l < 3; l++) /* E = (R Rot)^T */
                E[3 * k + l] = R[3 * l + k] + s * RK[3 * l + k] + c1 * RKK[3 * l + k];
        }
    } else {
        for (int k = 0; k < 3; k++) {
            r[k] = t[k] + CHAIN_ROTATED_AXIS[i][k] * q;
            for (int l = 0; l < 3; l++) E[3 * k + l] = R[3 * l + k];
        }
    }
}

/* out = E x for 3-vectors; FN(rotate_back): out = E^T x */
static inline void FN(rotate)(const SCALAR *E, const SCALAR *x, SCALAR *out)
{
    for (int k = 0; k < 3; k++) out[k] = E[3 * k] * x[0] + E[3 * k + 1] * x[1] + E[3 * k + 2] * x[2];
}

static inline void FN(rotate_back)(const SCALAR *E, const SCALAR *x, SCALAR *out)
{
    for (int k = 0; k < 3; k++) out[k] = E[k] * x[0] + E[3 + k] * x[1] + E[6 + k] * x[2];
}

/* A motion vector from the parent's coordinates into the body's: X m. */
static inline void FN(motion_to_body)(const SCALAR *E, const SCALAR *r, const SCALAR *m, SCALAR *out)
{
    SCALAR rw[3], v[3];
    FN(cross)(r, m, rw);
    for (int k = 0; k < 3; k++) v[k] = m[3 + k] - rw[k];
    FN(rotate)(E, m, out);
    FN(rotate)(E, v, &out[3]);
}

/* A force from the body's coordinates into the parent's: X^T f. */
static inline void FN(force_to_parent)(const SCALAR *E, const SCALAR *r, const SCALAR *f, SCALAR *out)
{
    SCALAR rf[3];
    FN(rotate_back)(E, &f[3], &out[3]);
    FN(rotate_back)(E, f, out);
    FN(cross)(r, &out[3], rf);
    for (int k = 0; k < 3; k++) out[k] += rf[k];
}

/* v x* f (the spatial force cross product) */
static inline void FN(cross_force)(const SCALAR *v, const SCALAR *f, SCALAR *out)
{
    SCALAR a[3], b[3];
    FN(cross)(v, f, a);
    FN(cross)(&v[3], &f[3], b);
    for (int k = 0; k < 3; k++) out[k] = a[k] + b[k];
    FN(cross)(v, &f[3], &out[3]);
}

/* v x m (the spatial motion cross product) */
static inline void FN(cross_motion)(const SCALAR *v, const SCALAR *m, SCALAR *out)
{
    SCALAR a[3], b[3];
    FN(cross)(v, m, out);
    FN(cross)(v, &m[3], a);
    FN(cross)(&v[3], m, b);
    for (int k = 0; k < 3; k++) out[3 + k] = a[k] + b[k];
}

/* A body's spatial inertia times a motion vector. */
static inline void FN(inertia_times)(const BodyInertia *b, const SCALAR *m, SCALAR *out)
{
    const SCALAR h[3] = {b->h[0], b->h[1], b->h[2]};
    SCALAR hv[3], hw[3];
    FN(cross)(h, &m[3], hv);
    FN(cross)(h, m, hw);
    for (int k = 0; k < 3; k++) {
        out[k] = b->ibar[3 * k] * m[0] + b->ibar[3 * k + 1] * m[1] + b->ibar[3 * k + 2] * m[2] + hv[k];
        out[3 + k] = b->m * m[3 + k] - hw[k];
    }
}

/* The 6x6 matrix of a body's spatial inertia. */
static inline void FN(inertia_matrix)(const BodyInertia *b, SCALAR *out)
{
    const double *h = b->h;
    const double hx[9] = {0, -h[2], h[1], h[2], 0, -h[0], -h[1], h[0], 0};
    for (int k = 0; k < 3; k++)
        for (int l = 0; l < 3; l++) {
            out[6 * k + l] = b->ibar[3 * k + l];
            out[6 * k + 3 + l] = hx[3 * k + l];
            out[6 * (3 + k) + l] = -hx[3 * k + l];
            out[6 * (3 + k) + 3 + l] = (k == l) * b->m;
        }
}

/* M = r x M, column by column (3x3, row-major). */
static inline void FN(cross_columns)(const SCALAR *r, const SCALAR *M, SCALAR *out)
{
    for (int l = 0; l < 3; l++) {
        out[l] = r[1] * M[6 + l] - r[2] * M[3 + l];
        out[3 + l] = r[2] * M[l] - r[0] * M[6 + l];
        out[6 + l] = r[0] * M[3 + l] - r[1] * M[l];
    }
}

/* out = E^T S E (3x3, row-major); S symmetric if `symmetric` (then only half is computed). */
static inline void FN(rotate_block)(const SCALAR *E, const SCALAR *S, int symmetric, SCALAR *out)
{
    SCALAR t[9]; /* S E */
    for (int k = 0; k < 3; k++)
        for (int l = 0; l < 3; l++)
            t[3 * k + l] = S[3 * k] * E[l] + S[3 * k + 1] * E[3 + l] + S[3 * k + 2] * E[6 + l];
    for (int k = 0; k < 3; k++)
        for (int l = symmetric ? k : 0; l < 3; l++) {
            out[3 * k + l] = E[k] * t[l] + E[3 + k] * t[3 + l] + E[6 + k] * t[6 + l];
            if (symmetric) out[3 * l + k] = out[3 * k + l];
        }
}

/* out += X^T I X: a symmetric 6x6 inertia in the body's coordinates, I = child - U U^T inv_d
 * (ABA's articulated inertia seen through the joint; U = NULL for child alone), added to the
 * parent's. X = [1 0; -r'x 1] diag(E, E) with r' = E r (the body's origin in its own frame),
 * so with the blocks I = [A B; B^T C]: first shift, A + (r'x B^T) + (r'x B^T)^T - r'x C r'x,
 * B + r'x C, C, then rotate each block back, E^T . E. */
static void FN(inertia_to_parent)(const SCALAR *E, const SCALAR *r, const SCALAR *child,
                                  const SCALAR *U, SCALAR inv_d, SCALAR *out)
{
    SCALAR A[9], B[9], C[9], rp[3], Bt[9], rBt[9], rC[9], rCr[9], As[9], Bs[9], blk[9];
    SCALAR w[6] = {0, 0, 0, 0, 0, 0}; /* U inv_d */
    if (U)
        for (int k = 0; k < 6; k++) w[k] = U[k] * inv_d;
    for (int k = 0; k < 3; k++)
        for (int l = 0; l < 3; l++) {
            A[3 * k + l] = child[6 * k + l] - (U ? w[k] * U[l] : 0);
            B[3 * k + l] = Bt[3 * l + k] = child[6 * k + 3 + l] - (U ? w[k] * U[3 + l] : 0);
            C[3 * k + l] = child[6 * (3 + k) + 3 + l] - (U ? w[3 + k] * U[3 + l] : 0);
        }
    FN(rotate)(E, r, rp);
    FN(cross_columns)(rp, Bt, rBt);
    FN(cross_columns)(rp, C, rC);
    /* rC r'x = -(r'x (rC)^T)^T: rCr = r'x C r'x */
    SCALAR rCt[9], t[9];
    for (int k = 0; k < 3; k++)
        for (int l = 0; l < 3; l++) rCt[3 * k + l] = rC[3 * l + k];
    FN(cross_columns)(rp, rCt, t);
    for (int k = 0; k < 3; k++)
        for (int l = 0; l < 3; l++) rCr[3 * k + l] = -t[3 * l + k];
    for (int k = 0; k < 9; k++) Bs[k] = B[k] + rC[k];
    for (int k = 0; k < 3; k++)
        for (int l = 0; l < 3; l++)
            As[3 * k + l] = A[3 * k + l] + rBt[3 * k + l] + rBt[3 * l + k] - rCr[3 * k + l];
    FN(rotate_block)(E, As, 1, blk);
    for (int k = 0; k < 3; k++)
        for (int l = 0; l < 3; l++) out[6 * k + l] += blk[3 * k + l];
    FN(rotate_block)(E, Bs, 0, blk);
    for (int k = 0; k < 3; k++)
        for (int l = 0; l < 3; l++) {
            out[6 * k + 3 + l] += blk[3 * k + l];
            out[6 * (3 + l) + k] += blk[3 * k + l];
        }
    FN(rotate_block)(E, C, 1, blk);
    for (int k = 0; k < 3; k++)
        for (int l = 0; l < 3; l++) out[6 * (3 + k) + 3 + l] += blk[3 * k + l];
}

/* S^T f: the joint's share of a spatial force (revolute: the moment about its axis). */
static inline SCALAR FN(joint_component)(int i, const SCALAR *f)
{
    const double *a = CHAIN_AXIS[i];
    const SCALAR *part = CHAIN_KIND[i] == 0 ? f : &f[3];
    return a[0] * part[0] + a[1] * part[1] + a[2] * part[2];
}

/* out = S * s, the joint's motion at speed s. */
static inline void FN(joint_motion)(int i, SCALAR s, SCALAR *out)
{
    const double *a = CHAIN_AXIS[i];
    const int at = CHAIN_KIND[i] == 0 ? 0 : 3;
    for (int k = 0; k < 6; k++) out[k] = 0;
    for (int k = 0; k < 3; k++) out[at + k] = a[k] * s;
}

/* The transforms and body velocities of state (q, qd), and the velocity-product
 * accelerations c_i = v_i x (S_i qd_i): the first pass of RNEA and ABA. */
static void FN(kinematics)(const SCALAR *q, const SCALAR *qd, SCALAR (*E)[9], SCALAR (*r)[3],
                           SCALAR (*v)[6], SCALAR (*c)[6])
{
    for (int i = 0; i < N_LINKS; i++) {
        SCALAR vj[6];
        FN(joint_transform)(i, q[i], E[i], r[i]);
        FN(joint_motion)(i, qd[i], vj);
        const int p = CHAIN_PARENT[i];
        if (p < 0) {
            for (int k = 0; k < 6; k++) v[i][k] = 0;
        } else {
            FN(motion_to_body)(E[i], r[i], v[p], v[i]);
        }
        for (int k = 0; k < 6; k++) v[i][k] += vj[k];
        FN(cross_motion)(v[i], vj, c[i]);
    }
}

/* The base's acceleration standing in for gravity, in the base's coordinates. */
static void FN(base_acceleration)(SCALAR *a0)
{
    for (int k = 0; k < 3; k++) {
        a0[k] = 0;
        a0[3 + k] = -CHAIN_GRAVITY[k];
    }
}

/* Recursive Newton-Euler: tau = M(q) qdd + h(q, qd); with qdd NULL, tau = h(q, qd) (the
 * Coriolis, centrifugal and gravity forces). */
static void FN(inverse_dynamics)(const BodyInertia *body, const SCALAR *q, const SCALAR *qd,
                                 const SCALAR *qdd, SCALAR *tau)
{
    SCALAR E[N_LINKS][9], r[N_LINKS][3], v[N_LINKS][6], c[N_LINKS][6], a[N_LINKS][6];
    SCALAR f[N_LINKS][6], a0[6];
    FN(kinematics)(q, qd, E, r, v, c);
    FN(base_acceleration)(a0);
    for (int i = 0; i < N_LINKS; i++) {
        const int p = CHAIN_PARENT[i];
        SCALAR Iv[6], vIv[6], Ia[6];
        FN(motion_to_body)(E[i], r[i], p < 0 ? a0 : a[p], a[i]);
        for (int k = 0; k < 6; k++) a[i][k] += c[i][k];
        if (qdd) {
            SCALAR aj[6];
            FN(joint_motion)(i, qdd[i], aj);
            for (int k = 0; k < 6; k++) a[i][k] += aj[k];
        }
        FN(inertia_times)(&body[i], a[i], Ia);
        FN(inertia_times)(&body[i], v[i], Iv);
        FN(cross_force)(v[i], Iv, vIv);
        for (int k = 0; k < 6; k++) f[i][k] = Ia[k] + vIv[k];
    }
    for (int i = N_LINKS - 1; i >= 0; i--) {
        tau[i] = FN(joint_component)(i, f[i]);
        const int p = CHAIN_PARENT[i];
        if (p >= 0) {
            SCALAR fp[6];
            FN(force_to_parent)(E[i], r[i], f[i], fp);
            for (int k = 0; k < 6; k++) f[p][k] += fp[k];
        }
    }
}

/* Composite-rigid-body algorithm: the joint-space inertia matrix M(q), row-major. */
static void FN(mass_matrix)(const BodyInertia *body, const SCALAR *q, SCALAR *M)
{
    SCALAR E[N_LINKS][9], r[N_LINKS][3], Ic[N_LINKS][36];
    for (int i = 0; i < N_LINKS; i++) {
        FN(joint_transform)(i, q[i], E[i], r[i]);
        FN(inertia_matrix)(&body[i], Ic[i]);
    }
    for (int i = N_LINKS - 1; i >= 0; i--)
        if (CHAIN_PARENT[i] >= 0)
            FN(inertia_to_parent)(E[i], r[i], Ic[i], NULL, 0, Ic[CHAIN_PARENT[i]]);
    for (int i = 0; i < N_LINKS * N_LINKS; i++) M[i] = 0;
    for (int i = 0; i < N_LINKS; i++) {
        SCALAR s[6], F[6];
        FN(joint_motion)(i, 1.0, s);
        for (int k = 0; k < 6; k++) {
            F[k] = 0;
            for (int l = 0; l < 6; l++) F[k] += Ic[i][6 * k + l] * s[l];
        }
        M[i * N_LINKS + i] = FN(joint_component)(i, F);
        for (int j = i; CHAIN_PARENT[j] >= 0;) {
            SCALAR Fp[6];
            FN(force_to_parent)(E[j], r[j], F, Fp);
            for (int k = 0; k < 6; k++) F[k] = Fp[k];
            j = CHAIN_PARENT[j];
            M[i * N_LINKS + j] = M[j * N_LINKS + i] = FN(joint_component)(j, F);
        }
    }
}

/* The joint forces besides the rigid body's: viscous and Coulomb friction (smoothed as
 * fc tanh(qd / fc_vel), as the planar arm) and the constant disturbance tau_d. */
static SCALAR FN(joint_losses)(const ChainParams *p, int i, SCALAR qd)
{
    const SCALAR viscous = p->b[i] * qd + p->tau_d[i];
    return p->fc[i] == 0 ? viscous : viscous + p->fc[i] * tanh(qd / p->fc_vel[i]);
}

/* Articulated-body algorithm: qdd from M qdd + h(q, qd) + losses(qd) = tau. 0 where a
 * joint's articulated inertia vanishes (no inertia about its axis). */
static int FN(forward_dynamics)(const ChainParams *p, const BodyInertia *body, const SCALAR *q,
                                const SCALAR *qd, const SCALAR *tau, SCALAR *qdd)
{
    SCALAR E[N_LINKS][9], r[N_LINKS][3], v[N_LINKS][6], c[N_LINKS][6];
    SCALAR IA[N_LINKS][36], pA[N_LINKS][6], U[N_LINKS][6], D[N_LINKS], u[N_LINKS], a[N_LINKS][6];
    FN(kinematics)(q, qd, E, r, v, c);
    for (int i = 0; i < N_LINKS; i++) {
        SCALAR Iv[6];
        FN(inertia_matrix)(&body[i], IA[i]);
        FN(inertia_times)(&body[i], v[i], Iv);
        FN(cross_force)(v[i], Iv, pA[i]);
    }
    for (int i = N_LINKS - 1; i >= 0; i--) {
        const double *ax = CHAIN_AXIS[i];
        const int at = CHAIN_KIND[i] == 0 ? 0 : 3;
        for (int k = 0; k < 6; k++)
            U[i][k] = IA[i][6 * k + at] * ax[0] + IA[i][6 * k + at + 1] * ax[1] +
                      IA[i][6 * k + at + 2] * ax[2];
        D[i] = FN(joint_component)(i, U[i]);
        if (!(creal(D[i]) > 0)) return 0;
        u[i] = tau[i] - FN(joint_losses)(p, i, qd[i]) - FN(joint_component)(i, pA[i]);
        const int parent = CHAIN_PARENT[i];
        if (parent < 0) continue;
        /* pa = pA + Ia c + U u / D with Ia = IA - U U^T / D */
        const SCALAR inv_d = 1 / D[i];
        SCALAR Uc = 0, pa[6], pp[6];
        for (int k = 0; k < 6; k++) Uc += U[i][k] * c[i][k];
        const SCALAR share = (u[i] - Uc) * inv_d;
        for (int k = 0; k < 6; k++) {
            pa[k] = pA[i][k] + U[i][k] * share;
            for (int l = 0; l < 6; l++) pa[k] += IA[i][6 * k + l] * c[i][l];
        }
        FN(inertia_to_parent)(E[i], r[i], IA[i], U[i], inv_d, IA[parent]);
        FN(force_to_parent)(E[i], r[i], pa, pp);
        for (int k = 0; k < 6; k++) pA[parent][k] += pp[k];
    }
    SCALAR a0[6];
    FN(base_acceleration)(a0);
    for (int i = 0; i < N_LINKS; i++) {
        const int parent = CHAIN_PARENT[i];
        FN(motion_to_body)(E[i], r[i], parent < 0 ? a0 : a[parent], a[i]);
        for (int k = 0; k < 6; k++) a[i][k] += c[i][k];
        SCALAR Ua = 0;
        for (int k = 0; k < 6; k++) Ua += U[i][k] * a[i][k];
        qdd[i] = (u[i] - Ua) / D[i];
        SCALAR aj[6];
        FN(joint_motion)(i, qdd[i], aj);
        for (int k = 0; k < 6; k++) a[i][k] += aj[k];
    }
    return 1;
}

/* Kinetic plus potential energy (zero potential at the base's origin). */
static SCALAR FN(energy)(const BodyInertia *body, const SCALAR *q, const SCALAR *qd)
{
    SCALAR E[N_LINKS][9], r[N_LINKS][3], v[N_LINKS][6], c[N_LINKS][6];
    SCALAR R[N_LINKS][9], o[N_LINKS][3]; /* each body's orientation and origin in the base */
    FN(kinematics)(q, qd, E, r, v, c);
    SCALAR kinetic = 0, potential = 0;
    for (int i = 0; i < N_LINKS; i++) {
        const int p = CHAIN_PARENT[i];
        for (int k = 0; k < 3; k++) {
            o[i][k] = r[i][k];
            for (int l = 0; l < 3; l++) R[i][3 * k + l] = E[i][3 * l + k];
        }
        if (p >= 0) {
            SCALAR Rp[9], op[3];
            for (int k = 0; k < 3; k++) {
                op[k] = o[p][k];
                for (int l = 0; l < 3; l++)
                    op[k] += R[p][3 * k + l] * r[i][l];
                for (int l = 0; l < 3; l++)
                    Rp[3 * k + l] = R[p][3 * k] * R[i][l] + R[p][3 * k + 1] * R[i][3 + l] +
                                    R[p][3 * k + 2] * R[i][6 + l];
            }
            for (int k = 0; k < 3; k++) o[i][k] = op[k];
            for (int k = 0; k < 9; k++) R[i][k] = Rp[k];
        }
        SCALAR Iv[6], h[3] = {body[i].h[0], body[i].h[1], body[i].h[2]}, Rh[3];
        FN(inertia_times)(&body[i], v[i], Iv);
        for (int k = 0; k < 6; k++) kinetic += 0.5 * v[i][k] * Iv[k];
        FN(rotate)(R[i], h, Rh); /* m (R c + o): the first moment in the base */
        for (int k = 0; k < 3; k++) potential -= CHAIN_GRAVITY[k] * (Rh[k] + body[i].m * o[i][k]);
    }
    return kinetic + potential;
}
