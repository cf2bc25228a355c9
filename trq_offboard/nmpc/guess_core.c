/* The real-time iteration's next linearisation point in C (trq_offboard/nmpc/guess_core.py).

   After each step the controller prepares the next one at its plan shifted by the time that
   will have elapsed (controller.py's _prepare, _guess, _reference_states; Ocp.pack and the
   clip in RtiSolver.prepare). In NumPy that is some forty small array operations a period;
   here it is one call, writing straight into the buffers the compiled preparation reads.

   The arithmetic is NumPy's, operation for operation and in its order, built without fused
   multiply-adds: the plan's rows interpolated as _interp_with does (x[i] g + x[i+1] f, with
   _interp_weights' s, i, f), its inputs taken at _shift's rows, the yaw kept next to the
   first row's, packed as Ocp.pack packs (tilts as states and their rates, throttles in
   fractions, lag states rolled out through their gains), clipped as np.clip clips (a NaN
   propagates), and the reference states' yaw unwrapped next to the first row's as
   Controller._reference_states does (Python's remainder, NumPy's np.remainder). The decision
   vector is stage-major, [s_0, v_0, s_1, ..., s_N] (Ocp.stage_major). */

#include <math.h>

enum { G_N, G_NX, G_NU, G_NS, G_NV, G_NLAG, G_TILTING, G_NDIMS };

/* np.clip's steps (a NaN propagates) */
static double clip(double x, double lo, double hi)
{
    x = (x != x || x > lo) ? x : lo;
    return (x != x || x < hi) ? x : hi;
}

/* (a + pi) % (2 pi) - pi with Python's (and np.remainder's) remainder, which takes the
   divisor's sign (a zero remainder's sign is lost in the - pi) */
static double wrap(double a)
{
    const double pi = 3.141592653589793, two_pi = 2.0 * 3.141592653589793;
    double m = fmod(a + pi, two_pi);
    if (m < 0.0)
        m += two_pi;
    return m - pi;
}

/* _shift's input row k of a plan made `elapsed` ago, its rows h apart: (elapsed + k h) / h +
   1e-9, truncated, at most N - 1 */
static const double *input_row(const double *u_old, int nu, int N, double elapsed, double h,
                               int k)
{
    const double t = elapsed + h * (double) k;
    const int r = (int) (t / h + 1e-9);
    return u_old + (r < N - 1 ? r : N - 1) * nu;
}

int trq_guess_ndims(void)
{
    return G_NDIMS;
}

/* dims: N, nx, nu, ns, nv, n_lag, tilting.
   sc: elapsed (s, since the plan's first row), h (s, the plan's row spacing), step_s (the
   OCP's step, for the tilt rates).
   st: [0] x_old ((N+1) nx, the plan's states), [1] u_old (N nu, its inputs), [2] pv ((N+1) 6,
   the reference's positions and velocities from elapsed on), [3] yaw_ref (N+1), [4] a_prev
   (4: the applied tilt; tilting), [5] y0 (nu: the actuators' outputs, physical; lag states),
   [6] lbw, [7] ubw (nw), [8] u_scale (nu), [9] lag_gain (n_lag; lag states);
   out: [10] w (nw, the linearisation point), [11] x_ref ((N+1) nx), [12] xr_w (nw: x_ref at
   the states' places in w, zeros elsewhere), [13] xs ((N+1) nx, work), [14] ys (nu, work). */
void trq_guess(const int *dims, const double *sc, void *const *st)
{
    const int N = dims[G_N], nx = dims[G_NX], nu = dims[G_NU], ns = dims[G_NS];
    const int nv = dims[G_NV], n_lag = dims[G_NLAG], tilting = dims[G_TILTING];
    const int nz = ns + nv, nw = N * nz + ns;
    const double elapsed = sc[0], h = sc[1], step_s = sc[2];
    const double *x_old = st[0], *u_old = st[1], *pv = st[2], *yaw_ref = st[3];
    const double *a_prev = st[4], *y0 = st[5], *lbw = st[6], *ubw = st[7];
    const double *u_scale = st[8], *lag_gain = st[9];
    double *w = st[10], *x_ref = st[11], *xr_w = st[12], *xs = st[13], *ys = st[14];
    double yaw, dyaw, row0_yaw;
    int k, j;

    /* the plan's states at elapsed + k h, k = 0..N (_interp_weights, _interp_with) */
    for (k = 0; k <= N; ++k) {
        const double t = elapsed + h * (double) k;
        double s = t / h, f, g;
        int i;
        s = s > 0.0 ? s : 0.0;                  /* np.clip(times / h, 0, N) */
        s = s < (double) N ? s : (double) N;
        i = (int) s;
        i = i < N - 1 ? i : N - 1;
        f = s - (double) i;
        g = 1.0 - f;
        for (j = 0; j < nx; ++j)
            xs[k * nx + j] = x_old[i * nx + j] * g + x_old[(i + 1) * nx + j] * f;
    }
    /* _guess: the yaw kept next to the first row's, which stays as it was */
    row0_yaw = xs[8];
    dyaw = row0_yaw - xs[8];
    for (k = 0; k <= N; ++k)
        xs[k * nx + 8] += dyaw;
    xs[8] = row0_yaw;
    yaw = row0_yaw;

    /* Ocp.pack: w from zeros */
    for (j = 0; j < nw; ++j)
        w[j] = 0.0;
    for (k = 0; k <= N; ++k) {
        double *s = w + k * nz;
        for (j = 0; j < nx; ++j)
            s[j] = xs[k * nx + j];
    }
    for (k = 0; k < N; ++k) {
        const double *u = input_row(u_old, nu, N, elapsed, h, k);
        double *s = w + k * nz, *v = s + ns, *s1 = s + nz;
        if (tilting) {
            /* s_k's tilts: the applied one, then the plan's; the servos' rates between */
            if (k == 0)
                for (j = 0; j < 4; ++j)
                    s[nx + j] = a_prev[j];
            for (j = 0; j < 4; ++j)
                s1[nx + j] = u[j];
            for (j = 0; j < 4; ++j)
                v[j] = (u[j] - s[nx + j]) / step_s;
            for (j = 4; j < 8; ++j)
                v[j] = u[j] / 100.0;
        } else {
            for (j = 0; j < nu; ++j)
                v[j] = u[j] / u_scale[j];
        }
    }
    if (n_lag) {
        /* the lag states rolled out under the plan's commands, scaled */
        for (j = 0; j < nu; ++j)
            ys[j] = y0[j] / u_scale[j];
        for (k = 0; k <= N; ++k) {
            double *s = w + k * nz + ns - n_lag;
            for (j = 0; j < n_lag; ++j)
                s[j] = ys[j];
            if (k == N)
                break;
            {
                const double *u = input_row(u_old, nu, N, elapsed, h, k);
                for (j = 0; j < nu; ++j)
                    ys[j] = ys[j] + lag_gain[j] * (u[j] / u_scale[j] - ys[j]);
            }
        }
    }
    for (j = 0; j < nw; ++j)
        w[j] = clip(w[j], lbw[j], ubw[j]);

    /* Controller._reference_states: positions and velocities, the yaw unwrapped next to the
       first row's, and the same at the states' places in w */
    for (j = 0; j < nw; ++j)
        xr_w[j] = 0.0;
    for (k = 0; k <= N; ++k) {
        double *r = x_ref + k * nx, *rw = xr_w + k * nz;
        for (j = 0; j < nx; ++j)
            r[j] = 0.0;
        for (j = 0; j < 6; ++j)
            r[j] = pv[k * 6 + j];
        r[8] = yaw + wrap(yaw_ref[k] - yaw);
        for (j = 0; j < nx; ++j)
            rw[j] = r[j];
    }
}

/* Ocp.unpack: the plan (u (N nu) physical [alpha, zeta] or [zeta], x ((N+1) nx)) of w. dims
   as trq_guess's; st: [0] w (nw), [1] u_scale (nu), out: [2] u, [3] x. */
void trq_unpack(const int *dims, void *const *st)
{
    const int N = dims[G_N], nx = dims[G_NX], nu = dims[G_NU], ns = dims[G_NS];
    const int nv = dims[G_NV], tilting = dims[G_TILTING], nz = ns + nv;
    const double *w = st[0], *u_scale = st[1];
    double *u = st[2], *x = st[3];
    int k, j;

    for (k = 0; k <= N; ++k)
        for (j = 0; j < nx; ++j)
            x[k * nx + j] = w[k * nz + j];
    for (k = 0; k < N; ++k) {
        const double *s1 = w + (k + 1) * nz, *v = w + k * nz + ns;
        if (tilting) {                    /* the plan's tilts are s_1..s_N's */
            for (j = 0; j < 4; ++j)
                u[k * nu + j] = s1[nx + j];
            for (j = 4; j < 8; ++j)
                u[k * nu + j] = 100.0 * v[j];
        } else {
            for (j = 0; j < nu; ++j)
                u[k * nu + j] = v[j] * u_scale[j];
        }
    }
}
