/* Compiled kernels of pcdet.graph (the Python side checks dtypes and documents both).
 *
 * common_neighbours(start, deg, nbr, out): for a graph in CSR form (row i lists its neighbours
 * nbr[start[i] : start[i] + deg[i]], ascending, never i itself, and every edge (i, j) appears in both rows; a
 * ValueError otherwise), out[e] (float64, one per entry of nbr) = the vertices adjacent to both ends of entry e.
 * Each row i marks its neighbours in a byte array of the vertices, then for each later neighbour j (j > i) counts
 * the marked vertices in row j: about sum(deg^2) / 2 reads of an array that stays in cache, where a sparse product
 * A @ A visits sum(deg^2) paths and writes them all before the mask keeps the edges'. The entry (j, i) takes the
 * count of (i, j).
 *
 * compatible_pairs(...): the length and angle tests of the candidate pairs a compatibility graph is built from, with
 * verdicts that are surely numpy's (below).
 *
 * Both release the interpreter lock while they work.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <math.h>
#include <stdlib.h>

static int64_t find(const int64_t *row, int64_t n, int64_t v) {
    int64_t lo = 0, hi = n;
    while (lo < hi) {
        int64_t mid = lo + (hi - lo) / 2;
        if (row[mid] < v) lo = mid + 1; else hi = mid;
    }
    return lo;
}

static int count(int64_t M, const int64_t *start, const int64_t *deg, const int64_t *nbr, double *out) {
    unsigned char *mark = calloc((size_t)(M > 0 ? M : 1), 1);
    if (!mark) return -1;
    for (int64_t i = 0; i < M; i++) {
        const int64_t *ni = nbr + start[i];
        for (int64_t a = 0; a < deg[i]; a++) mark[ni[a]] = 1;
        for (int64_t a = 0; a < deg[i]; a++) {
            int64_t j = ni[a];
            if (j <= i) continue;
            const int64_t *nj = nbr + start[j];
            int64_t c = 0;
            for (int64_t b = 0; b < deg[j]; b++) c += mark[nj[b]];
            out[start[i] + a] = (double)c;
        }
        for (int64_t a = 0; a < deg[i]; a++) mark[ni[a]] = 0;
    }
    free(mark);
    for (int64_t i = 0; i < M; i++) {  /* (i, j) with j < i: the count found from row j */
        const int64_t *ni = nbr + start[i];
        for (int64_t a = 0; a < deg[i]; a++) {
            int64_t j = ni[a];
            if (j >= i) continue;
            int64_t at = find(nbr + start[j], deg[j], i);
            if (at >= deg[j] || nbr[start[j] + at] != i) return -2;  /* (j, i) missing: not symmetric */
            out[start[i] + a] = out[start[j] + at];
        }
    }
    return 0;
}

static int valid(int64_t M, const int64_t *start, const int64_t *deg, const int64_t *nbr, int64_t E) {
    for (int64_t i = 0; i < M; i++) {
        if (deg[i] < 0 || start[i] < 0 || start[i] + deg[i] > E) return 0;
        const int64_t *ni = nbr + start[i];
        for (int64_t a = 0; a < deg[i]; a++)
            if (ni[a] < 0 || ni[a] >= M || ni[a] == i || (a && ni[a] <= ni[a - 1])) return 0;
    }
    return 1;
}

static PyObject *common_neighbours(PyObject *self, PyObject *args) {
    Py_buffer s, d, n, o;
    if (!PyArg_ParseTuple(args, "y*y*y*w*", &s, &d, &n, &o)) return NULL;
    PyObject *result = NULL;
    int64_t M = s.len / 8, E = n.len / 8;
    if (s.len % 8 || n.len % 8 || d.len != s.len || o.len != n.len) {
        PyErr_SetString(PyExc_ValueError, "common_neighbours: start, deg (M,) and nbr (E,) int64, out (E,) float64");
        goto done;
    }
    const int64_t *start = s.buf, *deg = d.buf, *nbr = n.buf;
    int ok, rc = 0;
    Py_BEGIN_ALLOW_THREADS
    ok = valid(M, start, deg, nbr, E);
    if (ok) rc = count(M, start, deg, nbr, o.buf);
    Py_END_ALLOW_THREADS
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "common_neighbours: not a CSR graph with ascending rows and no loops");
        goto done;
    }
    if (rc == -1) {
        PyErr_NoMemory();
        goto done;
    }
    if (rc == -2) {
        PyErr_SetString(PyExc_ValueError, "common_neighbours: the graph is not symmetric");
        goto done;
    }
    result = Py_None;
    Py_INCREF(result);
done:
    PyBuffer_Release(&s);
    PyBuffer_Release(&d);
    PyBuffer_Release(&n);
    PyBuffer_Release(&o);
    return result;
}

/* compatible_pairs(a, b, lo2, hi2, f, tol, cand, x, y, z, nx, ny, nz, k) -> (bytes, bytes): the candidate pairs
 * (cand[a[p]][r1], cand[b[p]][r2]) (both >= 0) of the scene pairs p whose model points' squared distance l2 has
 * lo2[p] < l2 < hi2[p], and then the angle test of each. a, b: (P,) int64 scene keypoints; lo2, hi2: (P,) float32;
 * cand: (S, k) int64, -1 for no candidate; x, y, z: (K,) float32 model keypoint coordinates. l2 is summed in
 * float32 in the order numpy's (bx - ax)^2, += (by - ay)^2, += (bz - az)^2 takes (this file is compiled without
 * fused multiply-adds), so the pairs are those numpy's length test (graph.length_matches) keeps. The first bytes
 * hold two int64 arrays of n entries each (the correspondences a[p] * k + r1 and b[p] * k + r2 of the pairs whose
 * angles surely agree), the second three of m entries (the pair p and the two correspondences of those the kernel
 * leaves undecided), by p, then r1, then r2; the pairs whose angles surely disagree are in neither.
 * f: (P, 3) float32, the scene pair's angles (rad) in the order the test takes them: the normals' angle, n1's and
 * n2's angle with the pair vector d; tol: the angle tolerance (rad, as a float32). nx, ny, nz: (K,) float32 unit
 * model normals. numpy's test (pcdet.grouping.common) is |f - arccos(clip(c))| < tol in float32, for each model
 * pair's cosines c (n1 . n2, n1 . d / |d|, n2 . d / |d|). Here c is computed in double from the same float32
 * inputs, and the test decides only where the float32 one cannot differ: numpy's cosines lie within 8 float32
 * roundings (5e-7) of these, its angles within 1e-6 rad of their arc cosines, and the margins below are wider than
 * both. Each scene pair's bounds on c are computed once, from cos f and sin f, when a candidate pair of it first
 * passes the length test. A NaN angle decides nothing. */
#define COS_MARGIN 2e-6
#define ANGLE_MARGIN 4e-6

/* w[0..3] for one angle f: the test surely holds when w[0] < c < w[1], surely fails when c < w[2] or c > w[3] */
static void angle_bounds(double f, double tol, double *w) {
    if (isnan(f)) {
        w[0] = w[1] = w[2] = w[3] = NAN;
        return;
    }
    const double pi = 3.14159265358979323846, in = tol - ANGLE_MARGIN, out = tol + ANGLE_MARGIN;
    double cf = cos(f), sf = sin(f), ci = cos(in), si = sin(in), co = cos(out), so = sin(out);
    /* cos(f + in) etc. by the sum formula: two sines and cosines of f for the four bounds */
    w[0] = f + in <= pi ? cf * ci - sf * si + COS_MARGIN : -INFINITY;  /* arccos(c) < f + tol, with margin */
    w[1] = f - in >= 0 ? cf * ci + sf * si - COS_MARGIN : INFINITY;    /* arccos(c) > f - tol */
    w[2] = f + out <= pi ? cf * co - sf * so - COS_MARGIN : -INFINITY; /* arccos(c) >= f + tol surely */
    w[3] = f - out >= 0 ? cf * co + sf * so + COS_MARGIN : INFINITY;   /* arccos(c) <= f - tol surely */
}

static int grow(int64_t **buf, int64_t *cap, int64_t need, int64_t width) {
    if (need <= *cap) return 0;
    int64_t c = 2 * *cap + need + 4096;
    int64_t *g = realloc(*buf, (size_t)(c * width) * sizeof(int64_t));
    if (!g) return -1;
    *buf = g;
    *cap = c;
    return 0;
}

static PyObject *compatible_pairs(PyObject *self, PyObject *args) {
    Py_buffer A, B, LO, HI, F, C, X, Y, Z, NX, NY, NZ;
    double tol;
    long long k;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*dy*y*y*y*y*y*y*L", &A, &B, &LO, &HI, &F, &tol, &C, &X, &Y, &Z, &NX, &NY,
                          &NZ, &k))
        return NULL;
    PyObject *result = NULL;
    int64_t P = A.len / 8, K = X.len / 4, S = k > 0 ? C.len / (8 * k) : 0;
    if (k <= 0 || A.len % 8 || B.len != A.len || LO.len != P * 4 || HI.len != P * 4 || F.len != P * 12
        || C.len != S * k * 8 || X.len % 4 || Y.len != X.len || Z.len != X.len || NX.len != X.len
        || NY.len != X.len || NZ.len != X.len) {
        PyErr_SetString(PyExc_ValueError, "compatible_pairs: a, b (P,) int64, lo2, hi2 (P,) float32, f (P, 3) float32, "
                                          "cand (S, k) int64, x, y, z, nx, ny, nz (K,) float32");
        goto done;
    }
    const int64_t *a = A.buf, *b = B.buf, *cand = C.buf;
    const float *lo2 = LO.buf, *hi2 = HI.buf, *fs = F.buf, *x = X.buf, *y = Y.buf, *z = Z.buf, *nx = NX.buf,
                *ny = NY.buf, *nz = NZ.buf;
    int64_t n = 0, cap = 0, m = 0, mcap = 0, *sure = NULL, *left = NULL;
    int bad = 0;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t i = 0; i < P && !bad; i++) bad = a[i] < 0 || a[i] >= S || b[i] < 0 || b[i] >= S;
    for (int64_t i = 0; i < S * k && !bad; i++) bad = cand[i] < -1 || cand[i] >= K;
    float *bx = malloc((size_t)k * 3 * sizeof(float));
    int64_t *passed = malloc((size_t)(k * k) * sizeof(int64_t));
    if (!bx || !passed) bad = bad ? bad : 2;
    for (int64_t p = 0; p < P && bad == 0; p++) {
        const int64_t *ca = cand + a[p] * k, *cb = cand + b[p] * k;
        const float lo = lo2[p], hi = hi2[p], nan = (float)NAN;
        /* the length test without branches (a missing candidate reads NaN and fails), into a list of r1 * k + r2 */
        for (int64_t r2 = 0; r2 < k; r2++) {
            int64_t j = cb[r2];
            bx[3 * r2] = j < 0 ? nan : x[j];
            bx[3 * r2 + 1] = j < 0 ? nan : y[j];
            bx[3 * r2 + 2] = j < 0 ? nan : z[j];
        }
        int64_t q = 0;
        for (int64_t r1 = 0; r1 < k; r1++) {
            int64_t i = ca[r1];
            if (i < 0) continue;
            float ax = x[i], ay = y[i], az = z[i];
            for (int64_t r2 = 0; r2 < k; r2++) {
                float d = bx[3 * r2] - ax;
                float l2 = d * d;
                d = bx[3 * r2 + 1] - ay;
                l2 += d * d;
                d = bx[3 * r2 + 2] - az;
                l2 += d * d;
                passed[q] = r1 * k + r2;
                q += (l2 > lo) & (l2 < hi);
            }
        }
        if (q == 0) continue;
        if (grow(&sure, &cap, n + q, 2) || grow(&left, &mcap, m + q, 3)) { bad = 2; break; }
        double w[12];
        for (int s = 0; s < 3; s++) angle_bounds((double)fs[3 * p + s], tol, w + 4 * s);
        for (int64_t e = 0; e < q; e++) {
            int64_t r1 = passed[e] / k, r2 = passed[e] - r1 * k, i = ca[r1], j = cb[r2];
            double c3 = (double)nx[i] * nx[j] + (double)ny[i] * ny[j] + (double)nz[i] * nz[j];
            if (c3 < w[2] || c3 > w[3]) continue;
            double dx = (double)x[j] - x[i], dy = (double)y[j] - y[i], dz = (double)z[j] - z[i];
            double len = sqrt(dx * dx + dy * dy + dz * dz);
            int agree = 0;
            if (len > 1e-6) {  /* shorter pairs go to numpy */
                double c1 = ((double)nx[i] * dx + (double)ny[i] * dy + (double)nz[i] * dz) / len;
                double c2 = ((double)nx[j] * dx + (double)ny[j] * dy + (double)nz[j] * dz) / len;
                if (c1 < w[6] || c1 > w[7] || c2 < w[10] || c2 > w[11]) continue;
                agree = c3 > w[0] && c3 < w[1] && c1 > w[4] && c1 < w[5] && c2 > w[8] && c2 < w[9];
            }
            int64_t ia = a[p] * k + r1, ib = b[p] * k + r2;
            if (agree) {
                sure[2 * n] = ia;
                sure[2 * n + 1] = ib;
                n++;
            } else {
                left[3 * m] = p;
                left[3 * m + 1] = ia;
                left[3 * m + 2] = ib;
                m++;
            }
        }
    }
    free(bx);
    free(passed);
    Py_END_ALLOW_THREADS
    if (bad == 1) PyErr_SetString(PyExc_ValueError, "compatible_pairs: a scene keypoint or a candidate is out of range");
    else if (bad == 2) PyErr_NoMemory();
    else {
        PyObject *s = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)(2 * n * sizeof(int64_t)));
        PyObject *o = s ? PyBytes_FromStringAndSize(NULL, (Py_ssize_t)(3 * m * sizeof(int64_t))) : NULL;
        if (s && o) {
            int64_t *out = (int64_t *)PyBytes_AS_STRING(s);
            for (int64_t e = 0; e < n; e++) {
                out[e] = sure[2 * e];
                out[n + e] = sure[2 * e + 1];
            }
            out = (int64_t *)PyBytes_AS_STRING(o);
            for (int64_t e = 0; e < m; e++)
                for (int c = 0; c < 3; c++) out[c * m + e] = left[3 * e + c];
            result = PyTuple_Pack(2, s, o);
        }
        Py_XDECREF(s);
        Py_XDECREF(o);
    }
    free(sure);
    free(left);
done:
    PyBuffer_Release(&A);
    PyBuffer_Release(&B);
    PyBuffer_Release(&LO);
    PyBuffer_Release(&HI);
    PyBuffer_Release(&F);
    PyBuffer_Release(&C);
    PyBuffer_Release(&X);
    PyBuffer_Release(&Y);
    PyBuffer_Release(&Z);
    PyBuffer_Release(&NX);
    PyBuffer_Release(&NY);
    PyBuffer_Release(&NZ);
    return result;
}

static PyMethodDef methods[] = {
    {"common_neighbours", common_neighbours, METH_VARARGS,
     "common_neighbours(start, deg, nbr, out): out[e] = vertices adjacent to both ends of CSR entry e"},
    {"compatible_pairs", compatible_pairs, METH_VARARGS,
     "compatible_pairs(a, b, lo2, hi2, f, tol, cand, x, y, z, nx, ny, nz, k) -> (bytes of (2, n) int64, bytes of "
     "(3, m) int64): the pairs whose angles surely agree, and those left undecided"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_graph", NULL, -1, methods};

PyMODINIT_FUNC PyInit__graph(void) { return PyModule_Create(&module); }
