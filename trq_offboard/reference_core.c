/* The flight plan's grid in C (trq_offboard/reference.py: Reference.grid through
   reference_core.py). The same figures as Reference._pv to the bit: every expression is
   Python's, operation for operation and in its order, the powers and the trigonometry are
   libm's pow, sin and cos (which CPython's float ** and math module call), and the library is
   built without contraction into fused multiply-adds and without the compiler's builtins (GCC
   would otherwise turn pow(x, 2.0) into x * x, which libm's pow need not round alike).

   The plan's figures come as one array (reference_core.py's PARAMS names their order), the
   landing's constants of reference.py among them. */
#include <math.h>

enum { P_T0, P_T1, P_T2, P_T3, P_T4, P_T5, P_TAKEOFF, P_TLAND,
       P_SN, P_SE, P_SD, P_HN, P_HE, P_HD, P_EN, P_EE, P_ED, P_GROUND,
       P_W, P_T, P_R, P_FULL_RAMP, P_PHI_END, P_RADIUS, P_HELIX_CLIMB,
       P_STEP_N, P_STEP_E, P_STEP_D, P_DURATION, P_KIND, P_LAND,
       P_LAND_BELOW, P_CRAWL, P_CRAWL_RAMP, P_COUNT };
enum { K_HOVER, K_STEP, K_CIRCLE, K_HELIX, K_FIGURE8 };

static const double PI = 3.141592653589793;

/* _smoothstep5: (value, derivative) of 10 s^3 - 15 s^4 + 6 s^5, clamped outside [0, 1] */
static void smoothstep5(double s, double *v, double *dv)
{
    if (s <= 0.0) { *v = 0.0; *dv = 0.0; return; }
    if (s >= 1.0) { *v = 1.0; *dv = 0.0; return; }
    *v = pow(s, 3.0) * ((10.0 - 15.0 * s) + (6.0 * s) * s);
    *dv = ((30.0 * s) * s) * pow(1.0 - s, 2.0);
}

static double ramp_integral(const double *p, double s)
{
    const double r = p[P_R];
    return r > 0 ? 0.5 * (s - (r / PI) * sin((PI * s) / r)) : s;
}

/* _phase: (phi, dphi/dt) tau seconds into the manoeuvre */
static void phase(const double *p, double tau, double *phi, double *dphi)
{
    const double w = p[P_W], T = p[P_T], r = p[P_R];
    tau = (0.0 > tau) ? 0.0 : tau;                 /* min(max(tau, 0.0), T) */
    tau = (T < tau) ? T : tau;
    if (tau < r) {
        *phi = w * ramp_integral(p, tau);
        *dphi = (w * 0.5) * (1.0 - cos((PI * tau) / r));
        return;
    }
    if (tau <= T - r) {
        *phi = w * ((p[P_FULL_RAMP] + tau) - r);
        *dphi = w;
        return;
    }
    const double back = T - tau;
    *phi = p[P_PHI_END] - w * ramp_integral(p, back);
    *dphi = (w * 0.5) * (1.0 - cos((PI * back) / r));
}

static void manoeuvre_pv(const double *p, double tau, double *o)
{
    const double cn = p[P_HN], ce = p[P_HE], cd = p[P_HD];
    const int kind = (int) p[P_KIND];
    o[3] = 0.0; o[4] = 0.0; o[5] = 0.0;
    o[0] = cn; o[1] = ce; o[2] = cd;
    if (kind == K_HOVER)
        return;
    if (kind == K_STEP) {
        if (0.0 <= tau && tau < p[P_DURATION]) {
            o[0] = cn + p[P_STEP_N]; o[1] = ce + p[P_STEP_E]; o[2] = cd + p[P_STEP_D];
        }
        return;
    }
    double phi, dphi;
    phase(p, tau, &phi, &dphi);
    const double R = p[P_RADIUS], c = cos(phi), s = sin(phi);
    if (kind == K_CIRCLE || kind == K_HELIX) {
        const double climb = kind == K_HELIX ? p[P_HELIX_CLIMB] / (2.0 * PI) : 0.0;
        o[0] = cn + R * (c - 1.0); o[1] = ce + R * s; o[2] = cd + climb * phi;
        o[3] = (-dphi * R) * s; o[4] = (dphi * R) * c; o[5] = dphi * climb;
        return;
    }
    /* figure8 */
    o[0] = cn + R * s; o[1] = ce + (0.5 * R) * sin(2.0 * phi); o[2] = cd;
    o[3] = (dphi * R) * c; o[4] = (dphi * R) * cos(2.0 * phi); o[5] = 0.0;
}

/* _pv: (north, east, down, vn, ve, vd) at t; the phase is not needed by the grid */
static void pv(const double *p, double t, double *o)
{
    o[3] = 0.0; o[4] = 0.0; o[5] = 0.0;
    if (t < p[P_T1]) {
        const double tk = p[P_TAKEOFF];
        double s, ds;
        smoothstep5(tk > 0 ? (t - p[P_T0]) / tk : 1.0, &s, &ds);
        const double sd = p[P_SD], dz = p[P_HD] - sd;
        o[0] = p[P_SN]; o[1] = p[P_SE]; o[2] = sd + s * dz;
        o[5] = tk > 0 ? (ds * dz) / tk : 0.0;
        return;
    }
    if (t < p[P_T2]) {
        o[0] = p[P_HN]; o[1] = p[P_HE]; o[2] = p[P_HD];
        return;
    }
    if (t < p[P_T3]) {
        manoeuvre_pv(p, t - p[P_T2], o);
        return;
    }
    const double en = p[P_EN], ee = p[P_EE], ed = p[P_ED];
    o[0] = en; o[1] = ee; o[2] = ed;
    if (t < p[P_T4] || !(p[P_LAND] != 0.0))
        return;
    const double dz = (p[P_GROUND] + p[P_LAND_BELOW]) - ed;
    if (t >= p[P_T5]) {
        const double x = (t - p[P_T5]) / p[P_CRAWL_RAMP];
        double s, ds;
        smoothstep5(x, &s, &ds);
        const double rise = x < 1.0 ? pow(x, 4.0) * ((2.5 - 3.0 * x) + x * x) : x - 0.5;
        o[2] = (ed + dz) + (p[P_CRAWL] * p[P_CRAWL_RAMP]) * rise;
        o[5] = p[P_CRAWL] * s;
        return;
    }
    const double tl = p[P_TLAND];
    double s, ds;
    smoothstep5(tl > 0 ? (t - p[P_T4]) / tl : 1.0, &s, &ds);
    o[2] = ed + s * dz;
    o[5] = tl > 0 ? (ds * dz) / tl : 0.0;
}

int trq_reference_params(void) { return P_COUNT; }

/* Reference.grid's positions and velocities: out (n x 6, row-major) at t0 + k step, k < n */
void trq_reference_grid(const double *p, double t0, double step, int n, double *out)
{
    for (int k = 0; k < n; k++)
        pv(p, t0 + (double) k * step, out + 6 * k);
}
