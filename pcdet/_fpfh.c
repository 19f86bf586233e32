/* Compiled kernel of pcdet.features: FPFH descriptors (Rusu et al. 2009) as open3d's legacy implementation computes
 * them, with each point's neighbours found on the hashed voxel grid of pcdet.grid (_grid.c describes the layout;
 * features.py builds the grid with cells a hair wider than the radius, checks dtypes and documents the result).
 *
 * A point's neighbours: the points q with a squared distance d2 < r2 (summed from left to right, no fused
 * multiply-adds), the point itself among them, and of more than max_nn only the max_nn nearest (ties by the lower
 * index), in the order (d2, index): what open3d's hybrid search returns, but for points at the same distance to the
 * bit, which its KD-tree orders (and, at the max_nn-th, keeps) as its traversal meets them.
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

#include "_cells.h"

typedef struct {
    const double *pts;    /* (N, 3) sorted by cell */
    const int64_t *order; /* (N,) each sorted point's index in the cloud as given */
    const int64_t *start, *keys, *tab;
    int64_t N, C;
    uint64_t mask;
    double cell, inv;
} Grid;

typedef struct {
    double d2;
    int64_t j; /* index in the cloud as given */
    int64_t e; /* position in the grid's order */
} Near;

static inline int before(const Near *a, const Near *b) { return a->d2 < b->d2 || (a->d2 == b->d2 && a->j < b->j); }

/* a[0..n) sorted in (d2, index) order: quicksort down to short runs, then insertion sort (qsort's calls through a
 * function pointer took a tenth of the descriptor time where half the points are keypoints) */
static void sort_near(Near *a, int64_t n) {
    while (n > 16) {
        Near pivot = a[n / 2];
        int64_t i = 0, j = n - 1;
        while (i <= j) {
            while (before(&a[i], &pivot)) i++;
            while (before(&pivot, &a[j])) j--;
            if (i <= j) {
                Near t = a[i];
                a[i++] = a[j];
                a[j--] = t;
            }
        }
        if (j + 1 < n - i) {  /* the shorter side by recursion, the longer by the loop */
            sort_near(a, j + 1);
            a += i;
            n -= i;
        } else {
            sort_near(a + i, n - i);
            n = j + 1;
        }
    }
    for (int64_t i = 1; i < n; i++) {
        Near x = a[i];
        int64_t j = i;
        for (; j > 0 && before(&x, &a[j - 1]); j--) a[j] = a[j - 1];
        a[j] = x;
    }
}

/* the k-th smallest (from 0) of d[0..n), d reordered */
static double kth(double *d, int64_t n, int64_t k) {
    int64_t lo = 0, hi = n - 1;
    while (lo < hi) {
        double pivot = d[lo + (hi - lo) / 2];
        int64_t i = lo, j = hi;
        while (i <= j) {
            while (d[i] < pivot) i++;
            while (pivot < d[j]) j--;
            if (i <= j) {
                double t = d[i];
                d[i++] = d[j];
                d[j--] = t;
            }
        }
        if (k <= j) hi = j;
        else if (k >= i) lo = i;
        else return d[k];
    }
    return d[k];
}

/* the k smallest of a[0..n) in (d2, index) order moved to a[0..k), in no particular order; scratch holds n doubles */
static void select_smallest(Near *a, int64_t n, int64_t k, double *scratch) {
    for (int64_t i = 0; i < n; i++) scratch[i] = a[i].d2;
    double tau = kth(scratch, n, k - 1);
    int64_t m = 0, ties = 0;
    for (int64_t i = 0; i < n; i++) {  /* those nearer than the k-th first, then those at its distance */
        if (a[i].d2 < tau) {
            Near t = a[m];
            a[m++] = a[i];
            a[i] = t;
        }
    }
    for (int64_t i = m; i < n; i++) {
        if (a[i].d2 == tau) {
            Near t = a[m + ties];
            a[m + ties++] = a[i];
            a[i] = t;
        }
    }
    if (m + ties > k) {  /* more at the k-th distance than room: the lowest indices */
        sort_near(a + m, ties);
    }
}

/* a query's candidates and room to select among them, grown as needed */
typedef struct {
    Near *near;
    double *d2;
    int64_t cap;
} Buffer;

static void drop(Buffer *b) {
    free(b->near);
    free(b->d2);
}

static int grow(Buffer *b) {
    int64_t cap = b->cap ? 2 * b->cap : 256;
    Near *near = realloc(b->near, (size_t)cap * sizeof(Near));
    if (near) b->near = near;
    double *d2 = realloc(b->d2, (size_t)cap * sizeof(double));
    if (d2) b->d2 = d2;
    if (!near || !d2) return 0;
    b->cap = cap;
    return 1;
}

/* the neighbours of p (the header's definition), into b->near: their number, or -1 when memory runs out; *corrupt
 * set where the hash table is not one table() made */
static int64_t neighbours(const Grid *g, const double *p, double r2, int64_t max_nn, Buffer *b, int *corrupt) {
    int64_t n = 0;
    int64_t cp[3];
    double gap[3][3];
    if (!locate(p, g->cell, g->inv, cp, gap)) return 0;
    for (int o = 0; o < 27; o++) {
        if (gap_to(gap, o) > r2 + 1e-12) continue;
        int64_t c = lookup(g->tab, g->mask, g->keys, g->C, neighbour_key(cp, o));
        if (c == -2) *corrupt = 1;
        if (c < 0) continue;
        for (int64_t e = g->start[c]; e < g->start[c + 1]; e++) {
            double d2 = dist2(p, g->pts + 3 * e);
            if (n == b->cap && !grow(b)) return -1;  /* room for this candidate, kept only if within reach */
            Near *slot = b->near + n;
            slot->d2 = d2;
            slot->e = e;
            slot->j = g->order[e];
            n += d2 < r2;
        }
    }
    if (n > max_nn) {
        select_smallest(b->near, n, max_nn, b->d2);
        n = max_nn;
    }
    return n;
}

static inline double dot(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

static inline void cross(const double *a, const double *b, double *out) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

/* the pair's features as open3d's ComputePairFeatures gives them (all 0 where the points coincide or the frame is
 * degenerate): f[1] phi, f[2] theta, and alpha = atan2(f[0], f[3]) (left to alpha_bin) */
static void pair_features(const double *p1, const double *n1, const double *p2, const double *n2, double *f) {
    double d[3] = {p2[0] - p1[0], p2[1] - p1[1], p2[2] - p1[2]};
    double len = sqrt(dot(d, d));
    f[0] = f[1] = f[2] = f[3] = 0.0;
    if (len == 0.0) return;
    double a1 = dot(n1, d) / len, a2 = dot(n2, d) / len;
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
    cross(d, u, v);
    double vn = sqrt(dot(v, v));
    if (vn == 0.0) {
        f[2] = 0.0;
        return;
    }
    double inv = 1.0 / vn;  /* open3d divides each by vn: this rounds differently, by a unit in the last place */
    v[0] *= inv;
    v[1] *= inv;
    v[2] *= inv;
    cross(u, v, w);
    f[1] = dot(v, w2);
    f[0] = dot(w, w2);
    f[3] = dot(u, w2);
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

static int parse_grid(Py_buffer *Pb, Py_buffer *Ob, Py_buffer *Sb, Py_buffer *Kb, Py_buffer *Tb, double cell, Grid *g) {
    int64_t N = Pb->len / 24, C = Kb->len / 8, T = Tb->len / 8;
    const int64_t *start = Sb->buf, *order = Ob->buf;
    int ok = grid_ok(Pb->len, order, Ob->len, start, Sb->len, Kb->len, Tb->len, cell, 1);
    g->pts = Pb->buf;
    g->order = order;
    g->start = start;
    g->keys = Kb->buf;
    g->tab = Tb->buf;
    g->N = N;
    g->C = C;
    g->mask = (uint64_t)T - 1;
    g->cell = cell;
    g->inv = 1.0 / cell;
    return ok;
}

static const char *GRID_ERR = "grid: points (N, 3) float64, order (N,) in 0..N-1, start (C + 1,) ascending from "
                              "0 to N, keys (C,), table (T,) int64";

/* which (M,) int64 indices into a cloud of n points */
static int valid_indices(const Py_buffer *Wb, int64_t n) {
    if (Wb->len % 8) return 0;
    const int64_t *w = Wb->buf;
    for (int64_t i = 0; i < Wb->len / 8; i++)
        if (w[i] < 0 || w[i] >= n) return 0;
    return 1;
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
