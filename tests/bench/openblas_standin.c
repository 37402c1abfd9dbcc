/* A stand-in for the scipy-openblas32 library, built by tests/bench/test_blas.py with gcc, so the
 * ctypes binding of hdeem_watch.bench.blas is tested against real C when the wheel is absent.
 *
 * It exports the four symbols the binding calls, with the wheel's signatures (scipy-openblas32
 * prefixes OpenBLAS's names with scipy_ and uses 32-bit int counts):
 *   const char *scipy_openblas_get_config(void);
 *   void scipy_openblas_set_num_threads(int);
 *   int scipy_openblas_get_num_threads(void);
 *   void scipy_cblas_daxpby(int n, double alpha, const double *x, int incx,
 *                           double beta, double *y, int incy);      y = alpha x + beta y
 * Like OpenBLAS, it reads OPENBLAS_CORETYPE and OPENBLAS_NUM_THREADS once, when it is loaded, and
 * reports what it saw in its config string ("... coretype=<value or -> threads=<value or ->").
 */
#include <stdio.h>
#include <stdlib.h>

static char config[256];
static int threads;

__attribute__((constructor)) static void read_load_time_environment(void) {
    const char *coretype = getenv("OPENBLAS_CORETYPE");
    const char *num_threads = getenv("OPENBLAS_NUM_THREADS");
    snprintf(config, sizeof config, "OpenBLAS stand-in coretype=%s threads=%s",
             coretype ? coretype : "-", num_threads ? num_threads : "-");
    threads = num_threads ? atoi(num_threads) : 2;
}

const char *scipy_openblas_get_config(void) { return config; }

void scipy_openblas_set_num_threads(int n) { threads = n; }

int scipy_openblas_get_num_threads(void) { return threads; }

void scipy_cblas_daxpby(int n, double alpha, const double *x, int incx, double beta, double *y,
                        int incy) {
    for (long i = 0; i < n; i++)
        y[i * incy] = alpha * x[i * incx] + beta * y[i * incy];
}
