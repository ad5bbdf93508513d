/* Compiled correlator of cdgps_cli.tracking (see cdgps_cli/tracking/correlator.py).
 *
 * correlate(samples, code, out, n, phase_cycles, doppler_hz, fs_hz, code_phase_chips, code_rate_hz, half_chips)
 *   samples: n complex samples as 2n float64 (re, im); code: 1023 int8 chips (+1/-1);
 *   out: 6 float64 receiving E, P, L as (re, im) pairs of
 *        sum_k x[k] exp(-j 2 pi (phase + f t_k)) c(code_phase + rate t_k + offset),
 *   offsets +half (early), 0 (prompt), -half (late); t_k = k / fs.
 * Plain C against the CPython buffer protocol, no numpy headers (as _ekfcore.c).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>

static int chip_index(double chips)
{
    double f = floor(chips);
    long long i = (long long)f % 1023;
    if (i < 0) i += 1023;
    return (int)i;
}

static PyObject *py_correlate(PyObject *self, PyObject *args)
{
    PyObject *os, *oc, *oo;
    Py_ssize_t n;
    double phase, fd, fs, cp, rate, half;
    if (!PyArg_ParseTuple(args, "OOOndddddd", &os, &oc, &oo, &n, &phase, &fd, &fs, &cp, &rate, &half)) return NULL;
    Py_buffer bs, bc, bo;
    if (PyObject_GetBuffer(os, &bs, PyBUF_SIMPLE) != 0) return NULL;
    if (PyObject_GetBuffer(oc, &bc, PyBUF_SIMPLE) != 0) { PyBuffer_Release(&bs); return NULL; }
    if (PyObject_GetBuffer(oo, &bo, PyBUF_WRITABLE) != 0) { PyBuffer_Release(&bs); PyBuffer_Release(&bc); return NULL; }
    PyObject *ret = NULL;
    if (n < 0 || bs.len < (Py_ssize_t)(2 * n * sizeof(double)) || bc.len != 1023 || bo.len != (Py_ssize_t)(6 * sizeof(double))
        || !(fs > 0)) {
        PyErr_SetString(PyExc_ValueError, "_trackcore.correlate: bad buffer sizes or rate");
        goto done;
    }
    const double *x = (const double *)bs.buf;
    const signed char *code = (const signed char *)bc.buf;
    double *out = (double *)bo.buf;
    const double two_pi = 6.283185307179586476925286766559;
    double er = 0, ei = 0, pr = 0, pi_ = 0, lr = 0, li = 0;
    const double dchip = rate / fs;
    /* carrier rotation by recurrence, re-anchored every 1024 samples against drift */
    for (Py_ssize_t k0 = 0; k0 < n; k0 += 1024) {
        double a = -two_pi * (phase + fd * (double)k0 / fs);
        double cr = cos(a), ci = sin(a);
        const double w = -two_pi * fd / fs, wr = cos(w), wi = sin(w);
        Py_ssize_t k1 = k0 + 1024 < n ? k0 + 1024 : n;
        for (Py_ssize_t k = k0; k < k1; ++k) {
            const double xr = x[2 * k], xi = x[2 * k + 1];
            const double br = xr * cr - xi * ci, bi = xr * ci + xi * cr;
            const double chips = cp + dchip * (double)k;
            const double ce = code[chip_index(chips + half)], cpp = code[chip_index(chips)], cl = code[chip_index(chips - half)];
            er += br * ce; ei += bi * ce;
            pr += br * cpp; pi_ += bi * cpp;
            lr += br * cl; li += bi * cl;
            const double nr = cr * wr - ci * wi;
            ci = cr * wi + ci * wr;
            cr = nr;
        }
    }
    out[0] = er; out[1] = ei; out[2] = pr; out[3] = pi_; out[4] = lr; out[5] = li;
    Py_INCREF(Py_None);
    ret = Py_None;
done:
    PyBuffer_Release(&bs);
    PyBuffer_Release(&bc);
    PyBuffer_Release(&bo);
    return ret;
}

static PyMethodDef methods[] = {
    {"correlate", py_correlate, METH_VARARGS, "Early, prompt and late correlations of one block (see the file header)."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef moddef = {
    PyModuleDef_HEAD_INIT, "_trackcore", "Compiled correlator of cdgps_cli.tracking.", -1, methods};

PyMODINIT_FUNC PyInit__trackcore(void)
{
    PyObject *m = PyModule_Create(&moddef);
    if (m && PyModule_AddIntConstant(m, "API", 1) < 0) { Py_DECREF(m); return NULL; }
    return m;
}
