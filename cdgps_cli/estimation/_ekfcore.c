/*
 * _ekfcore: compiled inner loops of cdgps_cli.estimation.filter (forward EKF with fixed biases, RTS smoother)
 * and the single-epoch carrier-phase measurement model they need.
 *
 * The Python side (cdgps_cli/estimation/kernel.py) packs the configuration into flat arrays and calls
 *
 *   phase_model(gi, gf, x, h, H)                      h(x) and H = dh/dx[:, :n_m] of one state
 *   filter_span(...) -> (k_stop, fail_run, reason)    steady-state epochs k0 .. k_stop-1
 *   rts(...) -> -1 or failing epoch                   RTS pass over filtered arrays
 *   dd_span(...) -> (k_stop, reason)                  whitened full-noise (DD) iterated EKF span
 *   sd_update(...) -> NIS or None                     the static engine's covariance-form update of one epoch
 *                                                     (kalman.iterated_update_covariance on RunDDModel rows;
 *                                                     numpy's own BLAS calls, so the same bits: see there)
 *
 * filter_span stops, without touching the outputs of that epoch, at the first epoch that needs the
 * Python logic of ekf.estimate (a lock event, a channel being re-biased, an innovation outlier, a
 * re-initialization, a Cholesky failure); x and P then hold the state entering that epoch and the
 * Python loop handles it exactly as the pure-numpy path does.
 *
 * Why a plain CPython extension with the buffer protocol (not the numpy C API): nothing here needs
 * numpy at build time, so `pip install -e .` compiles it with only a C compiler and the Python
 * headers (no numpy in [build-system] requires, no ABI coupling to the numpy version).  Every array
 * is checked for C-contiguity, element type and size before use.
 *
 * All matrices are row-major.  Dimensions are small (n <= ~100) so everything is plain loops.
 */

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define KERNEL_API 5

/* stop reasons of filter_span */
enum { STOP_END = 0, STOP_EVENT = 1, STOP_REBIAS = 2, STOP_OUTLIER = 3, STOP_REINIT = 4, STOP_CHOLESKY = 5 };

/* ------------------------------------------------------------------------------------------ */
/* buffers */

typedef struct {
    Py_buffer view;
    int held;
} Buf;

/* kind: 'd' float64, 'q' int64, 'b' one-byte integer (int8 / uint8 / bool) */
static int get_buf(PyObject *obj, Buf *b, char kind, Py_ssize_t count, int writable, const char *name)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, &b->view, flags) != 0) {
        PyErr_Format(PyExc_TypeError, "_ekfcore: %s: expected a C-contiguous%s array",
                     name, writable ? " writable" : "");
        return -1;
    }
    b->held = 1;
    const char *f = b->view.format ? b->view.format : "B";
    if (*f == '@' || *f == '=') {
        f++;
    } else if (*f == '<' || *f == '>' || *f == '!') {
        const uint16_t one = 1;
        int little = *(const uint8_t *)&one == 1;
        if ((*f == '<') == little) f++;          /* explicit byte order: accepted when native */
    }
    int ok = 0;
    switch (kind) {
    case 'd': ok = (f[0] == 'd' && f[1] == 0 && b->view.itemsize == 8); break;
    case 'q': ok = ((f[0] == 'q' || f[0] == 'l') && f[1] == 0 && b->view.itemsize == 8); break;
    case 'b': ok = ((f[0] == 'b' || f[0] == 'B' || f[0] == '?') && f[1] == 0 && b->view.itemsize == 1); break;
    }
    if (!ok) {
        PyErr_Format(PyExc_TypeError, "_ekfcore: %s: wrong element type (format %s)", name, b->view.format);
        return -1;
    }
    if (b->view.len != count * b->view.itemsize) {
        PyErr_Format(PyExc_ValueError, "_ekfcore: %s: expected %zd elements, got %zd", name, count,
                     (Py_ssize_t)(b->view.len / b->view.itemsize));
        return -1;
    }
    return 0;
}

static void release_all(Buf *bufs, int n)
{
    for (int i = 0; i < n; i++)
        if (bufs[i].held) {
            PyBuffer_Release(&bufs[i].view);
            bufs[i].held = 0;
        }
}

/* ------------------------------------------------------------------------------------------ */
/* geometry: packed by ekf_kernel.pack_geometry
 *
 * gi (int64): nq, nm, na, nc, ns, master, far, rigid, has_D, ntr,
 *             sec[na], rot_idx[ns*3], ch_ant[nc], trans[ntr*3] (antenna, axis, coordinate)
 * gf (float64): origin[3], pivot[na*3], rel[na*3], D[na*3*nq], U[nq*nm], tpos[nc*3]
 */

#define GI_HEAD 10

typedef struct {
    int nq, nm, na, nc, ns, master, far, rigid, has_D, ntr;
    const int64_t *sec, *rot_idx, *ch_ant, *trans;
    const double *origin, *pivot, *rel, *D, *U, *tpos;
} Geom;

/* validates the packed geometry; gi_len / gf_len are element counts */
static int geom_parse(const int64_t *gi, Py_ssize_t gi_len, const double *gf, Py_ssize_t gf_len, Geom *g)
{
    if (gi_len < GI_HEAD) goto bad;
    for (int i = 0; i < GI_HEAD; i++)
        if (gi[i] < -1 || gi[i] > 1000000) goto bad;
    g->nq = (int)gi[0]; g->nm = (int)gi[1]; g->na = (int)gi[2]; g->nc = (int)gi[3]; g->ns = (int)gi[4];
    g->master = (int)gi[5]; g->far = (int)gi[6]; g->rigid = (int)gi[7]; g->has_D = (int)gi[8]; g->ntr = (int)gi[9];
    if (g->nq < 1 || g->nm < 1 || g->na < 1 || g->nc < 0 || g->ns < 0 || g->ntr < 0) goto bad;
    if (g->master < 0 || g->master >= g->na || g->rigid < -1 || g->rigid >= g->nq) goto bad;
    Py_ssize_t need_i = GI_HEAD + g->na + 3 * (Py_ssize_t)g->ns + g->nc + 3 * (Py_ssize_t)g->ntr;
    Py_ssize_t need_f = 3 + 6 * (Py_ssize_t)g->na + 3 * (Py_ssize_t)g->na * g->nq + (Py_ssize_t)g->nq * g->nm
                        + 3 * (Py_ssize_t)g->nc;
    if (gi_len != need_i || gf_len != need_f) goto bad;
    const int64_t *p = gi + GI_HEAD;
    g->sec = p; p += g->na;
    g->rot_idx = p; p += 3 * g->ns;
    g->ch_ant = p; p += g->nc;
    g->trans = p;
    for (int a = 0; a < g->na; a++)
        if (g->sec[a] < -1 || g->sec[a] >= g->ns) goto bad;
    for (int i = 0; i < 3 * g->ns; i++)
        if (g->rot_idx[i] < -1 || g->rot_idx[i] >= g->nq) goto bad;
    for (int c = 0; c < g->nc; c++)
        if (g->ch_ant[c] < 0 || g->ch_ant[c] >= g->na) goto bad;
    for (int t = 0; t < g->ntr; t++) {
        const int64_t *tr = g->trans + 3 * t;
        if (tr[0] < 0 || tr[0] >= g->na || tr[1] < 0 || tr[1] > 2 || tr[2] < 0 || tr[2] >= g->nq) goto bad;
    }
    const double *f = gf;
    g->origin = f; f += 3;
    g->pivot = f; f += 3 * g->na;
    g->rel = f; f += 3 * g->na;
    g->D = f; f += 3 * (Py_ssize_t)g->na * g->nq;
    g->U = f; f += (Py_ssize_t)g->nq * g->nm;
    g->tpos = f;
    return 0;
bad:
    PyErr_SetString(PyExc_ValueError, "_ekfcore: inconsistent packed geometry");
    return -1;
}

/* scratch doubles needed by model_eval */
static Py_ssize_t model_work_size(const Geom *g)
{
    return g->nq + 36 * (Py_ssize_t)g->ns + 6 * (Py_ssize_t)g->na + 3 * (Py_ssize_t)g->na * g->nq
           + 3 * (Py_ssize_t)g->na * g->nm;
}

static void mm3(const double *a, const double *b, double *out)
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            out[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
}

/* elementary rotation about `axis` (right-handed, plane (i, j)) and its derivative */
static void rot_elem(int axis, double c, double s, double *E, double *dE)
{
    int i = (axis + 1) % 3, j = (axis + 2) % 3;
    memset(E, 0, 9 * sizeof(double));
    memset(dE, 0, 9 * sizeof(double));
    E[4 * axis] = 1.0;
    E[4 * i] = c;
    E[4 * j] = c;
    E[3 * i + j] = -s;
    E[3 * j + i] = s;
    dE[4 * i] = -s;
    dE[4 * j] = -s;
    dE[3 * i + j] = -c;
    dE[3 * j + i] = c;
}

/*
 * h (nc) and, when jac, Hm (nc x nm): the Jacobian's non-zero block, dh/dxi = (dh/dq) U (Hm is not
 * touched without jac).  Same model as kinematics.EpochGeometry.positions + measurement.EpochPhaseModel.
 */
static void model_eval_opt(const Geom *g, const double *x, double *h, double *Hm, double *work, int jac)
{
    const int nq = g->nq, nm = g->nm, na = g->na;
    double *q = work;
    double *R = q + nq;                 /* ns * 9 */
    double *dR = R + 9 * g->ns;         /* ns * 27: d/dθx, d/dθy, d/dθz */
    double *loc = dR + 27 * g->ns;      /* na * 3 */
    double *pos = loc + 3 * na;         /* na * 3 */
    double *J = pos + 3 * na;           /* na * 3 * nq */
    double *G = J + 3 * na * nq;        /* na * 3 * nm */

    for (int i = 0; i < nq; i++) {
        double s = 0.0;
        for (int j = 0; j < nm; j++) s += g->U[i * nm + j] * x[j];
        q[i] = s;
    }
    for (int s = 0; s < g->ns; s++) {
        double E[3][9], dE[3][9], RzRy[9], t[9];
        for (int ax = 0; ax < 3; ax++) {
            int64_t j = g->rot_idx[3 * s + ax];
            double ang = j >= 0 ? q[j] : 0.0;
            rot_elem(ax, cos(ang), sin(ang), E[ax], dE[ax]);
        }
        mm3(E[2], E[1], RzRy);
        mm3(RzRy, E[0], R + 9 * s);
        if (!jac) continue;
        mm3(RzRy, dE[0], dR + 27 * s);
        mm3(E[2], dE[1], t);
        mm3(t, E[0], dR + 27 * s + 9);
        mm3(dE[2], E[1], t);
        mm3(t, E[0], dR + 27 * s + 18);
    }
    if (jac) memcpy(J, g->D, sizeof(double) * 3 * na * nq);
    for (int a = 0; a < na; a++) {
        double *l = loc + 3 * a;
        const double *rel = g->rel + 3 * a;
        for (int i = 0; i < 3; i++) {
            double v = g->pivot[3 * a + i];
            if (g->has_D) {
                const double *Di = g->D + (3 * a + i) * nq;
                double s = 0.0;
                for (int j = 0; j < nq; j++) s += Di[j] * q[j];
                v += s;
            }
            l[i] = v;
        }
        int s = (int)g->sec[a];
        if (s >= 0) {
            const double *Rs = R + 9 * s;
            for (int i = 0; i < 3; i++)
                l[i] += Rs[3 * i] * rel[0] + Rs[3 * i + 1] * rel[1] + Rs[3 * i + 2] * rel[2];
        } else {
            for (int i = 0; i < 3; i++) l[i] += rel[i];
        }
    }
    for (int t = 0; t < g->ntr; t++) {
        const int64_t *tr = g->trans + 3 * t;
        loc[3 * tr[0] + tr[1]] += q[tr[2]];
        if (jac) J[(3 * tr[0] + tr[1]) * nq + tr[2]] += 1.0;
    }
    for (int a = 0; a < na && jac; a++) {
        int s = (int)g->sec[a];
        if (s < 0) continue;
        const double *rel = g->rel + 3 * a;
        for (int ax = 0; ax < 3; ax++) {
            int64_t j = g->rot_idx[3 * s + ax];
            if (j < 0) continue;
            const double *M = dR + 27 * s + 9 * ax;
            for (int i = 0; i < 3; i++)
                J[(3 * a + i) * nq + j] += M[3 * i] * rel[0] + M[3 * i + 1] * rel[1] + M[3 * i + 2] * rel[2];
        }
    }
    if (g->rigid >= 0) {
        double psi = q[g->rigid], c = cos(psi), s = sin(psi);
        for (int a = 0; a < na; a++) {
            const double *l = loc + 3 * a;
            double *p = pos + 3 * a;
            p[0] = (l[0] * c + l[1] * -s + l[2] * 0.0) + g->origin[0];
            p[1] = (l[0] * s + l[1] * c + l[2] * 0.0) + g->origin[1];
            p[2] = (l[0] * 0.0 + l[1] * 0.0 + l[2]) + g->origin[2];
            if (!jac) continue;
            double *J0 = J + (3 * a) * nq, *J1 = J0 + nq;
            for (int j = 0; j < nq; j++) {
                double a0 = J0[j], a1 = J1[j];
                J0[j] = c * a0 - s * a1;
                J1[j] = s * a0 + c * a1;
            }
            J0[g->rigid] += -s * l[0] - c * l[1];
            J1[g->rigid] += c * l[0] - s * l[1];
        }
    } else {
        for (int a = 0; a < na; a++)
            for (int i = 0; i < 3; i++) pos[3 * a + i] = loc[3 * a + i] + g->origin[i];
    }
    /* G_a = J_a U  (3 x nm) */
    for (int r = 0; r < 3 * na && jac; r++) {
        const double *Jr = J + r * nq;
        double *Gr = G + r * nm;
        for (int j = 0; j < nm; j++) Gr[j] = 0.0;
        for (int k = 0; k < nq; k++) {
            double v = Jr[k];
            if (v == 0.0) continue;
            const double *Uk = g->U + k * nm;
            for (int j = 0; j < nm; j++) Gr[j] += v * Uk[j];
        }
    }
    const int m = g->master;
    const double *pm = pos + 3 * m, *Gm = G + 3 * m * nm;
    for (int c = 0; c < g->nc; c++) {
        int a = (int)g->ch_ant[c];
        const double *pa = pos + 3 * a, *Ga = G + 3 * a * nm, *t = g->tpos + 3 * c;
        double *Hc = Hm + c * nm;
        if (g->far) {
            h[c] = -(t[0] * (pa[0] - pm[0]) + t[1] * (pa[1] - pm[1]) + t[2] * (pa[2] - pm[2]));
            for (int j = 0; j < nm && jac; j++)
                Hc[j] = -(t[0] * (Ga[j] - Gm[j]) + t[1] * (Ga[nm + j] - Gm[nm + j]) + t[2] * (Ga[2 * nm + j] - Gm[2 * nm + j]));
        } else {
            double va[3], vm[3];
            for (int i = 0; i < 3; i++) {
                va[i] = t[i] - pa[i];
                vm[i] = t[i] - pm[i];
            }
            double da = sqrt(va[0] * va[0] + va[1] * va[1] + va[2] * va[2]);
            double dm = sqrt(vm[0] * vm[0] + vm[1] * vm[1] + vm[2] * vm[2]);
            h[c] = da - dm;
            if (!jac) continue;
            for (int i = 0; i < 3; i++) {
                va[i] /= da;
                vm[i] /= dm;
            }
            for (int j = 0; j < nm; j++)
                Hc[j] = (vm[0] * Gm[j] + vm[1] * Gm[nm + j] + vm[2] * Gm[2 * nm + j])
                        - (va[0] * Ga[j] + va[1] * Ga[nm + j] + va[2] * Ga[2 * nm + j]);
        }
    }
}

static void model_eval(const Geom *g, const double *x, double *h, double *Hm, double *work)
{
    model_eval_opt(g, x, h, Hm, work, 1);
}

/* ------------------------------------------------------------------------------------------ */
/* dense helpers (n x n, row-major) */

/*
 * Upper Cholesky factor R of the SPD matrix M (M = R^T R; reads M's upper triangle, as LAPACK's
 * dpotrf with uplo="U" that the numpy path uses).  Right-looking, row-contiguous updates.  R's
 * strictly lower triangle is left undefined.  Returns 0, or -1 when M is not positive definite.
 */
static int cholesky_upper(const double *restrict M, double *restrict R, int n)
{
    for (int i = 0; i < n; i++) memcpy(R + i * n + i, M + i * n + i, sizeof(double) * (n - i));
    for (int i = 0; i < n; i++) {
        double *Ri = R + i * n;
        double d = Ri[i];
        if (!(d > 0.0)) return -1;          /* also catches NaN */
        double r = sqrt(d), ir = 1.0 / r;
        Ri[i] = r;
        for (int j = i + 1; j < n; j++) Ri[j] *= ir;
        for (int k = i + 1; k < n; k++) {
            double a = Ri[k];
            double *Rk = R + k * n;
            for (int j = k; j < n; j++) Rk[j] -= a * Ri[j];
        }
    }
    return 0;
}

/* V = R^-1 (upper triangular; row i solves V[i, :] R = e_i); V's strictly lower triangle is zeroed.
   d: n scratch doubles (reciprocal diagonal, so that no division sits on a dependency chain).  The
   rows are independent: step k advances every started row, which interleaves their chains. */
static void upper_inverse(const double *restrict R, double *restrict V, double *restrict d, int n)
{
    for (int k = 0; k < n; k++) d[k] = 1.0 / R[k * n + k];
    memset(V, 0, sizeof(double) * n * n);               /* row i accumulates -sum_k V[i,k] R[k,j] */
    for (int k = 0; k < n; k++) {
        const double *Rk = R + k * n;
        for (int i = 0; i <= k; i++) {
            double *Vi = V + i * n;
            double v = ((k == i ? 1.0 : 0.0) + Vi[k]) * d[k];
            Vi[k] = v;
            for (int j = k + 1; j < n; j++) Vi[j] -= v * Rk[j];
        }
    }
}

/* inverse of an SPD matrix by Cholesky: out = R^-1 R^-T (exactly symmetric); work: 2 n^2 + n.
   out[i][j] = sum_{k >= j} V[i][k] V[j][k] (j >= i), each summed over ascending k from 0.0 as a dot
   product would; the accumulators of row i advance together along k (T = V^T, in R's place: its row k
   is column k of V, contiguous), so they are independent chains and vectorize, with the same values. */
static int chol_inv(const double *restrict M, double *restrict out, double *restrict work, int n)
{
    double *R = work, *V = work + n * n, *T = work;
    if (cholesky_upper(M, R, n) != 0) return -1;
    upper_inverse(R, V, V + n * n, n);
    for (int k = 0; k < n; k++)
        for (int j = 0; j < n; j++) T[k * n + j] = V[j * n + k];
    for (int i = 0; i < n; i++) {
        const double *Vi = V + i * n;
        double *o = out + i * n;
        for (int j = i; j < n; j++) o[j] = 0.0;
        for (int k = i; k < n; k++) {
            const double v = Vi[k], *Tk = T + k * n;
            for (int j = i; j <= k; j++) o[j] += v * Tk[j];
        }
        for (int j = i + 1; j < n; j++) out[j * n + i] = o[j];
    }
    return 0;
}

/* sparse A in CSR form */
typedef struct {
    const int64_t *row, *col;
    const double *val;
} Csr;

static int csr_check(const Csr *A, int n, Py_ssize_t nnz)
{
    if (A->row[0] != 0 || A->row[n] != nnz) return -1;
    for (int i = 0; i < n; i++)
        if (A->row[i + 1] < A->row[i]) return -1;
    for (Py_ssize_t z = 0; z < nnz; z++)
        if (A->col[z] < 0 || A->col[z] >= n) return -1;
    return 0;
}

/* xo = A x */
static void csr_matvec(const Csr *A, const double *x, double *xo, int n)
{
    for (int i = 0; i < n; i++) {
        double s = 0.0;
        for (int64_t z = A->row[i]; z < A->row[i + 1]; z++) s += A->val[z] * x[A->col[z]];
        xo[i] = s;
    }
}

/* out = (X + X^T) / 2 for n x n row-major X; out may be X */
static void sym_part(const double *X, double *out, int n)
{
    for (int i = 0; i < n; i++) {
        out[i * n + i] = X[i * n + i];
        for (int j = i + 1; j < n; j++) {
            double v = 0.5 * (X[i * n + j] + X[j * n + i]);
            out[i * n + j] = v;
            out[j * n + i] = v;
        }
    }
}

/* xo = A x + B u (B: n x nu) */
static void predict_x(const Csr *A, const double *B, const double *u, int nu, const double *x, double *xo, int n)
{
    csr_matvec(A, x, xo, n);
    int any = 0;
    for (int j = 0; j < nu; j++) any |= (u[j] != 0.0);
    if (any) {                          /* B u (thrusters off: exactly zero, skipped) */
        for (int i = 0; i < n; i++) {
            double s = 0.0;
            const double *Bi = B + i * nu;
            for (int j = 0; j < nu; j++) s += Bi[j] * u[j];
            xo[i] += s;
        }
    }
}

/* AP = A P;  Po = AP A^T + Q (exactly symmetric) */
static void predict_P(const Csr *A, const double *Q, const double *P, double *AP, double *Po, int n)
{
    for (int i = 0; i < n; i++) {
        double *r = AP + i * n;
        for (int j = 0; j < n; j++) r[j] = 0.0;
        for (int64_t z = A->row[i]; z < A->row[i + 1]; z++) {
            double a = A->val[z];
            const double *Pr = P + A->col[z] * n;
            for (int j = 0; j < n; j++) r[j] += a * Pr[j];
        }
    }
    for (int i = 0; i < n; i++) {
        const double *r = AP + i * n;
        for (int l = i; l < n; l++) {
            double s = 0.0;
            for (int64_t z = A->row[l]; z < A->row[l + 1]; z++) s += r[A->col[z]] * A->val[z];
            s += Q[i * n + l];
            Po[i * n + l] = s;
            Po[l * n + i] = s;
        }
    }
}

/* H P H^T of one measurement row H (non-zero in the first nm columns) and the n x n covariance P */
static double quad_nm(const double *P, int n, const double *H, int nm)
{
    double s = 0.0;
    for (int a = 0; a < nm; a++) {
        const double *Pa = P + a * n;
        double t = 0.0;
        for (int bb = 0; bb < nm; bb++) t += Pa[bb] * H[bb];
        s += t * H[a];
    }
    return s;
}

/* s[i] = H_i P H_i^T for the m rows idx[i] of H (rows of nm; P's leading nm x nm block), each summed in
   quad_nm's order; the m rows' accumulators advance together (T: the rows transposed, nm x m; t: m). */
static void quad_rows(const double *restrict P, int n, const double *restrict H, int nm, const int *restrict idx,
                      int m, double *restrict T, double *restrict t, double *restrict s)
{
    for (int i = 0; i < m; i++) {
        const double *Hc = H + (Py_ssize_t)idx[i] * nm;
        for (int b = 0; b < nm; b++) T[b * m + i] = Hc[b];
        s[i] = 0.0;
    }
    for (int a = 0; a < nm; a++) {
        const double *Pa = P + a * n, *Ta = T + a * m;
        for (int i = 0; i < m; i++) t[i] = 0.0;
        for (int b = 0; b < nm; b++) {
            const double p = Pa[b], *Tb = T + b * m;
            for (int i = 0; i < m; i++) t[i] += p * Tb[i];
        }
        for (int i = 0; i < m; i++) s[i] += t[i] * Ta[i];
    }
}

/* ------------------------------------------------------------------------------------------ */
/* Python entry points */

static int get_geom(PyObject *ogi, PyObject *ogf, Buf *bgi, Buf *bgf, Geom *g);

static PyObject *py_phase_model(PyObject *self, PyObject *args)
{
    PyObject *o[5];
    Buf b[5];
    memset(b, 0, sizeof(b));
    if (!PyArg_ParseTuple(args, "OOOOO", &o[0], &o[1], &o[2], &o[3], &o[4])) return NULL;
    PyObject *ret = NULL;
    double *work = NULL;
    Geom g;
    if (get_geom(o[0], o[1], &b[0], &b[1], &g)) goto done;
    if (get_buf(o[2], &b[2], 'd', 2 * g.nm, 0, "x") || get_buf(o[3], &b[3], 'd', g.nc, 1, "h")
        || get_buf(o[4], &b[4], 'd', (Py_ssize_t)g.nc * g.nm, 1, "H"))
        goto done;
    work = malloc(sizeof(double) * (model_work_size(&g) + 1));
    if (!work) {
        PyErr_NoMemory();
        goto done;
    }
    model_eval(&g, b[2].view.buf, b[3].view.buf, b[4].view.buf, work);
    ret = Py_NewRef(Py_None);
done:
    free(work);
    release_all(b, 5);
    return ret;
}

/* shared geometry + CSR buffer acquisition for filter_span / rts */
static int get_geom(PyObject *ogi, PyObject *ogf, Buf *bgi, Buf *bgf, Geom *g)
{
    if (PyObject_GetBuffer(ogi, &bgi->view, PyBUF_SIMPLE) != 0) return -1;
    Py_ssize_t gi_len = bgi->view.len / 8;
    PyBuffer_Release(&bgi->view);
    if (PyObject_GetBuffer(ogf, &bgf->view, PyBUF_SIMPLE) != 0) return -1;
    Py_ssize_t gf_len = bgf->view.len / 8;
    PyBuffer_Release(&bgf->view);
    if (get_buf(ogi, bgi, 'q', gi_len, 0, "gi") || get_buf(ogf, bgf, 'd', gf_len, 0, "gf")) return -1;
    return geom_parse(bgi->view.buf, gi_len, bgf->view.buf, gf_len, g);
}

static int get_csr(PyObject *orow, PyObject *ocol, PyObject *oval, Buf *b, int n, Csr *A)
{
    if (get_buf(orow, &b[0], 'q', n + 1, 0, "A_row")) return -1;
    const int64_t *row = b[0].view.buf;
    Py_ssize_t nnz = row[n];
    if (nnz < 0 || nnz > (Py_ssize_t)n * n) {
        PyErr_SetString(PyExc_ValueError, "_ekfcore: bad CSR row pointer");
        return -1;
    }
    if (get_buf(ocol, &b[1], 'q', nnz, 0, "A_col") || get_buf(oval, &b[2], 'd', nnz, 0, "A_val")) return -1;
    A->row = row;
    A->col = b[1].view.buf;
    A->val = b[2].view.buf;
    if (csr_check(A, n, nnz)) {
        PyErr_SetString(PyExc_ValueError, "_ekfcore: bad CSR matrix");
        return -1;
    }
    return 0;
}

/*
 * filter_span(gi, gf, A_row, A_col, A_val, Q, B, chi2, Y, EVENT, bias, rebias, U_in,
 *             x, P, xs, Ps, resid, nis, nis_dof, r_var, hph,
 *             N, n, nu, k0, k1, fail_run, reinit_after, k_reinit_block, outlier_sigma)
 *   -> (k_stop, fail_run, reason)
 * r_var (C,): the measurement variance of each channel (m^2), R = diag(r_var) over the used rows.
 * hph (N, C): for each used channel c of a committed epoch k, H_c(x_k) P_k H_c(x_k)^T (m^2) with the
 * Jacobian at the filtered state x_k and the filtered P_k (the residual noise estimate's term).
 */
static PyObject *py_filter_span(PyObject *self, PyObject *args)
{
    enum { NB = 22 };
    PyObject *o[NB];
    Buf b[NB];
    memset(b, 0, sizeof(b));
    Py_ssize_t N, n, nu, k0, k1, fail_run, reinit_after, k_reinit_block;
    double outlier_sigma;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOOOOOOOOOOnnnnnnnnd", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5],
                          &o[6], &o[7], &o[8], &o[9], &o[10], &o[11], &o[12], &o[13], &o[14], &o[15], &o[16],
                          &o[17], &o[18], &o[19], &o[20], &o[21], &N, &n, &nu, &k0, &k1, &fail_run, &reinit_after,
                          &k_reinit_block, &outlier_sigma))
        return NULL;
    PyObject *ret = NULL;
    double *work = NULL;
    Geom g;
    Csr A;
    if (get_geom(o[0], o[1], &b[0], &b[1], &g)) goto done;
    if (n < 2 * g.nm || n > 4096 || N < 0 || nu < 0 || k0 < 0 || k1 > N || k0 > k1) {
        PyErr_SetString(PyExc_ValueError, "_ekfcore.filter_span: bad dimensions");
        goto done;
    }
    const Py_ssize_t C = g.nc, nn = n * n;
    if (get_csr(o[2], o[3], o[4], b + 2, (int)n, &A)
        || get_buf(o[5], &b[5], 'd', nn, 0, "Q") || get_buf(o[6], &b[6], 'd', n * nu, 0, "B")
        || get_buf(o[7], &b[7], 'd', C + 1, 0, "chi2") || get_buf(o[8], &b[8], 'd', N * C, 0, "Y")
        || get_buf(o[9], &b[9], 'b', N * C, 0, "EVENT") || get_buf(o[10], &b[10], 'd', C, 0, "bias")
        || get_buf(o[11], &b[11], 'b', C, 0, "rebias") || get_buf(o[12], &b[12], 'd', N * nu, 0, "U_in")
        || get_buf(o[13], &b[13], 'd', n, 1, "x") || get_buf(o[14], &b[14], 'd', nn, 1, "P")
        || get_buf(o[15], &b[15], 'd', N * n, 1, "xs") || get_buf(o[16], &b[16], 'd', N * nn, 1, "Ps")
        || get_buf(o[17], &b[17], 'd', N * C, 1, "resid") || get_buf(o[18], &b[18], 'd', N, 1, "nis")
        || get_buf(o[19], &b[19], 'q', N, 1, "nis_dof") || get_buf(o[20], &b[20], 'd', C, 0, "r_var")
        || get_buf(o[21], &b[21], 'd', N * C, 1, "hph"))
        goto done;

    const double *Q = b[5].view.buf, *B = b[6].view.buf, *chi2 = b[7].view.buf, *Y = b[8].view.buf;
    const int8_t *EV = b[9].view.buf;
    const double *bias = b[10].view.buf;
    const uint8_t *rebias = b[11].view.buf;
    const double *U_in = b[12].view.buf;
    double *x = b[13].view.buf, *P = b[14].view.buf, *xs = b[15].view.buf, *Ps = b[16].view.buf;
    double *resid = b[17].view.buf, *nis = b[18].view.buf;
    int64_t *dof = b[19].view.buf;
    const double *r_var = b[20].view.buf;
    double *hph = b[21].view.buf;
    const int nm = g.nm, ni = (int)n;
    for (Py_ssize_t c = 0; c < C; c++)
        if (!(r_var[c] > 0.0) || !isfinite(r_var[c])) {
            PyErr_SetString(PyExc_ValueError, "_ekfcore.filter_span: r_var must be positive and finite");
            goto done;
        }

    /* scratch */
    Py_ssize_t wm = model_work_size(&g);
    Py_ssize_t total = wm + 2 * n + 6 * nn + n + C + C * nm + C + nm + C * nm + C + C + C * nm
                       + nm * nm + nm + nm * C + 2 * C;
    work = malloc(sizeof(double) * (total + 1));
    int *used = malloc(sizeof(int) * (C + 1));
    if (!work || !used) {
        free(used);
        PyErr_NoMemory();
        goto done;
    }
    double *mw = work;
    double *xp = mw + wm, *xn = xp + n;
    double *Pp = xn + n, *AP = Pp + nn, *Yi = AP + nn, *Pn = Yi + nn;    /* prior, A P, information, posterior */
    double *cw = Pn + nn;                       /* 2 nn + n: chol_inv work */
    double *h = cw + 2 * nn + n, *Hm = h + C;
    double *rho = Hm + C * nm, *grad = rho + C, *Hu = grad + nm, *wr = Hu + C * nm;   /* wr: 1/R of used rows */
    double *hf = wr + C, *Hf = hf + C;          /* the model at the filtered state (hph) */
    double *acc = Hf + C * nm, *wrow = acc + nm * nm;  /* H^T R^-1 H's upper triangle; one row of R^-1 H */
    double *HT = wrow + nm, *qt = HT + nm * C, *quad = qt + C;   /* quad_rows: scratch and H P H^T */
    Py_ssize_t k = k0, fr = fail_run;
    int reason = STOP_END;

    Py_BEGIN_ALLOW_THREADS
    for (; k < k1; k++) {
        const double *y = Y + k * C;
        const int8_t *ev = EV + k * C;
        int stop = 0;
        for (Py_ssize_t c = 0; c < C; c++)
            if (ev[c] != 0) { stop = STOP_EVENT; break; }
        if (!stop)
            for (Py_ssize_t c = 0; c < C; c++)
                if (rebias[c] && !isnan(y[c])) { stop = STOP_REBIAS; break; }
        if (stop) { reason = stop; break; }
        /* time update (none at the grid's first epoch) */
        if (k > 0) {
            predict_x(&A, B, U_in + (k - 1) * nu, (int)nu, x, xp, ni);
            predict_P(&A, Q, P, AP, Pp, ni);
        } else {
            memcpy(xp, x, sizeof(double) * n);
            memcpy(Pp, P, sizeof(double) * nn);
        }
        model_eval(&g, xp, h, Hm, mw);
        int m = 0;
        for (Py_ssize_t c = 0; c < C; c++)
            if (!isnan(y[c]) && !isnan(bias[c])) used[m++] = (int)c;
        /* innovations and the per-channel outlier test: S_ii = H_i Pmm H_i^T + R_i */
        int outlier = 0;
        quad_rows(Pp, ni, Hm, nm, used, m, HT, qt, quad);
        for (int i = 0; i < m; i++) {
            int c = used[i];
            rho[i] = y[c] - h[c] - bias[c];
            double s = quad[i] + r_var[c];
            wr[i] = 1.0 / r_var[c];
            if (fabs(rho[i] / sqrt(s)) > outlier_sigma) { outlier = 1; break; }
        }
        if (outlier) { reason = STOP_OUTLIER; break; }
        double nis_k = NAN;
        Py_ssize_t fr_k = fr;
        double *Pk = Pp, *xk = xp;
        if (m > 0) {
            /* information form: Pn = (Pp^-1 + H^T R^-1 H)^-1, H^T R^-1 H only in the n_m block */
            if (chol_inv(Pp, Yi, cw, ni)) { reason = STOP_CHOLESKY; break; }
            /* Hu: the used rows of H, contiguous */
            for (int i = 0; i < m; i++) memcpy(Hu + i * nm, Hm + used[i] * nm, sizeof(double) * nm);
            double rr = 0.0;
            for (int i = 0; i < m; i++) rr += wr[i] * rho[i] * rho[i];
            /* g = H^T R^-1 rho and H^T R^-1 H, every entry summed over the rows i in order from 0.0;
               the entries' accumulators advance together, row by row (independent chains) */
            for (int a = 0; a < nm; a++) {
                grad[a] = 0.0;
                for (int bb = a; bb < nm; bb++) acc[a * nm + bb] = 0.0;
            }
            for (int i = 0; i < m; i++) {
                const double *Hi = Hu + i * nm;
                const double wrho = wr[i] * rho[i];
                for (int bb = 0; bb < nm; bb++) wrow[bb] = wr[i] * Hi[bb];
                for (int a = 0; a < nm; a++) {
                    const double ha = Hi[a];
                    double *ac = acc + a * nm;
                    grad[a] += ha * wrho;
                    for (int bb = a; bb < nm; bb++) ac[bb] += ha * wrow[bb];
                }
            }
            for (int a = 0; a < nm; a++)
                for (int bb = a; bb < nm; bb++) {
                    double v = acc[a * nm + bb];
                    Yi[a * n + bb] += v;
                    if (bb != a) Yi[bb * n + a] += v;
                }
            if (chol_inv(Yi, Pn, cw, ni)) { reason = STOP_CHOLESKY; break; }
            /* NIS = rho^T S^-1 rho = rho^T R^-1 rho - g^T Pn g (Woodbury), g = H^T R^-1 rho; x = xp + Pn g */
            for (int i = 0; i < ni; i++) xn[i] = 0.0;
            for (int bb = 0; bb < nm; bb++) {
                double gb = grad[bb];
                const double *Pb = Pn + bb * n;           /* column bb of the symmetric Pn */
                for (int i = 0; i < ni; i++) xn[i] += gb * Pb[i];
            }
            double gPg = 0.0;
            for (int a = 0; a < nm; a++) gPg += grad[a] * xn[a];
            nis_k = rr - gPg;
            for (int i = 0; i < ni; i++) xn[i] += xp[i];
            xk = xn;
            Pk = Pn;
            fr_k = (nis_k > chi2[m]) ? fr + 1 : 0;
        }
        if (fr_k >= reinit_after && k > k_reinit_block) { reason = STOP_REINIT; break; }
        /* commit epoch k */
        if (m > 0) {
            double *rk = resid + k * C;
            for (int i = 0; i < m; i++) {
                int c = used[i];
                const double *Hc = Hm + c * nm;
                double t = 0.0;
                for (int a = 0; a < nm; a++) t += Hc[a] * (xk[a] - xp[a]);
                rk[c] = y[c] - (h[c] + t) - bias[c];
            }
            nis[k] = nis_k;
            dof[k] = m;
            /* the residual noise estimate's H P H^T, Jacobian at the filtered state */
            model_eval(&g, xk, hf, Hf, mw);
            double *qk = hph + k * C;
            quad_rows(Pk, ni, Hf, nm, used, m, HT, qt, quad);
            for (int i = 0; i < m; i++) qk[used[i]] = quad[i];
        }
        memcpy(x, xk, sizeof(double) * n);
        memcpy(P, Pk, sizeof(double) * nn);
        memcpy(xs + k * n, x, sizeof(double) * n);
        memcpy(Ps + k * nn, P, sizeof(double) * nn);
        fr = fr_k;
    }
    Py_END_ALLOW_THREADS

    free(used);
    ret = Py_BuildValue("nni", k, fr, reason);
done:
    free(work);
    release_all(b, NB);
    return ret;
}

/*
 * dd_span(gi, gf, A_row, A_col, A_val, Q, L, Z, VAR, S, CHANT, HC, M, STOP, x, P, xs, Ps, nis, nis_dof,
 *         N, n, C, k0, k1, max_iter, outlier_sigma) -> (k_stop, reason)
 *
 * The whitened full-noise path: the iterated EKF of cdgps_cli.estimation.model_filter on rows whose
 * noise is a full covariance C_k = L_k L_k^T (satellite double differences, D Sigma D^T), given per
 * epoch k as the first M[k] of C padded rows: L = L_k (C x C, lower; rows whitened by forward
 * substitution), Z = z, VAR = diag C_k, and the far-field geometry of each row (S: s_j - s_r, CHANT: its antenna, HC: the
 * constant (s_j - s_r)^T d_a), so h = HC - S^T (p_a(q) - p_M(q)).  The update is in information form
 * on the whitened rows, iterated while the step exceeds 1e-9 of the state (max_iter at most); NIS
 * with the prior linearization.  It stops, without touching epoch k's outputs, where STOP[k] != 0
 * (an epoch Python handles: another spacing, a hook) or a row's innovation exceeds outlier_sigma
 * standard deviations (S_ii = H_i P H_i^T + VAR_i).
 */
static PyObject *py_dd_span(PyObject *self, PyObject *args)
{
    enum { NB = 20 };
    PyObject *o[NB];
    Buf b[NB];
    memset(b, 0, sizeof(b));
    Py_ssize_t N, n, C, k0, k1, max_iter;
    double outlier_sigma;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOOOOOOOOnnnnnnd", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5],
                          &o[6], &o[7], &o[8], &o[9], &o[10], &o[11], &o[12], &o[13], &o[14], &o[15], &o[16],
                          &o[17], &o[18], &o[19], &N, &n, &C, &k0, &k1, &max_iter, &outlier_sigma))
        return NULL;
    PyObject *ret = NULL;
    double *work = NULL;
    Geom g;
    Csr A;
    if (get_geom(o[0], o[1], &b[0], &b[1], &g)) goto done;
    if (n < 2 * g.nm || n > 4096 || N < 0 || C < 0 || C > 4096 || k0 < 0 || k1 > N || k0 > k1 || max_iter < 1) {
        PyErr_SetString(PyExc_ValueError, "_ekfcore.dd_span: bad dimensions");
        goto done;
    }
    const Py_ssize_t nn = n * n, NC = N * C;
    if (get_csr(o[2], o[3], o[4], b + 2, (int)n, &A)
        || get_buf(o[5], &b[5], 'd', nn, 0, "Q") || get_buf(o[6], &b[6], 'd', NC * C, 0, "L")
        || get_buf(o[7], &b[7], 'd', NC, 0, "Z")
        || get_buf(o[8], &b[8], 'd', NC, 0, "VAR") || get_buf(o[9], &b[9], 'd', NC * 3, 0, "S")
        || get_buf(o[10], &b[10], 'q', NC, 0, "CHANT") || get_buf(o[11], &b[11], 'd', NC, 0, "HC")
        || get_buf(o[12], &b[12], 'q', N, 0, "M") || get_buf(o[13], &b[13], 'b', N, 0, "STOP")
        || get_buf(o[14], &b[14], 'd', n, 1, "x") || get_buf(o[15], &b[15], 'd', nn, 1, "P")
        || get_buf(o[16], &b[16], 'd', N * n, 1, "xs") || get_buf(o[17], &b[17], 'd', N * nn, 1, "Ps")
        || get_buf(o[18], &b[18], 'd', N, 1, "nis") || get_buf(o[19], &b[19], 'q', N, 1, "nis_dof"))
        goto done;
    const double *Q = b[5].view.buf, *Lall = b[6].view.buf, *Z = b[7].view.buf;
    const double *VAR = b[8].view.buf, *S = b[9].view.buf, *HC = b[11].view.buf;
    const int64_t *CHANT = b[10].view.buf, *M = b[12].view.buf;
    const int8_t *STOP = b[13].view.buf;
    double *x = b[14].view.buf, *P = b[15].view.buf, *xs = b[16].view.buf, *Ps = b[17].view.buf;
    double *nis = b[18].view.buf;
    int64_t *dof = b[19].view.buf;
    for (Py_ssize_t k = 0; k < N; k++)
        for (Py_ssize_t i = 0; i < M[k] && i < C; i++)
            if (!(Lall[(k * C + i) * C + i] > 0.0)) {
                PyErr_SetString(PyExc_ValueError, "_ekfcore.dd_span: L must have a positive diagonal");
                goto done;
            }
    for (Py_ssize_t i = 0; i < NC; i++)
        if (CHANT[i] < 0 || CHANT[i] >= g.na) {
            PyErr_SetString(PyExc_ValueError, "_ekfcore.dd_span: CHANT out of range");
            goto done;
        }
    for (Py_ssize_t k = 0; k < N; k++)
        if (M[k] < 0 || M[k] > C) {
            PyErr_SetString(PyExc_ValueError, "_ekfcore.dd_span: M out of range");
            goto done;
        }
    const int nm = g.nm, ni = (int)n;
    Py_ssize_t wm = model_work_size(&g) + 3 * (Py_ssize_t)g.na * g.nm;   /* model_eval's scratch */
    Py_ssize_t total = wm + 4 * n + 6 * nn + n + 5 * C + 2 * C * nm + nm;
    work = malloc(sizeof(double) * (total + 1));
    if (!work) {
        PyErr_NoMemory();
        goto done;
    }
    double *mw = work;
    double *xp = mw + wm, *xi = xp + n, *xn = xi + n, *dx = xn + n;
    double *Pp = dx + n, *AP = Pp + nn, *Pinv = AP + nn, *Yi = Pinv + nn;
    double *cw = Yi + nn;                                 /* 2 nn + n */
    double *h = cw + 2 * nn + n, *v = h + C, *hw = v + C, *Hm = hw + C, *Hw = Hm + C * nm, *grad = Hw + C * nm;
    double *zw = grad + nm;
    double *Post = malloc(sizeof(double) * (nn + 1));
    if (!Post) {
        PyErr_NoMemory();
        goto done;
    }
    Py_ssize_t k = k0;
    int reason = STOP_END;

    Py_BEGIN_ALLOW_THREADS
    for (; k < k1; k++) {
        if (STOP[k]) { reason = STOP_EVENT; break; }
        if (k > 0) {
            double zero = 0.0;
            predict_x(&A, NULL, &zero, 0, x, xp, ni);
            predict_P(&A, Q, P, AP, Pp, ni);
        } else {
            memcpy(xp, x, sizeof(double) * n);
            memcpy(Pp, P, sizeof(double) * nn);
        }
        const int m = (int)M[k];
        double nis_k = NAN;
        double *xk = xp, *Pk = Pp;
        if (m > 0) {
            Geom gk = g;
            gk.nc = m;
            gk.ch_ant = CHANT + k * C;
            gk.tpos = S + k * C * 3;
            gk.far = 1;
            const double *L = Lall + k * C * C, *z = Z + k * C, *var = VAR + k * C, *hc = HC + k * C;
            for (int i = 0; i < m; i++) {                 /* zw = L^-1 z (forward substitution) */
                const double *Li = L + i * C;
                double t = z[i];
                for (int j = 0; j < i; j++) t -= Li[j] * zw[j];
                zw[i] = t / Li[i];
            }
            if (chol_inv(Pp, Pinv, cw, ni)) { reason = STOP_CHOLESKY; break; }
            memcpy(xi, xp, sizeof(double) * n);
            int outlier = 0, fail = 0;
            for (Py_ssize_t it = 0; it < max_iter; it++) {
                model_eval(&gk, xi, h, Hm, mw);
                for (int i = 0; i < m; i++) h[i] += hc[i];
                if (it == 0) {
                    for (int i = 0; i < m; i++) {
                        const double *Hc = Hm + i * nm;
                        double s = quad_nm(Pp, (int)n, Hc, nm) + var[i];
                        if (fabs((z[i] - h[i]) / sqrt(s)) > outlier_sigma) { outlier = 1; break; }
                    }
                    if (outlier) break;
                }
                for (int a = 0; a < nm; a++) dx[a] = xp[a] - xi[a];
                for (int i = 0; i < m; i++) {             /* hw = L^-1 h, Hw = L^-1 Hm */
                    const double *Li = L + i * C;
                    double sh = h[i], il = 1.0 / Li[i];
                    double *Hwi = Hw + i * nm;
                    for (int a = 0; a < nm; a++) Hwi[a] = Hm[i * nm + a];
                    for (int j = 0; j < i; j++) {
                        double l = Li[j];
                        if (l == 0.0) continue;
                        sh -= l * hw[j];
                        const double *Hj = Hw + j * nm;
                        for (int a = 0; a < nm; a++) Hwi[a] -= l * Hj[a];
                    }
                    sh *= il;
                    for (int a = 0; a < nm; a++) Hwi[a] *= il;
                    hw[i] = sh;
                    double t = 0.0;
                    for (int a = 0; a < nm; a++) t += Hwi[a] * dx[a];
                    v[i] = zw[i] - sh - t;
                }
                memcpy(Yi, Pinv, sizeof(double) * nn);
                double vv = 0.0;
                for (int i = 0; i < m; i++) vv += v[i] * v[i];
                for (int a = 0; a < nm; a++) {
                    double ga = 0.0;
                    for (int i = 0; i < m; i++) ga += Hw[i * nm + a] * v[i];
                    grad[a] = ga;
                    for (int bb = a; bb < nm; bb++) {
                        double s = 0.0;
                        for (int i = 0; i < m; i++) s += Hw[i * nm + a] * Hw[i * nm + bb];
                        Yi[a * n + bb] += s;
                        if (bb != a) Yi[bb * n + a] += s;
                    }
                }
                if (chol_inv(Yi, Post, cw, ni)) { fail = 1; break; }
                for (int i = 0; i < ni; i++) {
                    double s = 0.0;
                    const double *Pi = Post + i * n;
                    for (int a = 0; a < nm; a++) s += Pi[a] * grad[a];
                    xn[i] = xp[i] + s;
                }
                if (it == 0) {
                    double gPg = 0.0;
                    for (int a = 0; a < nm; a++) gPg += grad[a] * (xn[a] - xp[a]);
                    nis_k = vv - gPg;
                }
                double step = 0.0, big = 1.0;
                for (int i = 0; i < ni; i++) {
                    double d = fabs(xn[i] - xi[i]);
                    if (d > step) step = d;
                }
                memcpy(xi, xn, sizeof(double) * n);
                for (int i = 0; i < ni; i++)
                    if (fabs(xi[i]) > big) big = fabs(xi[i]);
                if (step <= 1e-9 * big) break;
            }
            if (outlier) { reason = STOP_OUTLIER; break; }
            if (fail) { reason = STOP_CHOLESKY; break; }
            xk = xi;
            Pk = Post;
        }
        if (m > 0) {
            nis[k] = nis_k;
            dof[k] = m;
        }
        memcpy(x, xk, sizeof(double) * n);
        memcpy(P, Pk, sizeof(double) * nn);
        memcpy(xs + k * n, x, sizeof(double) * n);
        memcpy(Ps + k * nn, P, sizeof(double) * nn);
    }
    Py_END_ALLOW_THREADS

    free(Post);
    ret = Py_BuildValue("ni", k, reason);
done:
    free(work);
    release_all(b, NB);
    return ret;
}

/*
 * C = C0 + op(A) B for p x p row-major matrices, op(A) = A (trans = 0) or A^T (trans = 1); C0 may be
 * NULL (zero).  Register-blocked in 2 x 4 tiles (the p = 18 matrices of the testbed are too small
 * for anything cleverer, too large for naive row updates to run at full speed).
 */
static void gemm_small(int p, int trans, const double *restrict A, const double *restrict B,
                       const double *restrict C0, double *restrict C)
{
#define AEL(i, q) (trans ? A[(q) * p + (i)] : A[(i) * p + (q)])
    int i = 0;
    for (; i + 1 < p; i += 2) {
        int j = 0;
        for (; j + 3 < p; j += 4) {
            double c00 = 0, c01 = 0, c02 = 0, c03 = 0, c10 = 0, c11 = 0, c12 = 0, c13 = 0;
            for (int q = 0; q < p; q++) {
                const double *b = B + q * p + j;
                double a0 = AEL(i, q), a1 = AEL(i + 1, q);
                c00 += a0 * b[0]; c01 += a0 * b[1]; c02 += a0 * b[2]; c03 += a0 * b[3];
                c10 += a1 * b[0]; c11 += a1 * b[1]; c12 += a1 * b[2]; c13 += a1 * b[3];
            }
            double *r0 = C + i * p + j, *r1 = r0 + p;
            if (C0) {
                const double *s0 = C0 + i * p + j, *s1 = s0 + p;
                r0[0] = s0[0] + c00; r0[1] = s0[1] + c01; r0[2] = s0[2] + c02; r0[3] = s0[3] + c03;
                r1[0] = s1[0] + c10; r1[1] = s1[1] + c11; r1[2] = s1[2] + c12; r1[3] = s1[3] + c13;
            } else {
                r0[0] = c00; r0[1] = c01; r0[2] = c02; r0[3] = c03;
                r1[0] = c10; r1[1] = c11; r1[2] = c12; r1[3] = c13;
            }
        }
        for (; j < p; j++) {
            double c0 = 0, c1 = 0;
            for (int q = 0; q < p; q++) {
                double b = B[q * p + j];
                c0 += AEL(i, q) * b;
                c1 += AEL(i + 1, q) * b;
            }
            C[i * p + j] = (C0 ? C0[i * p + j] : 0.0) + c0;
            C[(i + 1) * p + j] = (C0 ? C0[(i + 1) * p + j] : 0.0) + c1;
        }
    }
    for (; i < p; i++)
        for (int j = 0; j < p; j++) {
            double c = 0;
            for (int q = 0; q < p; q++) c += AEL(i, q) * B[q * p + j];
            C[i * p + j] = (C0 ? C0[i * p + j] : 0.0) + c;
        }
#undef AEL
}

/*
 * One RTS step: from the filtered xk, Pk of epoch k, their prediction xp, Pp (= A Pk A^T + Q) and
 * AP = A Pk, and the smoothed xn, Pn of epoch k+1, write the smoothed xo, Po of epoch k:
 *   G = Pk A^T Pp^-1,  xo = xk + G (xn - xp),  Po = Pk + G (Pn - Pp) G^T  (symmetrized, as in numpy).
 * Pp is overwritten; R, X, T: p^2 scratch each.  Returns -1 when Pp is not positive definite.
 */
static int rts_epoch(int p, const double *restrict xk, const double *restrict Pk, const double *restrict xp,
                     const double *restrict AP, double *restrict Pp, const double *restrict xn,
                     const double *restrict Pn, double *restrict xo, double *restrict Po,
                     double *restrict R, double *restrict X, double *restrict T)
{
    if (cholesky_upper(Pp, R, p)) return -1;
    /* X = Pp^-1 AP = G^T with Pp = R^T R: R^T Z = AP (forward), R X = Z (backward), row-wise in X */
    for (int i = 0; i < p; i++) {
        double *Xi = X + i * p;
        memcpy(Xi, AP + i * p, sizeof(double) * p);
        for (int q = 0; q < i; q++) {
            double r = R[q * p + i];
            const double *Xq = X + q * p;
            for (int j = 0; j < p; j++) Xi[j] -= r * Xq[j];
        }
        double inv = 1.0 / R[i * p + i];
        for (int j = 0; j < p; j++) Xi[j] *= inv;
    }
    for (int i = p - 1; i >= 0; i--) {
        double *Xi = X + i * p;
        const double *Ri = R + i * p;
        for (int q = i + 1; q < p; q++) {
            double r = Ri[q];
            const double *Xq = X + q * p;
            for (int j = 0; j < p; j++) Xi[j] -= r * Xq[j];
        }
        double inv = 1.0 / Ri[i];
        for (int j = 0; j < p; j++) Xi[j] *= inv;
    }
    /* xo = xk + X^T (xn - xp) */
    for (int i = 0; i < p; i++) xo[i] = 0.0;
    for (int j = 0; j < p; j++) {
        double d = xn[j] - xp[j];
        const double *Xj = X + j * p;
        for (int i = 0; i < p; i++) xo[i] += d * Xj[i];
    }
    for (int i = 0; i < p; i++) xo[i] += xk[i];
    /* D = Pn - Pp (into Pp);  T = D X;  Po = Pk + X^T T, symmetrized as 0.5 (Po + Po^T) */
    for (int z = 0; z < p * p; z++) Pp[z] = Pn[z] - Pp[z];
    gemm_small(p, 0, Pp, X, NULL, T);
    gemm_small(p, 1, X, T, Pk, Po);
    for (int i = 0; i < p; i++)
        for (int l = i + 1; l < p; l++) {
            double v = 0.5 * (Po[i * p + l] + Po[l * p + i]);
            Po[i * p + l] = v;
            Po[l * p + i] = v;
        }
    return 0;
}

/*
 * rts(A_row, A_col, A_val, Q, B, U_in, xf, Pf, xs, Ps, eq_k, eq_i, eq_q, no_link, N, p, nu) -> int
 *   Smoothed states into xs, Ps (which may be xf, Pf themselves).  eq_*: extra process noise
 *   (epoch, index, variance) sorted by epoch; no_link: N bytes or empty.  Returns -1, or the epoch
 *   whose predicted covariance is not positive definite.
 */
static PyObject *py_rts(PyObject *self, PyObject *args)
{
    enum { NB = 14 };
    PyObject *o[NB];
    Buf b[NB];
    memset(b, 0, sizeof(b));
    Py_ssize_t N, p, nu;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOOnnn", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7],
                          &o[8], &o[9], &o[10], &o[11], &o[12], &o[13], &N, &p, &nu))
        return NULL;
    PyObject *ret = NULL;
    double *work = NULL;
    Csr A;
    if (N < 0 || p < 1 || p > 4096 || nu < 0) {
        PyErr_SetString(PyExc_ValueError, "_ekfcore.rts: bad dimensions");
        return NULL;
    }
    const Py_ssize_t pp = p * p;
    Py_ssize_t ne = 0;
    {
        Py_buffer v;
        if (PyObject_GetBuffer(o[10], &v, PyBUF_SIMPLE) != 0) return NULL;
        ne = v.len / 8;
        PyBuffer_Release(&v);
        if (PyObject_GetBuffer(o[13], &v, PyBUF_SIMPLE) != 0) return NULL;
        Py_ssize_t nl = v.len;
        PyBuffer_Release(&v);
        if (nl != 0 && nl != N) {
            PyErr_SetString(PyExc_ValueError, "_ekfcore.rts: no_link: expected N or 0 bytes");
            return NULL;
        }
        if (get_buf(o[13], &b[13], 'b', nl, 0, "no_link")) goto done;
    }
    if (get_csr(o[0], o[1], o[2], b, (int)p, &A)
        || get_buf(o[3], &b[3], 'd', pp, 0, "Q") || get_buf(o[4], &b[4], 'd', p * nu, 0, "B")
        || get_buf(o[5], &b[5], 'd', N * nu, 0, "U_in")
        || get_buf(o[6], &b[6], 'd', N * p, 0, "xf") || get_buf(o[7], &b[7], 'd', N * pp, 0, "Pf")
        || get_buf(o[8], &b[8], 'd', N * p, 1, "xs") || get_buf(o[9], &b[9], 'd', N * pp, 1, "Ps")
        || get_buf(o[10], &b[10], 'q', ne, 0, "eq_k") || get_buf(o[11], &b[11], 'q', ne, 0, "eq_i")
        || get_buf(o[12], &b[12], 'd', ne, 0, "eq_q"))
        goto done;
    const double *Q = b[3].view.buf, *B = b[4].view.buf, *U_in = b[5].view.buf;
    const double *xf = b[6].view.buf, *Pf = b[7].view.buf;
    double *xs = b[8].view.buf, *Ps = b[9].view.buf;
    const int64_t *eqk = b[10].view.buf, *eqi = b[11].view.buf;
    const double *eqq = b[12].view.buf;
    const uint8_t *nolink = b[13].view.len ? b[13].view.buf : NULL;
    for (Py_ssize_t e = 0; e < ne; e++)
        if (eqi[e] < 0 || eqi[e] >= p || (e > 0 && eqk[e] < eqk[e - 1])) {
            PyErr_SetString(PyExc_ValueError, "_ekfcore.rts: bad extra process noise list");
            goto done;
        }
    work = malloc(sizeof(double) * (2 * p + 6 * pp + 1));
    if (!work) {
        PyErr_NoMemory();
        goto done;
    }
    double *xk = work, *xp = xk + p, *Pk = xp + p, *AP = Pk + pp, *Pp = AP + pp, *L = Pp + pp, *X = L + pp,
           *T = X + pp;
    const int pi = (int)p;
    Py_ssize_t fail = -1;
    Py_BEGIN_ALLOW_THREADS
    Py_ssize_t e = ne - 1;
    for (Py_ssize_t k = N - 2; k >= 0; k--) {
        if (nolink && nolink[k]) continue;
        memcpy(xk, xf + k * p, sizeof(double) * p);
        memcpy(Pk, Pf + k * pp, sizeof(double) * pp);
        predict_x(&A, B, U_in + k * nu, (int)nu, xk, xp, pi);
        predict_P(&A, Q, Pk, AP, Pp, pi);
        while (e >= 0 && eqk[e] > k + 1) e--;
        for (Py_ssize_t f = e; f >= 0 && eqk[f] == k + 1; f--) Pp[eqi[f] * p + eqi[f]] += eqq[f];
        if (rts_epoch(pi, xk, Pk, xp, AP, Pp, xs + (k + 1) * p, Ps + (k + 1) * pp, xs + k * p, Ps + k * pp, L, X, T)) {
            fail = k;
            break;
        }
    }
    Py_END_ALLOW_THREADS
    ret = PyLong_FromSsize_t(fail);
done:
    free(work);
    release_all(b, NB);
    return ret;
}

/* ------------------------------------------------------------------------------------------ */
/* batch initialization (cdgps_cli.estimation.initializer / batch_solver) */

/*
 * phase_model_batch(gi, gf, X, h, Hm, N, nx, jac) -> None
 *   h (N, nc) and, when jac, Hm (N, nc, nm) of the N states X (N, nx), x_k = X[k, :2 nm] (nx >= 2 nm).
 */
static PyObject *py_phase_model_batch(PyObject *self, PyObject *args)
{
    PyObject *o[5];
    Buf b[5];
    memset(b, 0, sizeof(b));
    Py_ssize_t N, nx;
    int jac;
    if (!PyArg_ParseTuple(args, "OOOOOnnp", &o[0], &o[1], &o[2], &o[3], &o[4], &N, &nx, &jac)) return NULL;
    PyObject *ret = NULL;
    double *work = NULL;
    Geom g;
    if (get_geom(o[0], o[1], &b[0], &b[1], &g)) goto done;
    if (N < 0 || nx < 2 * g.nm) {
        PyErr_SetString(PyExc_ValueError, "_ekfcore.phase_model_batch: bad dimensions");
        goto done;
    }
    if (get_buf(o[2], &b[2], 'd', N * nx, 0, "X") || get_buf(o[3], &b[3], 'd', N * g.nc, 1, "h")
        || get_buf(o[4], &b[4], 'd', jac ? N * g.nc * g.nm : 0, 1, "Hm"))
        goto done;
    work = malloc(sizeof(double) * (model_work_size(&g) + 1));
    if (!work) {
        PyErr_NoMemory();
        goto done;
    }
    const double *X = b[2].view.buf;
    double *h = b[3].view.buf, *Hm = b[4].view.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t k = 0; k < N; k++)
        model_eval_opt(&g, X + k * nx, h + k * g.nc, jac ? Hm + k * g.nc * g.nm : NULL, work, jac);
    Py_END_ALLOW_THREADS
    ret = Py_NewRef(Py_None);
done:
    free(work);
    release_all(b, 5);
    return ret;
}

/*
 * Householder reflection (LAPACK dlarfg's convention) of rows j0 .. rows-1 of the row-major
 * B (ld columns) that zeroes column col below row j0, applied to the columns col+1 .. ld-1:
 * H = I - tau v v^T, v = [1; B[j0+1:, col] / (alpha - beta)], beta = -sign(alpha) |B[j0:, col]|.
 * Column col is left as [beta; 0 ...] (nothing changes when it is zero below j0).
 * wv: ld scratch.  Rows whose entry in column col is zero are skipped (v_i = 0).
 */
/*
 * The loops below are element-wise (no reductions reordered, no fused multiply-add: -std=c99 turns
 * contraction off, and the avx2 target has no FMA), so the AVX2 clone that GCC selects at load time on
 * CPUs that have it returns the same bits as the default (SSE2) build, about 25 % faster.
 */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__) && !defined(CDGPS_NO_SIMD_CLONES)
#define SIMD_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define SIMD_CLONES
#endif

SIMD_CLONES
static void householder_step(double *restrict B, int ld, int j0, int rows, int col, double *restrict wv)
{
    double xn2 = 0.0;
    for (int i = j0 + 1; i < rows; i++) xn2 += B[(Py_ssize_t)i * ld + col] * B[(Py_ssize_t)i * ld + col];
    if (xn2 == 0.0) return;
    double alpha = B[(Py_ssize_t)j0 * ld + col];
    double beta = -copysign(sqrt(alpha * alpha + xn2), alpha);
    double scale = 1.0 / (alpha - beta), tau = (beta - alpha) / beta;
    const int c0 = col + 1, len = ld - c0;
    double *Bj = B + (Py_ssize_t)j0 * ld + c0;
    for (int c = 0; c < len; c++) wv[c] = Bj[c];
    for (int i = j0 + 1; i < rows; i++) {
        double *vi = B + (Py_ssize_t)i * ld + col;
        if (*vi == 0.0) continue;
        *vi *= scale;
        const double v = *vi, *Bi = vi + 1;
        for (int c = 0; c < len; c++) wv[c] += v * Bi[c];
    }
    for (int c = 0; c < len; c++) Bj[c] -= tau * wv[c];
    for (int i = j0 + 1; i < rows; i++) {
        double *vi = B + (Py_ssize_t)i * ld + col;
        if (*vi == 0.0) continue;
        const double v = tau * *vi;
        double *Bi = vi + 1;
        for (int c = 0; c < len; c++) Bi[c] -= v * wv[c];
        *vi = 0.0;
    }
    B[(Py_ssize_t)j0 * ld + col] = beta;
}

/* sum_i a_i b_i, four partial sums (a fixed order: the same bits in every build) */
static inline double dot4(const double *restrict a, const double *restrict b, int len)
{
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    int i = 0;
    for (; i + 3 < len; i += 4) {
        s0 += a[i] * b[i];
        s1 += a[i + 1] * b[i + 1];
        s2 += a[i + 2] * b[i + 2];
        s3 += a[i + 3] * b[i + 3];
    }
    for (; i < len; i++) s0 += a[i] * b[i];
    return (s0 + s1) + (s2 + s3);
}

/* y[j..] -= tau v v^T y[j..] for the reflector v = [1; v[j+1..]] (entries j .. rows-1) */
static inline void reflect(const double *restrict v, double *restrict y, int j, int rows, double tau)
{
    const double f = tau * (y[j] + dot4(v + j + 1, y + j + 1, rows - j - 1));
    y[j] -= f;
    for (int i = j + 1; i < rows; i++) y[i] -= f * v[i];
}

/*
 * Householder QR (dlarfg's convention) of the rows x q matrix whose columns are the rows of At
 * (q x rows, row-major: each column contiguous), rows >= q.  On return At[j][j..] = [R_jj; v_j[1:]]
 * and At[c][j] = R_jc for j < c (R's column c in the first entries of At's row c); tau (q).
 */
SIMD_CLONES
static void qr_columns(double *restrict At, int q, int rows, double *restrict tau)
{
    for (int j = 0; j < q; j++) {
        double *x = At + j * rows;
        const int len = rows - j - 1;
        double xn2 = dot4(x + j + 1, x + j + 1, len);
        tau[j] = 0.0;
        if (xn2 == 0.0) continue;
        const double alpha = x[j], beta = -copysign(sqrt(alpha * alpha + xn2), alpha);
        const double scale = 1.0 / (alpha - beta);
        tau[j] = (beta - alpha) / beta;
        for (int i = j + 1; i < rows; i++) x[i] *= scale;
        x[j] = beta;
        for (int c = j + 1; c < q; c++) reflect(x, At + c * rows, j, rows, tau[j]);
    }
}

/*
 * The first nq columns of Q = H_0 ... H_{q-1} (rows x rows) from qr_columns' reflectors, as the rows
 * of Qt (nq x rows, row-major), q <= nq <= rows (dorg2r's backward accumulation: H_j touches the
 * entries j.. of the columns j..).
 */
SIMD_CLONES
static void q_columns(const double *restrict At, const double *restrict tau, int q, int rows, double *restrict Qt, int nq)
{
    memset(Qt, 0, sizeof(double) * nq * rows);
    for (int c = 0; c < nq; c++) Qt[c * rows + c] = 1.0;
    for (int j = q - 1; j >= 0; j--) {
        if (tau[j] == 0.0) continue;
        for (int c = j; c < nq; c++) reflect(At + j * rows, Qt + c * rows, j, rows, tau[j]);
    }
}

/*
 * reduce_rows(H, J, present, ys, bi, meas, other, N, C, n, q, m, K, r, ncol, s, full) -> None
 *   batch_solver._reduced_rows per epoch k: the QR H[k][:, J] = Q R (C x q, C > q; rows of absent
 *   channels zero) and Q^T [E_k | y_k], with E_k[c, bi[k, c]] = s (no entry where bi < 0) and y_k = ys[k]
 *   (C x K, zero where absent).  Writes the filter's rows into meas[k] (q x ncol): s R in the columns
 *   r + J, the first q rows of Q^T [E_k | y_k] in the columns ncol - m - K ..; other columns untouched.
 *   With full, the other C - q rows of Q^T [E_k | y_k] (biases only) into other[k] ((C - q) x (m + K)).
 *   H (N, C, n), J (q) int64, present (N, C) bytes, ys (N, C, K), bi (N, C) int64, all row-major.
 */
static PyObject *py_reduce_rows(PyObject *self, PyObject *args)
{
    enum { NB = 7 };
    PyObject *o[NB];
    Buf b[NB];
    memset(b, 0, sizeof(b));
    Py_ssize_t N, C, n, q, m, K, r, ncol;
    double s;
    int full;
    if (!PyArg_ParseTuple(args, "OOOOOOOnnnnnnnndp", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &N, &C, &n, &q,
                          &m, &K, &r, &ncol, &s, &full))
        return NULL;
    PyObject *ret = NULL;
    double *work = NULL;
    if (N < 0 || n < 1 || q < 1 || C <= q || C > 100000 || m < 0 || K < 1 || r < 0 || ncol != r + n + m + K
        || ncol > 10000000) {
        PyErr_SetString(PyExc_ValueError, "_ekfcore.reduce_rows: bad dimensions");
        return NULL;
    }
    const Py_ssize_t ne = m + K, nq = full ? C : q;
    if (get_buf(o[0], &b[0], 'd', N * C * n, 0, "H") || get_buf(o[1], &b[1], 'q', q, 0, "J")
        || get_buf(o[2], &b[2], 'b', N * C, 0, "present") || get_buf(o[3], &b[3], 'd', N * C * K, 0, "ys")
        || get_buf(o[4], &b[4], 'q', N * C, 0, "bi") || get_buf(o[5], &b[5], 'd', N * q * ncol, 1, "meas")
        || get_buf(o[6], &b[6], 'd', full ? N * (C - q) * ne : 0, 1, "other"))
        goto done;
    const int64_t *J = b[1].view.buf, *bi = b[4].view.buf;
    for (Py_ssize_t j = 0; j < q; j++)
        if (J[j] < 0 || J[j] >= n) {
            PyErr_SetString(PyExc_ValueError, "_ekfcore.reduce_rows: column index out of range");
            goto done;
        }
    for (Py_ssize_t i = 0; i < N * C; i++)
        if (bi[i] < -1 || bi[i] >= m) {
            PyErr_SetString(PyExc_ValueError, "_ekfcore.reduce_rows: bias index out of range");
            goto done;
        }
    work = malloc(sizeof(double) * (C * q + q + C * nq + nq * ne + 1));
    if (!work) {
        PyErr_NoMemory();
        goto done;
    }
    double *At = work, *tau = At + C * q, *Qt = tau + q, *EY = Qt + C * nq;
    const double *H = b[0].view.buf, *ys = b[3].view.buf;
    const uint8_t *present = b[2].view.buf;
    double *meas = b[5].view.buf, *other = b[6].view.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t k = 0; k < N; k++) {
        const uint8_t *pk = present + k * C;
        for (Py_ssize_t c = 0; c < C; c++)
            for (Py_ssize_t j = 0; j < q; j++) At[j * C + c] = pk[c] ? H[(k * C + c) * n + J[j]] : 0.0;
        qr_columns(At, (int)q, (int)C, tau);
        q_columns(At, tau, (int)q, (int)C, Qt, (int)nq);
        memset(EY, 0, sizeof(double) * nq * ne);
        const double *yk = ys + k * C * K;
        const int64_t *bk = bi + k * C;
        for (Py_ssize_t j = 0; j < nq; j++) {                 /* row j of Q^T [E | y] */
            const double *Qj = Qt + j * C;
            double *Ej = EY + j * ne;
            for (Py_ssize_t c = 0; c < C; c++) {
                if (bk[c] >= 0) Ej[bk[c]] += s * Qj[c];
                for (Py_ssize_t l = 0; l < K; l++) Ej[m + l] += Qj[c] * yk[c * K + l];
            }
        }
        double *Mk = meas + k * q * ncol;
        for (Py_ssize_t i = 0; i < q; i++) {
            for (Py_ssize_t j = 0; j < q; j++) Mk[i * ncol + r + J[j]] = j >= i ? s * At[j * C + i] : 0.0;
            memcpy(Mk + i * ncol + ncol - ne, EY + i * ne, sizeof(double) * ne);
        }
        if (full) memcpy(other + k * (C - q) * ne, EY + q * ne, sizeof(double) * (C - q) * ne);
    }
    Py_END_ALLOW_THREADS
    ret = Py_NewRef(Py_None);
done:
    free(work);
    release_all(b, NB);
    return ret;
}

/* the time update of srif_forward: X[:, :w] = triu(X[:, r:w]) AG (X: n rows of ld columns; T: n x n scratch) */
SIMD_CLONES
static void srif_time_update(double *restrict X, int ld, int r, int n, const double *restrict AG, double *restrict T)
{
    const int w = r + n;
    for (int i = 0; i < n; i++)
        for (int l = 0; l < n; l++) T[i * n + l] = l >= i ? X[i * ld + r + l] : 0.0;
    for (int i = 0; i < n; i++) {
        double *xi = X + i * ld;
        for (int c = 0; c < w; c++) xi[c] = 0.0;
        for (int l = i; l < n; l++) {
            const double t = T[i * n + l], *ag = AG + l * w;
            for (int c = 0; c < w; c++) xi[c] += t * ag[c];
        }
    }
}

/*
 * srif_forward(AG, X, meas, smooth, left, N, r, n, q, ncol) -> None
 *   The epoch loop of batch_solver._forward (square-root information filter of the batch problem),
 *   columns [omega (r) | x (n) | biases and right-hand sides (ncol - r - n)], w = r + n:
 *   for k = 1 .. N-1 the QR of
 *       [ I_r                    0                    0        ]   prior on omega_{k-1}
 *       [ triu(X[:, r:w]) AG     (replaces X[:, :w])  X[:, w:] ]   information of x_{k-1}
 *       [ meas[k]  (zero in the omega columns)                  ]   measurements of epoch k
 *   triangularized in its first w columns only: the first r rows go to smooth[k-1] (r, ncol), the
 *   next n rows are the new X, the last q rows' columns w: (biases only) go to left[k-1] (q, ncol-w).
 *   X (n, ncol) is updated in place (in: after epoch 0, out: after epoch N-1, zero below the
 *   diagonal of its x block and in its omega block).  All arrays row-major.
 */
static PyObject *py_srif_forward(PyObject *self, PyObject *args)
{
    PyObject *o[5];
    Buf b[5];
    memset(b, 0, sizeof(b));
    Py_ssize_t N, r, n, q, ncol;
    if (!PyArg_ParseTuple(args, "OOOOOnnnnn", &o[0], &o[1], &o[2], &o[3], &o[4], &N, &r, &n, &q, &ncol)) return NULL;
    PyObject *ret = NULL;
    double *work = NULL;
    if (N < 1 || r < 0 || n < 1 || q < 0 || ncol < r + n || ncol > 1000000 || r + n + q > 1000000) {
        PyErr_SetString(PyExc_ValueError, "_ekfcore.srif_forward: bad dimensions");
        return NULL;
    }
    const Py_ssize_t w = r + n, nb = ncol - w;
    if (get_buf(o[0], &b[0], 'd', n * w, 0, "AG") || get_buf(o[1], &b[1], 'd', n * ncol, 1, "X")
        || get_buf(o[2], &b[2], 'd', N * q * ncol, 0, "meas")
        || get_buf(o[3], &b[3], 'd', (N - 1) * r * ncol, 1, "smooth")
        || get_buf(o[4], &b[4], 'd', (N - 1) * q * nb, 1, "left"))
        goto done;
    /* B: one scratch row (the omega prior row being eliminated), then n rows of X, then q of meas */
    const Py_ssize_t rows = 1 + n + q;
    work = malloc(sizeof(double) * (rows * ncol + n * n + ncol + 1));
    if (!work) {
        PyErr_NoMemory();
        goto done;
    }
    double *B = work, *T = B + rows * ncol, *wv = T + n * n;
    const double *AG = b[0].view.buf, *meas = b[2].view.buf;
    double *X = b[1].view.buf, *smooth = b[3].view.buf, *left = b[4].view.buf;
    Py_BEGIN_ALLOW_THREADS
    double *Bx = B + ncol;
    memcpy(Bx, X, sizeof(double) * n * ncol);
    for (Py_ssize_t k = 1; k < N; k++) {
        srif_time_update(Bx, (int)ncol, (int)r, (int)n, AG, T);
        memcpy(Bx + n * ncol, meas + k * q * ncol, sizeof(double) * q * ncol);
        /* omega columns: the prior row e_j (zero in the measurement rows, which stay zero there) */
        for (int j = 0; j < r; j++) {
            memset(B, 0, sizeof(double) * ncol);
            B[j] = 1.0;
            householder_step(B, (int)ncol, 0, (int)(1 + n), j, wv);
            memcpy(smooth + ((k - 1) * r + j) * ncol, B, sizeof(double) * ncol);
        }
        /* x columns: rows of X from the diagonal, and the measurement rows */
        for (int j = 0; j < n; j++)
            householder_step(Bx, (int)ncol, j, (int)(n + q), (int)(r + j), wv);
        for (Py_ssize_t i = 0; i < q; i++)
            memcpy(left + ((k - 1) * q + i) * nb, Bx + (n + i) * ncol + w, sizeof(double) * nb);
    }
    for (Py_ssize_t i = 0; i < n; i++)                  /* the x block's strict lower triangle */
        for (Py_ssize_t c = 0; c < r + i; c++) Bx[i * ncol + c] = 0.0;
    memcpy(X, Bx, sizeof(double) * n * ncol);
    Py_END_ALLOW_THREADS
    ret = Py_NewRef(Py_None);
done:
    free(work);
    release_all(b, 5);
    return ret;
}

/*
 * srif_smooth(smooth, AG, z, xs, ws, N, r, n, m, K) -> None
 *   The Dyer-McReynolds smoother of batch_solver._smooth, backwards from z = [x_N; b] (n + m, K):
 *   with the omega rows [R_w | R_wx | R_wb | d_w] of update k (smooth[k-1], r x (r+n+m+K), R_w upper
 *   triangular), omega_{k-1} = R_w^-1 (d_w - R_wx x_k - R_wb b) and x_{k-1} = AG [omega_{k-1}; x_k].
 *   xs (N, n, K) and ws (N-1, r, K) written; all arrays row-major.
 */
static PyObject *py_srif_smooth(PyObject *self, PyObject *args)
{
    PyObject *o[5];
    Buf b[5];
    memset(b, 0, sizeof(b));
    Py_ssize_t N, r, n, m, K;
    if (!PyArg_ParseTuple(args, "OOOOOnnnnn", &o[0], &o[1], &o[2], &o[3], &o[4], &N, &r, &n, &m, &K)) return NULL;
    PyObject *ret = NULL;
    double *work = NULL;
    if (N < 1 || r < 0 || n < 1 || m < 0 || K < 1 || r + n + m + K > 10000000) {
        PyErr_SetString(PyExc_ValueError, "_ekfcore.srif_smooth: bad dimensions");
        return NULL;
    }
    const Py_ssize_t w = r + n, ncol = w + m + K;
    if (get_buf(o[0], &b[0], 'd', (N - 1) * r * ncol, 0, "smooth") || get_buf(o[1], &b[1], 'd', n * w, 0, "AG")
        || get_buf(o[2], &b[2], 'd', (n + m) * K, 0, "z") || get_buf(o[3], &b[3], 'd', N * n * K, 1, "xs")
        || get_buf(o[4], &b[4], 'd', (N - 1) * r * K, 1, "ws"))
        goto done;
    work = malloc(sizeof(double) * (r * K + 1));
    if (!work) {
        PyErr_NoMemory();
        goto done;
    }
    const double *S = b[0].view.buf, *AG = b[1].view.buf, *z = b[2].view.buf;
    double *xs = b[3].view.buf, *ws = b[4].view.buf, *rhs = work;
    Py_BEGIN_ALLOW_THREADS
    memcpy(xs + (N - 1) * n * K, z, sizeof(double) * n * K);
    const double *bz = z + n * K;
    for (Py_ssize_t k = N - 1; k >= 1; k--) {
        const double *Sk = S + (k - 1) * r * ncol, *xn = xs + k * n * K;
        double *xo = xs + (k - 1) * n * K, *wo = ws + (k - 1) * r * K;
        for (Py_ssize_t i = 0; i < r; i++) {             /* d_w - R_wx x_k - R_wb b */
            const double *Si = Sk + i * ncol;
            for (Py_ssize_t l = 0; l < K; l++) {
                double v = Si[w + m + l];
                for (Py_ssize_t j = 0; j < n; j++) v -= Si[r + j] * xn[j * K + l];
                for (Py_ssize_t j = 0; j < m; j++) v -= Si[w + j] * bz[j * K + l];
                rhs[i * K + l] = v;
            }
        }
        for (Py_ssize_t i = r - 1; i >= 0; i--) {         /* R_w omega = rhs (back substitution) */
            const double *Si = Sk + i * ncol;
            for (Py_ssize_t l = 0; l < K; l++) {
                double v = rhs[i * K + l];
                for (Py_ssize_t j = i + 1; j < r; j++) v -= Si[j] * wo[j * K + l];
                wo[i * K + l] = v / Si[i];
            }
        }
        for (Py_ssize_t i = 0; i < n; i++) {             /* x_{k-1} = AG [omega; x_k] */
            const double *Ai = AG + i * w;
            for (Py_ssize_t l = 0; l < K; l++) {
                double v = 0.0;
                for (Py_ssize_t j = 0; j < r; j++) v += Ai[j] * wo[j * K + l];
                for (Py_ssize_t j = 0; j < n; j++) v += Ai[r + j] * xn[j * K + l];
                xo[i * K + l] = v;
            }
        }
    }
    Py_END_ALLOW_THREADS
    ret = Py_NewRef(Py_None);
done:
    free(work);
    release_all(b, 5);
    return ret;
}

/* ------------------------------------------------------------------------------------------ */
/* INIT's window smoother (cdgps_cli/estimation/window_smoother.py): the information filter from zero
   information and its Rauch-Tung-Striebel pass written with the prior information only.  The numpy
   twins are window_smoother._forward_numpy / _backward_numpy (same formulas; sums in another order). */

/* C = A B for A (m x q), B (q x n), row-major, plain loops (the r-column products of the window) */
static void mm_plain(const double *restrict A, const double *restrict B, double *restrict C, int m, int q, int n)
{
    for (int i = 0; i < m; i++) {
        double *Ci = C + (Py_ssize_t)i * n;
        for (int j = 0; j < n; j++) Ci[j] = 0.0;
        for (int l = 0; l < q; l++) {
            double a = A[(Py_ssize_t)i * q + l];
            if (a == 0.0) continue;
            const double *Bl = B + (Py_ssize_t)l * n;
            for (int j = 0; j < n; j++) Ci[j] += a * Bl[j];
        }
    }
}

/*
 * window_forward(AT_row, AT_col, AT_val, G, info, infv, Y, y, Ybar, ybar, N, p, r)
 *   For k = 0 .. N-1: for k > 0 the prior M = A^-T Y A^-1 (AT: CSR of A^-T), m = A^-T y, then with
 *   the process noise G (p x r): M -= M G (I + G^T M G)^-1 G^T M, m likewise; Y = (M + M^T)/2 and y = m
 *   stored in Ybar[k], ybar[k]; then Y += info[k], y += infv[k].  Y, y: the start on entry, the
 *   last posterior on return.  Returns -1, or the epoch whose I + G^T M G is not positive definite.
 */
static PyObject *py_window_forward(PyObject *self, PyObject *args)
{
    enum { NB = 10 };
    PyObject *o[NB];
    Buf b[NB + 2];
    memset(b, 0, sizeof(b));
    Py_ssize_t N, p, r;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOnnn", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7], &o[8], &o[9],
                          &N, &p, &r))
        return NULL;
    if (N < 1 || p < 1 || p > 4000 || r < 0 || r > p) {
        PyErr_SetString(PyExc_ValueError, "_ekfcore.window_forward: bad dimensions");
        return NULL;
    }
    PyObject *ret = NULL;
    double *work = NULL;
    Csr AT;
    if (get_csr(o[0], o[1], o[2], b, (int)p, &AT) || get_buf(o[3], &b[3], 'd', p * r, 0, "G")
        || get_buf(o[4], &b[4], 'd', N * p * p, 0, "info") || get_buf(o[5], &b[5], 'd', N * p, 0, "infv")
        || get_buf(o[6], &b[6], 'd', p * p, 1, "Y") || get_buf(o[7], &b[7], 'd', p, 1, "y")
        || get_buf(o[8], &b[8], 'd', N * p * p, 1, "Ybar") || get_buf(o[9], &b[9], 'd', N * p, 1, "ybar"))
        goto done;
    const Py_ssize_t pp = p * p;
    work = calloc(3 * pp + 3 * p * (r + 1) + 3 * r * r + 2 * r + p + 4, sizeof(double));
    if (!work) {
        PyErr_NoMemory();
        goto done;
    }
    const double *G = b[3].view.buf, *info = b[4].view.buf, *infv = b[5].view.buf;
    double *Y = b[6].view.buf, *y = b[7].view.buf, *Ybar = b[8].view.buf, *ybar = b[9].view.buf;
    double *zero = work, *AP = zero + pp, *M = AP + pp, *MG = M + pp, *K = MG + p * (r + 1), *GT = K + p * (r + 1),
           *S = GT + p * (r + 1), *R = S + r * r, *Rw = R + r * r, *gm = Rw + r * r, *m = gm + r + 1;
    long bad = -1;
    const int P = (int)p, Rr = (int)r;
    Py_BEGIN_ALLOW_THREADS
    for (int i = 0; i < P; i++)
        for (int j = 0; j < Rr; j++) GT[j * P + i] = G[i * Rr + j];
    for (Py_ssize_t k = 0; k < N && bad < 0; k++) {
        if (k > 0) {
            predict_P(&AT, zero, Y, AP, M, P);          /* M = A^-T Y A^-1 (zero: p x p zeros) */
            csr_matvec(&AT, y, m, P);                   /* m = A^-T y */
            if (Rr > 0) {
                mm_plain(M, G, MG, P, P, Rr);            /* MG = M G (p x r) */
                mm_plain(GT, MG, S, Rr, P, Rr);          /* S = G^T M G + I */
                for (int i = 0; i < Rr; i++) S[i * Rr + i] += 1.0;
                if (cholesky_upper(S, R, Rr)) {
                    bad = (long)k;
                    break;
                }
                /* K = MG S^-1: solve R^T R K^T = MG^T row by row of K */
                for (int i = 0; i < P; i++) {
                    double *Ki = K + i * Rr;
                    const double *MGi = MG + i * Rr;
                    for (int a = 0; a < Rr; a++) {           /* R^T w = MG_i */
                        double v = MGi[a];
                        for (int c = 0; c < a; c++) v -= R[c * Rr + a] * Ki[c];
                        Ki[a] = v / R[a * Rr + a];
                    }
                    for (int a = Rr - 1; a >= 0; a--) {      /* R K_i = w */
                        double v = Ki[a];
                        for (int c = a + 1; c < Rr; c++) v -= R[a * Rr + c] * Ki[c];
                        Ki[a] = v / R[a * Rr + a];
                    }
                }
                for (int i = 0; i < P; i++)                 /* M -= K MG^T */
                    for (int j = 0; j < P; j++) {
                        double s = 0.0;
                        for (int a = 0; a < Rr; a++) s += K[i * Rr + a] * MG[j * Rr + a];
                        M[i * P + j] -= s;
                    }
                for (int a = 0; a < Rr; a++) {              /* m -= K (G^T m) */
                    double s = 0.0;
                    for (int i = 0; i < P; i++) s += GT[a * P + i] * m[i];
                    gm[a] = s;
                }
                for (int i = 0; i < P; i++) {
                    double s = 0.0;
                    for (int a = 0; a < Rr; a++) s += K[i * Rr + a] * gm[a];
                    m[i] -= s;
                }
            }
            double *Yb = Ybar + k * pp, *yb = ybar + k * p;
            sym_part(M, Y, P);
            memcpy(y, m, sizeof(double) * p);
            memcpy(Yb, Y, sizeof(double) * pp);
            memcpy(yb, y, sizeof(double) * p);
        }
        const double *Ik = info + k * pp, *ik = infv + k * p;
        for (Py_ssize_t i = 0; i < pp; i++) Y[i] += Ik[i];
        for (Py_ssize_t i = 0; i < p; i++) y[i] += ik[i];
    }
    Py_END_ALLOW_THREADS
    ret = PyLong_FromLong(bad);
done:
    free(work);
    release_all(b, NB);
    return ret;
}

/*
 * window_backward(Ai_row, Ai_col, Ai_val, Q, Ybar, ybar, z, Pz, N, p)
 *   For k = N-2 .. 0, from z[k+1], Pz[k+1] (the last on entry):
 *   z[k] = A^-1 (z[k+1] - Q (Ybar[k+1] z[k+1] - ybar[k+1])),
 *   Pz[k] = A^-1 [(I - Q Ybar) Pz[k+1] (I - Ybar Q) + Q - Q Ybar Q] A^-T (symmetrized).
 */
static PyObject *py_window_backward(PyObject *self, PyObject *args)
{
    enum { NB = 8 };
    PyObject *o[NB];
    Buf b[NB + 2];
    memset(b, 0, sizeof(b));
    Py_ssize_t N, p;
    if (!PyArg_ParseTuple(args, "OOOOOOOOnn", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7], &N, &p))
        return NULL;
    if (N < 1 || p < 1 || p > 4000) {
        PyErr_SetString(PyExc_ValueError, "_ekfcore.window_backward: bad dimensions");
        return NULL;
    }
    PyObject *ret = NULL;
    double *work = NULL;
    Csr Ai;
    if (get_csr(o[0], o[1], o[2], b, (int)p, &Ai) || get_buf(o[3], &b[3], 'd', p * p, 0, "Q")
        || get_buf(o[4], &b[4], 'd', N * p * p, 0, "Ybar") || get_buf(o[5], &b[5], 'd', N * p, 0, "ybar")
        || get_buf(o[6], &b[6], 'd', N * p, 1, "z") || get_buf(o[7], &b[7], 'd', N * p * p, 1, "Pz"))
        goto done;
    const Py_ssize_t pp = p * p;
    work = calloc(6 * pp + 2 * p, sizeof(double));
    if (!work) {
        PyErr_NoMemory();
        goto done;
    }
    const double *Q = b[3].view.buf, *Ybar = b[4].view.buf, *ybar = b[5].view.buf;
    double *z = b[6].view.buf, *Pz = b[7].view.buf;
    double *zero = work, *QY = zero + pp, *F = QY + pp, *T1 = F + pp, *T2 = T1 + pp, *AP = T2 + pp, *t = AP + pp,
           *u = t + p;
    const int P = (int)p;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t k = N - 2; k >= 0; k--) {
        const double *Yb = Ybar + (k + 1) * pp, *yb = ybar + (k + 1) * p, *zn = z + (k + 1) * p, *Pn = Pz + (k + 1) * pp;
        gemm_small(P, 0, Q, Yb, NULL, QY);                /* QY = Q Ybar */
        for (int i = 0; i < P; i++) {                     /* t = Ybar z - ybar */
            double s = 0.0;
            for (int j = 0; j < P; j++) s += Yb[i * P + j] * zn[j];
            t[i] = s - yb[i];
        }
        for (int i = 0; i < P; i++) {                     /* u = z - Q t */
            double s = 0.0;
            for (int j = 0; j < P; j++) s += Q[i * P + j] * t[j];
            u[i] = zn[i] - s;
        }
        double *zk = z + k * p;
        csr_matvec(&Ai, u, zk, P);                        /* z[k] = A^-1 u */
        for (int i = 0; i < P; i++)                       /* F = I - QY */
            for (int j = 0; j < P; j++) F[i * P + j] = (i == j ? 1.0 : 0.0) - QY[i * P + j];
        gemm_small(P, 0, F, Pn, NULL, T1);                /* T1 = F Pn */
        for (int i = 0; i < P; i++)                       /* T2 = T1^T (= Pn F^T) */
            for (int j = 0; j < P; j++) T2[i * P + j] = T1[j * P + i];
        gemm_small(P, 0, F, T2, Q, T1);                   /* T1 = Q + F Pn F^T */
        gemm_small(P, 0, QY, Q, NULL, T2);                /* T2 = QY Q */
        for (Py_ssize_t i = 0; i < pp; i++) T1[i] -= T2[i];
        sym_part(T1, T1, P);                              /* (A^-1 X A^-T reads X's rows) */
        predict_P(&Ai, zero, T1, AP, Pz + k * pp, P);     /* Pz[k] = A^-1 X A^-T (exactly symmetric) */
    }
    Py_END_ALLOW_THREADS
    ret = Py_NewRef(Py_None);
done:
    free(work);
    release_all(b, NB);
    return ret;
}

/* ------------------------------------------------------------------------------------------ */
/* the static engine's per-epoch update: kalman.iterated_update_covariance's sparse path on the rows of
 * measurement.dd_signals.RunDDModel, the same BLAS / LAPACK calls with the same arguments as numpy's matmul
 * and scipy's potrf / trtrs wrappers make for it (so the same bits), the elementwise steps as numpy does them.
 *
 * The BLAS routines are numpy's own (its bundled OpenBLAS, ILP64 CBLAS), the LAPACK ones scipy's
 * (cython_lapack), their addresses set once by sd_set_routines (kalman._sd_kernel).  The caller falls back to
 * the numpy path when sd_update returns None (a layout or case this replica does not cover, a factor that
 * fails: numpy then raises as before). */

enum { CB_ROW = 101, CB_COL = 102, CB_NOTRANS = 111, CB_TRANS = 112, CB_UPPER = 121 };
typedef void (*cb_dgemm_t)(int, int, int, int64_t, int64_t, int64_t, double, const double *, int64_t,
                           const double *, int64_t, double, double *, int64_t);
typedef void (*cb_dgemv_t)(int, int, int64_t, int64_t, double, const double *, int64_t, const double *, int64_t,
                           double, double *, int64_t);
typedef void (*cb_dsyrk_t)(int, int, int, int64_t, int64_t, double, const double *, int64_t, double, double *,
                           int64_t);
typedef double (*cb_ddot_t)(int64_t, const double *, int64_t, const double *, int64_t);
typedef void (*lp_dpotrf_t)(char *, int *, double *, int *, int *);
typedef void (*lp_dtrtrs_t)(char *, char *, char *, int *, int *, double *, int *, double *, int *, int *);

static struct {
    cb_dgemm_t gemm; cb_dgemv_t gemv; cb_dsyrk_t syrk; cb_ddot_t dot; lp_dpotrf_t potrf; lp_dtrtrs_t trtrs;
} SD = {0};

static PyObject *py_sd_set_routines(PyObject *self, PyObject *args)
{
    unsigned long long a[6];
    if (!PyArg_ParseTuple(args, "KKKKKK", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5])) return NULL;
    for (int i = 0; i < 6; i++)
        if (!a[i]) { PyErr_SetString(PyExc_ValueError, "_ekfcore.sd_set_routines: null address"); return NULL; }
    SD.gemm = (cb_dgemm_t)(uintptr_t)a[0]; SD.gemv = (cb_dgemv_t)(uintptr_t)a[1];
    SD.syrk = (cb_dsyrk_t)(uintptr_t)a[2]; SD.dot = (cb_ddot_t)(uintptr_t)a[3];
    SD.potrf = (lp_dpotrf_t)(uintptr_t)a[4]; SD.trtrs = (lp_dtrtrs_t)(uintptr_t)a[5];
    Py_RETURN_NONE;
}

/* numpy's A @ x for A (m, k) C-contiguous, x contiguous (its gemv: column-major Aᵀ, transposed) */
static void np_mv(const double *A, int64_t m, int64_t k, const double *x, double *y)
{
    SD.gemv(CB_COL, CB_TRANS, k, m, 1.0, A, k, x, 1, 0.0, y, 1);
}

/* numpy's A @ B (m, q) for A (m, k) and B (k, q), each C-contiguous or, ``at`` / ``bt``, Fortran-ordered (given
 * as its C-contiguous transpose): numpy's gemm, a Fortran-ordered operand passed transposed */
static void np_mm(const double *A, int at, int64_t m, int64_t k, const double *B, int bt, int64_t q, double *C)
{
    SD.gemm(CB_ROW, at ? CB_TRANS : CB_NOTRANS, bt ? CB_TRANS : CB_NOTRANS, m, q, k, 1.0, A, at ? m : k, B,
            bt ? k : q, 0.0, C, q);
}

/* a buffer of float64 / int64 ``count`` elements, C-contiguous (0), else -1 with no error set (the caller
 * falls back to numpy) */
static int sd_buf(PyObject *obj, Buf *b, char kind, Py_ssize_t count, int writable)
{
    if (get_buf(obj, b, kind, count, writable, "sd_update") != 0) {
        PyErr_Clear();
        return -1;
    }
    return 0;
}

/* an (M, 3) float64 array of any strides; its memory order as numpy's ``arr - v`` makes it (C: 1, F: 0), or -1
 * (not covered: the caller falls back to numpy) */
static int sd_rows3(PyObject *obj, Py_buffer *v, int *held, Py_ssize_t M)
{
    if (PyObject_GetBuffer(obj, v, PyBUF_RECORDS_RO) != 0) { PyErr_Clear(); return -1; }
    *held = 1;
    if (v->ndim != 2 || v->shape[0] != M || v->shape[1] != 3 || v->itemsize != 8 || !v->format
        || strcmp(v->format, "d") != 0 || !v->strides)
        return -1;
    const Py_ssize_t s0 = v->strides[0], s1 = v->strides[1];
    if (s1 == 8 && s0 >= 24) return 1;
    if (s0 == 8 && s1 >= 8 * M) return 0;
    return -1;
}

/* ‖row i of (M, 3) ``v`` − o‖ as numpy's ``np.sqrt(np.einsum("ij,ij->i", l, l))`` of ``l = v − o``: einsum sums
 * a C-ordered row as (l0² + l2²) + l1², an F-ordered one as (l0² + l1²) + l2²; ``los`` (M, 3) gets l */
static void sd_ranges(const Py_buffer *v, int c_order, Py_ssize_t M, const double o[3], double *los, double *rng)
{
    const char *base = (const char *)v->buf;
    const Py_ssize_t s0 = v->strides[0], s1 = v->strides[1];
    for (Py_ssize_t i = 0; i < M; i++) {
        const char *row = base + i * s0;
        const double l0 = *(const double *)row - o[0], l1 = *(const double *)(row + s1) - o[1],
                     l2 = *(const double *)(row + 2 * s1) - o[2];
        const double q0 = l0 * l0, q1 = l1 * l1, q2 = l2 * l2;
        rng[i] = sqrt(c_order ? (q0 + q2) + q1 : (q0 + q1) + q2);
        if (los) { los[3 * i] = l0; los[3 * i + 1] = l1; los[3 * i + 2] = l2; }
    }
}

/* sd_update(P, xbar, z, u, inv_sigma, block, sat_xyz, sat_base_xyz, base_xyz, lam, amb, origin, max_iterations,
 *           x_out, P_out) -> NIS or None */
static PyObject *py_sd_update(PyObject *self, PyObject *args)
{
    PyObject *o[15];
    long long max_it_ll;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOLOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7], &o[8],
                          &o[9], &o[10], &o[11], &max_it_ll, &o[13], &o[14]))
        return NULL;
    if (!SD.gemm) Py_RETURN_NONE;
    enum { NB = 12 };
    Buf b[NB];
    memset(b, 0, sizeof b);
    PyObject *ret = NULL;
    double *work = NULL;
    Py_buffer sxv, sbv;
    int sx_held = 0, sb_held = 0;
    /* sizes from xbar and z */
    if (PyObject_GetBuffer(o[1], &b[1].view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) != 0) { PyErr_Clear(); goto none; }
    b[1].held = 1;
    const Py_ssize_t n = b[1].view.len / 8;
    if (PyObject_GetBuffer(o[2], &b[2].view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) != 0) { PyErr_Clear(); goto none; }
    b[2].held = 1;
    const Py_ssize_t p = b[2].view.len / 8, M = p / 2;
    release_all(b, NB);
    if (M < 2 || p != 2 * M || n < 4) goto none;
    if (sd_buf(o[0], &b[0], 'd', n * n, 0) || sd_buf(o[1], &b[1], 'd', n, 0) || sd_buf(o[2], &b[2], 'd', p, 0)
        || sd_buf(o[3], &b[3], 'd', p, 0) || sd_buf(o[4], &b[4], 'd', p, 0) || sd_buf(o[5], &b[5], 'q', p, 0)
        || sd_buf(o[8], &b[6], 'd', 3, 0) || sd_buf(o[9], &b[7], 'd', M, 0) || sd_buf(o[10], &b[8], 'q', M, 0)
        || sd_buf(o[11], &b[9], 'd', 3, 0) || sd_buf(o[13], &b[10], 'd', n, 1) || sd_buf(o[14], &b[11], 'd', n * n, 1))
        goto none;
    const int c_order = sd_rows3(o[6], &sxv, &sx_held, M), cb_order = sd_rows3(o[7], &sbv, &sb_held, M);
    if (c_order < 0 || cb_order < 0) goto none;
    const double *P = b[0].view.buf, *xbar = b[1].view.buf, *z = b[2].view.buf, *u = b[3].view.buf;
    const double *inv = b[4].view.buf, *base_xyz = b[6].view.buf, *lam = b[7].view.buf, *origin = b[9].view.buf;
    const int64_t *blkid = b[5].view.buf, *amb = b[8].view.buf;
    double *x_out = b[10].view.buf, *P_out = b[11].view.buf;
    const int64_t na = 3 + M;
    if (na >= n) goto none;                               /* every column active: the dense form */
    for (Py_ssize_t i = 0; i < M; i++)
        if (amb[i] < 3 || amb[i] >= n || !(lam[i] != 0.0)) goto none;
    /* work, each block 64-byte aligned: a and each row's rank among them (int64), zw, h, hw, v, g (p), xi, xn,
     * dx (n), d (na), Hpos (M*3), Ha, Hw (p*na), Pa (n*na), U (n*p), Ua (na*p), S, c (p*p), W (p*(n+1)), G (n*n),
     * B (p*p), the base ranges (M), los (M*3), the ranges (M) */
    const Py_ssize_t len[] = {na, M, p, p, p, p, p, n, n, n, na, 3 * M, p * na, p * na, n * na, n * p, na * p,
                              p * p, p * p, p * (n + 1), n * n, p * p, M, 3 * M, M};
    enum { NW = sizeof len / sizeof len[0] };
    double *blk[NW];
    Py_ssize_t total = 0;
    for (int i = 0; i < NW; i++) total += (len[i] + 7) / 8 * 8;
    work = aligned_alloc(64, total * sizeof(double));
    if (!work) { PyErr_NoMemory(); goto done; }
    for (int i = 0, off = 0; i < NW; off += (int)((len[i] + 7) / 8 * 8), i++) blk[i] = work + off;
    int64_t *a = (int64_t *)blk[0], *col_of_row = (int64_t *)blk[1];
    double *zw = blk[2], *h = blk[3], *hw = blk[4], *v = blk[5], *g = blk[6], *xi = blk[7], *xn = blk[8];
    double *dx = blk[9], *d = blk[10], *Hpos = blk[11], *Ha = blk[12], *Hw = blk[13], *Pa = blk[14], *U = blk[15];
    double *Ua = blk[16], *S = blk[17], *cf = blk[18], *W = blk[19], *G = blk[20], *Bw = blk[21];
    double *base_rng = blk[22], *los = blk[23], *rng = blk[24];
    /* B = (I − blockdiag(u uᵀ)) Σ^{-1/2} as whitening_matrix forms it (−0.0 across blocks) and the base ranges */
    for (Py_ssize_t i = 0; i < p; i++)
        for (Py_ssize_t j = 0; j < p; j++) {
            double e = blkid[i] == blkid[j] ? -(u[i] * u[j]) : -0.0;
            if (i == j) e += 1.0;
            Bw[i * p + j] = e * inv[j];
        }
    sd_ranges(&sbv, cb_order, M, base_xyz, NULL, base_rng);
    /* the active columns: 0, 1, 2 and the rows' ambiguities, ascending (H.any(axis=0).nonzero()) */
    a[0] = 0; a[1] = 1; a[2] = 2;
    for (Py_ssize_t i = 0; i < M; i++) {                  /* insertion sort of (column, row) */
        Py_ssize_t j = 3 + i;
        while (j > 3 && a[j - 1] > amb[i]) { a[j] = a[j - 1]; j--; }
        if (j > 3 && a[j - 1] == amb[i]) goto none;       /* two rows on one column: numpy's path */
        a[j] = amb[i];
    }
    for (Py_ssize_t i = 0; i < M; i++)
        for (Py_ssize_t j = 3; j < na; j++)
            if (a[j] == amb[i]) { col_of_row[i] = j; break; }
    const int last = (int)((max_it_ll > 1 ? max_it_ll : 1) - 1);
    double nis = NAN;
    np_mv(Bw, p, p, z, zw);                               /* zw = B z */
    memcpy(xi, xbar, n * sizeof(double));
    for (Py_ssize_t j = 0; j < na; j++)                   /* P̄[:, a], Fortran-ordered as numpy makes it */
        for (Py_ssize_t r = 0; r < n; r++) Pa[j * n + r] = P[r * n + a[j]];
    for (int it = 0; it <= last; it++) {
        /* predict: h(x_i) and the position columns of H (RunDDModel.predict) */
        const double o[3] = {origin[0] + xi[0], origin[1] + xi[1], origin[2] + xi[2]};
        int active[3] = {0, 0, 0};
        sd_ranges(&sxv, c_order, M, o, los, rng);
        for (Py_ssize_t i = 0; i < M; i++) {
            const double r = rng[i];
            for (int j = 0; j < 3; j++) {
                Hpos[3 * i + j] = (-los[3 * i + j]) / r;
                active[j] |= (Hpos[3 * i + j] != 0.0);
            }
            const double geo = r - base_rng[i];
            h[M + i] = geo;
            h[i] = geo + lam[i] * xi[amb[i]];
        }
        if (!active[0] || !active[1] || !active[2]) goto none;
        memset(Ha, 0, p * na * sizeof(double));           /* H[:, a], Fortran-ordered as numpy makes it */
        for (Py_ssize_t i = 0; i < M; i++) {
            for (int j = 0; j < 3; j++) Ha[j * p + i] = Ha[j * p + M + i] = Hpos[3 * i + j];
            Ha[col_of_row[i] * p + i] = lam[i];
        }
        np_mm(Bw, 0, p, p, Ha, 1, na, Hw);                /* H_w = B H[:, a] */
        np_mv(Bw, p, p, h, hw);                           /* h_w = B h */
        if (it == 0) {
            for (Py_ssize_t r = 0; r < p; r++) v[r] = zw[r] - hw[r];
        } else {                                          /* ν = z_w − h_w − H_w (x̄[a] − x_i[a]) */
            for (Py_ssize_t j = 0; j < na; j++) d[j] = xbar[a[j]] - xi[a[j]];
            np_mv(Hw, p, na, d, g);
            for (Py_ssize_t r = 0; r < p; r++) v[r] = (zw[r] - hw[r]) - g[r];
        }
        np_mm(Pa, 1, n, na, Hw, 1, p, U);                 /* U = P̄[:, a] H_wᵀ */
        for (Py_ssize_t j = 0; j < na; j++) memcpy(Ua + j * p, U + a[j] * p, p * sizeof(double));
        np_mm(Hw, 0, p, na, Ua, 0, p, S);                 /* S = H_w U[a] + I */
        for (Py_ssize_t r = 0; r < p; r++) S[r * p + r] += 1.0;
        for (Py_ssize_t r = 0; r < p; r++)                /* potrf's Fortran-ordered copy */
            for (Py_ssize_t c = 0; c < p; c++) cf[r + c * p] = S[r * p + c];
        int pi = (int)p, info = 0, nrhs = (int)(n + 1);
        char up = 'U', tr = 'T', nd = 'N';
        SD.potrf(&up, &pi, cf, &pi, &info);
        if (info != 0) goto none;
        memcpy(W, U, n * p * sizeof(double));             /* [Uᵀ | ν] Fortran-ordered: U's rows, then ν */
        memcpy(W + n * p, v, p * sizeof(double));
        SD.trtrs(&up, &tr, &nd, &pi, &nrhs, cf, &pi, W, &pi, &info);
        if (info != 0) goto none;
        SD.gemv(CB_COL, CB_TRANS, p, n, 1.0, W, p, W + n * p, 1, 0.0, dx, 1);      /* Δx = Vᵀ w */
        if (it == 0) nis = 0.0 + SD.dot(p, W + n * p, 1, W + n * p, 1);              /* wᵀ w */
        for (Py_ssize_t r = 0; r < n; r++) xn[r] = xbar[r] + dx[r];
        if (it == last) { memcpy(xi, xn, n * sizeof(double)); break; }
        double step = 0.0, mx = 0.0;
        int nan_step = 0, nan_mx = 0;
        for (Py_ssize_t r = 0; r < n; r++) {
            const double s = fabs(xn[r] - xi[r]), m = fabs(xn[r]);
            if (s != s) nan_step = 1; else if (s > step) step = s;
            if (m != m) nan_mx = 1; else if (m > mx) mx = m;
        }
        memcpy(xi, xn, n * sizeof(double));
        const double scale = (nan_mx || !(mx > 1.0)) ? 1.0 : mx;
        if (!nan_step && step <= 1e-9 * scale) break;
    }
    /* P⁺ = P̄ − Vᵀ V: numpy's syrk of the product with its own transpose, its upper triangle copied down */
    SD.syrk(CB_ROW, CB_UPPER, CB_NOTRANS, n, p, 1.0, W, p, 0.0, G, n);
    for (Py_ssize_t i = 0; i < n; i++)
        for (Py_ssize_t j = i + 1; j < n; j++) G[j * n + i] = G[i * n + j];
    for (Py_ssize_t r = 0; r < n * n; r++) P_out[r] = P[r] - G[r];
    memcpy(x_out, xi, n * sizeof(double));
    ret = PyFloat_FromDouble(nis);
    goto done;
none:
    ret = Py_NewRef(Py_None);
done:
    free(work);
    if (sx_held) PyBuffer_Release(&sxv);
    if (sb_held) PyBuffer_Release(&sbv);
    release_all(b, NB);
    return ret;
}

static PyMethodDef methods[] = {
    {"phase_model", py_phase_model, METH_VARARGS, "phase_model(gi, gf, x, h, H): h(x) and H[:, :n_m] of one state."},
    {"filter_span", py_filter_span, METH_VARARGS, "Forward EKF (fixed biases) over steady-state epochs."},
    {"rts", py_rts, METH_VARARGS, "Rauch-Tung-Striebel smoother pass."},
    {"dd_span", py_dd_span, METH_VARARGS, "Iterated EKF on whitened full-noise (DD) rows over steady-state epochs."},
    {"phase_model_batch", py_phase_model_batch, METH_VARARGS, "h (and H[:, :, :n_m]) of N states at once."},
    {"srif_forward", py_srif_forward, METH_VARARGS, "Epoch loop of the batch square-root information filter."},
    {"reduce_rows", py_reduce_rows, METH_VARARGS, "Per-epoch QR split of the batch solver's measurement rows."},
    {"srif_smooth", py_srif_smooth, METH_VARARGS, "Dyer-McReynolds smoother pass of the batch solver."},
    {"window_forward", py_window_forward, METH_VARARGS, "Information filter of INIT's window (from zero information)."},
    {"window_backward", py_window_backward, METH_VARARGS, "RTS pass of INIT's window from the prior information."},
    {"sd_set_routines", py_sd_set_routines, METH_VARARGS, "Addresses of numpy's CBLAS dgemm, dgemv, dsyrk, ddot and scipy's LAPACK dpotrf, dtrtrs."},
    {"sd_update", py_sd_update, METH_VARARGS, "The static engine's sparse covariance-form update of one epoch (RunDDModel rows)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moddef = {
    PyModuleDef_HEAD_INIT, "_ekfcore", "Compiled inner loops of cdgps_cli.estimation.filter (see cdgps_cli/estimation/kernel.py).", -1,
    methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__ekfcore(void)
{
    PyObject *m = PyModule_Create(&moddef);
    if (m && PyModule_AddIntConstant(m, "API", KERNEL_API) != 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
