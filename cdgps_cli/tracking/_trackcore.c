/* Compiled tracking loop of cdgps_cli.tracking (see cdgps_cli/tracking/correlator.py and channel.py).
 *
 * correlate(samples, code, out, n, phase_cycles, doppler_hz, fs_hz, code_phase_chips, code_rate_hz, half_chips)
 *   samples: n complex samples as 2n float64 (re, im); code: 1023 int8 chips (+1/-1);
 *   out: 6 float64 receiving E, P, L as (re, im) pairs of
 *        sum_k x[k] exp(-j 2 pi (phase + f t_k)) c(code_phase + rate t_k + offset),
 *   offsets +half (early), 0 (prompt), -half (late); t_k = k / fs.
 *
 * track(samples, code, state, params, aid, out, n_samples, m)
 *   runs m 1-ms updates of one channel (correlate, FLL or Costas PLL, DLL, NCO update), the same
 *   arithmetic as cdgps_cli.tracking.channel._run_numpy (its reference, tested equal):
 *   state  float64[STATE_LEN] in/out (channel.STATE_FIELDS);
 *   params float64[PARAM_LEN]: n, fs, pull_in, narrow_at, bn_first, bn_final, pll_order, fll_bn, dll_bn, spacing;
 *   aid    float64[m] external Doppler per update (Hz); out float64[m * OUT_LEN] (channel.OUT_FIELDS).
 * Plain C against the CPython buffer protocol, no numpy headers (as _ekfcore.c).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>

#define CODE_LEN 1023
#define TABLE_LEN (4 * CODE_LEN)
#define STATE_LEN 11
#define PARAM_LEN 10
#define OUT_LEN 8

static const double TWO_PI = 6.283185307179586476925286766559;
static const double L1_HZ = 1575.42e6;
static const double CHIP_RATE_HZ = 1.023e6;
/* third-order loop constants (cdgps_cli.tracking.loops) */
static const double A3 = 1.1, B3 = 2.4, BN_OVER_W0_3 = 0.7845;

static int chip_index(double chips)
{
    double f = floor(chips);
    long long i = (long long)f % CODE_LEN;
    if (i < 0) i += CODE_LEN;
    return (int)i;
}

/* E, P, L of n samples; table: the code repeated TABLE_LEN times as doubles (index = chip + CODE_LEN). */
static void corr3(const double *x, Py_ssize_t n, const signed char *code, const double *table, double phase,
                  double fd, double fs, double cp, double rate, double half, double *out)
{
    double er = 0, ei = 0, pr = 0, pi_ = 0, lr = 0, li = 0;
    const double dchip = rate / fs;
    const double cpr = cp - CODE_LEN * floor(cp / CODE_LEN);          /* [0, 1023) */
    const int fast = table != NULL && half >= 0 && half < 1 && dchip > 0
                     && cpr + dchip * (double)n + half + CODE_LEN + 2 < TABLE_LEN;
    const double w = -TWO_PI * fd / fs, wr = cos(w), wi = sin(w);
    /* carrier rotation by recurrence, re-anchored every 1024 samples against drift */
    for (Py_ssize_t k0 = 0; k0 < n; k0 += 1024) {
        const double a = -TWO_PI * (phase + fd * (double)k0 / fs);
        double cr = cos(a), ci = sin(a);
        const Py_ssize_t k1 = k0 + 1024 < n ? k0 + 1024 : n;
        for (Py_ssize_t k = k0; k < k1; ++k) {
            const double xr = x[2 * k], xi = x[2 * k + 1];
            const double br = xr * cr - xi * ci, bi = xr * ci + xi * cr;
            double ce, cpp, cl;
            if (fast) {
                const double c = cpr + dchip * (double)k + CODE_LEN;     /* >= 1022.5: truncation is floor */
                ce = table[(int)(c + half)]; cpp = table[(int)c]; cl = table[(int)(c - half)];
            } else {
                const double chips = cp + dchip * (double)k;
                ce = code[chip_index(chips + half)]; cpp = code[chip_index(chips)]; cl = code[chip_index(chips - half)];
            }
            er += br * ce; ei += bi * ce;
            pr += br * cpp; pi_ += bi * cpp;
            lr += br * cl; li += bi * cl;
            const double nr = cr * wr - ci * wi;
            ci = cr * wi + ci * wr;
            cr = nr;
        }
    }
    out[0] = er; out[1] = ei; out[2] = pr; out[3] = pi_; out[4] = lr; out[5] = li;
}

static void fill_table(const signed char *code, double *table)
{
    for (int i = 0; i < TABLE_LEN; ++i) table[i] = (double)code[i % CODE_LEN];
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
    if (n < 0 || bs.len < (Py_ssize_t)(2 * n * sizeof(double)) || bc.len != CODE_LEN
        || bo.len != (Py_ssize_t)(6 * sizeof(double)) || !(fs > 0)) {
        PyErr_SetString(PyExc_ValueError, "_trackcore.correlate: bad buffer sizes or rate");
        goto done;
    }
    double table[TABLE_LEN];
    fill_table((const signed char *)bc.buf, table);
    corr3((const double *)bs.buf, n, (const signed char *)bc.buf, table, phase, fd, fs, cp, rate, half, (double *)bo.buf);
    Py_INCREF(Py_None);
    ret = Py_None;
done:
    PyBuffer_Release(&bs);
    PyBuffer_Release(&bc);
    PyBuffer_Release(&bo);
    return ret;
}

/* loop filter command (error units per second) and state update: cdgps_cli.tracking.loops.LoopFilter */
static double pll_update(double *st, int order, double bn, double T, double err)
{
    double *i1 = &st[7], *i2 = &st[8], *e1 = &st[9], *y1 = &st[10];
    if (order == 2) {
        const double zeta = 1.0 / sqrt(2.0);
        const double wn = 2.0 * bn / (zeta + 1.0 / (4.0 * zeta));
        const double k1 = wn * wn, tau1 = 2.0 * zeta / wn;
        *i1 += 0.5 * T * k1 * (err + *e1);
        *e1 = err;
        return k1 * tau1 * err + *i1;
    }
    const double w0 = bn / BN_OVER_W0_3;
    const double y = A3 * w0 * w0 * err;
    *i2 += 0.5 * T * pow(w0, 3.0) * (err + *e1);
    *i1 += 0.5 * T * (y + *i2 + *y1);
    *y1 = y + *i2;
    *e1 = err;
    return B3 * w0 * err + *i1;
}

static void run_track(const double *x, const signed char *code, double *st, const double *par, const double *aid,
                      double *out, Py_ssize_t m)
{
    const Py_ssize_t n = (Py_ssize_t)par[0];
    const double fs = par[1], T = (double)n / fs;
    const long long pull_in = (long long)par[2], narrow_at = (long long)par[3];
    const double bn_first = par[4], bn_final = par[5];
    const int order = (int)par[6];
    const double fll_bn = par[7], dll_bn = par[8], spacing = par[9], half = spacing / 2.0;
    double table[TABLE_LEN];
    fill_table(code, table);
    for (Py_ssize_t j = 0; j < m; ++j) {
        const long long k = (long long)st[0];
        double *o = out + j * OUT_LEN;
        const double f_now = st[1] + aid[j];
        const double code_rate = CHIP_RATE_HZ * (1.0 + f_now / L1_HZ);
        double c[6];
        corr3(x + 2 * j * n, n, code, table, st[3], f_now, fs, st[4], code_rate, half, c);
        const double pr = c[2], pq = c[3];
        const double err = pr != 0 ? atan(pq / pr) : 0.0;
        o[0] = (double)k * T; o[1] = f_now; o[2] = st[3];
        o[3] = fmod(st[4], (double)CODE_LEN);
        if (o[3] < 0) o[3] += CODE_LEN;
        o[4] = pr; o[5] = pq; o[7] = err;
        st[3] += f_now * T;
        st[4] += code_rate * T;
        if (k < pull_in) {
            o[6] = 0.0;
            if (!isnan(st[5])) {
                const double cross = st[5] * pq - st[6] * pr;
                const double dot = st[5] * pr + st[6] * pq;
                st[1] += 4.0 * fll_bn * (dot != 0 ? atan(cross / dot) / (TWO_PI * T) : 0.0) * T;
            }
            st[2] = st[1];
        } else {
            o[6] = 1.0;
            const double bn = (narrow_at >= 0 && k >= narrow_at) ? bn_final : bn_first;
            st[1] = st[2] + pll_update(st, order, bn, T, err) / TWO_PI;
        }
        st[5] = pr; st[6] = pq;
        const double ea = hypot(c[0], c[1]), la = hypot(c[4], c[5]);
        if (ea + la > 0) st[4] += 4.0 * dll_bn * ((ea - la) / (ea + la) * (2.0 - spacing) / 2.0) * T;
        st[0] = (double)(k + 1);
    }
}

static PyObject *py_track(PyObject *self, PyObject *args)
{
    PyObject *obj[6];
    Py_ssize_t ns, m;
    if (!PyArg_ParseTuple(args, "OOOOOOnn", &obj[0], &obj[1], &obj[2], &obj[3], &obj[4], &obj[5], &ns, &m)) return NULL;
    Py_buffer b[6];
    int got = 0;
    PyObject *ret = NULL;
    for (; got < 6; ++got) {
        int flags = (got == 2 || got == 5) ? PyBUF_WRITABLE : PyBUF_SIMPLE;
        if (PyObject_GetBuffer(obj[got], &b[got], flags) != 0) goto done;
    }
    const double *par = (const double *)b[3].buf;
    if (b[3].len != (Py_ssize_t)(PARAM_LEN * sizeof(double)) || b[2].len != (Py_ssize_t)(STATE_LEN * sizeof(double))
        || b[1].len != CODE_LEN || m < 0 || ns < 0) {
        PyErr_SetString(PyExc_ValueError, "_trackcore.track: bad state, parameter or code buffer");
        goto done;
    }
    const Py_ssize_t n = (Py_ssize_t)par[0];
    const int order = (int)par[6];
    if (n <= 0 || !(par[1] > 0) || (order != 2 && order != 3) || b[0].len < (Py_ssize_t)(2 * ns * sizeof(double))
        || m * n > ns || b[4].len != (Py_ssize_t)(m * sizeof(double)) || b[5].len != (Py_ssize_t)(m * OUT_LEN * sizeof(double))) {
        PyErr_SetString(PyExc_ValueError, "_trackcore.track: bad sizes (samples, aid, out) or loop order");
        goto done;
    }
    Py_BEGIN_ALLOW_THREADS
    run_track((const double *)b[0].buf, (const signed char *)b[1].buf, (double *)b[2].buf, par,
              (const double *)b[4].buf, (double *)b[5].buf, m);
    Py_END_ALLOW_THREADS
    Py_INCREF(Py_None);
    ret = Py_None;
done:
    while (got-- > 0) PyBuffer_Release(&b[got]);
    return ret;
}

static PyMethodDef methods[] = {
    {"correlate", py_correlate, METH_VARARGS, "Early, prompt and late correlations of one block (see the file header)."},
    {"track", py_track, METH_VARARGS, "m 1-ms updates of one tracking channel (see the file header)."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef moddef = {
    PyModuleDef_HEAD_INIT, "_trackcore", "Compiled correlator and tracking loop of cdgps_cli.tracking.", -1, methods};

PyMODINIT_FUNC PyInit__trackcore(void)
{
    PyObject *m = PyModule_Create(&moddef);
    if (m && PyModule_AddIntConstant(m, "API", 2) < 0) { Py_DECREF(m); return NULL; }
    return m;
}
