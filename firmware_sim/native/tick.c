/* The board's per-tick servo path in C: interpolation -> servo model -> MuJoCo ctrl -> mj_step.
 *
 * A transcription of firmware_sim/board_stream.py `TargetStream.interpolate` and
 * firmware_sim/servo_model.py `ServoModel.step_list` (the Python reference) doing the same IEEE
 * double operations in the same order, so the board's state is bit-identical whichever runs
 * (tests/firmware/test_native_tick.py compares both over long random streams):
 *
 *   - Python's `float * int` and `float / int` convert the int to double first: (double)(t - t0);
 *   - Python's round(x) is round-half-even: nearbyint() in the default rounding mode; round()
 *     returns an int, so a result of 0 is +0.0 once multiplied back: `+ 0.0` turns nearbyint's
 *     -0.0 into +0.0 (and changes nothing else);
 *   - min(s, cap) keeps s unless cap < s;
 *   - compiled with -ffp-contract=off (no fused multiply-add) and without -ffast-math.
 *
 * gs_run runs n consecutive ticks in one call (t, t + tick_us, ...) with the same flags: the board
 * uses it for a run of "quiet" lockstep ticks, where its Python around each tick would change nothing
 * (no frame due, watchdog fed, no report due before the last one; see Board.run), so a batch leaves
 * exactly the state n gs_tick calls leave.
 *
 * gs_run_split runs two such batches in one call with what the board's Python does between them in the
 * middle: n1 ticks, then a report's snapshot (doubles copied out of the MjData: gs_copy), then the anchors
 * and next keyframes the Python prepared for the first tick of the second part (the frames due at it
 * applied: gs_pending), then n2 ticks. The lockstep board uses it for the ticks up to a report and the
 * quiet ticks after it up to the next frame it may handle (Board._plan_split): one call, one hand-over
 * to the worker per report period instead of two, and the same state as the two batches.
 *
 * gs_worker_* run gs_run on a thread of its own (POSIX threads), so the caller's thread can do other work
 * while the ticks run: the lockstep server encodes, writes and reads the link meanwhile (Python's GIL
 * is not held by this thread, which runs no Python). One job at a time; the caller must not touch the
 * state's arrays or the MjData between gs_worker_start and gs_worker_wait.
 *
 * No MuJoCo header is needed: mj_step comes in as a function pointer taken from the libmujoco the
 * mujoco wheel ships (already loaded by the Python bindings), and qpos/ctrl as the addresses of
 * the MjData arrays the bindings expose. Built and loaded by firmware_sim/native/__init__.py.
 */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

typedef void (*gs_mj_step_fn)(const void *m, void *d);

/* Field order and types match firmware_sim.native.TickState (ctypes); all 8-byte fields. */
typedef struct {
    int64_t n;                 /* servos */
    int64_t substeps;          /* mj_step calls per tick */
    const void *model;         /* mjModel* */
    void *data;                /* mjData* */
    gs_mj_step_fn mj_step;
    double *qpos;              /* d->qpos */
    double *mj_ctrl;           /* d->ctrl */
    const int64_t *qpos_adr;   /* per servo: index into qpos */
    const int64_t *act_id;     /* per servo: index into ctrl */
    const int64_t *anchor_t;   /* per servo: interpolation anchor (us) */
    const double *anchor_v;    /*   and its value (rad) */
    const int64_t *next_ok;    /* per servo: 1 when a buffered keyframe covers it */
    const int64_t *next_t;     /*   its apply-at (us) */
    const double *next_v;      /*   its target (rad) */
    double *desired;           /* per servo: the interpolated target (out, or in without GS_INTERP) */
    double *ctrl;              /* per servo: the servo model's output (out) */
    double *cmd;               /* per servo: the speed-limited command (in/out) */
    const double *mins;
    const double *maxs;
    const double *max_step;    /* rad per tick at the table speeds */
    const double *max_speed;   /* rad/s (for a speed cap) */
    double period_s;
    double resolution;
    double deadband;
    int64_t limit_clamps;      /* servo-ticks clamped to a joint limit (added to) */
    int64_t speed_clamps;      /* servo-ticks clamped to the speed limit (added to) */
} gs_tick_state;

#define GS_INTERP 1   /* interpolate `desired` from the anchors and next keyframes */
#define GS_CAP 2      /* lower every speed limit to `cap` rad/s */
#define GS_EPS 1e-9

/* One control tick at board time t (us). Returns 1 when a servo was clamped, else 0. */
int gs_tick(gs_tick_state *s, int64_t t, int64_t flags, double cap)
{
    const int64_t n = s->n;
    int64_t limit_hits = 0, speed_hits = 0;
    if (flags & GS_INTERP) {
        for (int64_t i = 0; i < n; i++) {
            double out = s->anchor_v[i];
            if (s->next_ok[i]) {
                const int64_t t1 = s->next_t[i], t0 = s->anchor_t[i];
                if (t1 > t0) {
                    const double a = s->anchor_v[i];
                    out = a + (s->next_v[i] - a) * (double)(t - t0) / (double)(t1 - t0);
                }
            }
            s->desired[i] = out;
        }
    }
    const double res = s->resolution, db = s->deadband;
    for (int64_t i = 0; i < n; i++) {
        const double x = s->desired[i], lo = s->mins[i], hi = s->maxs[i];
        double step = s->max_step[i];
        if (flags & GS_CAP) {
            const double sp = s->max_speed[i];
            step = (cap < sp ? cap : sp) * s->period_s;
        }
        const double tg = x > hi ? hi : (x < lo ? lo : x);
        if (fabs(tg - x) > GS_EPS)
            limit_hits++;
        double c = s->cmd[i];
        const double delta = tg - c;
        if (fabs(delta) > step + GS_EPS)
            speed_hits++;
        c += delta > step ? step : (delta < -step ? -step : delta);
        s->cmd[i] = c;
        double q = (nearbyint(c / res) + 0.0) * res;
        q = q > hi ? hi : (q < lo ? lo : q);
        const double m = s->qpos[s->qpos_adr[i]];
        const double v = fabs(q - m) < db ? m : q;
        const double out = v > hi ? hi : (v < lo ? lo : v);
        s->ctrl[i] = out;
        s->mj_ctrl[s->act_id[i]] = out;
    }
    s->limit_clamps += limit_hits;
    s->speed_clamps += speed_hits;
    for (int64_t k = 0; k < s->substeps; k++)
        s->mj_step(s->model, s->data);
    return (limit_hits || speed_hits) ? 1 : 0;
}

/* n ticks at board times t, t + tick_us, ... (each exactly gs_tick). Returns how many were clamped. */
int64_t gs_run(gs_tick_state *s, int64_t t, int64_t n, int64_t tick_us, int64_t flags, double cap)
{
    int64_t clamped = 0;
    for (int64_t k = 0; k < n; k++)
        clamped += gs_tick(s, t + k * tick_us, flags, cap);
    return clamped;
}

/* A report's snapshot: n doubles from src (MjData) to dst. */
typedef struct {
    double *dst;
    const double *src;
    int64_t n;
} gs_copy;

/* What the first tick after the snapshot sees: per servo its anchor and next keyframe (copied over the
 * state's arrays, which are the caller's; see the top of this file). */
typedef struct {
    const int64_t *anchor_t;
    const double *anchor_v;
    const int64_t *next_ok;
    const int64_t *next_t;
    const double *next_v;
} gs_pending;

/* gs_run of n1 ticks from t, the ncopy copies, the pending anchors (when p is not NULL), gs_run of n2 ticks
 * from t + n1 * tick_us. Returns the first part's clamped ticks; the second part's go to *clamped2. */
int64_t gs_run_split(gs_tick_state *s, int64_t t, int64_t n1, int64_t n2, int64_t tick_us, int64_t flags,
                     double cap, const gs_copy *copies, int64_t ncopy, const gs_pending *p, int64_t *clamped2)
{
    const int64_t c1 = gs_run(s, t, n1, tick_us, flags, cap);
    for (int64_t k = 0; k < ncopy; k++)
        memcpy(copies[k].dst, copies[k].src, (size_t)copies[k].n * sizeof(double));
    if (p) {
        const size_t n = (size_t)s->n;
        memcpy((void *)s->anchor_t, p->anchor_t, n * sizeof(int64_t));
        memcpy((void *)s->anchor_v, p->anchor_v, n * sizeof(double));
        memcpy((void *)s->next_ok, p->next_ok, n * sizeof(int64_t));
        memcpy((void *)s->next_t, p->next_t, n * sizeof(int64_t));
        memcpy((void *)s->next_v, p->next_v, n * sizeof(double));
    }
    *clamped2 = n2 > 0 ? gs_run(s, t + n1 * tick_us, n2, tick_us, flags, cap) : 0;
    return c1;
}

/* A clock for MuJoCo's mjcb_time that always says 0: MuJoCo then skips reading the system clock at
 * the start and end of each of its ~15 timed stages per mj_step (d->timer, which the board never
 * reads; ~1 us per mj_step here). Installed by firmware_sim/native/__init__.py. */
double gs_no_clock(void)
{
    return 0.0;
}

/* A thread that runs gs_run jobs (see the top of this file). */
typedef struct {
    pthread_mutex_t mu;
    pthread_cond_t cv;
    pthread_t th;
    int busy;                  /* a job is set and not yet done */
    int stop;
    gs_tick_state *s;
    int64_t t, n, n2, tick_us, flags;
    double cap;
    const gs_copy *copies;
    int64_t ncopy;
    const gs_pending *pending;
    int64_t result, result2;
} gs_worker;

static void *gs_worker_main(void *arg)
{
    gs_worker *w = (gs_worker *)arg;
    pthread_mutex_lock(&w->mu);
    for (;;) {
        while (!w->busy && !w->stop)
            pthread_cond_wait(&w->cv, &w->mu);
        if (w->stop)
            break;
        pthread_mutex_unlock(&w->mu);
        int64_t r2 = 0;
        const int64_t r = gs_run_split(w->s, w->t, w->n, w->n2, w->tick_us, w->flags, w->cap, w->copies, w->ncopy,
                                       w->pending, &r2);
        pthread_mutex_lock(&w->mu);
        w->result = r;
        w->result2 = r2;
        w->busy = 0;
        pthread_cond_broadcast(&w->cv);
    }
    pthread_mutex_unlock(&w->mu);
    return NULL;
}

/* A new worker thread, or NULL when one cannot be made (the caller then runs gs_run itself). */
void *gs_worker_new(void)
{
    gs_worker *w = (gs_worker *)calloc(1, sizeof *w);
    if (!w)
        return NULL;
    if (pthread_mutex_init(&w->mu, NULL) != 0) {
        free(w);
        return NULL;
    }
    if (pthread_cond_init(&w->cv, NULL) != 0) {
        pthread_mutex_destroy(&w->mu);
        free(w);
        return NULL;
    }
    if (pthread_create(&w->th, NULL, gs_worker_main, w) != 0) {
        pthread_cond_destroy(&w->cv);
        pthread_mutex_destroy(&w->mu);
        free(w);
        return NULL;
    }
    return w;
}

/* Start gs_run_split(s, t, n, n2, tick_us, flags, cap, copies, ncopy, pending, .) on the worker; returns at
 * once. The copies and pending must stay as they are until gs_worker_wait. */
void gs_worker_start_split(void *handle, gs_tick_state *s, int64_t t, int64_t n, int64_t n2, int64_t tick_us,
                           int64_t flags, double cap, const gs_copy *copies, int64_t ncopy, const gs_pending *pending)
{
    gs_worker *w = (gs_worker *)handle;
    pthread_mutex_lock(&w->mu);
    w->s = s;
    w->t = t;
    w->n = n;
    w->n2 = n2;
    w->copies = copies;
    w->ncopy = ncopy;
    w->pending = pending;
    w->tick_us = tick_us;
    w->flags = flags;
    w->cap = cap;
    w->busy = 1;
    pthread_cond_broadcast(&w->cv);
    pthread_mutex_unlock(&w->mu);
}

/* Start gs_run(s, t, n, tick_us, flags, cap) on the worker; returns at once. */
void gs_worker_start(void *handle, gs_tick_state *s, int64_t t, int64_t n, int64_t tick_us, int64_t flags, double cap)
{
    gs_worker_start_split(handle, s, t, n, 0, tick_us, flags, cap, NULL, 0, NULL);
}

/* Wait for the started job; returns the first part's clamped ticks, the second part's go to *clamped2. */
int64_t gs_worker_wait_split(void *handle, int64_t *clamped2)
{
    gs_worker *w = (gs_worker *)handle;
    pthread_mutex_lock(&w->mu);
    while (w->busy)
        pthread_cond_wait(&w->cv, &w->mu);
    const int64_t r = w->result;
    *clamped2 = w->result2;
    pthread_mutex_unlock(&w->mu);
    return r;
}

/* Wait for the started job; returns its gs_run result (of the first part). */
int64_t gs_worker_wait(void *handle)
{
    int64_t clamped2;
    return gs_worker_wait_split(handle, &clamped2);
}

/* Finish the job under way (if any), end the thread and free the worker. */
void gs_worker_free(void *handle)
{
    gs_worker *w = (gs_worker *)handle;
    if (!w)
        return;
    pthread_mutex_lock(&w->mu);
    while (w->busy)
        pthread_cond_wait(&w->cv, &w->mu);
    w->stop = 1;
    pthread_cond_broadcast(&w->cv);
    pthread_mutex_unlock(&w->mu);
    pthread_join(w->th, NULL);
    pthread_cond_destroy(&w->cv);
    pthread_mutex_destroy(&w->mu);
    free(w);
}
