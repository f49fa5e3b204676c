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
    const double *b, *fc, *tau_d;
    double fc_vel, payload;
} ChainParams;

static ChainParams chain_params(const ModelState *s)
{
    const double *v = s->v;
    ChainParams p = {&v[VR_b], &v[VR_fc], &v[VR_tau_d], v[VR_fc_vel], v[VR_payload]};
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
static void FN(cross)(const SCALAR *a, const SCALAR *b, SCALAR *out)
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

/* The transform parent -> body i at joint position q: the placement then the joint's
 * motion (a rotation about, or a translation along, its axis). */
static void FN(joint_transform)(int i, SCALAR q, SCALAR *E, SCALAR *r)
{
    const double *R = CHAIN_ROTATION[i], *a = CHAIN_AXIS[i];
    SCALAR rot[9]; /* parent <- body rotation, R Rot(a, q) */
    if (CHAIN_KIND[i] == 0) {
        const SCALAR s = sin(q), c1 = 1 - cos(q);
        /* Rodrigues: Rot = 1 + s K + (1 - cos) K^2, K = [a]x */
        const double K[9] = {0, -a[2], a[1], a[2], 0, -a[0], -a[1], a[0], 0};
        SCALAR J[9];
        for (int k = 0; k < 3; k++)
            for (int l = 0; l < 3; l++) {
                double k2 = 0;
                for (int m = 0; m < 3; m++) k2 += K[3 * k + m] * K[3 * m + l];
                J[3 * k + l] = (k == l) + s * K[3 * k + l] + c1 * k2;
            }
        for (int k = 0; k < 3; k++)
            for (int l = 0; l < 3; l++)
                rot[3 * k + l] = R[3 * k] * J[l] + R[3 * k + 1] * J[3 + l] + R[3 * k + 2] * J[6 + l];
        for (int k = 0; k < 3; k++) r[k] = CHAIN_TRANSLATION[i][k];
    } else {
        for (int k = 0; k < 9; k++) rot[k] = R[k];
        for (int k = 0; k < 3; k++)
            r[k] = CHAIN_TRANSLATION[i][k] + (R[3 * k] * a[0] + R[3 * k + 1] * a[1] + R[3 * k + 2] * a[2]) * q;
    }
    for (int k = 0; k < 3; k++)
        for (int l = 0; l < 3; l++) E[3 * k + l] = rot[3 * l + k];
}

/* out = E x for 3-vectors; FN(rotate_back): out = E^T x */
static void FN(rotate)(const SCALAR *E, const SCALAR *x, SCALAR *out)
{
    for (int k = 0; k < 3; k++) out[k] = E[3 * k] * x[0] + E[3 * k + 1] * x[1] + E[3 * k + 2] * x[2];
}

static void FN(rotate_back)(const SCALAR *E, const SCALAR *x, SCALAR *out)
{
    for (int k = 0; k < 3; k++) out[k] = E[k] * x[0] + E[3 + k] * x[1] + E[6 + k] * x[2];
}

/* A motion vector from the parent's coordinates into the body's: X m. */
static void FN(motion_to_body)(const SCALAR *E, const SCALAR *r, const SCALAR *m, SCALAR *out)
{
    SCALAR rw[3], v[3];
    FN(cross)(r, m, rw);
    for (int k = 0; k < 3; k++) v[k] = m[3 + k] - rw[k];
    FN(rotate)(E, m, out);
    FN(rotate)(E, v, &out[3]);
}

/* A force from the body's coordinates into the parent's: X^T f. */
static void FN(force_to_parent)(const SCALAR *E, const SCALAR *r, const SCALAR *f, SCALAR *out)
{
    SCALAR rf[3];
    FN(rotate_back)(E, &f[3], &out[3]);
    FN(rotate_back)(E, f, out);
    FN(cross)(r, &out[3], rf);
    for (int k = 0; k < 3; k++) out[k] += rf[k];
}

/* v x* f (the spatial force cross product) */
static void FN(cross_force)(const SCALAR *v, const SCALAR *f, SCALAR *out)
{
    SCALAR a[3], b[3];
    FN(cross)(v, f, a);
    FN(cross)(&v[3], &f[3], b);
    for (int k = 0; k < 3; k++) out[k] = a[k] + b[k];
    FN(cross)(v, &f[3], &out[3]);
}

/* v x m (the spatial motion cross product) */
static void FN(cross_motion)(const SCALAR *v, const SCALAR *m, SCALAR *out)
{
    SCALAR a[3], b[3];
    FN(cross)(v, m, out);
    FN(cross)(v, &m[3], a);
    FN(cross)(&v[3], m, b);
    for (int k = 0; k < 3; k++) out[3 + k] = a[k] + b[k];
}

/* A body's spatial inertia times a motion vector. */
static void FN(inertia_times)(const BodyInertia *b, const SCALAR *m, SCALAR *out)
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
static void FN(inertia_matrix)(const BodyInertia *b, SCALAR *out)
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

/* out += X^T I X: a 6x6 inertia in the body's coordinates added to the parent's. With the
 * blocks child = [A B; B^T C]: rotate each block back (E^T . E), then shift by r:
 * A + r x B^T - B r x - r x C r x, B + r x C, C. */
static void FN(inertia_to_parent)(const SCALAR *E, const SCALAR *r, const SCALAR *child, SCALAR *out)
{
    SCALAR blk[3][9], rx[9] = {0, -r[2], r[1], r[2], 0, -r[0], -r[1], r[0], 0};
    for (int b = 0; b < 3; b++) { /* A, B, C rotated back */
        const int row = b == 2 ? 3 : 0, col = b == 0 ? 0 : 3;
        SCALAR t[9];
        for (int k = 0; k < 3; k++)
            for (int l = 0; l < 3; l++)
                t[3 * k + l] = child[6 * (row + k) + col] * E[l] + child[6 * (row + k) + col + 1] * E[3 + l] +
                               child[6 * (row + k) + col + 2] * E[6 + l];
        for (int k = 0; k < 3; k++)
            for (int l = 0; l < 3; l++)
                blk[b][3 * k + l] = E[k] * t[l] + E[3 + k] * t[3 + l] + E[6 + k] * t[6 + l];
    }
    const SCALAR *A = blk[0], *B = blk[1], *C = blk[2];
    SCALAR rxC[9], Bn[9];
    for (int k = 0; k < 3; k++)
        for (int l = 0; l < 3; l++) {
            rxC[3 * k + l] = rx[3 * k] * C[l] + rx[3 * k + 1] * C[3 + l] + rx[3 * k + 2] * C[6 + l];
        }
    for (int k = 0; k < 9; k++) Bn[k] = B[k] + rxC[k];
    for (int k = 0; k < 3; k++)
        for (int l = 0; l < 3; l++) {
            /* A - B rx + rx B^T - rx C rx = A + rx B^T - Bn rx (Bn = B + rx C) */
            SCALAR a = A[3 * k + l];
            for (int m = 0; m < 3; m++) a += rx[3 * k + m] * B[3 * l + m] - Bn[3 * k + m] * rx[3 * m + l];
            out[6 * k + l] += a;
            out[6 * k + 3 + l] += Bn[3 * k + l];
            out[6 * (3 + l) + k] += Bn[3 * k + l];
            out[6 * (3 + k) + 3 + l] += C[3 * k + l];
        }
}

/* S^T f: the joint's share of a spatial force (revolute: the moment about its axis). */
static SCALAR FN(joint_component)(int i, const SCALAR *f)
{
    const double *a = CHAIN_AXIS[i];
    const SCALAR *part = CHAIN_KIND[i] == 0 ? f : &f[3];
    return a[0] * part[0] + a[1] * part[1] + a[2] * part[2];
}

/* out = S * s, the joint's motion at speed s. */
static void FN(joint_motion)(int i, SCALAR s, SCALAR *out)
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
        if (CHAIN_PARENT[i] >= 0) FN(inertia_to_parent)(E[i], r[i], Ic[i], Ic[CHAIN_PARENT[i]]);
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
    return p->b[i] * qd + p->fc[i] * tanh(qd / p->fc_vel) + p->tau_d[i];
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
        SCALAR Ia[36], pa[6], pp[6];
        for (int k = 0; k < 6; k++)
            for (int l = 0; l < 6; l++) Ia[6 * k + l] = IA[i][6 * k + l] - U[i][k] * U[i][l] / D[i];
        for (int k = 0; k < 6; k++) {
            pa[k] = pA[i][k] + U[i][k] * u[i] / D[i];
            for (int l = 0; l < 6; l++) pa[k] += Ia[6 * k + l] * c[i][l];
        }
        FN(inertia_to_parent)(E[i], r[i], Ia, IA[parent]);
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
