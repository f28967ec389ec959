/* The master's fixed-step Jacobi loop over one chunk of steps, in C (drivetrain/cosim/stepper.py).
 *
 * Per step kk, exactly what the Python loop in Master.run does, in the same order:
 *   y[ext_idx[j]] = ext_table[kk][j]            (external profiles)
 *   u[j] = y[gather[j]]                          (inputs from the previous outputs)
 *   per FMU i: fmi2SetReal (if it has inputs), fmi2DoStep(c, (double)kk * H, H, fmi2True),
 *              fmi2GetReal (if it has outputs)
 *   rec[kk + 1][:] = y[:ny]
 * It returns at the first non-zero status with out[0] = step, out[1] = FMU index, out[2] = call
 * (0 SetReal, 1 DoStep, 2 GetReal), out[3] = status; the caller handles it and resumes. */
#include <stddef.h>
#include <stdint.h>
#include <string.h>

typedef int (*set_real_t)(void *, const unsigned int *, size_t, const double *);
typedef int (*do_step_t)(void *, double, double, int);
typedef int (*get_real_t)(void *, const unsigned int *, size_t, double *);

typedef struct {
    void *c;                     /* fmi2Component */
    set_real_t set_real;
    do_step_t do_step;
    get_real_t get_real;
    const unsigned int *vr_in;
    size_t n_in;
    const double *u;             /* this FMU's inputs in the master's u buffer */
    const unsigned int *vr_out;
    size_t n_out;
    double *y;                   /* this FMU's outputs in the master's y buffer */
} stepper_fmu;

__attribute__((visibility("default")))
int stepper_run_chunk(int64_t k, int64_t k_end, double H, const stepper_fmu *fmus, int64_t n_fmus,
                      double *y, double *u, const intptr_t *gather, int64_t nu,
                      const intptr_t *ext_idx, int64_t n_ext, const double *ext_table,
                      double *rec, int64_t ny, int64_t *out)
{
    for (int64_t kk = k; kk < k_end; kk++) {
        double t = (double)kk * H;
        if (n_ext > 0) {
            const double *row = ext_table + kk * n_ext;
            for (int64_t j = 0; j < n_ext; j++)
                y[ext_idx[j]] = row[j];
        }
        for (int64_t j = 0; j < nu; j++)
            u[j] = y[gather[j]];
        for (int64_t i = 0; i < n_fmus; i++) {
            const stepper_fmu *f = fmus + i;
            int st;
            if (f->n_in) {
                st = f->set_real(f->c, f->vr_in, f->n_in, f->u);
                if (st) { out[0] = kk; out[1] = i; out[2] = 0; out[3] = st; return st; }
            }
            st = f->do_step(f->c, t, H, 1);
            if (st) { out[0] = kk; out[1] = i; out[2] = 1; out[3] = st; return st; }
            if (f->n_out) {
                st = f->get_real(f->c, f->vr_out, f->n_out, f->y);
                if (st) { out[0] = kk; out[1] = i; out[2] = 2; out[3] = st; return st; }
            }
        }
        if (ny > 0)
            memcpy(rec + (kk + 1) * ny, y, (size_t)ny * sizeof(double));
    }
    return 0;
}
