/* The energy-conserving coupling correction of spring-side ports (gearcontact_fmu/coupling.py,
 * EnergyCorrection), shared by the native FMUs: the GearContact (two ports) and the drivetrain line
 * models (drivetrain/fmu_build/native/line_native.c: one port). The operations are those of coupling.py, in the same
 * order (compile with -ffp-contract=off), so the corrected torques are bit for bit the Python's.
 *
 * The includer's generated build header defines the constants (drivetrain.fmu_build.native_gear.coupling_defines,
 * from coupling.py): CC_TIME_CONSTANT_S, CC_EPS_RAD, CC_CAP_REL, CC_CAP_FLOOR_NM
 * The state is a plain struct (no pointers): the FMUs copy it with their FMU state. */
#ifndef COUPLING_CORRECTION_H
#define COUPLING_CORRECTION_H

#include <math.h>

#define CC_MAX_PORTS 2

typedef struct {
    int n;                                           /* ports (<= CC_MAX_PORTS) */
    int started, enabled;
    double k[CC_MAX_PORTS];                          /* port-spring stiffnesses */
    double mismatch[CC_MAX_PORTS];                   /* cumulative measured work mismatch E (mismatch_J) */
    double held_before[CC_MAX_PORTS], held_last[CC_MAX_PORTS], c_last[CC_MAX_PORTS];
    double phi[CC_MAX_PORTS], phi_end[CC_MAX_PORTS], x[CC_MAX_PORTS], work[CC_MAX_PORTS];
} Correction;

/* EnergyCorrection.reset: tau_initial, the torques the ports return before the first step */
static void correction_reset(Correction *c, const double *tau_initial) {
    for (int q = 0; q < c->n; q++) {
        c->mismatch[q] = 0.0; c->held_before[q] = 0.0; c->c_last[q] = 0.0;
        c->phi[q] = 0.0; c->phi_end[q] = 0.0; c->x[q] = 0.0; c->work[q] = 0.0;
        c->held_last[q] = tau_initial[q];
    }
    c->started = 0;
}

/* Python's max(a, b) for floats */
static double cc_pmax(double a, double b) { return b > a ? b : a; }

/* EnergyCorrection.apply: one call per step, after the port's step */
static void correction_apply(Correction *c, const double *phi, const double *w, double H, const double *tau_mean,
                             const double *tau_base, const double *x_end, double *out) {
    double g = H < CC_TIME_CONSTANT_S ? H / CC_TIME_CONSTANT_S : 1.0;
    double eps2 = CC_EPS_RAD * CC_EPS_RAD;
    for (int q = 0; q < c->n; q++) {
        double phi_q = phi[q], w_q = w[q], tm_q = tau_mean[q];
        if (c->started) {
            double dphi = phi_q - c->phi[q];
            double a = c->x[q] - phi_q;
            double b = c->x[q] - c->phi_end[q];
            double jump = 0.5 * c->k[q] * (a * a - b * b);
            c->mismatch[q] += c->held_before[q] * dphi - c->work[q] + jump;
        }
        double cc = 0.0;
        if (c->enabled) {
            double dd = w_q * H;
            cc = -g * (c->mismatch[q] + c->c_last[q] * dd) * dd / (dd * dd + eps2);
            double cap = CC_CAP_REL * cc_pmax(fabs(tm_q), CC_CAP_FLOOR_NM);
            if (cc > cap) cc = cap;
            else if (cc < -cap) cc = -cap;
            if (!isfinite(cc)) cc = 0.0;
        }
        double o = tau_base[q] + cc;
        out[q] = o;
        c->held_before[q] = c->held_last[q];
        c->held_last[q] = o;
        c->c_last[q] = cc;
        c->phi[q] = phi_q;
        c->phi_end[q] = phi_q + w_q * H;
        c->x[q] = x_end[q];
        c->work[q] = H * tm_q * w_q;
    }
    c->started = 1;
}

#endif
