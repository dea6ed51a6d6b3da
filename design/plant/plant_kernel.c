/* Fixed-step plant kernel of smartjoint.design.plant.fixed_step (compiled on first use through cffi).
 *
 * The same algorithm as fixed_step._PythonKernel, statement for statement, so that the two agree
 * to round-off (tests/test_simulate.py): exact first-order-hold modal step, implicit Newton
 * solve in the joint velocities with an analytic Jacobian, exponential bristle integrator,
 * recursive step halving where a falling Stribeck branch leaves no unique root, exact energy
 * books per step (discretisation.work_coefficients) and recording.  The module docstring of fixed_step.py
 * documents the scheme; the structs are declared in plant_kernel.h.
 *
 * Layout (structure of arrays, so the per-mode loops vectorise): the state is x (2, n) with rows
 * eta_dot and omega*eta; ET (l, n) and HT (m, n) are the transposed input matrices; Vy and Dy
 * (ny, n); discretisation level d (step / 2^d): Phi (4, n) rows p00 p01 p10 p11, gamma0 and
 * gamma1 (2, n), G (l, l), book (18, n) at offsets d*4n, d*2n, d*l*l, d*18n.  q = E u_R (n) is the modal joint
 * force of the current u_R, kept so that a step needs E only twice per mode.
 */
#include <math.h>
#include <string.h>

#include "plant_kernel.h"

#define SJ_TOLERANCE 1e-12
#define SJ_ITERATIONS 30
#define SJ_SERIES 1e-4
#define SJ_MAX_DISTURBANCES 64

static double level_of(const sj_plant *p, int j, double v)
{
    return p->fc[j] + p->fd[j] * exp(-(v / p->vs[j]) * (v / p->vs[j]));
}

static double sign_of(double v) { return v > 0.0 ? 1.0 : (v < 0.0 ? -1.0 : 0.0); }

/* sum_i a_i b_i with four partial sums (independent chains; BLAS-like round-off). */
static double dot(const double *a, const double *b, int n)
{
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    int i = 0;
    for (; i + 4 <= n; i += 4) {
        s0 += a[i] * b[i]; s1 += a[i + 1] * b[i + 1]; s2 += a[i + 2] * b[i + 2]; s3 += a[i + 3] * b[i + 3];
    }
    for (; i < n; ++i) s0 += a[i] * b[i];
    return (s0 + s1) + (s2 + s3);
}

/* out = M^T y for M (k, n): out_i = sum_j M[j, i] y_j (vectorises over i). */
static void combine(const double *M, const double *y, int k, int n, double *out)
{
    for (int i = 0; i < n; ++i) out[i] = 0.0;
    for (int j = 0; j < k; ++j) {
        const double *row = M + (size_t)j * (size_t)n;
        double c = y[j];
        for (int i = 0; i < n; ++i) out[i] += row[i] * c;
    }
}

static int all_zero(const double *a, int n)
{
    for (int i = 0; i < n; ++i) if (a[i] != 0.0) return 0;
    return 1;
}

/* Bristle step of joint j (joints.JointLaws.advance) and d phi+ / d v_end. */
static double advance_bristle(const sj_plant *p, int j, double phi, double v_start, double v_end, double h,
                              double *derivative)
{
    double mid = 0.5 * (v_start + v_end);
    double g = level_of(p, j, mid);
    double dg = -2.0 * mid / (p->vs[j] * p->vs[j]) * (g - p->fc[j]);
    double x = p->s0[j] * fabs(mid) / g * h;
    double dx = 0.5 * p->s0[j] * h * (sign_of(mid) * g - fabs(mid) * dg) / (g * g);
    double phi1, phi2, dphi1, dphi2;
    double decay_minus_one = expm1(-x);  /* one call serves both e^-x and phi1 */
    double decay = 1.0 + decay_minus_one;
    if (x < SJ_SERIES) {
        phi1 = 1.0 - x / 2.0 + x * x / 6.0;
        phi2 = 0.5 - x / 6.0 + x * x / 24.0;
        dphi1 = -0.5 + x / 3.0;
        dphi2 = -1.0 / 6.0 + x / 12.0;
    } else {
        phi1 = -decay_minus_one / x;
        phi2 = (1.0 - phi1) / x;
        dphi1 = (decay - phi1) / x;
        dphi2 = (-dphi1 - phi2) / x;
    }
    double out = decay * phi + h * ((phi1 - phi2) * v_start + phi2 * v_end);
    if (out > p->bound[j]) { *derivative = 0.0; return p->bound[j]; }
    if (out < -p->bound[j]) { *derivative = 0.0; return -p->bound[j]; }
    *derivative = (-decay * phi + h * ((dphi1 - dphi2) * v_start + dphi2 * v_end)) * dx + h * phi2;
    return out;
}

/* Friction force u_R (Eq. 2) of joint j and its partial derivatives in v and phi. */
static double friction(const sj_plant *p, int j, double v, double phi, double normal_force,
                       double *d_v, double *d_phi)
{
    double g = level_of(p, j, v);
    double dg = -2.0 * v / (p->vs[j] * p->vs[j]) * (g - p->fc[j]);
    double phidot = v - p->s0[j] * fabs(v) / g * phi;
    double scale = p->arm[j] * normal_force;
    double dphidot_dv = 1.0 - p->s0[j] * phi * (sign_of(v) * g - fabs(v) * dg) / (g * g);
    *d_v = scale * (p->s1[j] * dphidot_dv + p->s2[j]);
    *d_phi = scale * (p->s0[j] - p->s1[j] * p->s0[j] * fabs(v) / g);
    return scale * (p->s0[j] * phi + p->s1[j] * phidot + p->s2[j] * v);
}

/* Solve the l x l system J c = r in place (partial pivoting); returns det(J). */
static double solve_small(int l, double *J, double *r)
{
    double det = 1.0;
    for (int c = 0; c < l; ++c) {
        int pivot = c;
        for (int i = c + 1; i < l; ++i)
            if (fabs(J[i * l + c]) > fabs(J[pivot * l + c])) pivot = i;
        if (pivot != c) {
            for (int k = 0; k < l; ++k) {
                double t = J[c * l + k]; J[c * l + k] = J[pivot * l + k]; J[pivot * l + k] = t;
            }
            double t = r[c]; r[c] = r[pivot]; r[pivot] = t;
            det = -det;
        }
        det *= J[c * l + c];
        if (J[c * l + c] == 0.0) return 0.0;
        for (int i = c + 1; i < l; ++i) {
            double f = J[i * l + c] / J[c * l + c];
            for (int k = c; k < l; ++k) J[i * l + k] -= f * J[c * l + k];
            r[i] -= f * r[c];
        }
    }
    for (int c = l - 1; c >= 0; --c) {
        double s = r[c];
        for (int k = c + 1; k < l; ++k) s -= J[c * l + k] * r[k];
        r[c] = s / J[c * l + c];
    }
    return det;
}

/* Newton on R(v) = v - v_free + G u_R(v) (fixed_step._solve_joints). 0 on success. */
static int solve_joints(const sj_plant *p, sj_state *s, const double *G, const double *v_free, double h,
                        double *v_new, double *phi_new, double *u_new, double *residual_out)
{
    int l = p->l;
    double *w = p->work + 5 * p->n;
    double *scale = w, *du = w + l, *residual = w + 2 * l, *J = w + 3 * l;
    double worst = 0.0;
    for (int j = 0; j < l; ++j) {
        /* Start from the friction force held at its value of the step start: in stick the
         * solution is close to it, which saves a Newton iteration over starting without it. */
        double held = v_free[j];
        for (int k = 0; k < l; ++k) held -= G[j * l + k] * s->u[k];
        v_new[j] = held;
        scale[j] = fmax(fabs(v_free[j]), p->vs[j]) + fabs(s->v[j]);
    }
    for (int it = 0; it < SJ_ITERATIONS; ++it) {
        for (int j = 0; j < l; ++j) {
            double dphi, du_dv, du_dphi;
            phi_new[j] = advance_bristle(p, j, s->phi[j], s->v[j], v_new[j], h, &dphi);
            u_new[j] = friction(p, j, v_new[j], phi_new[j], s->fn[j], &du_dv, &du_dphi);
            du[j] = du_dv + du_dphi * dphi;
        }
        int converged = 1;
        worst = 0.0;
        for (int i = 0; i < l; ++i) {
            double r = v_new[i] - v_free[i];
            for (int j = 0; j < l; ++j) r += G[i * l + j] * u_new[j];
            residual[i] = r;
            if (!(fabs(r) <= SJ_TOLERANCE * scale[i])) converged = 0;
            worst = fmax(worst, fabs(r));
        }
        if (converged) return 0;
        for (int i = 0; i < l; ++i)
            for (int j = 0; j < l; ++j) J[i * l + j] = (i == j ? 1.0 : 0.0) + G[i * l + j] * du[j];
        if (!(solve_small(l, J, residual) > 0.0)) break;  /* a falling branch: no unique root */
        double limit = 0.0;
        for (int j = 0; j < l; ++j) limit = fmax(limit, fabs(residual[j]) / scale[j]);
        for (int j = 0; j < l; ++j) v_new[j] -= limit <= 1.0 ? residual[j] : residual[j] / limit;
    }
    *residual_out = worst;
    return -1;
}

/* Free response x_free = Phi x + gamma0 f_a + gamma1 f_b (f_a = p_a - q, f_b = p_b, p = H w), and
 * v_free = E^T x_free[0] accumulated in the same pass, four joints at a time (ET is padded
 * with zero rows to a multiple of four) with four partial sums per joint. */
static void free_response(const sj_plant *p, const sj_state *s, const double *Phi, const double *a,
                          const double *b, const double *w_a, const double *w_b, int disturbed, double *v_free)
{
    int n = p->n, m = p->m, groups = (p->l + 3) / 4;
    double *free0 = p->work, *free1 = p->work + n, *p_a = p->work + 2 * n, *p_b = p->work + 3 * n;
    const double *x0 = s->x, *x1 = s->x + n;
    if (!disturbed) {  /* after the pulse: the common case */
        for (int i = 0; i < n; ++i) {
            free0[i] = Phi[i] * x0[i] + Phi[n + i] * x1[i] - a[i] * s->q[i];
            free1[i] = Phi[2 * n + i] * x0[i] + Phi[3 * n + i] * x1[i] - a[n + i] * s->q[i];
        }
    } else {
        combine(p->HT, w_a, m, n, p_a);
        combine(p->HT, w_b, m, n, p_b);
        for (int i = 0; i < n; ++i) {
            double f_a = p_a[i] - s->q[i];
            free0[i] = Phi[i] * x0[i] + Phi[n + i] * x1[i] + a[i] * f_a + b[i] * p_b[i];
            free1[i] = Phi[2 * n + i] * x0[i] + Phi[3 * n + i] * x1[i] + a[n + i] * f_a + b[n + i] * p_b[i];
        }
    }
    for (int g = 0; g < groups; ++g) {
        const double *e0 = p->ET + (size_t)(4 * g) * (size_t)n, *e1 = e0 + n, *e2 = e1 + n, *e3 = e2 + n;
        double s0[4] = {0.0, 0.0, 0.0, 0.0}, s1[4] = {0.0, 0.0, 0.0, 0.0};
        double s2[4] = {0.0, 0.0, 0.0, 0.0}, s3[4] = {0.0, 0.0, 0.0, 0.0};
        int i = 0;
        for (; i + 4 <= n; i += 4)
            for (int k = 0; k < 4; ++k) {
                double f = free0[i + k];
                s0[k] += e0[i + k] * f; s1[k] += e1[i + k] * f; s2[k] += e2[i + k] * f; s3[k] += e3[i + k] * f;
            }
        for (; i < n; ++i) {
            double f = free0[i];
            s0[0] += e0[i] * f; s1[0] += e1[i] * f; s2[0] += e2[i] * f; s3[0] += e3[i] * f;
        }
        double sums[4] = {(s0[0] + s0[1]) + (s0[2] + s0[3]), (s1[0] + s1[1]) + (s1[2] + s1[3]),
                          (s2[0] + s2[1]) + (s2[2] + s2[3]), (s3[0] + s3[1]) + (s3[2] + s3[3])};
        for (int k = 0; k < 4 && 4 * g + k < p->l; ++k) v_free[4 * g + k] = sums[k];
    }
}

/* Books the exact work of the step (discretisation.work_coefficients, step_works) from the start state
 * x, the modal joint force q (start) and q_new (end) and, if disturbed, p = H w at both ends;
 * then x = x_free - gamma1 q_new and q = q_new.  Four partial sums per work (vectorisable). */
static void book_and_update(const sj_plant *p, sj_state *s, const double *c, const double *b, const double *q_new_in,
                            int disturbed)
{
    int n = p->n, i = 0;
    const double *restrict free0 = p->work, *restrict free1 = p->work + n;
    const double *restrict p_a = p->work + 2 * n, *restrict p_b = p->work + 3 * n, *restrict q_new = q_new_in;
    const double *restrict b0 = b, *restrict b1 = b + n;
    double *restrict x0 = s->x, *restrict x1 = s->x + n, *restrict q = s->q;
    double w_in[4] = {0.0, 0.0, 0.0, 0.0}, w_joints[4] = {0.0, 0.0, 0.0, 0.0}, w_damping[4] = {0.0, 0.0, 0.0, 0.0};
    const double *restrict c0 = c, *restrict c1 = c + n, *restrict c2 = c + 2 * n, *restrict c3 = c + 3 * n;
    const double *restrict c4 = c + 4 * n, *restrict c5 = c + 5 * n, *restrict c6 = c + 6 * n;
    const double *restrict c7 = c + 7 * n, *restrict c8 = c + 8 * n, *restrict c9 = c + 9 * n;
    const double *restrict c10 = c + 10 * n, *restrict c11 = c + 11 * n, *restrict c12 = c + 12 * n;
    const double *restrict c13 = c + 13 * n, *restrict c14 = c + 14 * n, *restrict c15 = c + 15 * n;
    const double *restrict c16 = c + 16 * n, *restrict c17 = c + 17 * n;
#define SJ_BOOK(k, pa, pb)                                                                                      \
    do {                                                                                                        \
        int j = i + (k);                                                                                        \
        double y0 = x0[j], y1 = x1[j], fa = (pa) - q[j], fb = (pb) - q_new[j];                                  \
        double m0 = c0[j] * y0 + c1[j] * y1 + c2[j] * fa + c3[j] * fb;                                          \
        double m1 = c4[j] * y0 + c5[j] * y1 + c6[j] * fa + c7[j] * fb;                                          \
        w_damping[k] += y0 * (c8[j] * y0 + c12[j] * y1 + c13[j] * fa + c14[j] * fb)                             \
                        + y1 * (c9[j] * y1 + c15[j] * fa + c16[j] * fb) + fa * (c10[j] * fa + c17[j] * fb)       \
                        + c11[j] * fb * fb;                                                                     \
        w_in[k] += (pa) * m0 + ((pb) - (pa)) * m1;                                                              \
        w_joints[k] += q[j] * m0 + (q_new[j] - q[j]) * m1;                                                      \
        x0[j] = free0[j] - b0[j] * q_new[j];                                                                    \
        x1[j] = free1[j] - b1[j] * q_new[j];                                                                    \
        q[j] = q_new[j];                                                                                        \
    } while (0)
    if (disturbed) {
        for (; i + 4 <= n; i += 4) {
            SJ_BOOK(0, p_a[j], p_b[j]); SJ_BOOK(1, p_a[j], p_b[j]); SJ_BOOK(2, p_a[j], p_b[j]); SJ_BOOK(3, p_a[j], p_b[j]);
        }
        for (; i < n; ++i) SJ_BOOK(0, p_a[j], p_b[j]);
    } else {  /* after the pulse: no input work */
        for (; i + 4 <= n; i += 4) {
            SJ_BOOK(0, 0.0, 0.0); SJ_BOOK(1, 0.0, 0.0); SJ_BOOK(2, 0.0, 0.0); SJ_BOOK(3, 0.0, 0.0);
        }
        for (; i < n; ++i) SJ_BOOK(0, 0.0, 0.0);
    }
#undef SJ_BOOK
    s->work_in += (w_in[0] + w_in[1]) + (w_in[2] + w_in[3]);
    s->work_joints += (w_joints[0] + w_joints[1]) + (w_joints[2] + w_joints[3]);
    s->work_damping += (w_damping[0] + w_damping[1]) + (w_damping[2] + w_damping[3]);
}

/* x = x_free - gamma1 q_new and q = q_new, with the books if they are kept. */
static void update(const sj_plant *p, sj_state *s, const double *c, const double *b, const double *q_new,
                   int disturbed)
{
    int n = p->n;
    if (p->books) {
        book_and_update(p, s, c, b, q_new, disturbed);
        return;
    }
    for (int i = 0; i < n; ++i) {
        s->x[i] = p->work[i] - b[i] * q_new[i];
        s->x[n + i] = p->work[n + i] - b[n + i] * q_new[i];
    }
    memcpy(s->q, q_new, sizeof(double) * (size_t)n);
}

/* One step of length step/2^depth from w_a to w_b; halves itself where the solve fails. */
static int advance(const sj_plant *p, sj_state *s, const double *w_a, const double *w_b, int depth)
{
    int n = p->n, l = p->l, m = p->m, groups = (l + 3) / 4;
    const double *Phi = p->phi + (size_t)(depth * n * 4), *a = p->g0 + (size_t)(depth * n * 2);
    const double *b = p->g1 + (size_t)(depth * n * 2), *G = p->G + (size_t)(depth * l * l);
    const double *c = p->book + (size_t)(depth * n * 18);
    double h = p->step / (double)(1L << depth);
    double *q_new = p->work + 4 * n;
    double *w = p->work + 5 * n + 3 * l + l * l;
    double *v_free = w, *v_new = w + l, *phi_new = w + 2 * l, *u_new = w + 3 * l;
    int disturbed = !(all_zero(w_a, m) && all_zero(w_b, m));
    free_response(p, s, Phi, a, b, w_a, w_b, disturbed, v_free);
    if (l == 0) {
        memset(q_new, 0, sizeof(double) * (size_t)n);
        update(p, s, c, b, q_new, disturbed);
        return 0;
    }
    double residual = 0.0;
    if (solve_joints(p, s, G, v_free, h, v_new, phi_new, u_new, &residual) != 0) {
        if (depth >= p->levels - 1) {
            s->failed_step = h;
            s->failed_residual = residual;
            return -1;
        }
        double w_mid[SJ_MAX_DISTURBANCES];  /* linear in the step, as the first-order hold assumes */
        for (int k = 0; k < m; ++k) w_mid[k] = 0.5 * (w_a[k] + w_b[k]);
        if (advance(p, s, w_a, w_mid, depth + 1) != 0) return -1;
        return advance(p, s, w_mid, w_b, depth + 1);
    }
    double u4[4];
    for (int j = 0; j < l; ++j) {
        s->phi[j] = phi_new[j];
        s->u[j] = u_new[j];
    }
    /* q_new = E u_R, four joints per pass, then the books and x = x_free - gamma1 q_new. */
    for (int g = 0; g < groups; ++g) {
        const double *e0 = p->ET + (size_t)(4 * g) * (size_t)n, *e1 = e0 + n, *e2 = e1 + n, *e3 = e2 + n;
        for (int k = 0; k < 4; ++k) u4[k] = 4 * g + k < l ? s->u[4 * g + k] : 0.0;
        if (g == 0)
            for (int i = 0; i < n; ++i) q_new[i] = e0[i] * u4[0] + e1[i] * u4[1] + e2[i] * u4[2] + e3[i] * u4[3];
        else
            for (int i = 0; i < n; ++i) q_new[i] += e0[i] * u4[0] + e1[i] * u4[1] + e2[i] * u4[2] + e3[i] * u4[3];
    }
    update(p, s, c, b, q_new, disturbed);
    /* v = E^T x0 = v_free - G u_R exactly in exact arithmetic; v_free is recomputed from x
     * every step, so the two never drift apart. Saves a pass over E. */
    for (int i = 0; i < l; ++i) {
        double g = 0.0;
        for (int j = 0; j < l; ++j) g += G[i * l + j] * s->u[j];
        s->v[i] = v_free[i] - g;
    }
    return 0;
}

/* New normal forces act at once: u_R at the step start is recomputed (piezo instantaneous). */
void sj_set_normal_force(const sj_plant *p, sj_state *s, const double *normal_force)
{
    double d_v, d_phi;
    for (int j = 0; j < p->l; ++j) {
        s->fn[j] = normal_force[j];
        s->u[j] = friction(p, j, s->v[j], s->phi[j], s->fn[j], &d_v, &d_phi);
    }
    combine(p->ET, s->u, p->l, p->n, s->q);
}

/* Start of a run: the energy books at zero. */
void sj_start(const sj_plant *p, sj_state *s, const double *w0)
{
    (void)w0;
    s->work_in = s->work_joints = s->work_damping = p->books ? 0.0 : (double)NAN;
}

/* The sensors y = Vy eta_dot + Dy omega eta, as the controller reads them and the recorder
 * stores them (one function, so a compiled closed loop sees the numbers the Python loop sees). */
void sj_measure(const sj_plant *p, const sj_state *s, double *sensors)
{
    for (int k = 0; k < p->ny; ++k)
        sensors[k] = dot(p->Vy + (size_t)(k * p->n), s->x, p->n) + dot(p->Dy + (size_t)(k * p->n), s->x + p->n, p->n);
}

void sj_record_row(const sj_plant *p, const sj_state *s, const sj_record *r, long row)
{
    double e = 0.0;
    for (int j = 0; j < p->l; ++j) {
        r->v[row * p->l + j] = s->v[j];
        r->u[row * p->l + j] = s->u[j];
        r->fn[row * p->l + j] = s->fn[j];
        r->phi[row * p->l + j] = s->phi[j];
    }
    sj_measure(p, s, r->sensors + row * p->ny);
    e = dot(s->x, s->x, 2 * p->n);
    r->energy[row] = 0.5 * e;
    r->works[3 * row] = s->work_in;
    r->works[3 * row + 1] = s->work_joints;
    r->works[3 * row + 2] = s->work_damping;
}

/* Advance `steps` plant steps with disturbance samples w ((steps+1) x m, at the step ends);
 * global step index of the first is k0; rows are recorded before each step whose global index
 * is a multiple of record_every.  Returns the number of steps done (< steps on a failure). */
long sj_run(const sj_plant *p, sj_state *s, const double *w, long steps, long k0, long record_every,
            const sj_record *r)
{
    for (long k = 0; k < steps; ++k) {
        if ((k0 + k) % record_every == 0) sj_record_row(p, s, r, (k0 + k) / record_every);
        if (advance(p, s, w + k * p->m, w + (k + 1) * p->m, 0) != 0) return k;
    }
    return steps;
}

/* ---- Stick-exact steps (simulate(..., stick_step=H), stick_exact.py documents the scheme) ----
 *
 * State z = [x (interleaved eta_dot_i, omega_i eta_i); phi] of size N = 2n + l, dense exact
 * first-order-hold discretisation per step length, stored transposed with rows padded to Np:
 * Phi^T (N, Np), gamma0^T and gamma1^T (l + m, Np): rows the slip terms d, then the
 * disturbances; Gv = Cv gamma1_d and
 * Gp = gamma1_d rows of phi (l, l), row-major.  The same statements as stick_exact._StickPython. */
#define SJ_STICK_CORRECTION 1e-5  /* relative Newton correction that ends the slip-term solve */

/* out[:n] (+)= sum_c M[c, :n] y_c for M stored as `columns` rows of `stride` (a transposed matrix,
 * rows padded to a multiple of four so that the loop vectorises without a remainder). */
static void axpy_columns(const double *restrict M, const double *restrict y, int columns, int n, int stride,
                         double *restrict out, int overwrite)
{
    if (overwrite)
        for (int i = 0; i < n; ++i) out[i] = 0.0;
    for (int c = 0; c < columns; ++c) {
        const double *restrict col = M + (size_t)(c * stride);
        double yc = y[c];
        for (int i = 0; i < n; ++i) out[i] += col[i] * yc;
    }
}

/* J c = r for the Newton step of the slip terms: closed form up to three joints (the common
 * case; the pivoting loop of solve_small costs more than the rest of the solve), else
 * solve_small.  Returns 0.0 for a singular J. */
static double stick_solve(int l, double *J, double *r)
{
    if (l == 1) {
        if (J[0] == 0.0) return 0.0;
        r[0] /= J[0];
        return J[0];
    }
    if (l == 2) {
        double det = J[0] * J[3] - J[1] * J[2];
        if (det == 0.0) return 0.0;
        double a = (J[3] * r[0] - J[1] * r[1]) / det, b = (J[0] * r[1] - J[2] * r[0]) / det;
        r[0] = a;
        r[1] = b;
        return det;
    }
    if (l == 3) {
        double c00 = J[4] * J[8] - J[5] * J[7], c01 = J[5] * J[6] - J[3] * J[8], c02 = J[3] * J[7] - J[4] * J[6];
        double det = J[0] * c00 + J[1] * c01 + J[2] * c02;
        if (det == 0.0) return 0.0;
        double c10 = J[2] * J[7] - J[1] * J[8], c11 = J[0] * J[8] - J[2] * J[6], c12 = J[1] * J[6] - J[0] * J[7];
        double c20 = J[1] * J[5] - J[2] * J[4], c21 = J[2] * J[3] - J[0] * J[5], c22 = J[0] * J[4] - J[1] * J[3];
        double a = (c00 * r[0] + c10 * r[1] + c20 * r[2]) / det;
        double b = (c01 * r[0] + c11 * r[1] + c21 * r[2]) / det;
        double c = (c02 * r[0] + c12 * r[1] + c22 * r[2]) / det;
        r[0] = a;
        r[1] = b;
        r[2] = c;
        return det;
    }
    return solve_small(l, J, r);
}

static double stick_rate(const sj_stick *p, int j, double v, double *derivative)
{
    double g = p->fc[j] + p->fd[j] * exp(-(v / p->vs[j]) * (v / p->vs[j]));
    double dg = -2.0 * v / (p->vs[j] * p->vs[j]) * (g - p->fc[j]);
    *derivative = p->s0[j] * (sign_of(v) * g - fabs(v) * dg) / (g * g);
    return p->s0[j] * fabs(v) / g;
}

/* u_R = r F_N [sigma0 phi + sigma1 (v - d) + sigma2 v] (Eq. 2 with phi_dot = v - d, Eq. 1). */
static void stick_forces(const sj_stick *p, sj_stick_state *s)
{
    for (int j = 0; j < p->l; ++j) {
        double scale = p->arm[j] * s->fn[j];
        s->u[j] = scale * (p->s0[j] * s->z[p->n2 + j] + p->s1[j] * (s->v[j] - s->d[j]) + p->s2[j] * s->v[j]);
    }
}

/* The solved step: z = z_free + gamma1_d d+, and the new slip terms and joint velocities. */
static void stick_accept(const sj_stick *p, sj_stick_state *s, const sj_stick_step *k, const double *zf,
                         const double *d1, const double *v1)
{
    memcpy(s->z, zf, sizeof(double) * (size_t)p->N);
    axpy_columns(k->g1, d1, p->l, p->N, p->Np, s->z, 0);
    for (int j = 0; j < p->l; ++j) {
        s->d[j] = d1[j];
        s->v[j] = v1[j];
    }
}

/* One step of the given discretisation from w_a to w_b; 0 on success (z, d, v updated). */
static int stick_advance(const sj_stick *p, sj_stick_state *s, const sj_stick_step *k, double h, const double *w_a,
                         const double *w_b)
{
    int N = p->N, l = p->l, m = p->m, n2 = p->n2;
    double *zf = p->work, *vf = p->work + 2 * p->Np, *pf = vf + l, *d1 = pf + l, *r = d1 + l, *scale = r + l;
    double *v1 = scale + l, *rho = v1 + l, *drho = rho + l, *J = drho + l;
    int disturbed = !(all_zero(w_a, m) && all_zero(w_b, m));
    /* z_free = Phi z + gamma0 [d; w_a] + gamma1 [0; w_b], column by column (the matrices are
     * stored transposed), so that the loop over the N rows vectorises. */
    int Np = p->Np;
    axpy_columns(k->phi, s->z, N, Np, Np, zf, 1);
    axpy_columns(k->g0, s->d, l, Np, Np, zf, 0);
    if (disturbed) {
        axpy_columns(k->g0 + (size_t)(l * Np), w_a, m, Np, Np, zf, 0);
        axpy_columns(k->g1 + (size_t)(l * Np), w_b, m, Np, Np, zf, 0);
    }
    for (int j = 0; j < l; ++j) {
        vf[j] = dot(p->Cv + (size_t)(j * n2), zf, n2);
        pf[j] = zf[n2 + j];
        d1[j] = s->d[j];  /* start from the held slip term */
        scale[j] = fmax(fabs(vf[j]), p->vs[j]) + fabs(s->v[j]);
    }
    double worst = 0.0;
    for (int it = 0; it < SJ_ITERATIONS; ++it) {
        int converged = 1;
        worst = 0.0;
        for (int i = 0; i < l; ++i) {
            double v = vf[i], phi = pf[i];
            for (int j = 0; j < l; ++j) {
                v += k->Gv[i * l + j] * d1[j];
                phi += k->Gp[i * l + j] * d1[j];
            }
            v1[i] = v;
            rho[i] = stick_rate(p, i, v, &drho[i]);
            r[i] = d1[i] - rho[i] * phi;
            drho[i] *= phi;
            if (!(fabs(r[i]) <= SJ_TOLERANCE * scale[i])) converged = 0;
            worst = fmax(worst, fabs(r[i]));
        }
        if (converged) {
            stick_accept(p, s, k, zf, d1, v1);
            return 0;
        }
        for (int i = 0; i < l; ++i)
            for (int j = 0; j < l; ++j)
                J[i * l + j] = (i == j ? 1.0 : 0.0) - drho[i] * k->Gv[i * l + j] - rho[i] * k->Gp[i * l + j];
        if (stick_solve(l, J, r) == 0.0) break;
        double limit = 0.0;
        for (int j = 0; j < l; ++j) limit = fmax(limit, fabs(r[j]) / scale[j]);
        for (int j = 0; j < l; ++j) d1[j] -= limit <= 1.0 ? r[j] : r[j] / limit;
        if (limit <= SJ_STICK_CORRECTION) {
            /* Newton converges quadratically: after a correction this small the next one would be
             * below the tolerance, so take the result without another evaluation of rho */
            for (int i = 0; i < l; ++i) {
                double v = vf[i];
                for (int j = 0; j < l; ++j) v += k->Gv[i * l + j] * d1[j];
                v1[i] = v;
            }
            stick_accept(p, s, k, zf, d1, v1);
            return 0;
        }
    }
    s->failed_step = h;
    s->failed_residual = worst;
    return -1;
}

/* Every joint stuck enough for a step of length H: rho H < kappa and |u_R| < beta r F_N (F_c + F_d). */
static int stick_quiet(const sj_stick *p, const sj_stick_state *s, double H, double beta)
{
    for (int j = 0; j < p->l; ++j) {
        double unused;
        /* rho <= sigma0 |v| / F_c (g >= F_c): most joints pass on this bound without the exp */
        if (!(p->s0[j] * fabs(s->v[j]) / p->fc[j] * H < p->kappa)
            && !(stick_rate(p, j, s->v[j], &unused) * H < p->kappa)) return 0;
        if (!(fabs(s->u[j]) < beta * p->arm[j] * s->fn[j] * (p->fc[j] + p->fd[j]))) return 0;
    }
    return 1;
}

void sj_stick_set_normal_force(const sj_stick *p, sj_stick_state *s, const double *normal_force)
{
    for (int j = 0; j < p->l; ++j) s->fn[j] = normal_force[j];
    stick_forces(p, s);
}

void sj_stick_record_row(const sj_stick *p, const sj_stick_state *s, const sj_record *r, long row)
{
    for (int j = 0; j < p->l; ++j) {
        r->v[row * p->l + j] = s->v[j];
        r->u[row * p->l + j] = s->u[j];
        r->fn[row * p->l + j] = s->fn[j];
        r->phi[row * p->l + j] = s->z[p->n2 + j];
    }
    for (int k = 0; k < p->ny; ++k) r->sensors[row * p->ny + k] = dot(p->Cy + (size_t)(k * p->n2), s->z, p->n2);
    r->energy[row] = 0.5 * dot(s->z, s->z, p->n2);
    r->works[3 * row] = r->works[3 * row + 1] = r->works[3 * row + 2] = (double)NAN;
}

/* Disturbance samples at the short-step ends; rows from `rows` on are zero (a run samples a
 * disturbance with a known end only up to it). */
typedef struct {
    const double *w;
    long rows;
    int m;
} sj_stick_w;

static const double sj_zero_row[SJ_MAX_DISTURBANCES];

static const double *stick_w(const sj_stick_w *w, long row)
{
    return row < w->rows ? w->w + (size_t)row * (size_t)w->m : sj_zero_row;
}

static int stick_w_zero(const sj_stick_w *w, long row, long count)
{
    if (row >= w->rows) return 1;
    long end = row + count < w->rows ? row + count : w->rows;
    return all_zero(w->w + (size_t)row * (size_t)w->m, (int)((end - row) * w->m));
}

/* The interval of one step at `level` (length H, from short-step sample `row`): one step there
 * if the joints are quiet for it at both ends and the disturbance is off, else ratio[level]
 * intervals of the next level.  0 on success. */
static int stick_interval(const sj_stick *p, sj_stick_state *s, int level, const sj_stick_w *w, long row, double H)
{
    int N = p->N, l = p->l;
    if (level == 2) {
        if (stick_advance(p, s, &p->level[2], H, stick_w(w, row), stick_w(w, row + 1)) != 0) return -1;
        stick_forces(p, s);
        s->steps[2] += 1;
        return 0;
    }
    int shorts = level == 0 ? p->ratio[0] * p->ratio[1] : p->ratio[1];  /* short steps in this interval */
    if (stick_w_zero(w, row, shorts + 1) && stick_quiet(p, s, H, p->beta[level])) {
        double *backup = p->work + 2 * p->Np + 8 * l + l * l + (size_t)(level * (N + 3 * l));  /* after stick_advance's */
        memcpy(backup, s->z, sizeof(double) * (size_t)N);
        memcpy(backup + N, s->d, sizeof(double) * (size_t)l);
        memcpy(backup + N + l, s->v, sizeof(double) * (size_t)l);
        memcpy(backup + N + 2 * l, s->u, sizeof(double) * (size_t)l);
        if (stick_advance(p, s, &p->level[level], H, sj_zero_row, sj_zero_row) == 0) {
            stick_forces(p, s);
            if (stick_quiet(p, s, H, p->beta[level])) {
                s->steps[level] += 1;
                return 0;
            }
        }
        /* a slip may hide inside: redo the interval with the next level */
        memcpy(s->z, backup, sizeof(double) * (size_t)N);
        memcpy(s->d, backup + N, sizeof(double) * (size_t)l);
        memcpy(s->v, backup + N + l, sizeof(double) * (size_t)l);
        memcpy(s->u, backup + N + 2 * l, sizeof(double) * (size_t)l);
    }
    int parts = p->ratio[level], span = shorts / parts;
    for (int i = 0; i < parts; ++i)
        if (stick_interval(p, s, level + 1, w, row + (long)i * span, H / (double)parts) != 0) return -1;
    return 0;
}

/* `longs` long steps of length H; w: the first w_rows of the longs*ratio[0]*ratio[1] + 1
 * disturbance samples at the short-step ends (the rest zero); rows recorded before each long
 * step whose global index k0 + k is a multiple of record_every.  Returns the number of long
 * steps done (< longs on a failed short step). */
long sj_stick_run(const sj_stick *p, sj_stick_state *s, const double *w, long w_rows, long longs, long k0,
                  long record_every, const sj_record *r, double H)
{
    int shorts = p->ratio[0] * p->ratio[1];
    sj_stick_w samples = {w, w_rows, p->m};
    for (long k = 0; k < longs; ++k) {
        if ((k0 + k) % record_every == 0) sj_stick_record_row(p, s, r, (k0 + k) / record_every);
        if (stick_interval(p, s, 0, &samples, k * shorts, H) != 0) return k;
    }
    return longs;
}
