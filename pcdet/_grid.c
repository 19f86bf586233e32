/* Compiled kernel of pcdet.grid (the Python side builds the grid, checks dtypes and documents it).
 *
 * A grid: N points (N, 3) float64 sorted by cell, the C distinct cells' packed keys (C,) int64 in that order, start
 * (C + 1,) int64 (cell c holds the sorted points start[c] .. start[c + 1] - 1), and an open-addressing hash table
 * (T,) int64, T a power of two above C, holding c + 1 for each cell (0: empty slot; anything else is refused). A
 * point's cell is floor(x * inv), floor(y * inv), floor(z * inv) with inv = 1 / cell; its key packs the three in 21
 * bits each (offset by 2^20; grid.py keeps them in range).
 *
 * table(keys, T) -> bytes of (T,) int64: the hash table of the keys.
 *
 * nearest(points, order, start, keys, table, cell, queries, r2, out_d2, out_j, first): for each query q (Q, 3)
 * float64, the point nearest to q among those with a squared distance d2 < r2 (r2 at most cell^2), d2 summed as
 * (qx - px)^2 + (qy - py)^2 + (qz - pz)^2 from left to right (no fused multiply-adds): out_d2 its d2 and out_j its
 * index order[e] (order (N,) int64: each sorted point's index in the cloud as given), or inf and -1 where there is
 * none. Of points at the same distance, the lowest index. The 27 cells around q's are visited from its own
 * outwards, and a cell farther than the best so far (by more than 1e-12 m^2, far above rounding) is skipped.
 * first: stop at the first point within reach instead (out_d2 is then its d2, not the least).
 *
 * clusters(points, order, start, keys, table, cell, r2, out): the connected components of the points linked where
 * d2 <= r2 (r2 at most cell^2; d2 summed as above, as scipy's cKDTree.query_pairs decides it): out (N,) int64 gives
 * each point (by its index in the cloud as given) the lowest index in its component.
 *
 * All release the interpreter lock while they work.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <math.h>
#include <stdlib.h>

#include "_cells.h"

static PyObject *table(PyObject *self, PyObject *args) {
    Py_buffer K;
    long long T;
    if (!PyArg_ParseTuple(args, "y*L", &K, &T)) return NULL;
    PyObject *result = NULL;
    int64_t C = K.len / 8;
    if (K.len % 8 || T <= 0 || (T & (T - 1)) || T < 2 * C) {
        PyErr_SetString(PyExc_ValueError, "table: keys (C,) int64 and a power of two T >= 2 C");
        goto done;
    }
    if (!(result = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)(T * 8)))) goto done;
    int64_t *out = (int64_t *)PyBytes_AS_STRING(result);
    const int64_t *keys = K.buf;
    uint64_t mask = (uint64_t)T - 1;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t h = 0; h < T; h++) out[h] = 0;
    for (int64_t c = 0; c < C; c++) {
        uint64_t h = mix((uint64_t)keys[c]) & mask;
        while (out[h]) h = (h + 1) & mask;
        out[h] = c + 1;
    }
    Py_END_ALLOW_THREADS
done:
    PyBuffer_Release(&K);
    return result;
}

static PyObject *nearest(PyObject *self, PyObject *args) {
    Py_buffer Pb, Ob, Sb, Kb, Tb, Qb, Db, Jb;
    double cell, r2;
    int first;
    if (!PyArg_ParseTuple(args, GRID_ARGS "y*dw*w*p", &Pb, &Ob, &Sb, &Kb, &Tb, &cell, &Qb, &r2, &Db, &Jb, &first))
        return NULL;
    PyObject *result = NULL;
    int64_t C = Kb.len / 8, T = Tb.len / 8, Q = Qb.len / 24;
    const int64_t *start = Sb.buf;
    int ok = grid_ok(Pb.len, Ob.buf, Ob.len, start, Sb.len, Kb.len, Tb.len, cell, 0) && Qb.len % 24 == 0 &&
             Db.len == Q * 8 && Jb.len == Q * 8 && r2 <= cell * cell;  /* order is only copied out: not checked */
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "nearest: points (N, 3) float64, order (N,), start (C + 1,) ascending from 0 "
                                          "to N, keys (C,), table (T,) int64, queries (Q, 3) float64, out_d2 (Q,) "
                                          "float64, out_j (Q,) int64, r2 <= cell^2");
        goto done;
    }
    const double *pts = Pb.buf, *q = Qb.buf;
    const int64_t *order = Ob.buf, *keys = Kb.buf, *tab = Tb.buf;
    double *od = Db.buf;
    int64_t *oj = Jb.buf;
    int corrupt = 0;
    Py_BEGIN_ALLOW_THREADS
    const double inv = 1.0 / cell;
    const uint64_t mask = (uint64_t)T - 1;
    for (int64_t i = 0; i < Q; i++) {
        const double *p = q + 3 * i;
        double best = r2;
        int64_t bj = -1;
        int64_t cp[3];
        double gap[3][3];
        if (locate(p, cell, inv, cp, gap)) {  /* else out of every cell */
            for (int o = 0; o < 27; o++) {
                if (gap_to(gap, o) > best + 1e-12) continue;
                int64_t c = lookup(tab, mask, keys, C, neighbour_key(cp, o));
                if (c == -2) corrupt = 1;
                if (c < 0) continue;
                for (int64_t e = start[c]; e < start[c + 1]; e++) {
                    double d2 = dist2(p, pts + 3 * e);
                    if (d2 < best || (d2 == best && bj >= 0 && order[e] < order[bj])) {
                        best = d2;
                        bj = e;
                    }
                }
                if (first && bj >= 0) break;
            }
        }
        od[i] = bj >= 0 ? best : INFINITY;
        oj[i] = bj >= 0 ? order[bj] : -1;
    }
    Py_END_ALLOW_THREADS
    result = grid_finish("nearest", 0, corrupt);
done:
    RELEASE_GRID;
    PyBuffer_Release(&Qb);
    PyBuffer_Release(&Db);
    PyBuffer_Release(&Jb);
    return result;
}

/* the root of x's set, halving the path on the way */
static inline int64_t root(int64_t *parent, int64_t x) {
    while (parent[x] != x) {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    return x;
}

static PyObject *clusters(PyObject *self, PyObject *args) {
    Py_buffer Pb, Ob, Sb, Kb, Tb, Lb;
    double cell, r2;
    if (!PyArg_ParseTuple(args, GRID_ARGS "dw*", &Pb, &Ob, &Sb, &Kb, &Tb, &cell, &r2, &Lb)) return NULL;
    PyObject *result = NULL;
    int64_t N = Pb.len / 24, C = Kb.len / 8, T = Tb.len / 8;
    const int64_t *start = Sb.buf, *order = Ob.buf;
    int ok = grid_ok(Pb.len, order, Ob.len, start, Sb.len, Kb.len, Tb.len, cell, 1) && Lb.len == N * 8 &&
             r2 <= cell * cell;
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "clusters: points (N, 3) float64, order (N,) in 0..N-1, start (C + 1,) "
                                          "ascending from 0 to N, keys (C,), table (T,) int64, out (N,) int64, "
                                          "r2 <= cell^2");
        goto done;
    }
    const double *pts = Pb.buf;
    const int64_t *keys = Kb.buf, *tab = Tb.buf;
    int64_t *parent = Lb.buf;
    int corrupt = 0;
    Py_BEGIN_ALLOW_THREADS
    const double inv = 1.0 / cell;
    const uint64_t mask = (uint64_t)T - 1;
    for (int64_t i = 0; i < N; i++) parent[i] = i;
    for (int64_t e = 0; e < N; e++) {
        const double *p = pts + 3 * e;
        int64_t cp[3];
        double gap[3][3];
        if (!locate(p, cell, inv, cp, gap)) continue;  /* (the grid's own points always lie in a cell) */
        for (int o = 0; o < 27; o++) {
            if (gap_to(gap, o) > r2 + 1e-12) continue;
            int64_t c = lookup(tab, mask, keys, C, neighbour_key(cp, o));
            if (c == -2) corrupt = 1;
            if (c < 0) continue;
            for (int64_t f = start[c] > e + 1 ? start[c] : e + 1; f < start[c + 1]; f++) {  /* each pair once */
                double d2 = dist2(p, pts + 3 * f);
                if (d2 <= r2) {
                    int64_t ra = root(parent, order[e]), rb = root(parent, order[f]);
                    if (ra < rb) parent[rb] = ra;
                    else if (rb < ra) parent[ra] = rb;
                }
            }
        }
    }
    for (int64_t i = 0; i < N; i++) parent[i] = root(parent, i);
    Py_END_ALLOW_THREADS
    result = grid_finish("clusters", 0, corrupt);
done:
    RELEASE_GRID;
    PyBuffer_Release(&Lb);
    return result;
}

static PyMethodDef methods[] = {
    {"table", table, METH_VARARGS, "table(keys, T) -> bytes of (T,) int64: an open-addressing hash table of the keys"},
    {"nearest", nearest, METH_VARARGS,
     "nearest(points, order, start, keys, table, cell, queries, r2, out_d2, out_j, first): the nearest point within "
     "reach"},
    {"clusters", clusters, METH_VARARGS,
     "clusters(points, order, start, keys, table, cell, r2, out): each point's lowest index in its component"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_grid", NULL, -1, methods};

PyMODINIT_FUNC PyInit__grid(void) { return PyModule_Create(&module); }
