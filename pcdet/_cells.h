/* The hashed voxel grid shared by pcdet's kernels (_grid.c describes the layout): the key of a cell, the hash of a
 * key, the lookup of a cell by its key, and the 27 cells around a query's in the order they are visited. */
#ifndef PCDET_CELLS_H
#define PCDET_CELLS_H
#include <math.h>
#include <stdint.h>

static inline uint64_t mix(uint64_t k) {  /* a 64-bit finaliser (MurmurHash3's): nearby cells spread apart */
    k ^= k >> 33;
    k *= 0xff51afd7ed558ccdULL;
    k ^= k >> 33;
    k *= 0xc4ceb9fe1a85ec53ULL;
    k ^= k >> 33;
    return k;
}

static inline int64_t pack(int64_t x, int64_t y, int64_t z) {
    return ((x + (1 << 20)) << 42) | ((y + (1 << 20)) << 21) | (z + (1 << 20));
}

/* the cell of a key, -1 where there is none, -2 where the table holds what table() cannot have made */
static inline int64_t lookup(const int64_t *table, uint64_t mask, const int64_t *keys, int64_t C, int64_t key) {
    uint64_t h = mix((uint64_t)key) & mask;
    for (uint64_t probes = 0; probes <= mask; probes++, h = (h + 1) & mask) {
        int64_t c = table[h];
        if (c == 0) return -1;
        if (c < 0 || c > C) return -2;
        if (keys[c - 1] == key) return c - 1;
    }
    return -2;  /* no empty slot */
}

/* the 27 neighbouring cells, the query's own first, then those sharing a face, an edge, a corner */
static const int8_t OFFSETS[27][3] = {
    {0, 0, 0}, {-1, 0, 0}, {1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}, {0, 0, 1},
    {-1, -1, 0}, {-1, 1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 0, -1}, {-1, 0, 1}, {1, 0, -1}, {1, 0, 1},
    {0, -1, -1}, {0, -1, 1}, {0, 1, -1}, {0, 1, 1},
    {-1, -1, -1}, {-1, -1, 1}, {-1, 1, -1}, {-1, 1, 1}, {1, -1, -1}, {1, -1, 1}, {1, 1, -1}, {1, 1, 1}};

/* Whether arrays of these byte lengths make a grid (the layout _grid.c describes): N points (pts_len = 24 N), order
 * (N,), C keys (keys_len = 8 C), start (C + 1,) rising from 0 to N, a table of T slots (table_len = 8 T), T a power
 * of two above C, cell > 0; with check_order, every entry of order in 0..N-1 (for calls that index by them). */
static inline int grid_ok(int64_t pts_len, const int64_t *order, int64_t order_len, const int64_t *start,
                          int64_t start_len, int64_t keys_len, int64_t table_len, double cell, int check_order) {
    int64_t N = pts_len / 24, C = keys_len / 8, T = table_len / 8;
    if (pts_len % 24 || order_len != N * 8 || keys_len % 8 || start_len != (C + 1) * 8 || T <= C || (T & (T - 1)) ||
        table_len % 8 || !(cell > 0) || start[0] != 0 || start[C] != N)
        return 0;
    for (int64_t c = 0; c < C; c++)
        if (start[c] >= start[c + 1]) return 0;
    for (int64_t e = 0; check_order && e < N; e++)
        if (order[e] < 0 || order[e] >= N) return 0;
    return 1;
}

static inline double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

static inline void cross3(const double *a, const double *b, double *out) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

/* |p - s|^2, summed from left to right (the kernels are compiled without fused multiply-adds): as the KD-tree
 * sums it */
static inline double dist2(const double *p, const double *s) {
    double a = p[0] - s[0], d2 = a * a;
    a = p[1] - s[1];
    d2 += a * a;
    a = p[2] - s[2];
    d2 += a * a;
    return d2;
}

/* Where p lies: its cell c[3] and, per axis a, the squared gaps from p to the near faces of the neighbouring cells
 * below, its own (0) and above, gap[a][0..2]. 0 where p lies outside every cell a key can name. */
static inline int locate(const double *p, double cell, double inv, int64_t c[3], double gap[3][3]) {
    for (int a = 0; a < 3; a++) {
        double f = floor(p[a] * inv);
        if (!(fabs(f) < (1 << 20))) return 0;
        c[a] = (int64_t)f;
        double o = p[a] - c[a] * cell;
        gap[a][0] = o * o;
        gap[a][1] = 0;
        gap[a][2] = (cell - o) * (cell - o);
    }
    return 1;
}

/* how far at least the neighbouring cell OFFSETS[o] lies from the point whose gaps locate() gave, squared */
static inline double gap_to(const double gap[3][3], int o) {
    return gap[0][OFFSETS[o][0] + 1] + gap[1][OFFSETS[o][1] + 1] + gap[2][OFFSETS[o][2] + 1];
}

/* the key of the neighbouring cell OFFSETS[o] of cell c */
static inline int64_t neighbour_key(const int64_t c[3], int o) {
    return pack(c[0] + OFFSETS[o][0], c[1] + OFFSETS[o][1], c[2] + OFFSETS[o][2]);
}

#ifdef Py_PYTHON_H
/* A call's grid arguments: the buffers Pb (points), Ob (order), Sb (start), Kb (keys), Tb (table), then cell. */
#define GRID_ARGS "y*y*y*y*y*d"
#define RELEASE_GRID                                                                                                 \
    PyBuffer_Release(&Pb);                                                                                           \
    PyBuffer_Release(&Ob);                                                                                           \
    PyBuffer_Release(&Sb);                                                                                           \
    PyBuffer_Release(&Kb);                                                                                           \
    PyBuffer_Release(&Tb)

/* what a call returns after its loop: None, or its failure (memory ran out, a hash table that table() did not
 * make), named after the call */
static PyObject *grid_finish(const char *name, int nomem, int corrupt) {
    if (nomem) return PyErr_NoMemory();
    if (corrupt) return PyErr_Format(PyExc_ValueError, "%s: the hash table was not made by table() from these keys",
                                     name);
    Py_RETURN_NONE;
}
#endif

#endif
