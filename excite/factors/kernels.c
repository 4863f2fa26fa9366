/* The driver of the generated factor kernels: a generated function (CasADi's C calling
 * convention: f(arg, res, iw, w, mem)) applied to every factor of a batch, each input either
 * shared by all factors or one row per factor, each output one row per factor. The kernels
 * themselves are generated from the kinds' statements (excite/factors/generated.c, by
 * excite/factors/generate.py; never edited by hand); a kind without one here is generated and
 * compiled on demand, and reaches the same driver through its function's address. */
#include "../core/native.h"
#include <stdlib.h>

#include "generated.h"

typedef int (*kernel_fn)(const double **arg, double **res, long long *iw, double *w, int mem);
typedef int (*work_fn)(long long *sz_arg, long long *sz_res, long long *sz_iw, long long *sz_w);

static int resolve(PyObject *k, kernel_fn *f, work_fn *work);

/* generated() → {name: (nnz of each input, nnz of each output)} of the kernels compiled in */
NATIVE_FUNCTION(native_generated) {
    (void)args;
    if (nargs != 0) {
        PyErr_SetString(PyExc_TypeError, "generated() takes no arguments");
        return NULL;
    }
    PyObject *out = PyDict_New();
    for (int k = 0; out && k < excite_n_kernels; ++k) {
        const excite_kernel *K = &excite_kernels[k];
        PyObject *ins = PyTuple_New(K->n_in), *outs = PyTuple_New(K->n_out);
        for (int i = 0; ins && i < K->n_in; ++i) PyTuple_SET_ITEM(ins, i, PyLong_FromLongLong(K->nnz_in[i]));
        for (int i = 0; outs && i < K->n_out; ++i) PyTuple_SET_ITEM(outs, i, PyLong_FromLongLong(K->nnz_out[i]));
        PyObject *pair = (ins && outs) ? PyTuple_Pack(2, ins, outs) : NULL;
        Py_XDECREF(ins);
        Py_XDECREF(outs);
        if (!pair || PyDict_SetItemString(out, K->name, pair) < 0) {
            Py_XDECREF(pair);
            Py_DECREF(out);
            return NULL;
        }
        Py_DECREF(pair);
    }
    return out;
}

typedef int (*batch_fn)(const double **arg, double **res);
#define LANES 4 /* factors a batched kernel takes at once (excite/factors/generate.py: LANES) */

/* The batched version of a kernel compiled in by that name (excite_batched) that is a fold's step
 * (state 1) or not (state 0), or NULL. */
static batch_fn batched(PyObject *k, int state) {
    const char *name = PyUnicode_Check(k) ? PyUnicode_AsUTF8(k) : NULL;
    for (int i = 0; name && i < excite_n_batched; ++i)
        if (strcmp(excite_batched[i].name, name) == 0 && excite_batched[i].state == state)
            return (batch_fn)excite_batched[i].f;
    return NULL;
}


/* run(kernel, first, inputs, offsets, outputs): the kernel (a name compiled in, or (address of f,
 * address of f_work) of one compiled on demand) over every factor k of a batch, whose first
 * keyframe is first[k]. Each input is a float64 array of rows: offsets[i] = -1, one row shared by
 * every factor; -2, row k for factor k; a ≥ 0, row first[k] + a (a keyframe of the factor, in a
 * table of every keyframe's inputs). Each output is a float64 array of one row per factor. */
NATIVE_FUNCTION(native_run) {
    CHECK_NARGS(5, "run");
    kernel_fn f;
    work_fn work;
    if (resolve(args[0], &f, &work)) return NULL;
    if (!PyTuple_Check(args[2]) || !PyTuple_Check(args[3]) || !PyTuple_Check(args[4]) ||
        PyTuple_GET_SIZE(args[2]) != PyTuple_GET_SIZE(args[3])) {
        PyErr_SetString(PyExc_TypeError, "inputs, offsets and outputs: tuples (one offset per input)");
        return NULL;
    }
    Py_ssize_t n_in = PyTuple_GET_SIZE(args[2]), n_out = PyTuple_GET_SIZE(args[4]);
    if (n_in + n_out + 1 > MAX_ARGS) {
        PyErr_SetString(PyExc_ValueError, "too many inputs and outputs");
        return NULL;
    }
    Args a = {.n = 0};
    Py_buffer *fv = native_array(&a, args[1], 'q', 1, 0, "first");
    if (!fv) return native_release(&a), NULL;
    Py_ssize_t n = SHAPE(fv, 0);
    const int64_t *first = Q(fv);
    const double *in[MAX_ARGS];
    Py_ssize_t width[MAX_ARGS], offset[MAX_ARGS];
    double *out[MAX_ARGS];
    Py_ssize_t out_row[MAX_ARGS];
    for (Py_ssize_t i = 0; i < n_in; ++i) {
        Py_buffer *v = native_array(&a, PyTuple_GET_ITEM(args[2], i), 'd', -1, 0, "input");
        if (!v) return native_release(&a), NULL;
        in[i] = D(v);
        offset[i] = PyLong_AsSsize_t(PyTuple_GET_ITEM(args[3], i));
        if (PyErr_Occurred()) return native_release(&a), NULL;
        Py_ssize_t rows = v->ndim > 1 ? v->shape[0] : 1, len = v->len / 8;
        width[i] = rows ? len / rows : 0;
        for (Py_ssize_t k = 0; k < n; ++k) {
            Py_ssize_t row = offset[i] == -1 ? 0 : offset[i] == -2 ? k : first[k] + offset[i];
            if (offset[i] < -2 || row < 0 || row >= (rows ? rows : 1)) {
                PyErr_Format(PyExc_ValueError, "input %zd has no row %zd for factor %zd", i, row, k);
                return native_release(&a), NULL;
            }
        }
    }
    for (Py_ssize_t i = 0; i < n_out; ++i) {
        Py_buffer *v = native_array(&a, PyTuple_GET_ITEM(args[4], i), 'd', -1, 1, "output");
        if (!v) return native_release(&a), NULL;
        out[i] = D(v);
        out_row[i] = n > 0 ? v->len / 8 / n : 0;
    }
    long long sz_arg = 0, sz_res = 0, sz_iw = 0, sz_w = 0;
    work(&sz_arg, &sz_res, &sz_iw, &sz_w);
    if (sz_arg < n_in || sz_res < n_out) {
        PyErr_Format(PyExc_ValueError, "the kernel takes %lld inputs and %lld outputs (given %zd and %zd)", sz_arg,
                     sz_res, n_in, n_out);
        return native_release(&a), NULL;
    }
    batch_fn f4 = batched(args[0], 0);
    int rc = 0;
    Py_BEGIN_ALLOW_THREADS;
    const double **arg = calloc((size_t)sz_arg + 1, sizeof(double *));
    double **res = calloc((size_t)sz_res + 1, sizeof(double *));
    long long *iw = malloc(sizeof(long long) * ((size_t)sz_iw + 1));
    double *w = malloc(sizeof(double) * ((size_t)sz_w + 1));
    if (!arg || !res || !iw || !w) {
        rc = -1;
    } else {
        Py_ssize_t k = 0;
        for (; f4 && k + LANES <= n && !rc; k += LANES) { /* LANES factors at once, as far as they go */
            const double *arg4[LANES * MAX_ARGS];
            double *res4[LANES * MAX_ARGS];
            for (int l = 0; l < LANES; ++l) {
                for (Py_ssize_t i = 0; i < n_in; ++i)
                    arg4[LANES * i + l] =
                        in[i] + width[i] * (offset[i] == -1 ? 0 : offset[i] == -2 ? k + l : first[k + l] + offset[i]);
                for (Py_ssize_t i = 0; i < n_out; ++i) res4[LANES * i + l] = out[i] + (k + l) * out_row[i];
            }
            if (f4(arg4, res4)) rc = 1;
        }
        for (; k < n && !rc; ++k) {
            for (Py_ssize_t i = 0; i < n_in; ++i)
                arg[i] = in[i] + width[i] * (offset[i] == -1 ? 0 : offset[i] == -2 ? k : first[k] + offset[i]);
            for (Py_ssize_t i = 0; i < n_out; ++i) res[i] = out[i] + k * out_row[i];
            if (f(arg, res, iw, w, 0)) rc = 1;
        }
    }
    free(arg);
    free(res);
    free(iw);
    free(w);
    Py_END_ALLOW_THREADS;
    native_release(&a);
    if (rc == -1) return PyErr_NoMemory();
    if (rc) {
        PyErr_SetString(PyExc_RuntimeError, "a generated kernel failed");
        return NULL;
    }
    Py_RETURN_NONE;
}

static int resolve(PyObject *k, kernel_fn *f, work_fn *work) {
    if (PyUnicode_Check(k)) {
        const char *name = PyUnicode_AsUTF8(k);
        for (int i = 0; name && i < excite_n_kernels; ++i)
            if (strcmp(excite_kernels[i].name, name) == 0) {
                *f = (kernel_fn)excite_kernels[i].f;
                *work = (work_fn)excite_kernels[i].work;
                return 0;
            }
        PyErr_Format(PyExc_KeyError, "no generated kernel named %s", name ? name : "?");
        return -1;
    }
    if (PyTuple_Check(k) && PyTuple_GET_SIZE(k) == 2) {
        *f = (kernel_fn)PyLong_AsVoidPtr(PyTuple_GET_ITEM(k, 0));
        *work = (work_fn)PyLong_AsVoidPtr(PyTuple_GET_ITEM(k, 1));
        if (PyErr_Occurred() || !*f || !*work) return -1;
        return 0;
    }
    PyErr_SetString(PyExc_TypeError, "kernel: a name, or (address of f, address of f_work)");
    return -1;
}

/* The end of the fold of the interval whose samples start at i0, from its state st after the pairs
 * of samples down to s (st[ns … 2ns) free): sample 0 where one is left (s == 0), then finish into
 * out. Returns 0, or 1 where a kernel failed. */
static int fold_end(kernel_fn step, kernel_fn finish, double *st, long ns, long s, const double *Rm,
                    const double *Fm, const double *cv, Py_ssize_t i0, long n, double *out, long long *iw, double *w) {
    const double *arg[8];
    double *res[2];
    double *cur = st;
    if (s == 0) {
        arg[0] = st, arg[1] = Rm + 9 * i0, arg[2] = Rm + 9 * i0, arg[3] = Fm + 3 * i0, arg[4] = cv;
        res[0] = st + ns;
        if (step(arg, res, iw, w, 0)) return 1;
        cur = st + ns;
    }
    arg[0] = cur, arg[1] = Rm + 9 * i0, arg[2] = Rm + 9 * (i0 + n), arg[3] = cv;
    res[0] = out;
    return finish(arg, res, iw, w, 0) ? 1 : 0;
}

/* fold(step, step2, finish, first, per_keyframe, n, n_state, imu_R, imu_f, c, out): for every
 * interval starting at keyframe first[k] (its samples i0 … i0 + n, i0 = first[k]·per_keyframe),
 * the state starts at zero and takes the samples s = n − 1 down to 0: step2(state, R_i0, R_s, f_s,
 * R_{s−1}, f_{s−1}, c) two at a time, step(state, R_i0, R_s, f_s, c) for a last one; out[k] =
 * finish(state, R_i0, R_{i0+n}, c). */
NATIVE_FUNCTION(native_fold) {
    CHECK_NARGS(11, "fold");
    kernel_fn step, step2, finish;
    work_fn step_work, step2_work, finish_work;
    if (resolve(args[0], &step, &step_work) || resolve(args[1], &step2, &step2_work) ||
        resolve(args[2], &finish, &finish_work))
        return NULL;
    Args a = {.n = 0};
    Py_buffer *first = native_array(&a, args[3], 'q', 1, 0, "first");
    Py_buffer *R = first ? native_array(&a, args[7], 'd', 3, 0, "imu_R") : NULL;
    Py_buffer *F = R ? native_array(&a, args[8], 'd', 2, 0, "imu_f") : NULL;
    Py_buffer *c = F ? native_array(&a, args[9], 'd', 1, 0, "c") : NULL;
    Py_buffer *out = c ? native_array(&a, args[10], 'd', 2, 1, "out") : NULL;
    if (!out) return native_release(&a), NULL;
    long per = native_long(args[4]), n = native_long(args[5]), ns = native_long(args[6]);
    if (PyErr_Occurred()) return native_release(&a), NULL;
    Py_ssize_t N = SHAPE(first, 0), M = SHAPE(R, 0), width = SHAPE(out, 1);
    const int64_t *fi = Q(first);
    for (Py_ssize_t k = 0; k < N; ++k)
        if (fi[k] < 0 || fi[k] * per + n > M - 1) {
            PyErr_SetString(PyExc_ValueError, "fold: an interval reaches beyond the IMU samples");
            return native_release(&a), NULL;
        }
    if (SHAPE(out, 0) != N || SHAPE(F, 0) < M - 1) {
        PyErr_SetString(PyExc_ValueError, "fold: out must have a row per interval, imu_f a row per sample");
        return native_release(&a), NULL;
    }
    long long sz[3][4];
    step_work(&sz[0][0], &sz[0][1], &sz[0][2], &sz[0][3]);
    step2_work(&sz[1][0], &sz[1][1], &sz[1][2], &sz[1][3]);
    finish_work(&sz[2][0], &sz[2][1], &sz[2][2], &sz[2][3]);
    long long sz_iw = 0, sz_w = 0;
    for (int i = 0; i < 3; ++i) {
        sz_iw = sz[i][2] > sz_iw ? sz[i][2] : sz_iw;
        sz_w = sz[i][3] > sz_w ? sz[i][3] : sz_w;
    }
    batch_fn step2_x4 = batched(args[1], 1);
    int rc = 0;
    const double *Rm = D(R), *Fm = D(F), *cv = D(c);
    double *o = D(out);
    Py_BEGIN_ALLOW_THREADS;
    long long *iw = malloc(sizeof(long long) * ((size_t)sz_iw + 1));
    double *w = malloc(sizeof(double) * ((size_t)sz_w + 1));
    double *st = malloc(sizeof(double) * (2 * (size_t)ns + 1));
    double *st4 = malloc(sizeof(double) * (2 * LANES * (size_t)ns + 1));
    if (!iw || !w || !st || !st4) {
        rc = -1;
    } else {
        const double *arg[8], *arg4[7 * LANES];
        double *res[2];
        Py_ssize_t k = 0;
        /* LANES intervals at once (their states interleaved), as far as they go: the pairs of samples */
        for (; step2_x4 && k + LANES <= N && !rc; k += LANES) {
            double *cur = st4, *nxt = st4 + LANES * ns, *t;
            memset(cur, 0, sizeof(double) * LANES * ns);
            long s = n - 1;
            for (; s >= 1; s -= 2) {
                for (int l = 0; l < LANES; ++l) {
                    Py_ssize_t i0 = (Py_ssize_t)fi[k + l] * per;
                    arg4[LANES + l] = Rm + 9 * i0, arg4[2 * LANES + l] = Rm + 9 * (i0 + s);
                    arg4[3 * LANES + l] = Fm + 3 * (i0 + s), arg4[4 * LANES + l] = Rm + 9 * (i0 + s - 1);
                    arg4[5 * LANES + l] = Fm + 3 * (i0 + s - 1), arg4[6 * LANES + l] = cv;
                }
                arg4[0] = cur;
                res[0] = nxt;
                if (step2_x4(arg4, res)) rc = 1;
                t = cur, cur = nxt, nxt = t;
            }
            for (int l = 0; l < LANES && !rc; ++l) { /* each interval's state on its own: the rest as below */
                for (long e = 0; e < ns; ++e) st[e] = cur[LANES * e + l];
                rc = fold_end(step, finish, st, ns, s, Rm, Fm, cv, (Py_ssize_t)fi[k + l] * per, n, o + (k + l) * width,
                              iw, w);
            }
        }
        for (; k < N && !rc; ++k) {
            Py_ssize_t i0 = (Py_ssize_t)fi[k] * per;
            double *cur = st, *nxt = st + ns, *t;
            memset(cur, 0, sizeof(double) * ns);
            long s = n - 1;
            for (; s >= 1; s -= 2) {
                arg[0] = cur, arg[1] = Rm + 9 * i0, arg[2] = Rm + 9 * (i0 + s), arg[3] = Fm + 3 * (i0 + s);
                arg[4] = Rm + 9 * (i0 + s - 1), arg[5] = Fm + 3 * (i0 + s - 1), arg[6] = cv;
                res[0] = nxt;
                if (step2(arg, res, iw, w, 0)) rc = 1;
                t = cur, cur = nxt, nxt = t;
            }
            if (cur != st) memcpy(st, cur, sizeof(double) * ns);
            if (!rc) rc = fold_end(step, finish, st, ns, s, Rm, Fm, cv, i0, n, o + k * width, iw, w);
        }
    }
    free(iw);
    free(w);
    free(st);
    free(st4);
    Py_END_ALLOW_THREADS;
    native_release(&a);
    if (rc == -1) return PyErr_NoMemory();
    if (rc) {
        PyErr_SetString(PyExc_RuntimeError, "a generated kernel failed");
        return NULL;
    }
    Py_RETURN_NONE;
}
