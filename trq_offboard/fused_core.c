/* The fused filter's step in C (trq_offboard/fused_core.py): FusedFilter's bookkeeping around
   its compiled kernel (trq_offboard/fused.py), the same decisions and the same arithmetic
   operation for operation, with the filter's history owned here.

   fused.py stays the reference and the readable statement of the filter; this file repeats its
   methods under their names (place_imu is FusedFilter._place_imu, and so on). The kernel is
   the CasADi function fused.py generates (`_kernel`), whose generated C the Python side puts
   before this file and names through TRQ_K1 (and its _work function). FusedFilter's
   `_kernel_two` (two stretches chained, one call from Python) is here two calls of TRQ_K1,
   its arithmetic call by call: its straight-line code is twice the one's, read once a period
   from beyond the caches (docs/decisions/2026-12-07-period-paced.md). Built without fused
   multiply-add and without fast-math (fused_core.py's flags), so that every product and sum
   rounds as Python's does: tests/unit/trq_offboard/test_fused_core.py holds the two to the
   bit.

   Limits the Python filter does not have (its lists grow): HISTORY_MAX periods, POSES_MAX
   poses in a period, IMU_PENDING_MAX IMU messages and POSES_PENDING_MAX poses between two
   steps (more are counted dropped: imu_dropped, dropped), and regain_poses at most
   CANDIDATES_MAX; fused_core.py refuses a configuration past them. */

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define NX 12
#define NP (NX * NX)
#define HISTORY_MAX 256
#define POSES_MAX 16
#define IMU_PENDING_MAX 64
#define POSES_PENDING_MAX 64
#define CANDIDATES_MAX 16
#define HEALTH_N 22                     /* trq_fused_health's figures (fused_core.py's _OUT) */

enum { K_NEW, K_FUSED, K_REJECTED, K_HELD, K_RESET };

typedef struct {
    int64_t t_us;
    double pos[3], r_pos[3];
    int kind;
    double vel_shift[3], vel_var[3];
} pose_t;

typedef struct {
    int64_t t_us;
    double a_known[3], rot[9];          /* rot: R (NED from FRD) at t_us, row-major */
    double x[NX], P[NP];                /* P column-major (the kernels' order) */
    double w0[3], w1[3], covered_s;
    int n_poses;
    pose_t poses[POSES_MAX];
    int has_vel;
    double vel[3];
    int acc_taken;
    int acc_formed;                     /* acc_z, acc_var formed (FusedFilter._acc's cache) */
    double acc_z[3], acc_var;
} period_t;

typedef struct {
    int64_t t_us;
    double nu[3], r[3], paa[3];
} candidate_t;

/* a stretch's inputs after x and P (fused.py `_set_stretch`, `_kernel`'s order) */
typedef struct {
    double dt1, a[3], pos[3], r_pos[3], has_pos, dt2, z[3], var, has_acc, gate, zv[3], varv,
        has_vel;
} stretch_t;

typedef struct {
    long long sz_arg, sz_res, sz_iw, sz_w;
    const double **arg;
    double **res;
    long long *iw;
    double *w;
} kernel_t;

typedef struct {
    /* configuration (fused_core.py's CFG_* order) */
    double g, accel_std, imu_rate_hz, accel_gate, pose_gate, vel_std;
    int64_t dropout_us, imu_nominal_us, span_max_us;
    int reject_max, regain, history;
    /* the history: a ring of n periods from head */
    int head, n;
    period_t *per;
    /* received, not yet placed */
    int n_imu;
    int64_t imu_t[IMU_PENDING_MAX];
    double imu_f[IMU_PENDING_MAX][3];
    int n_pending;
    pose_t pending[POSES_PENDING_MAX];
    int n_cand;
    candidate_t cand[CANDIDATES_MAX];
    int has_imu_last, has_last_pose;
    int64_t imu_last_us, last_pose_us;
    /* health */
    double test_ratio;
    int64_t rejected, dropped, imu_dropped, accel_rejected, resets;
    /* the kernels and their outputs */
    kernel_t k1;
    stretch_t s1;
    double r1_x[NX], r1_P[NP], r1_ratio, r1_nis, r1_taken, r1_xp[NX], r1_Pp[NP];
} core_t;

int TRQ_K1(const double **arg, double **res, long long *iw, double *w, int mem);
int TRQ_K1_WORK(long long *sz_arg, long long *sz_res, long long *sz_iw, long long *sz_w);

static period_t *per(core_t *c, int k)
{
    return &c->per[(c->head + k) % HISTORY_MAX];
}

static int kernel_init(kernel_t *k, int (*work)(long long *, long long *, long long *,
                                                 long long *))
{
    work(&k->sz_arg, &k->sz_res, &k->sz_iw, &k->sz_w);
    k->arg = calloc((size_t) k->sz_arg + 1, sizeof(double *));
    k->res = calloc((size_t) k->sz_res + 1, sizeof(double *));
    k->iw = calloc((size_t) k->sz_iw + 1, sizeof(long long));
    k->w = calloc((size_t) k->sz_w + 1, sizeof(double));
    return k->arg && k->res && k->iw && k->w;
}

static void kernel_free(kernel_t *k)
{
    free(k->arg);
    free(k->res);
    free(k->iw);
    free(k->w);
}

/* fused.py `_set_stretch`: the stretch's fields as the kernel's inputs from index i on */
static void stretch_args(const double **arg, int i, const stretch_t *s)
{
    arg[i] = &s->dt1;
    arg[i + 1] = s->a;
    arg[i + 2] = s->pos;
    arg[i + 3] = s->r_pos;
    arg[i + 4] = &s->has_pos;
    arg[i + 5] = &s->dt2;
    arg[i + 6] = s->z;
    arg[i + 7] = &s->var;
    arg[i + 8] = &s->has_acc;
    arg[i + 9] = &s->gate;
    arg[i + 10] = s->zv;
    arg[i + 11] = &s->varv;
    arg[i + 12] = &s->has_vel;
}

void trq_fused_free(core_t *c)
{
    if (c == NULL)
        return;
    kernel_free(&c->k1);
    free(c->per);
    free(c);
}

/* cfg: g, accel_std, imu_rate_hz, accel_gate, pose_gate, autopilot_vel_std, dropout_us,
   imu_nominal_us, span_max_us, accel_reject_max, regain_poses, history. NULL when a limit
   is passed or memory is short. */
core_t *trq_fused_new(const double *cfg)
{
    core_t *c = calloc(1, sizeof(core_t));
    double **r;
    if (c == NULL)
        return NULL;
    c->g = cfg[0];
    c->accel_std = cfg[1];
    c->imu_rate_hz = cfg[2];
    c->accel_gate = cfg[3];
    c->pose_gate = cfg[4];
    c->vel_std = cfg[5];
    c->dropout_us = (int64_t) cfg[6];
    c->imu_nominal_us = (int64_t) cfg[7];
    c->span_max_us = (int64_t) cfg[8];
    c->reject_max = (int) cfg[9];
    c->regain = (int) cfg[10];
    c->history = (int) cfg[11];
    c->per = calloc(HISTORY_MAX, sizeof(period_t));
    if (c->per == NULL || c->history < 2 || c->history > HISTORY_MAX || c->regain < 3
        || c->regain > CANDIDATES_MAX || c->reject_max < 1
        || !kernel_init(&c->k1, TRQ_K1_WORK) || c->k1.sz_arg < 15 || c->k1.sz_res < 7) {
        trq_fused_free(c);
        return NULL;
    }
    stretch_args(c->k1.arg, 2, &c->s1);
    r = c->k1.res;
    r[0] = c->r1_x, r[1] = c->r1_P, r[2] = &c->r1_ratio, r[3] = &c->r1_nis;
    r[4] = &c->r1_taken, r[5] = c->r1_xp, r[6] = c->r1_Pp;
    c->test_ratio = NAN;
    return c;
}

/* frames.rotation_rows, row-major */
static void rotation(double roll, double pitch, double yaw, double *R)
{
    double cr = cos(roll), sr = sin(roll), cp = cos(pitch), sp = sin(pitch);
    double cy = cos(yaw), sy = sin(yaw);
    R[0] = cp * cy;
    R[1] = sr * sp * cy - cr * sy;
    R[2] = cr * sp * cy + sr * sy;
    R[3] = cp * sy;
    R[4] = sr * sp * sy + cr * cy;
    R[5] = cr * sp * sy - sr * cy;
    R[6] = -sp;
    R[7] = sr * cp;
    R[8] = cr * cp;
}

/* FusedFilter.reset after its Python part: x, P (column-major) and the attitude at t_us */
void trq_fused_reset(core_t *c, int64_t t_us, const double *x, const double *P,
                     const double *euler)
{
    period_t *p;
    c->head = 0;
    c->n = 1;
    p = per(c, 0);
    memset(p, 0, sizeof(period_t));
    p->t_us = t_us;
    rotation(euler[0], euler[1], euler[2], p->rot);
    memcpy(p->x, x, sizeof(p->x));
    memcpy(p->P, P, sizeof(p->P));
    p->acc_taken = 1;
    c->n_imu = c->n_pending = c->n_cand = 0;
    c->has_imu_last = 0;
    c->has_last_pose = 1;
    c->last_pose_us = t_us;
    c->test_ratio = NAN;
    c->rejected = c->dropped = c->imu_dropped = c->accel_rejected = c->resets = 0;
}

/* FusedFilter.add_imu after its finiteness check */
void trq_fused_add_imu(core_t *c, int64_t t_us, double f0, double f1, double f2)
{
    if (c->n_imu >= IMU_PENDING_MAX) {
        c->imu_dropped += 1;
        return;
    }
    c->imu_t[c->n_imu] = t_us;
    c->imu_f[c->n_imu][0] = f0;
    c->imu_f[c->n_imu][1] = f1;
    c->imu_f[c->n_imu][2] = f2;
    c->n_imu += 1;
}

/* FusedFilter.add_pose after its checks: the position and its variances per axis */
void trq_fused_add_pose(core_t *c, int64_t t_us, double p0, double p1, double p2, double r0,
                        double r1, double r2)
{
    pose_t *q;
    if (c->n_pending >= POSES_PENDING_MAX) {
        c->dropped += 1;
        return;
    }
    q = &c->pending[c->n_pending++];
    memset(q, 0, sizeof(pose_t));
    q->t_us = t_us;
    q->pos[0] = p0, q->pos[1] = p1, q->pos[2] = p2;
    q->r_pos[0] = r0, q->r_pos[1] = r1, q->r_pos[2] = r2;
    q->kind = K_NEW;
}

static int64_t max64(int64_t a, int64_t b) { return a > b ? a : b; }
static int64_t min64(int64_t a, int64_t b) { return a < b ? a : b; }

/* FusedFilter._place_imu */
static int place_imu(core_t *c, int64_t t_us)
{
    int first = c->n - 1, n_later = 0, i, j, k, placed;
    int64_t t, a, prev, lo, hi, start, end;
    double dt, s, w;
    period_t *p;
    /* sorted by time, stably (Python's sorted with the time as key) */
    for (i = 1; i < c->n_imu; ++i) {
        int64_t tk = c->imu_t[i];
        double fk[3] = {c->imu_f[i][0], c->imu_f[i][1], c->imu_f[i][2]};
        for (j = i - 1; j >= 0 && c->imu_t[j] > tk; --j) {
            c->imu_t[j + 1] = c->imu_t[j];
            memcpy(c->imu_f[j + 1], c->imu_f[j], sizeof(fk));
        }
        c->imu_t[j + 1] = tk;
        memcpy(c->imu_f[j + 1], fk, sizeof(fk));
    }
    for (i = 0; i < c->n_imu; ++i) {
        const double *f = c->imu_f[i];
        t = c->imu_t[i];
        if (t > t_us) {                         /* the next period's: kept in order */
            c->imu_t[n_later] = t;
            memmove(c->imu_f[n_later], f, 3 * sizeof(double));
            ++n_later;
            continue;
        }
        if (c->has_imu_last && t <= c->imu_last_us) {      /* a repeat or out of order */
            c->imu_dropped += 1;
            continue;
        }
        prev = c->imu_last_us;
        a = c->has_imu_last ? max64(prev, t - c->span_max_us) : t - c->imu_nominal_us;
        c->has_imu_last = 1;
        c->imu_last_us = t;
        placed = 0;
        for (k = c->n - 1; k > 0; --k) {
            end = per(c, k)->t_us;
            start = per(c, k - 1)->t_us;
            if (start >= t)
                continue;
            if (end <= a)
                break;
            lo = max64(a, start);
            hi = min64(t, end);
            dt = (double) (hi - lo) * 1e-6;
            s = (0.5 * (double) (lo + hi) - (double) start) / (double) (end - start);
            p = per(c, k);
            w = dt * (1.0 - s);
            for (j = 0; j < 3; ++j)
                p->w0[j] += w * f[j];
            w = dt * s;
            for (j = 0; j < 3; ++j)
                p->w1[j] += w * f[j];
            p->covered_s += dt;
            p->acc_formed = 0;
            placed = 1;
            if (k < first)
                first = k;
        }
        if (!placed)
            c->imu_dropped += 1;
    }
    c->n_imu = n_later;
    return first;
}

/* FusedFilter._place_poses */
static int place_poses(core_t *c, int64_t t_us)
{
    int first = c->n - 1, i, j, k;
    for (i = 0; i < c->n_pending; ++i) {
        pose_t q = c->pending[i];
        period_t *p;
        q.t_us = min64(q.t_us, t_us);
        k = c->n - 1;
        while (k > 0 && per(c, k - 1)->t_us > q.t_us)
            --k;
        if (k == 0 || per(c, k - 1)->t_us > q.t_us) {
            c->dropped += 1;
            continue;
        }
        p = per(c, k);
        if (p->n_poses >= POSES_MAX) {
            c->dropped += 1;
            continue;
        }
        /* kept in time order, stably: after every pose of its time or earlier */
        for (j = p->n_poses; j > 0 && p->poses[j - 1].t_us > q.t_us; --j)
            p->poses[j] = p->poses[j - 1];
        p->poses[j] = q;
        p->n_poses += 1;
        if (k < first)
            first = k;
    }
    c->n_pending = 0;
    return first;
}

/* FusedFilter._acc: 1 and the period's measurement formed, or 0 (no samples) */
static int acc_of(core_t *c, int k)
{
    period_t *p = per(c, k), *q;
    const double *a, *b;
    int i;
    if (p->covered_s <= 0.0)
        return 0;
    if (!p->acc_formed) {
        q = per(c, k - 1);
        a = q->rot;
        b = p->rot;
        for (i = 0; i < 3; ++i) {
            double sa = a[3 * i] * p->w0[0] + a[3 * i + 1] * p->w0[1] + a[3 * i + 2] * p->w0[2];
            double sb = b[3 * i] * p->w1[0] + b[3 * i + 1] * p->w1[1] + b[3 * i + 2] * p->w1[2];
            p->acc_z[i] = (sa + sb) / p->covered_s + (i == 2 ? c->g : 0.0);
        }
        p->acc_var = pow(c->accel_std, 2.0) / (p->covered_s * c->imu_rate_hz);
        p->acc_formed = 1;
    }
    return 1;
}

/* FusedFilter._gate */
static double gate_of(core_t *c, int k)
{
    int m = c->reject_max, lo = k - m > 1 ? k - m : 1, j;
    if (per(c, k - 1)->acc_taken)
        return c->accel_gate;
    if (k - lo == m) {
        for (j = lo; j < k; ++j)
            if (per(c, j)->acc_taken)
                return c->accel_gate;
        return INFINITY;
    }
    return c->accel_gate;
}

/* FusedFilter._set_stretch into s */
static void set_stretch(core_t *c, stretch_t *s, int64_t dt1_us, const double *a_known,
                        const pose_t *q, int64_t dt2_us, const period_t *acc_of_period,
                        double gate, const period_t *vel_of_period)
{
    s->dt1 = (double) dt1_us * 1e-6;
    memcpy(s->a, a_known, sizeof(s->a));
    if (q == NULL) {
        s->has_pos = 0.0;
    } else {
        memcpy(s->pos, q->pos, sizeof(s->pos));
        memcpy(s->r_pos, q->r_pos, sizeof(s->r_pos));
        s->has_pos = 1.0;
    }
    s->dt2 = (double) dt2_us * 1e-6;
    if (acc_of_period == NULL) {
        s->has_acc = 0.0;
    } else {
        memcpy(s->z, acc_of_period->acc_z, sizeof(s->z));
        s->var = acc_of_period->acc_var;
        s->has_acc = 1.0;
        s->gate = gate;
    }
    if (vel_of_period == NULL) {
        s->has_vel = 0.0;
    } else {
        memcpy(s->zv, vel_of_period->vel, sizeof(s->zv));
        s->varv = 2.0 * c->vel_std * c->vel_std;
        s->has_vel = 1.0;
    }
}

/* FusedFilter._stretch (the compiled kernel): the outputs in r1_* */
static void stretch(core_t *c, const double *x, const double *P, int64_t dt1_us,
                    const double *a_known, const pose_t *q, int64_t dt2_us,
                    const period_t *acc, double gate, const period_t *vel)
{
    c->k1.arg[0] = x;
    c->k1.arg[1] = P;
    set_stretch(c, &c->s1, dt1_us, a_known, q, dt2_us, acc, gate, vel);
    TRQ_K1(c->k1.arg, c->k1.res, c->k1.iw, c->k1.w, 0);
}

/* FusedFilter.dead_reckoning */
static int dead_reckoning(const core_t *c, int64_t t_us)
{
    return !c->has_last_pose || t_us - c->last_pose_us > c->dropout_us;
}

static void pose_seen(core_t *c, int64_t t_us)
{
    int64_t last = (c->has_last_pose && c->last_pose_us != 0) ? c->last_pose_us : t_us;
    c->last_pose_us = max64(last, t_us);
    c->has_last_pose = 1;
}

/* FusedFilter._on_a_line */
static int on_a_line(const core_t *c, const candidate_t *three)
{
    const candidate_t *a = &three[0], *b = &three[1], *e = &three[2];
    double w = (double) (b->t_us - a->t_us) / (double) (e->t_us - a->t_us);
    double lever = 0.5 * (double) (b->t_us - a->t_us) * (double) (e->t_us - b->t_us) * 1e-12;
    double sum = 0.0;
    int i;
    for (i = 0; i < 3; ++i) {
        double d = b->nu[i] - ((1.0 - w) * a->nu[i] + w * e->nu[i]);
        double var = b->r[i] + pow(1.0 - w, 2.0) * a->r[i] + w * w * e->r[i]
            + lever * lever * b->paa[i];
        sum += d * d / var;
    }
    return sum <= c->pose_gate;
}

/* FusedFilter._decide, the prior at the pose (x, P column-major) given */
static void decide(core_t *c, pose_t *q, double ratio, const double *x_prior,
                   const double *P_prior)
{
    candidate_t *run = c->cand;
    int i;
    c->test_ratio = ratio;
    if (ratio <= 1.0) {
        q->kind = K_FUSED;
        c->n_cand = 0;
        pose_seen(c, q->t_us);
        return;
    }
    if (!dead_reckoning(c, q->t_us)) {
        q->kind = K_REJECTED;
        c->rejected += 1;
        return;
    }
    if (c->n_cand >= CANDIDATES_MAX) {         /* never with regain <= CANDIDATES_MAX */
        memmove(run, run + 1, (CANDIDATES_MAX - 1) * sizeof(candidate_t));
        c->n_cand -= 1;
    }
    run = &c->cand[c->n_cand++];
    run->t_us = q->t_us;
    for (i = 0; i < 3; ++i) {
        run->nu[i] = q->pos[i] - x_prior[i];
        run->r[i] = q->r_pos[i];
        run->paa[i] = P_prior[(6 + i) * NX + 6 + i];
    }
    if (c->n_cand >= 3 && !on_a_line(c, &c->cand[c->n_cand - 3])) {
        memmove(c->cand, &c->cand[c->n_cand - 2], 2 * sizeof(candidate_t));
        c->n_cand = 2;
    }
    if (c->n_cand >= c->regain) {
        const candidate_t *first = &c->cand[0], *last = &c->cand[c->n_cand - 1];
        double span = (double) (q->t_us - first->t_us) * 1e-6;
        q->kind = K_RESET;
        for (i = 0; i < 3; ++i) {
            q->vel_shift[i] = (last->nu[i] - first->nu[i]) / span;
            q->vel_var[i] = (first->r[i] + q->r_pos[i]) / (span * span);
        }
        c->n_cand = 0;
        c->resets += 1;
        pose_seen(c, q->t_us);
    } else {
        q->kind = K_HELD;
        c->rejected += 1;
    }
}

/* FusedFilter._reset_to into x, P */
static void reset_to(const pose_t *q, const double *x_prior, const double *P_prior, double *x,
                     double *P)
{
    int i, j;
    memcpy(x, x_prior, NX * sizeof(double));
    memcpy(P, P_prior, NP * sizeof(double));
    for (i = 0; i < 3; ++i) {
        x[i] = q->pos[i];
        x[3 + i] = x[3 + i] + q->vel_shift[i];
    }
    for (i = 0; i < 6; ++i)
        for (j = 0; j < NX; ++j)
            P[j * NX + i] = P[i * NX + j] = 0.0;
    for (i = 0; i < 3; ++i) {
        P[i * NX + i] = q->r_pos[i];
        P[(3 + i) * NX + 3 + i] = q->vel_var[i];
    }
}

/* FusedFilter._acc_result */
static void acc_result(core_t *c, int k, int has_acc, int taken, int newest)
{
    period_t *p = per(c, k);
    p->acc_taken = !has_acc || taken;
    if (k == newest && !p->acc_taken)
        c->accel_rejected += 1;
}

/* FusedFilter._run_period */
static void run_period(core_t *c, int k, int newest)
{
    period_t *prev = per(c, k - 1), *p = per(c, k);
    int has_acc = acc_of(c, k);
    double gate = prev->acc_taken ? c->accel_gate : gate_of(c, k);
    const period_t *acc = has_acc ? p : NULL, *vel = p->has_vel ? p : NULL;
    double x[NX], P[NP];
    /* the prior at a pose (FusedFilter._prior): the kernel's, until its next call */
    const double *prior_x = c->r1_xp, *prior_P = c->r1_Pp;
    int64_t t = prev->t_us;
    int active[POSES_MAX], n_active = 0, i, done = 0;
    memcpy(x, prev->x, sizeof(x));
    memcpy(P, prev->P, sizeof(P));
    for (i = 0; i < p->n_poses; ++i) {
        int kind = p->poses[i].kind;
        if (kind == K_NEW || kind == K_FUSED || kind == K_RESET)
            active[n_active++] = i;
    }
    for (i = 0; i < n_active; ++i) {
        pose_t *q = &p->poses[active[i]];
        int last = i == n_active - 1;
        stretch(c, x, P, q->t_us - t, p->a_known, q, last ? p->t_us - q->t_us : 0,
                last ? acc : NULL, gate, last ? vel : NULL);
        if (q->kind == K_NEW)
            decide(c, q, c->r1_ratio, prior_x, prior_P);
        if (q->kind == K_FUSED) {
            memcpy(x, c->r1_x, sizeof(x));
            memcpy(P, c->r1_P, sizeof(P));
            if (last) {
                done = 1;
                acc_result(c, k, has_acc, c->r1_taken > 0.0, newest);
            }
        } else if (q->kind == K_RESET) {
            reset_to(q, prior_x, prior_P, x, P);
        } else {                                /* rejected or held: the prior goes on */
            memcpy(x, prior_x, sizeof(x));
            memcpy(P, prior_P, sizeof(P));
        }
        t = q->t_us;
    }
    if (!done) {
        stretch(c, x, P, p->t_us - t, p->a_known, NULL, 0, acc, gate, vel);
        memcpy(x, c->r1_x, sizeof(x));
        memcpy(P, c->r1_P, sizeof(P));
        acc_result(c, k, has_acc, c->r1_taken > 0.0, newest);
    }
    memcpy(p->x, x, sizeof(x));
    memcpy(p->P, P, sizeof(P));
}

/* a whole period p from t_prev as one stretch (_run_two's): to its pose q if any, on to its
   end, there its accelerometer (if has_acc) and its velocity, from x and P at t_prev: the
   kernel's outputs in r1_* (`stretch`) */
static void period_stretch(core_t *c, const double *x, const double *P, int64_t t_prev,
                           const period_t *p, const pose_t *q, int has_acc, double gate)
{
    int64_t t = q == NULL ? p->t_us : q->t_us;
    stretch(c, x, P, t - t_prev, p->a_known, q, p->t_us - t, has_acc ? p : NULL, gate,
            p->has_vel ? p : NULL);
}

/* FusedFilter._run_two: 1 done, 0 nothing done (the periods hold more) */
static int run_two(core_t *c, int k)
{
    period_t *p0 = per(c, k - 2), *p1 = per(c, k - 1), *p2 = per(c, k);
    pose_t *q1 = NULL, *q2 = NULL;
    int i, n_active = 0, acc1, acc2, m = c->reject_max, lo, any;
    double gate1, gate2_not, take1;
    for (i = 0; i < p1->n_poses; ++i) {
        int kind = p1->poses[i].kind;
        if (kind == K_NEW || kind == K_FUSED || kind == K_RESET) {
            ++n_active;
            q1 = &p1->poses[i];
        }
    }
    if (n_active > 1 || (n_active == 1 && q1->kind != K_FUSED))
        return 0;
    if (p2->n_poses > 0) {
        if (p2->n_poses > 1 || p2->poses[0].kind != K_NEW)
            return 0;
        q2 = &p2->poses[0];
    }
    acc1 = acc_of(c, k - 1);
    acc2 = acc_of(c, k);
    gate1 = p0->acc_taken ? c->accel_gate : gate_of(c, k - 1);
    lo = k - m > 1 ? k - m : 1;
    any = 0;
    for (i = lo; i < k - 1; ++i)
        any |= per(c, i)->acc_taken;
    gate2_not = (k - lo == m && !any) ? INFINITY : c->accel_gate;
    /* the period before, from p0 */
    period_stretch(c, p0->x, p0->P, p0->t_us, p1, q1, acc1, gate1);
    take1 = c->r1_taken;
    memcpy(p1->x, c->r1_x, sizeof(p1->x));
    memcpy(p1->P, c->r1_P, sizeof(p1->P));
    acc_result(c, k - 1, acc1, take1 > 0.0, k);
    /* the new one from its end; its gate as `_kernel_two`'s if_else(!has_acc1 || take1,
       accel_gate, gate2_not), C's truth of a double as the generated code's */
    period_stretch(c, p1->x, p1->P, p1->t_us, p2, q2, acc2,
                   (!acc1 || take1 != 0.0) ? c->accel_gate : gate2_not);
    if (q2 != NULL) {
        double ratio = c->r1_ratio;
        if (!(ratio <= 1.0)) {                  /* past the gate (or not a number) */
            run_period(c, k, k);
            return 1;
        }
        decide(c, q2, ratio, NULL, NULL);
    }
    memcpy(p2->x, c->r1_x, sizeof(p2->x));
    memcpy(p2->P, c->r1_P, sizeof(p2->P));
    acc_result(c, k, acc2, c->r1_taken > 0.0, k);
    return 1;
}

/* FusedFilter._run */
static void run(core_t *c, int first)
{
    int newest = c->n - 1, k;
    if (first < 1)
        first = 1;
    if (first == newest - 1 && run_two(c, newest))
        return;
    for (k = first; k <= newest; ++k)
        run_period(c, k, newest);
}

/* FusedFilter.health into out: x (12), test ratio, position variance (trace / 3),
   dead reckoning, rejected, resets, accel_rejected, dropped, imu_dropped, last_pose_us, the
   newest period's t_us */
void trq_fused_health(const core_t *c, int64_t t_us, double *out)
{
    const period_t *p;
    int i;
    if (c->n == 0) {                            /* before the first reset: nothing known */
        for (i = 0; i < HEALTH_N; ++i)
            out[i] = NAN;
        return;
    }
    p = &c->per[(c->head + c->n - 1) % HISTORY_MAX];
    memcpy(out, p->x, NX * sizeof(double));
    out[12] = c->test_ratio;
    out[13] = (p->P[0] + p->P[NX + 1] + p->P[2 * NX + 2]) / 3.0;
    out[14] = dead_reckoning(c, t_us);
    out[15] = (double) c->rejected;
    out[16] = (double) c->resets;
    out[17] = (double) c->accel_rejected;
    out[18] = (double) c->dropped;
    out[19] = (double) c->imu_dropped;
    out[20] = (double) c->last_pose_us;
    out[21] = (double) p->t_us;
}

/* FusedFilter.step: a_known (3), euler (3, or NULL: the last period's attitude), vel (3, or
   NULL; finite, and autopilot_vel_std > 0, checked by the caller); the health into out */
void trq_fused_step(core_t *c, int64_t t_us, const double *a_known, const double *euler,
                    const double *vel, double *out)
{
    period_t *last, *p;
    int first;
    if (c->n == 0) {                            /* before the first reset: no history */
        trq_fused_health(c, t_us, out);
        return;
    }
    last = per(c, c->n - 1);
    if (t_us <= last->t_us) {
        trq_fused_health(c, t_us, out);
        return;
    }
    if (c->n < c->history) {
        c->n += 1;
    } else {                                    /* the oldest period leaves the history */
        c->head = (c->head + 1) % HISTORY_MAX;
    }
    p = per(c, c->n - 1);
    if (p != last)
        memcpy(p->x, last->x, sizeof(p->x)), memcpy(p->P, last->P, sizeof(p->P));
    if (euler == NULL) {
        if (p != last)
            memcpy(p->rot, last->rot, sizeof(p->rot));
    } else {
        rotation(euler[0], euler[1], euler[2], p->rot);
    }
    p->t_us = t_us;
    memcpy(p->a_known, a_known, sizeof(p->a_known));
    memset(p->w0, 0, sizeof(p->w0));
    memset(p->w1, 0, sizeof(p->w1));
    p->covered_s = 0.0;
    p->n_poses = 0;
    p->has_vel = vel != NULL;
    if (vel != NULL)
        memcpy(p->vel, vel, sizeof(p->vel));
    p->acc_taken = 1;
    p->acc_formed = 0;
    first = c->n - 1;
    if (c->n_imu > 0) {
        int k = place_imu(c, t_us);
        if (k < first)
            first = k;
    }
    if (c->n_pending > 0) {
        int k = place_poses(c, t_us);
        if (k < first)
            first = k;
    }
    run(c, first);
    trq_fused_health(c, t_us, out);
}

/* the history for tests (FusedFilter._periods): its length, and period k's time, x, P
   (column-major), covered time and accelerometer decision */
int trq_fused_periods(const core_t *c)
{
    return c->n;
}

void trq_fused_period(const core_t *c, int k, double *out)
{
    const period_t *p = &c->per[(c->head + k) % HISTORY_MAX];
    out[0] = (double) p->t_us;
    memcpy(out + 1, p->x, NX * sizeof(double));
    memcpy(out + 1 + NX, p->P, NP * sizeof(double));
    out[1 + NX + NP] = p->covered_s;
    out[2 + NX + NP] = p->acc_taken;
}
