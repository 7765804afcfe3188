/* Fused K-Planes plane interpolation (bilinear, align_corners=True) + Hadamard product, CPU.
 *
 * Compiled at first use by senerf/fields/ckernel.py with -DREAL=float|double and -DNF=<features per plane>
 * (a compile-time feature count lets the compiler unroll and vectorise the feature loops); called through
 * ctypes on a range [n0, n1) of points so that Python threads can split the work (ctypes drops the GIL).
 *
 * Layout (see interp.py): table (rows, NF) row-major; plane (s, p) of resolution r = res[s] starts at row
 * offs[3 s + p]; texel (a, b) is row b * r + a; planes p = 0 xy, 1 xz, 2 yz.  u (N, 3) in [-1, 1].
 * out (N, S * NF): out[n, s NF + f] = prod_p bilinear_p(f).
 * Backward: gtable[row] += w_corner * gout[n, s NF + f] * prod_{q != p} bilinear_q(f); each caller owns its
 * gtable buffer (no races).  Corner rows of point n + PD are prefetched while point n is processed (the
 * planes are larger than the caches; the gathers are latency bound).
 * Total variation (kp_tv): one pass over a plane's rows, for the loss and, in the backward, the gradient.
 * Feature similarity (kp_feature_cosine, selftrain/reliability.py): plain float32 features whatever REAL and NF.
 */
#include <stdint.h>
#include <math.h>

#ifndef REAL
#define REAL float
#endif
#ifndef NF
#define NF 16
#endif
#define MAXS 8
#define PD 8
#define RING 16

static const int PA[3] = {0, 0, 1};
static const int PB[3] = {1, 2, 2};

typedef struct {
    int64_t row[MAXS][3];
    REAL w[MAXS][3][4];
} Corners;

static inline void corners(const REAL *un, int64_t S, const int64_t *res, const int64_t *offs, Corners *c) {
    for (int64_t s = 0; s < S; ++s) {
        int64_t r = res[s];
        REAL lim = (REAL)(r - 1);
        for (int p = 0; p < 3; ++p) {
            REAL xa = (un[PA[p]] + (REAL)1) * (REAL)0.5 * lim;
            REAL xb = (un[PB[p]] + (REAL)1) * (REAL)0.5 * lim;
            /* written so that NaN maps to 0: never an out-of-range row */
            xa = xa >= 0 ? (xa <= lim ? xa : lim) : 0;
            xb = xb >= 0 ? (xb <= lim ? xb : lim) : 0;
            int64_t ia = (int64_t)xa, ib = (int64_t)xb;   /* >= 0, so truncation == floor */
            if (ia > r - 2) ia = r - 2;
            if (ib > r - 2) ib = r - 2;
            REAL fa = xa - (REAL)ia, fb = xb - (REAL)ib;
            int64_t row = (offs[3 * s + p] + ib * r + ia) * NF;
            c->row[s][p] = row;
            c->w[s][p][0] = (1 - fa) * (1 - fb);
            c->w[s][p][1] = fa * (1 - fb);
            c->w[s][p][2] = (1 - fa) * fb;
            c->w[s][p][3] = fa * fb;
        }
    }
}

static inline void prefetch_rows(const REAL *base, const Corners *c, int64_t S, const int64_t *res, int rw) {
    for (int64_t s = 0; s < S; ++s)
        for (int p = 0; p < 3; ++p) {
            const REAL *t = base + c->row[s][p];
            __builtin_prefetch(t, rw, 1);
            __builtin_prefetch(t + NF, rw, 1);
            __builtin_prefetch(t + res[s] * NF, rw, 1);
            __builtin_prefetch(t + res[s] * NF + NF, rw, 1);
        }
}

static inline void blend(const REAL *restrict table, int64_t row, int64_t r, const REAL *w, REAL *restrict v) {
    const REAL *restrict t00 = table + row, *restrict t01 = t00 + NF, *restrict t10 = t00 + r * NF,
               *restrict t11 = t10 + NF;
    for (int f = 0; f < NF; ++f)
        v[f] = w[0] * t00[f] + w[1] * t01[f] + w[2] * t10[f] + w[3] * t11[f];
}

int kp_nf(void) { return NF; }

/* Point n's corners from the ring, once those of point n + PD are computed into it and their rows of table (and of
   gtable, when given) prefetched. */
static inline const Corners *ring_step(Corners *ring, const REAL *u, int64_t n, int64_t n1, int64_t S,
                                       const int64_t *res, const int64_t *offs, const REAL *table, const REAL *gtable) {
    if (n + PD < n1) {
        Corners *nx = &ring[(n + PD) % RING];
        corners(u + 3 * (n + PD), S, res, offs, nx);
        prefetch_rows(table, nx, S, res, 0);
        if (gtable) prefetch_rows(gtable, nx, S, res, 1);
    }
    return &ring[n % RING];
}

void kp_forward(const REAL *u, const REAL *table, int64_t n0, int64_t n1, int64_t S, const int64_t *res,
                const int64_t *offs, REAL *out) {
    Corners ring[RING];
    for (int64_t k = n0; k < n1 && k < n0 + PD; ++k) corners(u + 3 * k, S, res, offs, &ring[k % RING]);
    for (int64_t n = n0; n < n1; ++n) {
        const Corners *c = ring_step(ring, u, n, n1, S, res, offs, table, 0);
        for (int64_t s = 0; s < S; ++s) {
            REAL *restrict o = out + (n * S + s) * NF;
            REAL v0[NF], v1[NF], v2[NF];
            blend(table, c->row[s][0], res[s], c->w[s][0], v0);
            blend(table, c->row[s][1], res[s], c->w[s][1], v1);
            blend(table, c->row[s][2], res[s], c->w[s][2], v2);
            for (int f = 0; f < NF; ++f) o[f] = v0[f] * v1[f] * v2[f];
        }
    }
}

void kp_backward(const REAL *u, const REAL *table, int64_t n0, int64_t n1, int64_t S, const int64_t *res,
                 const int64_t *offs, const REAL *gout, REAL *gtable) {
    Corners ring[RING];
    for (int64_t k = n0; k < n1 && k < n0 + PD; ++k) corners(u + 3 * k, S, res, offs, &ring[k % RING]);
    for (int64_t n = n0; n < n1; ++n) {
        const Corners *c = ring_step(ring, u, n, n1, S, res, offs, table, gtable);
        for (int64_t s = 0; s < S; ++s) {
            const REAL *restrict g = gout + (n * S + s) * NF;
            int64_t r = res[s];
            REAL feat[3][NF];
            for (int p = 0; p < 3; ++p) blend(table, c->row[s][p], r, c->w[s][p], feat[p]);
            for (int p = 0; p < 3; ++p) {
                const REAL *q1 = feat[(p + 1) % 3], *q2 = feat[(p + 2) % 3];
                const REAL *w = c->w[s][p];
                REAL *restrict g00 = gtable + c->row[s][p], *restrict g01 = g00 + NF,
                     *restrict g10 = g00 + r * NF, *restrict g11 = g10 + NF;
                for (int f = 0; f < NF; ++f) {
                    REAL gp = g[f] * q1[f] * q2[f];
                    g00[f] += w[0] * gp;
                    g01[f] += w[1] * gp;
                    g10[f] += w[2] * gp;
                    g11[f] += w[3] * gp;
                }
            }
        }
    }
}

/* Real spherical harmonics of degree 4 (16 coefficients, tiny-cuda-nn's convention and signs; the same
 * formulas as senerf.fields.encoding.sh_encoding_reference) of unit directions dirs (N, 3) for points
 * [n0, n1), written to out (N, 16) row-major. */
void kp_sh4(const REAL *dirs, int64_t n0, int64_t n1, REAL *out) {
    for (int64_t n = n0; n < n1; ++n) {
        const REAL x = dirs[3 * n], y = dirs[3 * n + 1], z = dirs[3 * n + 2];
        const REAL x2 = x * x, y2 = y * y, z2 = z * z;
        REAL *o = out + 16 * n;
        o[0] = (REAL)0.28209479177387814;
        o[1] = (REAL)-0.48860251190291987 * y;
        o[2] = (REAL)0.48860251190291987 * z;
        o[3] = (REAL)-0.48860251190291987 * x;
        o[4] = (REAL)1.0925484305920792 * x * y;
        o[5] = (REAL)-1.0925484305920792 * y * z;
        o[6] = (REAL)0.94617469575755997 * z2 - (REAL)0.31539156525251999;
        o[7] = (REAL)-1.0925484305920792 * x * z;
        o[8] = (REAL)0.54627421529603959 * (x2 - y2);
        o[9] = (REAL)0.59004358992664352 * y * ((REAL)-3.0 * x2 + y2);
        o[10] = (REAL)2.8906114426405538 * x * y * z;
        o[11] = (REAL)0.45704579946446572 * y * ((REAL)1.0 - (REAL)5.0 * z2);
        o[12] = (REAL)0.3731763325901154 * z * ((REAL)5.0 * z2 - (REAL)3.0);
        o[13] = (REAL)0.45704579946446572 * x * ((REAL)1.0 - (REAL)5.0 * z2);
        o[14] = (REAL)1.4453057213202769 * z * (x2 - y2);
        o[15] = (REAL)0.59004358992664352 * x * (-x2 + (REAL)3.0 * y2);
    }
}

/* Total variation of one r x r plane (rows b of texels (a, b), NF features each), rows [b0, b1): returns the sum of
 * the squared differences to the next texel along a and along b (each difference counted by the texel before it).
 * With grad, also writes grad[b][a] = c * d/dp of that sum / 2 = c * (sum of p - neighbour over its 2-4 neighbours):
 * every texel of the range is written once, by this call alone, so ranges can run on threads without races. */
double kp_tv(const REAL *plane, int64_t r, int64_t b0, int64_t b1, REAL c, REAL *grad) {
    double total = 0.0;
    for (int64_t b = b0; b < b1; ++b) {
        REAL acc[NF];
        for (int f = 0; f < NF; ++f) acc[f] = 0;
        for (int64_t a = 0; a < r; ++a) {
            const REAL *restrict p = plane + (b * r + a) * NF;
            REAL g[NF];
            for (int f = 0; f < NF; ++f) g[f] = 0;
            if (a + 1 < r)
                for (int f = 0; f < NF; ++f) { REAL d = p[NF + f] - p[f]; acc[f] += d * d; g[f] -= d; }
            if (b + 1 < r)
                for (int f = 0; f < NF; ++f) { REAL d = p[r * NF + f] - p[f]; acc[f] += d * d; g[f] -= d; }
            if (!grad) continue;
            if (a > 0)
                for (int f = 0; f < NF; ++f) g[f] += p[f] - p[f - NF];
            if (b > 0)
                for (int f = 0; f < NF; ++f) g[f] += p[f] - p[f - r * NF];
            REAL *restrict out = grad + (b * r + a) * NF;
            for (int f = 0; f < NF; ++f) out[f] = c * g[f];
        }
        for (int f = 0; f < NF; ++f) total += acc[f];
    }
    return total;
}


/* Cosine similarity of pixel features with another view's features sampled bilinearly, fused (no sampled array is
 * made): for pixels n in [n0, n1), a = src[rows[n]] and b = feat bilinearly sampled at uv[n]; out[n] =
 * dot(a, b) / max(|a| |b|, eps).  src (M, C), feat (h, w, C) row-major float32 (whatever REAL is), uv (N, 2) float64
 * (column, row; pixel centres at i + 0.5).  The corners, weights and blend of reliability.py's _bilinear_corners and
 * bilinear_sample_reference, in the same float32 operations and order (b to the bit); the dot product and the
 * squared norms summed in double over FL independent lanes (vectorisable without reordering any sum: the result
 * depends on C alone, never on how the pixels are split over threads). */
#define FL 16

static inline float cosine_corner(double t, int64_t n, int64_t *i0, int64_t *i1) {
    double lim = (double)(n - 1);
    t = t >= 0 ? (t <= lim ? t : lim) : 0;   /* clamped to the image; NaN maps to 0: never an out-of-range row */
    *i0 = (int64_t)t;                         /* >= 0, so truncation == floor */
    *i1 = *i0 + 1 < n ? *i0 + 1 : n - 1;
    return (float)(t - (double)*i0);
}

void kp_feature_cosine(const float *src, const int64_t *rows, const float *feat, int64_t h, int64_t w, int64_t c,
                       const double *uv, int64_t n0, int64_t n1, double eps, float *out) {
    for (int64_t n = n0; n < n1; ++n) {
        int64_t x0, x1, y0, y1;
        const float fx = cosine_corner(uv[2 * n] - 0.5, w, &x0, &x1);
        const float fy = cosine_corner(uv[2 * n + 1] - 0.5, h, &y0, &y1);
        const float gx = 1.0f - fx, gy = 1.0f - fy;
        const float *restrict a = src + rows[n] * c;
        const float *restrict t00 = feat + (y0 * w + x0) * c, *restrict t01 = feat + (y0 * w + x1) * c,
                    *restrict t10 = feat + (y1 * w + x0) * c, *restrict t11 = feat + (y1 * w + x1) * c;
        double ab[FL], aa[FL], bb[FL];
        for (int l = 0; l < FL; ++l) ab[l] = aa[l] = bb[l] = 0.0;
        int64_t k = 0;
        for (; k + FL <= c; k += FL)
            for (int l = 0; l < FL; ++l) {
                const float top = t00[k + l] * gx + t01[k + l] * fx, bottom = t10[k + l] * gx + t11[k + l] * fx;
                const double av = a[k + l], bv = top * gy + bottom * fy;
                ab[l] += av * bv;
                aa[l] += av * av;
                bb[l] += bv * bv;
            }
        for (int l = 0; k < c; ++k, ++l) {
            const float top = t00[k] * gx + t01[k] * fx, bottom = t10[k] * gx + t11[k] * fx;
            const double av = a[k], bv = top * gy + bottom * fy;
            ab[l] += av * bv;
            aa[l] += av * av;
            bb[l] += bv * bv;
        }
        double sab = 0.0, saa = 0.0, sbb = 0.0;
        for (int l = 0; l < FL; ++l) { sab += ab[l]; saa += aa[l]; sbb += bb[l]; }
        const double den = sqrt(saa) * sqrt(sbb);
        out[n] = (float)(sab / (den < eps ? eps : den));   /* a NaN stays NaN, as np.maximum keeps it */
    }
}
