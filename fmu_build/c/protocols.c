/* The resolution protocols' inner loops over an FMU's own FMI 2 / FMI 3 functions, for Python importers
 * (ident.model.compiled, used by ident.protocols.resolution).
 *
 * Importer code, like runner.c, not model code: no physics here. It receives the FMU's setter, doStep and getter
 * function pointers as loaded by fmpy and repeats, call for call, what the Python loops of ident do through
 * ident.Plant (Plant.step, Plant.run_to_rest, ImpulseController.pulse, LinearPD.control / LinearPD.move): the
 * same doStep calls with the same communication points and step sizes, the same tests on the same outputs, the
 * same floating-point operations in the same order. The results are therefore bit for bit those of the Python
 * loops; only Python's per-call overhead is gone.
 *
 * Work is counted in doStep calls. A call returns to Python once it has taken `budget` doSteps (1), when the job
 * is done (0), or on a failure (-1, `failed` says which call and the values it was made with). The job structs
 * carry every loop variable, so the next call resumes exactly where the last one stopped: Python gets control
 * between chunks (Ctrl-C) and nothing depends on where the chunks fall.
 */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

enum { HD_FAIL_NONE = 0, HD_FAIL_SET = 1, HD_FAIL_STEP = 2, HD_FAIL_GET = 3, HD_FAIL_SETTLE = 4 };

/* One FMU instance as ident.Plant sees it. Python fills the FMU part and the state, and reads the state back. */
typedef struct {
    int fmi_version; /* 2 or 3 */
    void *instance;
    void *set_real, *do_step, *get_real, *get_int, *get_bool;
    uint32_t vr_torque, vr_arm, vr_count, vr_stuck[2];
    /* Plant.time, Plant.torque and the outputs at the last communication point */
    double time, torque, arm;
    int32_t count;
    int32_t motor_stuck, load_stuck;
    /* work: doSteps taken in this call; the call returns once steps >= budget (> 0) */
    int64_t steps, budget;
    /* failure: which call failed and its arguments (for Plant's messages) */
    int32_t failed;
    double fail_torque, fail_time, fail_dt;
} hd_plant;

typedef int (*set2_t)(void *, const uint32_t *, size_t, const double *);
typedef int (*step2_t)(void *, double, double, int);
typedef int (*getr2_t)(void *, const uint32_t *, size_t, double *);
typedef int (*geti2_t)(void *, const uint32_t *, size_t, int32_t *);
typedef int (*getb2_t)(void *, const uint32_t *, size_t, int *);

typedef int (*set3_t)(void *, const uint32_t *, size_t, const double *, size_t);
typedef int (*step3_t)(void *, double, double, bool, bool *, bool *, bool *, double *);
typedef int (*getr3_t)(void *, const uint32_t *, size_t, double *, size_t);
typedef int (*geti3_t)(void *, const uint32_t *, size_t, int32_t *, size_t);
typedef int (*getb3_t)(void *, const uint32_t *, size_t, bool *, size_t);

/* Plant.sample(): the outputs the protocols look at. Status > fmiWarning is a failure, as in ident.Plant. */
static int read_outputs(hd_plant *p) {
    int s;
    if (p->fmi_version == 2) {
        int b[2];
        s = ((getr2_t)p->get_real)(p->instance, &p->vr_arm, 1, &p->arm);
        if (s <= 1) s = ((geti2_t)p->get_int)(p->instance, &p->vr_count, 1, &p->count);
        if (s <= 1) s = ((getb2_t)p->get_bool)(p->instance, p->vr_stuck, 2, b);
        if (s <= 1) { p->motor_stuck = b[0] != 0; p->load_stuck = b[1] != 0; }
    } else {
        bool b[2];
        s = ((getr3_t)p->get_real)(p->instance, &p->vr_arm, 1, &p->arm, 1);
        if (s <= 1) s = ((geti3_t)p->get_int)(p->instance, &p->vr_count, 1, &p->count, 1);
        if (s <= 1) s = ((getb3_t)p->get_bool)(p->instance, p->vr_stuck, 2, b, 2);
        if (s <= 1) { p->motor_stuck = b[0]; p->load_stuck = b[1]; }
    }
    if (s > 1) { p->failed = HD_FAIL_GET; return -1; }
    return 0;
}

int hd_plant_read(hd_plant *p) { return read_outputs(p); }

/* Plant.step(torque, dt): set the input, doStep from the current communication point, read the outputs. */
static int step(hd_plant *p, double torque, double dt) {
    int s;
    if (p->fmi_version == 2) s = ((set2_t)p->set_real)(p->instance, &p->vr_torque, 1, &torque);
    else s = ((set3_t)p->set_real)(p->instance, &p->vr_torque, 1, &torque, 1);
    if (s > 1) { p->failed = HD_FAIL_SET; p->fail_torque = torque; return -1; }
    p->torque = torque;
    if (p->fmi_version == 2) {
        s = ((step2_t)p->do_step)(p->instance, p->time, dt, 1);
    } else {
        bool event = false, terminate = false, early = false;
        double last = 0.0;
        s = ((step3_t)p->do_step)(p->instance, p->time, dt, true, &event, &terminate, &early, &last);
    }
    p->steps++;
    if (s > 1) { p->failed = HD_FAIL_STEP; p->fail_time = p->time; p->fail_dt = dt; return -1; }
    p->time += dt;
    return read_outputs(p);
}

static bool at_rest(const hd_plant *p) { return p->motor_stuck && p->load_stuck; }

/* Plant.run_to_rest(dt, max_time), resumable: one zero-torque step first (`started`), then zero torque until
 * both bodies stick; HD_FAIL_SETTLE once the time passes t_end. 1: at rest, 0: budget used, -1: failure. */
typedef struct {
    int32_t started;
    double t_end;
} hd_rest;

static int to_rest(hd_plant *p, hd_rest *r, double dt, double max_time) {
    if (!r->started) {
        if (step(p, 0.0, dt)) return -1;
        r->t_end = p->time + max_time;
        r->started = 1;
    }
    while (!at_rest(p)) {
        if (p->time > r->t_end) { p->failed = HD_FAIL_SETTLE; return -1; }
        if (p->steps >= p->budget) return 0;
        if (step(p, 0.0, dt)) return -1;
    }
    r->started = 0;
    return 1;
}

/* ImpulseController.pulse repeated n times; with `decide`, the early-deciding median test of
 * ident.protocols.resolution (stop once more than n/2 increments are > eps1, or more than n/2 are <= eps1). */
typedef struct {
    double torque, width, rest_dt, max_rest, eps1;
    int64_t n, done, above, below;
    int32_t decide;
    int32_t decision; /* -1 while undecided (or without `decide`), else 0 / 1 */
    int32_t phase;    /* 0: a pulse starts, 1: bringing the plant to rest first, 2: resting after the pulse */
    double before;
    hd_rest rest;
    double *increments; /* n */
} hd_pulses;

enum { PH_START = 0, PH_PRE_REST = 1, PH_REST = 2 };

static void record_pulse(hd_pulses *j, double inc) {
    j->increments[j->done++] = inc;
    if (inc > j->eps1) j->above++;
    else j->below++;
    if (j->decide && 2 * j->above > j->n) j->decision = 1;
    else if (j->decide && 2 * j->below > j->n) j->decision = 0;
}

int hd_pulses_run(hd_plant *p, hd_pulses *j) {
    int r;
    p->steps = 0;
    while (j->done < j->n && j->decision < 0) {
        if (j->phase == PH_START && !(at_rest(p) && p->torque == 0.0)) j->phase = PH_PRE_REST;
        if (j->phase == PH_PRE_REST && (r = to_rest(p, &j->rest, j->rest_dt, j->max_rest)) != 1) return r < 0 ? -1 : 1;
        if (j->phase != PH_REST) {
            j->before = p->arm;
            j->phase = PH_REST;
            if (step(p, j->torque, j->width)) return -1;
        }
        if ((r = to_rest(p, &j->rest, j->rest_dt, j->max_rest)) != 1) return r < 0 ? -1 : 1;
        j->phase = PH_START;
        record_pulse(j, p->arm - j->before);
        if (p->steps >= p->budget && j->done < j->n && j->decision < 0) return 1;
    }
    return 0;
}

/* LinearPD.move repeated: `warmup` + `n_steps` set-point steps of `counts`, the PD (LinearPD.control) on the
 * encoder at period dt until the final-rest rule holds; increments of the measured steps; with
 * `stop_at_failure`, stop after the first measured step of eps1 or less. */
typedef struct {
    double Kp, Kd, saturation, count_rad, dt_star, f_m, dt, max_time, eps1;
    int64_t counts, warmup, n_steps, done; /* done: moves completed (warm-up included) */
    int32_t stop_at_failure, stopped;
    int64_t setpoint, count_prev;
    int32_t has_prev, derivative_zero;
    double last_torque;
    int32_t in_move;
    double start, t_end;
    double *increments; /* n_steps */
} hd_pd;

/* LinearPD.control: the same operations in the same order (Python evaluates a * b / c as (a * b) / c, and
 * max(-s, u) / min(s, u) keep their first argument unless the second is strictly beyond it). */
static double control(hd_pd *j, int32_t count) {
    int64_t prev = j->has_prev ? j->count_prev : count;
    j->count_prev = count;
    j->has_prev = 1;
    double y = (double)count * j->count_rad;
    double e = (double)j->setpoint * j->count_rad - y;
    int64_t dcount = (int64_t)count - prev;
    double u = j->Kp * e - j->Kd * ((double)dcount * j->count_rad) / j->dt_star;
    u = u > -j->saturation ? u : -j->saturation;
    u = u < j->saturation ? u : j->saturation;
    j->derivative_zero = dcount == 0;
    j->last_torque = u * j->f_m;
    return j->last_torque;
}

int hd_pd_run(hd_plant *p, hd_pd *j) {
    p->steps = 0;
    while (j->done < j->warmup + j->n_steps && !j->stopped) {
        if (!j->in_move) {
            j->start = p->arm;
            j->setpoint += j->counts;
            j->t_end = p->time + j->max_time;
            j->in_move = 1;
        }
        for (;;) {
            if (p->steps >= p->budget) return 1; /* before control(): it is called once per sample */
            double u = control(j, p->count);
            if (at_rest(p) && j->derivative_zero && u == p->torque) break;
            if (p->time > j->t_end) { p->failed = HD_FAIL_SETTLE; return -1; }
            if (step(p, u, j->dt)) return -1;
        }
        j->in_move = 0;
        double inc = p->arm - j->start;
        if (j->done++ >= j->warmup) {
            j->increments[j->done - 1 - j->warmup] = inc;
            if (j->stop_at_failure && !(inc > j->eps1)) j->stopped = 1;
        }
    }
    return 0;
}
