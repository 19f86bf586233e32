/* Compiled kernels of pcdet.residuals (the Python side checks shapes and dtypes and documents both).
 *
 * Every function takes B poses T (B, 4, 4) float64, row-major, and M correspondences, model points cm and scene
 * points cs (M, 3) float64, and measures each correspondence under each pose: the residual of correspondence m
 * under pose b is e = R_b cm_m + t_b - cs_m, each coordinate summed left to right (T[i][0] x + T[i][1] y +
 * T[i][2] z + T[i][3] - cs[i]; this file is compiled without fused multiply-adds), and its length
 * d = sqrt(e0^2 + e1^2 + e2^2).
 *
 * within(T, cm, cs, r) -> bytes: B int64 counts, then the indices m (ascending) with d < r of pose 0, of pose 1, ...
 * Poses are tested against a ball first: a correspondence whose scene point lies farther than r + R from the
 * placed centre of the model points' bounding box (R: the model points' largest distance from that centre, plus
 * a micrometre) cannot be within r, and its residual is not computed.
 *
 * tukey_sums(T, cm, cs, c, counts, sums): for each pose b, counts[b] = the correspondences with d < c, and with
 * weights w = (1 - (d / c)^2)^2 where d < c, 0 elsewhere, plus 1e-12 for every correspondence (so no weighting
 * is empty), the 16 sums a weighted Kabsch solves: sum w, sum w cm (3), sum w cs (3), sum w cm_i cs_j (9, row i).
 * The 1e-12 shares are summed once for all poses, and only the correspondences within the ball above (radius c)
 * are measured: outside it the weight is the 1e-12 alone.
 *
 * Both release the interpreter lock while they work.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <math.h>
#include <stdlib.h>

static inline double residual(const double *T, const double *p, const double *q) {
    double e = T[0] * p[0] + T[1] * p[1] + T[2] * p[2] + T[3] - q[0];
    double d2 = e * e;
    e = T[4] * p[0] + T[5] * p[1] + T[6] * p[2] + T[7] - q[1];
    d2 += e * e;
    e = T[8] * p[0] + T[9] * p[1] + T[10] * p[2] + T[11] - q[2];
    d2 += e * e;
    return sqrt(d2);
}

/* s += w * (1, p, q, p q^T) */
static inline void add(double *s, const double *p, const double *q, double w) {
    s[0] += w;
    for (int i = 0; i < 3; i++) {
        s[1 + i] += w * p[i];
        s[4 + i] += w * q[i];
    }
    for (int i = 0; i < 3; i++) {
        double wp = w * p[i];
        for (int j = 0; j < 3; j++) s[7 + 3 * i + j] += wp * q[j];
    }
}

/* The centre of the model points' bounding box and the squared radius around its placed image within which a
 * scene point can lie within r of its placed model point: (largest distance of a model point from the centre
 * + r + a micrometre)^2. */
static void bounds(const double *P, int64_t M, double *c, double *reach2, double r) {
    double lo[3], hi[3], R2 = 0;
    for (int i = 0; i < 3; i++) {
        lo[i] = INFINITY;
        hi[i] = -INFINITY;
    }
    for (int64_t m = 0; m < M; m++)
        for (int i = 0; i < 3; i++) {
            lo[i] = fmin(lo[i], P[3 * m + i]);
            hi[i] = fmax(hi[i], P[3 * m + i]);
        }
    for (int i = 0; i < 3; i++) c[i] = M ? (lo[i] + hi[i]) / 2 : 0.0;
    for (int64_t m = 0; m < M; m++) {
        double a = P[3 * m] - c[0], b = P[3 * m + 1] - c[1], z = P[3 * m + 2] - c[2];
        R2 = fmax(R2, a * a + b * b + z * z);
    }
    double reach = sqrt(R2) + r + 1e-6;
    *reach2 = reach * reach;
}

static int shapes(Py_buffer *T, Py_buffer *P, Py_buffer *Q, int64_t *B, int64_t *M, const char *name) {
    if (T->len % (16 * 8) || P->len % (3 * 8) || Q->len != P->len) {
        PyErr_Format(PyExc_ValueError, "%s: T (B, 4, 4), cm and cs (M, 3), all float64", name);
        return 0;
    }
    *B = T->len / (16 * 8);
    *M = P->len / (3 * 8);
    return 1;
}

static PyObject *within(PyObject *self, PyObject *args) {
    Py_buffer Tb, Pb, Qb;
    double r;
    if (!PyArg_ParseTuple(args, "y*y*y*d", &Tb, &Pb, &Qb, &r)) return NULL;
    PyObject *result = NULL;
    int64_t B, M;
    if (!shapes(&Tb, &Pb, &Qb, &B, &M, "within")) goto done;
    const double *T = Tb.buf, *P = Pb.buf, *Q = Qb.buf;
    int64_t n = 0, cap = 0, *idx = NULL, *counts = malloc((size_t)(B > 0 ? B : 1) * sizeof(int64_t));
    int nomem = counts == NULL;
    Py_BEGIN_ALLOW_THREADS
    double c[3], reach2;
    bounds(P, M, c, &reach2, r);
    for (int64_t b = 0; b < B && !nomem; b++) {
        const double *t = T + 16 * b;
        double o[3];
        for (int i = 0; i < 3; i++) o[i] = t[4 * i] * c[0] + t[4 * i + 1] * c[1] + t[4 * i + 2] * c[2] + t[4 * i + 3];
        int64_t before = n;
        for (int64_t m = 0; m < M; m++) {
            const double *q = Q + 3 * m;
            double a = q[0] - o[0], bb = q[1] - o[1], z = q[2] - o[2];
            if (a * a + bb * bb + z * z >= reach2) continue;
            if (!(residual(t, P + 3 * m, q) < r)) continue;
            if (n == cap) {
                int64_t *grown = realloc(idx, (size_t)(cap = 2 * cap + 4096) * sizeof(int64_t));
                if (!grown) { nomem = 1; break; }
                idx = grown;
            }
            idx[n++] = m;
        }
        counts[b] = n - before;
    }
    Py_END_ALLOW_THREADS
    if (nomem) PyErr_NoMemory();
    else if ((result = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)((B + n) * sizeof(int64_t))))) {
        int64_t *out = (int64_t *)PyBytes_AS_STRING(result);
        for (int64_t b = 0; b < B; b++) out[b] = counts[b];
        for (int64_t e = 0; e < n; e++) out[B + e] = idx[e];
    }
    free(idx);
    free(counts);
done:
    PyBuffer_Release(&Tb);
    PyBuffer_Release(&Pb);
    PyBuffer_Release(&Qb);
    return result;
}

static PyObject *tukey_sums(PyObject *self, PyObject *args) {
    Py_buffer Tb, Pb, Qb, Cb, Sb;
    double c;
    if (!PyArg_ParseTuple(args, "y*y*y*dw*w*", &Tb, &Pb, &Qb, &c, &Cb, &Sb)) return NULL;
    PyObject *result = NULL;
    int64_t B, M;
    if (!shapes(&Tb, &Pb, &Qb, &B, &M, "tukey_sums")) goto done;
    if (Cb.len != B * 8 || Sb.len != B * 16 * 8 || !(c > 0)) {
        PyErr_SetString(PyExc_ValueError, "tukey_sums: counts (B,) int64, sums (B, 16) float64, c > 0");
        goto done;
    }
    const double *T = Tb.buf, *P = Pb.buf, *Q = Qb.buf;
    int64_t *counts = Cb.buf;
    double *S = Sb.buf;
    Py_BEGIN_ALLOW_THREADS
    /* every correspondence's share of the 1e-12 weight, summed once for all poses */
    double all[16] = {0};
    for (int64_t m = 0; m < M; m++) add(all, P + 3 * m, Q + 3 * m, 1.0);
    double ctr[3], reach2;
    bounds(P, M, ctr, &reach2, c);
    for (int64_t b = 0; b < B; b++) {
        const double *t = T + 16 * b;
        double s[16] = {0}, o[3];
        for (int i = 0; i < 3; i++) o[i] = t[4 * i] * ctr[0] + t[4 * i + 1] * ctr[1] + t[4 * i + 2] * ctr[2] + t[4 * i + 3];
        int64_t inside = 0;
        for (int64_t m = 0; m < M; m++) {
            const double *p = P + 3 * m, *q = Q + 3 * m;
            double x = q[0] - o[0], y = q[1] - o[1], z = q[2] - o[2];
            if (x * x + y * y + z * z >= reach2) continue;  /* outside the ball: d >= c, weight 0 */
            double d = residual(t, p, q);
            if (!(d < c)) continue;
            double u = d / c;
            u = 1 - u * u;
            add(s, p, q, u * u);
            inside++;
        }
        counts[b] = inside;
        for (int i = 0; i < 16; i++) S[16 * b + i] = s[i] + 1e-12 * all[i];
    }
    Py_END_ALLOW_THREADS
    result = Py_None;
    Py_INCREF(result);
done:
    PyBuffer_Release(&Tb);
    PyBuffer_Release(&Pb);
    PyBuffer_Release(&Qb);
    PyBuffer_Release(&Cb);
    PyBuffer_Release(&Sb);
    return result;
}

static PyMethodDef methods[] = {
    {"within", within, METH_VARARGS,
     "within(T, cm, cs, r) -> bytes: B int64 counts, then each pose's ascending indices with residual < r"},
    {"tukey_sums", tukey_sums, METH_VARARGS,
     "tukey_sums(T, cm, cs, c, counts, sums): residuals under c and the Tukey-weighted Kabsch sums of each pose"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_residuals", NULL, -1, methods};

PyMODINIT_FUNC PyInit__residuals(void) { return PyModule_Create(&module); }
