/* Compiled kernels of Equation 3 (paper Equations 1 to 3) and its records' wall sectors, of the albedo at hits,
 * of pass 3's gathering rays, their hits, their cells' sums and the records' E_k and gradients from them, of point
 * lights' shadow rays and of the lookups' Morton order, for core/native_kernels.py.
 *
 * Each function is the loop form of a numpy function in core/ (named in its comment) and does
 * the same floating-point operations in the same order, so its results are identical to the bit:
 * built with -ffp-contract=off (no fused multiply-adds) and without -ffast-math (pdic_pair_walls, whose
 * angle libm rounds as it does, answers the same but for points within a rounding of an edge). Arrays are
 * C-contiguous, of the types each signature names; the caller checks shapes, dtypes and indices.
 * No globals, and the one allocation (pdic_cell_gradients' scratch) is the call's own: safe to call from several
 * threads at once (ctypes releases the GIL).
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#if defined(_WIN32)
#define PDIC_EXPORT __declspec(dllexport)
#else
#define PDIC_EXPORT __attribute__((visibility("default")))
#endif

/* 2 pi as numpy's 2 * np.pi (M_PI is not in every C library's math.h). */
#define PDIC_TWO_PI 6.283185307179586
/* 4 pi as numpy's 4.0 * np.pi. */
#define PDIC_FOUR_PI 12.566370614359172
/* pi / 4 and pi / 2 as numpy's np.pi / 4.0 and np.pi / 2.0. */
#define PDIC_QUARTER_PI 0.7853981633974483
#define PDIC_HALF_PI 1.5707963267948966

/* Bumped whenever a signature changes: core/native_kernels.py refuses a library of another version. */
PDIC_EXPORT int64_t pdic_native_version(void) { return 14; }

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

/* A whole number of texels as an integer: beyond +-2^62 (a UV of ~1e15 repeats and more) the cast would be
 * undefined in C; numpy's wraps there, so only such UVs read another texel than numpy's. */
static inline int64_t texel_index(double v) {
    const double limit = 4611686018427387904.0;
    return (int64_t)(v < -limit ? -limit : (v > limit ? limit : v));
}

/* One bilinear read of an (H, W, 3) float32 image at (x, y) = uv * (W, H), as numpy's form below. */
static void bilinear_at(const float *pixels, int64_t H, int64_t W, double u, double v, float *out) {
    double x = u * (double)W - 0.5, y = v * (double)H - 0.5;
    double x0 = floor(x), y0 = floor(y);
    float fx = (float)(x - x0), fy = (float)(y - y0);
    int64_t i0 = floor_mod(texel_index(x0), W), j0 = floor_mod(texel_index(y0), H);
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
        out[c] = bottom + top;
    }
}

/* core.albedo.sample_texture, bilinear ("Linear") with repeat, over an (H, W, 3) float32 image: the same
 * float32 blend as numpy's (weights rounded to float32 first, bottom and top rows, then between them).
 * uv (n, 2) float64 already free of NaN and inf; out (n, 3) float32. */
PDIC_EXPORT void pdic_bilinear_rgb(const float *pixels, int64_t H, int64_t W, const double *uv, int64_t n,
                                   float *out) {
    for (int64_t k = 0; k < n; ++k) bilinear_at(pixels, H, W, uv[2 * k], uv[2 * k + 1], out + 3 * k);
}

/* core.albedo.albedo for hits on triangles (h,) at Embree barycentrics (h, 2): the material's base colour,
 * or its texture at the hit's interpolated UV (NaN and inf read as 0; "Closest" or bilinear), clipped to
 * [0, 1]. material (T,) int32, base_color (M, 3) float32, texture_of (M,) int32 (-1: none), uvs (T, 3, 2)
 * float32; per texture its pixels, height, width and whether it is bilinear. out (h, 3) float32. */
PDIC_EXPORT void pdic_albedo(const int32_t *material, const float *base_color, const int32_t *texture_of,
                             const float *uvs, const float *const *pixels, const int64_t *heights,
                             const int64_t *widths, const uint8_t *linear, const int64_t *triangle,
                             const double *barycentric, int64_t hits, float *out) {
    for (int64_t h = 0; h < hits; ++h) {
        int64_t t = triangle[h], m = material[t], k = texture_of[m];
        float *o = out + 3 * h;
        if (k < 0) {
            for (int c = 0; c < 3; ++c) o[c] = base_color[3 * m + c];
            continue;
        }
        double u = barycentric[2 * h], v = barycentric[2 * h + 1], w = (1.0 - u) - v, st[2];
        const float *uv = uvs + 6 * t;
        for (int a = 0; a < 2; ++a) {
            double x = w * (double)uv[a];
            x += u * (double)uv[2 + a];
            x += v * (double)uv[4 + a];
            st[a] = isfinite(x) ? x : 0.0;  /* np.nan_to_num(nan=0, posinf=0, neginf=0) */
        }
        int64_t H = heights[k], W = widths[k];
        if (linear[k]) {
            bilinear_at(pixels[k], H, W, st[0], st[1], o);
        } else {
            int64_t i = floor_mod(texel_index(floor(st[0] * (double)W)), W);
            int64_t j = floor_mod(texel_index(floor(st[1] * (double)H)), H);
            for (int c = 0; c < 3; ++c) o[c] = pixels[k][3 * (j * W + i) + c];
        }
        for (int c = 0; c < 3; ++c) o[c] = o[c] < 0.0f ? 0.0f : (o[c] > 1.0f ? 1.0f : o[c]);
    }
}

/* The phi angle core.hemisphere.Hemisphere.sample_cells draws in each flat cell (record * C + cell) of a
 * hemisphere of `columns` phi columns, at uniform u (n, 2): 2 pi (k + u1) / columns. numpy takes its sine
 * and cosine (a C library's may differ in the last bit), pdic_gathering_rays the rest. */
PDIC_EXPORT void pdic_cell_phi(const int64_t *cells, int64_t n, int64_t C, int64_t columns, const double *u,
                               double *phi_out) {
    for (int64_t i = 0; i < n; ++i) {
        int64_t k = (cells[i] % C) % columns;
        phi_out[i] = (PDIC_TWO_PI * ((double)k + u[2 * i + 1])) / (double)columns;
    }
}

/* core.real_rays.gathering_rays: one real ray per flat cell, drawn in its cell (Hemisphere.sample_cells,
 * with the cell's phi's cosine and sine), turned into world space by its record's frame (t1, t2, n) and
 * leaving from the record's point pushed epsilon off its surface to the ray's side
 * (RayCaster.offset_origins). w_out, d_out, o_out : (n, 3) local direction, world direction, origin. */
PDIC_EXPORT void pdic_gathering_rays(const int64_t *cells, int64_t n, int64_t C, int64_t columns, int64_t rows,
                                     const double *u, const double *cos_phi, const double *sin_phi,
                                     const double *p_k, const double *t1, const double *t2, const double *nrm,
                                     double epsilon, double *w_out, double *d_out, double *o_out) {
    for (int64_t i = 0; i < n; ++i) {
        int64_t rec = cells[i] / C, j = (cells[i] % C) / columns;
        double sin2 = ((double)j + u[2 * i]) / (double)rows;
        double s = sqrt(sin2), c2 = 1.0 - sin2;
        double w[3] = {s * cos_phi[i], s * sin_phi[i], sqrt(c2 < 0.0 ? 0.0 : c2)};
        const double *a = t1 + 3 * rec, *b = t2 + 3 * rec, *z = nrm + 3 * rec, *p = p_k + 3 * rec;
        double d[3];
        for (int c = 0; c < 3; ++c) d[c] = (w[0] * a[c] + w[1] * b[c]) + w[2] * z[c];
        double along = z[0] * d[0] + z[1] * d[1] + z[2] * d[2];
        double side = along < 0.0 ? -1.0 : 1.0;  /* np.sign, 0 -> 1 */
        if (along != along) side = along;        /* np.sign(NaN) is NaN */
        double push = epsilon * side;
        for (int c = 0; c < 3; ++c) {
            w_out[3 * i + c] = w[c];
            d_out[3 * i + c] = d[c];
            o_out[3 * i + c] = p[c] + push * z[c];
        }
    }
}

/* core.sampling._concentric_polar: Shirley and Chiu's concentric map of uniform u (m, 2) to the unit disk, in
 * polar form r and phi (m,). numpy takes phi's cosine and sine (a C library's may differ in the last bit),
 * pdic_cosine_directions the rest. */
PDIC_EXPORT void pdic_concentric_polar(const double *u, int64_t m, double *r_out, double *phi_out) {
    for (int64_t i = 0; i < m; ++i) {
        double a = 2.0 * u[2 * i] - 1.0, b = 2.0 * u[2 * i + 1] - 1.0;
        int first = fabs(a) > fabs(b);
        double phi = first ? PDIC_QUARTER_PI * (b / a) : PDIC_HALF_PI - PDIC_QUARTER_PI * (a / b);
        r_out[i] = first ? a : b;
        phi_out[i] = (a == 0.0 && b == 0.0) ? 0.0 : phi;
    }
}

/* core.sampling.orthonormal_basis: Duff et al.'s tangents t1, t2 of the unit normal n, in numpy's order. */
static inline void duff_tangents(const double *n, double *t1, double *t2) {
    double x = n[0], y = n[1], z = n[2];
    double sign = z >= 0.0 ? 1.0 : -1.0;
    double a = -1.0 / (sign + z);
    double b = (x * y) * a;
    t1[0] = 1.0 + ((sign * x) * x) * a;
    t1[1] = sign * b;
    t1[2] = (-sign) * x;
    t2[0] = b;
    t2[1] = sign + (y * y) * a;
    t2[2] = -y;
}

/* core.sampling.cosine_directions: the cosine-weighted direction (core.sampling.cosine_hemisphere) at the disk
 * point r (cos phi, sin phi) turned into the frame of unit normals n (m, 3) (core.sampling.to_world: Duff et
 * al.'s tangents t1, t2, then (w_x t1 + w_y t2) + w_z n a component at a time). */
PDIC_EXPORT void pdic_cosine_directions(const double *r, const double *cos_phi, const double *sin_phi,
                                        const double *n, int64_t m, double *d_out) {
    for (int64_t i = 0; i < m; ++i) {
        double wx = r[i] * cos_phi[i], wy = r[i] * sin_phi[i];
        double v = 1.0 - (wx * wx + wy * wy);
        double wz = sqrt(v > 0.0 || v != v ? v : 0.0);  /* np.maximum(0.0, v): NaN kept */
        const double *z3 = n + 3 * i;
        double t1[3], t2[3];
        duff_tangents(z3, t1, t2);
        for (int c = 0; c < 3; ++c) d_out[3 * i + c] = (wx * t1[c] + wy * t2[c]) + wz * z3[c];
    }
}

/* core.sampling.pattern_directions: the r local directions w (r, 3) turned into the frame of each unit normal
 * n (m, 3) as core.sampling.to_world does, into d_out (m, r, 3). */
PDIC_EXPORT void pdic_pattern_directions(const double *w, int64_t r, const double *n, int64_t m, double *d_out) {
    for (int64_t i = 0; i < m; ++i) {
        const double *z3 = n + 3 * i;
        double t1[3], t2[3];
        duff_tangents(z3, t1, t2);
        for (int64_t k = 0; k < r; ++k) {
            const double *v = w + 3 * k;
            double *d = d_out + 3 * (i * r + k);
            for (int c = 0; c < 3; ++c) d[c] = (v[0] * t1[c] + v[1] * t2[c]) + v[2] * z3[c];
        }
    }
}

/* core.irradiance_cache._accumulate_numpy (np.unique, then np.bincount per channel): each candidate's Ward
 * weights w and products w E_k (E_k (m, 3)) over its pairs (members (m,)), summed from 0 in the pairs' order, then
 * added to its w_sum and E_sum (float32 when single, else float64; numpy adds in float64 and rounds to the
 * array's type). slot_of (one per candidate, all -1) and touched, w_acc (m,), E_acc (m, 3) are the caller's
 * scratch; slot_of is left all -1. */
PDIC_EXPORT void pdic_accumulate(const int64_t *members, int64_t m, const double *w, const double *E_k,
                                 void *w_sum, void *E_sum, int64_t single, int64_t *slot_of, int64_t *touched,
                                 double *w_acc, double *E_acc) {
    int64_t count = 0;
    for (int64_t i = 0; i < m; ++i) {
        int64_t c = members[i], s = slot_of[c];
        if (s < 0) {
            s = slot_of[c] = count++;
            touched[s] = c;
            w_acc[s] = 0.0;
            E_acc[3 * s] = E_acc[3 * s + 1] = E_acc[3 * s + 2] = 0.0;
        }
        w_acc[s] += w[i];
        for (int e = 0; e < 3; ++e) E_acc[3 * s + e] += w[i] * E_k[3 * i + e];
    }
    for (int64_t s = 0; s < count; ++s) {
        int64_t c = touched[s];
        slot_of[c] = -1;
        if (single) {
            float *ws = (float *)w_sum, *Es = (float *)E_sum;
            ws[c] = (float)((double)ws[c] + w_acc[s]);
            for (int e = 0; e < 3; ++e) Es[3 * c + e] = (float)((double)Es[3 * c + e] + E_acc[3 * s + e]);
        } else {
            double *ws = (double *)w_sum, *Es = (double *)E_sum;
            ws[c] = ws[c] + w_acc[s];
            for (int e = 0; e < 3; ++e) Es[3 * c + e] = Es[3 * c + e] + E_acc[3 * s + e];
        }
    }
}

/* core.real_rays.tally_real_rays: each ray's cell (distinct cells) takes its rotational-gradient axis, a count
 * of 1 and its distance t (inf on a miss) as CellSums.add_real_rays does; the rays that hit (tri >= 0),
 * in order, go to hit_out with their points o + d t in q_out, and their records (cell / C) sum 1 / t and
 * count them in inv_sum and inv_n (B,), zeroed by the caller, in ray order as np.bincount adds.
 * Returns how many hit. */
PDIC_EXPORT int64_t pdic_tally_real_rays(const int64_t *cells, int64_t n, int64_t C, const double *w_local,
                                         const double *t, const int64_t *tri, const double *o, const double *d,
                                         double *rot_sum, double *count, double *r_min, double *inv_sum,
                                         double *inv_n, int64_t *hit_out, double *q_out) {
    int64_t h = 0;
    for (int64_t i = 0; i < n; ++i) {
        int64_t cell = cells[i];
        const double *w = w_local + 3 * i;
        double cos_ = w[2] < 1e-6 ? 1e-6 : w[2];  /* np.maximum: NaN stays NaN */
        if (w[2] != w[2]) cos_ = w[2];
        rot_sum[3 * cell] += -w[1] / cos_;
        rot_sum[3 * cell + 1] += w[0] / cos_;
        count[cell] += 1.0;
        double r = r_min[cell], ti = t[i];
        r_min[cell] = (r != r || r <= ti) ? r : ti;  /* np.minimum: NaN wins */
        if (tri[i] < 0) continue;
        for (int c = 0; c < 3; ++c) q_out[3 * h + c] = o[3 * i + c] + d[3 * i + c] * ti;
        double far = (ti != ti || ti >= 1e-300) ? ti : 1e-300;
        inv_sum[cell / C] += 1.0 / far;
        inv_n[cell / C] += 1.0;
        hit_out[h++] = i;
    }
    return h;
}

/* core.lights.point_light_rays: the shadow rays toward a point light of radius 0 at c from points p with
 * unit shading and geometric normals n_s, n_g (m, 3), as core.lights._point_like and
 * core.rays.RayCaster.transmittance_between make them. Per point that receives light (in front of both
 * normals, lit at a positive weight cos_s / (4 pi d^2)), in order: its index (rows_out), weight, the
 * segment's start pushed epsilon off the surface, unit direction (0 for a zero-length segment), length
 * less epsilon (t_max, at least 0) and whether the length is positive (open_out). Returns how many. */
PDIC_EXPORT int64_t pdic_point_light_rays(const double *p, const double *n_s, const double *n_g, int64_t m,
                                          const double *c, double epsilon, int64_t *rows_out,
                                          double *weight_out, double *start_out, double *dir_out,
                                          double *t_max_out, uint8_t *open_out) {
    int64_t k = 0;
    for (int64_t i = 0; i < m; ++i) {
        const double *x = p + 3 * i, *s = n_s + 3 * i, *g = n_g + 3 * i;
        double delta[3] = {c[0] - x[0], c[1] - x[1], c[2] - x[2]};
        double D = sqrt(delta[0] * delta[0] + delta[1] * delta[1] + delta[2] * delta[2]);
        if (!(D > 0.0 && (g[0] * delta[0] + g[1] * delta[1] + g[2] * delta[2]) > 0.0
              && (s[0] * delta[0] + s[1] * delta[1] + s[2] * delta[2]) > 0.0)) continue;
        double w[3] = {delta[0] / D, delta[1] / D, delta[2] / D};
        double cos_s = s[0] * w[0] + s[1] * w[1] + s[2] * w[2];
        double cos_g = g[0] * w[0] + g[1] * w[1] + g[2] * w[2];
        double weight = cos_s / ((PDIC_FOUR_PI * D) * D);
        if (!(cos_s > 0.0 && cos_g > 0.0 && weight > 0.0)) continue;
        /* The ray toward the light is w (the same unit vector) and leaves in front of n_g (cos_g > 0). */
        double seg[3];
        for (int a = 0; a < 3; ++a) {
            double start = x[a] + epsilon * g[a];
            start_out[3 * k + a] = start;
            seg[a] = c[a] - start;
        }
        double dist = sqrt(seg[0] * seg[0] + seg[1] * seg[1] + seg[2] * seg[2]);
        for (int a = 0; a < 3; ++a) dir_out[3 * k + a] = dist > 0.0 ? seg[a] / dist : 0.0;
        double t_max = dist - epsilon;
        t_max_out[k] = (t_max != t_max || t_max >= 0.0) ? t_max : 0.0;  /* np.maximum(., 0): NaN stays */
        open_out[k] = dist > 0.0;
        rows_out[k] = i;
        weight_out[k] = weight;
        ++k;
    }
    return k;
}

/* core.direct._add_hard_light_numpy: a point light's colour P (3) times each lit point's weight w and
 * transmittance v, P (w v), added to E at its row (rows (k,) distinct, E (n, 3)); with edge_lit and edge_open
 * (or NULL) the same to edge_lit and P w to edge_open. */
PDIC_EXPORT void pdic_add_hard_light(double *E, double *edge_lit, double *edge_open, const int64_t *rows, int64_t k,
                                     const double *P, const double *w, const double *v) {
    for (int64_t i = 0; i < k; ++i) {
        double *e = E + 3 * rows[i];
        double share = w[i] * v[i];
        for (int c = 0; c < 3; ++c) {
            double lit = P[c] * share;
            e[c] = e[c] + lit;
            if (edge_lit) {
                edge_lit[3 * rows[i] + c] = edge_lit[3 * rows[i] + c] + lit;
                edge_open[3 * rows[i] + c] = edge_open[3 * rows[i] + c] + P[c] * w[i];
            }
        }
    }
}

/* a . b of 3-vectors summed left to right, as core.vectors.dots. */
static inline double dot3(const double *a, const double *b) { return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]; }

/* |w| as core.vectors.norms (the squares, then their sum left to right); w scaled to unit length where it is
 * positive, else zeroed (np.divide with where=). */
static inline double normalise3(double *w) {
    double sq[3] = {w[0] * w[0], w[1] * w[1], w[2] * w[2]};
    double d = sqrt((sq[0] + sq[1]) + sq[2]);
    for (int e = 0; e < 3; ++e) w[e] = d > 0.0 ? w[e] / d : 0.0;
    return d;
}

/* core.lights.disk_samples_numpy without a spot mask: samples q (k, m, 3) on the disk (normal n_disk (k, 3)) facing
 * each receiver pk (normals nsk, ngk): weight cos_s cos_l / (4 pi d^2) where ok, ok = d > 0, cos_s > 0, above n_g,
 * cos_l > 0 and a positive weight. Dot products left to right, as core.vectors.dots. */
PDIC_EXPORT void pdic_disk_samples(const double *q, const double *pk, const double *nsk, const double *ngk,
                                   const double *n_disk, int64_t k, int64_t m, double *weight, uint8_t *ok) {
    for (int64_t i = 0; i < k; ++i) {
        const double *x = pk + 3 * i, *s = nsk + 3 * i, *g = ngk + 3 * i, *nd = n_disk + 3 * i;
        for (int64_t j = 0; j < m; ++j) {
            int64_t r = i * m + j;
            const double *y = q + 3 * r;
            double w[3] = {y[0] - x[0], y[1] - x[1], y[2] - x[2]};
            double d = normalise3(w);
            double cos_s = dot3(s, w), cos_l = -dot3(nd, w), cos_g = dot3(g, w);
            int good = d > 0.0 && cos_s > 0.0 && cos_g > 0.0 && cos_l > 0.0;
            double value = good ? (cos_s * cos_l) / ((PDIC_FOUR_PI * d) * d) : 0.0;
            weight[r] = value;
            ok[r] = (uint8_t)(good && value > 0.0);
        }
    }
}

/* core.rays.shadow_segments_numpy without target normals: from points p (normals n) to targets t, each point
 * pushed epsilon along +-n to the side its target lies on (sign of n . toward, 0 read as +1, NaN kept), the unit
 * direction of the pushed segment (0 for a zero-length one), its length less epsilon (at least 0; NaN kept) and
 * whether it has a length. Dot products and lengths summed left to right, as core.vectors.dots and norms. */
PDIC_EXPORT void pdic_shadow_segments(const double *p, const double *n, const double *t, int64_t m, double epsilon,
                                      double *start_out, double *dir_out, double *t_max_out, uint8_t *open_out) {
    for (int64_t i = 0; i < m; ++i) {
        const double *x = p + 3 * i, *nx = n + 3 * i, *y = t + 3 * i;
        double toward[3] = {y[0] - x[0], y[1] - x[1], y[2] - x[2]};
        normalise3(toward);
        double facing = dot3(nx, toward);
        double side = facing > 0.0 ? 1.0 : (facing < 0.0 ? -1.0 : (facing == 0.0 ? 1.0 : facing));
        double push = epsilon * side, seg[3];
        for (int a = 0; a < 3; ++a) {
            double start = x[a] + push * nx[a];
            start_out[3 * i + a] = start;
            seg[a] = y[a] - start;
        }
        double dist = normalise3(seg);
        for (int a = 0; a < 3; ++a) dir_out[3 * i + a] = seg[a];
        double t_max = dist - epsilon;
        t_max_out[i] = (t_max != t_max || t_max >= 0.0) ? t_max : 0.0;  /* np.maximum(., 0): NaN stays */
        open_out[i] = dist > 0.0;
    }
}

/* core.lights.area_facing_numpy: points p in front of an area light (centre c, normal N) with some corner of its
 * rectangle (corners (4, 3)) above both normals n_s, n_g. Dot products left to right, as core.vectors.dots. */
PDIC_EXPORT void pdic_area_facing(const double *p, const double *n_s, const double *n_g, int64_t n, const double *c,
                                  const double *N, const double *corners, uint8_t *facing) {
    for (int64_t i = 0; i < n; ++i) {
        const double *x = p + 3 * i, *s = n_s + 3 * i, *g = n_g + 3 * i;
        double f[3] = {x[0] - c[0], x[1] - c[1], x[2] - c[2]};
        int front = dot3(f, N) > 0.0;
        int above_g = 0, above_s = 0;
        for (int k = 0; k < 4; ++k) {
            double t[3] = {corners[3 * k] - x[0], corners[3 * k + 1] - x[1], corners[3 * k + 2] - x[2]};
            above_g |= dot3(g, t) > 0.0;
            above_s |= dot3(s, t) > 0.0;
        }
        facing[i] = (uint8_t)(front && above_g && above_s);
    }
}

/* core.lights.area_samples_numpy: an area light's samples xy (k, m, 2) in its plane (centre c, normal N toward the
 * receivers, axes U, V; constant area density pdf) seen from points pk with normals nsk, ngk (k, 3). Per sample:
 * target q + lift N, weight cos_s cos_l / (d^2 pdf) where ok, ok = d > 0, cos_s > 0, cos_l > 0 and above n_g.
 * Dot products left to right, as core.vectors.dots; every operation in numpy's order. */
PDIC_EXPORT void pdic_area_samples(const double *xy, const double *pk, const double *nsk, const double *ngk,
                                   int64_t k, int64_t m, const double *c, const double *N, const double *U,
                                   const double *V, double pdf, double lift, double *targets, double *weight,
                                   uint8_t *ok) {
    for (int64_t i = 0; i < k; ++i) {
        const double *x = pk + 3 * i, *s = nsk + 3 * i, *g = ngk + 3 * i;
        for (int64_t j = 0; j < m; ++j) {
            int64_t r = i * m + j;
            double a = xy[2 * r], b = xy[2 * r + 1];
            double q[3], w[3];
            for (int e = 0; e < 3; ++e) {
                q[e] = (c[e] + a * U[e]) + b * V[e];
                w[e] = q[e] - x[e];
            }
            double d = normalise3(w);
            double cos_s = dot3(s, w), cos_l = -dot3(w, N), cos_g = dot3(g, w);
            int good = d > 0.0 && cos_s > 0.0 && cos_l > 0.0 && cos_g > 0.0;
            ok[r] = (uint8_t)good;
            weight[r] = good ? (cos_s * cos_l) / ((d * d) * pdf) : 0.0;
            for (int e = 0; e < 3; ++e) targets[3 * r + e] = q[e] + lift * N[e];
        }
    }
}

static inline double clip01(double v) { return v < 0.0 ? 0.0 : (v > 1.0 ? 1.0 : v); }

#if defined(__GNUC__) || defined(__clang__)
#define PDIC_PREFETCH(address) __builtin_prefetch(address)
#else
#define PDIC_PREFETCH(address) ((void)(address))
#endif

/* Hits whose cells pdic_hit_cells finds before it reads any, and how far ahead it asks for a cell's
 * memory: the grid's E and cell tables (Sponza 16/m: 2.35 M cells, 207 MB) are read at random, and a hit waited
 * for each of its cache misses in turn (Sponza 16/m Final: 163 ns a hit, 113 asking 32 hits ahead;
 * 155-175 and 73-82 ns on one thread alone, no other thread sharing the memory bus). Two misses a hit
 * since a cell's centroid, albedo and openness share a line (PdicCell): 75-80 -> 40-47 ns in a bake. */
#define PDIC_HIT_BLOCK 1024
#define PDIC_HIT_AHEAD 32

/* core.hit_radiance.HitGrid.lookup's cell of a hit on triangle t at Embree barycentric b, and the side
 * met by a ray along d (real_rays.side_met: back = the side the face normal f points away from). */
static inline int64_t grid_cell(const double *b, const double *f, const double *d, int64_t L, int64_t first,
                                uint8_t *back) {
    *back = (uint8_t)((f[0] * d[0] + f[1] * d[1] + f[2] * d[2]) > 0.0);
    double x = clip01(b[0]) * (double)L, y = clip01(b[1]) * (double)L;
    double fi = floor(x), fj = floor(y), top = (double)(L - 1);
    fi = fi < 0.0 ? 0.0 : (fi > top ? top : fi);
    fj = fj < 0.0 ? 0.0 : (fj > top ? top : fj);
    int64_t i = (int64_t)fi, j = (int64_t)fj;
    if (i > L - 1 - j) i = L - 1 - j;
    int64_t upper = ((x - (double)i) + (y - (double)j) > 1.0) && (i < L - 1 - j);
    return first + j * (2 * L - j) + 2 * i + upper;
}

/* A row of core.hit_radiance.HitGrid.cells (its dtype CELL): a cell's centroid, mean albedo and openness on the
 * side the face normal points to [0] and the other [1], one 64-byte cache line. */
typedef struct {
    double centroid[3];
    float albedo[3];
    uint8_t open[2];
    uint8_t unused[26];
} PdicCell;

/* Ask for the two lines a hit reads: its cell's E on the side met, and the cell's row. */
static inline void prefetch_cell(const float *E, const PdicCell *cells, int64_t V, int64_t back, int64_t cell) {
    PDIC_PREFETCH(E + 3 * (back * V + cell));
    PDIC_PREFETCH(cells + cell);
}

/* core.real_rays.hit_cells: for gathering hits on triangles (h,) at Embree barycentrics (h, 2), met by
 * rays `direction` (h, 3) at q (h, 3), `distance` (h,) from their record: the side met (real_rays.side_met:
 * back, n_hit), the hit grid's cell there (core.hit_radiance.HitGrid.lookup: E (2, V, 3) float32 per side and
 * the cells' table `cells` (V,), whose albedo and openness count where has_albedo and has_open), whether the hit
 * is near its cell's centroid (real_rays._near_cell) and, given the hits' record normals n_record (h, 3), whether
 * it lies in a gap (gap-gathering; corner-gathering when corner_reach > 0), as real_rays.radiance_at_hits tests.
 * Finite barycentrics only. Outputs (h, 3) float64: E_out, centroid_out, rho_out (with albedo), n_out;
 * (h,) uint8: open_out, near_out, gap_out. */
PDIC_EXPORT void pdic_hit_cells(const int64_t *triangle, const double *barycentric, const double *direction,
                                const double *q, const double *distance, int64_t h, const double *face_normals,
                                const int64_t *side, const int64_t *offset, int64_t V, const float *E,
                                const PdicCell *cells, int64_t has_albedo, int64_t has_open, double near_factor,
                                const double *n_record, double gap_reach, double gap_cos, double corner_reach,
                                double corner_height, double *E_out, double *centroid_out, double *rho_out,
                                double *n_out, uint8_t *open_out, uint8_t *near_out, uint8_t *gap_out) {
    int64_t found[PDIC_HIT_BLOCK];
    uint8_t backs[PDIC_HIT_BLOCK];
    for (int64_t begin = 0; begin < h; begin += PDIC_HIT_BLOCK) {
        int64_t n = h - begin < PDIC_HIT_BLOCK ? h - begin : PDIC_HIT_BLOCK;
        for (int64_t b = 0; b < n; ++b) {
            int64_t k = begin + b, t = triangle[k];
            found[b] = grid_cell(barycentric + 2 * k, face_normals + 3 * t, direction + 3 * k, side[t], offset[t],
                                 backs + b);
            if (b < PDIC_HIT_AHEAD) prefetch_cell(E, cells, V, backs[b], found[b]);
        }
        for (int64_t b = 0; b < n; ++b) {
            int64_t later = b + PDIC_HIT_AHEAD;
            if (later < n) prefetch_cell(E, cells, V, backs[later], found[later]);
            int64_t k = begin + b, t = triangle[k];
            const double *f = face_normals + 3 * t, *d = direction + 3 * k;
            int64_t back = backs[b], at = back * V + found[b];
            const PdicCell *cell = cells + found[b];
            double nh[3];
            for (int c = 0; c < 3; ++c) nh[c] = back ? -f[c] : f[c];
            double o[3];
            for (int c = 0; c < 3; ++c) {
                E_out[3 * k + c] = (double)E[3 * at + c];
                centroid_out[3 * k + c] = cell->centroid[c];
                n_out[3 * k + c] = nh[c];
                if (has_albedo) rho_out[3 * k + c] = (double)cell->albedo[c];
                o[c] = q[3 * k + c] - cell->centroid[c];
            }
            double reach = near_factor * distance[k];
            int near = (o[0] * o[0] + o[1] * o[1] + o[2] * o[2]) > reach * reach;
            int gap = 0;
            if (n_record) {
                const double *r = n_record + 3 * k;
                gap = (near || distance[k] < gap_reach) && ((nh[0] * r[0] + nh[1] * r[1] + nh[2] * r[2]) < -gap_cos);
                if (corner_reach > 0.0) {
                    double height = distance[k] * (d[0] * r[0] + d[1] * r[1] + d[2] * r[2]);
                    gap = gap || ((distance[k] < corner_reach) && (height < corner_height));
                }
            }
            open_out[k] = has_open ? (uint8_t)(cell->open[back] != 0) : 0;
            near_out[k] = (uint8_t)near;
            gap_out[k] = (uint8_t)gap;
        }
    }
}

/* sizeof(PdicCell), which core/native_kernels.py compares with HitGrid's row when it loads the library. */
PDIC_EXPORT int64_t pdic_cell_bytes(void) { return (int64_t)sizeof(PdicCell); }

/* The far end of a sector polygon's side past a ray that met nothing (record_walls._Sector.beyond): the ray's
 * wall t, else `far`, shortened by the wall margin, kept off zero. */
static inline double wall_end(double t, double far, double margin_keep, double tiny) {
    double v = (isfinite(t) ? t : far) * margin_keep;
    return v > tiny ? v : (isnan(v) ? v : tiny);
}

/* record_walls._Sector.beyond: is the point (x, y) in the record's tangent frame past the segment between
 * sector rays i and j's wall points (far: what stands in for a ray that met nothing)? */
static inline int past_segment(double x, double y, double t_i, double t_j, double far, const double *cos_a,
                               const double *sin_a, int64_t i, int64_t j, double margin_keep, double tiny) {
    double u_i = wall_end(t_i, far, margin_keep, tiny), u_j = wall_end(t_j, far, margin_keep, tiny);
    double hx_i = u_i * cos_a[i], hy_i = u_i * sin_a[i];
    double hx_j = u_j * cos_a[j], hy_j = u_j * sin_a[j];
    double ex = hx_j - hx_i, ey = hy_j - hy_i;
    double side_point = ex * (y - hy_i) - ey * (x - hx_i);
    double side_origin = ex * (0.0 - hy_i) - ey * (0.0 - hx_i);
    return (isfinite(t_i) || isfinite(t_j)) && (side_point * side_origin < 0.0);
}

/* core.record_walls.beyond_wall_and_reach for pairs (w,) of points p (m, 3) and records p_k, n_k (K, 3) with
 * sector walls wall (K, S) float32 and reach (K,): past_reach and past_far (w,). The record's frame is
 * sampling.orthonormal_basis's. The answers are numpy's but for a point within a rounding of a sector's or a
 * segment's edge: the sector comes from libm's atan2, which numpy's SIMD one (AVX-512 CPUs) rounds otherwise
 * in the last bit for a third of its arguments, and np.einsum's order of summing three products is its own.
 * cos_a, sin_a (S,): the sector rays' directions (record_walls._ray_angle), as numpy computes them. */
PDIC_EXPORT void pdic_pair_walls(const int64_t *rows, const int64_t *records, int64_t w, const double *p,
                                 const double *p_k, const double *n_k, const float *wall, int64_t S,
                                 const double *reach, const double *cos_a, const double *sin_a, double offset,
                                 double far_wall, double margin_keep, double tiny, uint8_t *past_reach,
                                 uint8_t *past_far) {
    for (int64_t k = 0; k < w; ++k) {
        int64_t r = records[k];
        const double *q = p + 3 * rows[k], *c = p_k + 3 * r, *nk = n_k + 3 * r;
        double d[3] = {q[0] - c[0], q[1] - c[1], q[2] - c[2]};
        double t1[3], t2[3];
        duff_tangents(nk, t1, t2);
        /* np.einsum("ij,ij->i")'s order here: (first + last) + middle. */
        double x = (d[0] * t1[0] + d[2] * t1[2]) + d[1] * t1[1];
        double y = (d[0] * t2[0] + d[2] * t2[2]) + d[1] * t2[1];
        double turn = (atan2(y, x) - offset) / PDIC_TWO_PI;
        double m = fmod(turn, 1.0);  /* numpy's remainder: the divisor's sign, +0 for an exact multiple */
        if (m != 0.0) {
            if (m < 0.0) m += 1.0;
        } else {
            m = 0.0;
        }
        turn = m * (double)S - 0.5;
        int64_t i = isnan(turn) ? 0 : (int64_t)floor(turn);
        i = ((i % S) + S) % S;
        int64_t j = (i + 1) % S;
        double t_i = (double)wall[S * r + i], t_j = (double)wall[S * r + j];
        double far = far_wall * (isfinite(t_i) ? t_i : (isfinite(t_j) ? t_j : 1.0));
        past_reach[k] = (uint8_t)past_segment(x, y, t_i, t_j, reach[r], cos_a, sin_a, i, j, margin_keep, tiny);
        past_far[k] = (uint8_t)past_segment(x, y, t_i, t_j, far, cos_a, sin_a, i, j, margin_keep, tiny);
    }
}

/* core.zone_grid.morton_keys_numpy: each point's Morton (Z-curve) key over the points' bounding box, MORTON_BITS
 * (10) bits per axis. NaN propagates into the box as numpy's min and max carry it (every key then 0), and a
 * coordinate that is NaN or infinite after scaling counts as 0 (np.nan_to_num with posinf and neginf 0). */
static inline uint64_t spread_bits(uint64_t x) {
    x &= 0x3FFu;
    x = (x | (x << 16)) & 0x030000FFu;
    x = (x | (x << 8)) & 0x0300F00Fu;
    x = (x | (x << 4)) & 0x030C30C3u;
    x = (x | (x << 2)) & 0x09249249u;
    return x;
}

PDIC_EXPORT void pdic_morton_keys(const double *p, int64_t m, uint64_t *keys) {
    if (m <= 0) return;
    double lo[3], hi[3];
    int nan_[3] = {0, 0, 0};
    for (int j = 0; j < 3; ++j) lo[j] = hi[j] = p[j];
    for (int64_t i = 0; i < m; ++i) {
        for (int j = 0; j < 3; ++j) {
            double v = p[3 * i + j];
            if (isnan(v)) nan_[j] = 1;
            else {
                if (v < lo[j]) lo[j] = v;
                if (v > hi[j]) hi[j] = v;
            }
        }
    }
    double range = 0.0;
    int range_nan = 0;
    for (int j = 0; j < 3; ++j) {
        if (nan_[j]) { lo[j] = NAN; range_nan = 1; continue; }
        double d = hi[j] - lo[j];
        if (isnan(d)) range_nan = 1;  /* inf - inf */
        else if (d > range) range = d;  /* d >= 0: hi >= lo */
    }
    /* Python's max(range, 1e-300) returns a NaN range as it is */
    double denom = range_nan ? NAN : (1e-300 > range ? 1e-300 : range);
    double scale = 1023.0 / denom;
    for (int64_t i = 0; i < m; ++i) {
        uint64_t c[3];
        for (int j = 0; j < 3; ++j) {
            double v = (p[3 * i + j] - lo[j]) * scale;
            if (isnan(v) || isinf(v)) v = 0.0;
            v = v < 0.0 ? 0.0 : (v > 1023.0 ? 1023.0 : v);
            c[j] = (uint64_t)v;
        }
        keys[i] = spread_bits(c[0]) | (spread_bits(c[1]) << 1) | (spread_bits(c[2]) << 2);
    }
}

/* core.zone_grid.spatial_order: np.argsort of pdic_morton_keys, kind="stable", as a stable least-significant-digit
 * radix sort of the keys' 30 bits in three passes of 10 (a stable order of given keys is unique). keys, keys_tmp,
 * order_tmp : scratch of m entries. */
PDIC_EXPORT void pdic_morton_order(const double *p, int64_t m, uint64_t *keys, uint64_t *keys_tmp, int64_t *order,
                                   int64_t *order_tmp) {
    if (m <= 0) return;
    pdic_morton_keys(p, m, keys);
    for (int64_t i = 0; i < m; ++i) order[i] = i;
    uint64_t *ka = keys, *kb = keys_tmp;
    int64_t *oa = order, *ob = order_tmp;
    for (int pass = 0; pass < 3; ++pass) {
        int shift = 10 * pass;
        int64_t start[1025];
        memset(start, 0, sizeof(start));
        for (int64_t i = 0; i < m; ++i) ++start[((ka[i] >> shift) & 1023u) + 1];
        for (int b = 0; b < 1024; ++b) start[b + 1] += start[b];
        for (int64_t i = 0; i < m; ++i) {
            int64_t at = start[(ka[i] >> shift) & 1023u]++;
            kb[at] = ka[i];
            ob[at] = oa[i];
        }
        uint64_t *k = ka; ka = kb; kb = k;
        int64_t *o = oa; oa = ob; ob = o;
    }
    if (oa != order) memcpy(order, oa, (size_t)m * sizeof(int64_t));
}

/* numpy's np.minimum and np.maximum of two doubles: a NaN in either gives NaN. */
static inline double np_min(double a, double b) { return isnan(a) ? a : (isnan(b) ? b : (a < b ? a : b)); }
static inline double np_max(double a, double b) { return isnan(a) ? a : (isnan(b) ? b : (a > b ? a : b)); }

/* One family of cell boundaries of the translational gradient (Hemisphere.irradiance_and_gradients), added to
 * gt (c, 3): for each column k, the sum over rows j >= first of step[j - first] / min(r, r') (L - L') against the
 * cell `rows_back` rows and `columns_back` columns before it (round in phi), times dir[k] (3); those summed over
 * k. Rows' boundaries: first 1, one row back, direction u; columns': first 0, one column back, v_lo. */
static void add_boundaries(const double *L, const double *r, int64_t c, int64_t M, int64_t N, int64_t first,
                           int64_t rows_back, int64_t columns_back, const double *step, const double *dir,
                           double *gt) {
    double term[6], part[6 * 3];
    for (int64_t i = 0; i < c * 3; ++i) part[i] = 0.0;
    for (int64_t k = 0; k < N; ++k) {
        int64_t before = (k + N - columns_back) % N;
        for (int64_t ch = 0; ch < c; ++ch) term[ch] = 0.0;
        for (int64_t j = first; j < M; ++j) {
            int64_t at = j * N + k, other = (j - rows_back) * N + before;
            double w = step[j - first] / np_min(r[at], r[other]);
            for (int64_t ch = 0; ch < c; ++ch) term[ch] += w * (L[at * c + ch] - L[other * c + ch]);
        }
        for (int64_t ch = 0; ch < c; ++ch)
            for (int x = 0; x < 3; ++x) part[ch * 3 + x] += term[ch] * dir[k * 3 + x];
    }
    for (int64_t i = 0; i < c * 3; ++i) gt[i] += part[i];
}

/* core.gather_cells.CellSums.irradiance_and_gradients up to the world frame, for B records of M x N cells
 * and c <= 6 channels: each cell's mean radiance L_sum / max(count, 1) (B M N, c) and rotational axis rot_sum /
 * max(count, 1) (B M N, 3), its distance max(r_min, r_floor, 1e-300), then core.hemisphere.Hemisphere.
 * irradiance_and_gradients: E (B, c), grad_r and grad_t (B, c, 3) in the local frame. Every sum runs in
 * the order numpy's runs it over a leading axis: from +0.0, one term after another (so a sum of -0.0 terms
 * is +0.0, as numpy's).
 * theta_step (M - 1,), phi_step (M,), u and v_lo (N, 3): Hemisphere.gradient_coefficients. Returns 0, or -1
 * when the scratch memory (M N (c + 4) doubles) could not be had. */
PDIC_EXPORT int64_t pdic_cell_gradients(const double *L_sum, const double *rot_sum, const double *count,
                                        const double *r_min, int64_t B, int64_t M, int64_t N, int64_t c,
                                        double r_floor, double cell_weight, const double *theta_step,
                                        const double *phi_step, const double *u, const double *v_lo,
                                        double *E, double *grad_r, double *grad_t) {
    int64_t C = M * N;
    double *L = (double *)malloc(sizeof(double) * (size_t)(C * (c + 4)));
    if (!L) return -1;
    double *rot = L + C * c, *r = rot + 3 * C;
    for (int64_t b = 0; b < B; ++b) {
        const double *Ls = L_sum + b * C * c, *Rs = rot_sum + b * C * 3, *cs = count + b * C, *rm = r_min + b * C;
        for (int64_t i = 0; i < C; ++i) {
            double k = np_max(cs[i], 1.0);
            if (k == 1.0) { /* a cell of one real ray or none, most of them: x / 1 is x, to the bit */
                for (int64_t ch = 0; ch < c; ++ch) L[i * c + ch] = Ls[i * c + ch];
                for (int x = 0; x < 3; ++x) rot[i * 3 + x] = Rs[i * 3 + x];
            } else {
                for (int64_t ch = 0; ch < c; ++ch) L[i * c + ch] = Ls[i * c + ch] / k;
                for (int x = 0; x < 3; ++x) rot[i * 3 + x] = Rs[i * 3 + x] / k;
            }
            r[i] = np_max(np_max(rm[i], r_floor), 1e-300);
        }
        double *Eb = E + b * c, *gr = grad_r + b * c * 3, *gt = grad_t + b * c * 3;
        double sum[6], acc[6 * 3];
        for (int64_t ch = 0; ch < c; ++ch) {
            sum[ch] = 0.0;
            for (int x = 0; x < 3; ++x) acc[ch * 3 + x] = 0.0;
        }
        for (int64_t i = 0; i < C; ++i) {
            const double *Li = L + i * c, *ri = rot + i * 3;
            for (int64_t ch = 0; ch < c; ++ch) {
                sum[ch] += Li[ch];
                for (int x = 0; x < 3; ++x) acc[ch * 3 + x] += Li[ch] * ri[x];
            }
        }
        for (int64_t ch = 0; ch < c; ++ch) {
            Eb[ch] = cell_weight * sum[ch];
            for (int x = 0; x < 3; ++x) {
                gr[ch * 3 + x] = cell_weight * acc[ch * 3 + x];
                gt[ch * 3 + x] = 0.0;
            }
        }
        if (M > 1) add_boundaries(L, r, c, M, N, 1, 1, 0, theta_step, u, gt);  /* rows j-1 | j, j >= 1 */
        if (N > 1) add_boundaries(L, r, c, M, N, 0, 0, 1, phi_step, v_lo, gt); /* columns k-1 | k, round */
    }
    free(L);
    return 0;
}

/* numpy's `table[rows, :3] += values` for a (n, width) float64 table, rows (h,) and values (h, 3): every row's
 * sum is taken from the table as it was (`scratch` (h, 3) holds them), then written in order, so a row met twice
 * keeps its last sum, as numpy's does (core.gather_cells.CellSums.add_real_radiance). */
PDIC_EXPORT void pdic_add_rows3(double *table, int64_t width, const int64_t *rows, const double *values, int64_t h,
                                double *scratch) {
    for (int64_t i = 0; i < h; ++i)
        for (int c = 0; c < 3; ++c) scratch[3 * i + c] = table[rows[i] * width + c] + values[3 * i + c];
    for (int64_t i = 0; i < h; ++i)
        for (int c = 0; c < 3; ++c) table[rows[i] * width + c] = scratch[3 * i + c];
}
