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
 * Both release the interpreter lock while they work.
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

static PyMethodDef methods[] = {
    {"box", box, METH_VARARGS, "box(centre, b) -> (lo0, lo1, lo2, span0, span1, span2): the grid around the votes"},
    {"accumulate", accumulate, METH_VARARGS,
     "accumulate(centre, b, weight, lo, span, out): trilinear votes summed into the dense grid out"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_votes", NULL, -1, methods};

PyMODINIT_FUNC PyInit__votes(void) { return PyModule_Create(&module); }
