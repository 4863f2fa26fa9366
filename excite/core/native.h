/* The native module of excite (excite._native): the evaluator's inner loops in C, compiled when
 * the package is built or installed (setup.py), or for a source checkout on first use
 * (excite/core/native.py). Every C file of the package is part of it.
 *
 * Arguments arrive as Python objects with the buffer protocol (numpy arrays): C-contiguous
 * float64 ('d') or int64 ('q'), checked here; outputs are arrays the caller allocated. The loops
 * run without the GIL, so that the chunks of a drive run in parallel on threads.
 */
#ifndef EXCITE_NATIVE_H
#define EXCITE_NATIVE_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define MAX_ARGS 48 /* inputs and outputs of one generated kernel's call */

/* The buffers of one call: released together when the call ends (grown as needed). */
typedef struct {
    Py_buffer *view;
    int n, cap;
} Args;

/* A C-contiguous buffer of ``type`` ('d': float64, 'q': int64) with ``ndim`` dimensions (-1:
 * any), writable where asked; NULL with a TypeError naming ``name`` otherwise. */
Py_buffer *native_array(Args *a, PyObject *o, char type, int ndim, int writable, const char *name);
void native_release(Args *a);
/* A Python int, float or bool argument; -1 / NaN with an exception set where it is none. */
long native_long(PyObject *o);
double native_double(PyObject *o);

#define D(view) ((double *)(view)->buf)
#define Q(view) ((int64_t *)(view)->buf)
#define SHAPE(view, i) ((view)->shape[i])

/* Every function of the module, by the file that defines it. */
#define NATIVE_FUNCTION(name) PyObject *name(PyObject *self, PyObject *const *args, Py_ssize_t nargs)

/* motion/kernels.c */
NATIVE_FUNCTION(native_segments);
NATIVE_FUNCTION(native_rotation_samples);
NATIVE_FUNCTION(native_imu_samples);
/* information/kernels.c */
NATIVE_FUNCTION(native_accumulate);
NATIVE_FUNCTION(native_eliminate);
NATIVE_FUNCTION(native_eliminate_slabs);
NATIVE_FUNCTION(native_theta_diagonal);
NATIVE_FUNCTION(native_local_maps);
NATIVE_FUNCTION(native_to_local);
/* factors/generated.c */
NATIVE_FUNCTION(native_generated);
NATIVE_FUNCTION(native_run);
NATIVE_FUNCTION(native_fold);

#define CHECK_NARGS(n_expected, fname)                                                          \
    if (nargs != (n_expected)) {                                                                \
        PyErr_Format(PyExc_TypeError, fname "() takes %d arguments (%zd given)", (n_expected),   \
                     nargs);                                                                    \
        return NULL;                                                                            \
    }

#endif
