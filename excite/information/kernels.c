/* The information's inner loops: JᵀJ of factor blocks accumulated into the band of keyframe
 * blocks, its elimination (block Cholesky, slab by slab for the sweeps), the diagonal of H_θθ,
 * and the world-to-local change of the trajectory states. The math is stated in
 * excite/information/kernels.py and at the call sites; the tests hold it to the dense numpy
 * marginal. */
#include "../core/native.h"
#include <stdlib.h>

/* a pivot below this fraction of its diagonal entry has lost every digit to cancellation */
#define PIVOT_RTOL 1e-12

/* The hot loops in two versions, picked when the module is loaded: for x86-64 with AVX2 (four
 * numbers per instruction) and for any CPU. No fused multiply-add either way (-ffp-contract=off):
 * the same arithmetic, the same results, on every machine. */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__GLIBC__)
#define HOT __attribute__((target_clones("avx2", "default")))
#else
#define HOT
#endif

typedef struct {
    const double *Jx, *Jt;
    const int64_t *cols, *first, *xc;
    Py_ssize_t N, r, nx, c, nxc;
    int64_t stride, ns;
} Block;

typedef struct {
    double *band, *Hxt, *Htt;
    Py_ssize_t D1, n, sd, p; /* band: (D1, n, sd, sd); Hxt: (n, sd, p); Htt: (p, p) */
} Info;

#define BAND(I, d, j) ((I)->band + (((d) * (I)->n + (j)) * (I)->sd * (I)->sd))
#define HXT(I, j) ((I)->Hxt + (j) * (I)->sd * (I)->p)

/* The entries 0..uu of G's row uu, padded to whole 4s (the rows' tails are kept zero). */
static inline Py_ssize_t row_span(Py_ssize_t uu) { return (uu + 4) & ~(Py_ssize_t)3; }

/* Add JᵀJ of factors f0 … f1−1 of a block (see accumulate() in kernels.py). Returns 0, or -1
 * (memory) / -2 (a factor's states wider than the information's). */
HOT static int accumulate(const Block *b, Info *I, Py_ssize_t f0, Py_ssize_t f1, Py_ssize_t origin, int sign,
                          const int64_t *comp) {
    Py_ssize_t r = b->r, nx = b->nx, ns = b->ns, c = b->c, nxc = b->nxc, sd = I->sd, p = I->p;
    Py_ssize_t xd = nx / ns, M = nxc + c, Ms = (M + 3) & ~(Py_ssize_t)3; /* rows of G padded to whole 4s */
    if (xd > sd) return -2;
    int64_t *buf = malloc(sizeof(int64_t) * (7 * (size_t)(nxc + 1) + (size_t)ns));
    double *w = malloc(sizeof(double) * (3 * (size_t)Ms + (size_t)M * Ms + (size_t)c * c + 1));
    if (!buf || !w) {
        free(buf);
        free(w);
        return -1;
    }
    int64_t *gx = buf, *gg = gx + nxc + 1, *gc = gg + nxc + 1, *run_g = gc + nxc + 1, *run_c = run_g + nxc + 1,
            *run_u = run_c + nxc + 1, *run_n = run_u + nxc + 1, *pos = run_n + nxc + 1;
    double *W0 = w, *W1 = W0 + Ms, *W2 = W1 + Ms, *G = W2 + Ms, *T = G + M * Ms;
    Py_ssize_t u = 0;
    for (Py_ssize_t g = 0; g < ns; ++g) {
        Py_ssize_t a = sign > 0 ? g : ns - 1 - g;
        Py_ssize_t u0 = u;
        for (Py_ssize_t t = 0; t < nxc; ++t) {
            if (b->xc[t] / xd == a) {
                int64_t x = b->xc[t], cc = comp[x - xd * a];
                Py_ssize_t i = u;
                while (i > u0 && gc[i - 1] > cc) {
                    gx[i] = gx[i - 1];
                    gc[i] = gc[i - 1];
                    --i;
                }
                gx[i] = x;
                gc[i] = cc;
                gg[u] = g;
                ++u;
            }
        }
    }
    Py_ssize_t n_runs = 0;
    for (Py_ssize_t k = 0; k < nxc; ++k) run_n[k] = 0;
    for (Py_ssize_t k = 0; k < nxc; ++k) {
        if (k == 0 || gg[k] != gg[k - 1] || gc[k] != gc[k - 1] + 1) {
            run_g[n_runs] = gg[k];
            run_c[n_runs] = gc[k];
            run_u[n_runs] = c + k;
            ++n_runs;
        }
        run_n[n_runs - 1] += 1;
    }
    for (Py_ssize_t k = M; k < Ms; ++k) W0[k] = W1[k] = W2[k] = 0.0;
    for (Py_ssize_t k = 0; k < c * c; ++k) T[k] = 0.0;
    for (Py_ssize_t f = f0; f < f1; ++f) {
        for (Py_ssize_t uu = 0; uu < M; ++uu)
            for (Py_ssize_t v = 0; v < row_span(uu); ++v) G[uu * Ms + v] = 0.0;
        const double *Jxf = b->Jx + f * r * nx, *Jtf = b->Jt + f * r * c;
        for (Py_ssize_t row0 = 0; row0 < r; row0 += 3) {
            Py_ssize_t nr = r - row0 < 3 ? r - row0 : 3;
            double *Wk[3] = {W0, W1, W2};
            for (int k = 0; k < 3; ++k) {
                double *wk = Wk[k];
                if (k < nr) {
                    const double *Jr = Jxf + (row0 + k) * nx, *Tr = Jtf + (row0 + k) * c;
                    for (Py_ssize_t v = 0; v < c; ++v) wk[v] = Tr[v];
                    for (Py_ssize_t v = 0; v < nxc; ++v) wk[c + v] = Jr[gx[v]];
                } else {
                    for (Py_ssize_t v = 0; v < Ms; ++v) wk[v] = 0.0;
                }
            }
            if (nr == 3) {
                for (Py_ssize_t uu = 0; uu < M; ++uu) {
                    double a0 = W0[uu], a1 = W1[uu], a2 = W2[uu];
                    if (a0 != 0.0 || a1 != 0.0 || a2 != 0.0) {
                        double *Gu = G + uu * Ms;
                        for (Py_ssize_t v = 0; v < row_span(uu); ++v) Gu[v] += a0 * W0[v] + a1 * W1[v] + a2 * W2[v];
                    }
                }
            } else { /* the last one or two rows: the same sums without the rows of zeros */
                for (Py_ssize_t uu = 0; uu < M; ++uu) {
                    double a0 = W0[uu], a1 = W1[uu];
                    if (a0 != 0.0 || a1 != 0.0) {
                        double *Gu = G + uu * Ms;
                        if (nr == 2)
                            for (Py_ssize_t v = 0; v < row_span(uu); ++v) Gu[v] += a0 * W0[v] + a1 * W1[v];
                        else
                            for (Py_ssize_t v = 0; v < row_span(uu); ++v) Gu[v] += a0 * W0[v];
                    }
                }
            }
        }
        for (Py_ssize_t g = 0; g < ns; ++g) {
            Py_ssize_t a = sign > 0 ? g : ns - 1 - g;
            pos[g] = origin + sign * (b->first[f] + b->stride * a);
        }
        for (Py_ssize_t A = 0; A < n_runs; ++A) {
            Py_ssize_t gA = run_g[A], cA = run_c[A], uA = run_u[A], nA = run_n[A];
            Py_ssize_t iA = pos[gA];
            for (Py_ssize_t B = 0; B <= A; ++B) {
                Py_ssize_t gB = run_g[B], cB = run_c[B], uB = run_u[B], nB = run_n[B];
                Py_ssize_t d = b->stride * (gA - gB);
                double *blk = BAND(I, d, iA - d);
                for (Py_ssize_t k = 0; k < nA; ++k) {
                    const double *Gu = G + (uA + k) * Ms;
                    double *bu = blk + (cA + k) * sd;
                    Py_ssize_t top = B == A ? k + 1 : nB;
                    for (Py_ssize_t v = 0; v < top; ++v) bu[cB + v] += Gu[uB + v];
                }
            }
            for (Py_ssize_t k = 0; k < nA; ++k) {
                const double *Gu = G + (uA + k) * Ms;
                double *Hu = HXT(I, iA) + (cA + k) * p;
                for (Py_ssize_t v = 0; v < c; ++v) Hu[b->cols[v]] += Gu[v];
            }
        }
        for (Py_ssize_t uu = 0; uu < c; ++uu)
            for (Py_ssize_t v = 0; v <= uu; ++v) T[uu * c + v] += G[uu * Ms + v];
    }
    for (Py_ssize_t uu = 0; uu < c; ++uu) {
        for (Py_ssize_t v = 0; v < uu; ++v) {
            I->Htt[b->cols[uu] * p + b->cols[v]] += T[uu * c + v];
            I->Htt[b->cols[v] * p + b->cols[uu]] += T[uu * c + v];
        }
        I->Htt[b->cols[uu] * p + b->cols[uu]] += T[uu * c + uu];
    }
    free(buf);
    free(w);
    return 0;
}

/* x[:top] −= Σ_{k<n} c[k·cs] Z[k, :top] (Z rows zs apart), three rows per pass, skipping zeros */
static inline void subtract_combination(double *x, const double *c, Py_ssize_t cs, const double *Z, Py_ssize_t zs,
                                        Py_ssize_t n, Py_ssize_t top) {
    Py_ssize_t k = 0;
    while (k + 3 <= n) {
        double c0 = c[k * cs], c1 = c[(k + 1) * cs], c2 = c[(k + 2) * cs];
        if (c0 != 0.0 || c1 != 0.0 || c2 != 0.0) {
            const double *z0 = Z + k * zs, *z1 = z0 + zs, *z2 = z1 + zs;
            for (Py_ssize_t e = 0; e < top; ++e) x[e] -= c0 * z0[e] + c1 * z1[e] + c2 * z2[e];
        }
        k += 3;
    }
    for (; k < n; ++k) {
        double ck = c[k * cs];
        const double *zk = Z + k * zs;
        for (Py_ssize_t e = 0; e < top; ++e) x[e] -= ck * zk[e];
    }
}

/* H_ee −= ZT[:, :m] ZT[:, :m]ᵀ (border_update): each entry the sum of its two rows' products in
 * four partial sums (k mod 4, the tail in the first) added as (s0 + s1) + (s2 + s3), a row
 * against four others at once. ACC holds the four partial sums; the same arithmetic in
 * either version. */
typedef double v4d __attribute__((vector_size(32)));
typedef double v2d __attribute__((vector_size(16)));
typedef struct {
    v2d lo, hi;
} v2x2;
#define LOAD(T, p) ({ T v_; memcpy(&v_, (p), sizeof v_); v_; })
#define BORDER_UPDATE(NAME, ACC, ZERO, STEP, LANE0, SUM)                                                         \
    static void NAME(const double *ZT, Py_ssize_t q, Py_ssize_t ld, Py_ssize_t m, double *Hee) {                 \
        Py_ssize_t m4 = m & ~(Py_ssize_t)3;                                                                      \
        for (Py_ssize_t e = 0; e < q; ++e) {                                                                     \
            const double *a = ZT + e * ld;                                                                       \
            Py_ssize_t e2 = 0;                                                                                   \
            for (; e2 + 4 <= e + 1; e2 += 4) {                                                                   \
                const double *b0 = ZT + e2 * ld, *b1 = b0 + ld, *b2 = b1 + ld, *b3 = b2 + ld;                    \
                ACC s0 = ZERO, s1 = ZERO, s2 = ZERO, s3 = ZERO;                                                  \
                for (Py_ssize_t k = 0; k < m4; k += 4) {                                                         \
                    STEP(s0, a + k, b0 + k);                                                                     \
                    STEP(s1, a + k, b1 + k);                                                                     \
                    STEP(s2, a + k, b2 + k);                                                                     \
                    STEP(s3, a + k, b3 + k);                                                                     \
                }                                                                                                \
                for (Py_ssize_t k = m4; k < m; ++k) {                                                            \
                    LANE0(s0) += a[k] * b0[k];                                                                   \
                    LANE0(s1) += a[k] * b1[k];                                                                   \
                    LANE0(s2) += a[k] * b2[k];                                                                   \
                    LANE0(s3) += a[k] * b3[k];                                                                   \
                }                                                                                                \
                Hee[e * q + e2] -= SUM(s0);                                                                      \
                Hee[e * q + e2 + 1] -= SUM(s1);                                                                  \
                Hee[e * q + e2 + 2] -= SUM(s2);                                                                  \
                Hee[e * q + e2 + 3] -= SUM(s3);                                                                  \
            }                                                                                                    \
            for (; e2 <= e; ++e2) {                                                                              \
                const double *b = ZT + e2 * ld;                                                                  \
                ACC s = ZERO;                                                                                    \
                for (Py_ssize_t k = 0; k < m4; k += 4) STEP(s, a + k, b + k);                                    \
                for (Py_ssize_t k = m4; k < m; ++k) LANE0(s) += a[k] * b[k];                                     \
                Hee[e * q + e2] -= SUM(s);                                                                       \
            }                                                                                                    \
        }                                                                                                        \
    }
/* d[:n] = s[:n] (no overlap), four at a time: the copies of a few dozen numbers the elimination makes
 * per state, inline rather than calls of memcpy */
static inline void copy_doubles(double *d, const double *s, Py_ssize_t n) {
    Py_ssize_t i = 0;
    for (; i + 4 <= n; i += 4) {
        v4d v = LOAD(v4d, s + i);
        memcpy(d + i, &v, sizeof v);
    }
    for (; i < n; ++i) d[i] = s[i];
}
#define V2_ZERO ((v2x2){{0.0, 0.0}, {0.0, 0.0}})
#define V2_STEP(s, x, y) ((s).lo += LOAD(v2d, x) * LOAD(v2d, y), (s).hi += LOAD(v2d, (x) + 2) * LOAD(v2d, (y) + 2))
#define V2_LANE0(s) ((s).lo[0])
#define V2_SUM(s) (((s).lo[0] + (s).lo[1]) + ((s).hi[0] + (s).hi[1]))
BORDER_UPDATE(border_update_plain, v2x2, V2_ZERO, V2_STEP, V2_LANE0, V2_SUM)
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__GLIBC__)
#define V4_ZERO ((v4d){0.0, 0.0, 0.0, 0.0})
#define V4_STEP(s, x, y) ((s) += LOAD(v4d, x) * LOAD(v4d, y))
#define V4_LANE0(s) ((s)[0])
#define V4_SUM(s) (((s)[0] + (s)[1]) + ((s)[2] + (s)[3]))
__attribute__((target("avx2"))) BORDER_UPDATE(border_update_avx2, v4d, V4_ZERO, V4_STEP, V4_LANE0, V4_SUM)
static void border_update(const double *ZT, Py_ssize_t q, Py_ssize_t ld, Py_ssize_t m, double *Hee) {
    static int avx2 = -1;
    if (avx2 < 0) avx2 = __builtin_cpu_supports("avx2") ? 1 : 0;
    (avx2 ? border_update_avx2 : border_update_plain)(ZT, q, ld, m, Hee);
}
#else
#define border_update border_update_plain
#endif

/* The numbers eliminate() works in, for states of sd and a border of q. */
static size_t workspace(Py_ssize_t D, Py_ssize_t sd, Py_ssize_t q) {
    return (size_t)(sd * sd + sd + sd * (D * sd + q) + sd * (sd + q) + q * 16 * sd);
}

/* Eliminate the states lo … hi−1 of a block-banded system with a border (block Cholesky); see
 * eliminate() in kernels.py; mem: workspace(D, sd, q) zeros (left as they were found but for the
 * zeros), or NULL; zero: each eliminated state's blocks (band[·, j], Hxe[j]) set to zero once read
 * (a sweep's ring reuses them). Returns -1, the first state whose pivot failed, or -2 (memory). */
HOT static Py_ssize_t eliminate(double *band, Py_ssize_t D, Py_ssize_t n, Py_ssize_t sd, double *Hxe, Py_ssize_t q,
                                double *Hee, Py_ssize_t lo, Py_ssize_t hi, double *work, int zero) {
    Py_ssize_t wz = D * sd + q, zt = 16 * sd, yx = sd + q;
    double *mem = work ? work : calloc(workspace(D, sd, q), sizeof(double));
    if (!mem) return -2;
    double *L = mem, *inv = L + sd * sd, *WZ = inv + sd, *YX = WZ + sd * wz, *ZT = YX + sd * yx;
    double *Zj = WZ + D * sd; /* columns D·sd … of WZ, row stride wz */
    Py_ssize_t fill = 0, bad = -1;
#define BLK(d, j) (band + (((d) * n + (j)) * sd * sd))
    for (Py_ssize_t j = lo; j < hi; ++j) {
        double *A = BLK(0, j);
        for (Py_ssize_t col = 0; col < sd; ++col) { /* L Lᵀ = A */
            for (Py_ssize_t row = col; row < sd; ++row) {
                double s = A[row * sd + col];
                for (Py_ssize_t k = 0; k < col; ++k) s -= L[row * sd + k] * L[col * sd + k];
                if (row == col) {
                    if (!(s > PIVOT_RTOL * A[col * sd + col])) {
                        bad = j;
                        goto done;
                    }
                    L[col * sd + col] = sqrt(s);
                    inv[col] = 1.0 / L[col * sd + col];
                } else {
                    L[row * sd + col] = s * inv[col];
                }
            }
        }
        Py_ssize_t nd = D < n - 1 - j ? D : n - 1 - j;
        for (Py_ssize_t d = 1; d <= D; ++d) {
            double *Wd = WZ + (d - 1) * sd;
            if (d <= nd) {
                const double *B = BLK(d, j);
                for (Py_ssize_t row = 0; row < sd; ++row)
                    for (Py_ssize_t k = 0; k < sd; ++k) Wd[k * wz + row] = B[row * sd + k];
            } else {
                for (Py_ssize_t k = 0; k < sd; ++k)
                    for (Py_ssize_t row = 0; row < sd; ++row) Wd[k * wz + row] = 0.0;
            }
        }
        const double *Hj = Hxe + j * sd * q;
        for (Py_ssize_t k = 0; k < sd; ++k) copy_doubles(Zj + k * wz, Hj + k * q, q);
        /* WZ ← L⁻¹ WZ: C_dᵀ and Z_j in one pass */
        for (Py_ssize_t row = 0; row < sd; ++row) {
            subtract_combination(WZ + row * wz, L + row * sd, 1, WZ, wz, row, wz);
            for (Py_ssize_t e = 0; e < wz; ++e) WZ[row * wz + e] *= inv[row];
        }
        for (Py_ssize_t e = 0; e < q; ++e) { /* H_ee −= Z_jᵀ Z_j, batched over 16 states (ZT's rows written in runs) */
            double *zr = ZT + e * zt + fill;
            for (Py_ssize_t k = 0; k < sd; ++k) zr[k] = Zj[k * wz + e];
        }
        fill += sd;
        if (fill + sd > zt) {
            border_update(ZT, q, zt, fill, Hee);
            fill = 0;
        }
        if (D == 1 && nd == 1) { /* [Y | X] −= C_1 [C_1ᵀ | Z_j], one pass per row */
            double *Y = BLK(0, j + 1), *X = Hxe + (j + 1) * sd * q;
            for (Py_ssize_t row = 0; row < sd; ++row) {
                double *yr = YX + row * yx;
                copy_doubles(yr, Y + row * sd, sd);
                copy_doubles(yr + sd, X + row * q, q);
                subtract_combination(yr, WZ + row, wz, WZ, wz, sd, sd + q);
                copy_doubles(Y + row * sd, yr, row + 1);
                copy_doubles(X + row * q, yr + sd, q);
            }
        } else {
            for (Py_ssize_t d = 1; d <= nd; ++d) {
                double *X = Hxe + (j + d) * sd * q;
                const double *Cd = WZ + (d - 1) * sd;
                for (Py_ssize_t row = 0; row < sd; ++row) subtract_combination(X + row * q, Cd + row, wz, Zj, wz, sd, q);
                for (Py_ssize_t d2 = d; d2 <= nd; ++d2) {
                    double *Y = BLK(d2 - d, j + d);
                    const double *C2 = WZ + (d2 - 1) * sd;
                    for (Py_ssize_t row = 0; row < sd; ++row)
                        subtract_combination(Y + row * sd, C2 + row, wz, Cd, wz, sd, d2 == d ? row + 1 : sd);
                }
            }
        }
        if (zero) { /* state j's blocks are read no more */
            for (Py_ssize_t d = 0; d <= D; ++d) memset(BLK(d, j), 0, sizeof(double) * sd * sd);
            memset(Hxe + j * sd * q, 0, sizeof(double) * sd * q);
        }
    }
    border_update(ZT, q, zt, fill, Hee);
    for (Py_ssize_t e = 0; e < q; ++e)
        for (Py_ssize_t e2 = 0; e2 < e; ++e2) Hee[e2 * q + e] = Hee[e * q + e2];
    for (Py_ssize_t j = hi; j < (hi + D < n ? hi + D : n); ++j) { /* mirror the remaining diagonal blocks */
        double *Y = BLK(0, j);
        for (Py_ssize_t row = 0; row < sd; ++row)
            for (Py_ssize_t col = 0; col < row; ++col) Y[col * sd + row] = Y[row * sd + col];
    }
done:
#undef BLK
    if (!work) free(mem);
    return bad;
}

static int block_of(Args *a, PyObject *t, Block *b) {
    if (!PyTuple_Check(t) || PyTuple_GET_SIZE(t) != 7) {
        PyErr_SetString(PyExc_TypeError, "a block is a tuple (Jx, Jt, cols, first, stride, n_states, xcols)");
        return -1;
    }
    Py_buffer *Jx = native_array(a, PyTuple_GET_ITEM(t, 0), 'd', 3, 0, "Jx");
    Py_buffer *Jt = Jx ? native_array(a, PyTuple_GET_ITEM(t, 1), 'd', 3, 0, "Jt") : NULL;
    Py_buffer *cols = Jt ? native_array(a, PyTuple_GET_ITEM(t, 2), 'q', 1, 0, "cols") : NULL;
    Py_buffer *first = cols ? native_array(a, PyTuple_GET_ITEM(t, 3), 'q', 1, 0, "first") : NULL;
    Py_buffer *xc = first ? native_array(a, PyTuple_GET_ITEM(t, 6), 'q', 1, 0, "xcols") : NULL;
    if (!xc) return -1;
    b->Jx = D(Jx), b->Jt = D(Jt), b->cols = Q(cols), b->first = Q(first), b->xc = Q(xc);
    b->N = SHAPE(Jx, 0), b->r = SHAPE(Jx, 1), b->nx = SHAPE(Jx, 2), b->c = SHAPE(Jt, 2), b->nxc = SHAPE(xc, 0);
    b->stride = native_long(PyTuple_GET_ITEM(t, 4));
    b->ns = native_long(PyTuple_GET_ITEM(t, 5));
    if (PyErr_Occurred()) return -1;
    if (SHAPE(Jt, 0) != b->N || SHAPE(Jt, 1) != b->r || SHAPE(cols, 0) != b->c || SHAPE(first, 0) != b->N ||
        b->ns < 1 || b->nx % b->ns) {
        PyErr_SetString(PyExc_ValueError, "a block's arrays do not agree in shape");
        return -1;
    }
    return 0;
}

static int info_of(Args *a, PyObject *const *args, Info *I) {
    Py_buffer *band = native_array(a, args[0], 'd', 4, 1, "band");
    Py_buffer *Hxt = band ? native_array(a, args[1], 'd', 3, 1, "Hxt") : NULL;
    Py_buffer *Htt = Hxt ? native_array(a, args[2], 'd', 2, 1, "Htt") : NULL;
    if (!Htt) return -1;
    I->band = D(band), I->Hxt = D(Hxt), I->Htt = D(Htt);
    I->D1 = SHAPE(band, 0), I->n = SHAPE(band, 1), I->sd = SHAPE(band, 2), I->p = SHAPE(Htt, 0);
    if (SHAPE(band, 3) != I->sd || SHAPE(Hxt, 0) != I->n || SHAPE(Hxt, 1) != I->sd || SHAPE(Hxt, 2) != I->p ||
        SHAPE(Htt, 1) != I->p) {
        PyErr_SetString(PyExc_ValueError, "band, Hxt and Htt do not agree in shape");
        return -1;
    }
    return 0;
}

static PyObject *fail(Args *a, int code) {
    native_release(a);
    if (code == -1 && !PyErr_Occurred()) PyErr_NoMemory();
    if (code == -2 && !PyErr_Occurred())
        PyErr_SetString(PyExc_ValueError, "a factor's states are wider than the information matrix's");
    return NULL;
}

/* accumulate(Jx, Jt, cols, first, stride, n_states, band, Hxt, Htt, f0, f1, origin, sign, xc, comp) */
NATIVE_FUNCTION(native_accumulate) {
    CHECK_NARGS(15, "accumulate");
    Args a = {.n = 0};
    Block b;
    Info I;
    PyObject *blk = PyTuple_Pack(7, args[0], args[1], args[2], args[3], args[4], args[5], args[13]);
    if (!blk) return NULL;
    int ok = block_of(&a, blk, &b) == 0 && info_of(&a, args + 6, &I) == 0;
    Py_DECREF(blk);
    Py_buffer *comp = ok ? native_array(&a, args[14], 'q', 1, 0, "comp") : NULL;
    if (!comp) return fail(&a, 0);
    if (SHAPE(comp, 0) != I.sd) return fail(&a, -2);
    long f0 = native_long(args[9]), f1 = native_long(args[10]), origin = native_long(args[11]),
         sign = native_long(args[12]);
    if (PyErr_Occurred()) return fail(&a, 0);
    int rc;
    Py_BEGIN_ALLOW_THREADS;
    rc = accumulate(&b, &I, f0, f1, origin, sign > 0 ? 1 : -1, Q(comp));
    Py_END_ALLOW_THREADS;
    if (rc) return fail(&a, rc);
    native_release(&a);
    Py_RETURN_NONE;
}

/* eliminate(band, Hxe, Hee, lo, hi) → -1, or the first state whose pivot failed */
NATIVE_FUNCTION(native_eliminate) {
    CHECK_NARGS(5, "eliminate");
    Args a = {.n = 0};
    Py_buffer *band = native_array(&a, args[0], 'd', 4, 1, "band");
    Py_buffer *Hxe = band ? native_array(&a, args[1], 'd', 3, 1, "Hxe") : NULL;
    Py_buffer *Hee = Hxe ? native_array(&a, args[2], 'd', 2, 1, "Hee") : NULL;
    if (!Hee) return fail(&a, 0);
    long lo = native_long(args[3]), hi = native_long(args[4]);
    if (PyErr_Occurred()) return fail(&a, 0);
    Py_ssize_t D1 = SHAPE(band, 0), n = SHAPE(band, 1), sd = SHAPE(band, 2), q = SHAPE(Hee, 0);
    if (SHAPE(Hxe, 0) != n || SHAPE(Hxe, 1) != sd || SHAPE(Hxe, 2) != q || SHAPE(Hee, 1) != q) {
        PyErr_SetString(PyExc_ValueError, "band, Hxe and Hee do not agree in shape");
        return fail(&a, 0);
    }
    Py_ssize_t bad;
    Py_BEGIN_ALLOW_THREADS;
    bad = eliminate(D(band), D1 - 1, n, sd, D(Hxe), q, D(Hee), lo, hi, NULL, 0);
    Py_END_ALLOW_THREADS;
    if (bad == -2) return fail(&a, -1);
    native_release(&a);
    return PyLong_FromSsize_t(bad);
}

/* eliminate_slabs(blocks, m, slab, forward, band, Hxt, Htt, w2, anchored, comp) → -1 or the
 * keyframe whose pivot failed (see eliminate_slabs() in kernels.py) */
NATIVE_FUNCTION(native_eliminate_slabs) {
    CHECK_NARGS(10, "eliminate_slabs");
    Args a = {.n = 0};
    if (!PyTuple_Check(args[0])) {
        PyErr_SetString(PyExc_TypeError, "blocks: a tuple of blocks is needed");
        return NULL;
    }
    Py_ssize_t nb = PyTuple_GET_SIZE(args[0]);
    Block *blocks = PyMem_Calloc((size_t)nb + 1, sizeof(Block));
    if (!blocks) return PyErr_NoMemory();
    for (Py_ssize_t i = 0; i < nb; ++i)
        if (block_of(&a, PyTuple_GET_ITEM(args[0], i), &blocks[i])) return PyMem_Free(blocks), fail(&a, 0);
    Info I;
    if (info_of(&a, args + 4, &I)) return PyMem_Free(blocks), fail(&a, 0);
    Py_buffer *w2v = native_array(&a, args[7], 'd', 1, 0, "w2");
    Py_buffer *compv = w2v ? native_array(&a, args[9], 'q', 1, 0, "comp") : NULL;
    if (!compv) return PyMem_Free(blocks), fail(&a, 0);
    long m = native_long(args[1]), slab = native_long(args[2]);
    int forward = PyObject_IsTrue(args[3]), anchored = PyObject_IsTrue(args[8]);
    if (PyErr_Occurred()) return PyMem_Free(blocks), fail(&a, 0);
    const double *w2 = D(w2v);
    Py_ssize_t nw = SHAPE(w2v, 0);
    const int64_t *comp = Q(compv);
    Py_ssize_t D = I.D1 - 1, sd = I.sd, result = -1;
    int rc = 0;
    Py_BEGIN_ALLOW_THREADS;
    Py_ssize_t n_slabs = (m + slab - 1) / slab;
    Py_ssize_t *edge = malloc(sizeof(Py_ssize_t) * (n_slabs + 1));
    Py_ssize_t *bounds = malloc(sizeof(Py_ssize_t) * (nb * (n_slabs + 1) + 1));
    double *work = malloc(sizeof(double) * workspace(D, sd, I.p));
    if (!edge || !bounds || !work) {
        rc = -1;
        goto out;
    }
    for (Py_ssize_t i = 0; i < n_slabs; ++i) edge[i] = i * slab;
    edge[n_slabs] = m + 1;
    /* per block, the factors whose first keyframe in the sweep's order is in each slab */
    for (Py_ssize_t bi = 0; bi < nb; ++bi) {
        const Block *b = &blocks[bi];
        Py_ssize_t span = b->stride * (b->ns - 1);
        for (Py_ssize_t i = 0; i <= n_slabs; ++i) {
            /* searchsorted(first, edge, "left") forward; searchsorted(first, m − span − edge, "right") backward */
            int64_t x = forward ? edge[i] : m - span - edge[i];
            Py_ssize_t lo = 0, hi = b->N;
            while (lo < hi) {
                Py_ssize_t mid = lo + (hi - lo) / 2;
                if (forward ? b->first[mid] < x : b->first[mid] <= x)
                    lo = mid + 1;
                else
                    hi = mid;
            }
            bounds[bi * (n_slabs + 1) + i] = lo;
        }
    }
    Py_ssize_t o = sd > 9 ? comp[9] : 9; /* the bias deviations' first stored component */
    for (Py_ssize_t i = 0; i < n_slabs; ++i) {
        Py_ssize_t s = i * slab, hi = s + slab < m ? s + slab : m;
        for (Py_ssize_t bi = 0; bi < nb; ++bi) {
            Py_ssize_t *bd = bounds + bi * (n_slabs + 1);
            Py_ssize_t f0 = forward ? bd[i] : bd[i + 1], f1 = forward ? bd[i + 1] : bd[i];
            if (f1 > f0) {
                rc = accumulate(&blocks[bi], &I, f0, f1, forward ? -s : m - s, forward ? 1 : -1, comp);
                if (rc) goto out;
            }
        }
        if (nw) { /* the bias walk's steps whose first keyframe in the sweep's order is in the slab */
            Py_ssize_t end_i1 = m - edge[i + 1];
            Py_ssize_t n_steps = forward ? hi - s : m - s - (end_i1 > 0 ? end_i1 : 0);
            int cut = anchored && (forward ? hi == m : s == 0);
            Py_ssize_t lo = cut && !forward ? 1 : 0;
            Py_ssize_t n_in = cut && forward ? n_steps - 1 : n_steps;
            Py_ssize_t a0 = forward ? 0 : 1;
            for (Py_ssize_t j = a0; j < n_steps + a0; ++j)
                for (Py_ssize_t c = 0; c < 6; ++c) BAND(&I, 0, j)[(o + c) * sd + o + c] += w2[c];
            for (Py_ssize_t j = 1 - a0 + lo; j < 1 - a0 + n_in; ++j)
                for (Py_ssize_t c = 0; c < 6; ++c) BAND(&I, 0, j)[(o + c) * sd + o + c] += w2[c];
            for (Py_ssize_t j = lo; j < n_in; ++j)
                for (Py_ssize_t c = 0; c < 6; ++c) BAND(&I, 1, j)[(o + c) * sd + o + c] -= w2[c];
        }
        memset(work, 0, sizeof(double) * workspace(D, sd, I.p));
        Py_ssize_t bad = eliminate(I.band, D, I.n, sd, I.Hxt, I.p, I.Htt, 0, hi - s, work, 1);
        if (bad == -2) {
            rc = -1;
            goto out;
        }
        if (bad >= 0) {
            result = forward ? s + bad : m - s - bad;
            goto out;
        }
        if (hi < m) { /* the keyframes the next slab shares move to the ring's front; the slab's own
                       * were zeroed as they were eliminated, the ring past them is untouched */
            Py_ssize_t k = hi - s, bs = sd * sd, hs = sd * I.p, z = k > D ? k : D;
            for (Py_ssize_t d = 0; d <= D; ++d) {
                double *row = I.band + d * I.n * bs;
                memmove(row, row + k * bs, sizeof(double) * D * bs);
                memset(row + z * bs, 0, sizeof(double) * (k + D - z) * bs);
            }
            memmove(I.Hxt, I.Hxt + k * hs, sizeof(double) * D * hs);
            memset(I.Hxt + z * hs, 0, sizeof(double) * (k + D - z) * hs);
        }
    }
out:
    free(edge);
    free(bounds);
    free(work);
    Py_END_ALLOW_THREADS;
    PyMem_Free(blocks);
    if (rc) return fail(&a, rc);
    native_release(&a);
    return PyLong_FromSsize_t(result);
}

/* theta_diagonal(blocks, out): out[cols] += Σ Jt² per column */
NATIVE_FUNCTION(native_theta_diagonal) {
    CHECK_NARGS(2, "theta_diagonal");
    Args a = {.n = 0};
    if (!PyTuple_Check(args[0])) {
        PyErr_SetString(PyExc_TypeError, "blocks: a tuple of blocks is needed");
        return NULL;
    }
    Py_ssize_t nb = PyTuple_GET_SIZE(args[0]);
    Block *blocks = PyMem_Calloc((size_t)nb + 1, sizeof(Block));
    if (!blocks) return PyErr_NoMemory();
    for (Py_ssize_t i = 0; i < nb; ++i)
        if (block_of(&a, PyTuple_GET_ITEM(args[0], i), &blocks[i])) return PyMem_Free(blocks), fail(&a, 0);
    Py_buffer *out = native_array(&a, args[1], 'd', 1, 1, "out");
    if (!out) return PyMem_Free(blocks), fail(&a, 0);
    double *o = D(out);
    int rc = 0;
    Py_BEGIN_ALLOW_THREADS;
    for (Py_ssize_t bi = 0; bi < nb && !rc; ++bi) {
        const Block *b = &blocks[bi];
        double *acc = calloc((size_t)b->c + 1, sizeof(double));
        if (!acc) {
            rc = -1;
            break;
        }
        for (Py_ssize_t f = 0; f < b->N; ++f)
            for (Py_ssize_t k = 0; k < b->r; ++k) {
                const double *row = b->Jt + (f * b->r + k) * b->c;
                for (Py_ssize_t u = 0; u < b->c; ++u) acc[u] += row[u] * row[u];
            }
        for (Py_ssize_t u = 0; u < b->c; ++u) o[b->cols[u]] += acc[u];
        free(acc);
    }
    Py_END_ALLOW_THREADS;
    PyMem_Free(blocks);
    if (rc) return fail(&a, rc);
    native_release(&a);
    Py_RETURN_NONE;
}

/* out (3 × 6) = [−R[x]×, R] */
static inline void skew_map(const double *R, const double *x, double *out) {
    for (int r = 0; r < 3; ++r) {
        const double *Rr = R + 3 * r;
        out[6 * r + 0] = -(Rr[1] * x[2] - Rr[2] * x[1]);
        out[6 * r + 1] = -(Rr[2] * x[0] - Rr[0] * x[2]);
        out[6 * r + 2] = -(Rr[0] * x[1] - Rr[1] * x[0]);
        for (int c = 0; c < 3; ++c) out[6 * r + 3 + c] = Rr[c];
    }
}

/* local_maps(R, v, p, V, P): V_k = [−R_k[v_k]×, R_k] with v_k = R_kᵀ v, P_k = [−R_k[d_k]×, R_k]
 * with d_k = R_kᵀ(p_{k+1} − p_k) (zero for the last keyframe) */
NATIVE_FUNCTION(native_local_maps) {
    CHECK_NARGS(5, "local_maps");
    Args a = {.n = 0};
    Py_buffer *R = native_array(&a, args[0], 'd', 3, 0, "R");
    Py_buffer *v = R ? native_array(&a, args[1], 'd', 2, 0, "v") : NULL;
    Py_buffer *p = v ? native_array(&a, args[2], 'd', 2, 0, "p") : NULL;
    Py_buffer *V = p ? native_array(&a, args[3], 'd', 3, 1, "V") : NULL;
    Py_buffer *P = V ? native_array(&a, args[4], 'd', 3, 1, "P") : NULL;
    if (!P) return fail(&a, 0);
    Py_ssize_t K = SHAPE(R, 0);
    const double *Rk = D(R), *vk = D(v), *pk = D(p);
    double *oV = D(V), *oP = D(P);
    Py_BEGIN_ALLOW_THREADS;
    double x[3], d[3];
    for (Py_ssize_t k = 0; k < K; ++k) {
        const double *Ri = Rk + 9 * k;
        for (int c = 0; c < 3; ++c) x[c] = Ri[c] * vk[3 * k] + Ri[3 + c] * vk[3 * k + 1] + Ri[6 + c] * vk[3 * k + 2];
        skew_map(Ri, x, oV + 18 * k);
        if (k + 1 < K) {
            for (int c = 0; c < 3; ++c) d[c] = pk[3 * (k + 1) + c] - pk[3 * k + c];
            for (int c = 0; c < 3; ++c) x[c] = Ri[c] * d[0] + Ri[3 + c] * d[1] + Ri[6 + c] * d[2];
            skew_map(Ri, x, oP + 18 * k);
        } else {
            memset(oP + 18 * k, 0, sizeof(double) * 18);
        }
    }
    Py_END_ALLOW_THREADS;
    native_release(&a);
    Py_RETURN_NONE;
}

/* to_local(Jx, first, stride, V, P, out, seen, Jt, from, to): world-state Jacobians re-expressed in
 * local states (see to_local() in kernels.py), and columns from[i] of Jt copied into columns to[i]
 * (< sd) of the first state; seen[col] set where a column was written non-zero, and at to[i] */
NATIVE_FUNCTION(native_to_local) {
    CHECK_NARGS(10, "to_local");
    Args a = {.n = 0};
    Py_buffer *Jx = native_array(&a, args[0], 'd', 3, 0, "Jx");
    Py_buffer *first = Jx ? native_array(&a, args[1], 'q', 1, 0, "first") : NULL;
    Py_buffer *V = first ? native_array(&a, args[3], 'd', 3, 0, "V") : NULL;
    Py_buffer *P = V ? native_array(&a, args[4], 'd', 3, 0, "P") : NULL;
    Py_buffer *out = P ? native_array(&a, args[5], 'd', 3, 1, "out") : NULL;
    Py_buffer *seenv = out ? native_array(&a, args[6], 'q', 1, 1, "seen") : NULL;
    Py_buffer *Jtv = seenv ? native_array(&a, args[7], 'd', 3, 0, "Jt") : NULL;
    Py_buffer *fromv = Jtv ? native_array(&a, args[8], 'q', 1, 0, "from") : NULL;
    Py_buffer *tov = fromv ? native_array(&a, args[9], 'q', 1, 0, "to") : NULL;
    if (!tov) return fail(&a, 0);
    long stride = native_long(args[2]);
    if (PyErr_Occurred()) return fail(&a, 0);
    Py_ssize_t N = SHAPE(Jx, 0), r = SHAPE(Jx, 1), nx = SHAPE(Jx, 2), ns = nx / 9, span = stride * (ns - 1);
    Py_ssize_t no = SHAPE(out, 2), sd = no / (span + 1);
    Py_ssize_t nc = SHAPE(fromv, 0), nt = SHAPE(Jtv, 2);
    const int64_t *from = Q(fromv), *to = Q(tov);
    int ok = SHAPE(Jtv, 0) == N && SHAPE(Jtv, 1) == r && SHAPE(tov, 0) == nc;
    for (Py_ssize_t i = 0; ok && i < nc; ++i) ok = from[i] >= 0 && from[i] < nt && to[i] >= 9 && to[i] < sd;
    if (SHAPE(out, 0) != N || SHAPE(out, 1) != r || no != sd * (span + 1) || SHAPE(seenv, 0) != no || sd < 9 || !ok) {
        PyErr_SetString(PyExc_ValueError, "to_local: out, seen, Jt and the columns copied do not fit Jx");
        return fail(&a, 0);
    }
    const double *T0 = D(Jtv);
    const double *J0 = D(Jx), *Vm = D(V), *Pm = D(P);
    const int64_t *fi = Q(first);
    double *O0 = D(out);
    int64_t *seen = Q(seenv);
    int rc = 0;
    Py_BEGIN_ALLOW_THREADS;
    char *flags = calloc((size_t)(2 * ns + span + 1), 1);
    if (!flags) {
        rc = -1;
    } else {
        char *rot_seen = flags, *vel_seen = flags + ns, *inc_seen = flags + 2 * ns;
        for (Py_ssize_t f = 0; f < N; ++f) {
            const double *J = J0 + f * r * nx;
            double *O = O0 + f * r * no;
            memset(O, 0, sizeof(double) * r * no);
            for (Py_ssize_t s = 0; s < ns; ++s) {
                Py_ssize_t k = fi[f] + s * stride, col = sd * s * stride;
                const double *Vk = Vm + 18 * k;
                for (Py_ssize_t row = 0; row < r; ++row) {
                    const double *Jr = J + row * nx + 9 * s;
                    double *Or = O + row * no + col;
                    double r0 = Jr[0], r1 = Jr[1], r2 = Jr[2], j0 = Jr[6], j1 = Jr[7], j2 = Jr[8];
                    if (r0 != 0.0 || r1 != 0.0 || r2 != 0.0) rot_seen[s] = 1;
                    if (j0 != 0.0 || j1 != 0.0 || j2 != 0.0) { /* velocity: δv_world = V_k [δθ_k; δv_k] */
                        vel_seen[s] = 1;
                        for (int c = 0; c < 3; ++c) Or[c] = (c == 0 ? r0 : c == 1 ? r1 : r2) + (j0 * Vk[c] + j1 * Vk[6 + c] + j2 * Vk[12 + c]);
                        for (int c = 3; c < 6; ++c) Or[c] = j0 * Vk[c] + j1 * Vk[6 + c] + j2 * Vk[12 + c];
                    } else {
                        Or[0] = r0, Or[1] = r1, Or[2] = r2;
                    }
                    if (s == 0)
                        for (Py_ssize_t i = 0; i < nc; ++i) Or[to[i]] = T0[(f * r + row) * nt + from[i]];
                }
            }
            for (Py_ssize_t q = 0; q < span; ++q) { /* increment q moves the position of every later state */
                const double *Pk = Pm + 18 * (fi[f] + q);
                for (Py_ssize_t row = 0; row < r; ++row) {
                    const double *Jr = J + row * nx;
                    double j0 = 0.0, j1 = 0.0, j2 = 0.0;
                    for (Py_ssize_t s = 0; s < ns; ++s)
                        if (s * stride > q) {
                            j0 += Jr[9 * s + 3];
                            j1 += Jr[9 * s + 4];
                            j2 += Jr[9 * s + 5];
                        }
                    if (j0 != 0.0 || j1 != 0.0 || j2 != 0.0) {
                        inc_seen[q] = 1;
                        double *Or = O + row * no;
                        for (int c = 0; c < 6; ++c)
                            Or[sd * q + (c < 3 ? c : c + 3)] += j0 * Pk[c] + j1 * Pk[6 + c] + j2 * Pk[12 + c];
                    }
                }
            }
        }
        for (Py_ssize_t s = 0; s < ns; ++s) {
            Py_ssize_t col = sd * s * stride;
            for (int c = 0; c < 3; ++c) {
                seen[col + c] |= rot_seen[s] || vel_seen[s];
                seen[col + 3 + c] |= vel_seen[s];
            }
        }
        for (Py_ssize_t q = 0; q < span; ++q)
            for (int c = 0; c < 3; ++c) {
                seen[sd * q + c] |= inc_seen[q];
                seen[sd * q + 6 + c] |= inc_seen[q];
            }
        for (Py_ssize_t i = 0; i < nc; ++i) seen[to[i]] = 1;
        free(flags);
    }
    Py_END_ALLOW_THREADS;
    if (rc) return fail(&a, rc);
    native_release(&a);
    Py_RETURN_NONE;
}
