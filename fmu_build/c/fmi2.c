/* FMI 2.0 co-simulation glue for the HarmonicDrive model: no physics here, see model.c. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model.h"

typedef enum { ST_INSTANTIATED, ST_INITIALIZATION, ST_STEP, ST_TERMINATED, ST_ERROR } Phase;

typedef struct {
    HDModel model;
    Phase phase;
    double start_time;
    char *name;
    fmi2CallbackFunctions cb;
    int logging_on;
} Instance;


static void log_msg(Instance *in, fmi2Status status, const char *category, const char *fmt, ...) {
    if (!in->cb.logger) return;
    if (status == fmi2OK && !in->logging_on) return;
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
    in->cb.logger(in->cb.componentEnvironment, in->name, status, category, fmt_safe);
}

static fmi2Status fail(Instance *in, const char *where, const char *msg) {
    log_msg(in, fmi2Error, "logStatusError", "%s: %s", where, msg);
    return fmi2Error;
}

static int allowed(Instance *in, const char *where, unsigned mask) {
    if (mask & (1u << in->phase)) return 1;
    log_msg(in, fmi2Error, "logStatusError", "%s must not be called in the current state", where);
    return 0;
}
#define M_INST (1u << ST_INSTANTIATED)
#define M_INIT (1u << ST_INITIALIZATION)
#define M_STEP (1u << ST_STEP)
#define M_TERM (1u << ST_TERMINATED)
#define M_ERR (1u << ST_ERROR)
#define M_ANY (M_INST | M_INIT | M_STEP | M_TERM | M_ERR)

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    (void)n; (void)cats;
    ((Instance *)c)->logging_on = on;
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
    in->logging_on = logging_on;
    const char *nm = name ? name : "HarmonicDrive";
    in->name = (char *)functions->allocateMemory(strlen(nm) + 1, 1);
    if (!in->name) { functions->freeMemory(in); return NULL; }
    strcpy(in->name, nm);
    hd_set_defaults(&in->model);
    in->phase = ST_INSTANTIATED;
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
    Instance *in = (Instance *)c;
    (void)tol_defined; (void)tol; (void)stop_defined; (void)stop_time;
    if (!allowed(in, "fmi2SetupExperiment", M_INST)) return fmi2Error;
    in->start_time = start_time;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    Instance *in = (Instance *)c;
    if (!allowed(in, "fmi2EnterInitializationMode", M_INST)) return fmi2Error;
    in->phase = ST_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Instance *in = (Instance *)c;
    char err[256];
    if (!allowed(in, "fmi2ExitInitializationMode", M_INIT)) return fmi2Error;
    if (hd_initialize(&in->model, in->start_time, err, sizeof err) != HD_OK)
        return fail(in, "fmi2ExitInitializationMode", err);
    in->phase = ST_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    Instance *in = (Instance *)c;
    if (!allowed(in, "fmi2Terminate", M_STEP | M_ERR)) return fmi2Error;
    in->phase = ST_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    Instance *in = (Instance *)c;
    hd_set_defaults(&in->model);
    in->start_time = 0.0;
    in->phase = ST_INSTANTIATED;
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Instance *in = (Instance *)c;
    char err[256];
    if (!allowed(in, "fmi2GetReal", M_ANY)) return fmi2Error;
    for (size_t i = 0; i < n; ++i)
        if (hd_get_real(&in->model, vr[i], &value[i], err, sizeof err) != HD_OK) return fail(in, "fmi2GetReal", err);
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer value[]) {
    Instance *in = (Instance *)c;
    char err[256];
    int32_t v;
    if (!allowed(in, "fmi2GetInteger", M_ANY)) return fmi2Error;
    for (size_t i = 0; i < n; ++i) {
        if (hd_get_integer(&in->model, vr[i], &v, err, sizeof err) != HD_OK) return fail(in, "fmi2GetInteger", err);
        value[i] = v;
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean value[]) {
    Instance *in = (Instance *)c;
    char err[256];
    int v;
    if (!allowed(in, "fmi2GetBoolean", M_ANY)) return fmi2Error;
    for (size_t i = 0; i < n; ++i) {
        if (hd_get_boolean(&in->model, vr[i], &v, err, sizeof err) != HD_OK) return fail(in, "fmi2GetBoolean", err);
        value[i] = v ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String value[]) {
    (void)vr; (void)value;
    return n == 0 ? fmi2OK : fail((Instance *)c, "fmi2GetString", "the model has no String variables");
}

/* Parameters may be set before initialization ends; the input at any time before termination. */
static int settable(Instance *in, const char *where, HDCausality causality) {
    unsigned mask = causality == HD_INPUT ? (M_INST | M_INIT | M_STEP) : (M_INST | M_INIT);
    return allowed(in, where, mask);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Instance *in = (Instance *)c;
    char err[256];
    for (size_t i = 0; i < n; ++i) {
        if (!settable(in, "fmi2SetReal", hd_causality(vr[i], HD_REAL))) return fmi2Error;
        if (hd_set_real(&in->model, vr[i], value[i], err, sizeof err) != HD_OK) return fail(in, "fmi2SetReal", err);
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[]) {
    Instance *in = (Instance *)c;
    char err[256];
    for (size_t i = 0; i < n; ++i) {
        if (!settable(in, "fmi2SetInteger", hd_causality(vr[i], HD_INTEGER))) return fmi2Error;
        if (hd_set_integer(&in->model, vr[i], value[i], err, sizeof err) != HD_OK)
            return fail(in, "fmi2SetInteger", err);
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean value[]) {
    (void)vr; (void)value;
    return n == 0 ? fmi2OK : fail((Instance *)c, "fmi2SetBoolean", "the model has no settable Boolean variables");
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String value[]) {
    (void)vr; (void)value;
    return n == 0 ? fmi2OK : fail((Instance *)c, "fmi2SetString", "the model has no String variables");
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    Instance *in = (Instance *)c;
    HDSnapshot *s = (HDSnapshot *)*state;
    if (!s) {
        s = (HDSnapshot *)in->cb.allocateMemory(1, sizeof(HDSnapshot));
        if (!s) return fail(in, "fmi2GetFMUstate", "out of memory");
    }
    s->model = in->model;
    s->phase = in->phase;
    s->start_time = in->start_time;
    *state = s;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    Instance *in = (Instance *)c;
    const HDSnapshot *s = (const HDSnapshot *)state;
    if (!s) return fail(in, "fmi2SetFMUstate", "NULL state");
    in->model = s->model;
    in->phase = (Phase)s->phase;
    in->start_time = s->start_time;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    Instance *in = (Instance *)c;
    if (state && *state) {
        in->cb.freeMemory(*state);
        *state = NULL;
    }
    return fmi2OK;
}

/* Serialized form: magic, size of the snapshot, snapshot bytes. Same platform and FMU build only. */
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    (void)c; (void)state;
    *size = hd_snapshot_bytes();
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[], size_t size) {
    Instance *in = (Instance *)c;
    if (!state || size < hd_snapshot_bytes()) return fail(in, "fmi2SerializeFMUstate", "buffer too small");
    hd_snapshot_write((const HDSnapshot *)state, (unsigned char *)bytes);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state) {
    Instance *in = (Instance *)c;
    char err[256];
    HDSnapshot snap;
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
    (void)u; (void)nu; (void)z; (void)nz; (void)du; (void)dz;
    return fail((Instance *)c, "fmi2GetDirectionalDerivative", "not provided (providesDirectionalDerivative=false)");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)n; (void)order; (void)value;
    return fail((Instance *)c, "fmi2SetRealInputDerivatives", "not supported (canInterpolateInputs=false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)n; (void)order; (void)value;
    return fail((Instance *)c, "fmi2GetRealOutputDerivatives", "not supported (maxOutputDerivativeOrder=0)");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean new_step) {
    Instance *in = (Instance *)c;
    char err[256];
    (void)t; (void)new_step;
    if (!allowed(in, "fmi2DoStep", M_STEP)) return fmi2Error;
    if (hd_do_step(&in->model, h, err, sizeof err) != HD_OK) return fail(in, "fmi2DoStep", err);
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    return fail((Instance *)c, "fmi2CancelStep", "doStep always completes synchronously");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s; (void)value;
    return fail((Instance *)c, "fmi2GetStatus", "no asynchronous steps");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    Instance *in = (Instance *)c;
    if (s == fmi2LastSuccessfulTime) { *value = in->model.time; return fmi2OK; }
    return fail(in, "fmi2GetRealStatus", "unsupported status kind");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s; (void)value;
    return fail((Instance *)c, "fmi2GetIntegerStatus", "unsupported status kind");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    (void)s; (void)value;
    return fail((Instance *)c, "fmi2GetBooleanStatus", "unsupported status kind");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s; (void)value;
    return fail((Instance *)c, "fmi2GetStringStatus", "unsupported status kind");
}
