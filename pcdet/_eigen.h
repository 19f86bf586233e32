/* Eigen-decomposition of a small symmetric matrix by cyclic Jacobi sweeps, shared by the kernels that need one
 * (_align.c: Horn's 4 x 4 matrix; _lrf.c: a neighbourhood's 3 x 3 covariance). */
#ifndef PCDET_EIGEN_H
#define PCDET_EIGEN_H
#include <math.h>

/* A (n x n, row-major, symmetric; n <= 4) is overwritten: its diagonal ends as the eigenvalues, in no particular
 * order; V's columns are the eigenvectors (orthonormal to rounding). */
static void jacobi(int n, double *A, double *V) {
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) V[i * n + j] = (i == j);
    for (int sweep = 0; sweep < 64; sweep++) {
        double off = 0, diag = 0;
        for (int p = 0; p < n; p++) {
            diag += A[p * n + p] * A[p * n + p];
            for (int q = p + 1; q < n; q++) off += A[p * n + q] * A[p * n + q];
        }
        if (off == 0 || off < 1e-34 * diag) break; /* off-diagonal below 1e-17 of the diagonal's size */
        for (int p = 0; p < n - 1; p++)
            for (int q = p + 1; q < n; q++) {
                double apq = A[p * n + q];
                if (apq == 0) continue;
                double theta = (A[q * n + q] - A[p * n + p]) / (2 * apq);
                double t = (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1));
                double c = 1 / sqrt(t * t + 1), s = t * c;
                for (int k = 0; k < n; k++) { /* A <- A J, then A <- J^T A, J the rotation in the (p, q) plane */
                    double akp = A[k * n + p], akq = A[k * n + q];
                    A[k * n + p] = c * akp - s * akq;
                    A[k * n + q] = s * akp + c * akq;
                }
                for (int k = 0; k < n; k++) {
                    double apk = A[p * n + k], aqk = A[q * n + k];
                    A[p * n + k] = c * apk - s * aqk;
                    A[q * n + k] = s * apk + c * aqk;
                }
                A[p * n + q] = A[q * n + p] = 0;
                for (int k = 0; k < n; k++) {
                    double vkp = V[k * n + p], vkq = V[k * n + q];
                    V[k * n + p] = c * vkp - s * vkq;
                    V[k * n + q] = s * vkp + c * vkq;
                }
            }
    }
}

#endif
