/* _lambdacore: compiled kernels of cdgps_cli.estimation.ambiguity (LAMBDA).
 *
 *   reduce(L, d, perm_rtol)            the reduction of ambiguity._reduce (no z, no on_tail): L (n, n) and d (n,)
 *                                  float64, modified in place; returns the operation list [(i, j, mu), ...],
 *                                  or None when an integer mu does not fit 2**62 (the caller then runs the
 *                                  Python reduction on its own copies).
 *   z_matrix(ops, Z)               ambiguity._z_matrix: Z (n, n) int64, the identity, becomes the product of the
 *                                  operations; False when _z_matrix would turn to Python integers (bound 2**62).
 *   enumerate(L, d, zs, m, cap, out_z, out_s)
 *                                  the depth-first search of ambiguity._enumerate; out_z (m, n) and out_s (m,)
 *                                  float64 receive the retained candidates (unsorted); returns (count, nodes
 *                                  exceeded cap).
 *
 * The arithmetic is operation for operation that of the Python functions (each product and sum rounded
 * once, in the same order; no fused multiply-add: compile without -ffp-contract=fast on machines with FMA,
 * see setup.py), so the results are bit-identical; tests/estimation/test_lambdacore.py checks it.
 * Plain C against the CPython API and the buffer protocol, as _ekfcore.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define LAMBDA_API 2

/* a C-contiguous float64 buffer of ``count`` elements (any count when negative) */
static int get_f64(PyObject *obj, Py_buffer *v, Py_ssize_t count, int writable, const char *name)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, v, flags) != 0) {
        PyErr_Format(PyExc_TypeError, "_lambdacore: %s: expected a C-contiguous%s float64 array", name,
                     writable ? " writable" : "");
        return -1;
    }
    const char *f = v->format ? v->format : "B";
    if (*f == '@' || *f == '=') f++;
    if (f[0] != 'd' || f[1] != 0 || v->itemsize != 8 || (count >= 0 && v->len != count * 8)) {
        PyErr_Format(PyExc_TypeError, "_lambdacore: %s: expected %zd float64 elements", name, count);
        PyBuffer_Release(v);
        return -1;
    }
    return 0;
}

/* ------------------------------------------------------------------------------------------ */
/* reduction */

typedef struct {
    int64_t *v;     /* triples i, j, mu */
    Py_ssize_t len, cap;
    int overflow;   /* a mu beyond 2**62 */
} Ops;

static int ops_push(Ops *o, int64_t i, int64_t j, double mu)
{
    if (!(fabs(mu) < 4611686018427387904.0)) {
        o->overflow = 1;
        return 0;
    }
    if (o->len + 3 > o->cap) {
        Py_ssize_t nc = o->cap ? 2 * o->cap : 3 * 256;
        int64_t *nv = realloc(o->v, (size_t)nc * sizeof(int64_t));
        if (!nv) return -1;
        o->v = nv;
        o->cap = nc;
    }
    o->v[o->len++] = i;
    o->v[o->len++] = j;
    o->v[o->len++] = (int64_t)mu;
    return 0;
}

/* ambiguity._gauss: z_j <- z_j - mu z_i, L[i:, j] -= mu L[i:, i] */
static int gauss(double *L, int n, Ops *o, int i, int j)
{
    double mu = floor(L[(Py_ssize_t)i * n + j] + 0.5);
    if (mu != 0.0) {
        for (int r = i; r < n; r++) {
            double t = mu * L[(Py_ssize_t)r * n + i];
            L[(Py_ssize_t)r * n + j] -= t;
        }
        return ops_push(o, i, j, mu);
    }
    return 0;
}

/* ambiguity._swap_if_shorter; 1 swapped, 0 not, -1 no memory */
static int swap_if_shorter(double *L, double *d, int n, Ops *o, int k, double perm_rtol)
{
    double lk = L[(Py_ssize_t)(k + 1) * n + k];
    double dk = d[k], dk1 = d[k + 1];
    double lk2 = lk * lk;
    double t = lk2 * dk1;
    double delta = dk + t;
    if (!(delta < dk1 * (1.0 - perm_rtol))) return 0;
    double eta = dk / delta;
    double dl = dk1 * lk;
    double lam = dl / delta;
    d[k] = eta * dk1;
    d[k + 1] = delta;
    double *rk = L + (Py_ssize_t)k * n, *rk1 = L + (Py_ssize_t)(k + 1) * n;
    for (int c = 0; c < k; c++) {
        double a = rk[c], b = rk1[c];
        double u = lk * a;
        double v1 = eta * a, v2 = lam * b;
        rk[c] = b - u;
        rk1[c] = v1 + v2;
    }
    rk1[k] = lam;
    for (int r = k + 2; r < n; r++) {
        double *row = L + (Py_ssize_t)r * n;
        double s = row[k];
        row[k] = row[k + 1];
        row[k + 1] = s;
    }
    if (ops_push(o, k, k + 1, 0.0) < 0) return -1;
    return 1;
}

/* ambiguity._reduce_column: column j from row start down, top down, where |L[i, j]| > 1/2 */
static int reduce_column(double *L, int n, Ops *o, int j, int start)
{
    for (int i = start; i < n; i++) {
        if (!(fabs(L[(Py_ssize_t)i * n + j]) > 0.5)) continue;
        if (gauss(L, n, o, i, j) < 0) return -1;
        if (o->overflow) return 0;
    }
    return 0;
}

/* ambiguity._size_reduce: the columns j with work to do, from the right, rows top down */
static int size_reduce(double *L, int n, Ops *o, const uint8_t *todo)
{
    for (int j = n - 3; j >= 0; j--) {
        if (!todo[j]) continue;
        if (reduce_column(L, n, o, j, j + 2) < 0) return -1;
        if (o->overflow) return 0;
    }
    return 0;
}

static PyObject *py_reduce(PyObject *self, PyObject *args)
{
    PyObject *oL, *od;
    double perm_rtol;
    if (!PyArg_ParseTuple(args, "OOd", &oL, &od, &perm_rtol)) return NULL;
    Py_buffer bL, bd;
    if (get_f64(od, &bd, -1, 1, "d") < 0) return NULL;
    if (bd.len / 8 > 100000) {
        PyBuffer_Release(&bd);
        PyErr_SetString(PyExc_ValueError, "_lambdacore.reduce: too many ambiguities");
        return NULL;
    }
    int n = (int)(bd.len / 8);
    if (get_f64(oL, &bL, (Py_ssize_t)n * n, 1, "L") < 0) {
        PyBuffer_Release(&bd);
        return NULL;
    }
    double *L = bL.buf, *d = bd.buf;
    Ops o = {NULL, 0, 0, 0};
    int fail = 0;
    uint8_t *todo = NULL;
    Py_BEGIN_ALLOW_THREADS
    int k = n - 2;
    while (k >= 0 && !fail && !o.overflow) {
        if (reduce_column(L, n, &o, k, k + 1) < 0) { fail = 1; break; }
        if (o.overflow) break;
        int s = swap_if_shorter(L, d, n, &o, k, perm_rtol);
        if (s < 0) { fail = 1; break; }
        if (s) {
            if (k < n - 2) k += 1;
        } else {
            k -= 1;
        }
    }
    if (!fail && !o.overflow && n >= 3) {
        todo = calloc((size_t)n, 1);
        if (!todo) {
            fail = 1;
        } else {
            /* the columns with an entry beyond 1/2 below the sub-diagonal, before any transformation */
            for (int i = 2; i < n; i++)
                for (int j = 0; j < i - 1; j++)
                    if (fabs(L[(Py_ssize_t)i * n + j]) > 0.5) todo[j] = 1;
            if (size_reduce(L, n, &o, todo) < 0) fail = 1;
        }
    }
    Py_END_ALLOW_THREADS
    free(todo);
    PyBuffer_Release(&bL);
    PyBuffer_Release(&bd);
    if (fail) {
        free(o.v);
        return PyErr_NoMemory();
    }
    if (o.overflow) {
        free(o.v);
        Py_RETURN_NONE;
    }
    Py_ssize_t m = o.len / 3;
    PyObject *out = PyList_New(m);
    if (!out) {
        free(o.v);
        return NULL;
    }
    for (Py_ssize_t q = 0; q < m; q++) {
        PyObject *t = Py_BuildValue("(LLL)", (long long)o.v[3 * q], (long long)o.v[3 * q + 1],
                                    (long long)o.v[3 * q + 2]);
        if (!t) {
            Py_DECREF(out);
            free(o.v);
            return NULL;
        }
        PyList_SET_ITEM(out, q, t);
    }
    free(o.v);
    return out;
}

/* ------------------------------------------------------------------------------------------ */
/* Z from the operation list (ambiguity._z_matrix) */

/* a - mu * b in int64; 0 when it would overflow */
static int sub_mul(int64_t a, int64_t mu, int64_t b, int64_t *out)
{
    if (b != 0 && mu != 0) {
        if (mu == INT64_MIN || b == INT64_MIN) return 0;
        int64_t am = mu < 0 ? -mu : mu, ab = b < 0 ? -b : b;
        if (am > INT64_MAX / ab) return 0;
    }
    int64_t p = mu * b;
    if ((p > 0 && a < INT64_MIN + p) || (p < 0 && a > INT64_MAX + p)) return 0;
    *out = a - p;
    return 1;
}

/* z_matrix(ops, Z): Z (n, n) int64, the identity on entry, becomes the product of the operations.
 * Returns 1 (done: the same Z as ambiguity._z_matrix), 0 when _z_matrix would have turned to its exact
 * Python-integer form (the next column could reach 2**62 by the bound from the columns' largest
 * entries; Z is then left unspecified). */
static PyObject *py_z_matrix(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *ops, *oZ;
    if (!PyArg_ParseTuple(args, "O!O", &PyList_Type, &ops, &oZ)) return NULL;
    Py_buffer bZ;
    if (PyObject_GetBuffer(oZ, &bZ, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | PyBUF_WRITABLE) != 0) return NULL;
    const char *f = bZ.format ? bZ.format : "B";
    if (*f == '@' || *f == '=') f++;
    Py_ssize_t n = (Py_ssize_t)floor(sqrt((double)(bZ.len / 8)) + 0.5);
    if (!((f[0] == 'q' || f[0] == 'l') && f[1] == 0 && bZ.itemsize == 8 && n * n * 8 == bZ.len)) {
        PyBuffer_Release(&bZ);
        PyErr_SetString(PyExc_TypeError, "_lambdacore.z_matrix: Z must be a square C-contiguous int64 array");
        return NULL;
    }
    int64_t *Z = bZ.buf;
    double *bound = malloc((size_t)(n ? n : 1) * sizeof(double));
    if (!bound) {
        PyBuffer_Release(&bZ);
        return PyErr_NoMemory();
    }
    for (Py_ssize_t c = 0; c < n; c++) bound[c] = 1.0;
    int ok = 1, err = 0;
    Py_ssize_t m = PyList_GET_SIZE(ops);
    for (Py_ssize_t q = 0; q < m && ok; q++) {
        PyObject *t = PyList_GET_ITEM(ops, q);
        long long i, j, mu;
        if (!PyArg_ParseTuple(t, "LLL", &i, &j, &mu)) {
            if (PyErr_ExceptionMatches(PyExc_OverflowError)) {     /* an integer beyond int64: Python's turn */
                PyErr_Clear();
                ok = 0;
            } else {
                err = 1;
            }
            break;
        }
        if (i < 0 || j < 0 || i >= n || j >= n) {
            PyErr_SetString(PyExc_ValueError, "_lambdacore.z_matrix: operation index out of range");
            err = 1;
            break;
        }
        if (mu) {
            if (bound[j] + fabs((double)mu) * bound[i] >= 4611686018427387904.0) { ok = 0; break; }
            double big = 0.0;
            for (Py_ssize_t r = 0; r < n; r++) {
                if (!sub_mul(Z[r * n + j], mu, Z[r * n + i], &Z[r * n + j])) { ok = 0; break; }
                double a = fabs((double)Z[r * n + j]);
                if (a > big) big = a;
            }
            bound[j] = big;
        } else {
            for (Py_ssize_t r = 0; r < n; r++) {
                int64_t s = Z[r * n + i];
                Z[r * n + i] = Z[r * n + j];
                Z[r * n + j] = s;
            }
            double s = bound[i];
            bound[i] = bound[j];
            bound[j] = s;
        }
    }
    free(bound);
    PyBuffer_Release(&bZ);
    if (err) return NULL;
    return PyBool_FromLong(ok);
}

/* ------------------------------------------------------------------------------------------ */
/* search */

/* ambiguity._retain on arrays: returns the new radius, updates *cnt and *imax */
static double retain(double *out_z, double *out_s, int *cnt, int *imax, const double *z, double dist, int m, int n)
{
    int slot;
    if (*cnt < m) {
        slot = (*cnt)++;
    } else {
        slot = *imax;
    }
    memcpy(out_z + (Py_ssize_t)slot * n, z, (size_t)n * sizeof(double));
    out_s[slot] = dist;
    if (*cnt < m) return INFINITY;
    int im = 0;
    for (int i = 1; i < m; i++)
        if (out_s[i] > out_s[im]) im = i;       /* max(): the first of equal maxima */
    *imax = im;
    return out_s[im];
}

/* returns the candidate count; *over = 1 when the node cap was exceeded; -1 no memory */
static int search_core(const double *L, const double *dl, const double *zs, int n, int m, long long cap,
                       double *out_z, double *out_s, int *over)
{
    double *S = malloc((size_t)n * n * sizeof(double));
    double *w = malloc((size_t)4 * n * sizeof(double));
    if (!S || !w) {
        free(S);
        free(w);
        return -1;
    }
    double *dist = w, *zb = w + n, *z = w + 2 * n, *step = w + 3 * n;
    double *Sn = S + (Py_ssize_t)(n - 1) * n;
    for (int j = 0; j < n; j++) Sn[j] = 0.0;
    for (int j = 0; j < n; j++) dist[j] = zb[j] = z[j] = step[j] = 0.0;
    int cnt = 0, imax = 0;
    double maxdist = INFINITY;
    long long nodes = 0;
    *over = 0;
    int k = n - 1;
    zb[k] = zs[k];
    z[k] = floor(zb[k] + 0.5);
    double y = zb[k] - z[k];
    step[k] = y > 0 ? 1.0 : -1.0;
    for (;;) {
        nodes++;
        if (nodes > cap) {
            *over = 1;
            break;
        }
        double q = y * y;
        double newdist = dist[k] + q / dl[k];
        if (newdist < maxdist) {
            if (k) {
                double e = z[k] - zb[k];
                const double *src = S + (Py_ssize_t)k * n, *lr = L + (Py_ssize_t)k * n;
                k -= 1;
                dist[k] = newdist;
                double *Sk = S + (Py_ssize_t)k * n;
                for (int j = 0; j <= k; j++) {
                    double t = e * lr[j];
                    Sk[j] = src[j] + t;
                }
                double zbk = zs[k] + Sk[k];
                zb[k] = zbk;
                double zk = floor(zbk + 0.5);
                z[k] = zk;
                y = zbk - zk;
                step[k] = y > 0 ? 1.0 : -1.0;
                continue;
            }
            maxdist = retain(out_z, out_s, &cnt, &imax, z, newdist, m, n);
            double st = step[0];
            z[0] += st;
            y = zb[0] - z[0];
            step[0] = -st - (st > 0 ? 1.0 : -1.0);
        } else {
            if (k == n - 1) break;
            k += 1;
            double st = step[k];
            z[k] += st;
            y = zb[k] - z[k];
            step[k] = -st - (st > 0 ? 1.0 : -1.0);
        }
    }
    free(S);
    free(w);
    return cnt;
}

static PyObject *py_enumerate(PyObject *self, PyObject *args)
{
    PyObject *oL, *od, *ozs, *ooz, *oos;
    int m;
    long long cap;
    if (!PyArg_ParseTuple(args, "OOOiLOO", &oL, &od, &ozs, &m, &cap, &ooz, &oos)) return NULL;
    if (m < 1) {
        PyErr_SetString(PyExc_ValueError, "_lambdacore.enumerate: m must be >= 1");
        return NULL;
    }
    Py_buffer b[5];
    int held = 0;
    PyObject *ret = NULL;
    if (get_f64(od, &b[0], -1, 0, "d") < 0) return NULL;
    held = 1;
    Py_ssize_t n = b[0].len / 8;
    if (n < 1 || n > 100000) {
        PyErr_SetString(PyExc_ValueError, "_lambdacore.enumerate: need 1 <= n <= 100000 ambiguities");
        goto done;
    }
    if (get_f64(oL, &b[1], n * n, 0, "L") < 0) goto done;
    held = 2;
    if (get_f64(ozs, &b[2], n, 0, "zs") < 0) goto done;
    held = 3;
    if (get_f64(ooz, &b[3], (Py_ssize_t)m * n, 1, "out_z") < 0) goto done;
    held = 4;
    if (get_f64(oos, &b[4], m, 1, "out_s") < 0) goto done;
    held = 5;
    int over = 0, cnt;
    Py_BEGIN_ALLOW_THREADS
    cnt = search_core(b[1].buf, b[0].buf, b[2].buf, (int)n, m, cap, b[3].buf, b[4].buf, &over);
    Py_END_ALLOW_THREADS
    if (cnt < 0) {
        PyErr_NoMemory();
        goto done;
    }
    ret = Py_BuildValue("(iO)", cnt, over ? Py_True : Py_False);
done:
    for (int i = 0; i < held; i++) PyBuffer_Release(&b[i]);
    return ret;
}

static PyMethodDef methods[] = {
    {"reduce", py_reduce, METH_VARARGS, "reduce(L, d, perm_rtol): LAMBDA reduction in place; the operation list (or None)."},
    {"z_matrix", py_z_matrix, METH_VARARGS, "z_matrix(ops, Z): Z <- product of the operations (Z the identity); False: too large."},
    {"enumerate", py_enumerate, METH_VARARGS,
     "enumerate(L, d, zs, m, cap, out_z, out_s): the integer search; (count, cap exceeded)."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_lambdacore",
                                    "Compiled LAMBDA kernels of cdgps_cli.estimation.ambiguity.", -1, methods};

PyMODINIT_FUNC PyInit__lambdacore(void)
{
    PyObject *mod = PyModule_Create(&moddef);
    if (mod && PyModule_AddIntConstant(mod, "API", LAMBDA_API) < 0) {
        Py_DECREF(mod);
        return NULL;
    }
    return mod;
}
