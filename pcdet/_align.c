/* Compiled kernel of pcdet.align (the Python side checks shapes and dtypes and documents both).
 *
 * rigid_from_covariance(H, cs, cd, T): for each of B problems, the rotation R maximising trace(R H) over proper
 * rotations, from the cross-covariance H (3, 3) of centred source and target points (H[i][j] = sum s_i d_j), and
 * T = [R, cd - R cs; 0 0 0 1] (4, 4). H (B, 3, 3), cs and cd (B, 3), T (B, 4, 4), float64, row-major.
 *
 * R comes from the unit quaternion of Horn's 4 x 4 symmetric matrix N(H) (Horn 1987): the eigenvector of its
 * largest eigenvalue, found by cyclic Jacobi rotations. That is the rotation Kabsch's SVD gives (V diag(1, 1,
 * det) U^T), without a reflection; where the largest eigenvalue is repeated (points on a line, or none) any of its
 * rotations is optimal, and the first of the equal eigenvalues is taken. The interpreter lock is released while it
 * works: numpy's batched SVD holds it, so grouping on several threads queued behind it.
 *
 * distinct(T, order, cos_min, near2, limit, kept) -> n: greedily, the entries of ``order`` (int64 indices into T
 * (B, 4, 4) float64) whose pose is not near any kept before it, in order, until ``limit`` are kept; they are
 * written to ``kept`` (int64, room for min(limit, len(order))). Near: (trace(Ra^T Rb) - 1) / 2 > cos_min and
 * |ta - tb|^2 < near2. The lock is released while it works.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>

#include "_eigen.h"

static void rigid(const double *H, const double *cs, const double *cd, double *T) {
    double xx = H[0], xy = H[1], xz = H[2], yx = H[3], yy = H[4], yz = H[5], zx = H[6], zy = H[7], zz = H[8];
    double N[4][4] = {{xx + yy + zz, yz - zy, zx - xz, xy - yx},
                      {yz - zy, xx - yy - zz, xy + yx, zx + xz},
                      {zx - xz, xy + yx, -xx + yy - zz, yz + zy},
                      {xy - yx, zx + xz, yz + zy, -xx - yy + zz}};
    double V[4][4];
    jacobi(4, &N[0][0], &V[0][0]);
    int best = 0;
    for (int i = 1; i < 4; i++)
        if (N[i][i] > N[best][best]) best = i;
    double w = V[0][best], x = V[1][best], y = V[2][best], z = V[3][best];
    double n = sqrt(w * w + x * x + y * y + z * z);
    w /= n, x /= n, y /= n, z /= n;
    double R[9] = {w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y),
                   2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x),
                   2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z};
    for (int i = 0; i < 3; i++) {
        T[4 * i + 0] = R[3 * i + 0];
        T[4 * i + 1] = R[3 * i + 1];
        T[4 * i + 2] = R[3 * i + 2];
        T[4 * i + 3] = cd[i] - (R[3 * i] * cs[0] + R[3 * i + 1] * cs[1] + R[3 * i + 2] * cs[2]);
    }
    T[12] = T[13] = T[14] = 0;
    T[15] = 1;
}

static PyObject *rigid_from_covariance(PyObject *self, PyObject *args) {
    Py_buffer Hb, Sb, Db, Tb;
    if (!PyArg_ParseTuple(args, "y*y*y*w*", &Hb, &Sb, &Db, &Tb)) return NULL;
    PyObject *result = NULL;
    int64_t B = Hb.len / (9 * 8);
    if (Hb.len != B * 9 * 8 || Sb.len != B * 3 * 8 || Db.len != B * 3 * 8 || Tb.len != B * 16 * 8) {
        PyErr_SetString(PyExc_ValueError, "rigid_from_covariance: H (B, 3, 3), cs, cd (B, 3), T (B, 4, 4) float64");
        goto done;
    }
    const double *H = Hb.buf, *cs = Sb.buf, *cd = Db.buf;
    double *T = Tb.buf;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t b = 0; b < B; b++) rigid(H + 9 * b, cs + 3 * b, cd + 3 * b, T + 16 * b);
    Py_END_ALLOW_THREADS
    result = Py_None;
    Py_INCREF(result);
done:
    PyBuffer_Release(&Hb);
    PyBuffer_Release(&Sb);
    PyBuffer_Release(&Db);
    PyBuffer_Release(&Tb);
    return result;
}

static int near_pose(const double *a, const double *b, double cos_min, double near2) {
    double dx = a[3] - b[3], dy = a[7] - b[7], dz = a[11] - b[11];
    if (dx * dx + dy * dy + dz * dz >= near2) return 0;
    double tr = 0; /* trace(Ra^T Rb): the sum of the entries' products, row by row */
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) tr += a[4 * i + j] * b[4 * i + j];
    return (tr - 1) / 2 > cos_min;
}

static PyObject *distinct(PyObject *self, PyObject *args) {
    Py_buffer Tb, Ob, Kb;
    double cos_min, near2;
    Py_ssize_t limit;
    if (!PyArg_ParseTuple(args, "y*y*ddnw*", &Tb, &Ob, &cos_min, &near2, &limit, &Kb)) return NULL;
    PyObject *result = NULL;
    int64_t B = Tb.len / (16 * 8), n = Ob.len / 8;
    int64_t room = n < limit ? n : (int64_t)limit;
    if (Tb.len != B * 16 * 8 || Ob.len != n * 8 || Kb.len < (room > 0 ? room : 0) * 8) {
        PyErr_SetString(PyExc_ValueError, "distinct: T (B, 4, 4) float64, order (n,) int64, kept (min(limit, n),) int64");
        goto done;
    }
    const double *T = Tb.buf;
    const int64_t *order = Ob.buf;
    int64_t *kept = Kb.buf;
    for (int64_t i = 0; i < n; i++)
        if (order[i] < 0 || order[i] >= B) {
            PyErr_SetString(PyExc_IndexError, "distinct: an index of order is outside T");
            goto done;
        }
    int64_t m = 0;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t i = 0; i < n && m < limit; i++) {
        const double *a = T + 16 * order[i];
        int64_t j = 0;
        while (j < m && !near_pose(T + 16 * kept[j], a, cos_min, near2)) j++;
        if (j == m) kept[m++] = order[i];
    }
    Py_END_ALLOW_THREADS
    result = PyLong_FromLongLong(m);
done:
    PyBuffer_Release(&Tb);
    PyBuffer_Release(&Ob);
    PyBuffer_Release(&Kb);
    return result;
}

static PyMethodDef methods[] = {
    {"distinct", distinct, METH_VARARGS,
     "distinct(T, order, cos_min, near2, limit, kept) -> n: the first entries of order whose pose is near no kept one"},
    {"rigid_from_covariance", rigid_from_covariance, METH_VARARGS,
     "rigid_from_covariance(H, cs, cd, T): the proper rotation maximising trace(R H) and its translation, each of B"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_align", NULL, -1, methods};

PyMODINIT_FUNC PyInit__align(void) { return PyModule_Create(&module); }
