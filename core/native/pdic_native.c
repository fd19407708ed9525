/* Compiled kernels of Equation 3 (paper Equations 1 to 3) for core/native_kernels.py.
 *
 * Each function is the loop form of a numpy function in core/ (named in its comment) and does
 * the same floating-point operations in the same order, so its results are identical to the bit:
 * built with -ffp-contract=off (no fused multiply-adds) and without -ffast-math. Arrays are
 * C-contiguous float64 / int64; the caller checks shapes and dtypes. No allocation, no globals:
 * safe to call from several threads at once (ctypes releases the GIL during the call).
 */
#include <math.h>
#include <stdint.h>

#if defined(_WIN32)
#define PDIC_EXPORT __declspec(dllexport)
#else
#define PDIC_EXPORT __attribute__((visibility("default")))
#endif

/* Bumped whenever a signature changes: core/native_kernels.py refuses a library of another version. */
PDIC_EXPORT int64_t pdic_native_version(void) { return 2; }

/* core.zone_grid.ZoneGrid.pairs: every (point, record) with |q - p_k|^2 <= zone_k^2, points in order,
 * each point's cell entries in order. Dense cell table: first (n_cells + 1), else the sorted occupied
 * cells with their entry ranges [start, stop). Writes at most `capacity` pairs; returns how many
 * there are (call again with a larger buffer when that exceeds capacity). */
PDIC_EXPORT int64_t pdic_zone_pairs(const double *q, int64_t m, const double *origin, double cell,
                                    const int64_t *dims, const int64_t *first, const int64_t *cells,
                                    const int64_t *start, const int64_t *stop, int64_t n_cells,
                                    const double *entry_p, const double *entry_zone2,
                                    const int64_t *records, int64_t *rows_out, int64_t *records_out,
                                    int64_t capacity) {
    int64_t count = 0;
    for (int64_t i = 0; i < m; ++i) {
        const double *x = q + 3 * i;
        int64_t c[3];
        int inside = 1;
        for (int j = 0; j < 3; ++j) {
            double v = floor((x[j] - origin[j]) / cell);
            if (!(v >= 0.0 && v < (double)dims[j])) { inside = 0; break; }  /* NaN and inf fall outside */
            c[j] = (int64_t)v;
        }
        if (!inside) continue;
        int64_t key = (c[2] * dims[1] + c[1]) * dims[0] + c[0];
        int64_t lo, hi;
        if (first) {
            lo = first[key];
            hi = first[key + 1];
        } else {
            int64_t a = 0, b = n_cells;  /* searchsorted, side left */
            while (a < b) {
                int64_t mid = a + (b - a) / 2;
                if (cells[mid] < key) a = mid + 1; else b = mid;
            }
            if (a >= n_cells || cells[a] != key) continue;
            lo = start[a];
            hi = stop[a];
        }
        for (int64_t e = lo; e < hi; ++e) {
            const double *y = entry_p + 3 * e;
            double d0 = x[0] - y[0], d1 = x[1] - y[1], d2 = x[2] - y[2];
            double dd = d0 * d0 + d1 * d1 + d2 * d2;
            if (dd <= entry_zone2[e]) {
                if (count < capacity) {
                    rows_out[count] = i;
                    records_out[count] = records[e];
                }
                ++count;
            }
        }
    }
    return count;
}

/* core.ward.ward_weight, core.ward.accepted and |p - p_k|^2 over pairs (rows, rec): Equation 1's
 * weight w, Equation 2 with Ward's in-front test (ok), and the squared distance d2.
 * R_k = R[rec] + R_add (deviation gap-fill's margin / a). */
PDIC_EXPORT void pdic_ward_accept(const double *p, const double *n, const double *p_k, const double *n_k,
                                  const double *R, double R_add, double inv_a, double floor_, double in_front,
                                  const int64_t *rows, const int64_t *rec, int64_t pairs,
                                  double *w_out, uint8_t *ok_out, double *d2_out) {
    for (int64_t i = 0; i < pairs; ++i) {
        const double *x = p + 3 * rows[i], *nx = n + 3 * rows[i];
        const double *y = p_k + 3 * rec[i], *ny = n_k + 3 * rec[i];
        double R_k = R[rec[i]] + R_add;
        double d0 = x[0] - y[0], d1 = x[1] - y[1], d2 = x[2] - y[2];
        double dd = d0 * d0 + d1 * d1 + d2 * d2;
        double cos_ = nx[0] * ny[0] + nx[1] * ny[1] + nx[2] * ny[2];
        cos_ = cos_ < -1.0 ? -1.0 : (cos_ > 1.0 ? 1.0 : cos_);  /* np.clip: NaN stays NaN */
        double den = sqrt(dd) / R_k + sqrt(1.0 - cos_);
        den = den < floor_ ? floor_ : den;  /* np.maximum: NaN stays NaN */
        double w = 1.0 / den;
        double lead = d0 * (nx[0] + ny[0]) + d1 * (nx[1] + ny[1]) + d2 * (nx[2] + ny[2]);
        w_out[i] = w;
        ok_out[i] = (w > inv_a) && !(0.5 * lead < -in_front * R_k);
        d2_out[i] = dd;
    }
}

/* core.interpolation's sums of Equation 3 (core.ward.record_estimate clamped at zero, weighted, added per
 * point in pair order as np.bincount does): num (m, C) += w E_rec, den (m) += w, smallest (m) = min zone.
 * at : (pairs, 3) the points the gradients extrapolate to, or NULL for p[rows]. grad_r / grad_t may be
 * NULL (no gradients); zone may be NULL (no smallest). */
PDIC_EXPORT void pdic_equation3_sums(const double *p, const double *n, const double *at, const double *p_k,
                                     const double *n_k, const double *E_k, const double *grad_r,
                                     const double *grad_t, int64_t channels, const double *zone,
                                     const int64_t *rows, const int64_t *rec, const double *w, int64_t pairs,
                                     double *num, double *den, double *smallest) {
    for (int64_t i = 0; i < pairs; ++i) {
        int64_t r = rows[i], k = rec[i];
        const double *x = at ? at + 3 * i : p + 3 * r, *nx = n + 3 * r;
        const double *y = p_k + 3 * k, *ny = n_k + 3 * k;
        double cr[3] = {ny[1] * nx[2] - ny[2] * nx[1], ny[2] * nx[0] - ny[0] * nx[2], ny[0] * nx[1] - ny[1] * nx[0]};
        double dl[3] = {x[0] - y[0], x[1] - y[1], x[2] - y[2]};
        for (int64_t ch = 0; ch < channels; ++ch) {
            double E = E_k[k * channels + ch];
            if (grad_r) {
                const double *g = grad_r + 3 * (k * channels + ch);
                E += g[0] * cr[0] + g[1] * cr[1] + g[2] * cr[2];
            }
            if (grad_t) {
                const double *g = grad_t + 3 * (k * channels + ch);
                E += g[0] * dl[0] + g[1] * dl[1] + g[2] * dl[2];
            }
            E = E < 0.0 ? 0.0 : E;  /* np.maximum(E, 0): NaN stays NaN */
            num[r * channels + ch] += w[i] * E;
        }
        den[r] += w[i];
        if (zone && zone[k] < smallest[r]) smallest[r] = zone[k];
    }
}

static inline int64_t floor_mod(int64_t a, int64_t n) {
    int64_t r = a % n;
    return r < 0 ? r + n : r;
}

/* core.albedo.sample_texture, bilinear ("Linear") with repeat, over an (H, W, 3) float32 image: the same
 * float32 blend as numpy's (weights rounded to float32 first, bottom and top rows, then between them).
 * uv (n, 2) float64 already free of NaN and inf; out (n, 3) float32. */
PDIC_EXPORT void pdic_bilinear_rgb(const float *pixels, int64_t H, int64_t W, const double *uv, int64_t n,
                                   float *out) {
    for (int64_t k = 0; k < n; ++k) {
        double x = uv[2 * k] * (double)W - 0.5, y = uv[2 * k + 1] * (double)H - 0.5;
        double x0 = floor(x), y0 = floor(y);
        float fx = (float)(x - x0), fy = (float)(y - y0);
        int64_t i0 = floor_mod((int64_t)x0, W), j0 = floor_mod((int64_t)y0, H);
        int64_t i1 = (i0 + 1) % W, j1 = (j0 + 1) % H;
        const float *p00 = pixels + 3 * (j0 * W + i0), *p01 = pixels + 3 * (j0 * W + i1);
        const float *p10 = pixels + 3 * (j1 * W + i0), *p11 = pixels + 3 * (j1 * W + i1);
        float gx = 1.0f - fx, gy = 1.0f - fy;
        for (int c = 0; c < 3; ++c) {
            float bottom = p00[c] * gx;
            bottom += p01[c] * fx;
            float top = p10[c] * gx;
            top += p11[c] * fx;
            bottom *= gy;
            top *= fy;
            out[3 * k + c] = bottom + top;
        }
    }
}
