/* Identification kernels of smartjoint.design.friction (compiled on first use through cffi).
 *
 * sj_rig_integrate: the rig integrator of rig_integration.py;
 * sj_equation_error_friction: the model force of paper Eq. 3 of identify.py.
 *
 * Each does what its Python reference does, statement for statement, so that the two agree
 * to round-off (tests/test_identify.py).
 *
 * The rig integrator:
 * the rig model of paper Section 3.2
 *
 *     m v' = F_exc - gain mu(v, phi),   phi' = f(v, phi)        (Eq. 1-2, gain = r F_N)
 *
 * by the implicit trapezoidal rule at `substeps` steps per sample, each step solved by Newton
 * on the analytic Jacobian from an explicit Euler predictor.  `force` and `gain` hold the
 * excitation and r F_N at every substep node: (samples - 1) substeps + 1 values each.
 */
#include <math.h>

#define SJ_RIG_ITERATIONS 20

typedef struct {
    double sigma0, sigma1, sigma2, coulomb, stribeck, stribeck_velocity, max_deflection;
    double inertia;
} sj_rig;

typedef struct { double acceleration, deflection_rate, level; } sj_rates;

/* v' and phi' of the rig (Eq. 1-2) and the Stribeck level F_c + F_d exp(-(v/v_s)^2). */
static sj_rates rates(const sj_rig *p, double excitation, double gain, double v, double phi)
{
    sj_rates r;
    double ratio = v / p->stribeck_velocity;
    r.level = p->coulomb + p->stribeck * exp(-(ratio * ratio));
    r.deflection_rate = v - p->sigma0 * fabs(v) / r.level * phi;
    double mu = p->sigma0 * phi + p->sigma1 * r.deflection_rate + p->sigma2 * v;
    r.acceleration = (excitation - gain * mu) / p->inertia;
    return r;
}

/* Integrates from (velocity0, deflection0) at time[0]; writes v and phi at every sample time.
 * Returns the number of substeps whose Newton solve stopped at the iteration limit. */
long sj_rig_integrate(const sj_rig *p, const double *time, long samples, int substeps, const double *force,
                      const double *gain, double velocity0, double deflection0, double *velocity,
                      double *deflection)
{
    const double s0 = p->sigma0, s1 = p->sigma1, s2 = p->sigma2;
    const double fc = p->coulomb, vs = p->stribeck_velocity, m = p->inertia;
    double v = velocity0, phi = deflection0;
    long node = 0, unconverged = 0;
    velocity[0] = v;
    deflection[0] = phi;
    for (long k = 1; k < samples; ++k) {
        double h = (time[k] - time[k - 1]) / substeps;
        for (int step = 0; step < substeps; ++step) {
            sj_rates start = rates(p, force[node], gain[node], v, phi);
            ++node;
            double v1 = v + h * start.acceleration, phi1 = phi + h * start.deflection_rate;
            int iteration = 0;
            for (; iteration < SJ_RIG_ITERATIONS; ++iteration) {
                sj_rates end = rates(p, force[node], gain[node], v1, phi1);
                double r_v = v1 - v - 0.5 * h * (start.acceleration + end.acceleration);
                double r_p = phi1 - phi - 0.5 * h * (start.deflection_rate + end.deflection_rate);
                /* d phi'/d phi, d phi'/d v (the sign(v) kink taken one-sidedly) and d v'/d . */
                double level = end.level;
                double f_phi = -s0 * fabs(v1) / level;
                double d_level = -2.0 * v1 / (vs * vs) * (level - fc);
                double sign = v1 > 0.0 ? 1.0 : (v1 < 0.0 ? -1.0 : 0.0);
                double f_v = 1.0 - s0 * phi1 * (sign * level - fabs(v1) * d_level) / (level * level);
                double a_v = -gain[node] * (s1 * f_v + s2) / m;
                double a_phi = -gain[node] * (s0 + s1 * f_phi) / m;
                double j11 = 1.0 - 0.5 * h * a_v, j12 = -0.5 * h * a_phi;
                double j21 = -0.5 * h * f_v, j22 = 1.0 - 0.5 * h * f_phi;
                double det = j11 * j22 - j12 * j21;
                double dv = (r_v * j22 - j12 * r_p) / det;
                double dp = (j11 * r_p - j21 * r_v) / det;
                v1 -= dv;
                phi1 -= dp;
                if (fabs(dv) <= 1e-13 * (1.0 + fabs(v1)) && fabs(dp) <= 1e-12 * p->max_deflection) break;
            }
            if (iteration == SJ_RIG_ITERATIONS) ++unconverged;
            v = v1;
            phi = phi1;
        }
        velocity[k] = v;
        deflection[k] = phi;
    }
    return unconverged;
}

/* The model friction force u_R(t_k) of Eq. 3 for a measured velocity (identify._simulate_friction_python):
 * Eq. 1 by the exact-exponential step at the midpoint velocity, Eq. 2 at each sample; `gain` is r F_N per
 * sample, `deflection0` the start deflection.  Writes `samples` forces to `friction`. */
void sj_equation_error_friction(const sj_rig *p, const double *time, long samples, const double *velocity,
                                const double *gain, double deflection0, double *friction)
{
    const double s0 = p->sigma0, s1 = p->sigma1, s2 = p->sigma2;
    const double fc = p->coulomb, fd = p->stribeck, vs = p->stribeck_velocity;
    double phi = deflection0;
    double previous_v = velocity[0];
    for (long k = 0; k < samples; ++k) {
        double v = velocity[k];
        if (k) {
            double dt = time[k] - time[k - 1];
            double mid = 0.5 * (v + previous_v);
            double ratio = mid / vs;
            double level = fc + fd * exp(-(ratio * ratio));
            double rate = s0 * fabs(mid) / level;
            if (rate > 0.0) {
                double target = copysign(level / s0, mid);
                phi = phi + (target - phi) * -expm1(-rate * dt);
            }
        }
        double ratio = v / vs;
        double level = fc + fd * exp(-(ratio * ratio));
        double phidot = v - s0 * fabs(v) / level * phi;
        friction[k] = gain[k] * (s0 * phi + s1 * phidot + s2 * v);
        previous_v = v;
    }
}
