/* Optional compiled walk of a receiver byte stream (u-blox UBX, NMEA 0183, RTCM 3): the walk of
 * cdgps_cli/io/ubx_frames.py (_split_stream_walk), step for step, in one linear pass.
 *
 * walk(buffer) -> (ubx, rtcm, counts, bad_ubx_offsets, bad_rtcm_offsets)
 *   ubx   : bytes, int64 pairs (start, end) of the checksum-valid UBX frames, in stream order
 *   rtcm  : bytes, int64 triples (start, end, message type) of the CRC-valid RTCM 3 frames
 *   counts: (bad_checksum_frames, truncated_tail_bytes, skipped_bytes, nmea_sentences, nmea_bytes,
 *            rtcm_bytes, bad_crc_rtcm_frames)
 *   bad_*_offsets: lists of the first MAX_SHOWN offsets
 * rawx_rows(buffer, offsets, out) -> forged: the RXM-RAWX measurements of ubx._decode_rawx gathered as its 40-byte
 *   rows, and the frames listing one signal twice (ubx._repeated_signal_frames), in one pass.
 * UBX checksums are summed over each candidate's bytes until the candidates that failed have cost more
 * than the stream's length, then come from prefix sums (O(1) per candidate, as in the Python walk), so a
 * stream full of false sync words announcing long frames stays linear.  Plain C and the buffer protocol.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define API 1
#define MAX_SHOWN 5
#define NMEA_BODY_MAX 115 /* NMEA_MAX_CHARS - 13 */

static uint32_t crc_table[256];

static void init_crc(void) {
    for (uint32_t i = 0; i < 256; i++) {
        uint32_t c = i << 16;
        for (int j = 0; j < 8; j++) {
            c <<= 1;
            if (c & 0x1000000) c ^= 0x1864CFB;
        }
        crc_table[i] = c & 0xFFFFFF;
    }
}

typedef struct { int64_t *v; Py_ssize_t n, cap; } vec;

static int push(vec *a, int64_t x) {
    if (a->n == a->cap) {
        Py_ssize_t cap = a->cap ? 2 * a->cap : 1024;
        int64_t *p = realloc(a->v, (size_t)cap * sizeof(int64_t));
        if (!p) return -1;
        a->v = p;
        a->cap = cap;
    }
    a->v[a->n++] = x;
    return 0;
}

/* first position >= from of byte c (n: none) */
static Py_ssize_t find_byte(const uint8_t *d, Py_ssize_t n, Py_ssize_t from, uint8_t c) {
    if (from >= n) return n;
    const uint8_t *p = memchr(d + from, c, (size_t)(n - from));
    return p ? (Py_ssize_t)(p - d) : n;
}

static Py_ssize_t find_sync(const uint8_t *d, Py_ssize_t n, Py_ssize_t from) {
    for (;;) {
        Py_ssize_t k = find_byte(d, n, from, 0xB5);
        if (k >= n - 1) return n;
        if (d[k + 1] == 0x62) return k;
        from = k + 1;
    }
}

static int hexval(uint8_t c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    return -1;
}

static int alnum(uint8_t c) { return (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9'); }

/* end of an NMEA sentence with a correct checksum at d[k] ('$'), 0 if none (the regex of ubx_frames.py) */
static Py_ssize_t nmea_at(const uint8_t *d, Py_ssize_t n, Py_ssize_t k) {
    Py_ssize_t i = k + 1;
    if (i >= n || d[i] < 'A' || d[i] > 'Z') return 0;
    i++;
    int r = 0;
    while (r < 6 && i + r < n && alnum(d[i + r])) r++;
    if (r < 1 || r > 5 || i + r >= n || d[i + r] != ',') return 0;
    Py_ssize_t j = i + r + 1;
    for (int m = 0;; m++, j++) {
        if (j + 3 < n && d[j] == '*' && hexval(d[j + 1]) >= 0 && hexval(d[j + 2]) >= 0) {
            Py_ssize_t end = 0;
            if (d[j + 3] == '\n') end = j + 4;
            else if (d[j + 3] == '\r' && j + 4 < n && d[j + 4] == '\n') end = j + 5;
            if (end) {
                uint8_t x = 0;
                for (Py_ssize_t q = k + 1; q < j; q++) x ^= d[q];
                return x == (uint8_t)(hexval(d[j + 1]) * 16 + hexval(d[j + 2])) ? end : 0;
            }
        }
        if (m >= NMEA_BODY_MAX || j >= n || d[j] < 0x20 || d[j] > 0x7E) return 0;
    }
}

/* S_i = sum of d_j (j < i), T_i = sum of j d_j (j < i), mod 256: the checksum over d[a:b] is
 * CK_A = S_b - S_a, CK_B = b CK_A - (T_b - T_a) (mod 256), O(1) per candidate */
static int prefix_sums(const uint8_t *d, Py_ssize_t n, uint8_t **ps, uint8_t **pt) {
    uint8_t *s = malloc((size_t)n + 1), *t = malloc((size_t)n + 1);
    if (!s || !t) { free(s); free(t); return -1; }
    s[0] = t[0] = 0;
    for (Py_ssize_t j = 0; j < n; j++) {
        s[j + 1] = (uint8_t)(s[j] + d[j]);
        t[j + 1] = (uint8_t)(t[j] + (uint8_t)j * d[j]);
    }
    *ps = s;
    *pt = t;
    return 0;
}

#if defined(__SSE2__)
#include <emmintrin.h>
/* the UBX checksum over d[a:b] summed directly, 16 bytes a step (SSE2, part of every x86-64): before a block
 * CK_A is the running sum S; after it S grows by the block's sum and CK_B by 16 S + 16 x0 + 15 x1 + ... + 1 x15.
 * Per 32-bit lane: vs the running sum (psadbw), vp the sum over blocks of S before each block, vw the weighted
 * sums (pmaddwd of the bytes widened to 16 bits: products <= 16 * 255, no sign issue); 32-bit sums wrap mod
 * 2^32, a multiple of 256.  The tail goes byte by byte. */
static void fletcher(const uint8_t *d, Py_ssize_t a, Py_ssize_t b, uint8_t *ck_a, uint8_t *ck_b) {
    const uint8_t *x = d + a;
    Py_ssize_t n = b - a, q = 0;
    uint32_t sa = 0, sb = 0;
    if (n >= 16) {
        const __m128i zero = _mm_setzero_si128();
        const __m128i w_lo = _mm_setr_epi16(16, 15, 14, 13, 12, 11, 10, 9), w_hi = _mm_setr_epi16(8, 7, 6, 5, 4, 3, 2, 1);
        __m128i vs = zero, vp = zero, vw = zero;
        for (; q + 16 <= n; q += 16) {
            __m128i v = _mm_loadu_si128((const __m128i *)(x + q));
            vp = _mm_add_epi32(vp, vs);
            vs = _mm_add_epi32(vs, _mm_sad_epu8(v, zero));
            vw = _mm_add_epi32(vw, _mm_add_epi32(_mm_madd_epi16(_mm_unpacklo_epi8(v, zero), w_lo),
                                                 _mm_madd_epi16(_mm_unpackhi_epi8(v, zero), w_hi)));
        }
        uint32_t s[4], p[4], w[4];
        _mm_storeu_si128((__m128i *)s, vs);
        _mm_storeu_si128((__m128i *)p, vp);
        _mm_storeu_si128((__m128i *)w, vw);
        sa = s[0] + s[2];                     /* psadbw: a sum in the low half of each 64-bit lane */
        sb = 16u * (p[0] + p[2]) + w[0] + w[1] + w[2] + w[3];
    }
    for (; q < n; q++) { sa += x[q]; sb += sa; }
    *ck_a = (uint8_t)sa;
    *ck_b = (uint8_t)sb;
}
#else
/* the UBX checksum over d[a:b] summed directly, 8 bytes a step: after bytes x0..x7, CK_A grows by their sum
 * and CK_B by 8 CK_A + 8 x0 + 7 x1 + ... + 1 x7 (32-bit sums wrap mod 2^32, a multiple of 256) */
static void fletcher(const uint8_t *d, Py_ssize_t a, Py_ssize_t b, uint8_t *ck_a, uint8_t *ck_b) {
    uint32_t sa = 0, sb = 0;
    Py_ssize_t q = a;
    for (; q + 8 <= b; q += 8) {
        const uint8_t *x = d + q;
        sb += 8 * sa + 8u * x[0] + 7u * x[1] + 6u * x[2] + 5u * x[3] + 4u * x[4] + 3u * x[5] + 2u * x[6] + x[7];
        sa += (uint32_t)x[0] + x[1] + x[2] + x[3] + x[4] + x[5] + x[6] + x[7];
    }
    for (; q < b; q++) { sa += d[q]; sb += sa; }
    *ck_a = (uint8_t)sa;
    *ck_b = (uint8_t)sb;
}
#endif

static int plausible_rtcm(int64_t t) { return (t >= 1001 && t <= 1300) || (t >= 4001 && t <= 4095); }

static PyObject *walk(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer buf;
    if (!PyArg_ParseTuple(args, "y*", &buf)) return NULL;
    const uint8_t *d = buf.buf;
    Py_ssize_t n = buf.len;
    uint8_t *s = NULL, *t = NULL;          /* prefix sums, made once direct sums have cost more than n */
    Py_ssize_t wasted = 0;                 /* bytes summed directly for candidates that failed */
    vec ubx = {0}, rtcm = {0}, badu = {0}, badr = {0};
    PyObject *out = NULL;
    int64_t n_badu = 0, trunc = 0, skipped = 0, nmea_n = 0, nmea_b = 0, rtcm_b = 0, n_badr = 0;
    Py_ssize_t pos = 0, scan = 0, nu = -1, nn = -1, nr = -1;
    int err = 0;
    for (;;) {
        if (nu < scan) nu = find_sync(d, n, scan);
        if (nn < scan) nn = find_byte(d, n, scan, '$');
        if (nr < scan) nr = find_byte(d, n, scan, 0xD3);
        Py_ssize_t k = nu < nn ? nu : nn;
        if (nr < k) k = nr;
        if (k >= n) { skipped += n - pos; break; }
        if (k == nu) {
            if (k + 6 > n) { skipped += k - pos; trunc = n - k; break; }
            Py_ssize_t len = d[k + 4] | (d[k + 5] << 8), end = k + 8 + len;
            int bad = 0;
            if (end > n) {
                if (find_sync(d, n, k + 2) >= n) { skipped += k - pos; trunc = n - k; break; }
                bad = 1;
            } else {
                Py_ssize_t a = k + 2, b = k + 6 + len;
                uint8_t ck_a = 0, ck_b = 0;
                if (s) {
                    ck_a = (uint8_t)(s[b] - s[a]);
                    ck_b = (uint8_t)((uint8_t)b * ck_a - (uint8_t)(t[b] - t[a]));
                } else {
                    fletcher(d, a, b, &ck_a, &ck_b);
                }
                bad = ck_a != d[b] || ck_b != d[b + 1];
                if (bad && !s && (wasted += b - a) > n) {  /* false syncs: O(1) checksums from here on */
                    if (prefix_sums(d, n, &s, &t) < 0) { PyErr_NoMemory(); goto done; }
                }
            }
            if (bad) {
                n_badu++;
                if (badu.n < MAX_SHOWN) err |= push(&badu, k);
                scan = k + 2;
            } else {
                err |= push(&ubx, k) | push(&ubx, end);
                skipped += k - pos;
                pos = scan = end;
            }
        } else if (k == nn) {
            Py_ssize_t end = nmea_at(d, n, k);
            if (end) {
                nmea_n++;
                nmea_b += end - k;
                skipped += k - pos;
                pos = scan = end;
            } else {
                scan = k + 1;
            }
        } else {
            Py_ssize_t end = 0;
            int ok = 0;
            int64_t mtype = 0;
            if (k + 6 <= n && !(d[k + 1] & 0xFC)) {
                Py_ssize_t len = ((d[k + 1] & 3) << 8) | d[k + 2];
                end = k + 6 + len;
                if (len < 2 || end > n) {
                    end = 0;
                } else {
                    uint32_t crc = 0;
                    for (Py_ssize_t q = k; q < k + 3 + len; q++)
                        crc = ((crc << 8) & 0xFFFFFF) ^ crc_table[((crc >> 16) ^ d[q]) & 0xFF];
                    uint32_t sent = ((uint32_t)d[k + 3 + len] << 16) | ((uint32_t)d[k + 4 + len] << 8) | d[k + 5 + len];
                    ok = crc == sent;
                    mtype = ((int64_t)d[k + 3] << 4) | (d[k + 4] >> 4);
                }
            }
            if (end && ok) {
                err |= push(&rtcm, k) | push(&rtcm, end) | push(&rtcm, mtype);
                rtcm_b += end - k;
                skipped += k - pos;
                pos = scan = end;
            } else {
                if (end && !ok && plausible_rtcm(mtype)) {
                    n_badr++;
                    if (badr.n < MAX_SHOWN) err |= push(&badr, k);
                }
                scan = k + 1;
            }
        }
        if (err) { PyErr_NoMemory(); goto done; }
    }
    PyObject *lu = PyList_New(badu.n), *lr = PyList_New(badr.n);
    if (!lu || !lr) { Py_XDECREF(lu); Py_XDECREF(lr); goto done; }
    for (Py_ssize_t j = 0; j < badu.n; j++) PyList_SET_ITEM(lu, j, PyLong_FromLongLong(badu.v[j]));
    for (Py_ssize_t j = 0; j < badr.n; j++) PyList_SET_ITEM(lr, j, PyLong_FromLongLong(badr.v[j]));
    static const char empty[1] = {0};   /* y# with a NULL pointer gives None, not b"" */
    out = Py_BuildValue("(y#y#(LLLLLLL)NN)", ubx.v ? (const char *)ubx.v : empty, ubx.n * (Py_ssize_t)sizeof(int64_t),
                        rtcm.v ? (const char *)rtcm.v : empty, rtcm.n * (Py_ssize_t)sizeof(int64_t),
                        (long long)n_badu, (long long)trunc, (long long)skipped, (long long)nmea_n,
                        (long long)nmea_b, (long long)rtcm_b, (long long)n_badr, lu, lr);
done:
    free(s); free(t); free(ubx.v); free(rtcm.v); free(badu.v); free(badr.v);
    PyBuffer_Release(&buf);
    return out;
}

/* open-addressing set of one frame's (gnssId, svId, sigId) keys: 512 slots for at most 255 keys, a slot
 * belonging to the frame whose stamp it carries (no clearing between frames) */
#define KEY_SLOTS 512
static int seen_before(uint32_t *key, uint32_t *stamp, uint32_t frame, uint32_t v) {
    uint32_t h = (v * 2654435761u) >> 23;
    for (;; h = (h + 1) & (KEY_SLOTS - 1)) {
        if (stamp[h] != frame) { stamp[h] = frame; key[h] = v; return 0; }
        if (key[h] == v) return 1;
    }
}

/* rawx_rows(buffer, offsets, out) -> forged
 *   offsets: int64 buffer, the sync-word offsets of RXM-RAWX frames whose payload is 16 + 32*numMeas bytes
 *   out    : writable buffer of 40 bytes per measurement of those frames: each measurement's 32 bytes, then the
 *            index of its frame (int64, little-endian), frame after frame (the rows of ubx._decode_rawx)
 *   forged : bytes, int64 indices of the frames listing one (gnssId, svId, sigId) more than once */
static PyObject *rawx_rows(PyObject *self, PyObject *args) {
    Py_buffer buf, obuf, rbuf;
    if (!PyArg_ParseTuple(args, "y*y*w*", &buf, &obuf, &rbuf)) return NULL;
    const uint8_t *d = buf.buf;
    const int64_t *off = obuf.buf;
    uint8_t *out = rbuf.buf;
    Py_ssize_t n = buf.len, m = obuf.len / (Py_ssize_t)sizeof(int64_t), cap = rbuf.len, used = 0;
    PyObject *res = NULL;
    vec forged = {0};
    uint32_t key[KEY_SLOTS], stamp[KEY_SLOTS];
    memset(stamp, 0, sizeof stamp);
    int err = 0;
    for (Py_ssize_t k = 0; k < m; k++) {
        int64_t a = off[k];
        Py_ssize_t num = (a >= 0 && a + 17 < n) ? d[a + 17] : -1;
        if (num < 0 || a + 22 + 32 * num > n || used + 40 * num > cap) {
            PyErr_SetString(PyExc_ValueError, "rawx_rows: a frame runs past the log or the output");
            goto done;
        }
        const uint8_t *src = d + a + 22;
        uint8_t e[8];
        int twice = 0;
        for (int b = 0; b < 8; b++) e[b] = (uint8_t)((uint64_t)k >> (8 * b));
        for (Py_ssize_t j = 0; j < num; j++, src += 32, used += 40) {
            memcpy(out + used, src, 32);
            memcpy(out + used + 32, e, 8);
            twice |= seen_before(key, stamp, (uint32_t)k + 1,
                                 ((uint32_t)src[20] << 16) | ((uint32_t)src[21] << 8) | src[22]);
        }
        if (twice) err |= push(&forged, k);
    }
    if (used != cap) {
        PyErr_SetString(PyExc_ValueError, "rawx_rows: the output is not 40 bytes per measurement");
        goto done;
    }
    if (err) { PyErr_NoMemory(); goto done; }
    static const char empty[1] = {0};
    res = Py_BuildValue("y#", forged.v ? (const char *)forged.v : empty, forged.n * (Py_ssize_t)sizeof(int64_t));
done:
    free(forged.v);
    PyBuffer_Release(&buf); PyBuffer_Release(&obuf); PyBuffer_Release(&rbuf);
    return res;
}

static PyMethodDef methods[] = {
    {"walk", walk, METH_VARARGS, "Walk a UBX/NMEA/RTCM 3 byte stream: the frames and counters of ubx_frames._split_stream_walk."},
    {"rawx_rows", rawx_rows, METH_VARARGS, "RXM-RAWX measurements as 40-byte rows and the frames repeating a signal."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_ubxcore", NULL, -1, methods};

PyMODINIT_FUNC PyInit__ubxcore(void) {
    init_crc();
    PyObject *m = PyModule_Create(&module);
    if (m && PyModule_AddIntConstant(m, "API", API) < 0) { Py_DECREF(m); return NULL; }
    return m;
}
