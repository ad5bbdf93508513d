/* Compiled satellite orbits of cdgps_cli.model.gps.orbits: Kepler's equation, the rest of the IS-GPS-200
 * user algorithm and the light-time step, on rows grouped in blocks (orbits.py: every row a block of its own).
 *
 * Every value is the one the numpy functions of orbits.py give (_eccentric_anomaly, _kepler_at_anomaly,
 * _light_time_rows; tested equal bit for bit): the same operations in the same order, no fused multiply-add
 * (built with -ffp-contract=off), sin/cos from libm as numpy's float64 sin/cos (sincos where both are needed:
 * glibc computes them by the same code).  The arctangent of the true anomaly is NOT computed here: numpy's
 * float64 arctan2 is a SIMD routine that differs from libm's atan2 by an ulp now and then, so the caller applies
 * np.arctan2 to the (y, x) this module writes and hands the result back.
 *
 * orbits.py passes every row as a block of its own (issue 29: a row's value then depends on its own data alone,
 * so a window of a record gives the whole record's values); the kernel keeps its block form.
 *
 * Work saved, exactly: Kepler's equation is iterated in lockstep per block (a block stops after
 * the first iteration in which all its steps are below 1e-15 rad), but a row whose step leaves E unchanged
 * (a fixed point) is not evaluated again: every further step would give the same E and the same small step.
 * Across light-time iterations a row whose transmission time did not change (the usual case once tau has
 * converged to well below the 0.24 us resolution of GPS seconds) continues its own sequence of steps: the flags
 * of the steps already taken are known (a bit mask per row), so only steps beyond them are taken, and its
 * position and clock are evaluated again only when its E differs from the one they were evaluated at.  A row
 * whose block stops before the steps it has taken is stepped again from its mean anomaly.
 *
 * anomaly(K, rows, t, starts, live, S, info, yat, xat, memo)
 *   K     float64 (n_eph, NK): per ephemeris the fields of orbits._CORE_FIELDS (the order of the enum below);
 *   rows  int64 (n): ephemeris (row of K) of each row;  t float64 (n): evaluation times, GPS s;
 *   starts int64 (nb): first row of each block;  live uint8 (nb): blocks to evaluate;
 *   S     float64 (n, NS) and info int64 (n): the per-row state kept between calls (any values when memo is 0);
 *   yat, xat float64 (n), written: sqrt(1-e^2) sin E and cos E - e of the rows evaluated (REDO in info);
 *   memo  int: rows whose time equals the previous call's may keep their orbit.
 * kepler(K, rows, t, starts, live, S, info, nu, xyz, clk, apply_tgd, cos_tilt, sin_tilt)
 *   nu float64 (n) = arctan2(yat, xat); writes xyz (n, 3) and clk (n) of the REDO rows of live blocks.
 * light(xyz, clk, starts, live, tau, rx, rx_per_row, order, rot, clock, range, travel, omega_e, c) -> blocks going
 *   for the rows of the live blocks: the Sagnac rotation by omega_e tau, the range to rx ((3,), or (N, 3) read at
 *   order), tau <- range / c, written to row order[i] of rot (N, 3), clock, range and travel (N); a block stops
 *   when all its steps |range/c - tau| are below 1e-12 s (live cleared).
 * newton(K, rows, t, ek, state): every row on its own (orbits.sat_position_rows), E into ek (n), state uint8 (n)
 *   scratch; anomaly_trig(K, rows, ek, sin, cos, yat, xat); orbit(K, rows, t, sin, cos, nu, xyz, clk, apply_tgd,
 *   cos_tilt, sin_tilt): the same in pieces, so that the rest runs chunk by chunk (small temporaries).
 * enu(R, rx, xyz, out) and niell(el, doy, p, out): orbits.azimuth_elevation's rotation to east/north/up (the sums
 *   in the order of numpy's einsum, checked against it) and positioning.niell_hydrostatic_mapping for one receiver.
 * Plain C against the CPython buffer protocol, no numpy headers (as _ekfcore.c).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#if defined(__GLIBC__)
#define SINCOS(x, s, c) sincos((x), (s), (c))
#else
#define SINCOS(x, s, c) (*(s) = sin(x), *(c) = cos(x))
#endif

enum { K_TOE, K_M0, K_N, K_E, K_SQ1E2, K_OMEGA, K_CUS, K_CUC, K_A, K_CRS, K_CRC, K_I0, K_IDOT, K_CIS, K_CIC,
       K_OMEGA0, K_NODE_RATE, K_NODE_TOE, K_GEO, K_WE, K_TOC, K_AF0, K_AF1, K_AF2, K_REL, K_TGD, NK };
/* per-row state: E after DONE steps from the mean anomaly at time S_TSEQ; sin and cos at the E where they were
 * last evaluated (S_BLAST); the E of the position and clock kept in xyz/clk (S_EKOUT, when VALID) */
enum { S_EK, S_SB, S_CB, S_BLAST, S_TSEQ, S_EKOUT, NS };
#define MAX_NEWTON 30
#define I_MASK 0x7fffffffLL                 /* bit i: the step of iteration i was not below 1e-15 */
#define I_FIX_SHIFT 32                      /* iteration whose step left E unchanged (0: none), 5 bits */
#define I_DONE_SHIFT 37                     /* steps taken from the mean anomaly, 5 bits */
#define I_REDO (1LL << 42)                  /* position and clock evaluated in this call */
#define I_VALID (1LL << 43)                 /* xyz and clk hold the orbit at S_TSEQ with E = S_EKOUT */
#define FIX(f) ((int)(((f) >> I_FIX_SHIFT) & 31))
#define DONE(f) ((int)(((f) >> I_DONE_SHIFT) & 31))
#define WITH_DONE(f, it) (((f) & ~(31LL << I_DONE_SHIFT)) | ((int64_t)(it) << I_DONE_SHIFT))

static int same_bits(double a, double b)
{
    uint64_t x, y;
    memcpy(&x, &a, 8);
    memcpy(&y, &b, 8);
    return x == y;
}

static double mean_anomaly(const double *k, double t)
{
    const double tk = t - k[K_TOE];
    return k[K_M0] + k[K_N] * tk;
}

/* Newton step `it` of E - e sin E = M on row state s, (E - e sin E - M) / (1 - e cos E) as numpy evaluates it,
 * recorded in *f (flag bit when the step is not below 1e-15; fixed point when it is and E did not change).
 * Returns the flag. */
static int newton_step(double *s, double m, double e, int64_t *f, int it)
{
    double sn, cs;
    const double b = s[S_EK];
    SINCOS(b, &sn, &cs);
    const double d = (b - e * sn - m) / (1.0 - e * cs);
    const double nb = b - d;
    const int big = !(fabs(d) < 1e-15);
    s[S_SB] = sn;
    s[S_CB] = cs;
    s[S_BLAST] = b;
    s[S_EK] = nb;
    int64_t g = WITH_DONE(*f, it);
    if (big) g |= 1LL << it;
    else if (same_bits(nb, b)) g |= (int64_t)it << I_FIX_SHIFT;
    *f = g;
    return big;
}

/* The block's rows: E after as many steps as the block takes (it stops after the first iteration in which no row's
 * step is above 1e-15, or after MAX_NEWTON), and the arctangent's (y, x) of the rows whose orbit must be evaluated. */
static void block_anomaly(const double *K, const int64_t *rows, const double *t, Py_ssize_t i0, Py_ssize_t i1,
                          double *S, int64_t *info, double *yat, double *xat, int memo)
{
    int64_t kept = 0;                                   /* OR of the step flags known from a previous call */
    for (Py_ssize_t i = i0; i < i1; ++i) {
        double *s = S + i * NS;
        if (memo && DONE(info[i]) > 0 && t[i] == s[S_TSEQ]) {
            kept |= info[i] & I_MASK;                   /* the same mean anomaly: its steps so far are known */
        } else {
            s[S_EK] = mean_anomaly(K + rows[i] * NK, t[i]);
            s[S_TSEQ] = t[i];
            info[i] = 0;
        }
    }
    int n_it = MAX_NEWTON;
    for (int it = 1; it <= MAX_NEWTON; ++it) {
        int big = (int)((kept >> it) & 1);
        for (Py_ssize_t i = i0; i < i1; ++i) {
            if (DONE(info[i]) >= it || FIX(info[i]) != 0) continue;
            const double *k = K + rows[i] * NK;
            big |= newton_step(S + i * NS, mean_anomaly(k, t[i]), k[K_E], info + i, it);
        }
        if (!big) {
            n_it = it;
            break;
        }
    }
    for (Py_ssize_t i = i0; i < i1; ++i) {
        double *s = S + i * NS;
        const double *k = K + rows[i] * NK;
        int64_t f = info[i];
        if (DONE(f) > n_it && !(FIX(f) > 0 && FIX(f) - 1 <= n_it)) {
            const double m = mean_anomaly(k, t[i]);     /* the block stopped before this row's steps: E after n_it */
            f &= I_VALID;
            s[S_EK] = m;
            for (int it = 1; it <= n_it && FIX(f) == 0; ++it) newton_step(s, m, k[K_E], &f, it);
        }
        const double ek = s[S_EK];
        if ((f & I_VALID) && same_bits(ek, s[S_EKOUT])) {
            info[i] = f & ~I_REDO;                      /* its position and clock are kept */
            continue;
        }
        info[i] = f | I_REDO;
        double sn, cs;
        if (same_bits(ek, s[S_BLAST])) {
            sn = s[S_SB];
            cs = s[S_CB];
        } else {
            SINCOS(ek, &sn, &cs);
        }
        s[S_SB] = sn;
        s[S_CB] = cs;
        s[S_BLAST] = ek;
        yat[i] = k[K_SQ1E2] * sn;
        xat[i] = cs - k[K_E];
    }
}

/* The rest of the user algorithm (orbits._kepler_at_anomaly) for one row, E's sine/cosine and true anomaly known. */
static void kepler_row(const double *k, double t, double sn, double cs, double nu, int tgd, double ct, double st,
                       double *xyz, double *clk)
{
    const double e = k[K_E], tk = t - k[K_TOE];
    const double phi = nu + k[K_OMEGA];
    double s2, c2, su, cu, so, co, si, ci;
    SINCOS(2.0 * phi, &s2, &c2);
    const double u = phi + k[K_CUS] * s2 + k[K_CUC] * c2;
    const double r = k[K_A] * (1.0 - e * cs) + k[K_CRS] * s2 + k[K_CRC] * c2;
    const double inc = k[K_I0] + k[K_IDOT] * tk + k[K_CIS] * s2 + k[K_CIC] * c2;
    SINCOS(u, &su, &cu);
    const double xp = r * cu, yp = r * su;
    const double om = k[K_OMEGA0] + k[K_NODE_RATE] * tk - k[K_NODE_TOE];
    SINCOS(om, &so, &co);
    SINCOS(inc, &si, &ci);
    double x = xp * co - yp * ci * so, y = xp * so + yp * ci * co, z = yp * si;
    if (k[K_GEO] != 0.0) {                 /* BeiDou GEO: R_Z(we tk) R_X(-5 deg) (orbits.beidou_geo_rotation) */
        const double y1 = ct * y + st * z, z1 = -st * y + ct * z;
        double sw, cw;
        SINCOS(k[K_WE] * tk, &sw, &cw);
        const double x2 = cw * x + sw * y1, y2 = -sw * x + cw * y1;
        x = x2;
        y = y2;
        z = z1;
    }
    xyz[0] = x;
    xyz[1] = y;
    xyz[2] = z;
    const double dt = t - k[K_TOC];
    double c = k[K_AF0] + k[K_AF1] * dt + k[K_AF2] * dt * dt + k[K_REL] * sn;
    if (tgd) c = c - k[K_TGD];
    *clk = c;
}

/* ---- argument handling ---- */

#define MAX_BUF 12

typedef struct {
    Py_buffer b[MAX_BUF];
    int n;
} Bufs;

static void release(Bufs *bs)
{
    for (int i = 0; i < bs->n; ++i) PyBuffer_Release(&bs->b[i]);
    bs->n = 0;
}

/* Buffer of obj with at least `need` bytes; NULL (exception set) otherwise. */
static void *take(Bufs *bs, PyObject *obj, int writable, Py_ssize_t need, const char *name)
{
    Py_buffer *b = &bs->b[bs->n];
    if (PyObject_GetBuffer(obj, b, writable ? PyBUF_WRITABLE : PyBUF_SIMPLE) != 0) return NULL;
    bs->n++;
    if (b->len < need) {
        PyErr_Format(PyExc_ValueError, "_orbitcore: %s has %zd bytes, %zd needed", name, b->len, need);
        return NULL;
    }
    return b->buf;
}

/* Every ephemeris row index within the table K (a buffer of NK doubles per ephemeris); 0 (IndexError set)
   otherwise. */
static int rows_in_range(const int64_t *rows, Py_ssize_t n, const Py_buffer *K)
{
    const Py_ssize_t n_eph = K->len / (Py_ssize_t)(NK * sizeof(double));
    for (Py_ssize_t i = 0; i < n; ++i)
        if (rows[i] < 0 || rows[i] >= n_eph) {
            PyErr_SetString(PyExc_IndexError, "_orbitcore: an ephemeris row is out of range");
            return 0;
        }
    return 1;
}

/* rows, t, starts, live (common to anomaly and kepler); n from t, nb from starts. */
static int blocks_args(Bufs *bs, PyObject *ok, PyObject *orows, PyObject *ot, PyObject *ostarts, PyObject *olive,
                       const double **K, const int64_t **rows, const double **t, const int64_t **starts,
                       uint8_t **live, Py_ssize_t *n, Py_ssize_t *nb)
{
    if (!(*t = take(bs, ot, 0, 0, "t"))) return -1;
    *n = bs->b[bs->n - 1].len / (Py_ssize_t)sizeof(double);
    if (!(*starts = take(bs, ostarts, 0, 0, "starts"))) return -1;
    *nb = bs->b[bs->n - 1].len / (Py_ssize_t)sizeof(int64_t);
    if (!(*rows = take(bs, orows, 0, *n * (Py_ssize_t)sizeof(int64_t), "rows"))) return -1;
    if (!(*live = take(bs, olive, 1, *nb, "live"))) return -1;
    if (!(*K = take(bs, ok, 0, 0, "K"))) return -1;
    if (!rows_in_range(*rows, *n, &bs->b[bs->n - 1])) return -1;
    for (Py_ssize_t j = 0; j < *nb; ++j)
        if ((*starts)[j] < 0 || (*starts)[j] > *n || (j > 0 && (*starts)[j] < (*starts)[j - 1])) {
            PyErr_SetString(PyExc_ValueError, "_orbitcore: block starts must increase within the rows");
            return -1;
        }
    return 0;
}

#define BLOCK_END(starts, nb, n, j) ((j) + 1 < (nb) ? (starts)[(j) + 1] : (n))

static PyObject *py_anomaly(PyObject *self, PyObject *args)
{
    PyObject *o[9];
    int memo;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOp", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7], &o[8], &memo))
        return NULL;
    Bufs bs = {.n = 0};
    const double *K, *t;
    const int64_t *rows, *starts;
    uint8_t *live;
    Py_ssize_t n, nb;
    double *S, *yat, *xat;
    int64_t *info;
    if (blocks_args(&bs, o[0], o[1], o[2], o[3], o[4], &K, &rows, &t, &starts, &live, &n, &nb) < 0 ||
        !(S = take(&bs, o[5], 1, n * NS * (Py_ssize_t)sizeof(double), "S")) ||
        !(info = take(&bs, o[6], 1, n * (Py_ssize_t)sizeof(int64_t), "info")) ||
        !(yat = take(&bs, o[7], 1, n * (Py_ssize_t)sizeof(double), "yat")) ||
        !(xat = take(&bs, o[8], 1, n * (Py_ssize_t)sizeof(double), "xat"))) {
        release(&bs);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t j = 0; j < nb; ++j)
        if (live[j]) block_anomaly(K, rows, t, starts[j], BLOCK_END(starts, nb, n, j), S, info, yat, xat, memo);
    Py_END_ALLOW_THREADS
    release(&bs);
    Py_RETURN_NONE;
}

static PyObject *py_kepler(PyObject *self, PyObject *args)
{
    PyObject *o[10];
    int tgd;
    double ct, st;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOpdd", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7], &o[8],
                          &o[9], &tgd, &ct, &st))
        return NULL;
    Bufs bs = {.n = 0};
    const double *K, *t, *nu;
    const int64_t *rows, *starts;
    uint8_t *live;
    Py_ssize_t n, nb;
    double *S, *xyz, *clk;
    int64_t *info;
    if (blocks_args(&bs, o[0], o[1], o[2], o[3], o[4], &K, &rows, &t, &starts, &live, &n, &nb) < 0 ||
        !(S = take(&bs, o[5], 1, n * NS * (Py_ssize_t)sizeof(double), "S")) ||
        !(info = take(&bs, o[6], 1, n * (Py_ssize_t)sizeof(int64_t), "info")) ||
        !(nu = take(&bs, o[7], 0, n * (Py_ssize_t)sizeof(double), "nu")) ||
        !(xyz = take(&bs, o[8], 1, 3 * n * (Py_ssize_t)sizeof(double), "xyz")) ||
        !(clk = take(&bs, o[9], 1, n * (Py_ssize_t)sizeof(double), "clk"))) {
        release(&bs);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t j = 0; j < nb; ++j) {
        if (!live[j]) continue;
        for (Py_ssize_t i = starts[j]; i < BLOCK_END(starts, nb, n, j); ++i) {
            if (!(info[i] & I_REDO)) continue;
            double *s = S + i * NS;
            kepler_row(K + rows[i] * NK, t[i], s[S_SB], s[S_CB], nu[i], tgd, ct, st, xyz + 3 * i, clk + i);
            s[S_EKOUT] = s[S_EK];
            info[i] |= I_VALID;
        }
    }
    Py_END_ALLOW_THREADS
    release(&bs);
    Py_RETURN_NONE;
}

/* One row of the light-time step: the Sagnac rotation by omega_e tau, the range to q, tau <- range / c, written to
 * output row w; returns whether its step was not below 1e-12 s. */
static inline int light_row(const double *p, double ck, double *tau, const double *q, Py_ssize_t w, double *rot,
                            double *clk_out, double *rng, double *tau_out, double omega_e, double c)
{
    const double tr = *tau;
    double sn, cs;
    SINCOS(omega_e * tr, &sn, &cs);
    const double x = cs * p[0] + sn * p[1], y = -sn * p[0] + cs * p[1], z = p[2];
    const double dx = x - q[0], dy = y - q[1], dz = z - q[2];
    const double r = sqrt(dx * dx + dy * dy + dz * dz);
    const double nt = r / c;
    rot[3 * w] = x;
    rot[3 * w + 1] = y;
    rot[3 * w + 2] = z;
    clk_out[w] = ck;
    rng[w] = r;
    tau_out[w] = nt;
    *tau = nt;
    return !(fabs(nt - tr) < 1e-12);
}

static PyObject *py_light(PyObject *self, PyObject *args)
{
    PyObject *o[11];
    int per_row;
    double omega_e, c;
    if (!PyArg_ParseTuple(args, "OOOOOOpOOOOOdd", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &per_row, &o[6], &o[7],
                          &o[8], &o[9], &o[10], &omega_e, &c))
        return NULL;
    Bufs bs = {.n = 0};
    const double *xyz, *clk, *rx;
    const int64_t *starts, *order;
    uint8_t *live;
    double *tau, *rot, *clk_out, *rng, *tau_out;
    Py_ssize_t n, nb, n_out;
    if (!(tau = take(&bs, o[4], 1, 0, "tau")) || !(starts = take(&bs, o[2], 0, 0, "starts")) ||
        !(rng = take(&bs, o[9], 1, 0, "range"))) {
        release(&bs);
        return NULL;
    }
    n = bs.b[0].len / (Py_ssize_t)sizeof(double);
    nb = bs.b[1].len / (Py_ssize_t)sizeof(int64_t);
    n_out = bs.b[2].len / (Py_ssize_t)sizeof(double);
    if (!(xyz = take(&bs, o[0], 0, 3 * n * (Py_ssize_t)sizeof(double), "xyz")) ||
        !(clk = take(&bs, o[1], 0, n * (Py_ssize_t)sizeof(double), "clk")) ||
        !(live = take(&bs, o[3], 1, nb, "live")) ||
        !(rx = take(&bs, o[5], 0, (per_row ? 3 * n_out : 3) * (Py_ssize_t)sizeof(double), "rx")) ||
        !(order = take(&bs, o[6], 0, n * (Py_ssize_t)sizeof(int64_t), "order")) ||
        !(rot = take(&bs, o[7], 1, 3 * n_out * (Py_ssize_t)sizeof(double), "rot")) ||
        !(clk_out = take(&bs, o[8], 1, n_out * (Py_ssize_t)sizeof(double), "clock")) ||
        !(tau_out = take(&bs, o[10], 1, n_out * (Py_ssize_t)sizeof(double), "travel time"))) {
        release(&bs);
        return NULL;
    }
    for (Py_ssize_t j = 0; j < nb; ++j)
        if (starts[j] < 0 || starts[j] > n || (j > 0 && starts[j] < starts[j - 1])) {
            release(&bs);
            PyErr_SetString(PyExc_ValueError, "_orbitcore: block starts must increase within the rows");
            return NULL;
        }
    for (Py_ssize_t i = 0; i < n; ++i)
        if (order[i] < 0 || order[i] >= n_out) {
            release(&bs);
            PyErr_SetString(PyExc_IndexError, "_orbitcore: an output row is out of range");
            return NULL;
        }
    Py_ssize_t going = 0;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t j = 0; j < nb; ++j) {
        if (!live[j]) continue;
        int more = 0;
        const Py_ssize_t i1 = BLOCK_END(starts, nb, n, j);
        for (Py_ssize_t i = starts[j]; i < i1; ++i)
            more |= light_row(xyz + 3 * i, clk[i], tau + i, per_row ? rx + 3 * order[i] : rx, order[i], rot, clk_out, rng,
                              tau_out, omega_e, c);
        live[j] = (uint8_t)more;
        going += more;
    }
    Py_END_ALLOW_THREADS
    release(&bs);
    return PyLong_FromSsize_t(going);
}

/* The n rows of orbits.sat_position_rows: E after each row's own Newton iterations (it stops after its first step
 * below 1e-15 rad), into ek; state (n bytes) is scratch, kept for the call's signature. */
static PyObject *py_newton(PyObject *self, PyObject *args)
{
    PyObject *o[5];
    if (!PyArg_ParseTuple(args, "OOOOO", &o[0], &o[1], &o[2], &o[3], &o[4])) return NULL;
    Bufs bs = {.n = 0};
    const double *K, *t;
    const int64_t *rows;
    double *ek;
    uint8_t *fixed;
    if (!(t = take(&bs, o[2], 0, 0, "t"))) {
        release(&bs);
        return NULL;
    }
    const Py_ssize_t n = bs.b[0].len / (Py_ssize_t)sizeof(double);
    if (!(K = take(&bs, o[0], 0, 0, "K")) || !(rows = take(&bs, o[1], 0, n * (Py_ssize_t)sizeof(int64_t), "rows")) ||
        !(ek = take(&bs, o[3], 1, n * (Py_ssize_t)sizeof(double), "ek")) || !(fixed = take(&bs, o[4], 1, n, "state"))) {
        release(&bs);
        return NULL;
    }
    if (!rows_in_range(rows, n, &bs.b[1])) {
        release(&bs);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; ++i) {         /* each row on its own: it stops after its first step below 1e-15 */
        const double *k = K + rows[i] * NK;
        const double m = mean_anomaly(k, t[i]), e = k[K_E];
        double b = m;
        for (int it = 1; it <= MAX_NEWTON; ++it) {
            double sn, cs;
            SINCOS(b, &sn, &cs);
            const double d = (b - e * sn - m) / (1.0 - e * cs);
            b = b - d;
            if (fabs(d) < 1e-15) break;
        }
        ek[i] = b;
        fixed[i] = 0;
    }
    Py_END_ALLOW_THREADS
    release(&bs);
    Py_RETURN_NONE;
}

/* sin E, cos E and the arctangent's (y, x) of rows with E known: sn, cs, yat, xat (n). */
static PyObject *py_anomaly_trig(PyObject *self, PyObject *args)
{
    PyObject *o[7];
    if (!PyArg_ParseTuple(args, "OOOOOOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6])) return NULL;
    Bufs bs = {.n = 0};
    const double *K, *ek;
    const int64_t *rows;
    double *sn, *cs, *yat, *xat;
    if (!(ek = take(&bs, o[2], 0, 0, "ek"))) {
        release(&bs);
        return NULL;
    }
    const Py_ssize_t n = bs.b[0].len / (Py_ssize_t)sizeof(double), need = n * (Py_ssize_t)sizeof(double);
    if (!(K = take(&bs, o[0], 0, 0, "K")) || !(rows = take(&bs, o[1], 0, n * (Py_ssize_t)sizeof(int64_t), "rows")) ||
        !(sn = take(&bs, o[3], 1, need, "sin")) || !(cs = take(&bs, o[4], 1, need, "cos")) ||
        !(yat = take(&bs, o[5], 1, need, "yat")) || !(xat = take(&bs, o[6], 1, need, "xat"))) {
        release(&bs);
        return NULL;
    }
    if (!rows_in_range(rows, n, &bs.b[1])) {
        release(&bs);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; ++i) {
        const double *k = K + rows[i] * NK;
        SINCOS(ek[i], sn + i, cs + i);
        yat[i] = k[K_SQ1E2] * sn[i];
        xat[i] = cs[i] - k[K_E];
    }
    Py_END_ALLOW_THREADS
    release(&bs);
    Py_RETURN_NONE;
}

/* Position and clock of rows with sin E, cos E and the true anomaly known: xyz (n, 3), clk (n). */
static PyObject *py_orbit(PyObject *self, PyObject *args)
{
    PyObject *o[8];
    int tgd;
    double ct, st;
    if (!PyArg_ParseTuple(args, "OOOOOOOOpdd", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7], &tgd, &ct, &st))
        return NULL;
    Bufs bs = {.n = 0};
    const double *K, *t, *sn, *cs, *nu;
    const int64_t *rows;
    double *xyz, *clk;
    if (!(t = take(&bs, o[2], 0, 0, "t"))) {
        release(&bs);
        return NULL;
    }
    const Py_ssize_t n = bs.b[0].len / (Py_ssize_t)sizeof(double), need = n * (Py_ssize_t)sizeof(double);
    if (!(K = take(&bs, o[0], 0, 0, "K")) || !(rows = take(&bs, o[1], 0, n * (Py_ssize_t)sizeof(int64_t), "rows")) ||
        !(sn = take(&bs, o[3], 0, need, "sin")) || !(cs = take(&bs, o[4], 0, need, "cos")) ||
        !(nu = take(&bs, o[5], 0, need, "nu")) || !(xyz = take(&bs, o[6], 1, 3 * need, "xyz")) ||
        !(clk = take(&bs, o[7], 1, need, "clk"))) {
        release(&bs);
        return NULL;
    }
    if (!rows_in_range(rows, n, &bs.b[1])) {
        release(&bs);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; ++i)
        kepler_row(K + rows[i] * NK, t[i], sn[i], cs[i], nu[i], tgd, ct, st, xyz + 3 * i, clk + i);
    Py_END_ALLOW_THREADS
    release(&bs);
    Py_RETURN_NONE;
}

/* East/north/up of satellites seen from one receiver (orbits.azimuth_elevation's einsum of R with xyz - rx):
 * out (n, 3); each component summed as numpy's einsum sums three products, (r0 d0 + r2 d2) + r1 d1. */
static PyObject *py_enu(PyObject *self, PyObject *args)
{
    PyObject *o[4];
    if (!PyArg_ParseTuple(args, "OOOO", &o[0], &o[1], &o[2], &o[3])) return NULL;
    Bufs bs = {.n = 0};
    const double *R, *rx, *xyz;
    double *out;
    if (!(xyz = take(&bs, o[2], 0, 0, "xyz"))) {
        release(&bs);
        return NULL;
    }
    const Py_ssize_t n = bs.b[0].len / (Py_ssize_t)(3 * sizeof(double));
    if (!(R = take(&bs, o[0], 0, 9 * (Py_ssize_t)sizeof(double), "R")) ||
        !(rx = take(&bs, o[1], 0, 3 * (Py_ssize_t)sizeof(double), "rx")) ||
        !(out = take(&bs, o[3], 1, 3 * n * (Py_ssize_t)sizeof(double), "out"))) {
        release(&bs);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; ++i) {
        const double d0 = xyz[3 * i] - rx[0], d1 = xyz[3 * i + 1] - rx[1], d2 = xyz[3 * i + 2] - rx[2];
        for (int k = 0; k < 3; ++k) {
            const double *r = R + 3 * k;
            out[3 * i + k] = (r[0] * d0 + r[2] * d2) + r[1] * d1;
        }
    }
    Py_END_ALLOW_THREADS
    release(&bs);
    Py_RETURN_NONE;
}

/* The Marini continued fraction normalised to 1 at zenith (positioning._marini). */
static double marini(double s, double a, double b, double c)
{
    return (1.0 + a / (1.0 + b / (1.0 + c))) / (s + a / (s + b / (s + c)));
}

/* Niell's hydrostatic mapping (positioning.niell_hydrostatic_mapping) at one latitude and height, as numpy evaluates
 * it: el, doy (n) -> out (n); p (11) = the a, b, c interpolated averages and amplitudes at the latitude, the
 * seasonal phase offset (0 or 0.5), the height (m) and the three coefficients of the height correction. */
static PyObject *py_niell(PyObject *self, PyObject *args)
{
    PyObject *o[4];
    if (!PyArg_ParseTuple(args, "OOOO", &o[0], &o[1], &o[2], &o[3])) return NULL;
    Bufs bs = {.n = 0};
    const double *el, *doy, *p;
    double *out;
    if (!(el = take(&bs, o[0], 0, 0, "el"))) {
        release(&bs);
        return NULL;
    }
    const Py_ssize_t n = bs.b[0].len / (Py_ssize_t)sizeof(double), need = n * (Py_ssize_t)sizeof(double);
    if (!(doy = take(&bs, o[1], 0, need, "doy")) || !(p = take(&bs, o[2], 0, 11 * (Py_ssize_t)sizeof(double), "p")) ||
        !(out = take(&bs, o[3], 1, need, "out"))) {
        release(&bs);
        return NULL;
    }
    const double two_pi = 2.0 * 3.141592653589793;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; ++i) {
        const double y = (doy[i] - 28.0) / 365.25 + p[6];
        const double cosy = cos(two_pi * y);
        const double a = p[0] - p[3] * cosy, b = p[1] - p[4] * cosy, c = p[2] - p[5] * cosy;
        const double e = el[i], s = sin(e > 1e-6 ? e : 1e-6);
        const double m = marini(s, a, b, c);
        const double dm = (1.0 / s - marini(s, p[8], p[9], p[10])) * p[7] / 1e3;
        out[i] = e > 0.0 ? m + dm : 0.0;
    }
    Py_END_ALLOW_THREADS
    release(&bs);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"anomaly", py_anomaly, METH_VARARGS, "Kepler's equation on the live blocks (see the file's header)."},
    {"kepler", py_kepler, METH_VARARGS, "Position and clock of the rows evaluated by anomaly (see the header)."},
    {"light", py_light, METH_VARARGS, "One light-time step of the live blocks; returns the blocks still going."},
    {"newton", py_newton, METH_VARARGS, "Kepler's equation on every row, each on its own (see the header)."},
    {"anomaly_trig", py_anomaly_trig, METH_VARARGS, "sin E, cos E and the true anomaly's (y, x)."},
    {"orbit", py_orbit, METH_VARARGS, "Position and clock from sin E, cos E and the true anomaly."},
    {"enu", py_enu, METH_VARARGS, "East/north/up of satellites from one receiver (einsum's sums)."},
    {"niell", py_niell, METH_VARARGS, "Niell hydrostatic mapping at one latitude and height."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef moddef = {
    PyModuleDef_HEAD_INIT, "_orbitcore", "Compiled Kepler orbits and light time of cdgps_cli.model.gps.orbits.", -1,
    methods};

PyMODINIT_FUNC PyInit__orbitcore(void)
{
    PyObject *m = PyModule_Create(&moddef);
    if (m && (PyModule_AddIntConstant(m, "API", 4) < 0 || PyModule_AddIntConstant(m, "NK", NK) < 0 ||
              PyModule_AddIntConstant(m, "NS", NS) < 0)) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
