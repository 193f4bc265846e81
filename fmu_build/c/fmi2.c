/* FMI 2.0 co-simulation glue for the HarmonicDrive model: no physics here, see model.c.
 *
 * Status semantics (FMI 2.0.4, section 2.1.3): a parameter or input value outside its allowed range is refused with
 * fmi2Discard and nothing changes (the standard's suggestion for a setter's range check); every other failure
 * returns fmi2Error and puts the instance into the state "error", where only the calls the standard's table allows
 * for it work: fmi2Get{Real,Integer,Boolean,String} (values for debugging only), fmi2SetDebugLogging, fmi2Reset,
 * fmi2FreeInstance and the FMU state functions (fmi2SetFMUstate of a state saved before the error resumes from it).
 * Status getters answer fmi2Discard for a status this FMU cannot give (it never returns fmi2Pending).
 * Log categories: see the <LogCategories> of the modelDescription (generated from fmu_build/variables.py). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model.h"

typedef struct {
    HDModel model;
    HDPhase phase;
    double start_time;
    char *name;
    fmi2CallbackFunctions cb;
    unsigned log_mask; /* bit HD_LOG_<category> set: messages of that category go to the logger */
} Instance;


static const char *const PHASE_NAME[HD_PHASE_COUNT] = {"instantiated", "initializationMode", "stepComplete",
                                                       "terminated", "error"};

static void log_msg(Instance *in, fmi2Status status, unsigned category, const char *fmt, ...) {
    if (!in->cb.logger || !(in->log_mask & (1u << category))) return;
    char buf[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    /* The message is passed as the format itself (with '%' doubled), so that importers whose logger cannot
     * expand C varargs (e.g. ctypes callbacks) still receive the whole text. */
    char fmt_safe[1024];
    size_t j = 0;
    for (size_t i = 0; buf[i] && j + 2 < sizeof fmt_safe; ++i) {
        if (buf[i] == '%') fmt_safe[j++] = '%';
        fmt_safe[j++] = buf[i];
    }
    fmt_safe[j] = '\0';
    in->cb.logger(in->cb.componentEnvironment, in->name, status, hd_log_category(category), fmt_safe);
}

/* fmi2Error: the instance enters the state "error" (the simulation cannot be continued with it). */
static fmi2Status fail(Instance *in, const char *where, const char *msg) {
    log_msg(in, fmi2Error, HD_LOG_logStatusError, "%s: %s", where, msg);
    in->phase = HD_PHASE_ERROR;
    return fmi2Error;
}

/* fmi2Discard: a value outside its range was not taken; nothing changed and the simulation can continue. */
static fmi2Status discard(Instance *in, const char *where, const char *msg) {
    log_msg(in, fmi2Discard, HD_LOG_logStatusDiscard, "%s: %s", where, msg);
    return fmi2Discard;
}

/* A call allowed in the instance's phase (``mask``), and with its arrays given; else fail() with the reason. */
static int allowed(Instance *in, const char *where, unsigned mask) {
    char msg[128];
    return hd_phase_allows(in->phase, mask, PHASE_NAME, msg, sizeof msg) || (fail(in, where, msg), 0);
}

static int arrays(Instance *in, const char *where, size_t n, const void *vr, const void *values) {
    return n == 0 || (vr && values) || (fail(in, where, "NULL array of value references or values"), 0);
}

#define M_INST (1u << HD_PHASE_INSTANTIATED)
#define M_INIT (1u << HD_PHASE_INITIALIZATION)
#define M_STEP (1u << HD_PHASE_STEP)
#define M_TERM (1u << HD_PHASE_TERMINATED)
#define M_ERR (1u << HD_PHASE_ERROR)
#define M_ANY (M_INST | M_INIT | M_STEP | M_TERM | M_ERR)

/* Every function taking an instance: NULL is refused (there is nobody to log to). */
#define INSTANCE() \
    Instance *in = (Instance *)c; \
    if (!in) return fmi2Error

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }


/* loggingOn with no categories: all of them; with categories: exactly those. Off with no categories: none; off
 * with categories: those are switched off. */
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    INSTANCE();
    if (n > 0 && !cats) return fail(in, "fmi2SetDebugLogging", "NULL categories");
    const char *bad = NULL;
    if (hd_log_mask(&in->log_mask, on, n, cats, &bad) != 0) {
        char msg[256];
        snprintf(msg, sizeof msg, "unknown log category \"%s\" (this FMU has: %s)", bad, HD_LOG_CATEGORY_LIST);
        return fail(in, "fmi2SetDebugLogging", msg);
    }
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resource_location,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible, fmi2Boolean logging_on) {
    (void)resource_location; (void)visible;
    if (!functions || !functions->allocateMemory || !functions->freeMemory) return NULL;
    if (type != fmi2CoSimulation || !guid || strcmp(guid, HD_INSTANTIATION_TOKEN) != 0) {
        if (functions->logger)
            functions->logger(functions->componentEnvironment, name, fmi2Error, "logStatusError",
                              "fmi2Instantiate: %s", type != fmi2CoSimulation ? "only co-simulation is supported"
                                                                               : "GUID does not match this FMU");
        return NULL;
    }
    Instance *in = (Instance *)functions->allocateMemory(1, sizeof(Instance));
    if (!in) return NULL;
    memset(in, 0, sizeof *in);
    in->cb = *functions;
    /* Errors are always reported (FMI 2: "logger was called"); loggingOn adds the default set (Discard). */
    in->log_mask = (1u << HD_LOG_logStatusError) | (logging_on ? HD_LOG_DEFAULT_MASK : 0u);
    const char *nm = name && *name ? name : "HarmonicDrive";
    in->name = (char *)functions->allocateMemory(strlen(nm) + 1, 1);
    if (!in->name) { functions->freeMemory(in); return NULL; }
    strcpy(in->name, nm);
    hd_set_defaults(&in->model);
    in->phase = HD_PHASE_INSTANTIATED;
    return in;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *in = (Instance *)c;
    if (!in) return;
    in->cb.freeMemory(in->name);
    in->cb.freeMemory(in);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tol_defined, fmi2Real tol, fmi2Real start_time,
                               fmi2Boolean stop_defined, fmi2Real stop_time) {
    INSTANCE();
    (void)tol_defined; (void)tol; (void)stop_defined; (void)stop_time;
    if (!allowed(in, "fmi2SetupExperiment", M_INST)) return fmi2Error;
    if (!isfinite(start_time)) {
        char msg[128];
        snprintf(msg, sizeof msg, "startTime = %g s must be finite", start_time);
        return fail(in, "fmi2SetupExperiment", msg);
    }
    in->start_time = start_time;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    INSTANCE();
    if (!allowed(in, "fmi2EnterInitializationMode", M_INST)) return fmi2Error;
    in->phase = HD_PHASE_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    INSTANCE();
    char err[256];
    if (!allowed(in, "fmi2ExitInitializationMode", M_INIT)) return fmi2Error;
    if (hd_initialize(&in->model, in->start_time, err, sizeof err) != HD_OK)
        return fail(in, "fmi2ExitInitializationMode", err);
    in->phase = HD_PHASE_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    INSTANCE();
    if (!allowed(in, "fmi2Terminate", M_STEP)) return fmi2Error;
    in->phase = HD_PHASE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    INSTANCE();
    hd_set_defaults(&in->model);
    in->start_time = 0.0;
    in->phase = HD_PHASE_INSTANTIATED;
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    INSTANCE();
    char err[256];
    if (!allowed(in, "fmi2GetReal", M_ANY) || !arrays(in, "fmi2GetReal", n, vr, value)) return fmi2Error;
    for (size_t i = 0; i < n; ++i)
        if (hd_get_real(&in->model, vr[i], &value[i], err, sizeof err) != HD_OK) return fail(in, "fmi2GetReal", err);
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer value[]) {
    INSTANCE();
    char err[256];
    int32_t v;
    if (!allowed(in, "fmi2GetInteger", M_ANY) || !arrays(in, "fmi2GetInteger", n, vr, value)) return fmi2Error;
    for (size_t i = 0; i < n; ++i) {
        if (hd_get_integer(&in->model, vr[i], &v, err, sizeof err) != HD_OK) return fail(in, "fmi2GetInteger", err);
        value[i] = v;
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean value[]) {
    INSTANCE();
    char err[256];
    int v;
    if (!allowed(in, "fmi2GetBoolean", M_ANY) || !arrays(in, "fmi2GetBoolean", n, vr, value)) return fmi2Error;
    for (size_t i = 0; i < n; ++i) {
        if (hd_get_boolean(&in->model, vr[i], &v, err, sizeof err) != HD_OK) return fail(in, "fmi2GetBoolean", err);
        value[i] = v ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String value[]) {
    INSTANCE();
    (void)vr; (void)value;
    if (!allowed(in, "fmi2GetString", M_ANY)) return fmi2Error;
    return n == 0 ? fmi2OK : fail(in, "fmi2GetString", "the model has no String variables");
}

/* Parameters may be set before initialization ends; the input at any time before termination. */
static int settable(Instance *in, const char *where, HDCausality causality) {
    unsigned mask = causality == HD_INPUT ? (M_INST | M_INIT | M_STEP) : (M_INST | M_INIT);
    return allowed(in, where, mask);
}

/* A refused value: Discard for a value outside its range, Error (and the error state) for anything else. */
static fmi2Status refused(Instance *in, const char *where, HDStatus status, const char *err) {
    return status == HD_RANGE ? discard(in, where, err) : fail(in, where, err);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    INSTANCE();
    char err[256];
    if (!arrays(in, "fmi2SetReal", n, vr, value)) return fmi2Error;
    for (size_t i = 0; i < n; ++i) {
        if (!settable(in, "fmi2SetReal", hd_causality(vr[i], HD_REAL))) return fmi2Error;
        HDStatus s = hd_set_real(&in->model, vr[i], value[i], err, sizeof err);
        if (s != HD_OK) return refused(in, "fmi2SetReal", s, err);
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[]) {
    INSTANCE();
    char err[256];
    if (!arrays(in, "fmi2SetInteger", n, vr, value)) return fmi2Error;
    for (size_t i = 0; i < n; ++i) {
        if (!settable(in, "fmi2SetInteger", hd_causality(vr[i], HD_INTEGER))) return fmi2Error;
        HDStatus s = hd_set_integer(&in->model, vr[i], value[i], err, sizeof err);
        if (s != HD_OK) return refused(in, "fmi2SetInteger", s, err);
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean value[]) {
    INSTANCE();
    (void)vr; (void)value;
    if (!allowed(in, "fmi2SetBoolean", M_INST | M_INIT | M_STEP)) return fmi2Error;
    return n == 0 ? fmi2OK : fail(in, "fmi2SetBoolean", "the model has no settable Boolean variables");
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String value[]) {
    INSTANCE();
    (void)vr; (void)value;
    if (!allowed(in, "fmi2SetString", M_INST | M_INIT | M_STEP)) return fmi2Error;
    return n == 0 ? fmi2OK : fail(in, "fmi2SetString", "the model has no String variables");
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    INSTANCE();
    if (!state) return fail(in, "fmi2GetFMUstate", "NULL state pointer");
    HDSnapshot *s = (HDSnapshot *)*state;
    if (!s) {
        s = (HDSnapshot *)in->cb.allocateMemory(1, sizeof(HDSnapshot)); /* zeroed, padding included */
        if (!s) return fail(in, "fmi2GetFMUstate", "out of memory");
    }
    s->model = in->model;
    s->phase = in->phase;
    s->start_time = in->start_time;
    *state = s;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    INSTANCE();
    char err[256];
    const HDSnapshot *s = (const HDSnapshot *)state;
    if (!s) return fail(in, "fmi2SetFMUstate", "NULL state");
    if (hd_snapshot_check(s, err, sizeof err) != HD_OK) return fail(in, "fmi2SetFMUstate", err);
    in->model = s->model;
    in->phase = (HDPhase)s->phase;
    in->start_time = s->start_time;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    INSTANCE();
    if (state && *state) {
        in->cb.freeMemory(*state);
        *state = NULL;
    }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    INSTANCE();
    (void)state;
    if (!size) return fail(in, "fmi2SerializedFMUstateSize", "NULL size pointer");
    *size = hd_snapshot_bytes();
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[], size_t size) {
    INSTANCE();
    if (!state || !bytes || size < hd_snapshot_bytes())
        return fail(in, "fmi2SerializeFMUstate", "NULL state or buffer, or buffer too small");
    hd_snapshot_write((const HDSnapshot *)state, (unsigned char *)bytes);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state) {
    INSTANCE();
    char err[256];
    HDSnapshot snap;
    if (!state) return fail(in, "fmi2DeSerializeFMUstate", "NULL state pointer");
    if (hd_snapshot_read((const unsigned char *)bytes, size, &snap, err, sizeof err) != HD_OK)
        return fail(in, "fmi2DeSerializeFMUstate", err);
    if (!*state) {
        *state = in->cb.allocateMemory(1, sizeof(HDSnapshot));
        if (!*state) return fail(in, "fmi2DeSerializeFMUstate", "out of memory");
    }
    *(HDSnapshot *)*state = snap;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real du[], fmi2Real dz[]) {
    INSTANCE();
    (void)u; (void)nu; (void)z; (void)nz; (void)du; (void)dz;
    return fail(in, "fmi2GetDirectionalDerivative", "not provided (providesDirectionalDerivative=false)");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    INSTANCE();
    (void)vr; (void)n; (void)order; (void)value;
    return fail(in, "fmi2SetRealInputDerivatives", "not supported (canInterpolateInputs=false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real value[]) {
    INSTANCE();
    (void)vr; (void)n; (void)order; (void)value;
    return fail(in, "fmi2GetRealOutputDerivatives", "not supported (maxOutputDerivativeOrder=0)");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean new_step) {
    INSTANCE();
    char err[256];
    HDStepStats st;
    (void)t; (void)new_step;
    if (!allowed(in, "fmi2DoStep", M_STEP)) return fmi2Error;
    if (hd_do_step(&in->model, h, &st, err, sizeof err) != HD_OK) return fail(in, "fmi2DoStep", err);
    log_msg(in, fmi2OK, HD_LOG_logSteps, "fmi2DoStep: %.17g s + %g s: %lld switching events, %lld model evaluations "
            "(budget %lld)", t, h, (long long)st.events, (long long)st.work, HD_WORK_BUDGET);
    return fmi2OK;
}

/* Only while a step is in progress (after fmi2Pending), which never happens: the call is not allowed. */
fmi2Status fmi2CancelStep(fmi2Component c) {
    INSTANCE();
    return fail(in, "fmi2CancelStep", "must not be called: fmi2DoStep never returns fmi2Pending");
}

/* FMI 2.0, 4.2.3: "If a status is required which cannot be retrieved by the slave it returns fmi2Discard". This
 * FMU knows only the last successful time (its current time) and that it never asks to terminate. */
static fmi2Status no_status(Instance *in, const char *where, fmi2StatusKind s) {
    char msg[160];
    snprintf(msg, sizeof msg, "status kind %d is not available (fmi2DoStep never returns fmi2Pending or "
                              "fmi2Discard)", (int)s);
    return discard(in, where, msg);
}

#define STATUS_CALL(where) \
    INSTANCE(); \
    if (!allowed(in, where, M_STEP | M_TERM)) return fmi2Error; \
    if (!value) return fail(in, where, "NULL value pointer")

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    STATUS_CALL("fmi2GetStatus");
    return no_status(in, "fmi2GetStatus", s);
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    STATUS_CALL("fmi2GetRealStatus");
    if (s == fmi2LastSuccessfulTime) { *value = in->model.time; return fmi2OK; }
    return no_status(in, "fmi2GetRealStatus", s);
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    STATUS_CALL("fmi2GetIntegerStatus");
    return no_status(in, "fmi2GetIntegerStatus", s);
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    STATUS_CALL("fmi2GetBooleanStatus");
    if (s == fmi2Terminated) { *value = fmi2False; return fmi2OK; }
    return no_status(in, "fmi2GetBooleanStatus", s);
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    STATUS_CALL("fmi2GetStringStatus");
    return no_status(in, "fmi2GetStringStatus", s);
}
