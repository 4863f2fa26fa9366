/* Sampling a trajectory's splines: the segment of each time, orientations from the rotation
 * spline, and the IMU's body rate and specific force at the IMU rate
 * (excite/motion/kernels.py states the math; the tests hold it to scipy's RotationSpline). */
#include "../core/native.h"

#define AHEAD 8     /* samples ahead whose spline segments are prefetched (sparse()) */
#define SERIES 1e-2 /* below this rotation angle, series expansions (exact to ~1e-16) */

static inline void cross(double ux, double uy, double uz, double vx, double vy, double vz, double *x, double *y,
                         double *z) {
    *x = uy * vz - uz * vy;
    *y = uz * vx - ux * vz;
    *z = ux * vy - uy * vx;
}

/* sin θ/θ, (1−cos θ)/θ², (θ−sin θ)/θ³ and (b′/θ, c′/θ) of the last two, from t2 = θ². */
static inline void coeffs(double t2, double *a, double *b, double *c, double *eb, double *ec) {
    if (t2 < SERIES * SERIES) {
        *a = 1.0 - t2 * (1.0 / 6.0) + t2 * t2 * (1.0 / 120.0);
        *b = 0.5 - t2 * (1.0 / 24.0) + t2 * t2 * (1.0 / 720.0);
        *c = 1.0 / 6.0 - t2 * (1.0 / 120.0) + t2 * t2 * (1.0 / 5040.0);
        *eb = -1.0 / 12.0 + t2 * (1.0 / 180.0);
        *ec = -1.0 / 60.0 + t2 * (1.0 / 1260.0);
    } else {
        double theta = sqrt(t2), s = sin(theta), co = cos(theta);
        *a = s / theta;
        *b = (1.0 - co) / t2;
        *c = (theta - s) / (t2 * theta);
        *eb = (theta * s - 2.0 * (1.0 - co)) / (t2 * t2);
        *ec = (theta * (1.0 - co) - 3.0 * (theta - s)) / (t2 * t2 * theta);
    }
}

/* PPoly coefficients c: (order, segments, 3), C order. */
static inline void horner(const double *c, Py_ssize_t order, Py_ssize_t nseg, Py_ssize_t k, double tau, double *x,
                          double *y, double *z) {
    double X = 0.0, Y = 0.0, Z = 0.0;
    for (Py_ssize_t m = 0; m < order; ++m) {
        const double *cm = c + (m * nseg + k) * 3;
        X = X * tau + cm[0];
        Y = Y * tau + cm[1];
        Z = Z * tau + cm[2];
    }
    *x = X;
    *y = Y;
    *z = Z;
}

/* value, first and second derivative of the three components of segment k at tau */
static inline void horner2(const double *c, Py_ssize_t order, Py_ssize_t nseg, Py_ssize_t k, double tau, double v[9]) {
    const double *c0 = c + k * 3;
    double px = c0[0], py = c0[1], pz = c0[2];
    double dx = 0.0, dy = 0.0, dz = 0.0, ddx = 0.0, ddy = 0.0, ddz = 0.0; /* half the second derivative */
    for (Py_ssize_t m = 1; m < order; ++m) {
        const double *cm = c + (m * nseg + k) * 3;
        ddx = ddx * tau + dx;
        ddy = ddy * tau + dy;
        ddz = ddz * tau + dz;
        dx = dx * tau + px;
        dy = dy * tau + py;
        dz = dz * tau + pz;
        px = px * tau + cm[0];
        py = py * tau + cm[1];
        pz = pz * tau + cm[2];
    }
    v[0] = px, v[1] = py, v[2] = pz, v[3] = dx, v[4] = dy, v[5] = dz;
    v[6] = 2.0 * ddx, v[7] = 2.0 * ddy, v[8] = 2.0 * ddz;
}

/* R = R_key[k] · Exp(φ(τ)); w, al = the body rate J_r(φ) φ̇ and angular acceleration J_r φ̈ + J̇_r φ̇ */
static inline void rotation_at(const double *c, Py_ssize_t order, Py_ssize_t nseg, Py_ssize_t k, double tau,
                               const double *R_key, double *R, double w[3], double al[3]) {
    double v[9];
    horner2(c, order, nseg, k, tau, v);
    double fx = v[0], fy = v[1], fz = v[2], dx = v[3], dy = v[4], dz = v[5], ddx = v[6], ddy = v[7], ddz = v[8];
    double t2 = fx * fx + fy * fy + fz * fz;
    double a, b, cc, eb, ec;
    coeffs(t2, &a, &b, &cc, &eb, &ec);
    double co = 1.0 - b * t2;
    double e00 = co + b * fx * fx, e01 = b * fx * fy - a * fz, e02 = b * fx * fz + a * fy;
    double e10 = b * fy * fx + a * fz, e11 = co + b * fy * fy, e12 = b * fy * fz - a * fx;
    double e20 = b * fz * fx - a * fy, e21 = b * fz * fy + a * fx, e22 = co + b * fz * fz;
    const double *K = R_key + 9 * k;
    for (int r = 0; r < 3; ++r) {
        double k0 = K[3 * r], k1 = K[3 * r + 1], k2 = K[3 * r + 2];
        R[3 * r + 0] = k0 * e00 + k1 * e10 + k2 * e20;
        R[3 * r + 1] = k0 * e01 + k1 * e11 + k2 * e21;
        R[3 * r + 2] = k0 * e02 + k1 * e12 + k2 * e22;
    }
    double pdx, pdy, pdz, ppx, ppy, ppz, qx, qy, qz, qqx, qqy, qqz, rx, ry, rz;
    cross(fx, fy, fz, dx, dy, dz, &pdx, &pdy, &pdz);
    cross(fx, fy, fz, pdx, pdy, pdz, &ppx, &ppy, &ppz);
    w[0] = dx - b * pdx + cc * ppx;
    w[1] = dy - b * pdy + cc * ppy;
    w[2] = dz - b * pdz + cc * ppz;
    double pd = fx * dx + fy * dy + fz * dz;
    cross(fx, fy, fz, ddx, ddy, ddz, &qx, &qy, &qz);
    cross(fx, fy, fz, qx, qy, qz, &qqx, &qqy, &qqz);
    cross(dx, dy, dz, pdx, pdy, pdz, &rx, &ry, &rz);
    al[0] = ddx - b * qx + cc * qqx - eb * pd * pdx + ec * pd * ppx + cc * rx;
    al[1] = ddy - b * qy + cc * qqy - eb * pd * pdy + ec * pd * ppy + cc * ry;
    al[2] = ddz - b * qz + cc * qqz - eb * pd * pdz + ec * pd * ppz + cc * rz;
}

/* The same, on four samples at once (the hot loop of imu_samples): vectors of one number per sample,
 * each the same arithmetic as above (so the same numbers); what branches per sample (coeffs) runs
 * per sample. */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__GLIBC__)
#define HOT __attribute__((target_clones("avx2", "default")))
#else
#define HOT
#endif
typedef double v4 __attribute__((vector_size(32)));
/* the helpers inlined into each version of the loop (a vector of four is passed differently with
 * and without AVX) */
#define INLINE4 static inline __attribute__((always_inline))
#define AT4(p, i) ((v4){(p)[0][i], (p)[1][i], (p)[2][i], (p)[3][i]}) /* entry i of four rows */

INLINE4 void cross4(v4 ux, v4 uy, v4 uz, v4 vx, v4 vy, v4 vz, v4 *x, v4 *y, v4 *z) {
    *x = uy * vz - uz * vy;
    *y = uz * vx - ux * vz;
    *z = ux * vy - uy * vx;
}

INLINE4 void horner4(const double *c, Py_ssize_t order, Py_ssize_t nseg, const Py_ssize_t k[4], v4 tau, v4 *x,
                           v4 *y, v4 *z) {
    v4 X = {0.0, 0.0, 0.0, 0.0}, Y = X, Z = X;
    for (Py_ssize_t m = 0; m < order; ++m) {
        const double *cm[4];
        for (int l = 0; l < 4; ++l) cm[l] = c + (m * nseg + k[l]) * 3;
        X = X * tau + AT4(cm, 0);
        Y = Y * tau + AT4(cm, 1);
        Z = Z * tau + AT4(cm, 2);
    }
    *x = X;
    *y = Y;
    *z = Z;
}

INLINE4 void horner2_4(const double *c, Py_ssize_t order, Py_ssize_t nseg, const Py_ssize_t k[4], v4 tau,
                             v4 v[9]) {
    const double *c0[4];
    for (int l = 0; l < 4; ++l) c0[l] = c + k[l] * 3;
    v4 px = AT4(c0, 0), py = AT4(c0, 1), pz = AT4(c0, 2);
    v4 dx = {0.0, 0.0, 0.0, 0.0}, dy = dx, dz = dx, ddx = dx, ddy = dx, ddz = dx;
    for (Py_ssize_t m = 1; m < order; ++m) {
        const double *cm[4];
        for (int l = 0; l < 4; ++l) cm[l] = c + (m * nseg + k[l]) * 3;
        ddx = ddx * tau + dx;
        ddy = ddy * tau + dy;
        ddz = ddz * tau + dz;
        dx = dx * tau + px;
        dy = dy * tau + py;
        dz = dz * tau + pz;
        px = px * tau + AT4(cm, 0);
        py = py * tau + AT4(cm, 1);
        pz = pz * tau + AT4(cm, 2);
    }
    v[0] = px, v[1] = py, v[2] = pz, v[3] = dx, v[4] = dy, v[5] = dz;
    v[6] = 2.0 * ddx, v[7] = 2.0 * ddy, v[8] = 2.0 * ddz;
}

INLINE4 void rotation_at4(const double *c, Py_ssize_t order, Py_ssize_t nseg, const Py_ssize_t k[4], v4 tau,
                                const double *R_key, v4 R[9], v4 w[3], v4 al[3]) {
    v4 v[9];
    horner2_4(c, order, nseg, k, tau, v);
    v4 fx = v[0], fy = v[1], fz = v[2], dx = v[3], dy = v[4], dz = v[5], ddx = v[6], ddy = v[7], ddz = v[8];
    v4 t2 = fx * fx + fy * fy + fz * fz;
    double a_[4], b_[4], c_[4], eb_[4], ec_[4];
    for (int l = 0; l < 4; ++l) coeffs(t2[l], &a_[l], &b_[l], &c_[l], &eb_[l], &ec_[l]);
    v4 a, b, cc, eb, ec;
    memcpy(&a, a_, sizeof a), memcpy(&b, b_, sizeof b), memcpy(&cc, c_, sizeof cc);
    memcpy(&eb, eb_, sizeof eb), memcpy(&ec, ec_, sizeof ec);
    v4 co = 1.0 - b * t2;
    v4 e00 = co + b * fx * fx, e01 = b * fx * fy - a * fz, e02 = b * fx * fz + a * fy;
    v4 e10 = b * fy * fx + a * fz, e11 = co + b * fy * fy, e12 = b * fy * fz - a * fx;
    v4 e20 = b * fz * fx - a * fy, e21 = b * fz * fy + a * fx, e22 = co + b * fz * fz;
    const double *K[4];
    for (int l = 0; l < 4; ++l) K[l] = R_key + 9 * k[l];
    for (int r = 0; r < 3; ++r) {
        v4 k0 = AT4(K, 3 * r), k1 = AT4(K, 3 * r + 1), k2 = AT4(K, 3 * r + 2);
        R[3 * r + 0] = k0 * e00 + k1 * e10 + k2 * e20;
        R[3 * r + 1] = k0 * e01 + k1 * e11 + k2 * e21;
        R[3 * r + 2] = k0 * e02 + k1 * e12 + k2 * e22;
    }
    v4 pdx, pdy, pdz, ppx, ppy, ppz, qx, qy, qz, qqx, qqy, qqz, rx, ry, rz;
    cross4(fx, fy, fz, dx, dy, dz, &pdx, &pdy, &pdz);
    cross4(fx, fy, fz, pdx, pdy, pdz, &ppx, &ppy, &ppz);
    w[0] = dx - b * pdx + cc * ppx;
    w[1] = dy - b * pdy + cc * ppy;
    w[2] = dz - b * pdz + cc * ppz;
    v4 pd = fx * dx + fy * dy + fz * dz;
    cross4(fx, fy, fz, ddx, ddy, ddz, &qx, &qy, &qz);
    cross4(fx, fy, fz, qx, qy, qz, &qqx, &qqy, &qqz);
    cross4(dx, dy, dz, pdx, pdy, pdz, &rx, &ry, &rz);
    al[0] = ddx - b * qx + cc * qqx - eb * pd * pdx + ec * pd * ppx + cc * rx;
    al[1] = ddy - b * qy + cc * qqy - eb * pd * pdy + ec * pd * ppy + cc * ry;
    al[2] = ddz - b * qz + cc * qqz - eb * pd * pdz + ec * pd * ppz + cc * rz;
}

/* imu_samples' loop body (see there) for samples i … i + 3 */
HOT static void imu_samples4(Py_ssize_t i, const double *T, const int64_t *sr, const double *xr, const double *cr,
                             Py_ssize_t order, Py_ssize_t nseg, const double *RK, const int64_t *sa, const double *xa,
                             const double *ca, Py_ssize_t order_a, Py_ssize_t nseg_a, const double *g,
                             const double *RVB, const double *p, double *oR, double *ow, double *of) {
    Py_ssize_t k[4], j[4];
    double tr[4], ta[4];
    for (int l = 0; l < 4; ++l) {
        k[l] = sr[i + l], j[l] = sa[i + l];
        tr[l] = T[i + l] - xr[k[l]], ta[l] = T[i + l] - xa[j[l]];
    }
    v4 taur, taua, R[9], w[3], al[3];
    memcpy(&taur, tr, sizeof taur), memcpy(&taua, ta, sizeof taua);
    rotation_at4(cr, order, nseg, k, taur, RK, R, w, al);
    v4 ax, ay, az;
    horner4(ca, order_a, nseg_a, j, taua, &ax, &ay, &az);
    ax -= g[0];
    ay -= g[1];
    az -= g[2];
    v4 px = {p[0], p[0], p[0], p[0]}, py = {p[1], p[1], p[1], p[1]}, pz = {p[2], p[2], p[2], p[2]};
    v4 l1x, l1y, l1z, wpx, wpy, wpz, l2x, l2y, l2z;
    cross4(al[0], al[1], al[2], px, py, pz, &l1x, &l1y, &l1z);
    cross4(w[0], w[1], w[2], px, py, pz, &wpx, &wpy, &wpz);
    cross4(w[0], w[1], w[2], wpx, wpy, wpz, &l2x, &l2y, &l2z);
    v4 fV[3];
    fV[0] = R[0] * ax + R[3] * ay + R[6] * az + l1x + l2x;
    fV[1] = R[1] * ax + R[4] * ay + R[7] * az + l1y + l2y;
    fV[2] = R[2] * ax + R[5] * ay + R[8] * az + l1z + l2z;
    for (int r = 0; r < 3; ++r) {
        for (int q = 0; q < 3; ++q) {
            v4 x = R[3 * r] * RVB[q] + R[3 * r + 1] * RVB[3 + q] + R[3 * r + 2] * RVB[6 + q];
            for (int l = 0; l < 4; ++l) oR[9 * (i + l) + 3 * r + q] = x[l];
        }
        v4 wr = RVB[r] * w[0] + RVB[3 + r] * w[1] + RVB[6 + r] * w[2];
        v4 fr = RVB[r] * fV[0] + RVB[3 + r] * fV[1] + RVB[6 + r] * fV[2];
        for (int l = 0; l < 4; ++l) ow[3 * (i + l) + r] = wr[l], of[3 * (i + l) + r] = fr[l];
    }
}

/* Times much sparser than a spline's segments (a long drive's spline at a coarse rate): each
 * sample's coefficients are a cache miss, so those of the sample AHEAD are fetched early. */
static inline int sparse(const int64_t *seg, Py_ssize_t n) { return n > 1 && seg[n - 1] - seg[0] > 2 * (n - 1); }

static inline void prefetch_segment(const double *c, Py_ssize_t order, Py_ssize_t nseg, Py_ssize_t k, const double *x) {
    for (Py_ssize_t m = 0; m < order; ++m) __builtin_prefetch(c + (m * nseg + k) * 3);
    __builtin_prefetch(x + k);
}

static inline void prefetch_rotation(const double *c, Py_ssize_t order, Py_ssize_t nseg, Py_ssize_t k, const double *x,
                                     const double *R_key) {
    prefetch_segment(c, order, nseg, k, x);
    __builtin_prefetch(R_key + 9 * k);
    __builtin_prefetch(R_key + 9 * k + 8);
}

/* index of the first break > x (numpy's searchsorted side="right") */
static Py_ssize_t upper_bound(const double *breaks, Py_ssize_t n, double x) {
    Py_ssize_t lo = 0, hi = n;
    while (lo < hi) {
        Py_ssize_t mid = lo + (hi - lo) / 2;
        if (breaks[mid] <= x)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* segments(breaks, t, out): out[i] = clip(searchsorted(breaks, t[i], "right") − 1, 0, breaks.size − 2) */
NATIVE_FUNCTION(native_segments) {
    CHECK_NARGS(3, "segments");
    Args a = {.n = 0};
    Py_buffer *br = native_array(&a, args[0], 'd', 1, 0, "breaks");
    Py_buffer *t = br ? native_array(&a, args[1], 'd', 1, 0, "t") : NULL;
    Py_buffer *out = t ? native_array(&a, args[2], 'q', 1, 1, "out") : NULL;
    if (!out || SHAPE(out, 0) != SHAPE(t, 0) || SHAPE(br, 0) < 2) {
        if (out) PyErr_SetString(PyExc_ValueError, "segments: out must match t, and two breaks are needed");
        native_release(&a);
        return NULL;
    }
    const double *B = D(br), *T = D(t);
    int64_t *o = Q(out);
    Py_ssize_t n = SHAPE(t, 0), nb = SHAPE(br, 0), last = nb - 2;
    Py_BEGIN_ALLOW_THREADS;
    Py_ssize_t k = 0;
    for (Py_ssize_t i = 0; i < n; ++i) {
        if (i == 0 || T[i] < T[i - 1]) {
            k = upper_bound(B, nb, T[i]) - 1;
            k = k < 0 ? 0 : (k > last ? last : k);
        }
        while (k < last && B[k + 1] <= T[i]) ++k;
        o[i] = k;
    }
    Py_END_ALLOW_THREADS;
    native_release(&a);
    Py_RETURN_NONE;
}

/* rotation_samples(t, seg, x, c, R_key, R, w, al) */
NATIVE_FUNCTION(native_rotation_samples) {
    CHECK_NARGS(8, "rotation_samples");
    Args a = {.n = 0};
    Py_buffer *t = native_array(&a, args[0], 'd', 1, 0, "t");
    Py_buffer *seg = t ? native_array(&a, args[1], 'q', 1, 0, "seg") : NULL;
    Py_buffer *x = seg ? native_array(&a, args[2], 'd', 1, 0, "x") : NULL;
    Py_buffer *c = x ? native_array(&a, args[3], 'd', 3, 0, "c") : NULL;
    Py_buffer *K = c ? native_array(&a, args[4], 'd', 3, 0, "R_key") : NULL;
    Py_buffer *R = K ? native_array(&a, args[5], 'd', 3, 1, "R") : NULL;
    Py_buffer *w = R ? native_array(&a, args[6], 'd', 2, 1, "w") : NULL;
    Py_buffer *al = w ? native_array(&a, args[7], 'd', 2, 1, "al") : NULL;
    if (!al) {
        native_release(&a);
        return NULL;
    }
    Py_ssize_t n = SHAPE(t, 0), order = SHAPE(c, 0), nseg = SHAPE(c, 1);
    const double *T = D(t), *X = D(x), *C = D(c), *RK = D(K);
    const int64_t *S = Q(seg);
    double *oR = D(R), *ow = D(w), *oa = D(al);
    Py_BEGIN_ALLOW_THREADS;
    int ahead = sparse(S, n);
    for (Py_ssize_t i = 0; i < n; ++i) {
        if (ahead && i + AHEAD < n) prefetch_rotation(C, order, nseg, S[i + AHEAD], X, RK);
        Py_ssize_t k = S[i];
        rotation_at(C, order, nseg, k, T[i] - X[k], RK, oR + 9 * i, ow + 3 * i, oa + 3 * i);
    }
    Py_END_ALLOW_THREADS;
    native_release(&a);
    Py_RETURN_NONE;
}

/* imu_samples(t, seg_rot, x_rot, c_rot, R_key, seg_acc, x_acc, c_acc, gravity, R_V_B, p_V_B, R, w, f):
 * orientation R_W_B, body rate ω_B and specific force f_B of an IMU at (R_V_B, p_V_B) in V */
NATIVE_FUNCTION(native_imu_samples) {
    CHECK_NARGS(14, "imu_samples");
    Args a = {.n = 0};
    static const char *names[14] = {"t", "seg_rot", "x_rot", "c_rot", "R_key", "seg_acc", "x_acc",
                                    "c_acc", "gravity", "R_V_B", "p_V_B", "R", "w", "f"};
    static const char types[14] = {'d', 'q', 'd', 'd', 'd', 'q', 'd', 'd', 'd', 'd', 'd', 'd', 'd', 'd'};
    static const int dims[14] = {1, 1, 1, 3, 3, 1, 1, 3, 1, 2, 1, 3, 2, 2};
    Py_buffer *v[14];
    for (int i = 0; i < 14; ++i) {
        v[i] = native_array(&a, args[i], types[i], dims[i], i >= 11, names[i]);
        if (!v[i]) {
            native_release(&a);
            return NULL;
        }
    }
    Py_ssize_t n = SHAPE(v[0], 0), order = SHAPE(v[3], 0), nseg = SHAPE(v[3], 1);
    Py_ssize_t order_a = SHAPE(v[7], 0), nseg_a = SHAPE(v[7], 1);
    const double *T = D(v[0]), *xr = D(v[2]), *cr = D(v[3]), *RK = D(v[4]), *xa = D(v[6]), *ca = D(v[7]);
    const double *g = D(v[8]), *RVB = D(v[9]), *p = D(v[10]);
    const int64_t *sr = Q(v[1]), *sa = Q(v[5]);
    double *oR = D(v[11]), *ow = D(v[12]), *of = D(v[13]);
    Py_BEGIN_ALLOW_THREADS;
    double R[9], w[3], al[3];
    double px = p[0], py = p[1], pz = p[2];
    int ahead = sparse(sr, n);
    Py_ssize_t i0 = 0;
    for (; i0 + 4 <= n; i0 += 4) {
        for (Py_ssize_t i = i0 + AHEAD; ahead && i < i0 + AHEAD + 4 && i < n; ++i) {
            prefetch_rotation(cr, order, nseg, sr[i], xr, RK);
            prefetch_segment(ca, order_a, nseg_a, sa[i], xa);
        }
        imu_samples4(i0, T, sr, xr, cr, order, nseg, RK, sa, xa, ca, order_a, nseg_a, g, RVB, p, oR, ow, of);
    }
    for (Py_ssize_t i = i0; i < n; ++i) {
        Py_ssize_t k = sr[i];
        rotation_at(cr, order, nseg, k, T[i] - xr[k], RK, R, w, al);
        Py_ssize_t j = sa[i];
        double ax, ay, az;
        horner(ca, order_a, nseg_a, j, T[i] - xa[j], &ax, &ay, &az);
        ax -= g[0];
        ay -= g[1];
        az -= g[2];
        /* specific force at the IMU point, in V: Rᵀ(a − g) + α × p + ω × (ω × p) */
        double l1x, l1y, l1z, wpx, wpy, wpz, l2x, l2y, l2z;
        cross(al[0], al[1], al[2], px, py, pz, &l1x, &l1y, &l1z);
        cross(w[0], w[1], w[2], px, py, pz, &wpx, &wpy, &wpz);
        cross(w[0], w[1], w[2], wpx, wpy, wpz, &l2x, &l2y, &l2z);
        double fV[3];
        fV[0] = R[0] * ax + R[3] * ay + R[6] * az + l1x + l2x;
        fV[1] = R[1] * ax + R[4] * ay + R[7] * az + l1y + l2y;
        fV[2] = R[2] * ax + R[5] * ay + R[8] * az + l1z + l2z;
        double *Ri = oR + 9 * i, *wi = ow + 3 * i, *fi = of + 3 * i;
        for (int r = 0; r < 3; ++r) {
            for (int q = 0; q < 3; ++q)
                Ri[3 * r + q] = R[3 * r] * RVB[q] + R[3 * r + 1] * RVB[3 + q] + R[3 * r + 2] * RVB[6 + q];
            wi[r] = RVB[r] * w[0] + RVB[3 + r] * w[1] + RVB[6 + r] * w[2];
            fi[r] = RVB[r] * fV[0] + RVB[3 + r] * fV[1] + RVB[6 + r] * fV[2];
        }
    }
    Py_END_ALLOW_THREADS;
    native_release(&a);
    Py_RETURN_NONE;
}
