/* HarmonicDrive plant: the physics, independent of any FMI version.
 *
 * Two inertias (motor J_m, load J_l) joined by a gear ratio r (= q_l/q_m at rest, r < 1) and a torsional spring
 * K_s on the load-side deflection d = r q_m - q_l, with exact (Karnopp) stick-slip friction on both sides:
 *
 *     J_m q_m'' = T - F_m - r K_s d          J_l q_l'' = K_s d - F_l
 *
 * Between switching events the equations are linear with constant forcing, so every segment is solved in closed
 * form and every event (a slipping body's velocity reaching zero, a stuck body's net torque leaving its static
 * band) is located as the first root of a known function. See model.c.
 *
 * Optional effects (parameters vr 100+, all off by default): viscous friction b_m, b_l (direction-dependent
 * with viscous_asymmetry); Stribeck and asymmetric friction; a hardening spring K_s (d + hardening d^3); a Dahl
 * hysteresis element z in parallel with the spring; a kinematic error d = r q_m + A sin(2 q_m + phi)
 * + A4 sin(4 q_m + phi4) - q_l. With any of them on, the same Karnopp stick-slip is propagated by a fixed-substep
 * sixth-order Runge-Kutta method with the friction / hysteresis modes held inside each substep and events located
 * to the last bit (model.c, "general propagator").
 *
 * All the state of one instance lives in HDModel: no globals, instances are independent, and copying the struct
 * copies the complete simulation state (used for FMU state get/set/serialize).
 */
#ifndef HD_MODEL_H
#define HD_MODEL_H

#include <stddef.h>
#include <stdint.h>

#include "model_vars.h" /* generated from fmu_build/variables.py: value references, ranges, start values */

/* HD_RANGE: a value outside its allowed range (NaN included) was refused and nothing changed; the FMI glue answers
 * it with Discard, as both standards suggest for a min/max violation in a setter. HD_ERROR: anything else. */
typedef enum { HD_OK = 0, HD_ERROR = 1, HD_RANGE = 2 } HDStatus;

/* Phase of an FMU instance in the FMI state machines (kept in the FMU state, hence here): FMI 2 instantiated,
 * initializationMode, stepComplete, terminated, error; FMI 3 Instantiated, Initialization Mode, Step Mode,
 * Terminated (HD_PHASE_ERROR is Terminated entered through an error: the same allowed calls). */
typedef enum {
    HD_PHASE_INSTANTIATED = 0, HD_PHASE_INITIALIZATION, HD_PHASE_STEP, HD_PHASE_TERMINATED, HD_PHASE_ERROR,
    HD_PHASE_COUNT
} HDPhase;

typedef struct {
    /* Parameters (SI). Names equal the FMU variable names. */
    double J_m, f_m, K_s, J_l, f_l, r, arm_length;
    int32_t encoder_counts_per_rev;
    double q_m_start, q_l_start, v_m_start, v_l_start;
    /* Optional effects (0 = off, except the shape parameters stribeck_velocity, stribeck_shape, hysteresis_stiffness,
     * hysteresis_exponent, hardening_exponent, hardening_deflection, phase). */
    double b_m, b_l, stribeck_ratio, stribeck_velocity, friction_asymmetry, hardening;
    double hysteresis_torque, hysteresis_stiffness, kinematic_error, kinematic_error_phase, viscous_asymmetry;
    double kinematic_error_4, kinematic_error_4_phase, stribeck_shape, hysteresis_exponent;
    double hardening_exponent, hardening_deflection;

    /* Input: motor torque [N m], held constant over a communication step. */
    double motor_torque;

    /* Continuous and discrete state. */
    double time;
    double q_m, q_l, v_m, v_l;
    int32_t motor_stuck, load_stuck;   /* 1 while the body sticks (its velocity is then exactly 0) */
    int32_t motor_dir, load_dir;       /* +1 / -1: slip direction while slipping */
    double input_work, friction_work;  /* [J], accumulated exactly per segment (quadrature with effects) */
    double hysteresis_state;           /* z [N m] of the Dahl element (also an output) */
    int32_t hyst_dir;                  /* +1 / -1: direction of twisting on the current hysteresis branch */
    double hyst_d0, hyst_z0;           /* branch anchor: deflection and z where the branch started */
    int64_t event_count;               /* switching events handled since initialization */
    double model_evaluations;          /* the doSteps' work since initialization (a local variable; "work budget") */

    /* Outputs derived from the state (refreshed after every change). */
    double spring_torque, arm_position, deflection, motor_friction_torque, load_friction_torque;
    int32_t encoder_count;
} HDModel;

/* Causality of a value reference, as in the variable table. */
typedef enum { HD_UNKNOWN = 0, HD_INDEPENDENT, HD_PARAMETER, HD_INPUT, HD_OUTPUT, HD_LOCAL } HDCausality;
typedef enum { HD_REAL = 0, HD_INTEGER, HD_BOOLEAN } HDType;

void hd_set_defaults(HDModel *m);
HDCausality hd_causality(uint32_t vr, HDType type);

/* Accessors by value reference. On failure they write a message naming the variable (and the allowed range)
 * into err and return HD_RANGE (a value outside its range) or HD_ERROR (an unknown or not settable variable); the
 * model is left unchanged. */
HDStatus hd_get_real(const HDModel *m, uint32_t vr, double *value, char *err, size_t errlen);
HDStatus hd_get_integer(const HDModel *m, uint32_t vr, int32_t *value, char *err, size_t errlen);
HDStatus hd_get_boolean(const HDModel *m, uint32_t vr, int *value, char *err, size_t errlen);
HDStatus hd_set_real(HDModel *m, uint32_t vr, double value, char *err, size_t errlen);
HDStatus hd_set_integer(HDModel *m, uint32_t vr, int32_t value, char *err, size_t errlen);

/* Checks every parameter, then sets the state from the *_start parameters at time t0. */
HDStatus hd_initialize(HDModel *m, double t0, char *err, size_t errlen);

/* A snapshot of an instance (FMU state): the model plus the FMI glue's phase and start time.
 *
 * Serialized field by field (no struct padding, every byte written): a header (magic, format, payload size, a hash
 * of this build's instantiation token) and the fields in the order of the variable table, then the internal state.
 * For the same platform and the same FMU build only, which the header lets hd_snapshot_read check. A state read
 * back is validated like parameters before it is accepted (hd_snapshot_check): every parameter and the input in its
 * range, every number finite, the phase and the stick/slip modes valid enum values, a stuck body at rest. */
typedef struct {
    HDModel model;
    int32_t phase; /* HDPhase */
    double start_time;
} HDSnapshot;

size_t hd_snapshot_bytes(void);
void hd_snapshot_write(const HDSnapshot *s, unsigned char *bytes);
HDStatus hd_snapshot_read(const unsigned char *bytes, size_t size, HDSnapshot *s, char *err, size_t errlen);
HDStatus hd_snapshot_check(const HDSnapshot *s, char *err, size_t errlen);

/* Work budget of one doStep, in evaluations of the model's equations (one closed-form state evaluation, or one
 * right-hand side of the general propagator: a substep is seven). It bounds the CPU time of every doStep, for any
 * step size and any state that passed the checks; see model.c, "work budget". */
#define HD_WORK_BUDGET 2000000LL

/* What one doStep did (for the logSteps log category). */
typedef struct {
    int64_t events; /* switching events handled */
    int64_t work;   /* evaluations of the model's equations */
} HDStepStats;

/* Advances the plant by h seconds with the current motor_torque held. Exact stick-slip inside.
 * On error the model is left as it was before the call. stats may be NULL. */
HDStatus hd_do_step(HDModel *m, double h, HDStepStats *stats, char *err, size_t errlen);

/* Debug logging, the same in both FMI versions: the log mask after SetDebugLogging(on, n, categories). With no
 * categories, on sets every category and off clears them all; with categories, on sets exactly those and off clears
 * those. Returns -1 (mask unchanged) and the offending name in *bad when a category is unknown or NULL. */
int hd_log_mask(unsigned *mask, int on, size_t n, const char *const categories[], const char **bad);
const char *hd_log_category(unsigned bit); /* the category's name */

/* Is a call allowed in ``phase`` (bit ``phase`` of ``mask``)? If not, ``msg`` says why, with the phase's name in the
 * FMI version's words (``names``). */
int hd_phase_allows(HDPhase phase, unsigned mask, const char *const names[HD_PHASE_COUNT], char *msg, size_t n);

#endif
