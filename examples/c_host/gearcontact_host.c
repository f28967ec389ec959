/* Minimal non-Python FMI 2.0 co-simulation host for the GearContact FMU (the situation of a C/C++
 * tool such as a commercial simulator loading a pythonfmu FMU).
 *
 * It loads <unzipped FMU>/binaries/linux64/GearContact.so, instantiates, sets two parameters by value
 * reference (given on the command line), replays the scenario of examples/gearcontact_input.csv
 * (flange_a ramped to 0.01 rad in 0.02 s, flange_b held) at H = 1e-4 s for 0.3 s and prints the final
 * flange torques. Build and run: examples/c_host/run_c_host.sh (needs LD_PRELOAD of libpython and
 * PYTHONPATH to the site-packages, see docs/FMU.md).
 *
 * usage: gearcontact_host <unzipped FMU dir> <vr flange_a_phi> <vr flange_a_w> <vr flange_b_phi>
 *                         <vr flange_b_w> <vr flange_a_tau> <vr flange_b_tau> [nan_at_step]
 */
#include <dlfcn.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                   fmi2String category, fmi2String message, ...) {
    (void)env;
    (void)category;
    printf("[%s status %d] %s\n", instance, (int)status, message);
}

#define LOAD(name)                                                        \
    name##TYPE* name = (name##TYPE*)dlsym(lib, #name);                    \
    if (!name) { fprintf(stderr, "missing %s\n", #name); return 2; }

int main(int argc, char** argv) {
    if (argc < 8) {
        fprintf(stderr, "usage: %s fmu_dir vr_phi_a vr_w_a vr_phi_b vr_w_b vr_tau_a vr_tau_b [nan_at_step]\n", argv[0]);
        return 2;
    }
    char path[4096], uri[4200];
    snprintf(path, sizeof path, "%s/binaries/linux64/GearContact.so", argv[1]);
    snprintf(uri, sizeof uri, "file://%s/resources", argv[1]);
    fmi2ValueReference vin[4], vout[2];
    for (int i = 0; i < 4; i++) vin[i] = (fmi2ValueReference)atoi(argv[2 + i]);
    for (int i = 0; i < 2; i++) vout[i] = (fmi2ValueReference)atoi(argv[6 + i]);
    int nan_at = argc > 8 ? atoi(argv[8]) : -1;

    void* lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "dlopen: %s\n", dlerror()); return 2; }
    LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal) LOAD(fmi2GetReal) LOAD(fmi2DoStep)
    LOAD(fmi2Terminate) LOAD(fmi2FreeInstance)

    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("gear", fmi2CoSimulation, "", uri, &cb, fmi2False, fmi2True);
    if (!c) { fprintf(stderr, "instantiate failed\n"); return 3; }
    fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
    fmi2EnterInitializationMode(c);
    fmi2ExitInitializationMode(c);

    const double H = 1e-4;
    fmi2Real out[2] = {0.0, 0.0};
    int rc = 0;
    for (int n = 0; n < 3000; n++) {
        double t = n * H;
        fmi2Real u[4] = {t < 0.02 ? 0.5 * t : 0.01, t < 0.02 ? 0.5 : 0.0, 0.0, 0.0};
        if (n == nan_at) u[0] = NAN;
        fmi2SetReal(c, vin, 4, u);
        fmi2Status s = fmi2DoStep(c, t, H, fmi2True);
        if (s != fmi2OK) {
            printf("doStep at t = %g returned status %d\n", t, (int)s);
            rc = 10 + (int)s;
            break;
        }
        fmi2GetReal(c, vout, 2, out);
    }
    printf("flange_a_tau = %.6f N.m, flange_b_tau = %.6f N.m\n", out[0], out[1]);
    fmi2Terminate(c);
    fmi2FreeInstance(c);
    return rc;
}
