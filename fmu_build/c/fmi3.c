/* FMI 3.0 co-simulation glue for the HarmonicDrive model: no physics here, see model.c.
 *
 * Status semantics (FMI 3.0, 2.2.3 and 2.3.1): a parameter or input value outside its allowed range is refused with
 * fmi3Discard and nothing changes (the standard's example for fmi3Discard: "handling of min/max violation"); every
 * other failure returns fmi3Error, and "if any function called in super state FMU State Setable returns fmi3Error,
 * the FMU enters state Terminated": then only fmi3Get{VariableType} (values for debugging only),
 * fmi3SetDebugLogging, fmi3Reset, fmi3FreeInstance and the FMU state functions work (fmi3SetFMUState of a state saved
 * before the error resumes from it). With loggingOn = false "any logging is disabled"; loggingOn = true enables the
 * categories that explain Error and Discard. Log categories: see the <LogCategories> of the modelDescription. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "model.h"

typedef struct {
    HDModel model;
    HDPhase phase; /* HD_PHASE_ERROR: Terminated, entered through an error */
    double start_time;
    char *name;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
    unsigned log_mask; /* bit HD_LOG_<category> set: messages of that category go to logMessage */
} Instance;

#define M_INST (1u << HD_PHASE_INSTANTIATED)
#define M_INIT (1u << HD_PHASE_INITIALIZATION)
#define M_STEP (1u << HD_PHASE_STEP)
#define M_TERM (1u << HD_PHASE_TERMINATED)
#define M_ERR (1u << HD_PHASE_ERROR)
#define M_ANY (M_INST | M_INIT | M_STEP | M_TERM | M_ERR)
#define M_SET (M_INST | M_INIT | M_STEP)


static const char *const PHASE_NAME[HD_PHASE_COUNT] = {"Instantiated", "Initialization Mode", "Step Mode",
                                                       "Terminated", "Terminated after an error"};

static void log_msg(Instance *in, fmi3Status status, unsigned category, const char *fmt, ...) {
    if (!in->log || !(in->log_mask & (1u << category))) return;
    char buf[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    in->log(in->env, status, hd_log_category(category), buf);
}

/* fmi3Error: the instance enters Terminated (HD_PHASE_ERROR). */
static fmi3Status fail(Instance *in, const char *where, const char *msg) {
    log_msg(in, fmi3Error, HD_LOG_logStatusError, "%s: %s", where, msg);
    in->phase = HD_PHASE_ERROR;
    return fmi3Error;
}

/* fmi3Discard: "the FMU is in the same state as before the call ... the computation can continue". */
static fmi3Status discard(Instance *in, const char *where, const char *msg) {
    log_msg(in, fmi3Discard, HD_LOG_logStatusDiscard, "%s: %s", where, msg);
    return fmi3Discard;
}

/* A call allowed in the instance's phase (``mask``), and with its arrays given; else fail() with the reason. */
static int allowed(Instance *in, const char *where, unsigned mask) {
    char msg[128];
    return hd_phase_allows(in->phase, mask, PHASE_NAME, msg, sizeof msg) || (fail(in, where, msg), 0);
}

static int arrays(Instance *in, const char *where, size_t n, const void *vr, const void *values) {
    return n == 0 || (vr && values) || (fail(in, where, "NULL array of value references or values"), 0);
}

/* Every function taking an instance: NULL is refused (there is nobody to log to). */
#define INSTANCE(c) \
    Instance *in = (Instance *)(c); \
    if (!in) return fmi3Error

const char *fmi3GetVersion(void) { return fmi3Version; }


/* loggingOn with no categories: all of them; with categories: exactly those. Off with no categories: none; off
 * with categories: those are switched off. */
fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean on, size_t n, const fmi3String cats[]) {
    INSTANCE(c);
    if (n > 0 && !cats) return fail(in, "fmi3SetDebugLogging", "NULL categories");
    const char *bad = NULL;
    if (hd_log_mask(&in->log_mask, on, n, cats, &bad) != 0) {
        char msg[256];
        snprintf(msg, sizeof msg, "unknown log category \"%s\" (this FMU has: %s)", bad, HD_LOG_CATEGORY_LIST);
        return fail(in, "fmi3SetDebugLogging", msg);
    }
    return fmi3OK;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String name, fmi3String token, fmi3String resource_path,
                                         fmi3Boolean visible, fmi3Boolean logging_on, fmi3Boolean event_mode_used,
                                         fmi3Boolean early_return_allowed, const fmi3ValueReference required[],
                                         size_t n_required, fmi3InstanceEnvironment env,
                                         fmi3LogMessageCallback log, fmi3IntermediateUpdateCallback update) {
    (void)resource_path; (void)visible; (void)early_return_allowed; (void)required; (void)n_required; (void)update;
    if (!token || strcmp(token, HD_INSTANTIATION_TOKEN) != 0 || event_mode_used) {
        if (log)
            log(env, fmi3Error, "logStatusError",
                event_mode_used ? "fmi3InstantiateCoSimulation: event mode is not supported"
                                : "fmi3InstantiateCoSimulation: instantiation token does not match this FMU");
        return NULL;
    }
    Instance *in = (Instance *)calloc(1, sizeof(Instance));
    if (!in) return NULL;
    const char *nm = name && *name ? name : "HarmonicDrive";
    in->name = (char *)malloc(strlen(nm) + 1);
    if (!in->name) { free(in); return NULL; }
    strcpy(in->name, nm);
    in->env = env;
    in->log = log;
    in->log_mask = logging_on ? HD_LOG_DEFAULT_MASK : 0u;
    hd_set_defaults(&in->model);
    in->phase = HD_PHASE_INSTANTIATED;
    return in;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String name, fmi3String token, fmi3String resource_path,
                                          fmi3Boolean visible, fmi3Boolean logging_on,
                                          fmi3InstanceEnvironment env, fmi3LogMessageCallback log) {
    (void)name; (void)token; (void)resource_path; (void)visible; (void)logging_on;
    if (log) log(env, fmi3Error, "logStatusError", "only co-simulation is supported");
    return NULL;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String name, fmi3String token, fmi3String resource_path,
                                               fmi3Boolean visible, fmi3Boolean logging_on,
                                               fmi3InstanceEnvironment env, fmi3LogMessageCallback log,
                                               fmi3ClockUpdateCallback clock_update,
                                               fmi3LockPreemptionCallback lock,
                                               fmi3UnlockPreemptionCallback unlock) {
    (void)name; (void)token; (void)resource_path; (void)visible; (void)logging_on;
    (void)clock_update; (void)lock; (void)unlock;
    if (log) log(env, fmi3Error, "logStatusError", "only co-simulation is supported");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance c) {
    Instance *in = (Instance *)c;
    if (!in) return;
    free(in->name);
    free(in);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance c, fmi3Boolean tol_defined, fmi3Float64 tol,
                                       fmi3Float64 start_time, fmi3Boolean stop_defined, fmi3Float64 stop_time) {
    INSTANCE(c);
    (void)tol_defined; (void)tol; (void)stop_defined; (void)stop_time;
    if (!allowed(in, "fmi3EnterInitializationMode", M_INST)) return fmi3Error;
    if (!isfinite(start_time)) {
        char msg[128];
        snprintf(msg, sizeof msg, "startTime = %g s must be finite", start_time);
        return fail(in, "fmi3EnterInitializationMode", msg);
    }
    in->start_time = start_time;
    in->phase = HD_PHASE_INITIALIZATION;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance c) {
    INSTANCE(c);
    char err[256];
    if (!allowed(in, "fmi3ExitInitializationMode", M_INIT)) return fmi3Error;
    if (hd_initialize(&in->model, in->start_time, err, sizeof err) != HD_OK)
        return fail(in, "fmi3ExitInitializationMode", err);
    in->phase = HD_PHASE_STEP;
    return fmi3OK;
}

fmi3Status fmi3EnterStepMode(fmi3Instance c) {
    INSTANCE(c);
    return allowed(in, "fmi3EnterStepMode", M_STEP) ? fmi3OK : fmi3Error; /* already in Step Mode: a no-op */
}

fmi3Status fmi3Terminate(fmi3Instance c) {
    INSTANCE(c);
    if (!allowed(in, "fmi3Terminate", M_STEP)) return fmi3Error;
    in->phase = HD_PHASE_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance c) {
    INSTANCE(c);
    hd_set_defaults(&in->model);
    in->start_time = 0.0;
    in->phase = HD_PHASE_INSTANTIATED;
    return fmi3OK;
}

/* Scalar variables only: nValues must equal nValueReferences. */
static int scalar_counts(Instance *in, const char *where, size_t nvr, size_t nv) {
    if (nvr == nv) return 1;
    char msg[128];
    snprintf(msg, sizeof msg, "nValues (%zu) must equal nValueReferences (%zu)", nv, nvr);
    fail(in, where, msg);
    return 0;
}

fmi3Status fmi3GetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 v[], size_t nv) {
    INSTANCE(c);
    char err[256];
    if (!allowed(in, "fmi3GetFloat64", M_ANY) || !scalar_counts(in, "fmi3GetFloat64", nvr, nv) || !arrays(in, "fmi3GetFloat64", nvr, vr, v))
        return fmi3Error;
    for (size_t i = 0; i < nvr; ++i)
        if (hd_get_real(&in->model, vr[i], &v[i], err, sizeof err) != HD_OK) return fail(in, "fmi3GetFloat64", err);
    return fmi3OK;
}

fmi3Status fmi3GetInt32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Int32 v[], size_t nv) {
    INSTANCE(c);
    char err[256];
    if (!allowed(in, "fmi3GetInt32", M_ANY) || !scalar_counts(in, "fmi3GetInt32", nvr, nv) || !arrays(in, "fmi3GetInt32", nvr, vr, v))
        return fmi3Error;
    for (size_t i = 0; i < nvr; ++i)
        if (hd_get_integer(&in->model, vr[i], &v[i], err, sizeof err) != HD_OK) return fail(in, "fmi3GetInt32", err);
    return fmi3OK;
}

fmi3Status fmi3GetBoolean(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Boolean v[], size_t nv) {
    INSTANCE(c);
    char err[256];
    int b;
    if (!allowed(in, "fmi3GetBoolean", M_ANY) || !scalar_counts(in, "fmi3GetBoolean", nvr, nv) || !arrays(in, "fmi3GetBoolean", nvr, vr, v))
        return fmi3Error;
    for (size_t i = 0; i < nvr; ++i) {
        if (hd_get_boolean(&in->model, vr[i], &b, err, sizeof err) != HD_OK) return fail(in, "fmi3GetBoolean", err);
        v[i] = b ? fmi3True : fmi3False;
    }
    return fmi3OK;
}

static int settable(Instance *in, const char *where, HDCausality causality) {
    unsigned mask = causality == HD_INPUT ? (M_INST | M_INIT | M_STEP) : (M_INST | M_INIT);
    return allowed(in, where, mask);
}

/* A refused value: Discard for a value outside its range, Error (and Terminated) for anything else. */
static fmi3Status refused(Instance *in, const char *where, HDStatus status, const char *err) {
    return status == HD_RANGE ? discard(in, where, err) : fail(in, where, err);
}

fmi3Status fmi3SetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 v[],
                          size_t nv) {
    INSTANCE(c);
    char err[256];
    if (!scalar_counts(in, "fmi3SetFloat64", nvr, nv) || !arrays(in, "fmi3SetFloat64", nvr, vr, v)) return fmi3Error;
    for (size_t i = 0; i < nvr; ++i) {
        if (!settable(in, "fmi3SetFloat64", hd_causality(vr[i], HD_REAL))) return fmi3Error;
        HDStatus s = hd_set_real(&in->model, vr[i], v[i], err, sizeof err);
        if (s != HD_OK) return refused(in, "fmi3SetFloat64", s, err);
    }
    return fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Int32 v[], size_t nv) {
    INSTANCE(c);
    char err[256];
    if (!scalar_counts(in, "fmi3SetInt32", nvr, nv) || !arrays(in, "fmi3SetInt32", nvr, vr, v)) return fmi3Error;
    for (size_t i = 0; i < nvr; ++i) {
        if (!settable(in, "fmi3SetInt32", hd_causality(vr[i], HD_INTEGER))) return fmi3Error;
        HDStatus s = hd_set_integer(&in->model, vr[i], v[i], err, sizeof err);
        if (s != HD_OK) return refused(in, "fmi3SetInt32", s, err);
    }
    return fmi3OK;
}

/* Getters and setters of types the model does not have: fine for zero variables (where the call is allowed), an
 * error otherwise. */
#define NO_SUCH_TYPE(fn, ctype, constness, mask) \
    fmi3Status fn(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, constness ctype v[], size_t nv) { \
        INSTANCE(c); \
        (void)vr; (void)v; (void)nv; \
        if (!allowed(in, #fn, mask)) return fmi3Error; \
        return nvr == 0 ? fmi3OK : fail(in, #fn, "the model has no variables of this type"); \
    }
NO_SUCH_TYPE(fmi3GetFloat32, fmi3Float32, , M_ANY)
NO_SUCH_TYPE(fmi3GetInt8, fmi3Int8, , M_ANY)
NO_SUCH_TYPE(fmi3GetUInt8, fmi3UInt8, , M_ANY)
NO_SUCH_TYPE(fmi3GetInt16, fmi3Int16, , M_ANY)
NO_SUCH_TYPE(fmi3GetUInt16, fmi3UInt16, , M_ANY)
NO_SUCH_TYPE(fmi3GetUInt32, fmi3UInt32, , M_ANY)
NO_SUCH_TYPE(fmi3GetInt64, fmi3Int64, , M_ANY)
NO_SUCH_TYPE(fmi3GetUInt64, fmi3UInt64, , M_ANY)
NO_SUCH_TYPE(fmi3GetString, fmi3String, , M_ANY)
NO_SUCH_TYPE(fmi3SetFloat32, fmi3Float32, const, M_SET)
NO_SUCH_TYPE(fmi3SetInt8, fmi3Int8, const, M_SET)
NO_SUCH_TYPE(fmi3SetUInt8, fmi3UInt8, const, M_SET)
NO_SUCH_TYPE(fmi3SetInt16, fmi3Int16, const, M_SET)
NO_SUCH_TYPE(fmi3SetUInt16, fmi3UInt16, const, M_SET)
NO_SUCH_TYPE(fmi3SetUInt32, fmi3UInt32, const, M_SET)
NO_SUCH_TYPE(fmi3SetInt64, fmi3Int64, const, M_SET)
NO_SUCH_TYPE(fmi3SetUInt64, fmi3UInt64, const, M_SET)
NO_SUCH_TYPE(fmi3SetBoolean, fmi3Boolean, const, M_SET)
NO_SUCH_TYPE(fmi3SetString, fmi3String, const, M_SET)

fmi3Status fmi3GetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, size_t sizes[], fmi3Binary v[],
                         size_t nv) {
    INSTANCE(c);
    (void)vr; (void)sizes; (void)v; (void)nv;
    if (!allowed(in, "fmi3GetBinary", M_ANY)) return fmi3Error;
    return nvr == 0 ? fmi3OK : fail(in, "fmi3GetBinary", "the model has no Binary variables");
}

fmi3Status fmi3SetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const size_t sizes[],
                         const fmi3Binary v[], size_t nv) {
    INSTANCE(c);
    (void)vr; (void)sizes; (void)v; (void)nv;
    if (!allowed(in, "fmi3SetBinary", M_SET)) return fmi3Error;
    return nvr == 0 ? fmi3OK : fail(in, "fmi3SetBinary", "the model has no Binary variables");
}

fmi3Status fmi3GetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Clock v[]) {
    INSTANCE(c);
    (void)vr; (void)v;
    return nvr == 0 ? fmi3OK : fail(in, "fmi3GetClock", "the model has no clocks");
}

fmi3Status fmi3SetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock v[]) {
    INSTANCE(c);
    (void)vr; (void)v;
    return nvr == 0 ? fmi3OK : fail(in, "fmi3SetClock", "the model has no clocks");
}

fmi3Status fmi3GetFMUState(fmi3Instance c, fmi3FMUState *state) {
    INSTANCE(c);
    if (!state) return fail(in, "fmi3GetFMUState", "NULL state pointer");
    HDSnapshot *s = (HDSnapshot *)*state;
    if (!s) {
        s = (HDSnapshot *)calloc(1, sizeof(HDSnapshot)); /* zeroed, padding included */
        if (!s) return fail(in, "fmi3GetFMUState", "out of memory");
    }
    s->model = in->model;
    s->phase = in->phase;
    s->start_time = in->start_time;
    *state = s;
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance c, fmi3FMUState state) {
    INSTANCE(c);
    char err[256];
    const HDSnapshot *s = (const HDSnapshot *)state;
    if (!s) return fail(in, "fmi3SetFMUState", "NULL state");
    if (hd_snapshot_check(s, err, sizeof err) != HD_OK) return fail(in, "fmi3SetFMUState", err);
    in->model = s->model;
    in->phase = (HDPhase)s->phase;
    in->start_time = s->start_time;
    return fmi3OK;
}

fmi3Status fmi3FreeFMUState(fmi3Instance c, fmi3FMUState *state) {
    INSTANCE(c);
    (void)in;
    if (state && *state) {
        free(*state);
        *state = NULL;
    }
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance c, fmi3FMUState state, size_t *size) {
    INSTANCE(c);
    (void)state;
    if (!size) return fail(in, "fmi3SerializedFMUStateSize", "NULL size pointer");
    *size = hd_snapshot_bytes();
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance c, fmi3FMUState state, fmi3Byte bytes[], size_t size) {
    INSTANCE(c);
    if (!state || !bytes || size < hd_snapshot_bytes())
        return fail(in, "fmi3SerializeFMUState", "NULL state or buffer, or buffer too small");
    hd_snapshot_write((const HDSnapshot *)state, (unsigned char *)bytes); /* every byte written: no padding */
    return fmi3OK;
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance c, const fmi3Byte bytes[], size_t size, fmi3FMUState *state) {
    INSTANCE(c);
    char err[256];
    HDSnapshot snap;
    if (!state) return fail(in, "fmi3DeserializeFMUState", "NULL state pointer");
    if (hd_snapshot_read((const unsigned char *)bytes, size, &snap, err, sizeof err) != HD_OK)
        return fail(in, "fmi3DeserializeFMUState", err);
    if (!*state) {
        *state = calloc(1, sizeof(HDSnapshot));
        if (!*state) return fail(in, "fmi3DeserializeFMUState", "out of memory");
    }
    *(HDSnapshot *)*state = snap;
    return fmi3OK;
}

fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 t, fmi3Float64 h, fmi3Boolean no_set_prior,
                      fmi3Boolean *event_handling_needed, fmi3Boolean *terminate, fmi3Boolean *early_return,
                      fmi3Float64 *last_successful_time) {
    INSTANCE(c);
    char err[256];
    HDStepStats st;
    (void)no_set_prior;
    if (event_handling_needed) *event_handling_needed = fmi3False;
    if (terminate) *terminate = fmi3False;
    if (early_return) *early_return = fmi3False;
    if (last_successful_time) *last_successful_time = in->model.time;
    if (!allowed(in, "fmi3DoStep", M_STEP)) return fmi3Error;
    if (hd_do_step(&in->model, h, &st, err, sizeof err) != HD_OK) return fail(in, "fmi3DoStep", err);
    if (last_successful_time) *last_successful_time = in->model.time;
    log_msg(in, fmi3OK, HD_LOG_logSteps, "fmi3DoStep: %.17g s + %g s: %lld switching events, %lld model evaluations "
            "(budget %lld)", t, h, (long long)st.events, (long long)st.work, HD_WORK_BUDGET);
    return fmi3OK;
}

/* ---- API parts this co-simulation FMU does not provide (capability flags say so). ---- */
#define UNSUPPORTED(call, ...) \
    fmi3Status call(__VA_ARGS__) { \
        INSTANCE(instance); \
        return fail(in, #call, "not supported by this FMU"); \
    }

UNSUPPORTED(fmi3EnterEventMode, fmi3Instance instance)
UNSUPPORTED(fmi3GetNumberOfVariableDependencies, fmi3Instance instance, fmi3ValueReference vr, size_t *n)
UNSUPPORTED(fmi3GetVariableDependencies, fmi3Instance instance, fmi3ValueReference dependent, size_t e1[],
            fmi3ValueReference ind[], size_t e2[], fmi3DependencyKind kinds[], size_t n)
UNSUPPORTED(fmi3GetDirectionalDerivative, fmi3Instance instance, const fmi3ValueReference u[], size_t nu,
            const fmi3ValueReference k[], size_t nk, const fmi3Float64 seed[], size_t ns, fmi3Float64 sens[],
            size_t nsens)
UNSUPPORTED(fmi3GetAdjointDerivative, fmi3Instance instance, const fmi3ValueReference u[], size_t nu,
            const fmi3ValueReference k[], size_t nk, const fmi3Float64 seed[], size_t ns, fmi3Float64 sens[],
            size_t nsens)
UNSUPPORTED(fmi3EnterConfigurationMode, fmi3Instance instance)
UNSUPPORTED(fmi3ExitConfigurationMode, fmi3Instance instance)
UNSUPPORTED(fmi3GetIntervalDecimal, fmi3Instance instance, const fmi3ValueReference vr[], size_t n, fmi3Float64 iv[],
            fmi3IntervalQualifier q[])
UNSUPPORTED(fmi3GetIntervalFraction, fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
            fmi3UInt64 cnt[], fmi3UInt64 res[], fmi3IntervalQualifier q[])
UNSUPPORTED(fmi3GetShiftDecimal, fmi3Instance instance, const fmi3ValueReference vr[], size_t n, fmi3Float64 s[])
UNSUPPORTED(fmi3GetShiftFraction, fmi3Instance instance, const fmi3ValueReference vr[], size_t n, fmi3UInt64 cnt[],
            fmi3UInt64 res[])
UNSUPPORTED(fmi3SetIntervalDecimal, fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
            const fmi3Float64 iv[])
UNSUPPORTED(fmi3SetIntervalFraction, fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
            const fmi3UInt64 cnt[], const fmi3UInt64 res[])
UNSUPPORTED(fmi3SetShiftDecimal, fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
            const fmi3Float64 s[])
UNSUPPORTED(fmi3SetShiftFraction, fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
            const fmi3UInt64 cnt[], const fmi3UInt64 res[])
UNSUPPORTED(fmi3EvaluateDiscreteStates, fmi3Instance instance)
UNSUPPORTED(fmi3UpdateDiscreteStates, fmi3Instance instance, fmi3Boolean *a, fmi3Boolean *b, fmi3Boolean *c,
            fmi3Boolean *d, fmi3Boolean *e, fmi3Float64 *f)
UNSUPPORTED(fmi3EnterContinuousTimeMode, fmi3Instance instance)
UNSUPPORTED(fmi3CompletedIntegratorStep, fmi3Instance instance, fmi3Boolean a, fmi3Boolean *b, fmi3Boolean *c)
UNSUPPORTED(fmi3SetTime, fmi3Instance instance, fmi3Float64 t)
UNSUPPORTED(fmi3SetContinuousStates, fmi3Instance instance, const fmi3Float64 x[], size_t n)
UNSUPPORTED(fmi3GetContinuousStateDerivatives, fmi3Instance instance, fmi3Float64 dx[], size_t n)
UNSUPPORTED(fmi3GetEventIndicators, fmi3Instance instance, fmi3Float64 z[], size_t n)
UNSUPPORTED(fmi3GetContinuousStates, fmi3Instance instance, fmi3Float64 x[], size_t n)
UNSUPPORTED(fmi3GetNominalsOfContinuousStates, fmi3Instance instance, fmi3Float64 x[], size_t n)
UNSUPPORTED(fmi3GetNumberOfEventIndicators, fmi3Instance instance, size_t *n)
UNSUPPORTED(fmi3GetNumberOfContinuousStates, fmi3Instance instance, size_t *n)
UNSUPPORTED(fmi3GetOutputDerivatives, fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
            const fmi3Int32 orders[], fmi3Float64 v[], size_t nv)
UNSUPPORTED(fmi3ActivateModelPartition, fmi3Instance instance, fmi3ValueReference clock, fmi3Float64 t)
