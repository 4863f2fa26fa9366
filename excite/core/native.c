/* The module object of excite._native and the argument helpers of native.h. */
#include "native.h"

#ifndef EXCITE_NATIVE_SOURCES
#define EXCITE_NATIVE_SOURCES "unknown"
#endif

static int type_matches(const Py_buffer *v, char type) {
    if (v->itemsize != 8 || v->format == NULL) return 0;
    const char *f = v->format;
    if (*f == '<' || *f == '=' || *f == '@') f++;
    if (f[1] != '\0') return 0;
    if (type == 'd') return f[0] == 'd';
    return f[0] == 'q' || (f[0] == 'l' && sizeof(long) == 8);
}

Py_buffer *native_array(Args *a, PyObject *o, char type, int ndim, int writable, const char *name) {
    if (a->n >= a->cap) {
        int cap = a->cap ? 2 * a->cap : 16;
        Py_buffer *grown = PyMem_Realloc(a->view, sizeof(Py_buffer) * (size_t)cap);
        if (!grown) {
            PyErr_NoMemory();
            return NULL;
        }
        a->view = grown;
        a->cap = cap;
    }
    Py_buffer *v = &a->view[a->n];
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(o, v, flags) != 0) {
        PyErr_Clear();
        PyErr_Format(PyExc_TypeError, "%s: a C-contiguous%s %s array is needed", name,
                     writable ? " writable" : "", type == 'd' ? "float64" : "int64");
        return NULL;
    }
    a->n++;
    if (!type_matches(v, type) || (ndim >= 0 && v->ndim != ndim)) {
        PyErr_Format(PyExc_TypeError, "%s: a %s array of %d dimensions is needed (got format %s, %d dimensions)",
                     name, type == 'd' ? "float64" : "int64", ndim, v->format ? v->format : "?", v->ndim);
        return NULL;
    }
    return v;
}

void native_release(Args *a) {
    for (int i = 0; i < a->n; ++i) PyBuffer_Release(&a->view[i]);
    PyMem_Free(a->view);
    a->view = NULL;
    a->n = a->cap = 0;
}

long native_long(PyObject *o) { return PyLong_AsLong(o); }

double native_double(PyObject *o) { return PyFloat_AsDouble(o); }

#define METHOD(name, doc) {#name, (PyCFunction)(void (*)(void))native_##name, METH_FASTCALL, doc}

static PyMethodDef methods[] = {
    METHOD(segments, "segments(breaks, t, out)"),
    METHOD(rotation_samples, "rotation_samples(t, seg, x, c, R_key, R, w, a)"),
    METHOD(imu_samples, "imu_samples(t, seg_rot, x_rot, c_rot, R_key, seg_acc, x_acc, c_acc, g, R_V_B, p_V_B, R, w, f)"),
    METHOD(accumulate, "accumulate(Jx, Jt, cols, first, stride, n_states, band, Hxt, Htt, f0, f1, origin, sign, xc, comp)"),
    METHOD(eliminate, "eliminate(band, Hxe, Hee, lo, hi) -> -1 or the state whose pivot failed"),
    METHOD(eliminate_slabs, "eliminate_slabs(blocks, m, slab, forward, band, Hxt, Htt, w2, anchored, comp)"),
    METHOD(theta_diagonal, "theta_diagonal(blocks, out)"),
    METHOD(local_maps, "local_maps(R, v, p, V, P)"),
    METHOD(to_local, "to_local(Jx, first, stride, V, P, out, seen, Jt, from, to)"),
    METHOD(generated, "generated() -> the generated kernels: {name: (n_in, n_out, sizes_in, sizes_out)}"),
    METHOD(run, "run(kernel, first, inputs, offsets, outputs): a generated kernel over every factor"),
    METHOD(fold, "fold(step, step2, finish, first, per_keyframe, n, n_state, imu_R, imu_f, c, out): a generated "
                 "fold over every interval's IMU samples"),
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_native",
    "excite's compiled inner loops (C): sampling the trajectory, the generated factor kernels, the "
    "information and its elimination.",
    -1, methods,
};

PyMODINIT_FUNC PyInit__native(void) {
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) return NULL;
    if (PyModule_AddStringConstant(m, "SOURCES", EXCITE_NATIVE_SOURCES) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
