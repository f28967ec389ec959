/* fmi2_state.h: the FMI 2.0 co-simulation state machine of every C binary of the project's FMUs (as the Reference
 * FMUs have it), its rules and its messages written once. Included by the native FMUs' shell (fmi2_shell.h) and
 * by the pythonfmu FMUs' wrapper (drivetrain/fmu_build/native/pythonfmu_wrapper.c), so that a host reads the same
 * words from either kind of FMU (tests/fmu_build/test_fmi_conformance.py, tests/fmu_build/test_fmu_hostile.py).
 *
 * What it holds: the states and their names, a double as Python's repr prints it (pyfloat), and for each call
 * the check of its state (refused with fmi2Error and a logged reason, the state unchanged) and its transition;
 * the refusals that put the instance into its error state (a start or stop time that is not one, an unknown or
 * mistyped value reference, setting an output, a constant or a fixed parameter after initialization, a
 * parameter that is not a finite number, a doStep that may not be taken); the words of fmi2Instantiate's
 * refusals and of the functions not provided. How a message is logged and what the error state does beyond
 * remembering its message (NaN outputs, telling the Python slave) stay the includer's.
 *
 * Contract: the including file defines, before including this header ONCE,
 *   Inst                     its instance type, with the members phase, failed, failmsg[], have_t_next, t_next,
 *                            last_ok (the header reaches them by name)
 *   FMI2_STATE_MODEL         the model name every message starts with (a const char * expression)
 *   FMI2_STATE_REFUSE(c, ...)  log a printf-style message with fmi2Error (category logStatusError)
 *   fail(c, fmt, ...)        the instance enters its error state, logged (declared before this header)
 */
#ifndef FMI2_STATE_H
#define FMI2_STATE_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

enum { PH_INSTANTIATED, PH_INIT, PH_STEP, PH_TERMINATED };
static const char *STATE_PHASE_NAMES[] = {"the instantiated state (before fmi2EnterInitializationMode)",
                                          "initialization mode", "step mode", "the terminated state"};

/* fmi2Instantiate's refusals (format arguments: the model name, a suffix such as " (native)", and for the GUID
 * the one asked for and the binary's) */
#define STATE_MSG_NOT_COSIM "%s%s: only co-simulation is supported"
#define STATE_MSG_GUID "%s%s: GUID %s does not match this binary's %s (modelDescription.xml and binary from " \
                       "different builds)"
/* a function not provided (declared so in modelDescription.xml; arguments: the model name, what) */
#define STATE_MSG_NOT_PROVIDED "%s: no %s"

/* a double as Python's repr prints it (for messages): nan, inf, the shortest round-trip %g, with ".0"
 * on integral values */
typedef struct { char s[40]; } PyFloat;
static PyFloat pyfloat(double x) {
    PyFloat f;
    if (isnan(x)) { snprintf(f.s, sizeof f.s, "nan"); return f; }
    if (isinf(x)) { snprintf(f.s, sizeof f.s, x > 0 ? "inf" : "-inf"); return f; }
    for (int prec = 1; prec <= 17; prec++) {
        snprintf(f.s, sizeof f.s, "%.*g", prec, x);
        if (strtod(f.s, NULL) == x) break;
    }
    if (!strpbrk(f.s, ".en")) strcat(f.s, ".0");
    return f;
}

/* ---- calls in the wrong state: refused with fmi2Error and a logged reason, the state unchanged ---- */

static fmi2Status state_error(Inst *c, const char *call, const char *allowed) {
    FMI2_STATE_REFUSE(c, "%s: %s in %s: allowed only %s (FMI 2.0 co-simulation state machine); the call is "
                      "refused", FMI2_STATE_MODEL, call, STATE_PHASE_NAMES[c->phase], allowed);
    return fmi2Error;
}

/* fmi2SetupExperiment: right after instantiation or reset; a start time that is not finite or a stop time
 * before it puts the instance into its error state. fmi2OK, else fmi2Error */
static fmi2Status state_setup_checked(Inst *c, double start, int stop_defined, double stop) {
    if (c->phase != PH_INSTANTIATED)
        return state_error(c, "fmi2SetupExperiment", "after fmi2Instantiate or fmi2Reset");
    if (!isfinite(start)) {
        fail(c, "%s: fmi2SetupExperiment with start time %s: the start time must be a finite time; the instance is "
             "now in its error state", FMI2_STATE_MODEL, pyfloat(start).s);
        return fmi2Error;
    }
    if (stop_defined && !(stop >= start)) {
        fail(c, "%s: fmi2SetupExperiment with stop time %s s before the start time %s s; the instance is now in its "
             "error state", FMI2_STATE_MODEL, pyfloat(stop).s, pyfloat(start).s);
        return fmi2Error;
    }
    return fmi2OK;
}

/* each call's check (fmi2OK: allowed now) and its transition (after the call succeeded) */
static fmi2Status state_enter_allowed(Inst *c) {
    if (c->phase != PH_INSTANTIATED)
        return state_error(c, "fmi2EnterInitializationMode", "once, after fmi2Instantiate or fmi2Reset");
    return fmi2OK;
}
static void state_entered(Inst *c) { c->phase = PH_INIT; c->have_t_next = 0; }

static fmi2Status state_exit_allowed(Inst *c) {
    if (c->phase != PH_INIT)
        return state_error(c, "fmi2ExitInitializationMode",
                           "in initialization mode (after fmi2EnterInitializationMode)");
    return fmi2OK;
}
static void state_exited(Inst *c) { c->phase = PH_STEP; }

/* fmi2ExitInitializationMode's answer once the includer's initialization ran (and the state is step mode): a
 * call whose work failed returns fmi2Error (issue 45), never fmi2OK after a logged failure. The instance is in
 * its error state (the cause already logged by fail()); every later doStep is refused as before. */
static fmi2Status state_exit_result(Inst *c) {
    if (!c->failed) return fmi2OK;
    FMI2_STATE_REFUSE(c, "%s: fmi2ExitInitializationMode: the initialization failed (%s); the instance is in its "
                      "error state", FMI2_STATE_MODEL, c->failmsg);
    return fmi2Error;
}

static fmi2Status state_terminate_allowed(Inst *c) {
    if (c->phase != PH_STEP)
        return state_error(c, "fmi2Terminate", "once, in step mode (after fmi2ExitInitializationMode)");
    return fmi2OK;
}
static void state_terminated(Inst *c) { c->phase = PH_TERMINATED; }

/* fmi2Instantiate / fmi2Reset: the instantiated state, no error, no step yet */
static void state_reset(Inst *c) {
    c->phase = PH_INSTANTIATED;
    c->failed = 0;
    c->failmsg[0] = 0;
    c->have_t_next = 0;
    c->last_ok = 0.0;
}

/* getters: not before fmi2EnterInitializationMode */
static fmi2Status state_get_allowed(Inst *c, const char *call) {
    if (c->phase == PH_INSTANTIATED)
        return state_error(c, call, "after fmi2EnterInitializationMode (the start values are in modelDescription.xml)");
    return fmi2OK;
}

/* setters: not after fmi2Terminate */
static fmi2Status state_set_allowed(Inst *c, const char *call) {
    if (c->phase == PH_TERMINATED)
        return state_error(c, call, "before fmi2Terminate (or after fmi2Reset)");
    return fmi2OK;
}

/* ---- refusals that put the instance into its error state ---- */

/* a value reference that is not a variable of type ``want`` (``have``: the type of the variable it is, NULL for
 * none; ``name``: its name): fmi2Error */
static fmi2Status state_bad_vr(Inst *c, const char *call, fmi2ValueReference vr, const char *want, const char *have,
                               const char *name) {
    fail(c, "%s: %s with value references that are not %s variables of this FMU: %u (%s%s%s); the "
         "instance is now in its error state", FMI2_STATE_MODEL, call, want, vr, have ? have : "no such variable",
         have ? " " : "", have ? name : "");
    return fmi2Error;
}

/* may variable ``name`` be set now: inputs at any time; parameters before fmi2ExitInitializationMode (tunable
 * ones at any time); outputs and constants never. 1, else 0 (the instance failed). Called after
 * state_set_allowed (so never in the terminated state) */
static int state_settable(Inst *c, const char *call, const char *name, int is_input, int is_parameter, int is_constant,
                          int is_tunable) {
    if (is_input) return 1;
    if (!is_parameter || is_constant) {
        fail(c, "%s: %s of %s: %s cannot be set; the instance is now in its error state", FMI2_STATE_MODEL, call,
             name, is_constant ? "a constant" : "an output");
        return 0;
    }
    if ((c->phase == PH_STEP || c->phase == PH_TERMINATED) && !is_tunable) {
        fail(c, "%s: %s of %s after initialization: fixed parameters can only be set before "
             "fmi2ExitInitializationMode (FMI 2.0; the value would not take effect); the instance is now in its "
             "error state", FMI2_STATE_MODEL, call, name);
        return 0;
    }
    return 1;
}

/* fmi2SetReal of a parameter that is not a finite number: fmi2Error (inputs: refused at the next doStep) */
static fmi2Status state_nonfinite_parameter(Inst *c, const char *name, double x) {
    fail(c, "%s: fmi2SetReal of %s = %s: parameters that are not finite numbers are refused; the instance "
         "is now in its error state", FMI2_STATE_MODEL, name, pyfloat(x).s);
    return fmi2Error;
}

/* ---- fmi2DoStep ---- */

/* 1 (logged; the instance failed, unless it was in its error state already; the caller answers fmi2Error) when
 * no step may be taken now: before initialization, after fmi2Terminate, a time or step size that is not a
 * finite time (> 0 for the step), in the error state, or a time that is not where the previous step ended */
static int state_step_refused(Inst *c, double t, double H) {
    char why[256];
    why[0] = 0;
    if (c->phase == PH_TERMINATED) snprintf(why, sizeof why, "after fmi2Terminate");
    else if (c->phase != PH_STEP) snprintf(why, sizeof why, "before fmi2ExitInitializationMode");
    else if (!isfinite(t)) snprintf(why, sizeof why, "(the communication point must be a finite time)");
    else if (!(H > 0.0) || !isfinite(H))
        snprintf(why, sizeof why, "with step size %s s (the communication step size must be a positive finite time)",
                 pyfloat(H).s);
    else if (c->failed) {
        FMI2_STATE_REFUSE(c, "%s is in the error state: %s", FMI2_STATE_MODEL, c->failmsg);
        return 1;
    } else if (c->have_t_next && fabs(t - c->t_next) > 1e-3 * H + 1e-12 * fabs(c->t_next))
        snprintf(why, sizeof why, "but the previous step ended at t = %.12g s (communication points must follow each "
                 "other; to go back, restore an FMU state)", c->t_next);
    if (!why[0]) return 0;
    char at[48];
    if (isfinite(t)) snprintf(at, sizeof at, "%.12g", t); else snprintf(at, sizeof at, "%s", pyfloat(t).s);
    if (c->failed)
        FMI2_STATE_REFUSE(c, "%s: fmi2DoStep at t = %s s %s; the instance is now in its error state",
                          FMI2_STATE_MODEL, at, why);
    else
        fail(c, "%s: fmi2DoStep at t = %s s %s; the instance is now in its error state", FMI2_STATE_MODEL, at, why);
    return 1;
}

/* a step from t to t + H done: the next one starts at t + H */
static void state_step_done(Inst *c, double t, double H) {
    c->t_next = t + H;
    c->have_t_next = 1;
    c->last_ok = t + H;
}

#endif
