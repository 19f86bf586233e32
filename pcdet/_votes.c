/* Compiled kernel of pcdet.grouping.hough: trilinear Hough votes summed into a dense grid.
 *
 * A vote at point c (m) on a grid of cell b falls at g = c / b - 0.5 in cell units: its lower cell is floor(g)
 * and it weighs (s0 * s1) * s2 on each of the 8 cells around, s_i = 1 - (g_i - floor(g_i)) toward the lower cell
 * of axis i and g_i - floor(g_i) toward the upper (times the vote's own weight, where given). As
 * grouping/hough.py computes it in numpy, operation for operation.
 *
 * box(centre, b) -> (lo0, lo1, lo2, span0, span1, span2): the grid around the votes centre (V, 3) float64 (V >= 1),
 *     with an empty cell on every side: lo = min floor(g) - 1, span = max floor(g) - lo + 3.
 * accumulate(centre, b, weight, lo, span, out): each vote adds its weights to out (span0 * span1 * span2,) float64,
 *     the cell (i, j, k) - lo at (i * span1 + j) * span2 + k; weight (V,) float64, or (0,): none. The sums run corner
 *     by corner ((dx, dy, dz) = (0, 0, 0), (0, 0, 1), ..., (1, 1, 1)) and vote by vote within each, so each cell's
 *     total rounds as numpy's bincount of the eight corners' codes concatenated in that order. Refused
 *     (ValueError) where a vote's cells lie outside the grid.
 *
 * near(centre, b, lo, span, cells, peaks, r) -> bytes of int64: the P counts, then the votes within r (m) of each
 *     peak point (P, 3) float64 in turn, as ascending vote indices. A vote at c is within r where |c - peak|^2 <=
 *     r^2, summed x, y, z in that order; only the votes whose lower cell lies from the peak's cell (cells (P, 3)
 *     int64, the peak at (cell + 0.5) b) - 2 to + 1 on each axis are looked at: with r <= 1.5 b (refused otherwise)
 *     no other can be within r. The votes are bucketed by cell first (a counting sort over the span0 * span1 *
 *     span2 cells of the grid lo, span).
 *
 * All release the interpreter lock while they work.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

static PyObject *box(PyObject *self, PyObject *args) {
    Py_buffer Cb;
    double b;
    if (!PyArg_ParseTuple(args, "y*d", &Cb, &b)) return NULL;
    PyObject *result = NULL;
    int64_t V = Cb.len / 24;
    if (Cb.len % 24 || V < 1 || !(b > 0)) {
        PyErr_SetString(PyExc_ValueError, "box: centre (V, 3) float64 with V >= 1, b > 0");
        goto done;
    }
    const double *c = Cb.buf;
    double mn[3] = {INFINITY, INFINITY, INFINITY}, mx[3] = {-INFINITY, -INFINITY, -INFINITY};
    Py_BEGIN_ALLOW_THREADS
    for (int64_t v = 0; v < V; v++)
        for (int i = 0; i < 3; i++) {
            double f = floor(c[3 * v + i] / b - 0.5);
            if (f < mn[i]) mn[i] = f;
            if (f > mx[i]) mx[i] = f;
        }
    Py_END_ALLOW_THREADS
    for (int i = 0; i < 3; i++)
        if (!(fabs(mn[i]) < 4e18 && fabs(mx[i]) < 4e18)) {
            PyErr_SetString(PyExc_ValueError, "box: a vote is not finite or lies too far out");
            goto done;
        }
    int64_t lo[3], span[3];
    for (int i = 0; i < 3; i++) {
        lo[i] = (int64_t)mn[i] - 1;
        span[i] = (int64_t)mx[i] - lo[i] + 3;
    }
    result = Py_BuildValue("(LLLLLL)", (long long)lo[0], (long long)lo[1], (long long)lo[2], (long long)span[0],
                           (long long)span[1], (long long)span[2]);
done:
    PyBuffer_Release(&Cb);
    return result;
}

static PyObject *accumulate(PyObject *self, PyObject *args) {
    Py_buffer Cb, Wb, Lb, Sb, Db;
    double b;
    if (!PyArg_ParseTuple(args, "y*dy*y*y*w*", &Cb, &b, &Wb, &Lb, &Sb, &Db)) return NULL;
    PyObject *result = NULL;
    int64_t V = Cb.len / 24;
    const int64_t *lo = Lb.buf, *span = Sb.buf;
    if (Cb.len % 24 || !(b > 0) || (Wb.len != 0 && Wb.len != V * 8) || Lb.len != 24 || Sb.len != 24 ||
        span[0] < 1 || span[1] < 1 || span[2] < 1 || Db.len != span[0] * span[1] * span[2] * 8) {
        PyErr_SetString(PyExc_ValueError, "accumulate: centre (V, 3) float64, b > 0, weight (V,) or (0,) float64, lo "
                                          "and span (3,) int64, out (span0 * span1 * span2,) float64");
        goto done;
    }
    const double *c = Cb.buf, *weight = Wb.len ? Wb.buf : NULL;
    double *out = Db.buf;
    int outside = 0, nomem = 0;
    int64_t *code = malloc((size_t)(V > 0 ? V : 1) * sizeof(int64_t)); /* each vote's lower cell, and where in it */
    double *frac = malloc((size_t)(V > 0 ? V : 1) * 3 * sizeof(double));
    Py_BEGIN_ALLOW_THREADS
    if (!code || !frac) nomem = 1;
    for (int64_t v = 0; v < V && !outside && !nomem; v++) {
        int64_t cell[3];
        for (int i = 0; i < 3; i++) {
            double g = c[3 * v + i] / b - 0.5, f = floor(g);
            if (!(f - lo[i] >= 0 && f - lo[i] + 1 < span[i])) outside = 1;
            cell[i] = (int64_t)f - lo[i];
            frac[3 * v + i] = g - f;
        }
        code[v] = (cell[0] * span[1] + cell[1]) * span[2] + cell[2];
    }
    for (int corner = 0; corner < 8 && !outside && !nomem; corner++) {
        int dx = (corner >> 2) & 1, dy = (corner >> 1) & 1, dz = corner & 1;
        int64_t step = (dx * span[1] + dy) * span[2] + dz;
        for (int64_t v = 0; v < V; v++) {
            const double *f = frac + 3 * v;
            double w = ((dx ? f[0] : 1 - f[0]) * (dy ? f[1] : 1 - f[1])) * (dz ? f[2] : 1 - f[2]);
            if (weight) w = w * weight[v];
            out[code[v] + step] += w;
        }
    }
    Py_END_ALLOW_THREADS
    free(code);
    free(frac);
    if (nomem) {
        PyErr_NoMemory();
        goto done;
    }
    if (outside) {
        PyErr_SetString(PyExc_ValueError, "accumulate: a vote's cells lie outside the grid");
        goto done;
    }
    result = Py_None;
    Py_INCREF(result);
done:
    PyBuffer_Release(&Cb);
    PyBuffer_Release(&Wb);
    PyBuffer_Release(&Lb);
    PyBuffer_Release(&Sb);
    PyBuffer_Release(&Db);
    return result;
}

static int cmp_i64(const void *a, const void *b) {
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

static PyObject *near(PyObject *self, PyObject *args) {
    Py_buffer Cb, Lb, Sb, Kb, Pb;
    double b, r;
    if (!PyArg_ParseTuple(args, "y*dy*y*y*y*d", &Cb, &b, &Lb, &Sb, &Kb, &Pb, &r)) return NULL;
    PyObject *result = NULL;
    int64_t V = Cb.len / 24, P = Pb.len / 24;
    const int64_t *lo = Lb.buf, *span = Sb.buf, *pcell = Kb.buf;
    if (Cb.len % 24 || Pb.len % 24 || Kb.len != Pb.len || !(b > 0) || !(r >= 0 && r <= 1.5 * b) || Lb.len != 24 ||
        Sb.len != 24 || span[0] < 1 || span[1] < 1 || span[2] < 1) {
        PyErr_SetString(PyExc_ValueError, "near: centre (V, 3) float64, b > 0, lo and span (3,) int64, cells (P, 3) "
                                          "int64, peaks (P, 3) float64, 0 <= r <= 1.5 b");
        goto done;
    }
    const double *c = Cb.buf, *pk = Pb.buf;
    int64_t C = span[0] * span[1] * span[2], cap = P + 1024, n = P;
    int64_t *start = calloc((size_t)C + 1, sizeof(int64_t)), *code = malloc((size_t)(V > 0 ? V : 1) * sizeof(int64_t));
    int64_t *order = malloc((size_t)(V > 0 ? V : 1) * sizeof(int64_t)), *out = malloc((size_t)cap * sizeof(int64_t));
    int nomem = !start || !code || !order || !out, outside = 0;
    double r2 = r * r;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t v = 0; v < V && !nomem && !outside; v++) { /* each vote's lower cell, counted */
        int64_t cell[3];
        for (int i = 0; i < 3; i++) {
            double f = floor(c[3 * v + i] / b - 0.5);
            if (!(f - lo[i] >= 0 && f - lo[i] < span[i])) outside = 1;
            cell[i] = (int64_t)f - lo[i];
        }
        code[v] = outside ? 0 : (cell[0] * span[1] + cell[1]) * span[2] + cell[2];
        start[code[v] + 1]++;
    }
    if (!nomem && !outside) {
        for (int64_t k = 0; k < C; k++) start[k + 1] += start[k];
        for (int64_t v = 0; v < V; v++) order[start[code[v]]++] = v; /* by cell, ascending within each */
        for (int64_t k = C; k > 0; k--) start[k] = start[k - 1];
        start[0] = 0;
    }
    for (int64_t p = 0; p < P && !nomem && !outside; p++) {
        const double *q = pk + 3 * p;
        int64_t pc[3], first = n;
        for (int i = 0; i < 3; i++) pc[i] = pcell[3 * p + i] - lo[i];
        for (int64_t i = pc[0] - 2; i <= pc[0] + 1 && !nomem; i++)
            for (int64_t j = pc[1] - 2; j <= pc[1] + 1 && !nomem; j++)
                for (int64_t k = pc[2] - 2; k <= pc[2] + 1 && !nomem; k++) {
                    if (i < 0 || j < 0 || k < 0 || i >= span[0] || j >= span[1] || k >= span[2]) continue;
                    int64_t cc = (i * span[1] + j) * span[2] + k;
                    for (int64_t e = start[cc]; e < start[cc + 1]; e++) {
                        const double *x = c + 3 * order[e];
                        double dx = x[0] - q[0], dy = x[1] - q[1], dz = x[2] - q[2];
                        double d2 = dx * dx;
                        d2 += dy * dy;
                        d2 += dz * dz;
                        if (!(d2 <= r2)) continue;
                        if (n == cap) {
                            int64_t *grown = realloc(out, (size_t)(2 * cap) * sizeof(int64_t));
                            if (!grown) {
                                nomem = 1;
                                break;
                            }
                            out = grown;
                            cap *= 2;
                        }
                        out[n++] = order[e];
                    }
                }
        if (!nomem) {
            qsort(out + first, (size_t)(n - first), sizeof(int64_t), cmp_i64);
            out[p] = n - first;
        }
    }
    Py_END_ALLOW_THREADS
    free(start);
    free(code);
    free(order);
    if (nomem) {
        free(out);
        PyErr_NoMemory();
        goto done;
    }
    if (outside) {
        free(out);
        PyErr_SetString(PyExc_ValueError, "near: a vote lies outside the grid");
        goto done;
    }
    result = PyBytes_FromStringAndSize((const char *)out, (Py_ssize_t)(n * 8));
    free(out);
done:
    PyBuffer_Release(&Cb);
    PyBuffer_Release(&Lb);
    PyBuffer_Release(&Sb);
    PyBuffer_Release(&Kb);
    PyBuffer_Release(&Pb);
    return result;
}

static PyMethodDef methods[] = {
    {"box", box, METH_VARARGS, "box(centre, b) -> (lo0, lo1, lo2, span0, span1, span2): the grid around the votes"},
    {"accumulate", accumulate, METH_VARARGS,
     "accumulate(centre, b, weight, lo, span, out): trilinear votes summed into the dense grid out"},
    {"near", near, METH_VARARGS, "near(centre, b, lo, span, cells, peaks, r) -> bytes: the votes within r of each peak"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_votes", NULL, -1, methods};

PyMODINIT_FUNC PyInit__votes(void) { return PyModule_Create(&module); }
