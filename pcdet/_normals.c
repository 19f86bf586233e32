/* Compiled kernel of pcdet.cloud.estimate_normals: each point's unit normal, the direction of least spread of its
 * neighbours (those _near.h defines: within the radius, at most max_nn nearest), found on the hashed voxel grid of
 * pcdet.grid (_grid.c describes the layout; cloud.py builds the grid with cells a hair wider than the radius).
 *
 * normals(grid..., lo, hi, r2, max_nn, out): out (hi - lo, 3) float64, the normals of the points at positions
 *     lo..hi-1 of the grid's order: the eigenvector of the smallest eigenvalue of its neighbours' covariance (about
 *     their mean, divided by their number; least_axis says how it is found); (0, 0, 1) where a point has fewer than
 *     3 neighbours or they all lie at one place, as open3d's estimate_normals gives. The sign is whatever the
 *     solution gives: cloud.py turns the normals toward a viewpoint or along the surface.
 *
 * It releases the interpreter lock while it works. Each point's normal depends on nothing else, so calls on parts of
 * the positions from several threads give what one call gives.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "_near.h"

/* The unit eigenvector v of the smallest eigenvalue of the symmetric 3x3 matrix with entries m = (xx, xy, xz, yy, yz,
 * zz). The eigenvalue from the trigonometric solution of the characteristic cubic (about the mean of the diagonal,
 * scaled), the vector as the largest cross product of two rows of A - lambda I, which span the plane it is normal
 * to. Where those rows span no plane (the two smallest eigenvalues equal: neighbours along a line) v is a unit vector
 * normal to the largest row; where A is a multiple of I (all neighbours at one place), (0, 0, 1). */
static void least_axis(const double m[6], double v[3]) {
    double q = (m[0] + m[3] + m[5]) / 3.0;
    double b0 = m[0] - q, b1 = m[3] - q, b2 = m[5] - q;
    double p2 = b0 * b0 + b1 * b1 + b2 * b2 + 2.0 * (m[1] * m[1] + m[2] * m[2] + m[4] * m[4]);
    v[0] = v[1] = 0.0;
    v[2] = 1.0;
    if (!(p2 > 0.0)) return;
    double p = sqrt(p2 / 6.0);
    double det = b0 * (b1 * b2 - m[4] * m[4]) - m[1] * (m[1] * b2 - m[4] * m[2]) + m[2] * (m[1] * m[4] - b1 * m[2]);
    double r = det / (2.0 * p * p * p);
    r = r < -1.0 ? -1.0 : (r > 1.0 ? 1.0 : r);
    double lambda = q + 2.0 * p * cos(acos(r) / 3.0 + 2.0943951023931957);  /* + 2 pi / 3: the smallest root */
    double rows[3][3] = {{m[0] - lambda, m[1], m[2]}, {m[1], m[3] - lambda, m[4]}, {m[2], m[4], m[5] - lambda}};
    double c[3][3], best = -1.0;
    int k = 0;
    cross3(rows[0], rows[1], c[0]);
    cross3(rows[0], rows[2], c[1]);
    cross3(rows[1], rows[2], c[2]);
    for (int i = 0; i < 3; i++) {
        double n2 = dot3(c[i], c[i]);
        if (n2 > best) {
            best = n2;
            k = i;
        }
    }
    if (best > 1e-20 * p2 * p2) {  /* the rows span a plane, to well above rounding */
        double len = sqrt(best);
        for (int i = 0; i < 3; i++) v[i] = c[k][i] / len;
        return;
    }
    int big = 0;  /* a line: the largest row is its direction; v is normal to it, along the axis it leans least on */
    double big2 = -1.0;
    for (int i = 0; i < 3; i++) {
        double n2 = dot3(rows[i], rows[i]);
        if (n2 > big2) {
            big2 = n2;
            big = i;
        }
    }
    int axis = 0;
    for (int i = 1; i < 3; i++)
        if (fabs(rows[big][i]) < fabs(rows[big][axis])) axis = i;
    double e[3] = {0.0, 0.0, 0.0}, w[3];
    e[axis] = 1.0;
    cross3(rows[big], e, w);
    double len = sqrt(dot3(w, w));
    if (len > 0.0)
        for (int i = 0; i < 3; i++) v[i] = w[i] / len;
}

/* the cell holding grid position e: the c with start[c] <= e < start[c + 1] */
static int64_t cell_of(const Grid *g, int64_t e) {
    int64_t lo = 0, hi = g->C - 1;
    while (lo < hi) {
        int64_t mid = lo + (hi - lo + 1) / 2;
        if (g->start[mid] <= e) lo = mid;
        else hi = mid - 1;
    }
    return lo;
}

/* The normals of grid positions lo..hi-1 into out (hi - lo, 3). The points of a cell share their candidates, the
 * points of the 27 cells around it (in the order of OFFSETS, as _near.h's neighbours() visits them), looked up once
 * for the cell: the neighbours are those neighbours() gives, in the same order. 0, or -1 when memory runs out. */
static int normals_of(const Grid *g, int64_t lo, int64_t hi, double r2, int64_t max_nn, double *out, Buffer *b,
                      int *corrupt) {
    const int64_t M21 = ((int64_t)1 << 21) - 1, R = (int64_t)1 << 20;
    for (int64_t e = lo, c = lo < hi ? cell_of(g, lo) : 0; e < hi; c++) {
        int64_t key = g->keys[c], cc[3] = {(key >> 42) - R, ((key >> 21) & M21) - R, (key & M21) - R};
        int64_t from[27], to[27];
        int nr = 0;
        for (int o = 0; o < 27; o++) {
            int64_t d = lookup(g->tab, g->mask, g->keys, g->C, neighbour_key(cc, o));
            if (d == -2) *corrupt = 1;
            if (d < 0) continue;
            from[nr] = g->start[d];
            to[nr++] = g->start[d + 1];
        }
        for (int64_t end = g->start[c + 1] < hi ? g->start[c + 1] : hi; e < end; e++) {
            const double *p = g->pts + 3 * e;
            double *v = out + 3 * (e - lo);
            int64_t n = 0;
            for (int k = 0; k < nr; k++) {
                for (int64_t f = from[k]; f < to[k]; f++) {
                    double d2 = dist2(p, g->pts + 3 * f);
                    if (!(d2 < r2)) continue;
                    if (n == b->cap && !grow(b)) return -1;
                    Near *slot = b->near + n++;
                    slot->d2 = d2;
                    slot->e = f;
                    slot->j = g->order[f];
                }
            }
            if (n > max_nn) {
                select_smallest(b->near, n, max_nn, b->d2);
                n = max_nn;
            }
            v[0] = v[1] = 0.0;
            v[2] = 1.0;
            if (n < 3) continue;
            double mean[3] = {0.0, 0.0, 0.0};
            for (int64_t k = 0; k < n; k++) {
                const double *x = g->pts + 3 * b->near[k].e;
                mean[0] += x[0];
                mean[1] += x[1];
                mean[2] += x[2];
            }
            for (int d = 0; d < 3; d++) mean[d] /= (double)n;
            double m[6] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
            for (int64_t k = 0; k < n; k++) {
                const double *x = g->pts + 3 * b->near[k].e;
                double dx = x[0] - mean[0], dy = x[1] - mean[1], dz = x[2] - mean[2];
                m[0] += dx * dx;
                m[1] += dx * dy;
                m[2] += dx * dz;
                m[3] += dy * dy;
                m[4] += dy * dz;
                m[5] += dz * dz;
            }
            for (int d = 0; d < 6; d++) m[d] /= (double)n;
            least_axis(m, v);
        }
    }
    return 0;
}

static PyObject *normals(PyObject *self, PyObject *args) {
    Py_buffer Pb, Ob, Sb, Kb, Tb, Db;
    double cell, r2;
    long long lo, hi, max_nn;
    if (!PyArg_ParseTuple(args, GRID_ARGS "LLdLw*", &Pb, &Ob, &Sb, &Kb, &Tb, &cell, &lo, &hi, &r2, &max_nn, &Db))
        return NULL;
    PyObject *result = NULL;
    Grid g;
    int ok = parse_grid(&Pb, &Ob, &Sb, &Kb, &Tb, cell, &g);
    if (!ok || lo < 0 || hi < lo || hi > g.N || Db.len != (hi - lo) * 24 || r2 > cell * cell || max_nn < 1) {
        PyErr_SetString(PyExc_ValueError, ok ? "normals: 0 <= lo <= hi <= N, out (hi - lo, 3) float64, r2 <= cell^2, "
                                               "max_nn >= 1" : GRID_ERR);
        goto done;
    }
    Buffer b = {NULL, NULL, 0};
    int corrupt = 0, nomem = 0;
    Py_BEGIN_ALLOW_THREADS
    nomem = normals_of(&g, lo, hi, r2, max_nn, Db.buf, &b, &corrupt) < 0;
    drop(&b);
    Py_END_ALLOW_THREADS
    result = grid_finish("normals", nomem, corrupt);
done:
    RELEASE_GRID;
    PyBuffer_Release(&Db);
    return result;
}

static PyMethodDef methods[] = {
    {"normals", normals, METH_VARARGS,
     "normals(grid..., lo, hi, r2, max_nn, out): the unit normals (hi - lo, 3) of grid positions lo..hi-1"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_normals", NULL, -1, methods};

PyMODINIT_FUNC PyInit__normals(void) { return PyModule_Create(&module); }
