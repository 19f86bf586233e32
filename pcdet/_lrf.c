/* Compiled kernel of pcdet.lrf.shot_lrf: the SHOT local reference frame (Tombari, Salti, Di Stefano 2010) at each
 * query, from the cloud's points within the support radius, found on the hashed voxel grid of pcdet.grid (_grid.c
 * describes the layout; lrf.py builds the grid with cells a hair wider than the radius, checks dtypes and documents
 * the frame).
 *
 * frames(grid..., Q, r, min_nn, out): out (M, 9) float64, rows x, y, z of the frame at each query Q (M, 3) float64:
 *     over the n points q within r of the query p (_near.h's neighbours, with no cap on their number), the
 *     covariance sum w (q - p)(q - p)^T / sum w with w = r - |q - p|, its eigenvectors of the largest (x) and
 *     smallest (z) eigenvalue (_eigen.h), each turned to where most of the q - p point (where as many point each
 *     way, to where their projections weighted by w lean), and y = z x x. All NaN where n < min_nn or the weights sum to 0.
 *
 * It releases the interpreter lock while it works. Each query's frame depends on nothing else, so calls on parts of
 * the queries from several threads give what one call gives.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "_eigen.h"
#include "_near.h"

/* axis (3,) negated where more of the n offsets d (n, 3) point against it than along it (a zero projection counts
 * on neither side); where as many point each way, where their projections weighted by w (n,) sum below 0 */
static void disambiguate(double *axis, const double *d, const double *w, int64_t n) {
    int64_t lead = 0;
    for (int64_t k = 0; k < n; k++) {
        double pr = dot3(d + 3 * k, axis);
        lead += (pr > 0) - (pr < 0);
    }
    double lean = 0;
    if (lead == 0)
        for (int64_t k = 0; k < n; k++) lean += dot3(d + 3 * k, axis) * w[k];
    if (lead < 0 || lean < 0)
        for (int i = 0; i < 3; i++) axis[i] = -axis[i];
}

/* the frame at p into f (9,): 1, or 0 where it is not valid; n neighbours in b, their offsets written to d (n, 3)
 * and their weights to w (n,) */
static int frame_at(const Grid *g, const double *p, const Buffer *b, int64_t n, double r, int64_t min_nn, double *d,
                    double *w, double *f) {
    if (n < min_nn) return 0;
    double m[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0}, wsum = 0;
    for (int64_t k = 0; k < n; k++) {
        const double *q = g->pts + 3 * b->near[k].e;
        double *o = d + 3 * k;
        o[0] = q[0] - p[0];
        o[1] = q[1] - p[1];
        o[2] = q[2] - p[2];
        w[k] = r - sqrt(b->near[k].d2);
        wsum += w[k];
        for (int i = 0; i < 3; i++)
            for (int j = i; j < 3; j++) m[3 * i + j] += o[i] * o[j] * w[k];
    }
    if (!(wsum > 0)) return 0;
    for (int i = 0; i < 3; i++)
        for (int j = i; j < 3; j++) m[3 * j + i] = (m[3 * i + j] /= wsum);
    double V[9];
    jacobi(3, m, V);
    int hi = 0, lo = 0;
    for (int i = 1; i < 3; i++) {
        if (m[4 * i] > m[4 * hi]) hi = i;
        if (m[4 * i] < m[4 * lo]) lo = i;
    }
    if (hi == lo) lo = (hi + 2) % 3; /* all three equal (at most rounding apart): any two orthogonal axes */
    double x[3] = {V[hi], V[3 + hi], V[6 + hi]}, z[3] = {V[lo], V[3 + lo], V[6 + lo]}, y[3];
    disambiguate(x, d, w, n);
    disambiguate(z, d, w, n);
    cross3(z, x, y);
    for (int i = 0; i < 3; i++) {
        f[i] = x[i];
        f[3 + i] = y[i];
        f[6 + i] = z[i];
    }
    return 1;
}

static PyObject *frames(PyObject *self, PyObject *args) {
    Py_buffer Pb, Ob, Sb, Kb, Tb, Qb, Fb;
    double cell, r;
    long long min_nn;
    if (!PyArg_ParseTuple(args, GRID_ARGS "y*dLw*", &Pb, &Ob, &Sb, &Kb, &Tb, &cell, &Qb, &r, &min_nn, &Fb)) return NULL;
    PyObject *result = NULL;
    Grid g;
    int ok = parse_grid(&Pb, &Ob, &Sb, &Kb, &Tb, cell, &g);
    int64_t M = Qb.len / 24;
    if (!ok || Qb.len % 24 || Fb.len != M * 9 * 8 || !(r > 0) || r * r > cell * cell) {
        PyErr_SetString(PyExc_ValueError, ok ? "frames: Q (M, 3) float64, out (M, 9) float64, 0 < r <= cell" : GRID_ERR);
        goto done;
    }
    const double *Q = Qb.buf;
    double *out = Fb.buf;
    Buffer b = {NULL, NULL, 0};
    double *d = NULL;
    int64_t dcap = 0;
    int corrupt = 0, nomem = 0;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t i = 0; i < M && !nomem; i++) {
        double *f = out + 9 * i;
        int64_t n = neighbours(&g, Q + 3 * i, r * r, INT64_MAX, &b, &corrupt);
        if (n < 0) {
            nomem = 1;
            break;
        }
        if (n > dcap) {
            double *grown = realloc(d, (size_t)n * 4 * sizeof(double)); /* offsets (n, 3), then weights (n,) */
            if (!grown) {
                nomem = 1;
                break;
            }
            d = grown;
            dcap = n;
        }
        if (!frame_at(&g, Q + 3 * i, &b, n, r, min_nn, d, d + 3 * n, f))
            for (int k = 0; k < 9; k++) f[k] = NAN;
    }
    free(d);
    drop(&b);
    Py_END_ALLOW_THREADS
    result = grid_finish("frames", nomem, corrupt);
done:
    RELEASE_GRID;
    PyBuffer_Release(&Qb);
    PyBuffer_Release(&Fb);
    return result;
}

static PyMethodDef methods[] = {
    {"frames", frames, METH_VARARGS,
     "frames(grid..., Q, r, min_nn, out): the SHOT frame (rows x, y, z) at each query, NaN where not valid"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_lrf", NULL, -1, methods};

PyMODINIT_FUNC PyInit__lrf(void) { return PyModule_Create(&module); }
