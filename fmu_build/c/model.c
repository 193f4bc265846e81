/* HarmonicDrive plant physics: closed-form segments and exactly located stick-slip events. See model.h.
 *
 * Two paths share the Karnopp stick/slip rules, the FMU state and the variable access:
 *
 * 1. Base model (every optional effect off): closed form.
 *
 * Segment solution. With each body's stick/slip state fixed and the torque held, the deflection obeys
 *     d'' = -w^2 d + c,   w^2 = K_s (a_m r^2/J_m + a_l/J_l),   c = a_m r F_m/J_m - a_l F_l/J_l
 * (a_* = 1 for a slipping body, F_m = T - f_m dir_m, F_l = -f_l dir_l), so d(t), its integrals and both bodies'
 * velocities and positions are sums of a constant, a linear term and one sinusoid of frequency w. A stuck body does
 * not move at all (its position is kept bit-for-bit).
 *
 * Events. Every event function G (a slipping body's -dir*v, a stuck body's +-N - f) has the shape
 * a + b t + R cos(w t - psi), so its local maxima are known in closed form and their heights grow linearly with
 * their index. The first time G reaches zero therefore lies on the rising flank before the first local maximum
 * that is >= 0, which is computed directly; on that monotone flank Newton's method on the closed form proposes the
 * root and a few trials of the committed state formulas bracket it to the last bit (see locate()). Events are
 * evaluated through the same state formulas that are committed, so the stick/slip decision taken after an event
 * always agrees with the event that triggered it (no Zeno loops from rounding).
 *
 * 2. General propagator (any optional effect on: viscous, also direction-dependent, Stribeck, asymmetric
 * friction, hardening spring, Dahl hysteresis, kinematic error). With d = r q_m + e(q_m) - q_l, the kinematic error
 * e = A sin(2 q_m + phi) + A4 sin(4 q_m + phi4), g = dd/dq_m = r + e'(q_m), tau_s = K_s (d + hardening d^3) + z
 * (d^3: d |d|^p d_h^(2 - p) at a hardening_exponent p other than 2):
 *     J_m v_m' = T - g tau_s - F_m          J_l v_l' = tau_s - F_l
 * A slipping body feels F = dir f (1 + a dir)(1 + s exp(-|v/vs|^delta)) + b (1 + a_v dir) v (delta = 2, the
 * default, a Gaussian decay; 1 an exponential one); a stuck body stays stuck
 * while its net torque N lies in [-f (1 - a)(1 + s), f (1 + a)(1 + s)]. The Dahl element
 * z' = sigma dd |1 - sgn(dd) z/H|^n sgn(1 - sgn(dd) z/H) (n = 1 by default) is solved exactly on each branch of
 * constant sgn(dd): z is a function of d (anchored where the branch began).
 * Each body's stick/slip mode and slip direction and the hysteresis branch are MODES held fixed inside a substep,
 * where the right-hand side is then smooth: Butcher's sixth-order Runge-Kutta method with fixed substeps (90 per
 * period of the stiffest oscillation, at most 0.25 of each viscous or Stribeck time constant; shortened further
 * while a fast transient is under way: a body in its Stribeck range, an unsaturated hysteresis branch), the two
 * works as quadratures.
 * An event inside a substep (a slipping body's velocity reaching 0 - with Coulomb friction or an asymmetric viscous
 * term -, a stuck body's N leaving its band, dd changing sign) is located to the last bit on the substep fraction
 * (regula falsi, then halving), each trial being one step of the method from the substep start; that very state is
 * committed and the modes are re-decided from it (no Zeno loops). A slipping body's velocity that passes through 0
 * and back inside one substep (a torque step that briefly outweighs the drive) is found from the cubic through its
 * values and accelerations at the substep's ends (fx_interior_stop), so that the result does not depend on the
 * communication step.
 *
 * Both paths count their work: every doStep does at most HD_WORK_BUDGET evaluations of the model's equations and
 * every event advances time, so each call returns within a bounded CPU time for any step size and any state, or is
 * refused with an error naming a step size that fits (see hd_do_step).
 */
#include "model.h"

#include <float.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#define HD_PI 3.14159265358979323846

/* ---------------------------------------------------------------- parameters and variable access --------- */

void hd_set_defaults(HDModel *m) {
    memset(m, 0, sizeof(*m));
#define X(vr, name, lo, hi, start, unit) m->name = start;
    HD_REAL_PARAMETERS(X)
    HD_REAL_INPUTS(X)
    HD_INTEGER_PARAMETERS(X)
#undef X
    m->motor_stuck = m->load_stuck = 1;
    m->motor_dir = m->load_dir = m->hyst_dir = 1; /* valid modes in every state, initialized or not */
}

HDCausality hd_causality(uint32_t vr, HDType type) {
    switch (type) {
    case HD_REAL:
        if (vr == HD_VR_time) return HD_INDEPENDENT;
#define X(v, name, lo, hi, start, unit) if (vr == v) return HD_PARAMETER;
        HD_REAL_PARAMETERS(X)
#undef X
#define X(v, name, lo, hi, start, unit) if (vr == v) return HD_INPUT;
        HD_REAL_INPUTS(X)
#undef X
#define X(v, name, unit) if (vr == v) return HD_OUTPUT;
        HD_REAL_OUTPUTS(X)
#undef X
#define X(v, name, unit) if (vr == v) return HD_LOCAL;
        HD_REAL_LOCALS(X)
#undef X
        break;
    case HD_INTEGER:
#define X(v, name, lo, hi, start, unit) if (vr == v) return HD_PARAMETER;
        HD_INTEGER_PARAMETERS(X)
#undef X
#define X(v, name, unit) if (vr == v) return HD_OUTPUT;
        HD_INTEGER_OUTPUTS(X)
#undef X
        break;
    case HD_BOOLEAN:
#define X(v, name, unit) if (vr == v) return HD_OUTPUT;
        HD_BOOLEAN_OUTPUTS(X)
#undef X
        break;
    }
    return HD_UNKNOWN;
}

static HDStatus unknown_vr(uint32_t vr, const char *type, char *err, size_t errlen) {
    snprintf(err, errlen, "unknown %s value reference %u", type, (unsigned)vr);
    return HD_ERROR;
}

HDStatus hd_get_real(const HDModel *m, uint32_t vr, double *value, char *err, size_t errlen) {
    if (vr == HD_VR_time) { *value = m->time; return HD_OK; }
#define X(v, name, lo, hi, start, unit) if (vr == v) { *value = m->name; return HD_OK; }
    HD_REAL_PARAMETERS(X)
    HD_REAL_INPUTS(X)
#undef X
#define X(v, name, unit) if (vr == v) { *value = m->name; return HD_OK; }
    HD_REAL_OUTPUTS(X)
    HD_REAL_LOCALS(X)
#undef X
    return unknown_vr(vr, "Real", err, errlen);
}

HDStatus hd_get_integer(const HDModel *m, uint32_t vr, int32_t *value, char *err, size_t errlen) {
#define X(v, name, lo, hi, start, unit) if (vr == v) { *value = m->name; return HD_OK; }
    HD_INTEGER_PARAMETERS(X)
#undef X
#define X(v, name, unit) if (vr == v) { *value = m->name; return HD_OK; }
    HD_INTEGER_OUTPUTS(X)
#undef X
    return unknown_vr(vr, "Integer", err, errlen);
}

HDStatus hd_get_boolean(const HDModel *m, uint32_t vr, int *value, char *err, size_t errlen) {
#define X(v, name, unit) if (vr == v) { *value = m->name != 0; return HD_OK; }
    HD_BOOLEAN_OUTPUTS(X)
#undef X
    return unknown_vr(vr, "Boolean", err, errlen);
}

/* NaN fails both comparisons, so it is rejected with the same message as an out-of-range value. */
static HDStatus check_range(const char *name, double value, double lo, double hi, const char *unit, char *err,
                            size_t errlen) {
    if (value >= lo && value <= hi) return HD_OK;
    snprintf(err, errlen, "%s = %g%s is outside the allowed range [%g, %g]%s", name, value, unit, lo, hi,
             isnan(value) ? " (NaN)" : "");
    return HD_RANGE;
}

HDStatus hd_set_real(HDModel *m, uint32_t vr, double value, char *err, size_t errlen) {
#define X(v, name, lo, hi, start, unit) \
    if (vr == v) { \
        if (check_range(#name, value, lo, hi, unit, err, errlen) != HD_OK) return HD_RANGE; \
        m->name = value; \
        return HD_OK; \
    }
    HD_REAL_PARAMETERS(X)
    HD_REAL_INPUTS(X)
#undef X
    if (hd_causality(vr, HD_REAL) != HD_UNKNOWN) {
        snprintf(err, errlen, "Real value reference %u is not a parameter or input and cannot be set", (unsigned)vr);
        return HD_ERROR;
    }
    return unknown_vr(vr, "Real", err, errlen);
}

HDStatus hd_set_integer(HDModel *m, uint32_t vr, int32_t value, char *err, size_t errlen) {
#define X(v, name, lo, hi, start, unit) \
    if (vr == v) { \
        if (check_range(#name, (double)value, lo, hi, unit, err, errlen) != HD_OK) return HD_RANGE; \
        m->name = value; \
        return HD_OK; \
    }
    HD_INTEGER_PARAMETERS(X)
#undef X
    if (hd_causality(vr, HD_INTEGER) != HD_UNKNOWN) {
        snprintf(err, errlen, "Integer value reference %u is an output and cannot be set", (unsigned)vr);
        return HD_ERROR;
    }
    return unknown_vr(vr, "Integer", err, errlen);
}

static HDStatus check_all(const HDModel *m, char *err, size_t errlen) {
#define X(v, name, lo, hi, start, unit) \
    if (check_range(#name, (double)m->name, lo, hi, unit, err, errlen) != HD_OK) return HD_ERROR;
    HD_REAL_PARAMETERS(X)
    HD_REAL_INPUTS(X)
    HD_INTEGER_PARAMETERS(X)
#undef X
    return HD_OK;
}

/* ---------------------------------------------------------------- FMU state snapshots -------------------- */

#define HD_SNAPSHOT_MAGIC 0x48444d53u /* "HDMS" */
#define HD_SNAPSHOT_FORMAT 3u         /* field-by-field layout (1 was the raw struct; 3 adds model_evaluations) */
#define HD_SNAPSHOT_HEADER (4 * sizeof(uint32_t))

static uint32_t token_hash(void) { /* FNV-1a of the instantiation token: tells builds apart */
    uint32_t h = 2166136261u;
    for (const char *p = HD_INSTANTIATION_TOKEN; *p; ++p) h = (h ^ (uint8_t)*p) * 16777619u;
    return h;
}

/* Writes (write = 1) or reads the snapshot's fields at p, or only counts their bytes (p = NULL); returns the byte
 * count. The fields come from the variable table (parameters, input, outputs) plus the internal state, so that a
 * variable added to the table is serialized without touching this function. */
static size_t snapshot_fields(HDSnapshot *s, unsigned char *p, int write) {
    HDSnapshot unused; /* counting only: the fields' sizes are taken from a real object (no NULL member access) */
    if (!s) s = &unused;
    size_t n = 0;
#define FIELD(ref) \
    do { \
        if (p) { \
            if (write) memcpy(p + n, &(ref), sizeof(ref)); else memcpy(&(ref), p + n, sizeof(ref)); \
        } \
        n += sizeof(ref); \
    } while (0)
    HDModel *m = &s->model;
#define X(vr, name, lo, hi, start, unit) FIELD(m->name);
    HD_REAL_PARAMETERS(X)
    HD_REAL_INPUTS(X)
    HD_INTEGER_PARAMETERS(X)
#undef X
#define X(vr, name, unit) FIELD(m->name);
    HD_REAL_OUTPUTS(X)
    HD_INTEGER_OUTPUTS(X)
    HD_BOOLEAN_OUTPUTS(X)
#undef X
    FIELD(m->time);
    FIELD(m->motor_dir);
    FIELD(m->load_dir);
    FIELD(m->hyst_dir);
    FIELD(m->hyst_d0);
    FIELD(m->hyst_z0);
    FIELD(m->event_count);
    FIELD(m->model_evaluations);
    FIELD(s->phase);
    FIELD(s->start_time);
#undef FIELD
    return n;
}

size_t hd_snapshot_bytes(void) { return HD_SNAPSHOT_HEADER + snapshot_fields(NULL, NULL, 0); }

void hd_snapshot_write(const HDSnapshot *s, unsigned char *bytes) {
    uint32_t head[4] = {HD_SNAPSHOT_MAGIC, HD_SNAPSHOT_FORMAT, (uint32_t)snapshot_fields(NULL, NULL, 0), token_hash()};
    memcpy(bytes, head, sizeof head);
    snapshot_fields((HDSnapshot *)s, bytes + HD_SNAPSHOT_HEADER, 1); /* write: s is only read */
}

static int is_sign(int32_t x) { return x == 1 || x == -1; }
static int is_flag(int32_t x) { return x == 0 || x == 1; }

/* The checks of a state that comes from outside (deserialized bytes, an FMU state handle): what the API itself
 * guarantees for every state it creates. A state that passes cannot hang or break a doStep (the work budget bounds
 * every step) and gives finite outputs. */
HDStatus hd_snapshot_check(const HDSnapshot *s, char *err, size_t errlen) {
    const HDModel *m = &s->model;
    if (s->phase < 0 || s->phase >= HD_PHASE_COUNT) {
        snprintf(err, errlen, "FMU state: phase %d is not a valid phase (0..%d)", (int)s->phase, HD_PHASE_COUNT - 1);
        return HD_ERROR;
    }
    char what[200];
    if (check_all(m, what, sizeof what) != HD_OK) {
        snprintf(err, errlen, "FMU state: %s", what);
        return HD_ERROR;
    }
#define FINITE(x) \
    if (!isfinite(x)) { snprintf(err, errlen, "FMU state: %s = %g is not finite", #x, (double)(x)); return HD_ERROR; }
    FINITE(s->start_time)
    FINITE(m->time)
    FINITE(m->hyst_d0)
    FINITE(m->hyst_z0)
#define X(vr, name, unit) FINITE(m->name)
    HD_REAL_OUTPUTS(X)
#undef X
#undef FINITE
    if (!is_flag(m->motor_stuck) || !is_flag(m->load_stuck) || !is_sign(m->motor_dir) || !is_sign(m->load_dir)
        || !is_sign(m->hyst_dir)) {
        snprintf(err, errlen, "FMU state: invalid stick/slip modes (motor_stuck %d, load_stuck %d, motor_dir %d, "
                              "load_dir %d, hysteresis branch %d)", (int)m->motor_stuck, (int)m->load_stuck,
                 (int)m->motor_dir, (int)m->load_dir, (int)m->hyst_dir);
        return HD_ERROR;
    }
    if ((m->motor_stuck && m->v_m != 0.0) || (m->load_stuck && m->v_l != 0.0)) {
        snprintf(err, errlen, "FMU state: a stuck body moves (v_m = %g rad/s, v_l = %g rad/s)", m->v_m, m->v_l);
        return HD_ERROR;
    }
    if (!(fabs(m->hyst_z0) <= 2.0 * m->hysteresis_torque) || m->event_count < 0
        || !(m->model_evaluations >= 0.0 && m->model_evaluations <= 9007199254740992.0)) {
        snprintf(err, errlen, "FMU state: hysteresis anchor z0 = %g N.m beyond 2 hysteresis_torque = %g N.m, "
                              "event count %lld < 0, or model_evaluations %g outside [0, 2^53]", m->hyst_z0,
                 2.0 * m->hysteresis_torque, (long long)m->event_count, m->model_evaluations);
        return HD_ERROR;
    }
    return HD_OK;
}

HDStatus hd_snapshot_read(const unsigned char *bytes, size_t size, HDSnapshot *s, char *err, size_t errlen) {
    uint32_t head[4];
    if (!bytes || size != hd_snapshot_bytes()) {
        snprintf(err, errlen, "serialized state has the wrong size for this FMU (%zu bytes, expected %zu)", size,
                 hd_snapshot_bytes());
        return HD_ERROR;
    }
    memcpy(head, bytes, sizeof head);
    if (head[0] != HD_SNAPSHOT_MAGIC || head[1] != HD_SNAPSHOT_FORMAT
        || head[2] != (uint32_t)snapshot_fields(NULL, NULL, 0) || head[3] != token_hash()) {
        snprintf(err, errlen, "serialized state does not come from this FMU");
        return HD_ERROR;
    }
    HDSnapshot tmp;
    memset(&tmp, 0, sizeof tmp);
    snapshot_fields(&tmp, (unsigned char *)bytes + HD_SNAPSHOT_HEADER, 0); /* read: bytes are only read */
    if (hd_snapshot_check(&tmp, err, errlen) != HD_OK) return HD_ERROR;
    *s = tmp;
    return HD_OK;
}

/* ---------------------------------------------------------------- stick/slip decisions ------------------- */

static double base_deflection(const HDModel *m) { return m->r * m->q_m - m->q_l; }

/* Net non-friction torque on each body: depends on positions and input only, so the two decisions are independent. */
static double net_motor(const HDModel *m) { return m->motor_torque - m->r * m->K_s * base_deflection(m); }
static double net_load(const HDModel *m) { return m->K_s * base_deflection(m); }

/* Karnopp rule for one body at zero velocity: stick while |N| <= f, else break away in the direction of N. */
static void decide_at_zero_velocity(double net, double level, int32_t *stuck, int32_t *dir) {
    if (fabs(net) <= level) {
        *stuck = 1;
    } else {
        *stuck = 0;
        *dir = net > 0 ? 1 : -1;
    }
}

/* Re-decides every body whose velocity is exactly zero; a body sliding with v != 0 keeps sliding. */
static void settle_modes(HDModel *m) {
    if (m->motor_stuck || m->v_m == 0.0) {
        m->v_m = 0.0;
        decide_at_zero_velocity(net_motor(m), m->f_m, &m->motor_stuck, &m->motor_dir);
    }
    if (m->load_stuck || m->v_l == 0.0) {
        m->v_l = 0.0;
        decide_at_zero_velocity(net_load(m), m->f_l, &m->load_stuck, &m->load_dir);
    }
}

/* ---------------------------------------------------------------- optional effects: forces and modes ---- */

/* Any effect on selects the general propagator; all off keeps the closed-form path, bit for bit. */
static int effects_on(const HDModel *m) {
    return m->b_m != 0.0 || m->b_l != 0.0 || m->stribeck_ratio != 0.0 || m->friction_asymmetry != 0.0
        || m->hardening != 0.0 || m->hysteresis_torque != 0.0 || m->kinematic_error != 0.0
        || m->kinematic_error_4 != 0.0 || m->viscous_asymmetry != 0.0;
}

/* The state the general propagator integrates: positions, velocities and the two work quadratures. */
typedef struct {
    double q_m, q_l, v_m, v_l, w_in, w_fr;
} FxState;

/* Spring at given positions: twist d (with kinematic error), g = dd/dq_m, hysteresis torque z, total tau_s. */
typedef struct {
    double d, g, z, tau;
} FxSpring;

/* Net torques (N), friction torques (F: the holding reaction N while stuck) and accelerations of both bodies. */
typedef struct {
    FxSpring s;
    double N_m, N_l, F_m, F_l, a_m, a_l;
} FxForces;

/* x^y for the shape exponents, with y = 1 (the exponential Stribeck decay, the Dahl element of exponent 2) taken as x
 * itself: exactly what pow returns there, without its cost (measured: pow was 30 % of an exponential-decay
 * simulation). */
static double shape_pow(double x, double y) {
    return y == 1.0 ? x : pow(x, y);
}

/* The hardening's shape: d^3 at the default exponent 2 (computed so, as before the exponent existed: every cubic
 * trajectory stays the same to the last bit), else d |d|^p d_h^(2 - p), which equals the cubic at |d| = d_h. */
static double hardening_excess(const HDModel *m, double d) {
    if (m->hardening_exponent == 2.0) return d * d * d;
    double p = m->hardening_exponent;
    return d * shape_pow(fabs(d), p) * shape_pow(m->hardening_deflection, 2.0 - p);
}

/* The hardening's share of the tangent stiffness over K_s, hardening x d(hardening_excess)/dd: 3 hardening d^2 (in
 * the order it was computed before the exponent existed), else hardening (p + 1) |d|^p d_h^(2 - p). */
static double hardening_slope(const HDModel *m, double d) {
    if (m->hardening_exponent == 2.0) return 3.0 * m->hardening * d * d;
    double p = m->hardening_exponent;
    return m->hardening * (p + 1.0) * shape_pow(fabs(d), p) * shape_pow(m->hardening_deflection, 2.0 - p);
}

/* z on the current Dahl branch: the exact solution of z' = sigma dd u^n, u = 1 - dir z/H, with dir held, as a
 * function of the twist, exactly z0 at the anchor d0. With x = sigma dir (d - d0)/H (>= 0 along the branch) and
 * u0 = 1 - dir z0/H, du/dx = -u^n gives
 *   n = 1 (the default):  z = z0 + (z0 - dir H) expm1(-x);
 *   n > 1:                u = u0 (1 + (n - 1) u0^(n-1) x)^(-1/(n-1)),
 *                         z = z0 - dir H u0 expm1(-log1p((n - 1) u0^(n-1) x) / (n - 1))
 * (an algebraic approach to dir H; the n -> 1 limit is the exponential). For n = 2 (the diagnosis's other shape)
 * that is z = z0 + dir H u0 a / (1 + a), a = u0 x, the same solution without the expm1 and log1p (measured: they were
 * 44 % of an exponent-2 simulation's time). */
static double hysteresis_z(const HDModel *m, double d) {
    double H = m->hysteresis_torque;
    if (!(H > 0.0)) return 0.0;
    double dir = m->hyst_dir, x = -m->hysteresis_stiffness * dir * (d - m->hyst_d0) / H;
    if (m->hysteresis_exponent == 1.0) {
        if (x > 50.0) x = 50.0; /* only reachable transiently against the branch, before its event: no overflow */
        return m->hyst_z0 + (m->hyst_z0 - dir * H) * expm1(x);
    }
    double n1 = m->hysteresis_exponent - 1.0, u0 = 1.0 - dir * m->hyst_z0 / H;
    double a = fmax(-n1 * shape_pow(fmax(u0, 0.0), n1) * x, -1.0);
    if (n1 == 1.0) /* 1 + a >= exp(-50): the same bound on the growth against the branch as e's below */
        return m->hyst_z0 + dir * H * u0 * a / fmax(1.0 + a, exp(-50.0));
    /* e > 50 only transiently against the branch, before its event: no overflow */
    double e = fmin(-log1p(a) / n1, 50.0);
    return m->hyst_z0 - dir * H * u0 * expm1(e);
}

/* The Dahl element's tangent stiffness sigma u^n over sigma where u = 1 - dir z/H reaches 2 (a reversal from the other
 * saturation), relative to the classic element's: 2^(n-1), exactly 1 for n = 1. */
static double hysteresis_slope(const HDModel *m) {
    return m->hysteresis_exponent == 1.0 ? 1.0 : pow(2.0, m->hysteresis_exponent - 1.0);
}

/* How much faster than the classic Dahl element's (n = 1) an element of exponent n changes near u = left / H:
 * its relaxation rate sigma |dd| u^(n-1) / H, times (prod_{j<7} (1 + j (n-1)))^(1/7), the growth of its seventh
 * derivative in x over the exponential's (a step's error grows with it: u^(7) = -(prod) u^(7(n-1)+1) along a
 * branch). Exactly 1 for n = 1. */
static double hysteresis_rate_factor(double n, double u) {
    if (n == 1.0) return 1.0;
    double prod = 1.0;
    for (int j = 0; j < 7; j++) prod *= 1.0 + j * (n - 1.0);
    return shape_pow(u, n - 1.0) * pow(prod, 1.0 / 7.0);
}

static FxSpring fx_spring(const HDModel *m, double q_m, double q_l) {
    FxSpring s;
    s.d = m->r * q_m - q_l;
    s.g = m->r;
    if (m->kinematic_error != 0.0 || m->kinematic_error_4 != 0.0) {
        /* a harmonic of zero amplitude adds zero: its sine and cosine are not evaluated (the kinematic-error
         * candidate's fits have only the 2/rev one; a sincos is about a quarter of such a model's evaluation) */
        double e2 = 0.0, g2 = 0.0, e4 = 0.0, g4 = 0.0;
        if (m->kinematic_error != 0.0) {
            double ph = 2.0 * q_m + m->kinematic_error_phase;
            e2 = m->kinematic_error * sin(ph), g2 = 2.0 * m->kinematic_error * cos(ph);
        }
        if (m->kinematic_error_4 != 0.0) {
            double ph4 = 4.0 * q_m + m->kinematic_error_4_phase;
            e4 = m->kinematic_error_4 * sin(ph4), g4 = 4.0 * m->kinematic_error_4 * cos(ph4);
        }
        s.d = m->r * q_m + e2 + e4 - q_l;
        s.g = m->r + g2 + g4;
    }
    s.z = hysteresis_z(m, s.d);
    s.tau = m->K_s * (s.d + m->hardening * hardening_excess(m, s.d)) + s.z;
    return s;
}

/* Static level for motion in direction dir: f (1 + a dir)(1 + s). */
static double static_level(const HDModel *m, double f, int32_t dir) {
    return f * (1.0 + m->friction_asymmetry * dir) * (1.0 + m->stribeck_ratio);
}

/* The Stribeck decay exp(-|x|^delta), x = v / vs. The default delta = 2 is computed as exp(-x x), as it was before
 * the exponent existed, so that every trajectory of a Gaussian decay stays the same to the last bit. */
static double stribeck_decay(const HDModel *m, double x) {
    return exp(m->stribeck_shape == 2.0 ? -x * x : -shape_pow(fabs(x), m->stribeck_shape));
}

/* The decay's steepest slope max |d/dx exp(-x^delta)| = delta u^((delta-1)/delta) exp(-u), u = (delta-1)/delta, at
 * x = u^(1/delta) (sqrt(2/e) for the Gaussian, 1 at x = 0 for the exponential), and the speed (in vs) beyond which
 * the decay is below exp(-36), where it no longer changes the friction as doubles see it: 36^(1/delta) (6 for the
 * Gaussian, as before the exponent existed; 36 for the exponential). */
static double stribeck_slope_max(double delta) {
    if (delta == 2.0) return sqrt(2.0 / exp(1.0));
    double u = (delta - 1.0) / delta;
    return delta * pow(u, u) * exp(-u);
}

static double stribeck_range(double delta) {
    return delta == 2.0 ? 6.0 : pow(36.0, 1.0 / delta);
}

/* Friction of a slipping body; the viscous coefficient is b (1 + a_v dir). At v = 0 it is dir * static_level bit for
 * bit (exp(0) = 1, b 0 = 0), so a body that just broke away (|N| beyond its level as doubles) accelerates in its slip
 * direction exactly. */
static double slip_friction(const HDModel *m, double f, double b, double vs, int32_t dir, double v) {
    double s = m->stribeck_ratio != 0.0 ? m->stribeck_ratio * stribeck_decay(m, v / vs) : 0.0; /* no exp() unused */
    return dir * (f * (1.0 + m->friction_asymmetry * dir) * (1.0 + s)) + b * (1.0 + m->viscous_asymmetry * dir) * v;
}

/* Is a slipping body's velocity zero an event (Karnopp re-decision: stick, or a new slip direction)? Yes when its
 * friction depends on the slip direction: Coulomb friction f > 0, or an asymmetric viscous term b (1 + a_v dir) (so
 * that dir is the sign of v even for a body without Coulomb friction). Otherwise the body never sticks. */
static int velocity_switches(const HDModel *m, double f, double b) {
    return f > 0.0 || (b != 0.0 && m->viscous_asymmetry != 0.0);
}

static FxState fx_state(const HDModel *m) {
    FxState y = {m->q_m, m->q_l, m->v_m, m->v_l, m->input_work, m->friction_work};
    return y;
}

static FxForces fx_forces(const HDModel *m, const FxState *y) {
    FxForces f;
    f.s = fx_spring(m, y->q_m, y->q_l);
    f.N_m = m->motor_torque - f.s.g * f.s.tau;
    f.N_l = f.s.tau;
    f.F_m = f.N_m, f.a_m = 0.0;
    f.F_l = f.N_l, f.a_l = 0.0;
    if (!m->motor_stuck) {
        f.F_m = slip_friction(m, m->f_m, m->b_m, m->stribeck_velocity / m->r, m->motor_dir, y->v_m);
        f.a_m = (f.N_m - f.F_m) / m->J_m;
    }
    if (!m->load_stuck) {
        f.F_l = slip_friction(m, m->f_l, m->b_l, m->stribeck_velocity, m->load_dir, y->v_l);
        f.a_l = (f.N_l - f.F_l) / m->J_l;
    }
    return f;
}

/* Karnopp rule with the asymmetric static band: stick while -L(-1) <= N <= L(+1), else break away towards N. */
static void fx_decide(const HDModel *m, double net, double f, int32_t *stuck, int32_t *dir) {
    if (net > static_level(m, f, 1)) {
        *stuck = 0, *dir = 1;
    } else if (-net > static_level(m, f, -1)) {
        *stuck = 0, *dir = -1;
    } else {
        *stuck = 1;
    }
}

/* Starts a new hysteresis branch at the current twist and z (z is continuous across the switch). */
static void fx_flip_hysteresis(HDModel *m, const FxSpring *s) {
    m->hyst_z0 = s->z;
    m->hyst_d0 = s->d;
    m->hyst_dir = -m->hyst_dir;
}

/* Re-decides every body at zero velocity (stuck, exactly 0, or - with friction - at or past zero against its slip
 * direction), then the hysteresis branch from the sign of the twist rate dd (of its rate when dd = 0). */
static void fx_settle(HDModel *m) {
    FxState y = fx_state(m);
    FxSpring s = fx_spring(m, y.q_m, y.q_l);
    if (m->motor_stuck || m->v_m == 0.0 || (velocity_switches(m, m->f_m, m->b_m) && -m->motor_dir * m->v_m >= 0.0)) {
        m->v_m = 0.0;
        fx_decide(m, m->motor_torque - s.g * s.tau, m->f_m, &m->motor_stuck, &m->motor_dir);
    }
    if (m->load_stuck || m->v_l == 0.0 || (velocity_switches(m, m->f_l, m->b_l) && -m->load_dir * m->v_l >= 0.0)) {
        m->v_l = 0.0;
        fx_decide(m, s.tau, m->f_l, &m->load_stuck, &m->load_dir);
    }
    if (m->hysteresis_torque > 0.0) {
        double dd = s.g * m->v_m - m->v_l;
        if (dd == 0.0) {
            y = fx_state(m);
            FxForces f = fx_forces(m, &y);
            dd = s.g * f.a_m - f.a_l; /* the sign dd takes next (the velocity terms are zero) */
        }
        if (m->hyst_dir * dd < 0.0) fx_flip_hysteresis(m, &s);
        m->hysteresis_state = s.z;
    }
}

static int outputs_finite(const HDModel *m);

static void update_outputs(HDModel *m) {
    if (effects_on(m)) {
        FxState y = fx_state(m);
        FxForces f = fx_forces(m, &y);
        m->spring_torque = f.s.tau;
        m->deflection = f.s.d;
        m->hysteresis_state = f.s.z;
        m->motor_friction_torque = f.F_m;
        m->load_friction_torque = f.F_l;
    } else {
        m->spring_torque = m->K_s * base_deflection(m);
        m->deflection = base_deflection(m);
        m->hysteresis_state = 0.0;
        m->motor_friction_torque = m->motor_stuck ? net_motor(m) : m->f_m * m->motor_dir;
        m->load_friction_torque = m->load_stuck ? net_load(m) : m->f_l * m->load_dir;
    }
    m->arm_position = m->arm_length * m->q_l;
    double count = floor(m->q_m * (double)m->encoder_counts_per_rev / (2.0 * HD_PI));
    if (count > 2147483647.0) count = 2147483647.0; /* int32 output: saturate rather than overflow */
    if (count < -2147483648.0) count = -2147483648.0;
    m->encoder_count = (int32_t)count;
}

HDStatus hd_initialize(HDModel *m, double t0, char *err, size_t errlen) {
    if (check_all(m, err, errlen) != HD_OK) return HD_ERROR;
    m->time = t0;
    m->q_m = m->q_m_start;
    m->q_l = m->q_l_start;
    m->v_m = m->v_m_start;
    m->v_l = m->v_l_start;
    m->motor_stuck = m->load_stuck = 0;
    m->motor_dir = m->v_m < 0 ? -1 : 1;
    m->load_dir = m->v_l < 0 ? -1 : 1;
    m->input_work = m->friction_work = 0.0;
    m->event_count = 0;
    m->model_evaluations = 0.0;
    m->hysteresis_state = m->hyst_z0 = 0.0; /* the hysteresis element starts relaxed, on a rising branch */
    m->hyst_dir = 1;
    m->hyst_d0 = fx_spring(m, m->q_m, m->q_l).d;
    if (effects_on(m)) fx_settle(m); else settle_modes(m);
    update_outputs(m);
    if (!outputs_finite(m)) { /* not reachable with parameters in their ranges; checked all the same */
        snprintf(err, errlen, "the initial state gives a non-finite output");
        return HD_ERROR;
    }
    return HD_OK;
}

/* ---------------------------------------------------------------- closed-form segment -------------------- */

/* (1-cos x)/x^2, (x-sin x)/x^3, (x^2/2-1+cos x)/x^4 at once: Taylor series near 0, where the direct forms cancel,
 * and elsewhere one sine and cosine of x/2 shared by all three (sin x = 2 sin(x/2) cos(x/2), 1 - cos x = 2 sin^2(x/2)):
 * the segment is evaluated at every trial of an event search, so its trigonometry is most of the model's cost. */
static void kernels(double x, double *c1, double *s1, double *c2) {
    double x2 = x * x;
    if (fabs(x) < 0.5) { /* series up to x^10 or x^12: the first neglected terms are below 2e-16 relative */
        *s1 = 1.0 / 6 - x2 * (1.0 / 120 - x2 * (1.0 / 5040 - x2 * (1.0 / 362880 - x2 * (1.0 / 39916800
                                                                                 - x2 / 6227020800.0))));
        *c2 = 1.0 / 24 - x2 * (1.0 / 720 - x2 * (1.0 / 40320 - x2 * (1.0 / 3628800 - x2 * (1.0 / 479001600
                                                                                 - x2 / 87178291200.0))));
        *c1 = 0.5 - x2 * (1.0 / 24 - x2 * (1.0 / 720 - x2 * (1.0 / 40320 - x2 * (1.0 / 3628800
                                                            - x2 * (1.0 / 479001600 - x2 / 87178291200.0)))));
        return;
    }
    double sh = sin(0.5 * x), ch = cos(0.5 * x);
    *c1 = 2.0 * sh * sh / x2;
    *s1 = (x - 2.0 * sh * ch) / (x2 * x);
    *c2 = (0.5 * x2 - 2.0 * sh * sh) / (x2 * x2);
}

/* Work done in one doStep, counted in evaluations of the model's equations (see "work budget" in hd_do_step). */
typedef struct {
    int64_t used, limit;
} Work;

static int work_exhausted(const Work *w) { return w->used > w->limit; }

typedef struct {
    Work *work;       /* counts every state evaluation of the segment */
    double t_clock;   /* time into the communication step at the segment start */
    int motor_slips, load_slips;
    double F_m, F_l;  /* constant forcing on each slipping body (torque minus Coulomb friction) */
    double w, c;      /* deflection frequency and forcing, see the file comment */
    double d0, dd0;   /* deflection and its rate at the segment start */
    double a_m0, a_l0; /* accelerations at the start, from the same net torques as the stick/slip decision */
    double e;         /* d''(0) = r a_m0 - a_l0: drives the deflection's departure from d0 */
} Segment;

typedef struct {
    double q_m, q_l, v_m, v_l, dq_m, dq_l;
} Motion;

static Segment make_segment(const HDModel *m, Work *work, double t_clock) {
    Segment s;
    s.work = work;
    s.t_clock = t_clock;
    s.motor_slips = !m->motor_stuck;
    s.load_slips = !m->load_stuck;
    s.F_m = m->motor_torque - m->f_m * m->motor_dir;
    s.F_l = -m->f_l * m->load_dir;
    double w2 = m->K_s * ((s.motor_slips ? m->r * m->r / m->J_m : 0.0) + (s.load_slips ? 1.0 / m->J_l : 0.0));
    s.w = sqrt(w2);
    s.c = (s.motor_slips ? m->r * s.F_m / m->J_m : 0.0) - (s.load_slips ? s.F_l / m->J_l : 0.0);
    s.d0 = base_deflection(m);
    s.dd0 = (s.motor_slips ? m->r * m->v_m : 0.0) - (s.load_slips ? m->v_l : 0.0);
    /* Net torque minus friction, as in the decision: a body that just broke away (|N| > f as doubles) gets an
     * acceleration of the right sign exactly, so it cannot "return to zero velocity" through rounding. */
    s.a_m0 = s.motor_slips ? (net_motor(m) - m->f_m * m->motor_dir) / m->J_m : 0.0;
    s.a_l0 = s.load_slips ? (net_load(m) - m->f_l * m->load_dir) / m->J_l : 0.0;
    s.e = m->r * s.a_m0 - s.a_l0;
    return s;
}

/* State of the segment at local time t (t = 0 reproduces the start state exactly). Written as the start
 * acceleration plus the integrals of the deflection's departure d(t) - d0 = dd0 t sinc(w t) + e t^2 c1(w t). */
static Motion segment_at(const HDModel *m, const Segment *s, double t) {
    s->work->used++;
    double x = s->w * t, t2 = t * t, k1, k2, k3;
    kernels(x, &k1, &k2, &k3);
    double c1 = t2 * k1, s1 = t2 * t * k2, c2 = t2 * t2 * k3;
    double J1 = s->e * s1 + s->dd0 * c1; /* integral of d - d0 over [0, t] */
    double J2 = s->e * c2 + s->dd0 * s1; /* double integral of d - d0 */
    Motion mo = {m->q_m, m->q_l, 0.0, 0.0, 0.0, 0.0};
    if (s->motor_slips) {
        double k = m->r * m->K_s / m->J_m;
        mo.v_m = m->v_m + s->a_m0 * t - k * J1;
        mo.dq_m = m->v_m * t + 0.5 * s->a_m0 * t2 - k * J2;
        mo.q_m = m->q_m + mo.dq_m;
    }
    if (s->load_slips) {
        double k = m->K_s / m->J_l;
        mo.v_l = m->v_l + s->a_l0 * t + k * J1;
        mo.dq_l = m->v_l * t + 0.5 * s->a_l0 * t2 + k * J2;
        mo.q_l = m->q_l + mo.dq_l;
    }
    return mo;
}

/* ---------------------------------------------------------------- events --------------------------------- */

typedef enum { EV_MOTOR_VELOCITY, EV_LOAD_VELOCITY, EV_MOTOR_BREAK, EV_LOAD_BREAK } EventKind;

typedef struct {
    EventKind kind;
    double sign;   /* velocity events: -dir; break events: +1 / -1 for the two edges of the static band */
    double level;  /* static level subtracted from a break event's signed net torque */
    int strict;    /* break events need |N| > level strictly; velocity events fire at v == 0 */
    double a, b, C, S; /* G(t) = a + b t + C cos(w t) + S sin(w t), for the geometry of the search only */
} EventFn;

/* G(t), evaluated through exactly the state that would be committed at t. */
static double event_value(const HDModel *m, const Segment *s, const EventFn *e, double t) {
    Motion mo = segment_at(m, s, t);
    switch (e->kind) {
    case EV_MOTOR_VELOCITY: return e->sign * mo.v_m;
    case EV_LOAD_VELOCITY: return e->sign * mo.v_l;
    case EV_MOTOR_BREAK: return e->sign * (m->motor_torque - m->r * m->K_s * (m->r * mo.q_m - mo.q_l)) - e->level;
    case EV_LOAD_BREAK: return e->sign * (m->K_s * (m->r * mo.q_m - mo.q_l)) - e->level;
    }
    return -1.0;
}

/* An event fires only at a time that advances the step's clock: a root closer to the segment start than the clock
 * can resolve (a body that just broke away, whose velocity stays exactly 0 over a subnormal interval) is no event,
 * so every event moves time forward and no sequence of events can stand still (see "work budget"). */
static int fires(const HDModel *m, const Segment *s, const EventFn *e, double t) {
    if (s->t_clock + t == s->t_clock) return 0;
    double g = event_value(m, s, e, t);
    return e->strict ? g > 0.0 : g >= 0.0;
}

/* Smallest t in (lo, hi] where the event fires, given it does not fire at lo (lo = 0 is taken as not firing)
 * and fires at hi, on a flank where G is monotone. Returns the firing end of the final bracket. */
static double bisect(const HDModel *m, const Segment *s, const EventFn *e, double lo, double hi) {
    for (int i = 0; i < 200; ++i) {
        double mid = lo + 0.5 * (hi - lo);
        if (mid <= lo || mid >= hi) break;
        if (fires(m, s, e, mid)) hi = mid; else lo = mid;
    }
    return hi;
}

/* The geometry's amplitude R and phase psi: G = a + b t + R cos(w t - psi). */
typedef struct {
    double R, psi;
} Flank;

/* G(t) of the search geometry, and its slope: a + b t + C cos(w t) + S sin(w t), from the coefficients alone. */
static double geometry_value(const EventFn *e, double w, double t, double *slope) {
    double sn = sin(w * t), cs = cos(w * t);
    *slope = e->b + w * (e->S * cs - e->C * sn);
    return e->a + e->b * t + e->C * cs + e->S * sn;
}

/* Where the geometry's G crosses zero in (lo, hi): Newton's method kept inside a shrinking bracket (a halving
 * whenever a Newton step would leave it), at most 60 iterations of arithmetic only - no state is evaluated. It starts
 * from the root of a + b t_mid + R cos(w t - psi) on the rising branch (exact when b = 0, as for a break event), so
 * a few iterations suffice. */
static double geometry_root(const EventFn *e, double w, double R, double psi, double lo, double hi) {
    double t = lo + 0.5 * (hi - lo);
    if (R > 0.0 && w > 0.0) {
        double c = -(e->a + e->b * t) / R, phi = -acos(c < -1.0 ? -1.0 : c > 1.0 ? 1.0 : c);
        double guess = (phi + psi + 2.0 * HD_PI * round((w * t - psi - phi) / (2.0 * HD_PI))) / w;
        if (guess > lo && guess < hi) t = guess;
    }
    for (int i = 0; i < 60; ++i) {
        double slope, g = geometry_value(e, w, t, &slope);
        if (g == 0.0) return t;
        double step = g / slope;
        if (fabs(step) <= 4.0 * DBL_EPSILON * t) return t; /* as close as doubles resolve */
        if (g > 0.0) hi = t; else lo = t;
        t -= step;
        if (!(t > lo && t < hi)) t = lo + 0.5 * (hi - lo);
        if (!(t > lo && t < hi)) return t; /* the bracket has shrunk to adjacent doubles */
    }
    return t;
}

/* The event's time on a rising flank (lo, hi], exactly as bisect() defines it (a time where the event fires whose
 * predecessor in the final bracket does not), found with a handful of state evaluations instead of ~60: the
 * geometry's root is bracketed by trials at +-16 ulps, widened 256-fold while a trial lands on the wrong side
 * (every trial still narrows the bracket), and the last few bits are bisected. The geometry only proposes where to
 * look: every decision is taken by fires() on the committed state formulas, so a geometry spoilt by cancellation
 * costs evaluations, never correctness. */
static double locate(const HDModel *m, const Segment *s, const EventFn *e, const Flank *f, double lo, double hi) {
    double t = geometry_root(e, s->w, f->R, f->psi, lo, hi);
    if (!(t > lo && t < hi)) return bisect(m, s, e, lo, hi);
    double d = 16.0 * DBL_EPSILON * t;
    for (int k = 0; k < 8 && hi - lo > 2.0 * d; ++k, d *= 256.0) {
        double below = t - d, above = t + d;
        if (below > lo && below < hi) { if (fires(m, s, e, below)) hi = below; else lo = below; }
        if (above > lo && above < hi) { if (fires(m, s, e, above)) hi = above; else lo = above; }
    }
    return bisect(m, s, e, lo, hi);
}

/* First time in (0, h] at which the event fires, or -1 if it does not fire in the segment. */
static double first_firing(const HDModel *m, const Segment *s, const EventFn *e, double h) {
    double b = e->b, reach = e->a + (b > 0.0 ? b * h : 0.0) + fabs(e->C) + fabs(e->S); /* >= G on (0, h] */
    if (reach < -1e-9 * (fabs(e->a) + fabs(b) * h + fabs(e->C) + fabs(e->S)))
        return -1.0; /* far from firing: a margin a billion times the rounding of G's terms */
    double w = s->w, R = hypot(e->C, e->S);
    Flank f = {R, R > 0.0 ? atan2(e->S, e->C) : 0.0};
    if (!(R > 0.0) || !(w > 0.0) || R * w <= fabs(b)) { /* G monotone over the whole segment */
        return fires(m, s, e, h) ? locate(m, s, e, &f, 0.0, h) : -1.0;
    }
    /* G = a + b t + R cos(w t - psi); maxima where sin(w t - psi) = b/(R w) with a positive cosine. */
    double psi = f.psi, sigma = b / (R * w);
    double th = asin(sigma), top = R * sqrt(1.0 - sigma * sigma);
    double period = 2.0 * HD_PI / w, rise = (HD_PI + 2.0 * th) / w; /* rising flank: last minimum -> maximum */
    double k0 = floor(-(th + psi) / (2.0 * HD_PI)) + 1.0;            /* index of the first maximum after t = 0 */
    double k = k0;
    if (b > 0.0) { /* heights a + b t_k + top grow with k: jump to the first that can reach zero */
        double t_req = -(e->a + top) / b, kk = ceil((w * t_req - th - psi) / (2.0 * HD_PI)) - 1.0;
        if (kk > k) k = kk; /* one early, in case rounding put the estimate one maximum late */
    }
    for (int tries = 0; tries < 4; ++tries, k += 1.0) {
        double t_max = (th + psi + 2.0 * HD_PI * k) / w;
        if (t_max <= 0.0) t_max = (th + psi + 2.0 * HD_PI * (k + 1.0)) / w;
        double lo = t_max - rise > 0.0 ? t_max - rise : 0.0;
        if (lo >= h) return -1.0;
        if (t_max >= h) return fires(m, s, e, h) ? locate(m, s, e, &f, lo, h) : -1.0;
        if (fires(m, s, e, t_max)) {
            if (lo > 0.0 && fires(m, s, e, lo)) return locate(m, s, e, &f, 0.0, lo); /* rounding guard */
            return locate(m, s, e, &f, lo, t_max);
        }
        if (b <= 0.0) return -1.0; /* later maxima are no higher */
    }
    /* The analytic estimate was off by more than rounding: fall back to scanning maxima one by one (within the
     * work budget: the caller refuses the step when it is spent). */
    for (double t_max = (th + psi + 2.0 * HD_PI * k) / w; t_max < h && !work_exhausted(s->work); t_max += period) {
        if (fires(m, s, e, t_max)) return locate(m, s, e, &f, t_max - rise > 0.0 ? t_max - rise : 0.0, t_max);
    }
    return fires(m, s, e, h) ? locate(m, s, e, &f, 0.0, h) : -1.0;
}

/* Coefficients of the deflection d(t) = Da + Dc cos(w t) + Ds sin(w t). */
static void deflection_coefficients(const Segment *s, double *Da, double *Dc, double *Ds) {
    *Da = s->c / (s->w * s->w);
    *Dc = s->d0 - *Da;
    *Ds = s->dd0 / s->w;
}

static EventFn velocity_event(const HDModel *m, const Segment *s, int motor) {
    double Da, Dc, Ds;
    deflection_coefficients(s, &Da, &Dc, &Ds);
    /* v(t) = v0 + (F + g Da) t / J + g (Dc sin(w t) + Ds (1 - cos(w t))) / (J w), g = -r K_s (motor) or K_s (load) */
    double J = motor ? m->J_m : m->J_l, g = motor ? -m->r * m->K_s : m->K_s;
    double v0 = motor ? m->v_m : m->v_l, F = motor ? s->F_m : s->F_l, dir = motor ? m->motor_dir : m->load_dir;
    EventFn e;
    e.kind = motor ? EV_MOTOR_VELOCITY : EV_LOAD_VELOCITY;
    e.sign = -dir;
    e.level = 0.0;
    e.strict = 0;
    e.a = e.sign * (v0 + g * Ds / (J * s->w));
    e.b = e.sign * (F + g * Da) / J;
    e.C = e.sign * (-g * Ds / (J * s->w));
    e.S = e.sign * (g * Dc / (J * s->w));
    return e;
}

static EventFn break_event(const HDModel *m, const Segment *s, int motor, double sign) {
    double Da, Dc, Ds;
    deflection_coefficients(s, &Da, &Dc, &Ds);
    /* N(t) = N0 + g d(t): motor N = T - r K_s d, load N = K_s d */
    double N0 = motor ? m->motor_torque : 0.0, g = motor ? -m->r * m->K_s : m->K_s;
    EventFn e;
    e.kind = motor ? EV_MOTOR_BREAK : EV_LOAD_BREAK;
    e.sign = sign;
    e.level = motor ? m->f_m : m->f_l;
    e.strict = 1;
    e.a = sign * (N0 + g * Da) - e.level;
    e.b = 0.0;
    e.C = sign * g * Dc;
    e.S = sign * g * Ds;
    return e;
}

/* The events that can end the current segment. A body without friction never sticks, so its velocity is no event. */
static int segment_events(const HDModel *m, const Segment *s, EventFn *ev) {
    int n = 0;
    if (s->motor_slips && m->f_m > 0.0) ev[n++] = velocity_event(m, s, 1);
    if (s->load_slips && m->f_l > 0.0) ev[n++] = velocity_event(m, s, 0);
    if (!s->motor_slips) { ev[n++] = break_event(m, s, 1, 1.0); ev[n++] = break_event(m, s, 1, -1.0); }
    if (!s->load_slips) { ev[n++] = break_event(m, s, 0, 1.0); ev[n++] = break_event(m, s, 0, -1.0); }
    return n;
}

static void commit(HDModel *m, const Segment *s, const Motion *mo) {
    m->input_work += m->motor_torque * mo->dq_m;
    m->friction_work += (s->motor_slips ? m->f_m * m->motor_dir * mo->dq_m : 0.0)
                      + (s->load_slips ? m->f_l * m->load_dir * mo->dq_l : 0.0);
    m->q_m = mo->q_m;
    m->q_l = mo->q_l;
    m->v_m = mo->v_m;
    m->v_l = mo->v_l;
}

static int state_finite(const HDModel *m) {
    return isfinite(m->q_m) && isfinite(m->q_l) && isfinite(m->v_m) && isfinite(m->v_l) && isfinite(m->input_work)
        && isfinite(m->friction_work) && isfinite(m->hysteresis_state);
}

/* ---------------------------------------------------------------- general propagator ---------------------- */

/* Substeps per period of the stiffest oscillation. On a harmonic oscillation the sixth-order method's errors per
 * period at 90 substeps (amplitude 3e-11, phase 5e-10 rad) are below those of classical RK4 at 400 substeps (4e-11,
 * 3e-9 rad), which this propagator used before, for 630 model evaluations per period instead of 1600 (87 is the
 * fewest that keeps both below; tests/test_fmu_effects.py recomputes them from the method's stability polynomial). */
#define HD_SUBSTEPS_PER_PERIOD 90.0
/* Substeps through decays and transients, the same way: on y' = -y the error of one step of the method at 0.25 (of
 * a viscous or Stribeck time constant) and 0.16 (a transient's resolution) is below RK4's at the 0.1 and 0.05 it used
 * (the largest that are: 0.277 and 0.168; the test recomputes them). Per step, not per unit of time: with the
 * per-time criterion (0.33, 0.2) the all-effects comparison with an independent DOP853 integrator got worse than
 * with RK4, with this one better (hysteresis state 9.0e-12 against 2.7e-11 N.m). */
#define HD_DECAY_FRACTION 0.25
#define HD_TRANSIENT_RESOLUTION 0.16
#define HD_STEP_WORK 6      /* model evaluations of one step of the method (its first stage is the substep's) */
#define HD_SUBSTEP_WORK 9.0 /* model evaluations of one substep without events (counted in fx_do_step) */

/* The state's derivative from the forces in that state. */
static FxState fx_deriv_of(const HDModel *m, const FxState *y, const FxForces *f) {
    double v_m = m->motor_stuck ? 0.0 : y->v_m, v_l = m->load_stuck ? 0.0 : y->v_l;
    FxState dy = {v_m, v_l, f->a_m, f->a_l, m->motor_torque * v_m, f->F_m * v_m + f->F_l * v_l};
    return dy;
}

static FxState fx_deriv(const HDModel *m, const FxState *y) {
    FxForces f = fx_forces(m, y);
    return fx_deriv_of(m, y, &f);
}

/* A substep's start: its state, the derivative there (the first stage of every step from it), its place in the
 * communication step and its length. */
typedef struct {
    FxState y0, k0;
    double t, len;
} FxStart;

static FxState fx_axpy(const FxState *y, double c, const FxState *k) {
    FxState r = {y->q_m + c * k->q_m, y->q_l + c * k->q_l, y->v_m + c * k->v_m, y->v_l + c * k->v_l,
                 y->w_in + c * k->w_in, y->w_fr + c * k->w_fr};
    return r;
}

/* Butcher's sixth-order Runge-Kutta method with seven stages (J. C. Butcher, J. Austral. Math. Soc. 4, 1964): nodes
 * 0, 1/3, 2/3, 1/3, 1/2, 1/2, 1. Its 37 order conditions up to order six hold exactly in rational arithmetic
 * (tests/test_fmu_effects.py checks them from these very numbers, read out of this file). */
static const double RK6_A[7][6] = {
    {0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {1.0 / 3, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.0, 2.0 / 3, 0.0, 0.0, 0.0, 0.0},
    {1.0 / 12, 1.0 / 3, -1.0 / 12, 0.0, 0.0, 0.0},
    {-1.0 / 16, 9.0 / 8, -3.0 / 16, -3.0 / 8, 0.0, 0.0},
    {0.0, 9.0 / 8, -3.0 / 8, -3.0 / 4, 1.0 / 2, 0.0},
    {9.0 / 44, -9.0 / 11, 63.0 / 44, 18.0 / 11, 0.0, -16.0 / 11},
};
static const double RK6_B[7] = {11.0 / 120, 0.0, 27.0 / 40, 27.0 / 40, -4.0 / 15, -4.0 / 15, 11.0 / 120};

/* One step of length h of the sixth-order method from the substep start with the modes of m held; a stuck body keeps
 * its state bit for bit. */
static FxState fx_rk6(const HDModel *m, const FxStart *st, double h) {
    const FxState *y = &st->y0;
    FxState k[7];
    k[0] = st->k0;
    for (int i = 1; i < 7; ++i) {
        FxState yi = *y; /* the stages need positions and velocities only: the works are quadratures */
        for (int j = 0; j < i; ++j) {
            double c = h * RK6_A[i][j];
            if (c == 0.0) continue;
            yi.q_m += c * k[j].q_m, yi.q_l += c * k[j].q_l, yi.v_m += c * k[j].v_m, yi.v_l += c * k[j].v_l;
        }
        k[i] = fx_deriv(m, &yi);
    }
    FxState out = *y;
    for (int i = 0; i < 7; ++i)
        if (RK6_B[i] != 0.0) out = fx_axpy(&out, h * RK6_B[i], &k[i]);
    if (m->motor_stuck) out.q_m = y->q_m, out.v_m = 0.0;
    if (m->load_stuck) out.q_l = y->q_l, out.v_l = 0.0;
    return out;
}

typedef enum { FX_MOTOR_VELOCITY, FX_LOAD_VELOCITY, FX_MOTOR_BREAK, FX_LOAD_BREAK, FX_HYSTERESIS } FxEventKind;

typedef struct {
    FxEventKind kind;
    int32_t sign; /* break events: +1 / -1 for the two edges of the static band */
} FxEvent;

/* The event function in state y (modes of m): velocity -dir v (fires at >= 0); break +-N minus its static level and
 * hysteresis dd against the branch direction (both fire at > 0 strictly). */
static double fx_value(const HDModel *m, const FxEvent *e, const FxState *y) {
    FxSpring s;
    switch (e->kind) {
    case FX_MOTOR_VELOCITY: return -m->motor_dir * y->v_m;
    case FX_LOAD_VELOCITY: return -m->load_dir * y->v_l;
    case FX_MOTOR_BREAK:
        s = fx_spring(m, y->q_m, y->q_l);
        return e->sign * (m->motor_torque - s.g * s.tau) - static_level(m, m->f_m, e->sign);
    case FX_LOAD_BREAK:
        s = fx_spring(m, y->q_m, y->q_l);
        return e->sign * s.tau - static_level(m, m->f_l, e->sign);
    case FX_HYSTERESIS:
        s = fx_spring(m, y->q_m, y->q_l);
        return -m->hyst_dir * (s.g * y->v_m - y->v_l);
    }
    return -1.0;
}

/* Does the event fire at the value g? (For doubles a - b > 0 exactly when a > b: the comparison itself.) */
static int fx_fires_at(const FxEvent *e, double g) {
    return e->kind == FX_MOTOR_VELOCITY || e->kind == FX_LOAD_VELOCITY ? g >= 0.0 : g > 0.0;
}

/* The events that can end the current substep. A body whose friction does not depend on its slip direction (no
 * Coulomb friction, symmetric viscous term) never sticks: its velocity is no event. */
static int fx_events(const HDModel *m, FxEvent *ev) {
    int n = 0;
    if (!m->motor_stuck && velocity_switches(m, m->f_m, m->b_m)) ev[n].kind = FX_MOTOR_VELOCITY, ev[n++].sign = 0;
    if (!m->load_stuck && velocity_switches(m, m->f_l, m->b_l)) ev[n].kind = FX_LOAD_VELOCITY, ev[n++].sign = 0;
    for (int32_t sign = -1; sign <= 1; sign += 2) {
        if (m->motor_stuck) ev[n].kind = FX_MOTOR_BREAK, ev[n++].sign = sign;
        if (m->load_stuck) ev[n].kind = FX_LOAD_BREAK, ev[n++].sign = sign;
    }
    if (m->hysteresis_torque > 0.0) ev[n].kind = FX_HYSTERESIS, ev[n++].sign = 0;
    return n;
}

/* The next trial in the bracket (lo, hi): the regula falsi point, at least tol inside (a root next to one end is then
 * bracketed by the next trial), or the midpoint when the values do not straddle zero strictly, the bracket is within
 * 2 tol or `halve` (after 60 trials: halving alone bounds the search). Strictly: a value 0 at the fraction 0 (a body
 * that just broke away, at velocity 0) fires there but is taken as not firing; interpolating from it would probe
 * the rounding noise next to 0 and find a Zeno sequence of events (the paper-effects hardening cases did). */
static double falsi_trial(double lo, double hi, double g_lo, double g_hi, int halve) {
    double mid = lo + 0.5 * (hi - lo), tol = 16.0 * DBL_EPSILON * hi;
    if (halve || !(hi - lo > 2.0 * tol && g_lo < 0.0 && g_hi > 0.0)) return mid;
    double trial = lo + (hi - lo) * (g_lo / (g_lo - g_hi));
    trial = trial > hi - tol ? hi - tol : trial < lo + tol ? lo + tol : trial;
    return trial > lo && trial < hi ? trial : mid;
}

/* Smallest substep fraction in (0, 1] at which the event fires (it fires at 1; 0 is taken as not firing), to the
 * last bit; every trial is one step of the method of that length from the substep start, smooth in the fraction.
 * A fraction that does not advance the step's clock t is taken as not firing either (see fires()). The trials are
 * placed by the Illinois variant of regula falsi on the event function's values (superlinear: 8-25 trials instead of
 * ~55 halvings; near the root the values are quantized at the rounding level of the torques, and the last few
 * hundred ulps are halved), each at least 16 ulps inside the bracket, until it is 32 ulps wide, then halved; every
 * bracket update is decided by fx_fires_at alone, so the result is a fraction that fires next to one that does not,
 * as with plain halving. */
static double fx_bisect(const HDModel *m, const FxStart *st, const FxEvent *e, Work *work, double g1) {
    double lo = 0.0, hi = 1.0, g_lo = fx_value(m, e, &st->y0), g_hi = g1, t = st->t;
    int side = 0;
    for (int i = 0; i < 200; ++i) {
        double mid = lo + 0.5 * (hi - lo);
        if (mid <= lo || mid >= hi) break;
        double trial = falsi_trial(lo, hi, g_lo, g_hi, i >= 60);
        if (t + trial * st->len == t) { lo = trial; continue; }
        work->used += HD_STEP_WORK + 1; /* a step of the method and the event function */
        FxState y = fx_rk6(m, st, trial * st->len);
        double g = fx_value(m, e, &y);
        if (fx_fires_at(e, g)) {
            hi = trial, g_hi = g;
            if (side == 1) g_lo *= 0.5;
            side = 1;
        } else {
            lo = trial, g_lo = g;
            if (side == -1) g_hi *= 0.5;
            side = -1;
        }
    }
    return hi;
}

/* Where a slipping body's velocity passes through 0 and back inside one substep, so that its event function -dir v
 * is below 0 at both ends: the body stops, sticks and breaks away again within one sample (a torque step at the
 * substep's start that briefly outweighs the drive; measured on an independent simulator's log, where the missed
 * stop put the load 1.5 noise sigmas off within 3 s). The velocity over the substep is taken as the cubic through
 * its values and accelerations at both ends (the right-hand side is smooth inside a substep, a small part of a
 * period); where that cubic reaches 0, one step of the method to its extremum tells whether the body really stopped
 * there. Returns the fraction (in (0, 1)) at which the event fires, with the function's value there in *g_at, or 0
 * where it does not; a body speeding up at the start (-dir v' <= 0) has no such stop before its end's check. The
 * forces at the end, *f1, are computed once: the next substep starts from them. (The hysteresis branch's twist rate
 * could reverse and turn back likewise; checking it cost 17 % more time on a hysteresis model, with no case found
 * where it mattered, so it is left to the end's check.) */
static double fx_interior_stop(const HDModel *m, const FxStart *st, const FxEvent *e, const FxState *y1, double g1,
                               FxForces *f1, int *have_f1, Work *work, double *g_at) {
    int motor = e->kind == FX_MOTOR_VELOCITY;
    double dir = motor ? m->motor_dir : m->load_dir;
    double g0 = fx_value(m, e, &st->y0), d0 = -dir * (motor ? st->k0.v_m : st->k0.v_l) * st->len;
    if (!(d0 > 0.0)) return 0.0;
    work->used += 1; /* the forces at the end (the next substep's start's, computed once) */
    if (!*have_f1) *f1 = fx_forces(m, y1), *have_f1 = 1;
    FxState k1 = fx_deriv_of(m, y1, f1);
    double d1 = -dir * (motor ? k1.v_m : k1.v_l) * st->len;
    double c2 = 3.0 * (g1 - g0) - 2.0 * d0 - d1, c3 = 2.0 * (g0 - g1) + d0 + d1;
    /* the cubic's derivative d0 + 2 c2 x + 3 c3 x^2 falls from d0 > 0 through 0 at its first root in (0, 1) */
    double x = -1.0;
    if (c3 == 0.0) {
        if (c2 < 0.0) x = -d0 / (2.0 * c2);
    } else {
        double disc = c2 * c2 - 3.0 * c3 * d0;
        if (disc >= 0.0) {
            double r = sqrt(disc), a = (-c2 - r) / (3.0 * c3), b = (-c2 + r) / (3.0 * c3);
            x = fmin(a, b) > 0.0 ? fmin(a, b) : fmax(a, b);
        }
    }
    if (!(x > 0.0 && x < 1.0) || g0 + x * (d0 + x * (c2 + x * c3)) < 0.0) return 0.0; /* no maximum reaching 0 */
    work->used += HD_STEP_WORK + 1; /* the step to that fraction and the function there */
    FxState y = fx_rk6(m, st, x * st->len);
    double g = fx_value(m, e, &y);
    if (!fx_fires_at(e, g)) return 0.0;
    *g_at = g;
    return x;
}

/* Longest substep for the bodies that slip: HD_SUBSTEPS_PER_PERIOD per period of their stiffest oscillation (tangent
 * stiffness at the twist d, the hysteresis element's sigma times hysteresis_slope, largest gear factor r + 2A + 4A4;
 * a stuck body takes no part, the other rings against the spring alone), at most HD_DECAY_FRACTION of a slipping
 * body's viscous time constant J / (b (1 + |a_v|)). */
static double mode_substep(const HDModel *m, double d, int motor_slips, int load_slips) {
    double K = m->K_s * (1.0 + hardening_slope(m, d))
             + (m->hysteresis_torque > 0.0 ? m->hysteresis_stiffness * hysteresis_slope(m) : 0.0);
    double G = m->r + 2.0 * m->kinematic_error + 4.0 * m->kinematic_error_4;
    double w2 = K * ((motor_slips ? G * G / m->J_m : 0.0) + (load_slips ? 1.0 / m->J_l : 0.0));
    double h_max = 2.0 * HD_PI / sqrt(w2) / HD_SUBSTEPS_PER_PERIOD;
    double va = 1.0 + fabs(m->viscous_asymmetry); /* the larger of the two directions' viscous coefficients */
    if (motor_slips && m->b_m > 0.0) h_max = fmin(h_max, HD_DECAY_FRACTION * m->J_m / (m->b_m * va));
    if (load_slips && m->b_l > 0.0) h_max = fmin(h_max, HD_DECAY_FRACTION * m->J_l / (m->b_l * va));
    return h_max;
}

/* Substep length for a communication step h: the longest one with both bodies slipping, at the step start (the
 * shortest of the modes; fx_local_substep lengthens it while a body is stuck and shortens it through transients).
 * (Stribeck friction is stiff only while a body is slow: fx_local_substep limits the substeps then.) */
static HDStatus fx_substep(const HDModel *m, double h, double *h_sub, char *err, size_t errlen) {
    double h_max = mode_substep(m, fx_spring(m, m->q_m, m->q_l).d, 1, 1);
    if (h == 0.0) {
        *h_sub = 0.0;
        return HD_OK;
    }
    double n = ceil(h / h_max);
    if (!(HD_SUBSTEP_WORK * n <= (double)HD_WORK_BUDGET)) { /* refused before any work: the substeps alone */
        snprintf(err, errlen, "a step of %g s needs %g substeps of at most %g s (%g per period of the stiffest "
                              "oscillation), more than the %lld model evaluations one doStep may do; use "
                              "communication steps of at most %.2g s",
                 h, n, h_max, HD_SUBSTEPS_PER_PERIOD, HD_WORK_BUDGET,
                 0.5 * h_max * (double)HD_WORK_BUDGET / HD_SUBSTEP_WORK);
        return HD_ERROR;
    }
    *h_sub = n >= 1.0 ? h / n : h;
    return HD_OK;
}

/* Substep limit of one Stribeck transient: while a body is slow (or gets slow within h_sub: inside `range` vs) its
 * friction changes on the time scale vs/|a|, and the falling friction-speed curve (slope up to k f / vs,
 * k = (1 + |a|) s stribeck_slope_max) acts as a negative damping of rate k f / (J vs). A decay exponent that is not
 * an integer makes |v/vs|^delta non-smooth at v = 0 (its derivatives of order above delta grow without bound there),
 * where the method loses its order: the substeps are then graded, each changing v by at most the resolution times
 * |v| (not less than 1e-3 vs). Measured with delta = 1.5 on a breakaway slide: 3.5e-10 rad from an independent
 * DOP853 integration ungraded, 1.9e-12 graded (the test's bound, met by the Gaussian and the exponential: 1e-10).
 * The exponential decay (delta = 1) reaches 36 vs instead of the Gaussian's 6, but every derivative of exp(-x) is
 * exp(-x) itself: at x = |v|/vs the term's slope is exp(-x) of its steepest, and a step's error (its torque times
 * (|a| h / vs)^7) that of a step at the breakaway when h is exp(x/7) times longer. Its substeps are sized so, from the
 * slowest speed the body may reach within h_sub. Measured: on a 7 s torque-step log 54 model evaluations per sample
 * instead of 136 with the breakaway's substeps over the whole range; every effect on, against an independent DOP853
 * integration, 4.9e-14 rad on q_m (3.7e-14 before; 3.0e-10, beyond the test's 1e-10, with no Stribeck limit past the
 * breakaway). The Gaussian's substeps lengthen likewise: a step's error goes with the decay's seventh derivative,
 * H_7(x) exp(-x^2), whose largest size at x or beyond (a speed the substep may still reach) falls from its peak (402,
 * at x = 0.38) to 1.5e-11 of it at x = 6; GAUSS_SEVENTH[k] is (that peak over the largest size at k/4 or beyond)^(1/7),
 * rounded down (at most the factor at any x >= k/4, so no substep errs more than one at the breakaway), and the
 * negative damping is that of the slope's largest size at x or beyond (2 x exp(-x^2), peak at x = 1/sqrt(2)).
 * Measured (7 s at 5 kHz of the independent generator's logs, s = 0.5): on the stiff drive of an actuator-lag log
 * 94 evaluations per sample instead of 120 at vs = 1e-3, 232 instead of 252 at 1e-4; on bench/log_simulation.py's
 * 45.5 instead of 52.1. Against the independent DOP853 integration, slides from breakaways at 1.02x, 1.5x and 3x the
 * level: 1.65e-11, 1.2e-11 and 4.6e-13 rad, the same to three digits as with the breakaway's substeps. */
#define HD_SQRT_HALF 0.70710678118654752
static const double GAUSS_SEVENTH[25] = {1.000, 1.000, 1.016, 1.091, 1.091, 1.102, 1.249, 1.321, 1.322, 1.413, 1.712,
    1.872, 1.881, 2.021, 2.288, 2.686, 3.251, 4.042, 5.151, 6.720, 8.966, 12.227, 17.031, 24.221, 35.159};
static double stribeck_cap(double cap, double v, double a, double vs, double h_sub, double rate_max, double range,
                           double delta) {
    double slowest = fabs(v) - fabs(a) * h_sub; /* the slowest speed this substep may reach */
    if (slowest < range * vs) {
        double scale = vs;
        if (delta == 1.0 && slowest > 0.0) {
            scale = vs * exp(slowest / (7.0 * vs));
            rate_max *= exp(-slowest / vs);
        } else if (delta == 2.0 && slowest > 0.0) {
            double x = slowest / vs;
            scale = vs * GAUSS_SEVENTH[(int)(4.0 * x)];
            if (x > HD_SQRT_HALF) rate_max *= x * exp(0.5 - x * x) / HD_SQRT_HALF; /* 2x exp(-x^2) over its peak */
        } else if (delta != floor(delta)) {
            scale = fmin(vs, fmax(fabs(v), 1e-3 * vs));
        }
        if (a != 0.0) cap = fmin(cap, HD_TRANSIENT_RESOLUTION * scale / fabs(a));
        cap = fmin(cap, HD_DECAY_FRACTION / rate_max);
    }
    return cap;
}

/* The substep from here: longer than the step's h_sub while a body is stuck (mode_substep of the other one alone),
 * shorter while a fast transient is under way (rate * substep <= HD_TRANSIENT_RESOLUTION): a body in or entering its
 * Stribeck range, and a hysteresis branch not yet saturated, which relaxes at sigma |dd| / H. */
static double fx_local_substep(const HDModel *m, double h_sub, const FxForces *forces) {
    const FxForces f = *forces; /* in the current state */
    double cap = m->motor_stuck || m->load_stuck /* one body rings alone: a lower frequency */
               ? fmax(h_sub, mode_substep(m, f.s.d, !m->motor_stuck, !m->load_stuck)) : h_sub;
    const double look = cap; /* how far ahead the transients are judged */
    if (m->stribeck_ratio > 0.0) {
        double k = (1.0 + fabs(m->friction_asymmetry)) * m->stribeck_ratio * stribeck_slope_max(m->stribeck_shape);
        double vs_m = m->stribeck_velocity / m->r, vs_l = m->stribeck_velocity;
        double delta = m->stribeck_shape, range = stribeck_range(delta); /* once for both bodies: a pow */
        if (!m->motor_stuck && m->f_m > 0.0)
            cap = stribeck_cap(cap, m->v_m, f.a_m, vs_m, look, k * m->f_m / (m->J_m * vs_m), range, delta);
        if (!m->load_stuck && m->f_l > 0.0)
            cap = stribeck_cap(cap, m->v_l, f.a_l, vs_l, look, k * m->f_l / (m->J_l * vs_l), range, delta);
    }
    double H = m->hysteresis_torque, left = fabs(m->hyst_dir * H - f.s.z); /* the transient's torque still to come */
    if (H > 0.0 && left > 1e-13 * H) {
        double v_m = m->motor_stuck ? 0.0 : m->v_m, v_l = m->load_stuck ? 0.0 : m->v_l;
        double dd = fabs(f.s.g * v_m - v_l) + fabs(f.s.g * f.a_m - f.a_l) * look;
        double rate = m->hysteresis_stiffness * dd / H * hysteresis_rate_factor(m->hysteresis_exponent, left / H);
        /* A step's error from a transient grows as its torque times (rate h)^7: a transient of torque `left` on top
         * of the load's torque scale F may take (F / left)^(1/7) times the resolution of a full-size one. */
        double F = H + m->f_l + fabs(f.s.tau), resolution = HD_TRANSIENT_RESOLUTION * fmax(1.0, pow(F / left, 1.0 / 7));
        if (rate * cap > resolution) cap = resolution / rate;
    }
    return fmax(cap, 1e-4 * h_sub); /* bounded work per step */
}

static void fx_commit(HDModel *m, const FxState *y) {
    m->q_m = y->q_m;
    m->q_l = y->q_l;
    m->v_m = y->v_m;
    m->v_l = y->v_l;
    m->input_work = y->w_in;
    m->friction_work = y->w_fr;
    m->hysteresis_state = hysteresis_z(m, fx_spring(m, y->q_m, y->q_l).d);
}

/* ---------------------------------------------------------------- the communication step ------------------ */

/* After every segment / substep: the state must stay finite, and the step within its work budget. */
static int step_failed(const HDModel *w, const Work *work, const HDStepStats *st, double h, double t, double t0,
                       char *err, size_t errlen) {
    if (!state_finite(w)) {
        snprintf(err, errlen, "the state overflowed during a step of %g s at t = %g s; use smaller torques or "
                              "steps", h, t0);
        return 1;
    }
    if (work_exhausted(work)) {
        /* The step got as far as t on its budget: half of that leaves room for a busier stretch. */
        snprintf(err, errlen, "a step of %g s needs more than the %lld model evaluations one doStep may do (%lld "
                              "switching events in its first %.3g s); use communication steps of at most %.2g s",
                 h, (long long)work->limit, (long long)st->events, t, 0.5 * t);
        return 1;
    }
    return 0;
}

/* Advances the working copy w by h with the general propagator; the caller commits it on success. */
static HDStatus fx_do_step(HDModel *w, double h, double t0, Work *work, HDStepStats *st, char *err, size_t errlen) {
    double h_sub;
    if (fx_substep(w, h, &h_sub, err, errlen) != HD_OK) return HD_ERROR;
    double t = 0.0;
    FxForces f_end; /* the forces at a substep's end committed without an event: the next start's, bit for bit */
    int have_end = 0;
    while (t < h && !(w->motor_stuck && w->load_stuck)) {
        FxStart s0;
        s0.y0 = fx_state(w);
        FxForces f0 = have_end ? f_end : fx_forces(w, &s0.y0);
        have_end = 0;
        s0.k0 = fx_deriv_of(w, &s0.y0, &f0);
        double cap = fx_local_substep(w, h_sub, &f0);
        int last = h - t <= cap * (1.0 + 1e-12);
        s0.t = t, s0.len = last ? h - t : cap;
        FxState y1 = fx_rk6(w, &s0, s0.len);
        FxEvent ev[7];
        int n = fx_events(w, ev), which = -1;
        work->used += HD_STEP_WORK + 2 + n; /* the start's forces, the step, commit, every event function at its end */
        double theta = 1.0;
        for (int i = 0; i < n; ++i) {
            double g1 = fx_value(w, &ev[i], &y1), th;
            if (fx_fires_at(&ev[i], g1)) {
                th = fx_bisect(w, &s0, &ev[i], work, g1);
            } else {
                int velocity = ev[i].kind == FX_MOTOR_VELOCITY || ev[i].kind == FX_LOAD_VELOCITY;
                double g_x = 0.0, x = velocity ? fx_interior_stop(w, &s0, &ev[i], &y1, g1, &f_end, &have_end,
                                                                    work, &g_x) : 0.0;
                if (x == 0.0) continue;
                FxStart head = s0; /* the event lies in (0, x]: located there as at a substep's end */
                head.len = x * s0.len;
                th = x * fx_bisect(w, &head, &ev[i], work, g_x);
            }
            if (which < 0 || th < theta) theta = th, which = i;
        }
        if (which < 0) {
            fx_commit(w, &y1); /* f_end, where computed, holds at the committed state */
            t = last ? h : t + s0.len;
        } else {
            have_end = 0; /* the substep ends at the event instead */
            FxState y = fx_rk6(w, &s0, theta * s0.len);
            work->used += HD_STEP_WORK + 3; /* the step to the event, its commit and the new decisions */
            fx_commit(w, &y);
            t += theta * s0.len; /* > t: fx_bisect never returns a fraction that leaves the clock where it was */
            if (ev[which].kind == FX_MOTOR_VELOCITY) w->v_m = 0.0;
            if (ev[which].kind == FX_LOAD_VELOCITY) w->v_l = 0.0;
            fx_settle(w);
            w->event_count++;
            st->events++;
        }
        if (step_failed(w, work, st, h, t, t0, err, errlen)) return HD_ERROR;
    }
    return HD_OK;
}

/* Advances the working copy w by h in closed form, segment by segment; the caller commits it on success. */
static HDStatus cf_do_step(HDModel *w, double h, double t0, Work *work, HDStepStats *st, char *err, size_t errlen) {
    double t = 0.0;
    while (t < h && !(w->motor_stuck && w->load_stuck)) {
        Segment s = make_segment(w, work, t);
        EventFn ev[6];
        int n = segment_events(w, &s, ev);
        work->used += 1; /* the segment's and its events' coefficients */
        double rest = h - t, t_event = rest;
        int which = -1;
        for (int i = 0; i < n; ++i) {
            double te = first_firing(w, &s, &ev[i], t_event);
            if (te > 0.0 && te <= t_event && (which < 0 || te < t_event)) { t_event = te; which = i; }
        }
        Motion mo = segment_at(w, &s, t_event);
        commit(w, &s, &mo);
        t = which < 0 ? h : t + t_event; /* > t: fires() never accepts an event that leaves the clock where it was */
        if (which >= 0) {
            if (ev[which].kind == EV_MOTOR_VELOCITY) w->v_m = 0.0;
            if (ev[which].kind == EV_LOAD_VELOCITY) w->v_l = 0.0;
            settle_modes(w);
            w->event_count++;
            st->events++;
        }
        if (step_failed(w, work, st, h, t, t0, err, errlen)) return HD_ERROR;
    }
    return HD_OK;
}

static int outputs_finite(const HDModel *m) {
#define X(vr, name, unit) if (!isfinite(m->name)) return 0;
    HD_REAL_OUTPUTS(X)
#undef X
    return 1;
}

/* Work budget. Every doStep may do at most HD_WORK_BUDGET evaluations of the model's equations (a closed-form
 * state, or one right-hand side of the general propagator), counted as they are done; a step that would need more
 * is refused with an error naming the step size that fits (the model is left as it was). No decision depends on the
 * clock of the machine. Why this bounds every step:
 * - every event advances the step's clock (fires(), fx_bisect), so no sequence of events can stand still - the
 *   subnormal step that used to fire the same event at the same instant two million times now takes one event;
 * - every loop iteration does a bounded amount of work (at most six event searches of at most 216 trials each -
 *   16 bracketing trials and 200 halvings, about 15 in practice -, or one substep of the general propagator and
 *   seven searches of at most 200 trials), and the only unbounded search (scanning the maxima
 *   of an event function) stops when the budget is spent;
 * - a step that needs more substeps than the budget allows (a stiff spring, a huge step) is refused before any
 *   work is done.
 * The size: counted this way one evaluation costs 40-90 ns at -O2 (measured; -O3, now used, about 10 % less) for
 * realistic drives, up to about 150 ns for the costliest effect combinations measured (kinematic error, hysteresis
 * and direction-dependent friction at once), and about 1.5 times that in the AddressSanitizer + UBSan build (bench/fmu_robustness.py measures it). 2e6
 * evaluations therefore keep every doStep under about 0.3 s of CPU (0.5 s sanitized): a margin of 2-3 on the 1 s a
 * co-simulation master may expect, with room for a busy machine. They allow about 2,000 periods of the stiffest
 * oscillation per step with the general propagator (90 substeps per period, about 10 evaluations each) or
 * at least 9,000 stick-slip events in closed form (at most 216 evaluations each; about 15 typically). */
HDStatus hd_do_step(HDModel *m, double h, HDStepStats *stats, char *err, size_t errlen) {
    HDStepStats st = {0, 0};
    if (stats) *stats = st;
    if (!(h >= 0.0) || !isfinite(h)) {
        snprintf(err, errlen, "communication step size %g s must be finite and >= 0", h);
        return HD_ERROR;
    }
    if (!isfinite(m->time + h)) {
        snprintf(err, errlen, "a step of %g s from t = %g s would take time beyond the largest double", h, m->time);
        return HD_ERROR;
    }
    if (!isfinite(m->motor_torque)) {
        snprintf(err, errlen, "motor_torque = %g N.m is not finite", m->motor_torque); /* unreachable via set */
        return HD_ERROR;
    }
    HDModel w = *m; /* advance a copy: on error the caller's state is untouched */
    Work work = {0, HD_WORK_BUDGET};
    HDStatus status;
    if (effects_on(&w)) {
        fx_settle(&w); /* the torque may have changed since the last step */
        status = fx_do_step(&w, h, m->time, &work, &st, err, errlen);
    } else {
        settle_modes(&w); /* the torque may have changed since the last step */
        status = cf_do_step(&w, h, m->time, &work, &st, err, errlen);
    }
    st.work = work.used;
    if (stats) *stats = st;
    if (status != HD_OK) return HD_ERROR;
    w.time = m->time + h;
    w.model_evaluations += (double)work.used; /* exact: a double counts every integer up to 2^53 */
    update_outputs(&w);
    if (!outputs_finite(&w)) {
        snprintf(err, errlen, "an output overflowed during a step of %g s at t = %g s; use smaller torques or steps",
                 h, m->time);
        return HD_ERROR;
    }
    *m = w;
    return HD_OK;
}


/* ------------------------------------------------------------------------------------------ debug logging ---- */

static const char *const LOG_CATEGORY[] = {
#define X(bit, name) name,
    HD_LOG_CATEGORIES(X)
#undef X
};
#define N_LOG_CATEGORIES (sizeof LOG_CATEGORY / sizeof LOG_CATEGORY[0])

const char *hd_log_category(unsigned bit) { return bit < N_LOG_CATEGORIES ? LOG_CATEGORY[bit] : "unknown"; }

int hd_log_mask(unsigned *mask, int on, size_t n, const char *const categories[], const char **bad) {
    unsigned named = 0;
    for (size_t i = 0; i < n; ++i) {
        unsigned bit = 0;
        while (bit < N_LOG_CATEGORIES && !(categories[i] && strcmp(categories[i], LOG_CATEGORY[bit]) == 0)) ++bit;
        if (bit == N_LOG_CATEGORIES) {
            *bad = categories[i] ? categories[i] : "NULL";
            return -1;
        }
        named |= 1u << bit;
    }
    unsigned all = (1u << N_LOG_CATEGORIES) - 1u;
    if (on) *mask = n == 0 ? all : named;
    else *mask = n == 0 ? 0u : *mask & ~named;
    return 0;
}

int hd_phase_allows(HDPhase phase, unsigned mask, const char *const names[HD_PHASE_COUNT], char *msg, size_t n) {
    if ((unsigned)phase < HD_PHASE_COUNT && (mask & (1u << phase))) return 1;
    snprintf(msg, n, "must not be called in the current state (%s)",
             (unsigned)phase < HD_PHASE_COUNT ? names[phase] : "invalid");
    return 0;
}
