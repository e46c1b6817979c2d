/* Thin glue to UMFPACK (SuiteSparse): one opaque handle per matrix pattern.
 *
 * The Fortran side stores matrices in CSR with 1-based indices. UMFPACK reads compressed
 * columns, so the CSR arrays of A are handed over as the CSC arrays of A^T and the solve asks
 * for A x = b through UMFPACK_At. The symbolic factorization depends only on the pattern, so
 * it is kept in the handle and reused for every numeric factorization until the pattern
 * changes (a new handle). Every function but the library description returns an UMFPACK status
 * code (0 = ok); nothing here prints or stops. */
#define _GNU_SOURCE /* RTLD_DEFAULT, RTLD_NOLOAD, dladdr */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <umfpack.h>

typedef struct {
  int n;
  int *ap; /* 0-based row pointers (as UMFPACK column pointers) */
  int *ai; /* 0-based column indices */
  void *symbolic;
  void *numeric;
  double control[UMFPACK_CONTROL];
  double info[UMFPACK_INFO];
} twomem_umf_t;

/* The UMFPACK version and the BLAS its dense kernels run on, into text (at most cap bytes, NUL
 * included), for `twomem --version` and the result file. A factorization spends its time in the
 * dense products of its frontal matrices, which Debian's default reference BLAS computes about
 * half as fast as OpenBLAS (docs/performance.md, "Measuring"): that is why
 * scripts/bootstrap.sh installs OpenBLAS, and why a run should say which one it got. The BLAS
 * is named by the file that defines the dgemm_ the process resolves (the one UMFPACK calls: an
 * LD_LIBRARY_PATH or a Debian alternative can put another library there than the one the build
 * saw), and OpenBLAS's own description is added when that file is OpenBLAS or loads it. */
void twomem_umf_library(char *text, size_t cap) {
  Dl_info info;
  void *dgemm = dlsym(RTLD_DEFAULT, "dgemm_");
  if (dgemm == NULL || dladdr(dgemm, &info) == 0 || info.dli_fname == NULL) {
    snprintf(text, cap, "%d.%d.%d, BLAS not found", UMFPACK_MAIN_VERSION, UMFPACK_SUB_VERSION,
             UMFPACK_SUBSUB_VERSION);
    return;
  }
  char *path = realpath(info.dli_fname, NULL);
  const char *(*openblas_config)(void) = NULL;
  void *blas = dlopen(info.dli_fname, RTLD_LAZY | RTLD_NOLOAD);
  /* (the POSIX way to turn dlsym's object pointer into a function pointer) */
  if (blas != NULL) *(void **)(&openblas_config) = dlsym(blas, "openblas_get_config");
  snprintf(text, cap, "%d.%d.%d, BLAS %s%s%s%s", UMFPACK_MAIN_VERSION, UMFPACK_SUB_VERSION,
           UMFPACK_SUBSUB_VERSION, path != NULL ? path : info.dli_fname, openblas_config ? " (" : "",
           openblas_config ? openblas_config() : "", openblas_config ? ")" : "");
  if (blas != NULL) dlclose(blas);
  free(path);
}

/* Analyse the pattern (n, row_ptr, col: 1-based CSR) with a nested-dissection (METIS) ordering,
 * or UMFPACK's minimum-degree choice (AMD/COLAMD) when minimum_degree is non-zero. On success
 * *handle owns copies. */
int twomem_umf_analyse(int n, const int *row_ptr, const int *col, const double *val, int minimum_degree,
                       void **handle) {
  *handle = NULL;
  twomem_umf_t *h = calloc(1, sizeof *h);
  if (!h) return UMFPACK_ERROR_out_of_memory;
  int nnz = row_ptr[n] - 1;
  h->n = n;
  h->ap = malloc(sizeof(int) * (size_t)(n + 1));
  h->ai = malloc(sizeof(int) * (size_t)(nnz > 0 ? nnz : 1));
  if (!h->ap || !h->ai) {
    free(h->ap);
    free(h->ai);
    free(h);
    return UMFPACK_ERROR_out_of_memory;
  }
  for (int i = 0; i <= n; ++i) h->ap[i] = row_ptr[i] - 1;
  for (int k = 0; k < nnz; ++k) h->ai[k] = col[k] - 1;
  umfpack_di_defaults(h->control);
  /* Nested dissection suits 2D finite-element graphs: METIS ordering gives the Newton systems
   * smaller factors, and far shorter factorizations, than UMFPACK's default AMD/COLAMD choice
   * (docs/performance.md). A matrix factorized once per run (minimum_degree) saves less by it
   * than METIS's own analysis costs. */
  h->control[UMFPACK_ORDERING] = minimum_degree ? UMFPACK_ORDERING_AMD : UMFPACK_ORDERING_METIS;
  int status = umfpack_di_symbolic(n, n, h->ap, h->ai, val, &h->symbolic, h->control, h->info);
  if (status != UMFPACK_OK) {
    free(h->ap);
    free(h->ai);
    free(h);
    return status;
  }
  *handle = h;
  return UMFPACK_OK;
}

/* Numeric factorization for new values on the analysed pattern. */
int twomem_umf_factor(void *handle, const double *val) {
  twomem_umf_t *h = handle;
  if (!h) return UMFPACK_ERROR_argument_missing;
  if (h->numeric) umfpack_di_free_numeric(&h->numeric);
  return umfpack_di_numeric(h->ap, h->ai, val, h->symbolic, &h->numeric, h->control, h->info);
}

/* Solve A x = b with the last factorization and at most refinement_steps steps of iterative
 * refinement (UMFPACK's default is 2; val must be the factored values, which refinement reads). */
int twomem_umf_solve(void *handle, const double *val, const double *b, double *x, int refinement_steps) {
  twomem_umf_t *h = handle;
  if (!h || !h->numeric) return UMFPACK_ERROR_argument_missing;
  h->control[UMFPACK_IRSTEP] = refinement_steps;
  return umfpack_di_solve(UMFPACK_At, h->ap, h->ai, val, x, b, h->numeric, h->control, h->info);
}

/* Reciprocal condition number estimate of the last factorization (UMFPACK_RCOND). */
double twomem_umf_rcond(void *handle) {
  twomem_umf_t *h = handle;
  return h ? h->info[UMFPACK_RCOND] : 0.0;
}

void twomem_umf_free(void **handle) {
  twomem_umf_t *h = *handle;
  if (!h) return;
  if (h->numeric) umfpack_di_free_numeric(&h->numeric);
  if (h->symbolic) umfpack_di_free_symbolic(&h->symbolic);
  free(h->ap);
  free(h->ai);
  free(h);
  *handle = NULL;
}
