/* pythonfmu_wrapper.c: the FMI 2.0 binary of every pythonfmu FMU of this project (drivetrain.fmu_build.fmi_wrapper).
 *
 * pythonfmu 0.7.0's export library answers any Python exception with fmi2Fatal and releases the slave
 * object; the next call on that instance dereferences it and crashes the host. It also cannot return fmi2Error
 * from fmi2SetupExperiment or a getter, accepts any call in any state, and crashes on a second fmi2FreeInstance.
 * This wrapper is what the host loads (binaries/linux64/<modelIdentifier>.so). It loads the export library
 * (renamed <modelIdentifier>.pythonfmu-export.so, next to it; RTLD_LOCAL | RTLD_DEEPBIND, found with dladdr;
 * never unloaded) and forwards every call after checking it against the variable table generated from the
 * FMU's final modelDescription.xml (wrapper_table.h) and the FMI 2.0 co-simulation state machine of the
 * Reference FMUs. What it refuses, it refuses with fmi2Error and a logged reason; the state machine's rules and
 * words are written once, in fmu_runtime/native/fmi2_state.h (shared with the native builds' shell fmi2_shell.h):
 *   - unknown or mistyped value references, setting an output or a constant, a fixed parameter after
 *     initialization, a Real parameter that is not a finite number, an Integer outside its declared min/max:
 *     the instance enters its error state (the slave is told through the hidden String variable
 *     WRAPPER_VR_FAIL, so that its outputs become NaN and its "error" output says why);
 *   - calls in the wrong state (fmi2SetupExperiment / fmi2EnterInitializationMode not right after
 *     instantiation or reset, fmi2ExitInitializationMode without enter, fmi2Terminate twice, a set after
 *     fmi2Terminate, a get before fmi2EnterInitializationMode): refused, the state is unchanged;
 *   - fmi2DoStep before initialization, after fmi2Terminate, with a step size <= 0 or not finite, at a
 *     time that is not finite or not where the previous step ended, or in the error state;
 *   - fmi2SetupExperiment with a start time that is not finite or a stop time before it;
 *   - FMU state serialization (not supported: canSerializeFMUstate="false");
 *   - a wrong GUID or a resource path with '%' at fmi2Instantiate (pythonfmu crashes on the latter).
 * After an fmi2Fatal of the export library (a Python exception the slave did not turn into its error state)
 * every later call on that instance is refused with fmi2Error without being forwarded, and fmi2FreeInstance
 * does not forward either (the slave's memory is left to the process end): the host never reaches the
 * released slave. A second fmi2FreeInstance of one instance is harmless.
 */
#define _GNU_SOURCE
#include <ctype.h>
#include <dlfcn.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

enum { C_PARAMETER, C_CALCULATED, C_INPUT, C_OUTPUT, C_LOCAL, C_INDEPENDENT };
enum { V_CONSTANT, V_FIXED, V_TUNABLE, V_DISCRETE, V_CONTINUOUS };

typedef struct {
    fmi2ValueReference vr;
    char type;                  /* 'R' Real, 'I' Integer, 'B' Boolean, 'S' String, 'E' Enumeration */
    int causality, variability;
    int has_min, has_max;
    double min, max;
    const char *name;
} WrapperVar;

/* generated: WRAPPER_MODEL, WRAPPER_GUID, WRAPPER_EXPORT_LIBRARY, WRAPPER_VR_FAIL, WRAPPER_VR_ERROR (-1: none),
 * WRAPPER_N_VARS, WRAPPER_VARS[], WRAPPER_MAX_VR, WRAPPER_ROW[] (value reference -> row, -1 for none) */
#include "wrapper_table.h"

#define MSG_MAX 2048

/* ---- the export library, loaded once per process and never unloaded ---- */

typedef struct {
    fmi2InstantiateTYPE *Instantiate;
    fmi2FreeInstanceTYPE *FreeInstance;
    fmi2SetDebugLoggingTYPE *SetDebugLogging;
    fmi2SetupExperimentTYPE *SetupExperiment;
    fmi2EnterInitializationModeTYPE *EnterInitializationMode;
    fmi2ExitInitializationModeTYPE *ExitInitializationMode;
    fmi2TerminateTYPE *Terminate;
    fmi2ResetTYPE *Reset;
    fmi2GetRealTYPE *GetReal;
    fmi2GetIntegerTYPE *GetInteger;
    fmi2GetBooleanTYPE *GetBoolean;
    fmi2GetStringTYPE *GetString;
    fmi2SetRealTYPE *SetReal;
    fmi2SetIntegerTYPE *SetInteger;
    fmi2SetBooleanTYPE *SetBoolean;
    fmi2SetStringTYPE *SetString;
    fmi2GetFMUstateTYPE *GetFMUstate;
    fmi2SetFMUstateTYPE *SetFMUstate;
    fmi2FreeFMUstateTYPE *FreeFMUstate;
    fmi2DoStepTYPE *DoStep;
} Inner;

static Inner F;
static int inner_state = 0;                 /* 0 not tried, 1 loaded, -1 failed (inner_error says why) */
static char inner_error[MSG_MAX];
static pthread_mutex_t inner_lock = PTHREAD_MUTEX_INITIALIZER;

static int load_inner(void) {
    pthread_mutex_lock(&inner_lock);
    if (inner_state == 0) {
        Dl_info info;
        char path[4096];
        void *h = NULL;
        if (!dladdr((void *)&fmi2Instantiate, &info) || !info.dli_fname) {
            snprintf(inner_error, sizeof inner_error, "cannot locate the wrapper's own file (dladdr)");
        } else {
            const char *slash = strrchr(info.dli_fname, '/');
            int dir_len = slash ? (int)(slash - info.dli_fname) : 1;
            snprintf(path, sizeof path, "%.*s/%s", dir_len, slash ? info.dli_fname : ".", WRAPPER_EXPORT_LIBRARY);
            h = dlopen(path, RTLD_NOW | RTLD_LOCAL | RTLD_DEEPBIND);
            if (!h) snprintf(inner_error, sizeof inner_error, "cannot load pythonfmu's export library %s: %s", path,
                             dlerror());
        }
        if (h) {
            int ok = 1;
#define LOAD(member, symbol) \
            if (ok && !(*(void **)(&F.member) = dlsym(h, symbol))) { \
                snprintf(inner_error, sizeof inner_error, "%s has no %s", path, symbol); ok = 0; }
            LOAD(Instantiate, "fmi2Instantiate") LOAD(FreeInstance, "fmi2FreeInstance")
            LOAD(SetDebugLogging, "fmi2SetDebugLogging") LOAD(SetupExperiment, "fmi2SetupExperiment")
            LOAD(EnterInitializationMode, "fmi2EnterInitializationMode")
            LOAD(ExitInitializationMode, "fmi2ExitInitializationMode") LOAD(Terminate, "fmi2Terminate")
            LOAD(Reset, "fmi2Reset") LOAD(GetReal, "fmi2GetReal") LOAD(GetInteger, "fmi2GetInteger")
            LOAD(GetBoolean, "fmi2GetBoolean") LOAD(GetString, "fmi2GetString") LOAD(SetReal, "fmi2SetReal")
            LOAD(SetInteger, "fmi2SetInteger") LOAD(SetBoolean, "fmi2SetBoolean") LOAD(SetString, "fmi2SetString")
            LOAD(GetFMUstate, "fmi2GetFMUstate") LOAD(SetFMUstate, "fmi2SetFMUstate")
            LOAD(FreeFMUstate, "fmi2FreeFMUstate") LOAD(DoStep, "fmi2DoStep")
#undef LOAD
            inner_state = ok ? 1 : -1;
        } else {
            inner_state = -1;
        }
    }
    int st = inner_state;
    pthread_mutex_unlock(&inner_lock);
    return st == 1;
}

/* ---- the instance ---- */

typedef struct {
    fmi2Component inner;
    fmi2CallbackFunctions cb;
    char name[256];
    int logging_on;
    int phase;
    int failed;                 /* the error state: every later doStep refused */
    int lost;                   /* the export library answered fmi2Fatal: nothing is forwarded any more */
    int have_t_next;
    double t_next, last_ok;
    char failmsg[MSG_MAX];
} Inst;

#define STATE_MAGIC 0x46574d53u   /* "SMWF" */
typedef struct {
    unsigned magic;
    fmi2FMUstate inner;
    int phase, failed, have_t_next;
    double t_next, last_ok;
    char failmsg[MSG_MAX];
} WrappedState;

/* live instances: fmi2FreeInstance frees only a listed one (a second free is harmless) */
static Inst **live = NULL;
static size_t n_live = 0, cap_live = 0;
static pthread_mutex_t live_lock = PTHREAD_MUTEX_INITIALIZER;

static int live_add(Inst *c) {
    int ok = 1;
    pthread_mutex_lock(&live_lock);
    if (n_live == cap_live) {
        size_t cap = cap_live ? 2 * cap_live : 16;
        Inst **grown = (Inst **)realloc(live, cap * sizeof *grown);
        if (grown) { live = grown; cap_live = cap; } else ok = 0;
    }
    if (ok) live[n_live++] = c;
    pthread_mutex_unlock(&live_lock);
    return ok;
}

static int live_remove(Inst *c) {
    int found = 0;
    pthread_mutex_lock(&live_lock);
    for (size_t i = 0; i < n_live; i++)
        if (live[i] == c) { live[i] = live[--n_live]; found = 1; break; }
    pthread_mutex_unlock(&live_lock);
    return found;
}

/* ---- messages ---- */

/* the host's logger takes the message as a printf format: every '%' is doubled */
static void vlog_to(const fmi2CallbackFunctions *cb, const char *name, fmi2Status st, const char *fmt, va_list ap) {
    if (!cb || !cb->logger) return;
    char buf[MSG_MAX], esc[2 * MSG_MAX];
    vsnprintf(buf, sizeof buf, fmt, ap);
    size_t k = 0;
    for (const char *p = buf; *p && k < sizeof esc - 3; p++) {
        if (*p == '%') esc[k++] = '%';
        esc[k++] = *p;
    }
    esc[k] = 0;
    cb->logger(cb->componentEnvironment, name, st, st == fmi2OK ? "logAll" : "logStatusError", esc);
}

static void logf_(Inst *c, fmi2Status st, const char *fmt, ...) {
    if (st == fmi2OK && !c->logging_on) return;
    va_list ap;
    va_start(ap, fmt);
    vlog_to(&c->cb, c->name, st, fmt, ap);
    va_end(ap);
}

/* the error state: logged, remembered, and told to the slave (its outputs become NaN, "error" says why) */
static void fail(Inst *c, const char *fmt, ...) {
    char buf[MSG_MAX];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    logf_(c, fmi2Error, "%s", buf);
    if (c->failed) return;
    c->failed = 1;
    snprintf(c->failmsg, sizeof c->failmsg, "%s", buf);
    if (!c->lost && WRAPPER_VR_FAIL >= 0) {
        fmi2ValueReference vr = (fmi2ValueReference)WRAPPER_VR_FAIL;
        fmi2String v = c->failmsg;
        if (F.SetString(c->inner, &vr, 1, &v) == fmi2Fatal) c->lost = 1;
    }
}

/* ---- the FMI 2.0 co-simulation state machine: its rules and words (shared with the native shell) ---- */

#define FMI2_STATE_MODEL WRAPPER_MODEL
#define FMI2_STATE_REFUSE(c, ...) logf_(c, fmi2Error, __VA_ARGS__)
#include "fmi2_state.h"

/* the status of a forwarded call; fmi2Fatal: the instance is lost (nothing is forwarded any more) */
static fmi2Status inner_status(Inst *c, const char *call, fmi2Status st) {
    if (st == fmi2Fatal) {
        c->lost = 1;
        logf_(c, fmi2Fatal, "%s: %s: the Python slave raised an exception (pythonfmu answers fmi2Fatal and releases "
              "it); every later call on this instance is refused", WRAPPER_MODEL, call);
    }
    return st;
}

/* the slave's "error" output into failmsg when it is in its error state (after a call that may have failed it) */
static void sync_failed(Inst *c) {
    if (c->lost || WRAPPER_VR_ERROR < 0) return;
    fmi2ValueReference vr = (fmi2ValueReference)WRAPPER_VR_ERROR;
    fmi2String v = NULL;
    if (inner_status(c, "fmi2GetString", F.GetString(c->inner, &vr, 1, &v)) != fmi2OK) return;
    if (v && v[0]) {
        c->failed = 1;
        snprintf(c->failmsg, sizeof c->failmsg, "%s", v);
    } else {
        c->failed = 0;
        c->failmsg[0] = 0;
    }
}

#define ENTER(call)                                                                                   \
    Inst *c = (Inst *)comp;                                                                           \
    if (!c) return fmi2Error;                                                                         \
    if (c->lost) {                                                                                    \
        logf_(c, fmi2Error, "%s: %s refused: the instance was lost at an earlier fmi2Fatal", WRAPPER_MODEL, call); \
        return fmi2Error;                                                                             \
    }

/* ---- variables ---- */

static const WrapperVar *var_of(fmi2ValueReference vr) {
    if (vr > (fmi2ValueReference)WRAPPER_MAX_VR) return NULL;
    int row = WRAPPER_ROW[vr];
    return row < 0 ? NULL : &WRAPPER_VARS[row];
}

static const char *type_name(char t) {
    switch (t) {
    case 'R': return "Real";
    case 'I': return "Integer";
    case 'B': return "Boolean";
    case 'S': return "String";
    default: return "Enumeration";
    }
}

/* 1 when every reference is a variable of type t, else the instance fails (logged) and 0 */
static int check_refs(Inst *c, const char *call, const fmi2ValueReference vr[], size_t nvr, char t) {
    if (nvr && !vr) {
        fail(c, "%s: %s with %zu value references and no array; the instance is now in its error state",
             WRAPPER_MODEL, call, nvr);
        return 0;
    }
    for (size_t i = 0; i < nvr; i++) {
        const WrapperVar *v = var_of(vr[i]);
        if (!v || v->type != t) {
            state_bad_vr(c, call, vr[i], type_name(t), v ? type_name(v->type) : NULL, v ? v->name : NULL);
            return 0;
        }
    }
    return 1;
}

/* parameters before fmi2ExitInitializationMode only (tunable ones at any time), inputs at any time, others never */
static int settable_now(Inst *c, const WrapperVar *v, const char *call) {
    return state_settable(c, call, v->name, v->causality == C_INPUT, v->causality == C_PARAMETER,
                          v->variability == V_CONSTANT, v->variability == V_TUNABLE);
}

/* an Integer inside its declared min/max (a Real's range stays the model's refusal, with its message) */
static int in_range(Inst *c, const WrapperVar *v, const char *call, fmi2Integer x) {
    if ((v->has_min && x < v->min) || (v->has_max && x > v->max)) {
        char lo[40] = "None", hi[40] = "None";
        if (v->has_min) snprintf(lo, sizeof lo, "%.0f", v->min);
        if (v->has_max) snprintf(hi, sizeof hi, "%.0f", v->max);
        fail(c, "%s: %s of %s = %d: outside its declared range [%s, %s]; the instance is now in its error state",
             WRAPPER_MODEL, call, v->name, (int)x, lo, hi);
        return 0;
    }
    return 1;
}

/* a '%' of the path itself: "%25" in a URI, or a '%' that is not a URI escape */
static int has_literal_percent(const char *loc) {
    for (const char *p = strchr(loc, '%'); p; p = strchr(p + 1, '%')) {
        if (strncmp(p, "%25", 3) == 0) return 1;
        if (!(isxdigit((unsigned char)p[1]) && isxdigit((unsigned char)p[2]))) return 1;
    }
    return 0;
}

/* ---- FMI 2.0 ---- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    if (!functions) return NULL;
    const char *name = instanceName ? instanceName : WRAPPER_MODEL;
#define REFUSE(...) do { Inst tmp; memset(&tmp, 0, sizeof tmp); tmp.cb = *functions; \
        snprintf(tmp.name, sizeof tmp.name, "%s", name); logf_(&tmp, fmi2Error, __VA_ARGS__); return NULL; } while (0)
    if (fmuType != fmi2CoSimulation) REFUSE(STATE_MSG_NOT_COSIM, WRAPPER_MODEL, "");
    if (fmuGUID && fmuGUID[0] && strcmp(fmuGUID, WRAPPER_GUID) != 0)
        REFUSE(STATE_MSG_GUID, WRAPPER_MODEL, "", fmuGUID, WRAPPER_GUID);
    if (!fmuResourceLocation || !fmuResourceLocation[0])
        REFUSE("%s: fmi2Instantiate without a resource location (the Python model is in resources/)", WRAPPER_MODEL);
    if (has_literal_percent(fmuResourceLocation))
        REFUSE("%s: the resource location %s has a '%%' in its path (pythonfmu 0.7.0 crashes on it); extract the "
               "FMU into a directory without one", WRAPPER_MODEL, fmuResourceLocation);
    if (!load_inner()) REFUSE("%s: %s", WRAPPER_MODEL, inner_error);
#undef REFUSE
    Inst *c = (Inst *)calloc(1, sizeof(Inst));
    if (!c) return NULL;
    c->cb = *functions;
    c->logging_on = loggingOn;
    snprintf(c->name, sizeof c->name, "%s", name);
    c->inner = F.Instantiate(instanceName, fmuType, fmuGUID, fmuResourceLocation, functions, visible, loggingOn);
    if (!c->inner) { free(c); return NULL; }            /* the export library has logged why */
    if (!live_add(c)) { F.FreeInstance(c->inner); free(c); return NULL; }
    state_reset(c);
    return c;
}

void fmi2FreeInstance(fmi2Component comp) {
    Inst *c = (Inst *)comp;
    if (!c || !live_remove(c)) return;                  /* NULL, or freed already */
    if (!c->lost) F.FreeInstance(c->inner);             /* a lost slave is not touched again */
    free(c);
}

fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t n, const fmi2String cats[]) {
    ENTER("fmi2SetDebugLogging")
    c->logging_on = loggingOn;
    return inner_status(c, "fmi2SetDebugLogging", F.SetDebugLogging(c->inner, loggingOn, n, cats));
}

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    ENTER("fmi2SetupExperiment")
    if (state_setup_checked(c, startTime, stopTimeDefined, stopTime) != fmi2OK) return fmi2Error;
    if (toleranceDefined && !(tolerance > 0.0 && isfinite(tolerance))) toleranceDefined = fmi2False;
    return inner_status(c, "fmi2SetupExperiment", F.SetupExperiment(c->inner, toleranceDefined, tolerance, startTime,
                                                                     stopTimeDefined, stopTime));
}

fmi2Status fmi2EnterInitializationMode(fmi2Component comp) {
    ENTER("fmi2EnterInitializationMode")
    if (state_enter_allowed(c) != fmi2OK) return fmi2Error;
    fmi2Status st = inner_status(c, "fmi2EnterInitializationMode", F.EnterInitializationMode(c->inner));
    if (st > fmi2Warning) return st;
    state_entered(c);
    return st;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    ENTER("fmi2ExitInitializationMode")
    if (state_exit_allowed(c) != fmi2OK) return fmi2Error;
    fmi2Status st = inner_status(c, "fmi2ExitInitializationMode", F.ExitInitializationMode(c->inner));
    if (st > fmi2Warning) return st;
    state_exited(c);
    sync_failed(c);     /* a failed initialization: fmi2Error now, every doStep refused (as in the native builds) */
    return st == fmi2OK ? state_exit_result(c) : (c->failed ? state_exit_result(c) : st);
}

fmi2Status fmi2Terminate(fmi2Component comp) {
    ENTER("fmi2Terminate")
    if (state_terminate_allowed(c) != fmi2OK) return fmi2Error;
    fmi2Status st = inner_status(c, "fmi2Terminate", F.Terminate(c->inner));
    if (st <= fmi2Warning) state_terminated(c);
    return st;
}

fmi2Status fmi2Reset(fmi2Component comp) {
    ENTER("fmi2Reset")
    fmi2Status st = inner_status(c, "fmi2Reset", F.Reset(c->inner));
    if (st > fmi2Warning) return st;
    state_reset(c);
    return st;
}

#define GETTER(NAME, T, CTYPE)                                                                            \
fmi2Status fmi2Get##NAME(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, CTYPE value[]) { \
    ENTER("fmi2Get" #NAME)                                                                                \
    if (state_get_allowed(c, "fmi2Get" #NAME) != fmi2OK) return fmi2Error;                                \
    if (!check_refs(c, "fmi2Get" #NAME, vr, nvr, T)) return fmi2Error;                                    \
    if (nvr && !value) return fmi2Error;                                                                  \
    return inner_status(c, "fmi2Get" #NAME, F.Get##NAME(c->inner, vr, nvr, value));                       \
}
GETTER(Real, 'R', fmi2Real)
GETTER(Integer, 'I', fmi2Integer)
GETTER(Boolean, 'B', fmi2Boolean)
GETTER(String, 'S', fmi2String)

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    ENTER("fmi2SetReal")
    if (state_set_allowed(c, "fmi2SetReal") != fmi2OK) return fmi2Error;
    if (!check_refs(c, "fmi2SetReal", vr, nvr, 'R')) return fmi2Error;
    if (nvr && !value) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        const WrapperVar *v = var_of(vr[i]);
        if (!settable_now(c, v, "fmi2SetReal")) return fmi2Error;
        if (v->causality == C_INPUT) continue;       /* inputs: a non-finite value is refused at the next doStep */
        if (!isfinite(value[i])) return state_nonfinite_parameter(c, v->name, value[i]);
        /* a Real outside its declared min/max is left to the model (its own message, as in the native builds) */
    }
    return inner_status(c, "fmi2SetReal", F.SetReal(c->inner, vr, nvr, value));
}

fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    ENTER("fmi2SetInteger")
    if (state_set_allowed(c, "fmi2SetInteger") != fmi2OK) return fmi2Error;
    if (!check_refs(c, "fmi2SetInteger", vr, nvr, 'I')) return fmi2Error;
    if (nvr && !value) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        const WrapperVar *v = var_of(vr[i]);
        if (!settable_now(c, v, "fmi2SetInteger") || !in_range(c, v, "fmi2SetInteger", value[i]))
            return fmi2Error;
    }
    return inner_status(c, "fmi2SetInteger", F.SetInteger(c->inner, vr, nvr, value));
}

fmi2Status fmi2SetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    ENTER("fmi2SetBoolean")
    if (state_set_allowed(c, "fmi2SetBoolean") != fmi2OK) return fmi2Error;
    if (!check_refs(c, "fmi2SetBoolean", vr, nvr, 'B')) return fmi2Error;
    if (nvr && !value) return fmi2Error;
    for (size_t i = 0; i < nvr; i++)
        if (!settable_now(c, var_of(vr[i]), "fmi2SetBoolean")) return fmi2Error;
    return inner_status(c, "fmi2SetBoolean", F.SetBoolean(c->inner, vr, nvr, value));
}

fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    ENTER("fmi2SetString")
    if (state_set_allowed(c, "fmi2SetString") != fmi2OK) return fmi2Error;
    if (!check_refs(c, "fmi2SetString", vr, nvr, 'S')) return fmi2Error;
    if (nvr && !value) return fmi2Error;
    for (size_t i = 0; i < nvr; i++)
        if (!settable_now(c, var_of(vr[i]), "fmi2SetString")) return fmi2Error;
    fmi2String stack[16];
    fmi2String *vals = nvr <= 16 ? stack : (fmi2String *)malloc(nvr * sizeof *vals);
    if (!vals) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) vals[i] = value[i] ? value[i] : "";      /* NULL is "" */
    fmi2Status st = inner_status(c, "fmi2SetString", F.SetString(c->inner, vr, nvr, vals));
    if (vals != stack) free(vals);
    return st;
}

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real t, fmi2Real H, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    ENTER("fmi2DoStep")
    if (state_step_refused(c, t, H)) return fmi2Error;     /* misuse, or the error state (logged) */
    fmi2Status st = inner_status(c, "fmi2DoStep", F.DoStep(c->inner, t, H, noSetFMUStatePriorToCurrentPoint));
    if (st <= fmi2Warning) {
        state_step_done(c, t, H);
    } else if (st == fmi2Discard || st == fmi2Error) {
        sync_failed(c);     /* the slave failed in this step (logged by it): later steps are refused here */
        if (!c->failed) { c->failed = 1; snprintf(c->failmsg, sizeof c->failmsg, "fmi2DoStep at t = %.12g s failed", t); }
    }
    return st;
}

fmi2Status fmi2CancelStep(fmi2Component comp) {
    ENTER("fmi2CancelStep")
    logf_(c, fmi2Error, "%s: fmi2CancelStep: doStep never runs asynchronously", WRAPPER_MODEL);
    return fmi2Error;
}

/* ---- FMU state: the slave's, with the wrapper's own (state, error, where the next step starts) ---- */

static WrappedState *wrapped(fmi2FMUstate s) {
    WrappedState *w = (WrappedState *)s;
    return (w && w->magic == STATE_MAGIC) ? w : NULL;
}

fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *state) {
    ENTER("fmi2GetFMUstate")
    if (!state) return fmi2Error;
    WrappedState *w = wrapped(*state);
    int fresh = w == NULL;
    if (fresh) {
        w = (WrappedState *)calloc(1, sizeof *w);
        if (!w) return fmi2Error;
        w->magic = STATE_MAGIC;
    }
    fmi2Status st = inner_status(c, "fmi2GetFMUstate", F.GetFMUstate(c->inner, &w->inner));
    if (st > fmi2Warning) {
        if (fresh) free(w);
        return st;
    }
    w->phase = c->phase; w->failed = c->failed; w->have_t_next = c->have_t_next;
    w->t_next = c->t_next; w->last_ok = c->last_ok;
    memcpy(w->failmsg, c->failmsg, sizeof w->failmsg);
    *state = (fmi2FMUstate)w;
    return st;
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate state) {
    ENTER("fmi2SetFMUstate")
    WrappedState *w = wrapped(state);
    if (!w) {
        logf_(c, fmi2Error, "%s: fmi2SetFMUstate with a state that is not one of this FMU's", WRAPPER_MODEL);
        return fmi2Error;
    }
    fmi2Status st = inner_status(c, "fmi2SetFMUstate", F.SetFMUstate(c->inner, w->inner));
    if (st > fmi2Warning) return st;
    c->phase = w->phase; c->failed = w->failed; c->have_t_next = w->have_t_next;
    c->t_next = w->t_next; c->last_ok = w->last_ok;
    memcpy(c->failmsg, w->failmsg, sizeof c->failmsg);
    return st;
}

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *state) {
    Inst *c = (Inst *)comp;
    if (!c || !state || !*state) return fmi2OK;
    WrappedState *w = wrapped(*state);
    if (!w) {
        logf_(c, fmi2Error, "%s: fmi2FreeFMUstate with a state that is not one of this FMU's", WRAPPER_MODEL);
        return fmi2Error;
    }
    fmi2Status st = fmi2OK;
    if (!c->lost && w->inner) st = inner_status(c, "fmi2FreeFMUstate", F.FreeFMUstate(c->inner, &w->inner));
    w->magic = 0;
    free(w);
    *state = NULL;
    return st > fmi2Warning ? st : fmi2OK;
}

static fmi2Status no_serialization(fmi2Component comp, const char *call) {
    ENTER(call)
    logf_(c, fmi2Error, "%s: %s: FMU states cannot be serialized (canSerializeFMUstate=\"false\"); keep them with "
          "fmi2GetFMUstate/fmi2SetFMUstate", WRAPPER_MODEL, call);
    return fmi2Error;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate state, size_t *size) {
    (void)state; (void)size;
    return no_serialization(comp, "fmi2SerializedFMUstateSize");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate state, fmi2Byte bytes[], size_t size) {
    (void)state; (void)bytes; (void)size;
    return no_serialization(comp, "fmi2SerializeFMUstate");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state) {
    (void)bytes; (void)size; (void)state;
    return no_serialization(comp, "fmi2DeSerializeFMUstate");
}

/* ---- not provided (declared so in modelDescription.xml) ---- */

static fmi2Status not_provided(fmi2Component comp, const char *what) {
    ENTER(what)
    logf_(c, fmi2Error, STATE_MSG_NOT_PROVIDED, WRAPPER_MODEL, what);
    return fmi2Error;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real du[], fmi2Real dz[]) {
    (void)u; (void)nu; (void)z; (void)nz; (void)du; (void)dz;
    return not_provided(comp, "directional derivatives");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return not_provided(comp, "input derivatives");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return not_provided(comp, "output derivatives");
}

fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *value) {
    (void)s;
    ENTER("fmi2GetStatus")
    if (value) *value = fmi2OK;
    return fmi2OK;
}

fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *value) {
    ENTER("fmi2GetRealStatus")
    if (s == fmi2LastSuccessfulTime && value) { *value = c->last_ok; return fmi2OK; }
    return fmi2Discard;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s; (void)value;
    ENTER("fmi2GetIntegerStatus")
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *value) {
    ENTER("fmi2GetBooleanStatus")
    if (s == fmi2Terminated && value) { *value = c->failed ? fmi2True : fmi2False; return fmi2OK; }
    return fmi2Discard;
}

fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *value) {
    (void)s; (void)value;
    ENTER("fmi2GetStringStatus")
    return fmi2Discard;
}
