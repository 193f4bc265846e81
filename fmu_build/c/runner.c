/* A tight co-simulation loop over an FMU's own FMI 2 / FMI 3 functions, for Python importers (ident.Plant).
 *
 * This is importer code, not model code: it receives the FMU's fmiXSetReal / fmiXDoStep / fmiXGetReal function
 * pointers (as loaded by fmpy) and calls them once per sample, so that simulating a long log does not pay Python's
 * per-call overhead. Input u[k] is held over the k-th step of dt; out receives n_out outputs after every step.
 * Returns 0, or k + 1 when the FMU refused step k (its status > warning).
 */
#include <stdbool.h>
#include <stddef.h>

typedef int (*set2_t)(void *, const unsigned *, size_t, const double *);
typedef int (*step2_t)(void *, double, double, int);
typedef int (*get2_t)(void *, const unsigned *, size_t, double *);

typedef int (*set3_t)(void *, const unsigned *, size_t, const double *, size_t);
typedef int (*step3_t)(void *, double, double, bool, bool *, bool *, bool *, double *);
typedef int (*get3_t)(void *, const unsigned *, size_t, double *, size_t);

long hd_run_fmi2(void *set, void *step, void *get, void *c, unsigned vr_in, const unsigned *vr_out, size_t n_out,
                 const double *u, size_t n, double t0, double dt, double *out) {
    double t = t0;
    for (size_t k = 0; k < n; ++k) {
        if (((set2_t)set)(c, &vr_in, 1, &u[k]) > 1) return (long)k + 1;
        if (((step2_t)step)(c, t, dt, 1) > 1) return (long)k + 1;
        if (((get2_t)get)(c, vr_out, n_out, &out[k * n_out]) > 1) return (long)k + 1;
        t += dt;
    }
    return 0;
}

long hd_run_fmi3(void *set, void *step, void *get, void *c, unsigned vr_in, const unsigned *vr_out, size_t n_out,
                 const double *u, size_t n, double t0, double dt, double *out) {
    double t = t0, last = 0.0;
    bool event = false, terminate = false, early = false;
    for (size_t k = 0; k < n; ++k) {
        if (((set3_t)set)(c, &vr_in, 1, &u[k], 1) > 1) return (long)k + 1;
        if (((step3_t)step)(c, t, dt, true, &event, &terminate, &early, &last) > 1) return (long)k + 1;
        if (((get3_t)get)(c, vr_out, n_out, &out[k * n_out], n_out) > 1) return (long)k + 1;
        t += dt;
    }
    return 0;
}
