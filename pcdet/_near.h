/* A point's neighbours on the hashed voxel grid of pcdet.grid (_grid.c describes the layout), shared by the kernels
 * that describe a point by its neighbourhood (_fpfh.c, _normals.c): the points q with a squared distance d2 < r2
 * (summed from left to right, no fused multiply-adds), the point itself among them, and of more than max_nn only the
 * max_nn nearest (ties by the lower index): what open3d's hybrid search returns, but for points at the same distance
 * to the bit, which its KD-tree orders (and, at the max_nn-th, keeps) as its traversal meets them. */
#ifndef PCDET_NEAR_H
#define PCDET_NEAR_H
#include <stdint.h>
#include <stdlib.h>

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
static inline void sort_near(Near *a, int64_t n) {
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
static inline double kth(double *d, int64_t n, int64_t k) {
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
static inline void select_smallest(Near *a, int64_t n, int64_t k, double *scratch) {
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

static inline void drop(Buffer *b) {
    free(b->near);
    free(b->d2);
}

static inline int grow(Buffer *b) {
    int64_t cap = b->cap ? 2 * b->cap : 256;
    Near *near = realloc(b->near, (size_t)cap * sizeof(Near));
    if (near) b->near = near;
    double *d2 = realloc(b->d2, (size_t)cap * sizeof(double));
    if (d2) b->d2 = d2;
    if (!near || !d2) return 0;
    b->cap = cap;
    return 1;
}

/* the neighbours of p (as defined above), into b->near: their number, or -1 when memory runs out; *corrupt
 * set where the hash table is not one table() made */
static inline int64_t neighbours(const Grid *g, const double *p, double r2, int64_t max_nn, Buffer *b, int *corrupt) {
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

#ifdef Py_PYTHON_H
/* the grid of a call's buffers (grid_ok's checks) into g: 0 where they do not make one */
static inline int parse_grid(Py_buffer *Pb, Py_buffer *Ob, Py_buffer *Sb, Py_buffer *Kb, Py_buffer *Tb, double cell, Grid *g) {
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
static inline int valid_indices(const Py_buffer *Wb, int64_t n) {
    if (Wb->len % 8) return 0;
    const int64_t *w = Wb->buf;
    for (int64_t i = 0; i < Wb->len / 8; i++)
        if (w[i] < 0 || w[i] >= n) return 0;
    return 1;
}

#endif

#endif
