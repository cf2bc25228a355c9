/* One physics tick of the truth plant, compiled: the same arithmetic as the Python reference
 * (sil_vehicle/vehicle.py Vehicle._step_python and the pure functions of sil_vehicle/dynamics),
 * operation for operation and in the same order, so that both give bit-identical results
 * (IEEE double, no fused multiply-add: built with -ffp-contract=off, never -ffast-math; sin, cos,
 * exp, atan2, acos come from the same C library as Python's math module). tests/consistency/
 * test_compiled_core.py holds the two to equality, bit for bit.
 *
 * Layout of the two arrays (sil_vehicle/dynamics/compiled.py names every index):
 *   p (parameters, set once): see P_* below;
 *   s (state and inputs, read and written every tick): see S_* below.
 * Returns 0, or TICK_ATTITUDE when the vehicle tumbled during this tick (the ground's events,
 * touchdown and tip-over, are judged after the tick in Python, Vehicle._ground_events, for both
 * cores; S_LANDED and S_IMPACT_SPEED are kept in the layout, unused here).
 * No allocation, no I/O, no global state: a pure function of (p, s) into s.
 */
#include <math.h>

enum {
    P_DT, P_MASS, P_IXX, P_IYY, P_IZZ, P_GRAVITY, P_DRAG, P_IDLE, P_MOTOR_FACTOR, P_MOTOR_MAX,
    P_SERVO_FACTOR, P_SERVO_MAX, P_TILT_MIN, P_TILT_MAX, P_TILT_LOCKED, P_CRASH_SPEED,
    P_CRASH_TILT, P_THRUST, /* c2, c1, c0 */ P_TORQUE = P_THRUST + 3, /* c2, c1, c0 */
    P_ROTORS = P_TORQUE + 3, /* 4 x (spin, px, py, pz, ax, ay, az) */
    P_GEAR = P_ROTORS + 28, /* sil_vehicle/dynamics/contact.py's Gear: */
    P_GROUND = P_GEAR, P_REACH, P_GEAR_K, P_GEAR_C, P_GEAR_MU, P_GEAR_KT, P_GEAR_CT, P_GEAR_N,
    P_GEAR_POINTS, /* GEAR_MAX x (x, y, z) */
    P_SIZE = P_GEAR_POINTS + 3 * 8
};

enum {
    S_X = 0, /* 13 */ S_MOTOR = 13, /* 4 */ S_TILT = 17, /* 4 */ S_LANDED = 21, S_CRASHED = 22,
    S_RUNNING = 23, S_T = 24, S_CMD_THROTTLE = 25, /* 4 */ S_CMD_TILT = 29, /* 4 */
    S_WIND = 33, /* 3 */ S_MOTOR_FAULT = 36, /* 4 x (a, b, w, phi, off) */
    S_SERVO_FAULT = 56, /* 4 x (stuck, angle) */ S_IMPACT_SPEED = 64,
    S_ANCHORS = 65, /* 8 x (north, east): the contact points' stick anchors */
    S_SIZE = S_ANCHORS + 16
};

enum { TICK_OK = 0, TICK_IMPACT = 1, TICK_ATTITUDE = 2 };

int trq_tick_sizes(int *p_size, int *s_size)
{
    *p_size = P_SIZE;
    *s_size = S_SIZE;
    return 0;
}

static double first_order_step(double value, double target, double factor, double max_change,
                               double lo, double hi)
{
    double delta = factor * (target - value);
    if (delta > max_change)
        delta = max_change;
    else if (delta < -max_change)
        delta = -max_change;
    value += delta;
    return value < lo ? lo : value > hi ? hi : value;
}

static double quadratic(const double *c, double zeta)
{
    double value = (c[0] * zeta + c[1]) * zeta + c[2];
    return value > 0.0 ? value : 0.0;
}

static double fault_factor(const double *f, double t_s)
{
    double e;
    if (f[4] != 0.0)
        return 0.0;
    if (f[1] == 0.0)
        e = f[0];
    else
        e = f[0] - f[1] * sin(f[2] * t_s + f[3]);
    return e < 0.0 ? 0.0 : e > 1.0 ? 1.0 : e;
}

/* sil_vehicle/dynamics/contact.py contact_wrench: world force, body moment */
/* R (NED from FRD) of the unit quaternion q = (w, x, y, z), row by row into r[9]: the one copy
 * of the rotation here (sil_vehicle/frames.py's formula, term for term) */
static void rotation(const double *q, double *r)
{
    double qw = q[0], qx = q[1], qy = q[2], qz = q[3];
    r[0] = 1 - 2 * (qy * qy + qz * qz);
    r[1] = 2 * (qx * qy - qw * qz);
    r[2] = 2 * (qx * qz + qw * qy);
    r[3] = 2 * (qx * qy + qw * qz);
    r[4] = 1 - 2 * (qx * qx + qz * qz);
    r[5] = 2 * (qy * qz - qw * qx);
    r[6] = 2 * (qx * qz - qw * qy);
    r[7] = 2 * (qy * qz + qw * qx);
    r[8] = 1 - 2 * (qx * qx + qy * qy);
}

/* a wrench (force, then moment) into w[6] */
static void put_wrench(double *w, double fx, double fy, double fz, double mx, double my,
                       double mz)
{
    w[0] = fx;
    w[1] = fy;
    w[2] = fz;
    w[3] = mx;
    w[4] = my;
    w[5] = mz;
}

static void contact_wrench(const double *x, const double *p, const double *anchors,
                           double *cw)
{
    double pn0 = x[0], pe0 = x[1], pd = x[2], vn = x[3], ve = x[4], vd = x[5];
    double pr = x[10], qr = x[11], rr = x[12];
    double r[9];
    double r00, r01, r02, r10, r11, r12, r20, r21, r22;
    rotation(x + 6, r);
    r00 = r[0], r01 = r[1], r02 = r[2], r10 = r[3], r11 = r[4], r12 = r[5];
    r20 = r[6], r21 = r[7], r22 = r[8];
    double k = p[P_GEAR_K], c = p[P_GEAR_C], mu = p[P_GEAR_MU], kt = p[P_GEAR_KT];
    double ct = p[P_GEAR_CT];
    double ground = p[P_GROUND];
    double f_n = 0.0, f_e = 0.0, f_d = 0.0, m_x = 0.0, m_y = 0.0, m_z = 0.0;
    int i, n = (int)p[P_GEAR_N];
    for (i = 0; i < n; i++) {
        const double *pt = p + P_GEAR_POINTS + 3 * i;
        double px = pt[0], py = pt[1], pz = pt[2];
        double depth = pd + r20 * px + r21 * py + r22 * pz - ground;
        double ux, uy, uz, un, ue, ud, normal, fn, fe, gn, ge, gd, slip, t2, bx, by, bz;
        if (depth <= 0.0)
            continue;
        ux = qr * pz - rr * py;
        uy = rr * px - pr * pz;
        uz = pr * py - qr * px;
        un = vn + r00 * ux + r01 * uy + r02 * uz;
        ue = ve + r10 * ux + r11 * uy + r12 * uz;
        ud = vd + r20 * ux + r21 * uy + r22 * uz;
        normal = k * depth + c * ud;
        if (normal <= 0.0)
            continue;
        fn = pn0 + r00 * px + r01 * py + r02 * pz;
        fe = pe0 + r10 * px + r11 * py + r12 * pz;
        gn = -kt * (fn - anchors[2 * i]) - ct * un;
        ge = -kt * (fe - anchors[2 * i + 1]) - ct * ue;
        slip = mu * normal;
        t2 = gn * gn + ge * ge;
        if (t2 > slip * slip) {                     /* sliding: Coulomb's mu N */
            double sc = slip / sqrt(t2);
            gn = gn * sc;
            ge = ge * sc;
        }
        gd = -normal;
        f_n += gn;
        f_e += ge;
        f_d += gd;
        bx = r00 * gn + r10 * ge + r20 * gd;
        by = r01 * gn + r11 * ge + r21 * gd;
        bz = r02 * gn + r12 * ge + r22 * gd;
        m_x += py * bz - pz * by;
        m_y += pz * bx - px * bz;
        m_z += px * by - py * bx;
    }
    put_wrench(cw, f_n, f_e, f_d, m_x, m_y, m_z);
}

static void derivative(const double *x, const double *w, const double *wind, const double *p,
                       const double *anchors, double *dx)
{
    double vn = x[3], ve = x[4], vd = x[5], qw = x[6], qx = x[7], qy = x[8], qz = x[9];
    double pr = x[10], qr = x[11], rr = x[12];
    double fx = w[0], fy = w[1], fz = w[2], mx = w[3], my = w[4], mz = w[5];
    double r[9], fn, fe, fdn, rx, ry, rz, s, inv_m, ixx, iyy, izz;
    rotation(x + 6, r);
    fn = r[0] * fx + r[1] * fy + r[2] * fz;
    fe = r[3] * fx + r[4] * fy + r[5] * fz;
    fdn = r[6] * fx + r[7] * fy + r[8] * fz;
    if (x[2] > p[P_REACH]) {                        /* the ground within reach */
        double cw[6];
        contact_wrench(x, p, anchors, cw);
        fn = fn + cw[0];
        fe = fe + cw[1];
        fdn = fdn + cw[2];
        mx = mx + cw[3];
        my = my + cw[4];
        mz = mz + cw[5];
    }
    rx = vn - wind[0];
    ry = ve - wind[1];
    rz = vd - wind[2];
    s = -p[P_DRAG] * sqrt(rx * rx + ry * ry + rz * rz);
    inv_m = 1.0 / p[P_MASS];
    ixx = p[P_IXX];
    iyy = p[P_IYY];
    izz = p[P_IZZ];
    dx[0] = vn;
    dx[1] = ve;
    dx[2] = vd;
    dx[3] = (fn + s * rx) * inv_m;
    dx[4] = (fe + s * ry) * inv_m;
    dx[5] = (fdn + s * rz) * inv_m + p[P_GRAVITY];
    dx[6] = 0.5 * (-qx * pr - qy * qr - qz * rr);
    dx[7] = 0.5 * (qw * pr + qy * rr - qz * qr);
    dx[8] = 0.5 * (qw * qr - qx * rr + qz * pr);
    dx[9] = 0.5 * (qw * rr + qx * qr - qy * pr);
    dx[10] = (mx - (izz - iyy) * qr * rr) / ixx;
    dx[11] = (my - (ixx - izz) * rr * pr) / iyy;
    dx[12] = (mz - (iyy - ixx) * pr * qr) / izz;
}

static void rk4_step(double *x, double dt, const double *w, const double *wind, const double *p,
                     const double *anchors)
{
    double k1[13], k2[13], k3[13], k4[13], y[13];
    double h = 0.5 * dt, d6 = dt / 6.0, n;
    int i;
    derivative(x, w, wind, p, anchors, k1);
    for (i = 0; i < 13; i++)
        y[i] = x[i] + h * k1[i];
    derivative(y, w, wind, p, anchors, k2);
    for (i = 0; i < 13; i++)
        y[i] = x[i] + h * k2[i];
    derivative(y, w, wind, p, anchors, k3);
    for (i = 0; i < 13; i++)
        y[i] = x[i] + dt * k3[i];
    derivative(y, w, wind, p, anchors, k4);
    for (i = 0; i < 13; i++)
        x[i] = x[i] + d6 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
    n = 1.0 / sqrt(x[6] * x[6] + x[7] * x[7] + x[8] * x[8] + x[9] * x[9]);
    x[6] *= n;
    x[7] *= n;
    x[8] *= n;
    x[9] *= n;
}

static void body_wrench(const double *zeta, const double *alpha, const double *p, double *w)
{
    double fx = 0.0, fy = 0.0, fz = 0.0, mx = 0.0, my = 0.0, mz = 0.0;
    int i;
    for (i = 0; i < 4; i++) {
        const double *r = p + P_ROTORS + 7 * i;
        double f = quadratic(p + P_THRUST, zeta[i]);
        double tau = quadratic(p + P_TORQUE, zeta[i]) * r[0];
        double sa = sin(alpha[i]), ca = cos(alpha[i]);
        double nx = -r[5] * sa, ny = r[4] * sa, nz = -ca;
        double px = r[1], py = r[2], pz = r[3];
        fx += f * nx;
        fy += f * ny;
        fz += f * nz;
        mx += f * (py * nz - pz * ny) - tau * nx;
        my += f * (pz * nx - px * nz) - tau * ny;
        mz += f * (px * ny - py * nx) - tau * nz;
    }
    put_wrench(w, fx, fy, fz, mx, my, mz);
}

int trq_tick(const double *p, double *s)
{
    double *x = s + S_X, *motor = s + S_MOTOR, *tilt = s + S_TILT;
    const double *wind = s + S_WIND;
    int running = s[S_RUNNING] != 0.0, locked = p[P_TILT_LOCKED] != 0.0;
    int crashed = s[S_CRASHED] != 0.0, event = TICK_OK;
    double w[6];
    int i;
    for (i = 0; i < 4; i++) {
        double target = 0.0;
        if (running) {
            double c = s[S_CMD_THROTTLE + i];
            if (p[P_IDLE] > c)              /* Python's max(cmd, idle), min(.., 100.0) */
                c = p[P_IDLE];
            if (100.0 < c)
                c = 100.0;
            target = c * fault_factor(s + S_MOTOR_FAULT + 5 * i, s[S_T]);
        }
        motor[i] = first_order_step(motor[i], target, p[P_MOTOR_FACTOR], p[P_MOTOR_MAX], 0.0,
                                    100.0);
    }
    for (i = 0; i < 4; i++) {
        const double *sf = s + S_SERVO_FAULT + 2 * i;
        double target;
        if (sf[0] != 0.0) {
            tilt[i] = sf[1];
            continue;
        }
        target = (locked || !running) ? 0.0 : s[S_CMD_TILT + i];
        tilt[i] = first_order_step(tilt[i], target, p[P_SERVO_FACTOR], p[P_SERVO_MAX],
                                   p[P_TILT_MIN], p[P_TILT_MAX]);
    }
    if (locked)
        for (i = 0; i < 4; i++)
            tilt[i] = 0.0;
    body_wrench(motor, tilt, p, w);
    rk4_step(x, p[P_DT], w, wind, p, s + S_ANCHORS);   /* the ground inside (derivative) */
    if (!crashed) {
        double qx = x[7], qy = x[8];
        double c = 1 - 2 * (qx * qx + qy * qy);
        if (acos(c > 1.0 ? 1.0 : c < -1.0 ? -1.0 : c) > p[P_CRASH_TILT]) {
            crashed = 1;
            event = TICK_ATTITUDE;
        }
    }
    s[S_CRASHED] = crashed;
    return event;
}
