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
 * length_matches(...): the length test of the candidate pairs a compatibility graph is built from (below).
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

/* length_matches(a, b, lo2, hi2, cand, x, y, z, k) -> bytes of three int64 arrays of n entries each, one after the
 * other: the scene pair p, and the correspondences a[p] * k + r1 and b[p] * k + r2, of every candidate pair
 * (cand[a[p]][r1], cand[b[p]][r2]) (both >= 0) whose model points' squared distance l2 has lo2[p] < l2 < hi2[p],
 * by p, then r1, then r2. a, b: (P,) int64 scene keypoints; lo2, hi2: (P,) float32; cand: (S, k) int64, -1 for no
 * candidate; x, y, z: (K,) float32 model keypoint coordinates. l2 is summed in float32 in the order numpy's
 * (bx - ax)^2, += (by - ay)^2, += (bz - az)^2 takes (this file is compiled without fused multiply-adds), so the
 * pairs are those numpy's length test keeps. */
static PyObject *length_matches(PyObject *self, PyObject *args) {
    Py_buffer A, B, LO, HI, C, X, Y, Z;
    long long k;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*L", &A, &B, &LO, &HI, &C, &X, &Y, &Z, &k)) return NULL;
    PyObject *result = NULL;
    int64_t P = A.len / 8, K = X.len / 4, S = k > 0 ? C.len / (8 * k) : 0;
    if (k <= 0 || A.len % 8 || B.len != A.len || LO.len != P * 4 || HI.len != P * 4 || C.len != S * k * 8
        || X.len % 4 || Y.len != X.len || Z.len != X.len) {
        PyErr_SetString(PyExc_ValueError, "length_matches: a, b (P,) int64, lo2, hi2 (P,) float32, cand (S, k) int64, "
                                          "x, y, z (K,) float32");
        goto done;
    }
    const int64_t *a = A.buf, *b = B.buf, *cand = C.buf;
    const float *lo2 = LO.buf, *hi2 = HI.buf, *x = X.buf, *y = Y.buf, *z = Z.buf;
    int64_t n = 0, cap = 0, *codes = NULL;
    int bad = 0;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t i = 0; i < P && !bad; i++) bad = a[i] < 0 || a[i] >= S || b[i] < 0 || b[i] >= S;
    for (int64_t i = 0; i < S * k && !bad; i++) bad = cand[i] < -1 || cand[i] >= K;
    float *bx = malloc((size_t)k * 3 * sizeof(float));
    if (!bx) bad = bad ? bad : 2;
    for (int64_t p = 0; p < P && bad == 0; p++) {
        if (cap - n < k * k) {  /* room for every pair of this scene pair: the loop below stores without a branch */
            int64_t *grown = realloc(codes, (size_t)(cap = 2 * cap + k * k + 4096) * sizeof(int64_t));
            if (!grown) { bad = 2; break; }
            codes = grown;
        }
        const int64_t *ca = cand + a[p] * k, *cb = cand + b[p] * k;
        const float lo = lo2[p], hi = hi2[p], nan = (float)NAN;
        for (int64_t r2 = 0; r2 < k; r2++) {  /* b's candidates once; a missing one reads NaN and fails the test */
            int64_t j = cb[r2];
            bx[3 * r2] = j < 0 ? nan : x[j];
            bx[3 * r2 + 1] = j < 0 ? nan : y[j];
            bx[3 * r2 + 2] = j < 0 ? nan : z[j];
        }
        for (int64_t r1 = 0; r1 < k; r1++) {
            int64_t i = ca[r1];
            if (i < 0) continue;
            float ax = x[i], ay = y[i], az = z[i];
            int64_t base = (p * k + r1) * k;
            for (int64_t r2 = 0; r2 < k; r2++) {
                float d = bx[3 * r2] - ax;
                float l2 = d * d;
                d = bx[3 * r2 + 1] - ay;
                l2 += d * d;
                d = bx[3 * r2 + 2] - az;
                l2 += d * d;
                codes[n] = base + r2;
                n += (l2 > lo) & (l2 < hi);  /* stored always, kept when it passes: no branch to mispredict */
            }
        }
    }
    free(bx);
    Py_END_ALLOW_THREADS
    if (bad == 1) PyErr_SetString(PyExc_ValueError, "length_matches: a scene keypoint or a candidate is out of range");
    else if (bad == 2) PyErr_NoMemory();
    else if ((result = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)(3 * n * sizeof(int64_t))))) {
        int64_t *out = (int64_t *)PyBytes_AS_STRING(result);
        for (int64_t e = 0; e < n; e++) {  /* code (p * k + r1) * k + r2 -> p, a[p] * k + r1, b[p] * k + r2 */
            int64_t c = codes[e], q = c / k, r2 = c - q * k, p = q / k, r1 = q - p * k;
            out[e] = p;
            out[n + e] = a[p] * k + r1;
            out[2 * n + e] = b[p] * k + r2;
        }
    }
    free(codes);
done:
    PyBuffer_Release(&A);
    PyBuffer_Release(&B);
    PyBuffer_Release(&LO);
    PyBuffer_Release(&HI);
    PyBuffer_Release(&C);
    PyBuffer_Release(&X);
    PyBuffer_Release(&Y);
    PyBuffer_Release(&Z);
    return result;
}

static PyMethodDef methods[] = {
    {"common_neighbours", common_neighbours, METH_VARARGS,
     "common_neighbours(start, deg, nbr, out): out[e] = vertices adjacent to both ends of CSR entry e"},
    {"length_matches", length_matches, METH_VARARGS,
     "length_matches(a, b, lo2, hi2, cand, x, y, z, k) -> bytes of (3, n) int64: the pairs that pass the length test"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_graph", NULL, -1, methods};

PyMODINIT_FUNC PyInit__graph(void) { return PyModule_Create(&module); }
