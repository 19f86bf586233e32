/* Compiled kernel of pcdet.graph: common neighbours of every edge of a sparse undirected graph.
 *
 * The graph is in CSR form: row i lists its neighbours nbr[start[i] : start[i] + deg[i]], ascending, never i
 * itself, and every edge (i, j) appears in both rows (a ValueError otherwise). common_neighbours(start, deg, nbr, out) writes into out[e] (float64, one per
 * entry of nbr) the number of vertices adjacent to both ends of entry e.
 *
 * Each row i marks its neighbours in a byte array of the vertices, then for each later neighbour j (j > i) counts
 * the marked vertices in row j: about sum(deg^2) / 2 reads of an array that stays in cache, where a sparse product
 * A @ A visits sum(deg^2) paths and writes them all before the mask keeps the edges'. The entry (j, i) takes the
 * count of (i, j). The interpreter lock is released meanwhile.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <stdlib.h>

static int64_t find(const int64_t *row, int64_t n, int64_t v) {
    int64_t lo = 0, hi = n;
    while (lo < hi) {
        int64_t mid = lo + (hi - lo) / 2;
        if (row[mid] < v) lo = mid + 1; else hi = mid;
    }
    return lo;
}

static int count(int64_t M, const int64_t *start, const int64_t *deg, const int64_t *nbr, int64_t E, double *out) {
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
    (void)E;
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
    if (ok) rc = count(M, start, deg, nbr, E, o.buf);
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

static PyMethodDef methods[] = {
    {"common_neighbours", common_neighbours, METH_VARARGS,
     "common_neighbours(start, deg, nbr, out): out[e] = vertices adjacent to both ends of CSR entry e"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_graph", NULL, -1, methods};

PyMODINIT_FUNC PyInit__graph(void) { return PyModule_Create(&module); }
