/* One IMU sample of the estimator (sil_vehicle/estimator/predictor.py, NativeOutputPredictor):
 * the output predictor's step (OutputPredictor.propagate) and the filter period's delta angle
 * and delta velocity sums with the sculling term (OutputPredictor._sum), the Python reference's
 * floating-point operations in its order. Built without fused multiply-add and without
 * fast-math, so that both give the same numbers bit for bit
 * (tests/unit/sil_vehicle/test_estimator_predictor.py holds them equal).
 *
 * The state array (enum S_*), read and written by each call. */
#include <math.h>

enum {
    S_DT, S_G,                                  /* IMU period (s), gravity (m/s^2) */
    S_Q, S_V = S_Q + 4, S_P = S_V + 3,          /* output state: q (wxyz), v, p (NED) */
    S_CANG = S_P + 3,                           /* attitude correction per sample */
    S_BG = S_CANG + 3, S_BA = S_BG + 3,         /* the filter's bias estimates */
    S_DA = S_BA + 3, S_DV = S_DA + 3,           /* the period's sums */
    S_GYRO = S_DV + 3, S_ACCEL = S_GYRO + 3,    /* the sample: rad/s, m/s^2 (body FRD) */
    S_SIZE = S_ACCEL + 3
};

int trq_imu_sample_size(void) { return S_SIZE; }

void trq_imu_sample(double *s)
{
    const double dt = s[S_DT];
    const double g0 = s[S_GYRO], g1 = s[S_GYRO + 1], g2 = s[S_GYRO + 2];
    const double f0 = s[S_ACCEL], f1 = s[S_ACCEL + 1], f2 = s[S_ACCEL + 2];
    /* q <- q (x) exp(dA - bg dt + c_ang), normalised */
    const double vx = (g0 - s[S_BG]) * dt + s[S_CANG];
    const double vy = (g1 - s[S_BG + 1]) * dt + s[S_CANG + 1];
    const double vz = (g2 - s[S_BG + 2]) * dt + s[S_CANG + 2];
    const double t2 = vx * vx + vy * vy + vz * vz;
    const double bw = 1.0 - t2 / 8.0 + t2 * t2 / 384.0;
    const double sn = 0.5 - t2 / 48.0 + t2 * t2 / 3840.0;
    const double bx = sn * vx, by = sn * vy, bz = sn * vz;
    const double aw = s[S_Q], ax = s[S_Q + 1], ay = s[S_Q + 2], az = s[S_Q + 3];
    const double qw = aw * bw - ax * bx - ay * by - az * bz;
    const double qx = aw * bx + ax * bw + ay * bz - az * by;
    const double qy = aw * by - ax * bz + ay * bw + az * bx;
    const double qz = aw * bz + ax * by - ay * bx + az * bw;
    const double n = sqrt(qw * qw + qx * qx + qy * qy + qz * qz);
    s[S_Q] = qw / n;
    s[S_Q + 1] = qx / n;
    s[S_Q + 2] = qy / n;
    s[S_Q + 3] = qz / n;
    /* v' = v + R(q_old) (dV - ba dt) + g dt,  p <- p + (v + v') dt / 2 */
    const double x = (f0 - s[S_BA]) * dt;
    const double y = (f1 - s[S_BA + 1]) * dt;
    const double z = (f2 - s[S_BA + 2]) * dt;
    const double w = aw, a = ax, b = ay, c2 = az;
    const double dvx = (1.0 - 2.0 * (b * b + c2 * c2)) * x + 2.0 * (a * b - w * c2) * y
                       + 2.0 * (a * c2 + w * b) * z;
    const double dvy = 2.0 * (a * b + w * c2) * x + (1.0 - 2.0 * (a * a + c2 * c2)) * y
                       + 2.0 * (b * c2 - w * a) * z;
    const double dvz = 2.0 * (a * c2 - w * b) * x + 2.0 * (b * c2 + w * a) * y
                       + (1.0 - 2.0 * (a * a + b * b)) * z;
    const double v00 = s[S_V], v01 = s[S_V + 1], v02 = s[S_V + 2];
    const double v0 = v00 + dvx, v1 = v01 + dvy, v2 = v02 + dvz + s[S_G] * dt;
    const double h = 0.5 * dt;
    s[S_P] = s[S_P] + (v00 + v0) * h;
    s[S_P + 1] = s[S_P + 1] + (v01 + v1) * h;
    s[S_P + 2] = s[S_P + 2] + (v02 + v2) * h;
    s[S_V] = v0;
    s[S_V + 1] = v1;
    s[S_V + 2] = v2;
    /* the sums: dv rotated into the start-of-period frame by the angle turned to mid-sample */
    const double dax = g0 * dt, day = g1 * dt, daz = g2 * dt;
    const double dux = f0 * dt, duy = f1 * dt, duz = f2 * dt;
    const double rx = s[S_DA] + 0.5 * dax, ry = s[S_DA + 1] + 0.5 * day,
                 rz = s[S_DA + 2] + 0.5 * daz;
    s[S_DV] += dux + ry * duz - rz * duy;
    s[S_DV + 1] += duy + rz * dux - rx * duz;
    s[S_DV + 2] += duz + rx * duy - ry * dux;
    s[S_DA] += dax;
    s[S_DA + 1] += day;
    s[S_DA + 2] += daz;
}
