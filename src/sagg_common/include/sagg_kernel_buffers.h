/* Buffer handling shared by sagg's compiled kernels (sagg_low_level: knn_kernel.c, reach_kernel.c;
 * sagg_goal_generator: em_kernel.c): a C-contiguous float64 or int64 array taken through the buffer
 * protocol (no numpy headers), and released. Static functions: each extension that includes this
 * file has its own copy. A build-time header only (each setup.py puts this folder on its include
 * path), not installed. */
#ifndef SAGG_KERNEL_BUFFERS_H
#define SAGG_KERNEL_BUFFERS_H
#define PY_SSIZE_T_CLEAN
#include <Python.h>

typedef struct {
    Py_buffer view;
    int held;
} Buf;

static int get_buf(PyObject *obj, Buf *b, const char *name, const char *fmt, Py_ssize_t itemsize,
                   int writable) {
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, &b->view, flags) < 0) {
        PyErr_Format(PyExc_TypeError, "%s must be a C-contiguous %s array", name,
                     fmt[0] == 'd' ? "float64" : "int64");
        return -1;
    }
    b->held = 1;
    const char *f = b->view.format ? b->view.format : "B";
    if (f[0] == '<' || f[0] == '=' || f[0] == '@') f++;
    int ok = b->view.itemsize == itemsize &&
             (fmt[0] == 'd' ? (f[0] == 'd' && f[1] == 0) : ((f[0] == 'l' || f[0] == 'q') && f[1] == 0));
    if (!ok) {
        PyErr_Format(PyExc_TypeError, "%s must be %s, got format '%s'", name,
                     fmt[0] == 'd' ? "float64" : "int64", b->view.format ? b->view.format : "B");
        return -1;
    }
    return 0;
}

static void release(Buf *b) {
    if (b->held) PyBuffer_Release(&b->view);
    b->held = 0;
}

#endif
