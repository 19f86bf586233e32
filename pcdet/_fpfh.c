/* Compiled kernel of pcdet.features: FPFH descriptors (Rusu et al. 2009) as open3d's legacy implementation computes
 * them, with each point's neighbours found on the hashed voxel grid of pcdet.grid (_grid.c describes the layout;
 * features.py builds the grid with cells a hair wider than the radius, checks dtypes and documents the result).
 *
 * A point's neighbours are those _near.h defines (found there), in the order (d2, index).
 *
 * The pair features are open3d's, computed in the same order, but for two choices that change a histogram only
 * where a value lies within rounding of a bin's edge: each of v's components is multiplied by 1 / |v| instead of
 * divided by |v|, and alpha is binned from a polynomial approximation of atan2 unless that lies near an edge
 * (alpha_bin). Where open3d writes acos|a1| > acos|a2| to choose the pair's source, its results are those of
 * |a1| < |a2|, which the kernel uses (tests/test_features.py holds a real case where glibc's acos rounds the two
 * to one value).
 *
 * reach(grid..., P, which, r2, max_nn, mark): mark (N,) uint8 set to 1 at every neighbour of each point which (M,)
 *     int64 (indices into P (N, 3) float64, the cloud as given).
 * spfh(grid..., normals, which, r2, max_nn, out): out (M, 33) float64, the simplified point feature histogram of
 *     each point which (M,) int64, given by its position in the grid's order, as its normal in normals (N, 3)
 *     float64 (in the grid's order too): over its neighbours but itself (n of them), 100 / n added to one of 11
 *     bins of each of the three angles of the pair (alpha, phi, theta as open3d computes them); zero where n is 0.
 * fpfh(grid..., P, which, r2, max_nn, spfh, row, out): out (M, 33) float64; row (N,) int64 names the row of spfh
 *     (S, 33) that holds each neighbour's histogram (-1: none; refused). Each point's FPFH is its own histogram
 *     plus, for each of its 3 groups of 11 bins, its neighbours' histograms (the first neighbour and those at
 *     d2 == 0 skipped) weighted by 1 / d2 and scaled to sum to 100; zero where it has no other neighbour.
 *
 * All release the interpreter lock while they work. Each point's result depends on nothing else, so calls on parts
 * of `which` from several threads give what one call gives.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "_near.h"

/* the pair's features as open3d's ComputePairFeatures gives them (all 0 where the points coincide or the frame is
 * degenerate): f[1] phi, f[2] theta, and alpha = atan2(f[0], f[3]) (left to alpha_bin) */
static void pair_features(const double *p1, const double *n1, const double *p2, const double *n2, double *f) {
    double d[3] = {p2[0] - p1[0], p2[1] - p1[1], p2[2] - p1[2]};
    double len = sqrt(dot3(d, d));
    f[0] = f[1] = f[2] = f[3] = 0.0;
    if (len == 0.0) return;
    double a1 = dot3(n1, d) / len, a2 = dot3(n2, d) / len;
    /* the end whose normal makes the smaller angle with the line between them is the source (the header) */
    int swap = fabs(a1) < fabs(a2);
    const double *u = n1, *w2 = n2;
    if (swap) {
        u = n2;
        w2 = n1;
        d[0] = -d[0];
        d[1] = -d[1];
        d[2] = -d[2];
        f[2] = -a2;
    } else {
        f[2] = a1;
    }
    double v[3], w[3];
    cross3(d, u, v);
    double vn = sqrt(dot3(v, v));
    if (vn == 0.0) {
        f[2] = 0.0;
        return;
    }
    double inv = 1.0 / vn;  /* open3d divides each by vn: this rounds differently, by a unit in the last place */
    v[0] *= inv;
    v[1] *= inv;
    v[2] *= inv;
    cross3(u, v, w);
    f[1] = dot3(v, w2);
    f[0] = dot3(w, w2);
    f[3] = dot3(u, w2);
}

/* floor(b) clamped to 0..10; (int) truncates towards 0, which differs from floor only below 0, clamped alike */
static inline int bin(double b) {
    int h = (int)b;
    return h < 0 ? 0 : h >= 11 ? 10 : h;
}

/* floor(11 (atan2(y, x) + pi) / (2 pi)), clamped to 0..10, as open3d bins alpha. atan2 is a quarter of the cost
 * of a pair, so it is first approximated (a polynomial within 2.1e-4 rad of it, 3.7e-4 in t); only where t lies
 * within 1e-3 of a bin's edge (or is not a number) is atan2 itself asked */
static inline int alpha_bin(double y, double x) {
    double ax = fabs(x), ay = fabs(y);
    int steep = ay > ax;
    double a = (steep ? ax : ay) / (steep ? ay : ax), s = a * a;
    double r = ((-0.0464964749 * s + 0.15931422) * s - 0.327622764) * s * a + a;
    r = steep ? M_PI_2 - r : r;
    r = x < 0 ? M_PI - r : r;
    double t = (copysign(r, y) + M_PI) * (11 / (2.0 * M_PI)), frac = t - (int)t;
    if (!(frac >= 1e-3 && frac <= 1 - 1e-3)) t = 11 * (atan2(y, x) + M_PI) / (2.0 * M_PI);
    return bin(t);
}


static PyObject *reach(PyObject *self, PyObject *args) {
    Py_buffer Pb, Ob, Sb, Kb, Tb, Xb, Wb, Mb;
    double cell, r2;
    long long max_nn;
    if (!PyArg_ParseTuple(args, GRID_ARGS "y*y*dLw*", &Pb, &Ob, &Sb, &Kb, &Tb, &cell, &Xb, &Wb, &r2, &max_nn, &Mb))
        return NULL;
    PyObject *result = NULL;
    Grid g;
    int ok = parse_grid(&Pb, &Ob, &Sb, &Kb, &Tb, cell, &g);
    int64_t N = g.N, M = Wb.len / 8;
    if (!ok || Xb.len != N * 24 || Mb.len != N || r2 > cell * cell || max_nn < 1 || !valid_indices(&Wb, N)) {
        PyErr_SetString(PyExc_ValueError, ok ? "reach: P (N, 3) float64, which (M,) int64 in 0..N-1, mark (N,) uint8, "
                                               "r2 <= cell^2, max_nn >= 1" : GRID_ERR);
        goto done;
    }
    const double *P = Xb.buf;
    const int64_t *which = Wb.buf;
    uint8_t *mark = Mb.buf;
    Buffer b = {NULL, NULL, 0};
    int corrupt = 0, nomem = 0;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t i = 0; i < M && !nomem; i++) {
        int64_t n = neighbours(&g, P + 3 * which[i], r2, max_nn, &b, &corrupt);
        if (n < 0) nomem = 1;
        for (int64_t k = 0; k < n; k++) mark[b.near[k].j] = 1;
    }
    drop(&b);
    Py_END_ALLOW_THREADS
    result = grid_finish("reach", nomem, corrupt);
done:
    RELEASE_GRID;
    PyBuffer_Release(&Xb);
    PyBuffer_Release(&Wb);
    PyBuffer_Release(&Mb);
    return result;
}

static PyObject *spfh(PyObject *self, PyObject *args) {
    Py_buffer Pb, Ob, Sb, Kb, Tb, Nb, Wb, Db;
    double cell, r2;
    long long max_nn;
    if (!PyArg_ParseTuple(args, GRID_ARGS "y*y*dLw*", &Pb, &Ob, &Sb, &Kb, &Tb, &cell, &Nb, &Wb, &r2, &max_nn, &Db))
        return NULL;
    PyObject *result = NULL;
    Grid g;
    int ok = parse_grid(&Pb, &Ob, &Sb, &Kb, &Tb, cell, &g);
    int64_t N = g.N, M = Wb.len / 8;
    if (!ok || Nb.len != N * 24 || Db.len != M * 33 * 8 || r2 > cell * cell || max_nn < 1 || !valid_indices(&Wb, N)) {
        PyErr_SetString(PyExc_ValueError, ok ? "spfh: normals (N, 3) float64 in the grid's order, which (M,) int64 in "
                                               "0..N-1, out (M, 33) float64, r2 <= cell^2, max_nn >= 1" : GRID_ERR);
        goto done;
    }
    const double *nrm = Nb.buf;
    const int64_t *which = Wb.buf;
    double *out = Db.buf;
    Buffer b = {NULL, NULL, 0};
    int corrupt = 0, nomem = 0;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t i = 0; i < M && !nomem; i++) {
        double *h = out + 33 * i;
        memset(h, 0, 33 * sizeof(double));
        const double *p = g.pts + 3 * which[i], *n1 = nrm + 3 * which[i];
        int64_t n = neighbours(&g, p, r2, max_nn, &b, &corrupt);
        if (n < 0) nomem = 1;
        if (n < 2) continue;
        /* open3d skips the first neighbour, the point itself or one at the same place: every pair at distance 0
         * adds to the same bins, so skipping any one at d2 == 0 gives the same histogram */
        double incr = 100.0 / (double)(n - 1), f[4];
        int skipped = 0;
        for (int64_t k = 0; k < n; k++) {
            if (!skipped && b.near[k].d2 == 0.0) {
                skipped = 1;
                continue;
            }
            int64_t e = b.near[k].e;
            pair_features(p, n1, g.pts + 3 * e, nrm + 3 * e, f);
            h[alpha_bin(f[0], f[3])] += incr;
            h[11 + bin(11 * (f[1] + 1.0) * 0.5)] += incr;
            h[22 + bin(11 * (f[2] + 1.0) * 0.5)] += incr;
        }
    }
    drop(&b);
    Py_END_ALLOW_THREADS
    result = grid_finish("spfh", nomem, corrupt);
done:
    RELEASE_GRID;
    PyBuffer_Release(&Nb);
    PyBuffer_Release(&Wb);
    PyBuffer_Release(&Db);
    return result;
}

static PyObject *fpfh(PyObject *self, PyObject *args) {
    Py_buffer Pb, Ob, Sb, Kb, Tb, Xb, Wb, Hb, Rb, Db;
    double cell, r2;
    long long max_nn;
    if (!PyArg_ParseTuple(args, GRID_ARGS "y*y*dLy*y*w*", &Pb, &Ob, &Sb, &Kb, &Tb, &cell, &Xb, &Wb, &r2, &max_nn, &Hb,
                          &Rb, &Db))
        return NULL;
    PyObject *result = NULL;
    Grid g;
    int ok = parse_grid(&Pb, &Ob, &Sb, &Kb, &Tb, cell, &g);
    int64_t N = g.N, M = Wb.len / 8, S = Hb.len / (33 * 8);
    if (!ok || Xb.len != N * 24 || Hb.len % (33 * 8) || Rb.len != N * 8 || Db.len != M * 33 * 8 || r2 > cell * cell ||
        max_nn < 1 || !valid_indices(&Wb, N)) {
        PyErr_SetString(PyExc_ValueError, ok ? "fpfh: P (N, 3) float64, which (M,) int64 in 0..N-1, spfh (S, 33) "
                                               "float64, row (N,) int64, out (M, 33) float64, r2 <= cell^2, "
                                               "max_nn >= 1" : GRID_ERR);
        goto done;
    }
    const double *P = Xb.buf, *H = Hb.buf;
    const int64_t *which = Wb.buf, *row = Rb.buf;
    double *out = Db.buf;
    Buffer b = {NULL, NULL, 0};
    int corrupt = 0, nomem = 0, missing = 0;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t i = 0; i < M && !nomem && !missing; i++) {
        double *f = out + 33 * i;
        memset(f, 0, 33 * sizeof(double));
        int64_t s = which[i];
        int64_t n = neighbours(&g, P + 3 * s, r2, max_nn, &b, &corrupt);
        if (n < 0) nomem = 1;
        if (n < 2) continue;
        sort_near(b.near, n);
        double sum[3] = {0.0, 0.0, 0.0};
        for (int64_t k = 1; k < n; k++) {  /* the first is the point itself (or one at its place) */
            double d2 = b.near[k].d2;
            if (d2 == 0.0) continue;
            int64_t r = row[b.near[k].j];
            if (r < 0 || r >= S) {
                missing = 1;
                break;
            }
            const double *h = H + 33 * r;
            double v[33];
            for (int b = 0; b < 33; b++) v[b] = h[b] / d2;  /* independent: the compiler pairs the divisions */
            for (int b = 0; b < 33; b++) f[b] += v[b];
            for (int b = 0; b < 11; b++) {  /* each group summed in bin order, as open3d sums it */
                sum[0] += v[b];
                sum[1] += v[11 + b];
                sum[2] += v[22 + b];
            }
        }
        int64_t own = row[s];
        if (own < 0 || own >= S) missing = 1;
        if (missing) break;
        for (int b = 0; b < 3; b++)
            if (sum[b] != 0.0) sum[b] = 100.0 / sum[b];
        for (int b = 0; b < 33; b++) f[b] = f[b] * sum[b / 11] + H[33 * own + b];
    }
    drop(&b);
    Py_END_ALLOW_THREADS
    if (missing) {
        PyErr_SetString(PyExc_ValueError, "fpfh: a neighbour's histogram is not in spfh (row -1 or out of range)");
        goto done;
    }
    result = grid_finish("fpfh", nomem, corrupt);
done:
    RELEASE_GRID;
    PyBuffer_Release(&Xb);
    PyBuffer_Release(&Wb);
    PyBuffer_Release(&Hb);
    PyBuffer_Release(&Rb);
    PyBuffer_Release(&Db);
    return result;
}

static PyMethodDef methods[] = {
    {"reach", reach, METH_VARARGS, "reach(grid..., P, which, r2, max_nn, mark): mark every neighbour of the points"},
    {"spfh", spfh, METH_VARARGS, "spfh(grid..., normals, which, r2, max_nn, out): the points' SPFH (M, 33)"},
    {"fpfh", fpfh, METH_VARARGS, "fpfh(grid..., P, which, r2, max_nn, spfh, row, out): the points' FPFH (M, 33)"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_fpfh", NULL, -1, methods};

PyMODINIT_FUNC PyInit__fpfh(void) { return PyModule_Create(&module); }
