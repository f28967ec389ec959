/* fmi2_shell.h: the FMI 2.0 co-simulation shell shared by the native FMUs (gearcontact_native.c and the
 * drivetrain's line_native.c): the log and the error state, value references, fmi2Get/Set*, the life-cycle
 * calls that do not depend on the model, the FMU-state free, and the functions not provided. The state
 * machine's rules and messages are fmi2_state.h's (shared with the pythonfmu FMUs' wrapper), included here.
 *
 * Design: a model file defines its own Inst struct and a few hooks, then includes this header ONCE, after
 * Inst and before its model code. Inst must have the members name, cb, logging_on and, in its state part,
 * r[], iv[], phase, failed, failmsg[SHELL_MSG_MAX], t_next, last_ok, have_t_next: the shell reaches them by
 * name, so each model keeps its own layout (and its FMU-state bytes). Hook macros, defined before Inst:
 *   SHELL_MODEL_NAME   the name every message starts with;  SHELL_GUID  the build's GUID
 *   SHELL_VAR, SHELL_VARS, SHELL_N_VARS   the variable table's type, the table (by value reference), its size
 *   SHELL_MSG_MAX      the error message's size (a log line holds twice that)
 *   SHELL_NAN_ON_FAILURE(i)   nonzero for a Real variable that becomes NaN in the error state
 * Hook functions (declared below, defined by the model file): shell_before_get_real, shell_get_real,
 * shell_get_string, shell_accept_real, shell_accept_integer, shell_set_string.
 */
#ifndef FMI2_SHELL_H
#define FMI2_SHELL_H

#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

/* ---- the model's hooks ---- */

/* fmi2GetReal, before reading (e.g. a rebuild after a parameter changed in initialization mode) */
static void shell_before_get_real(Inst *c);
/* the value of Real variable v (value reference vr) */
static double shell_get_real(const Inst *c, const SHELL_VAR *v, fmi2ValueReference vr);
/* the value of String variable v other than "error" */
static const char *shell_get_string(const Inst *c, const SHELL_VAR *v, fmi2ValueReference vr);
/* a settable Real / Integer value x for v: fmi2OK to store it, else refused (the instance failed) */
static fmi2Status shell_accept_real(Inst *c, const SHELL_VAR *v, double x);
static fmi2Status shell_accept_integer(Inst *c, const SHELL_VAR *v, int x);
/* store the settable String value s ("" for NULL) of v: fmi2OK, else refused (the instance failed) */
static fmi2Status shell_set_string(Inst *c, const SHELL_VAR *v, fmi2ValueReference vr, const char *s);

/* ---- the log and the error state ---- */

/* log: the message is handed to the host's logger as a printf format, so every '%' is doubled */
static void logf_(Inst *c, fmi2Status st, const char *cat, const char *fmt, ...) {
    if (!c || !c->cb.logger) return;
    if (st == fmi2OK && !c->logging_on) return;
    char buf[2 * SHELL_MSG_MAX], esc[4 * SHELL_MSG_MAX + 108];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    size_t k = 0;
    for (const char *p = buf; *p && k < sizeof esc - 3; p++) {
        if (*p == '%') esc[k++] = '%';
        esc[k++] = *p;
    }
    esc[k] = 0;
    c->cb.logger(c->cb.componentEnvironment, c->name, st, cat, esc);
}

/* the instance enters its error state (fmu_runtime.guard.enter_error_state): every later doStep is
 * refused, the output "error" holds the message, the outputs a host would pass on become NaN */
static void fail(Inst *c, const char *fmt, ...) {
    char buf[SHELL_MSG_MAX];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    c->failed = 1;
    snprintf(c->failmsg, sizeof c->failmsg, "%s", buf);
    for (int i = 0; i < SHELL_N_VARS; i++)
        if (SHELL_NAN_ON_FAILURE(i)) c->r[i] = NAN;
    logf_(c, fmi2Error, "logStatusError", "%s", buf);
}

/* ---- the FMI 2.0 co-simulation state machine: its rules and words (shared with the pythonfmu wrapper) ---- */

#define FMI2_STATE_MODEL SHELL_MODEL_NAME
#define FMI2_STATE_REFUSE(c, ...) logf_(c, fmi2Error, "logStatusError", __VA_ARGS__)
#include "fmi2_state.h"

/* ---- life cycle ---- */

/* the shell's part of fmi2Instantiate / fmi2Reset: the variables' start values, no error, no step yet */
static void shell_defaults(Inst *c) {
    for (int i = 0; i < SHELL_N_VARS; i++) {
        c->r[i] = SHELL_VARS[i].real_start;
        c->iv[i] = SHELL_VARS[i].int_start;
    }
    state_reset(c);
}

/* fmi2EnterInitializationMode's part: fmi2OK and initialization mode, or refused */
static fmi2Status shell_enter(Inst *c) {
    fmi2Status st = state_enter_allowed(c);
    if (st != fmi2OK) return st;
    state_entered(c);
    return fmi2OK;
}

/* fmi2ExitInitializationMode's part: fmi2OK and step mode, or refused */
static fmi2Status shell_exit(Inst *c) {
    fmi2Status st = state_exit_allowed(c);
    if (st != fmi2OK) return st;
    state_exited(c);
    return fmi2OK;
}

/* ---- live instances: a second fmi2FreeInstance of one instance (a host's error) is harmless ----
 * Every instance handed out is listed until it is freed; fmi2FreeInstance frees only a listed one. The list
 * is guarded by a spin lock (hosts may instantiate from several threads; GCC/Clang builtins, else unguarded). */
static Inst **shell_live = NULL;
static size_t shell_n_live = 0, shell_cap_live = 0;
#if defined(__GNUC__)
static volatile int shell_live_lock = 0;
#define SHELL_LOCK() while (__sync_lock_test_and_set(&shell_live_lock, 1)) {}
#define SHELL_UNLOCK() __sync_lock_release(&shell_live_lock)
#else
#define SHELL_LOCK()
#define SHELL_UNLOCK()
#endif

/* list c as live; 0 when there is no memory for the list (then the instance is not handed out) */
static int shell_register(Inst *c) {
    int ok = 1;
    SHELL_LOCK();
    if (shell_n_live == shell_cap_live) {
        size_t cap = shell_cap_live ? 2 * shell_cap_live : 16;
        Inst **grown = (Inst **)realloc(shell_live, cap * sizeof *grown);
        if (grown) { shell_live = grown; shell_cap_live = cap; } else ok = 0;
    }
    if (ok) shell_live[shell_n_live++] = c;
    SHELL_UNLOCK();
    return ok;
}

/* 1 and c no longer listed when c was live (free it now), else 0 (freed already, or never handed out) */
static int shell_release(Inst *c) {
    int found = 0;
    SHELL_LOCK();
    for (size_t i = 0; i < shell_n_live; i++)
        if (shell_live[i] == c) { shell_live[i] = shell_live[--shell_n_live]; found = 1; break; }
    SHELL_UNLOCK();
    return found;
}

/* fmi2Instantiate's checks: the new instance (name, callbacks, logging set), or NULL (logged) */
static Inst *shell_instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                               const fmi2CallbackFunctions *functions, fmi2Boolean loggingOn) {
    if (!functions) return NULL;
    Inst *c = (Inst *)calloc(1, sizeof(Inst));
    if (!c) return NULL;
    c->cb = *functions;
    c->logging_on = loggingOn;
    snprintf(c->name, sizeof c->name, "%s", instanceName ? instanceName : SHELL_MODEL_NAME);
    if (fmuType != fmi2CoSimulation) {
        logf_(c, fmi2Error, "logStatusError", STATE_MSG_NOT_COSIM, SHELL_MODEL_NAME, " (native)");
        free(c);
        return NULL;
    }
    if (fmuGUID && fmuGUID[0] && strcmp(fmuGUID, SHELL_GUID) != 0) {
        logf_(c, fmi2Error, "logStatusError", STATE_MSG_GUID, SHELL_MODEL_NAME, " (native)", fmuGUID, SHELL_GUID);
        free(c);
        return NULL;
    }
    return c;
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t n, const fmi2String cats[]) {
    (void)n; (void)cats;
    ((Inst *)comp)->logging_on = loggingOn;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component comp) {
    Inst *c = (Inst *)comp;
    fmi2Status st = state_terminate_allowed(c);
    if (st != fmi2OK) return st;
    state_terminated(c);
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component comp) { (void)comp; return fmi2Error; }

/* ---- variable access ---- */

static const SHELL_VAR *var_of(fmi2ValueReference vr) { return vr < SHELL_N_VARS ? &SHELL_VARS[vr] : NULL; }

static fmi2Status bad_vr(Inst *c, const char *call, fmi2ValueReference vr, const char *type) {
    const SHELL_VAR *v = var_of(vr);
    return state_bad_vr(c, call, vr, type, v ? v->type : NULL, v ? v->name : NULL);
}

/* getters: not before fmi2EnterInitializationMode; setters: not after fmi2Terminate (state unchanged) */
#define CHECK_GET_PHASE(call)                                                                  \
    if (state_get_allowed(c, call) != fmi2OK) return fmi2Error;
#define CHECK_SET_PHASE(call)                                                                  \
    if (state_set_allowed(c, call) != fmi2OK) return fmi2Error;

#define CHECK_VR(call, want)                                                                   \
    const SHELL_VAR *v = var_of(vr[i]);                                                        \
    if (!v || strcmp(v->type, want) != 0) return bad_vr(c, call, vr[i], want);

/* parameters before fmi2ExitInitializationMode only, inputs at any time, outputs never (fmi2_state.h) */
static int settable_now(Inst *c, const SHELL_VAR *v, const char *call) {
    return state_settable(c, call, v->name, v->is_input, v->is_parameter, 0, 0);
}

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    Inst *c = (Inst *)comp;
    CHECK_GET_PHASE("fmi2GetReal")
    shell_before_get_real(c);
    for (size_t i = 0; i < nvr; i++) {
        CHECK_VR("fmi2GetReal", "Real")
        value[i] = shell_get_real(c, v, vr[i]);
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    Inst *c = (Inst *)comp;
    CHECK_GET_PHASE("fmi2GetInteger")
    for (size_t i = 0; i < nvr; i++) {
        CHECK_VR("fmi2GetInteger", "Integer")
        value[i] = c->iv[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    Inst *c = (Inst *)comp;
    CHECK_GET_PHASE("fmi2GetBoolean")
    for (size_t i = 0; i < nvr; i++) {
        CHECK_VR("fmi2GetBoolean", "Boolean")
        value[i] = c->iv[vr[i]] ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    Inst *c = (Inst *)comp;
    CHECK_GET_PHASE("fmi2GetString")
    for (size_t i = 0; i < nvr; i++) {
        CHECK_VR("fmi2GetString", "String")
        if (vr[i] == VR_error) value[i] = c->failed ? c->failmsg : "";
        else value[i] = shell_get_string(c, v, vr[i]);
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    Inst *c = (Inst *)comp;
    CHECK_SET_PHASE("fmi2SetReal")
    for (size_t i = 0; i < nvr; i++) {
        CHECK_VR("fmi2SetReal", "Real")
        if (!settable_now(c, v, "fmi2SetReal")) return fmi2Error;
        if (!v->is_input && !isfinite(value[i])) return state_nonfinite_parameter(c, v->name, value[i]);
        if (shell_accept_real(c, v, value[i]) != fmi2OK) return fmi2Error;
        c->r[vr[i]] = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    Inst *c = (Inst *)comp;
    CHECK_SET_PHASE("fmi2SetInteger")
    for (size_t i = 0; i < nvr; i++) {
        CHECK_VR("fmi2SetInteger", "Integer")
        if (!settable_now(c, v, "fmi2SetInteger")) return fmi2Error;
        if (shell_accept_integer(c, v, value[i]) != fmi2OK) return fmi2Error;
        c->iv[vr[i]] = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    Inst *c = (Inst *)comp;
    CHECK_SET_PHASE("fmi2SetBoolean")
    for (size_t i = 0; i < nvr; i++) {
        CHECK_VR("fmi2SetBoolean", "Boolean")
        if (!settable_now(c, v, "fmi2SetBoolean")) return fmi2Error;
        c->iv[vr[i]] = value[i] ? 1 : 0;
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    Inst *c = (Inst *)comp;
    CHECK_SET_PHASE("fmi2SetString")
    for (size_t i = 0; i < nvr; i++) {
        CHECK_VR("fmi2SetString", "String")
        if (!settable_now(c, v, "fmi2SetString")) return fmi2Error;
        fmi2Status st = shell_set_string(c, v, vr[i], value[i] ? value[i] : "");
        if (st != fmi2OK) return st;
    }
    return fmi2OK;
}

/* ---- FMU state (the model file gets, sets and serializes its own) ---- */

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *state) {
    (void)comp;
    if (state && *state) { free(*state); *state = NULL; }
    return fmi2OK;
}

/* ---- not provided (declared so in modelDescription.xml) ---- */

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real du[], fmi2Real dz[]) {
    (void)u; (void)nu; (void)z; (void)nz; (void)du; (void)dz;
    logf_((Inst *)comp, fmi2Error, "logStatusError", STATE_MSG_NOT_PROVIDED, SHELL_MODEL_NAME, "directional derivatives");
    return fmi2Error;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    logf_((Inst *)comp, fmi2Error, "logStatusError", STATE_MSG_NOT_PROVIDED, SHELL_MODEL_NAME, "input derivatives");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    logf_((Inst *)comp, fmi2Error, "logStatusError", STATE_MSG_NOT_PROVIDED, SHELL_MODEL_NAME, "output derivatives");
    return fmi2Error;
}

fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *value) {
    (void)comp; (void)s;
    *value = fmi2OK;
    return fmi2OK;
}

fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *value) {
    Inst *c = (Inst *)comp;
    if (s == fmi2LastSuccessfulTime) { *value = c->last_ok; return fmi2OK; }
    return fmi2Discard;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *value) {
    (void)comp; (void)s; (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *value) {
    Inst *c = (Inst *)comp;
    if (s == fmi2Terminated) { *value = c->failed ? fmi2True : fmi2False; return fmi2OK; }
    return fmi2Discard;
}

fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *value) {
    (void)comp; (void)s; (void)value;
    return fmi2Discard;
}

#endif
