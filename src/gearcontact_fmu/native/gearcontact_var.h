/* gearcontact_var.h: one variable of the native GearContact's model description. The table of them, GC_VARS
 * (indexed by value reference), and the build's GUID, GC_GUID, are generated per build in gearcontact_values.c;
 * gearcontact_native.c, the same for every build, is compiled once and linked with each build's values. */
#ifndef GEARCONTACT_VAR_H
#define GEARCONTACT_VAR_H

typedef struct {
    const char *name;
    const char *type;            /* "Real" | "Integer" | "Boolean" | "String" */
    int is_input, is_parameter, is_counter;
    int nan_on_failure;          /* an output that becomes NaN when the instance fails (NAN_ON_FAILURE) */
    int fixed_by_build;          /* a parameter the contact map depends on: only its built value is accepted */
    double real_start;
    int int_start;               /* Integer and Boolean */
    const char *string_start;
} GcVar;

/* compiled with FMI2_FUNCTION_PREFIX (several source FMUs linked into one binary): the build's two tables are
 * prefixed like the FMI functions, so that two GearContact builds do not clash */
#ifdef FMI2_FUNCTION_PREFIX
#include "fmi2Functions.h"
#define GC_GUID fmi2FullName(GC_GUID)
#define GC_VARS fmi2FullName(GC_VARS)
#endif

#endif
