/* The table of the generated kernels (excite/factors/generated.c). */
#ifndef EXCITE_GENERATED_H
#define EXCITE_GENERATED_H

typedef struct {
    const char *name;
    void *f;    /* int f(const double **arg, double **res, long long *iw, double *w, int mem) */
    void *work; /* int f_work(long long *sz_arg, long long *sz_res, long long *sz_iw, long long *sz_w) */
    int n_in, n_out;
    const long long *nnz_in, *nnz_out;
} excite_kernel;

extern const excite_kernel excite_kernels[];
extern const int excite_n_kernels;

/* A kernel of the table that also runs on several factors at once (excite/factors/generate.py:
 * batched); state: a fold's step, its state interleaved. */
typedef struct {
    const char *name;
    void *f; /* int f(const double **arg, double **res) */
    int state;
} excite_batched_kernel;

extern const excite_batched_kernel excite_batched[];
extern const int excite_n_batched;

#endif
