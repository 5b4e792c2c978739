// crop2.cpp -- preprocessing "sphere-crop-v2", see crop2.h. Each step
// repeats training/preprocess.py's arithmetic in the same order (float64,
// no fused multiply-add: -ffp-contract=off in the Makefile; sums in index
// order; no libm function but sqrt and floor), so that the circle and the
// crop are bit-identical to the Python reference.
#include "crop2.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

// A few steps are also written with AVX-512 intrinsics (gathers and
// compressing stores, which the compiler's vector loops do not use), taken
// when the CPU has AVX-512F (or as set_avx512 says: tests run both): the
// same operations on the same values.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
// (GCC 12's AVX-512 header warns of its own undefined vectors: PR 105593)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include <immintrin.h>
#pragma GCC diagnostic pop
#define CROP2_AVX512 1
#endif

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "kernels.h"
#include "pi_err.h"

// The vector loops below are compiled four ways, picked at run time; each
// lane does the same IEEE operations (no fused multiply-add:
// -ffp-contract=off), so every version gives the same bits. x86-64-v4 adds
// AVX-512 BW, DQ and VL to avx512f: the 16-bit loops (block sums and means,
// the box maximum) get the full 512-bit width.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define KERN2_CLONES __attribute__((target_clones("arch=x86-64-v4", "avx512f", "avx2", "default")))
#else
#define KERN2_CLONES
#endif

namespace crop2
{

namespace
{

int avx512_forced = -1; // set_avx512

// whether the steps written with AVX-512 intrinsics run (set_avx512)
inline bool avx512()
{
#ifdef CROP2_AVX512
    if (avx512_forced >= 0) return avx512_forced != 0;
    return __builtin_cpu_supports("avx512f");
#else
    return false;
#endif
}

// The coarse accumulator and the box maximum's rows and planes, in 16 or 32
// bits (coarse).
template <class T> struct Acc {
    std::vector<T> acc, pair, h3, vmax, bmax;
};
// Working memory, kept between frames (per thread): fresh allocations of
// these sizes cost more in page faults than the work itself.
struct Scratch {
    std::vector<uint8_t> red; // the reduced image: block means fit a byte
    std::vector<int32_t> row, M, GX, GY, V, D;
    std::vector<int32_t> keep;
    Acc<uint16_t> a16;
    Acc<int32_t> a32;
    bool last16 = true; // whether the last frame counted in 16 bits
};
thread_local Scratch scratch;

template <class T> void fill(std::vector<T> &v, size_t n, T value)
{
    if (v.size() < n) v.resize(n);
    std::fill(v.begin(), v.begin() + (long)n, value);
}

struct Cand {
    double cx, cy, r;
    long votes;
};

// A fit; the i-th of find_sphere's fits keeps its support's rays in bank[i].
struct Found {
    double cx, cy, r, support;
};

// Python's math.floor(x) for the values here (finite, well inside long).
// floor of a double known to lie well inside int32, as an int32: truncation,
// then one down where that went up (negative non-integers); exact, and
// vectorisable (no libm call, no branch)
inline int32_t floor32(double x)
{
    const int32_t t = (int32_t)x;
    return t - (int32_t)((double)t > x);
}

// (no libm call: truncation, then one down for negative non-integers; exact)
inline long ifloor(double x)
{
    const long t = (long)x;
    return (double)t > x ? t - 1 : t;
}

// ---- coarse stage -------------------------------------------------------------

// One row of s x s block sums, s <= 16 (a sum fits 16 bits): col = the s
// rows summed per byte, then h[i] = col[i] + col[i + 3] + ... + col[i + 3 (s -
// 1)], the block of pixel column X and channel c being h[3 s X + c].
KERN2_CLONES void block_sums(const uint8_t *p, size_t stride, int s, size_t nbytes, uint16_t *col,
                             uint16_t *h)
{
    const size_t m = nbytes - 3 * (size_t)(s - 1);
    if (s == 3) { // the usual reduction (512 to 767 pixel frames): one pass each
        const uint8_t *q1 = p + stride, *q2 = q1 + stride;
        for (size_t i = 0; i < nbytes; i++) col[i] = (uint16_t)(p[i] + q1[i] + q2[i]);
        for (size_t i = 0; i < m; i++) h[i] = (uint16_t)(col[i] + col[i + 3] + col[i + 6]);
        return;
    }
    for (size_t i = 0; i < nbytes; i++) col[i] = p[i];
    for (int y = 1; y < s; y++) {
        const uint8_t *q = p + (size_t)y * stride;
        for (size_t i = 0; i < nbytes; i++) col[i] = (uint16_t)(col[i] + q[i]);
    }
    for (size_t i = 0; i < m; i++) h[i] = col[i];
    for (int xx = 1; xx < s; xx++) {
        const uint16_t *c = col + 3 * xx;
        for (size_t i = 0; i < m; i++) h[i] = (uint16_t)(h[i] + c[i]);
    }
}

// q[c n + X] = (v[3 X + c] + half) / n as (v[3 X + c] + half) * mul >> sh
// (mul, sh checked exact for every possible sum), for a row of n reduced
// pixels: their means by channel (planar).
KERN2_CLONES void block_means(const uint16_t *__restrict v, size_t n, uint32_t half, uint32_t mul,
                              int sh, uint8_t *__restrict q)
{
    for (size_t i = 0; i < n; i++) {
        q[i] = (uint8_t)((((uint32_t)v[3 * i] + half) * mul) >> sh);
        q[n + i] = (uint8_t)((((uint32_t)v[3 * i + 1] + half) * mul) >> sh);
        q[2 * n + i] = (uint8_t)((((uint32_t)v[3 * i + 2] + half) * mul) >> sh);
    }
}

// A multiplier and shift with (v * mul) >> sh == v / n for every v in 0 ..
// vmax, all products below 2^32; false when there is none.
bool exact_divider(uint32_t n, uint32_t vmax, uint32_t *mul, int *sh)
{
    for (int k = 8; k < 32; k++) {
        const uint64_t m = ((1ull << k) + n - 1) / n;
        if ((uint64_t)vmax * m >= (1ull << 32)) break;
        bool ok = true;
        for (uint32_t v = 0; v <= vmax && ok; v++) ok = (uint32_t)(((uint64_t)v * m) >> k) == v / n;
        if (ok) {
            *mul = (uint32_t)m;
            *sh = k;
            return true;
        }
    }
    return false;
}

// Block means of s x s blocks, rounded half up; the remainder dropped. Row
// Y of the reduced image holds its ws blue means, then the green, then the
// red (planar per row: the gradient's loops read each channel contiguously).
void reduce(const uint8_t *bgr, size_t stride, int w, int h, int s, std::vector<uint8_t> &red,
            int *hs, int *ws)
{
    *hs = h / s;
    *ws = w / s;
    red.resize((size_t)*hs * *ws * 3);
    const uint32_t n = (uint32_t)s * (uint32_t)s, half = n / 2;
    const size_t nbytes = (size_t)*ws * s * 3, nout = (size_t)*ws * 3;
    // the divider of the last s (frames of one size keep theirs)
    thread_local uint32_t div_n = 0, div_mul = 0;
    thread_local int div_sh = -1;
    if (div_n != n) {
        div_n = n;
        if (s > 16 || !exact_divider(n, 255 * n + half, &div_mul, &div_sh)) div_sh = -1;
    }
    if (div_sh >= 0) {
        thread_local std::vector<uint16_t> col, hsum;
        thread_local std::vector<uint16_t> pick;
        col.resize(nbytes);
        hsum.resize(nbytes + 1);
        pick.resize(nout + 1);
        for (int Y = 0; Y < *hs; Y++) {
            block_sums(bgr + (size_t)Y * s * stride, stride, s, nbytes, col.data(), hsum.data());
            // a block's three sums as one 8-byte move (the fourth value is
            // overwritten by the next block's, or lands in the spare one)
            const uint16_t *hs16 = hsum.data();
            uint16_t *pk = pick.data();
            for (int X = 0; X < *ws; X++) {
                uint64_t t;
                std::memcpy(&t, hs16 + (size_t)X * 3 * s, 8);
                std::memcpy(pk + (size_t)X * 3, &t, 8);
            }
            block_means(pick.data(), *ws, half, div_mul, div_sh, &red[(size_t)Y * nout]);
        }
        return;
    }
    std::vector<int32_t> &row = scratch.row;
    row.assign(nbytes, 0);
    for (int Y = 0; Y < *hs; Y++) {
        std::fill(row.begin(), row.end(), 0);
        for (int y = 0; y < s; y++) {
            const uint8_t *q = bgr + ((size_t)Y * s + y) * stride;
            for (size_t i = 0; i < nbytes; i++) row[i] += q[i];
        }
        uint8_t *o = &red[(size_t)Y * nout];
        for (int X = 0; X < *ws; X++) {
            const int32_t *q = &row[(size_t)X * s * 3];
            int32_t b = 0, g = 0, r = 0;
            for (int xx = 0; xx < s; xx++, q += 3) {
                b += q[0];
                g += q[1];
                r += q[2];
            }
            o[X] = (uint8_t)((b + (int32_t)half) / (int32_t)n); // non-negative: / floors
            o[*ws + X] = (uint8_t)((g + (int32_t)half) / (int32_t)n);
            o[2 * *ws + X] = (uint8_t)((r + (int32_t)half) / (int32_t)n);
        }
    }
}

// n edges; the vectors keep their size between frames (resizing them would
// clear them, a cost of its own)
struct Edges {
    std::vector<int32_t> x, y, gx, gy;
    size_t n = 0;
};

// Sobel per channel on the reduced image, the channel of the largest
// gx^2 + gy^2 (first on ties), at least edge_min^2, not below either
// neighbour across the edge (direction in four classes, integer tests).
// Sobel as its separable parts: V = r[y-1] + 2 r[y] + r[y+1] and D = r[y+1] -
// r[y-1] per byte, then gx = V[x+1] - V[x-1], gy = D[x-1] + 2 D[x] + D[x+1].
// One row of the gradient image: per pixel the channel of the largest
// magnitude^2 (first on ties) and its gx, gy. Planar loops so that they
// vectorise; magnitudes^2 fit int32 (|g| <= 4 * 255 * 2).
KERN2_CLONES void gradient_row(const uint8_t *r0, const uint8_t *r1, const uint8_t *r2, int gw,
                               int32_t *__restrict V, int32_t *__restrict D, int32_t *__restrict m,
                               int32_t *__restrict ox, int32_t *__restrict oy)
{
    const int ws = gw + 2, nb = ws * 3;
    for (int k = 0; k < nb; k++) {
        V[k] = r0[k] + 2 * r1[k] + r2[k];
        D[k] = r2[k] - r0[k];
    }
    // the rows are planar (channel c at [c ws, (c + 1) ws))
    const int32_t *Vb = V, *Vg = V + ws, *Vr = V + 2 * ws;
    const int32_t *Db = D, *Dg = D + ws, *Dr = D + 2 * ws;
    for (int j = 0; j < gw; j++) {
        const int32_t xb = Vb[j + 2] - Vb[j], yb = Db[j] + 2 * Db[j + 1] + Db[j + 2];
        const int32_t xg = Vg[j + 2] - Vg[j], yg = Dg[j] + 2 * Dg[j + 1] + Dg[j + 2];
        const int32_t xr = Vr[j + 2] - Vr[j], yr = Dr[j] + 2 * Dr[j + 1] + Dr[j + 2];
        const int32_t mb = xb * xb + yb * yb, mg = xg * xg + yg * yg, mr = xr * xr + yr * yr;
        // the first channel of the largest: the later one only when strictly larger
        const int32_t bm = mg > mb ? mg : mb, bx = mg > mb ? xg : xb, by = mg > mb ? yg : yb;
        m[j] = mr > bm ? mr : bm;
        ox[j] = mr > bm ? xr : bx;
        oy[j] = mr > bm ? yr : by;
    }
}

// One row of edges: keep[j] = 1 where the magnitude^2 m (mc[j]; up and dn
// the rows above and below, each row with a zero before and after) is at
// least tmin and not below either neighbour across the edge (direction in
// four classes, integer tests), else 0. A loop of its own so that it
// vectorises.
KERN2_CLONES void nms_row(const int32_t *up, const int32_t *mc, const int32_t *dn,
                          const int32_t *gx, const int32_t *gy, int gw, int32_t tmin,
                          int32_t *__restrict keep)
{
    for (int j = 0; j < gw; j++) {
        const int32_t m = mc[j], gxv = gx[j], gyv = gy[j];
        const int32_t ax = gxv < 0 ? -gxv : gxv, ay = gyv < 0 ? -gyv : gyv;
        const bool horiz = 5 * ay <= 2 * ax, vert = 5 * ax <= 2 * ay;
        const bool same = (gxv > 0) == (gyv > 0);
        // the neighbours: left/right, up/down, up-left/down-right, up-right/down-left
        const int32_t dga = same ? up[j - 1] : up[j + 1], dgb = same ? dn[j + 1] : dn[j - 1];
        const int32_t a = horiz ? mc[j - 1] : (vert ? up[j] : dga);
        const int32_t b = horiz ? mc[j + 1] : (vert ? dn[j] : dgb);
        keep[j] = (int32_t)((m >= tmin) & (m >= a) & (m >= b));
    }
}

#ifdef CROP2_AVX512
// nms_row and the kept edges' x (j + 1), y (y), gx and gy appended at ex[0
// ..), ey, egx, egy with AVX-512: 16 pixels' tests as one mask (the last
// block's loads masked to the row: no scalar tail), the kept ones compressed
// in order into a register and stored whole, 16 slots from the count (the
// slots past the kept ones are overwritten next or left unused), not by
// compressing stores to memory, which are microcoded and slow on some CPUs
// (AMD Zen 4); their count returned. The count before pixel j is at most j,
// so a block's store ends at most 15 slots past the row's last pixel's slot:
// within edges()'s cap, a slot per pixel and 16 spare.
__attribute__((target("avx512f"))) size_t edges_row512(const int32_t *up, const int32_t *mc,
                                                       const int32_t *dn, const int32_t *gx,
                                                       const int32_t *gy, int gw, int32_t tmin,
                                                       int32_t y, int32_t *ex, int32_t *ey,
                                                       int32_t *egx, int32_t *egy)
{
    const __m512i vt = _mm512_set1_epi32(tmin), zero = _mm512_setzero_si512(),
                  vy = _mm512_set1_epi32(y),
                  step = _mm512_set_epi32(16, 15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1);
    size_t ne = 0;
    for (int j = 0; j < gw; j += 16) {
        // the block's pixels in the row (masked loads read nothing beyond them)
        const __mmask16 in = gw - j >= 16 ? (__mmask16)0xFFFF : (__mmask16)((1u << (gw - j)) - 1);
        const __m512i m = _mm512_maskz_loadu_epi32(in, mc + j),
                      gxv = _mm512_maskz_loadu_epi32(in, gx + j),
                      gyv = _mm512_maskz_loadu_epi32(in, gy + j);
        const __m512i ax = _mm512_abs_epi32(gxv), ay = _mm512_abs_epi32(gyv);
        const __m512i ax2 = _mm512_add_epi32(ax, ax), ay2 = _mm512_add_epi32(ay, ay);
        const __m512i ax5 = _mm512_add_epi32(_mm512_add_epi32(ax2, ax2), ax),
                      ay5 = _mm512_add_epi32(_mm512_add_epi32(ay2, ay2), ay);
        const __mmask16 horiz = _mm512_cmp_epi32_mask(ay5, ax2, _MM_CMPINT_LE),
                        vert = _mm512_cmp_epi32_mask(ax5, ay2, _MM_CMPINT_LE);
        const __mmask16 same = (__mmask16) ~(_mm512_cmp_epi32_mask(gxv, zero, _MM_CMPINT_NLE) ^
                                             _mm512_cmp_epi32_mask(gyv, zero, _MM_CMPINT_NLE));
        const __m512i dga = _mm512_mask_blend_epi32(same, _mm512_maskz_loadu_epi32(in, up + j + 1),
                                                    _mm512_maskz_loadu_epi32(in, up + j - 1));
        const __m512i dgb = _mm512_mask_blend_epi32(same, _mm512_maskz_loadu_epi32(in, dn + j - 1),
                                                    _mm512_maskz_loadu_epi32(in, dn + j + 1));
        const __m512i a = _mm512_mask_blend_epi32(
            horiz, _mm512_mask_blend_epi32(vert, dga, _mm512_maskz_loadu_epi32(in, up + j)),
            _mm512_maskz_loadu_epi32(in, mc + j - 1));
        const __m512i b = _mm512_mask_blend_epi32(
            horiz, _mm512_mask_blend_epi32(vert, dgb, _mm512_maskz_loadu_epi32(in, dn + j)),
            _mm512_maskz_loadu_epi32(in, mc + j + 1));
        const __mmask16 k = in & _mm512_cmp_epi32_mask(m, vt, _MM_CMPINT_NLT) &
                            _mm512_cmp_epi32_mask(m, a, _MM_CMPINT_NLT) &
                            _mm512_cmp_epi32_mask(m, b, _MM_CMPINT_NLT);
        if (!k) continue;
        _mm512_storeu_si512(
            ex + ne, _mm512_maskz_compress_epi32(k, _mm512_add_epi32(_mm512_set1_epi32(j), step)));
        _mm512_storeu_si512(ey + ne, vy);
        _mm512_storeu_si512(egx + ne, _mm512_maskz_compress_epi32(k, gxv));
        _mm512_storeu_si512(egy + ne, _mm512_maskz_compress_epi32(k, gyv));
        ne += (size_t)__builtin_popcount((unsigned)k);
    }
    return ne;
}
#endif

// One row's edges (nms_row's arguments), their x (j + 1), y, gx and gy
// appended at ex[0 ..), ey, egx, egy (room for gw + 16), by edges_row512 or
// the portable steps (set_avx512); their count returned. keep: gw + 4 flags,
// the last 4 zero.
inline size_t row_edges_at(const int32_t *up, const int32_t *mc, const int32_t *dn,
                           const int32_t *gx, const int32_t *gy, int gw, int32_t tmin, int32_t y,
                           int32_t *keep, int32_t *ex, int32_t *ey, int32_t *egx, int32_t *egy)
{
#ifdef CROP2_AVX512
    if (avx512()) return edges_row512(up, mc, dn, gx, gy, gw, tmin, y, ex, ey, egx, egy);
#endif
    nms_row(up, mc, dn, gx, gy, gw, tmin, keep);
    // branch-free: each edge written at the end and kept by advancing the
    // count; the kept ones, four flags at a time
    size_t ne = 0;
    for (int j = 0; j < gw; j += 4) {
        if (!(keep[j] | keep[j + 1] | keep[j + 2] | keep[j + 3])) continue;
        for (int jj = j; jj < j + 4 && jj < gw; jj++) {
            ex[ne] = jj + 1;
            ey[ne] = y;
            egx[ne] = gx[jj];
            egy[ne] = gy[jj];
            ne += (size_t)keep[jj];
        }
    }
    return ne;
}

// The edges of the reduced image (see above) into e. pf[0 .. pf_len): memory
// the votes will write next (the accumulator), brought into the cache a share
// per row meanwhile: after a frame's network run it is no longer there, and
// the votes land all over it.
void edges(const std::vector<uint8_t> &red, int hs, int ws, double edge_min, Edges &e,
           const uint8_t *pf, size_t pf_len)
{
    const int gh = hs - 2, gw = ws - 2;
    const size_t P = (size_t)gw + 2;
    const double emin2 = edge_min * edge_min;
    // m >= emin2 (a double) as an integer test: m >= ceil(emin2); an emin2
    // no magnitude reaches (or NaN): no edge
    if (!(emin2 <= 2147483647.0)) return;
    const int32_t tmin = emin2 <= -2147483648.0 ? INT32_MIN : (int32_t)-std::floor(-emin2);
    // Row by row: the gradient of row i, then the edges of row i - 1 (its
    // rows above and below are known by then), so that the rows in use stay
    // in the cache. The magnitudes^2 of the last three rows (a ring, each
    // row with a zero before and after; a row of zeros above the first and
    // below the last), gx and gy of the last two.
    std::vector<int32_t> &M = scratch.M, &GX = scratch.GX, &GY = scratch.GY, &V = scratch.V,
                         &D = scratch.D;
    M.assign(4 * P, 0);
    GX.resize(2 * (size_t)gw);
    GY.resize(2 * (size_t)gw);
    const size_t nb = (size_t)ws * 3;
    V.resize(nb);
    D.resize(nb);
    const int32_t *zero = &M[3 * P];
    // the padded row t (1 .. gh: gradient row t - 1; 0 and gh + 1: zeros)
    auto mrow = [&](int t) -> int32_t * {
        return t == 0 || t == gh + 1 ? const_cast<int32_t *>(zero) : &M[(size_t)(t % 3) * P];
    };
    // a slot per pixel and 16 spare (edges_row512's whole-vector stores; the
    // portable loop below writes each pixel's edge at the count and keeps it
    // by advancing the count: one slot past the kept edges, at most the
    // pixel's own)
    const size_t cap = (size_t)gh * gw + 16;
    if (e.x.size() < cap) {
        e.x.resize(cap);
        e.y.resize(cap);
        e.gx.resize(cap);
        e.gy.resize(cap);
    }
    std::vector<int32_t> &keep = scratch.keep;
    keep.resize((size_t)gw + 4);
    std::fill(keep.begin() + gw, keep.end(), 0);
    size_t ne = 0;
    // the edges of gradient row i (padded row i + 1)
    auto row_edges = [&](int i) {
        ne += row_edges_at(mrow(i) + 1, mrow(i + 1) + 1, mrow(i + 2) + 1, &GX[(size_t)(i % 2) * gw],
                           &GY[(size_t)(i % 2) * gw], gw, tmin, i + 1, keep.data(), &e.x[ne],
                           &e.y[ne], &e.gx[ne], &e.gy[ne]);
    };
    for (int i = 0; i < gh; i++) {
        const uint8_t *r0 = &red[(size_t)i * nb];
        gradient_row(r0, r0 + nb, r0 + 2 * nb, gw, V.data(), D.data(), mrow(i + 1) + 1,
                     &GX[(size_t)(i % 2) * gw], &GY[(size_t)(i % 2) * gw]);
        if (i >= 1) row_edges(i - 1);
        // a share of pf (prefetched for writing)
        const size_t lo = pf_len * (size_t)i / (size_t)gh,
                     hi = pf_len * (size_t)(i + 1) / (size_t)gh;
        for (size_t q = lo & ~(size_t)63; q < hi; q += 64) __builtin_prefetch(pf + q, 1, 3);
    }
    if (gh >= 1) row_edges(gh - 1);
    e.n = ne;
}

// Fine stripes behind the sphere (preprocess.py ORIENT_SLOPES, STRIPE_SHARE,
// STRIPE_DROP: the same numbers). Bin 0 .. 15 of a gradient's orientation
// modulo 180 degrees, bin k within pi/32 of k pi/16: integer tests against
// 1000 tan((2k + 1) pi / 32), bin 8 for a zero gradient.
constexpr int orient_slopes[8] = {98, 303, 535, 821, 1219, 1871, 3297, 10153};
constexpr double stripe_share = 0.45;
constexpr int stripe_drop = 3;

inline int orientation_bin(int32_t gx, int32_t gy)
{
    const bool flip = gy < 0 || (gy == 0 && gx < 0);
    const int64_t a = flip ? -(int64_t)gx : gx, b = flip ? -(int64_t)gy : gy;
    // b >= 0, the angle in [0, pi); q: how many bin edges in [0, pi/2]
    // atan2(b, |a|) reaches
    int q = 0;
    for (int t : orient_slopes) q += 1000 * b >= t * (a < 0 ? -a : a);
    return a < 0 ? (16 - q) % 16 : q;
}

// e without the edges of an orientation that dominates them: when the
// largest of the 16 bins holds at least stripe_share of the edges, those of
// every bin with more than stripe_drop times the median count (kept in
// order; with a median of 0, every non-empty bin). Stripes outvote the rim,
// whose edges run every way.
void drop_stripes(Edges &e)
{
    if (e.n == 0) return;
    thread_local std::vector<uint8_t> bin;
    bin.resize(e.n);
    long cnt[16] = {0};
    for (size_t i = 0; i < e.n; i++) cnt[bin[i] = (uint8_t)orientation_bin(e.gx[i], e.gy[i])]++;
    long srt[16];
    std::copy(cnt, cnt + 16, srt);
    std::sort(srt, srt + 16);
    if ((double)srt[15] < stripe_share * (double)e.n) return;
    const long mid = srt[7] + srt[8]; // twice the median
    bool drop[16];
    for (int k = 0; k < 16; k++) drop[k] = 2 * cnt[k] > stripe_drop * mid;
    size_t m = 0;
    for (size_t i = 0; i < e.n; i++) {
        if (drop[bin[i]]) continue;
        e.x[m] = e.x[i];
        e.y[m] = e.y[i];
        e.gx[m] = e.gx[i];
        e.gy[m] = e.gy[i];
        m++;
    }
    e.n = m;
}

// near[i] = 1 where edge (x[i], y[i]) lies within d2lo <= d^2 <= d2hi of
// (Xc, Yc), else 0 (in doubles: exact for any frame size). Its own loop so
// that it vectorises.
KERN2_CLONES void annulus(const int32_t *x, const int32_t *y, size_t n, double Xc, double Yc,
                          double d2lo, double d2hi, uint8_t *near)
{
    for (size_t i = 0; i < n; i++) {
        const double dx = x[i] - Xc, dy = y[i] - Yc, d2 = dx * dx + dy * dy;
        near[i] = (uint8_t)((d2 >= d2lo) & (d2 <= d2hi));
    }
}

// Radius (reduced pixels) about centre (Xc, Yc) between lo and hi: histogram
// of the distances of the edges whose gradient points along the radius,
// smoothed 1-2-1. -1 when there is none.
long radius_vote(const Edges &e, long Xc, long Yc, long lo, long hi)
{
    std::vector<long> hist((size_t)(hi - lo + 3), 0); // padded by one bin each side
    bool any = false;
    // only edges at distances that round to lo .. hi can count: those with
    // (lo - 1)^2 < d^2 < (hi + 1)^2, found first by a vector loop; the exact
    // test below then sees them in the same order
    thread_local std::vector<uint8_t> near;
    thread_local std::vector<uint32_t> idx;
    if (near.size() < e.n) {
        near.resize(e.n);
        idx.resize(e.n);
    }
    annulus(e.x.data(), e.y.data(), e.n, (double)Xc, (double)Yc, (double)((lo - 1) * (lo - 1)),
            (double)((hi + 1) * (hi + 1)), near.data());
    size_t nn = 0;
    for (size_t i = 0; i < e.n; i++) {
        idx[nn] = (uint32_t)i;
        nn += near[i];
    }
    for (size_t q = 0; q < nn; q++) {
        const size_t i = idx[q];
        const int64_t dx = e.x[i] - Xc, dy = e.y[i] - Yc, gx = e.gx[i], gy = e.gy[i];
        const int64_t d2 = dx * dx + dy * dy, dot = dx * gx + dy * gy, m2 = gx * gx + gy * gy;
        if (!(100 * dot * dot >= 81 * d2 * m2)) continue;
        const long b = ifloor(std::sqrt((double)d2) + 0.5);
        if (b < lo || b > hi) continue;
        hist[(size_t)(b - lo + 1)]++;
        any = true;
    }
    if (!any) return -1;
    long best = -1, bi = 0;
    for (long i = 0; i <= hi - lo; i++) {
        const long v = hist[(size_t)i] + 2 * hist[(size_t)i + 1] + hist[(size_t)i + 2];
        if (v > best) {
            best = v;
            bi = i;
        }
    }
    return lo + bi;
}

// The accumulator slots an edge at (x, y) with unit gradient (ux, uy) votes
// for at signed radii sr[k]: boff[k] + Y * ws + X for the cell X = floor(x -
// sr ux + 0.5), Y = floor(y - sr uy + 0.5), trash + k outside (a slot per k:
// votes outside in a row do not wait for each other). For m edges at once
// (n slots each, edge i's at cell + i n): one call and one counting loop per
// batch, not per edge (the votes a third cheaper). Its own loop so that it
// vectorises.
KERN2_CLONES void vote_cells(const double *sr, const int32_t *boff, int n, const int32_t *ex,
                             const int32_t *ey, const double *eux, const double *euy, size_t m,
                             int ws, int hs, int32_t trash, int32_t *cell)
{
    // x, y, sr are within the frame's size (<= 16384 * 2): floor32 is exact
    for (size_t i = 0; i < m; i++, cell += n) {
        const double x = ex[i], y = ey[i], ux = eux[i], uy = euy[i];
        for (int k = 0; k < n; k++) {
            const int32_t X = floor32(x - sr[k] * ux + 0.5), Y = floor32(y - sr[k] * uy + 0.5);
            const int32_t in = (X >= 0) & (X < ws) & (Y >= 0) & (Y < hs);
            cell[k] = in ? boff[k] + Y * ws + X : trash + k;
        }
    }
}

// The unit gradient of each edge: g / sqrt(gx^2 + gy^2), as preprocess.py.
KERN2_CLONES void unit_gradients(const int32_t *gx, const int32_t *gy, size_t n,
                                 std::vector<double> &ux, std::vector<double> &uy)
{
    ux.resize(n);
    uy.resize(n);
    double *a = ux.data(), *b = uy.data();
    for (size_t i = 0; i < n; i++) {
        const double x = gx[i], y = gy[i];
        const double m = std::sqrt((double)((int64_t)gx[i] * gx[i] + (int64_t)gy[i] * gy[i]));
        a[i] = x / m;
        b[i] = y / m;
    }
}

// The coarse accumulator's nb radius bins (planes of hs x ws): per bin the
// 3 x 3 box sum (zeros outside) of it plus the next bin (when there is
// one), and per cell the largest (vmax) and its bin (bmax, the first on
// ties). Row by row, all bins per row (the rows of vmax and bmax stay in
// the cache): the horizontal 3-sums of three rows per bin in h3 (3 ws cells
// per bin, a ring), the vertical sum of a row once the row below it is
// summed. Each row of a bin's plane is cleared after its last use (the next
// frame finds the accumulator zero). Row loops, so that they vectorise.
template <class T>
inline __attribute__((always_inline)) void box_max_t(T *acc, int nb, int hs, int ws, T *pair, T *h3,
                                                     T *vmax, T *bmax)
{
    const size_t W = (size_t)ws, plane = (size_t)hs * W;
    for (int Y = 0; Y <= hs; Y++) {
        for (int b = 0; b < nb && Y < hs; b++) {
            // the horizontal 3-sums of row Y (no neighbour beyond the row)
            T *ar = acc + (size_t)b * plane + (size_t)Y * W;
            T *hr = h3 + ((size_t)b * 3 + (size_t)(Y % 3)) * W;
            if (b + 1 < nb) {
                const T *nr = ar + plane;
                for (size_t c = 0; c < W; c++) pair[c] = (T)(ar[c] + nr[c]);
            } else {
                for (size_t c = 0; c < W; c++) pair[c] = ar[c];
            }
            for (size_t c = 1; c + 1 < W; c++) hr[c] = (T)(pair[c - 1] + pair[c] + pair[c + 1]);
            hr[0] = (T)(pair[0] + (ws > 1 ? pair[1] : 0));
            if (ws > 1) hr[W - 1] = (T)(pair[W - 2] + pair[W - 1]);
            // used by this bin and the one before
            std::fill(ar, ar + W, (T)0);
        }
        // row Yo = Y - 1: the rows above and below it (zero beyond the plane)
        const int Yo = Y - 1;
        if (Yo < 0) continue;
        T *vm = vmax + (size_t)Yo * W, *bm = bmax + (size_t)Yo * W;
        for (int b = 0; b < nb; b++) {
            const T *hb = h3 + (size_t)b * 3 * W;
            const T *hm = hb + (size_t)(Yo % 3) * W;
            const T *hu = Yo > 0 ? hb + (size_t)((Yo - 1) % 3) * W : nullptr;
            const T *hd = Yo + 1 < hs ? hb + (size_t)((Yo + 1) % 3) * W : nullptr;
            if (b == 0) {
                // every sum is >= 0: the first bin wins a cell of zeros, as
                // against -1, so its sums are the row's start
                for (size_t c = 0; c < W; c++) {
                    vm[c] = (T)((hu ? hu[c] : 0) + hm[c] + (hd ? hd[c] : 0));
                    bm[c] = 0;
                }
                continue;
            }
            for (size_t c = 0; c < W; c++) {
                const T v = (T)((hu ? hu[c] : 0) + hm[c] + (hd ? hd[c] : 0));
                const bool gt = v > vm[c];
                vm[c] = gt ? v : vm[c];
                bm[c] = gt ? (T)b : bm[c];
            }
        }
    }
}

KERN2_CLONES void box_max(int32_t *acc, int nb, int hs, int ws, int32_t *pair, int32_t *h3,
                          int32_t *vmax, int32_t *bmax)
{
    box_max_t<int32_t>(acc, nb, hs, ws, pair, h3, vmax, bmax);
}

// The same in 16 bits (twice the lanes, half the memory), for an
// accumulator whose every sum of two bins fits 16 bits (see coarse).
KERN2_CLONES void box_max16(uint16_t *acc, int nb, int hs, int ws, uint16_t *pair, uint16_t *h3,
                            uint16_t *vmax, uint16_t *bmax)
{
    box_max_t<uint16_t>(acc, nb, hs, ws, pair, h3, vmax, bmax);
}

// box_max16 under box_max's name: the overload vote_peaks<T> calls for the
// 16-bit accumulator, so that one template serves both types.
inline void box_max(uint16_t *acc, int nb, int hs, int ws, uint16_t *pair, uint16_t *h3,
                    uint16_t *vmax, uint16_t *bmax)
{
    box_max16(acc, nb, hs, ws, pair, h3, vmax, bmax);
}

// The largest of v[0 .. n), n >= 1. A loop of its own so that it vectorises.
template <class T> inline __attribute__((always_inline)) T max_of_t(const T *v, size_t n)
{
    T m = v[0];
    for (size_t i = 1; i < n; i++) m = v[i] > m ? v[i] : m;
    return m;
}

KERN2_CLONES int32_t max_of(const int32_t *v, size_t n)
{
    return max_of_t(v, n);
}

// The same in 16 bits (the box sums of a 16-bit accumulator, read as they
// are: twice the lanes, and no copy to 32 bits).
KERN2_CLONES uint16_t max_of16(const uint16_t *v, size_t n)
{
    return max_of_t(v, n);
}

// Whether any of v[0 .. n) equals x. A loop of its own so that it vectorises.
template <class T> inline __attribute__((always_inline)) bool any_eq_t(const T *v, size_t n, T x)
{
    T hit = 0;
    for (size_t i = 0; i < n; i++) hit |= (T)(v[i] == x);
    return hit != 0;
}

KERN2_CLONES bool any_eq(const int32_t *v, size_t n, int32_t x)
{
    return any_eq_t(v, n, x);
}

KERN2_CLONES bool any_eq16(const uint16_t *v, size_t n, uint16_t x)
{
    return any_eq_t(v, n, x);
}

// The first index of x in v[0 .. n) (x is there): blocks looked at as a
// whole first (by any, the vector test for the element type), the one
// holding it then one by one.
template <class T, bool (*any)(const T *, size_t, T)> size_t first_of_t(const T *v, size_t n, T x)
{
    const size_t blk = 256;
    size_t i = 0;
    while (i + blk < n && !any(v + i, blk, x)) i += blk;
    while (v[i] != x) i++;
    return i;
}

size_t first_of(const int32_t *v, size_t n, int32_t x)
{
    return first_of_t<int32_t, any_eq>(v, n, x);
}

size_t first_of(const uint16_t *v, size_t n, uint16_t x)
{
    return first_of_t<uint16_t, any_eq16>(v, n, x);
}

inline int32_t max_of(const uint16_t *v, size_t n)
{
    return max_of16(v, n);
}

double rim_outside(double cx, double cy, double r, int h, int w);

// The peaks after the candidates down to this share of the best's votes are
// kept apart (weak): those whose circle is cut by the frame edge are judged
// as second spheres (preprocess.py WEAK_PEAK: the same value, and its
// measured reason).
constexpr double weak_peak = 0.25;

// The candidates from the box sums' per-cell largest (vmax) and its bin
// (bmax), planes of hs x ws in 16 or 32 bits: the strongest cell first, its
// radius from the votes, then the cells near it cleared; into out those with
// at least cand_frac of the best's votes, the weaker ones after them (down
// to weak_peak of it) into weak. vmax is cleared there.
template <class T>
void peaks(T *vmax, const T *bmax, const Edges &e, const std::vector<long> &start, int nb, int hs,
           int ws, int s, int h, int w, long gap_lo, const pp_params *p, std::vector<Cand> &out,
           std::vector<Cand> &weak)
{
    const size_t plane = (size_t)hs * ws;
    const double sup = p->cand_gap * (double)gap_lo;
    long best = -1;
    // a peak whose circle would be refused as cut by the frame edge is refined but does not use
    // up one of the `candidates` places (training/preprocess.py says why); 4 x candidates at most,
    // the weaker ones included
    for (int k = 0, taken = 0; k < 4 * p->candidates && taken < p->candidates; k++) {
        const int32_t v = max_of(vmax, plane);
        const size_t ci = first_of(vmax, plane, (T)v); // the first cell holding it
        if (v <= 0 || (best >= 0 && (double)v < std::min(weak_peak, p->cand_frac) * (double)best))
            break;
        if (best < 0) best = v;
        const bool strong = (double)v >= p->cand_frac * (double)best;
        const long Yc = (long)(ci / ws), Xc = (long)(ci % ws);
        const int b = bmax[ci];
        const long r_s =
            radius_vote(e, Xc, Yc, start[(size_t)b], start[(size_t)std::min(b + 2, nb)] - 1);
        bool cut = false;
        if (r_s >= 0) {
            const double off = (s - 1) / 2.0;
            std::vector<Cand> &to = strong ? out : weak;
            to.push_back({(double)(Xc * s) + off, (double)(Yc * s) + off, (double)(r_s * s), v});
            // only a candidate's cut decides its place (preprocess.py _coarse, likewise)
            cut = strong && rim_outside(to.back().cx, to.back().cy, to.back().r, h, w) > p->max_cut;
        }
        if (strong && !cut) taken++;
        const long R = ifloor(sup) + 1;
        for (long Y = std::max(0L, Yc - R); Y <= std::min((long)hs - 1, Yc + R); Y++)
            for (long X = std::max(0L, Xc - R); X <= std::min((long)ws - 1, Xc + R); X++) {
                const long d2 = (X - Xc) * (X - Xc) + (Y - Yc) * (Y - Yc);
                if ((double)d2 <= sup * sup) vmax[(size_t)Y * ws + X] = (T)0;
            }
    }
}

// The votes of the edges e (unit gradients ux, uy) at the signed radii srs
// (bin planes at boff) into a.acc, counted in T; then 3 x 3 box sums per bin
// (zeros outside), each bin plus the next, per cell its best bin (first on
// ties): the candidates from these into out (peaks). The box sum is linear:
// it is taken once of each bin plus the next. The accumulator is left zero.
template <class T>
void vote_peaks(Acc<T> &a, const Edges &e, const std::vector<double> &ux,
                const std::vector<double> &uy, const std::vector<double> &srs,
                const std::vector<int32_t> &boff, const std::vector<long> &start, int nb, int hs,
                int ws, int s, int h, int w, long gap_lo, const pp_params *p,
                std::vector<Cand> &out, std::vector<Cand> &weak)
{
    const size_t plane = (size_t)hs * ws, nv = srs.size();
    // the accumulator is left zero after each frame (box_max clears it)
    if (a.acc.size() < (size_t)nb * plane + nv) a.acc.assign((size_t)nb * plane + nv, 0);
    const size_t batch = 16; // edges per vote_cells call
    std::vector<int32_t> cell(batch * nv);
    // a vote outside the plane goes to one of the slots after the last bin, never read
    const int32_t trash = (int32_t)((size_t)nb * plane);
    T *acc = a.acc.data();
    for (size_t i = 0; i < e.n; i += batch) {
        const size_t m = std::min(batch, e.n - i);
        vote_cells(srs.data(), boff.data(), (int)nv, &e.x[i], &e.y[i], &ux[i], &uy[i], m, ws, hs,
                   trash, cell.data());
        const size_t nc = m * nv;
        for (size_t k = 0; k < nc; k++) acc[(size_t)cell[k]]++;
    }
    a.pair.resize((size_t)ws);
    a.h3.resize(3 * (size_t)nb * ws);
    a.vmax.resize(plane);
    a.bmax.resize(plane);
    box_max(acc, nb, hs, ws, a.pair.data(), a.h3.data(), a.vmax.data(), a.bmax.data());
    // the slots of the votes outside
    std::fill(acc + (size_t)nb * plane, acc + (size_t)nb * plane + nv, (T)0);
    peaks(a.vmax.data(), a.bmax.data(), e, start, nb, hs, ws, s, h, w, gap_lo, p, out, weak);
}

// Candidate circles, strongest first; the weaker peaks after them into weak
// (weak_peak); *s_out the reduction. A peak clears the centres within
// cand_gap times gap_r (reduced pixels, rounded down as the radii are)
// around it (preprocess.py _coarse).
std::vector<Cand> coarse(const uint8_t *bgr, size_t stride, int w, int h, const pp_params *p,
                         double rmin, double rmax, double gap_r, int *s_out,
                         std::vector<Cand> &weak)
{
    std::vector<Cand> out;
    const int s = std::max(1, std::min(h, w) / p->coarse_size);
    *s_out = s;
    int hs, ws;
    std::vector<uint8_t> &red = scratch.red;
    reduce(bgr, stride, w, h, s, red, &hs, &ws);
    if (hs < 8 || ws < 8) return out;
    thread_local Edges e;
    e.n = 0;
    // the accumulator the last frame used (frames of one size use the same)
    const uint8_t *pf = scratch.last16 ? (const uint8_t *)scratch.a16.acc.data()
                                       : (const uint8_t *)scratch.a32.acc.data();
    const size_t pf_len = scratch.last16 ? scratch.a16.acc.size() * sizeof(uint16_t)
                                         : scratch.a32.acc.size() * sizeof(int32_t);
    edges(red, hs, ws, p->edge_min, e, pf, pf_len);
    drop_stripes(e);
    if (e.n == 0) return out;
    const long lo = std::max(1L, ifloor(rmin / s));
    const long hi = ifloor(rmax / s) + 1;
    if (hi < lo) return out;
    const long gap_lo = std::max(1L, ifloor(gap_r / s));
    // radius bins about coarse_rbin * radius wide
    std::vector<int> bins;
    std::vector<long> start;
    {
        long st = lo;
        int b = 0;
        start.push_back(lo);
        for (long rho = lo; rho <= hi; rho++) {
            if ((double)rho > (double)st * (1.0 + p->coarse_rbin) && rho - st >= 2) {
                b++;
                st = rho;
                start.push_back(rho);
            }
            bins.push_back(b);
        }
        start.push_back(hi + 1);
    }
    const int nb = bins.back() + 1;
    const size_t plane = (size_t)hs * ws;
    const int nr = (int)(hi - lo + 1);
    // an edge votes once per radius and sign: a sum over two bins (a cell's
    // count, a box sum) is at most the edges times twice the radii of the
    // two widest neighbouring bins; below 2^16, 16 bits count exactly
    size_t widest = 0;
    for (int b = 0; b < nb; b++)
        widest = std::max(widest, (size_t)(start[(size_t)std::min(b + 2, nb)] - start[(size_t)b]));
    const bool narrow = e.n * 2 * widest < 65536;
    scratch.last16 = narrow;
    std::vector<double> srs(2 * (size_t)nr);
    std::vector<int32_t> boff(2 * (size_t)nr);
    for (int sg = 0; sg < 2; sg++)
        for (int k = 0; k < nr; k++) {
            srs[(size_t)sg * nr + k] = (sg == 0 ? 1.0 : -1.0) * (double)(lo + k);
            boff[(size_t)sg * nr + k] = (int32_t)((size_t)bins[(size_t)k] * plane);
        }
    thread_local std::vector<double> ux, uy;
    unit_gradients(e.gx.data(), e.gy.data(), e.n, ux, uy);
    if (narrow)
        vote_peaks(scratch.a16, e, ux, uy, srs, boff, start, nb, hs, ws, s, h, w, gap_lo, p, out,
                   weak);
    else
        vote_peaks(scratch.a32, e, ux, uy, srs, boff, start, nb, hs, ws, s, h, w, gap_lo, p, out,
                   weak);
    return out;
}

// ---- fine stage -----------------------------------------------------------------

struct Frame {
    const uint8_t *p;
    size_t stride;
    int w, h;
};

// Whether the bilinear sample at (X, Y) has all four corners inside the
// frame: X, Y in [0, w - 1) x [0, h - 1) (truncation is the floor there).
inline bool inside(const Frame &f, double X, double Y)
{
    return X >= 0.0 && Y >= 0.0 && X < f.w - 1 && Y < f.h - 1;
}

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "ray_gather reads bytes as words");

// Per sample of a ray from (cx, cy) along (ux, uy) at distances rho[0 ..
// ns), every sample inside the frame: the fractions of X and Y, and the
// corners as two 64-bit words (little-endian): wa from the top-left
// corner's first byte (p00's channel c at bit 8 c, p01's at 24 + 8 c), wb
// from two bytes before the bottom-left one (p10's at 16 + 8 c, p11's at 40
// + 8 c). Both stay within the frame's rows: wa ends at most 2 bytes past
// row y0's pixels (in row y0 + 1, which exists), wb starts in row y0 + 1 or
// at most 2 bytes before it.
KERN2_CLONES void ray_gather(const uint8_t *fp, int64_t st, double cx, double cy, double ux,
                             double uy, const double *rho, size_t ns, double *__restrict fx,
                             double *__restrict fy, uint64_t *__restrict wa,
                             uint64_t *__restrict wb)
{
    for (size_t j = 0; j < ns; j++) {
        const double X = cx + rho[j] * ux, Y = cy + rho[j] * uy;
        const int32_t x0 = (int32_t)X, y0 = (int32_t)Y;
        fx[j] = X - (double)x0;
        fy[j] = Y - (double)y0;
        const uint8_t *a = fp + ((int64_t)y0 * st + 3 * (int64_t)x0);
        std::memcpy(&wa[j], a, 8);
        std::memcpy(&wb[j], a + st - 2, 8);
    }
}

#ifdef CROP2_AVX512
// ray_gather with AVX-512's gather instructions (the compiler's vector loop
// reads the corners one by one): the same operations per sample, the same
// bytes. st below 2^31 (the row offset is a 32 x 32-bit product).
__attribute__((target("avx512f"))) void
ray_gather512(const uint8_t *fp, int64_t st, double cx, double cy, double ux, double uy,
              const double *rho, size_t ns, double *__restrict fx, double *__restrict fy,
              uint64_t *__restrict wa, uint64_t *__restrict wb)
{
    const __m512d vcx = _mm512_set1_pd(cx), vcy = _mm512_set1_pd(cy), vux = _mm512_set1_pd(ux),
                  vuy = _mm512_set1_pd(uy);
    const __m512i vst = _mm512_set1_epi64(st), vlow = _mm512_set1_epi64(st - 2);
    size_t j = 0;
    for (; j + 8 <= ns; j += 8) {
        const __m512d r = _mm512_loadu_pd(rho + j);
        const __m512d X = _mm512_add_pd(vcx, _mm512_mul_pd(r, vux));
        const __m512d Y = _mm512_add_pd(vcy, _mm512_mul_pd(r, vuy));
        const __m256i x0 = _mm512_cvttpd_epi32(X), y0 = _mm512_cvttpd_epi32(Y);
        _mm512_storeu_pd(fx + j, _mm512_sub_pd(X, _mm512_cvtepi32_pd(x0)));
        _mm512_storeu_pd(fy + j, _mm512_sub_pd(Y, _mm512_cvtepi32_pd(y0)));
        const __m512i x64 = _mm512_cvtepi32_epi64(x0), y64 = _mm512_cvtepi32_epi64(y0);
        const __m512i off = _mm512_add_epi64(_mm512_mul_epi32(y64, vst),
                                             _mm512_add_epi64(x64, _mm512_add_epi64(x64, x64)));
        _mm512_storeu_si512(wa + j, _mm512_i64gather_epi64(off, fp, 1));
        _mm512_storeu_si512(wb + j, _mm512_i64gather_epi64(_mm512_add_epi64(off, vlow), fp, 1));
    }
    if (j < ns) // the last ns % 8 samples, one by one
        ray_gather(fp, st, cx, cy, ux, uy, rho + j, ns - j, fx + j, fy + j, wa + j, wb + j);
}
#endif

// Bilinear interpolation of the three channels (preprocess.py _sample's
// operations and order) from ray_gather's words; v planar (channel c at v[c
// ns]). The bytes become doubles through their bits (no conversion
// instruction): the same values.
KERN2_CLONES void bilinear3(const uint64_t *__restrict wa, const uint64_t *__restrict wb,
                            const double *__restrict fx, const double *__restrict fy, size_t ns,
                            double *__restrict v)
{
    // a byte k as a double: the bits of 2^52 + k, less 2^52 (exact)
    const uint64_t two52 = 0x4330000000000000ull;
    const double d52 = 4503599627370496.0;
    auto byte = [&](uint64_t w, int sh) {
        const uint64_t u = ((w >> sh) & 255u) | two52;
        double d;
        std::memcpy(&d, &u, 8);
        return d - d52;
    };
    for (size_t j = 0; j < ns; j++) {
        const uint64_t a = wa[j], b = wb[j];
        for (int c = 0; c < 3; c++) {
            const double p00 = byte(a, 8 * c), p01 = byte(a, 24 + 8 * c), p10 = byte(b, 16 + 8 * c),
                         p11 = byte(b, 40 + 8 * c);
            const double top = p00 + fx[j] * (p01 - p00);
            const double bot = p10 + fx[j] * (p11 - p10);
            v[(size_t)c * ns + j] = top + fy[j] * (bot - top);
        }
    }
}

// pf[i] = 1 where score i (1 .. n - 2) is a local maximum of at least thr
// (at least its left neighbour, above its right one), else 0. A loop of
// its own so that it vectorises.
KERN2_CLONES void peak_flags(const double *score, long n, double thr, uint8_t *pf)
{
    for (long i = 1; i < n - 1; i++) {
        const double c = score[i];
        pf[i] = (uint8_t)((c >= thr) & (c >= score[i - 1]) & (c > score[i + 1]));
    }
}

// The colour step at samples 1 .. ns - 2: the largest channel difference of
// the samples either side (planar v: channel c at v[c * ns]).
KERN2_CLONES void step_score(const double *v, size_t ns, double *score)
{
    const double *b = v, *g = v + ns, *r = v + 2 * ns;
    for (size_t i = 0; i + 2 < ns; i++) {
        const double d0 = std::fabs(b[i + 2] - b[i]), d1 = std::fabs(g[i + 2] - g[i]),
                     d2 = std::fabs(r[i + 2] - r[i]);
        score[i] = std::max(std::max(d0, d1), d2);
    }
}

#ifdef CROP2_AVX512
// The local maxima of at least thr among score[1 .. n - 2] (see peak_flags)
// with AVX-512: each 16 scores' tests as one mask (the last block's loads
// masked to scores 1 .. n - 2 and their neighbours: no scalar tail), the
// indexes of those passing compressed in order into a register and stored
// whole, 16 slots from the count, not by a compressing store to memory
// (microcoded and slow on some CPUs, AMD Zen 4); their count returned. The
// count before score i is at most i - 1, so a store ends at most 15 slots
// past score n - 2's slot: within pk's n slots and 16 spare.
__attribute__((target("avx512f"))) long peaks512(const double *score, long n, double thr,
                                                 int32_t *pk)
{
    const __m512d vt = _mm512_set1_pd(thr);
    const __m512i step = _mm512_set_epi32(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0);
    long m = 0;
    for (long i = 1; i < n - 1; i += 16) {
        // the block's scores among 1 .. n - 2 (masked loads read nothing beyond their neighbours)
        const __mmask16 in =
            n - 1 - i >= 16 ? (__mmask16)0xFFFF : (__mmask16)((1u << (n - 1 - i)) - 1);
        __mmask16 k = 0;
        for (int h = 0; h < 2; h++) {
            const double *q = score + i + 8 * h;
            const __mmask8 ih = (__mmask8)(in >> (8 * h));
            const __m512d c = _mm512_maskz_loadu_pd(ih, q);
            const __mmask8 kh =
                ih & _mm512_cmp_pd_mask(c, vt, _CMP_GE_OQ) &
                _mm512_cmp_pd_mask(c, _mm512_maskz_loadu_pd(ih, q - 1), _CMP_GE_OQ) &
                _mm512_cmp_pd_mask(c, _mm512_maskz_loadu_pd(ih, q + 1), _CMP_GT_OQ);
            k = (__mmask16)(k | ((unsigned)kh << (8 * h)));
        }
        _mm512_storeu_si512(pk + m, _mm512_maskz_compress_epi32(
                                        k, _mm512_add_epi32(_mm512_set1_epi32((int)i), step)));
        m += __builtin_popcount((unsigned)k);
    }
    return m;
}
#endif

// Edge candidates per ray (see preprocess.py _ray_edges): ok[k] false for a
// ray that leaves the frame; cands of ray k in cand[off[k] .. off[k + 1]).
struct RayEdges {
    std::vector<char> ok;
    std::vector<int> off;
    std::vector<double> cand;
};

// The colour steps along rays (preprocess.py _ray_scores): n = 2 floor(2 win)
// + 1 scores centred on the samples at rho[1 .. n], rho[j] = r + (j - 1 -
// floor(2 win)) / 2.
struct RayScores {
    long n = 0;
    std::vector<double> rho, FX, FY, v, score;
    std::vector<uint64_t> WA, WB;
    std::vector<uint8_t> pf;
    std::vector<int32_t> pk;
    void setup(double r, double win)
    {
        const long m = ifloor(win * 2.0);
        n = 2 * m + 1;
        const size_t ns = (size_t)n + 2;
        rho.resize(ns);
        FX.resize(ns);
        FY.resize(ns);
        WA.resize(ns);
        WB.resize(ns);
        v.resize(3 * ns);
        score.resize((size_t)n);
        for (long j = 0; j < n + 2; j++) rho[(size_t)j] = r + ((double)(j - 1) - (double)m) * 0.5;
    }
    // the scores of the ray along (ux, uy) from (cx, cy); false when it leaves the frame
    bool ray(const Frame &f, double cx, double cy, double ux, double uy)
    {
        const size_t ns = (size_t)n + 2;
        // the samples lie on a segment: inside when both ends are (the
        // region [0, w - 1) x [0, h - 1) is convex)
        const double r0 = rho[0], r1 = rho[ns - 1];
        if (!inside(f, cx + r0 * ux, cy + r0 * uy) || !inside(f, cx + r1 * ux, cy + r1 * uy))
            return false;
#ifdef CROP2_AVX512
        if (avx512() && f.stride < ((size_t)1 << 31))
            ray_gather512(f.p, (int64_t)f.stride, cx, cy, ux, uy, rho.data(), ns, FX.data(),
                          FY.data(), WA.data(), WB.data());
        else
#endif
            ray_gather(f.p, (int64_t)f.stride, cx, cy, ux, uy, rho.data(), ns, FX.data(), FY.data(),
                       WA.data(), WB.data());
        bilinear3(WA.data(), WB.data(), FX.data(), FY.data(), ns, v.data());
        step_score(v.data(), ns, score.data());
        return true;
    }
    // the local maxima of at least thr among scores 1 .. n - 2, in order:
    // their indexes into pk[0 .. return value)
    long peaks(double thr)
    {
        pk.resize((size_t)n + 16); // 16 spare: peaks512's whole-vector stores
#ifdef CROP2_AVX512
        if (avx512()) return peaks512(score.data(), n, thr, pk.data());
#endif
        pf.resize((size_t)n);
        peak_flags(score.data(), n, thr, pf.data());
        long m = 0;
        for (long i = 1; i < n - 1; i++) {
            pk[(size_t)m] = (int32_t)i;
            m += pf[(size_t)i];
        }
        return m;
    }
    // the sub-pixel distance of the peak at score i (parabola)
    double peak_pos(long i) const
    {
        const double c = score[(size_t)i], a = score[(size_t)i - 1], b = score[(size_t)i + 1];
        const double den = a - 2.0 * c + b;
        const double o = den < 0.0 ? 0.5 * (a - b) / den : 0.0;
        return rho[(size_t)i + 1] + o * 0.5;
    }
};

// The median of v[0 .. n) (Python's: the mean of the two middle values of
// the sorted values); reorders v. A selection, not a sort: the same values.
double median_of(double *v, size_t n)
{
    const size_t hi = n / 2, lo = (n - 1) / 2;
    std::nth_element(v, v + hi, v + n);
    const double b = v[hi];
    const double a = lo == hi ? b : *std::max_element(v, v + hi);
    return (a + b) / 2.0;
}

// How many of v[0 .. n) have k v[i] <= t (k v[i] rounded). A loop of its own
// so that it vectorises.
KERN2_CLONES size_t count_scaled_le(const double *v, size_t n, double k, double t)
{
    size_t c = 0;
    for (size_t i = 0; i < n; i++) c += !(k * v[i] > t);
    return c;
}

// ratio > 0: only peaks of at least ratio times their ray's median step. The
// scores are an odd number (2 floor(2 win) + 1), so the median is the middle
// one, m, and c >= ratio m holds exactly when at least (n + 1) / 2 scores s
// have ratio s <= c (ratio s grows with s): counted, not sorted.
void ray_edges(const Frame &f, const std::vector<double> &dirs, double cx, double cy, double r,
               double win, double thr, double ratio, RayEdges &re)
{
    const int K = (int)dirs.size() / 2;
    thread_local RayScores rs;
    rs.setup(r, win);
    const long n = rs.n;
    re.ok.assign((size_t)K, 0);
    re.off.assign((size_t)K + 1, 0);
    re.cand.clear();
    for (int k = 0; k < K; k++) {
        re.off[(size_t)k] = (int)re.cand.size();
        if (!rs.ray(f, cx, cy, dirs[2 * (size_t)k], dirs[2 * (size_t)k + 1])) continue;
        re.ok[(size_t)k] = 1;
        const long np = rs.peaks(thr);
        for (long m = 0; m < np; m++) {
            const long i = rs.pk[(size_t)m];
            // (the position only of a peak kept)
            if (ratio > 0.0 && count_scaled_le(rs.score.data(), (size_t)n, ratio,
                                               rs.score[(size_t)i]) < (size_t)(n + 1) / 2)
                continue;
            re.cand.push_back(rs.peak_pos(i));
        }
    }
    re.off[(size_t)K] = (int)re.cand.size();
}

bool solve3(const double M[9], const double v[3], double x[3])
{
    const double a = M[0], b = M[1], c = M[2], d = M[3], e = M[4], f = M[5], g = M[6], h = M[7],
                 i = M[8];
    const double co0 = e * i - f * h, co1 = f * g - d * i, co2 = d * h - e * g;
    const double det = a * co0 + b * co1 + c * co2;
    if (!(std::fabs(det) > 1e-300)) return false;
    const double p = v[0], q = v[1], r = v[2];
    x[0] = (p * co0 + b * (f * r - q * i) + c * (q * h - e * r)) / det;
    x[1] = (a * (q * i - f * r) + p * co1 + c * (d * r - q * g)) / det;
    x[2] = (a * (e * r - q * h) + b * (q * g - d * r) + p * co2) / det;
    return true;
}

bool kasa(const std::vector<double> &x, const std::vector<double> &y,
          const std::vector<double> &wts, double *cx, double *cy, double *r)
{
    double sw = 0, sxx = 0, syy = 0, sxy = 0, sx = 0, sy = 0, sxz = 0, syz = 0, sz = 0;
    for (size_t i = 0; i < x.size(); i++) {
        const double wi = wts[i];
        if (wi == 0.0) continue;
        const double xi = x[i], yi = y[i];
        const double zi = xi * xi + yi * yi;
        sw += wi;
        sx += wi * xi;
        sy += wi * yi;
        sxx += wi * xi * xi;
        syy += wi * yi * yi;
        sxy += wi * xi * yi;
        sxz += wi * xi * zi;
        syz += wi * yi * zi;
        sz += wi * zi;
    }
    const double M[9] = {sxx, sxy, sx, sxy, syy, sy, sx, sy, sw}, v[3] = {sxz, syz, sz};
    double s[3];
    if (!solve3(M, v, s)) return false;
    const double ccx = s[0] / 2.0, ccy = s[1] / 2.0;
    const double rr = s[2] + ccx * ccx + ccy * ccy;
    if (!(rr > 0.0)) return false;
    *cx = ccx;
    *cy = ccy;
    *r = std::sqrt(rr);
    return true;
}

// e[i] = the distance of (px[i], py[i]) from (cx, cy), less r. A loop of
// its own so that it vectorises.
KERN2_CLONES void residuals(const double *__restrict px, const double *__restrict py, size_t n,
                            double cx, double cy, double r, double *__restrict e)
{
    for (size_t i = 0; i < n; i++)
        e[i] = std::sqrt((px[i] - cx) * (px[i] - cx) + (py[i] - cy) * (py[i] - cy)) - r;
}

// Tukey's biweight of res[i] / cut (0 outside (-1, 1)). A loop of its own
// so that it vectorises.
KERN2_CLONES void tukey_weights(const double *__restrict res, size_t n, double cut,
                                double *__restrict w)
{
    for (size_t i = 0; i < n; i++) {
        const double u = res[i] / cut;
        w[i] = (-1.0 < u && u < 1.0) ? (1.0 - u * u) * (1.0 - u * u) : 0.0;
    }
}

// The robust fit's weights of its residuals (preprocess.py _tukey_weights):
// Tukey's biweight at tukey_c times the scale, 1.4826 times the median
// |residual|, at least sigma_min_px. ares is scratch.
void robust_weights(const std::vector<double> &res, const pp_params *p, std::vector<double> &ares,
                    std::vector<double> &wts)
{
    const size_t na = res.size();
    ares.resize(na);
    for (size_t i = 0; i < na; i++) ares[i] = std::fabs(res[i]);
    // the scale is sigma_min_px when 1.4826 times the upper middle value
    // is not above it (the median is at most that value, and rounding is
    // monotonic): counted, the median taken only otherwise
    const double smin = p->sigma_min_px;
    double sigma = smin;
    if (count_scaled_le(ares.data(), na, 1.4826, smin) < na / 2 + 1)
        sigma = std::max(smin, 1.4826 * median_of(ares.data(), na));
    wts.resize(na);
    tukey_weights(res.data(), na, p->tukey_c * sigma, wts.data());
}

// Tukey-reweighted circle through the candidate nearest the current circle on
// each ray (preprocess.py _fit_rays). Rays from (ox, oy). Each candidate's
// point (rho ux, rho uy) is the same in every iteration: taken once; its
// residual for all candidates at once.
bool fit_rays(const RayEdges &re, const std::vector<double> &dirs, double ox, double oy,
              double *pcx, double *pcy, double *pr, const pp_params *p)
{
    const int K = (int)dirs.size() / 2;
    double cx = *pcx - ox, cy = *pcy - oy, r = *pr;
    thread_local std::vector<double> xs, ys, res, ares, wts, px, py, e;
    xs.reserve((size_t)K);
    ys.reserve((size_t)K);
    res.reserve((size_t)K);
    const size_t nc = re.cand.size();
    px.resize(nc);
    py.resize(nc);
    e.resize(nc);
    for (int k = 0; k < K; k++) {
        const double ux = dirs[2 * (size_t)k], uy = dirs[2 * (size_t)k + 1];
        for (int i = re.off[(size_t)k]; i < re.off[(size_t)k + 1]; i++) {
            px[(size_t)i] = re.cand[(size_t)i] * ux;
            py[(size_t)i] = re.cand[(size_t)i] * uy;
        }
    }
    for (int it = 0; it < p->irls_iters; it++) {
        xs.clear();
        ys.clear();
        res.clear();
        residuals(px.data(), py.data(), nc, cx, cy, r, e.data());
        for (int k = 0; k < K; k++) {
            const int a = re.off[(size_t)k], b = re.off[(size_t)k + 1];
            if (!re.ok[(size_t)k] || a == b) continue;
            // the first of the smallest |e| (finite: the circle comes from a fit;
            // preprocess.py's NaN are the padding of its ragged rays, here absent)
            int bi = a;
            double be = std::fabs(e[(size_t)a]);
            for (int i = a + 1; i < b; i++)
                if (std::fabs(e[(size_t)i]) < be) {
                    bi = i;
                    be = std::fabs(e[(size_t)i]);
                }
            xs.push_back(px[(size_t)bi]);
            ys.push_back(py[(size_t)bi]);
            res.push_back(e[(size_t)bi]);
        }
        if (xs.size() < 8) return false;
        robust_weights(res, p, ares, wts);
        if (!kasa(xs, ys, wts, &cx, &cy, &r)) return false;
    }
    *pcx = cx + ox;
    *pcy = cy + oy;
    *pr = r;
    return true;
}

// Radius bin of each candidate for one centre shift: floor(((rho - dot) -
// base) / step), Python's order, as the histogram slot it counts in: nb (a
// slot not looked at) when it is outside 0 .. nb - 1 or when the previous
// candidate is on the same ray (first[i] == 0) and in the same bin. A ray's
// candidates come in increasing rho, so their bins never decrease: a ray
// counts once per bin. inv: 1 / step when step is a power of two (then
// multiplying by it is dividing, exactly), else 0. A loop of its own so that
// it vectorises.
KERN2_CLONES void bin_slots(const double *rho, const double *ux, const double *uy,
                            const int32_t *first, size_t n, double DX, double DY, double base,
                            double step, double inv, int32_t nb, int32_t *bi, int32_t *slot)
{
    // values within a few hundred bins: floor32 is exact
    if (inv != 0.0)
        for (size_t i = 0; i < n; i++) {
            const double dot = DX * ux[i] + DY * uy[i];
            bi[i] = floor32(((rho[i] - dot) - base) * inv);
        }
    else
        for (size_t i = 0; i < n; i++) {
            const double dot = DX * ux[i] + DY * uy[i];
            bi[i] = floor32(((rho[i] - dot) - base) / step);
        }
    slot[0] = (bi[0] >= 0 && bi[0] < nb) ? bi[0] : nb;
    for (size_t i = 1; i < n; i++) {
        const int32_t b = bi[i], a = bi[i - 1];
        const int32_t keep = (b >= 0) & (b < nb) & ((first[i] != 0) | (b != a));
        slot[i] = keep ? b : nb;
    }
}

// The bins a candidate can fall in over a block of shifts about (DX, DY):
// lo[i] .. hi[i], from its bin at (DX, DY) less and plus hw[i] bins (the
// most dx ux + dy uy moves over the block, widened by far more than
// rounding). A loop of its own so that it vectorises.
KERN2_CLONES void bin_bounds(const double *rho, const double *ux, const double *uy,
                             const double *hw, size_t n, double DX, double DY, double base,
                             double rel, int32_t *lo, int32_t *hi)
{
    for (size_t i = 0; i < n; i++) {
        const double v = ((rho[i] - (DX * ux[i] + DY * uy[i])) - base) * rel;
        lo[i] = floor32(v - hw[i]);
        hi[i] = floor32(v + hw[i]);
    }
}

// The bins 0 .. top candidate i counts in over a block (its ray once per
// bin): klo[i] .. khi[i], none when klo[i] > khi[i]; from its bounds lo[i]
// .. hi[i] (bin_bounds), less those of the ray's earlier candidates. A ray's
// bounds never decrease along it (its candidates come in increasing rho), so
// the last bin its earlier candidates count in is the previous one's
// min(hi, top) (when that one counts in none, its bins are the earlier
// ones' already, or lie below 0, or above top as all later ones' do). A loop
// of its own so that it vectorises.
KERN2_CLONES void block_bins(const int32_t *lo, const int32_t *hi, const int32_t *first, size_t n,
                             int32_t top, int32_t *__restrict klo, int32_t *__restrict khi)
{
    for (size_t i = 0; i < n; i++) {
        const int32_t after = (i == 0 || first[i]) ? 0 : std::min(hi[i - 1], top) + 1;
        klo[i] = std::max(std::max(lo[i], 0), after);
        khi[i] = std::min(hi[i], top);
    }
}

// The (shift, radius) most rays agree on (preprocess.py _consensus): for
// each shift on the grid, the radius bin of each candidate, then the bin
// reached by the most rays (a ray counts once per bin: on a busy backdrop a
// few rays with many candidates would otherwise outvote the rim); first in
// grid order, then bin order, on ties.
bool consensus(const RayEdges &re, const std::vector<double> &dirs, double r, double win,
               double step, double *dx, double *dy, double *rr)
{
    const int K = (int)dirs.size() / 2;
    const long W = ifloor(win / step);
    const double base = r - ((double)W * step + win) - step;
    const long nb = ifloor(2.0 * ((double)W * step + win) / step) + 3;
    thread_local std::vector<double> ux, uy, rho;
    thread_local std::vector<int32_t> first, bi, slot, hist;
    ux.clear();
    uy.clear();
    rho.clear();
    first.clear();
    for (int k = 0; k < K; k++) {
        if (!re.ok[(size_t)k]) continue;
        for (int i = re.off[(size_t)k]; i < re.off[(size_t)k + 1]; i++) {
            ux.push_back(dirs[2 * (size_t)k]);
            uy.push_back(dirs[2 * (size_t)k + 1]);
            rho.push_back(re.cand[(size_t)i]);
            first.push_back(i == re.off[(size_t)k]);
        }
    }
    const size_t n = rho.size();
    if (n == 0) return false;
    int e;
    const double inv = std::frexp(step, &e) == 0.5 ? 1.0 / step : 0.0;
    const long G = 2 * W + 1;
    bi.resize(n);
    slot.resize(n);
    // four histograms, counted in turn and added: one count does not wait
    // for the previous one to the same bin
    const size_t hn = (size_t)nb + 1;
    hist.resize(4 * hn);
    int32_t *h0 = hist.data(), *h1 = h0 + hn, *h2 = h1 + hn, *h3 = h2 + hn;
    // Branch and bound over blocks of CB x CB shifts: for a block, the
    // bins each candidate can fall in over all its shifts (from the range of
    // dx ux + dy uy over the block, widened by far more than rounding) give
    // per bin the most rays any of its shifts can count there. Blocks are
    // counted shift by shift in decreasing order of that bound until it
    // falls below the best count so far: a block skipped holds no shift
    // reaching the best, so the (first in grid order, then bin order) winner
    // is the same as counting every shift.
    const long CB = 3, NBk = (G + CB - 1) / CB;
    thread_local std::vector<int32_t> diff, blo, bhi, klo, khi;
    thread_local std::vector<double> hw;
    thread_local std::vector<std::pair<long, long>> blocks;
    diff.resize(hn + 1);
    blo.resize(n);
    bhi.resize(n);
    klo.resize(n);
    khi.resize(n);
    hw.resize(n);
    blocks.clear();
    const double rel = 1.0 / step, half = (double)(CB - 1) / 2.0;
    for (size_t i = 0; i < n; i++) hw[i] = half * (std::fabs(ux[i]) + std::fabs(uy[i])) + 1e-6;
    for (long by = 0; by < NBk; by++)
        for (long bx = 0; bx < NBk; bx++) {
            // the block's middle (a block cut by the grid's end lies within
            // the same half-width of it)
            const double DX = ((double)(bx * CB - W) + half) * step;
            const double DY = ((double)(by * CB - W) + half) * step;
            bin_bounds(rho.data(), ux.data(), uy.data(), hw.data(), n, DX, DY, base, rel,
                       blo.data(), bhi.data());
            std::fill(diff.begin(), diff.end(), 0);
            block_bins(blo.data(), bhi.data(), first.data(), n, (int32_t)nb - 1, klo.data(),
                       khi.data());
            for (size_t i = 0; i < n; i++) {
                const int32_t lo = klo[i], hi = khi[i];
                if (lo > hi) continue;
                diff[(size_t)lo]++;
                diff[(size_t)hi + 1]--;
            }
            long run = 0, ub = 0;
            for (long b = 0; b < nb; b++) {
                run += diff[(size_t)b];
                ub = std::max(ub, run);
            }
            blocks.emplace_back(ub, by * NBk + bx);
        }
    std::stable_sort(blocks.begin(), blocks.end(),
                     [](const std::pair<long, long> &u, const std::pair<long, long> &v) {
                         return u.first > v.first;
                     });
    long best = 0, bg = -1, bb = 0;
    for (const auto &blk : blocks) {
        if (blk.first < best || blk.first == 0) break;
        const long by = blk.second / NBk, bx = blk.second % NBk;
        for (long gy = by * CB; gy < std::min(G, by * CB + CB); gy++)
            for (long gx = bx * CB; gx < std::min(G, bx * CB + CB); gx++) {
                const long g = gy * G + gx;
                const double DY = (double)(gy - W) * step, DX = (double)(gx - W) * step;
                bin_slots(rho.data(), ux.data(), uy.data(), first.data(), n, DX, DY, base, step,
                          inv, (int32_t)nb, bi.data(), slot.data());
                std::fill(hist.begin(), hist.end(), 0);
                size_t i = 0;
                for (; i + 4 <= n; i += 4) {
                    h0[slot[i]]++;
                    h1[slot[i + 1]]++;
                    h2[slot[i + 2]]++;
                    h3[slot[i + 3]]++;
                }
                for (; i < n; i++) h0[slot[i]]++;
                for (long b = 0; b < nb; b++) {
                    const long v = (long)h0[b] + h1[b] + h2[b] + h3[b];
                    if (v > best || (v == best && v > 0 && g < bg)) {
                        best = v;
                        bg = g;
                        bb = b;
                    }
                }
            }
    }
    if (bg < 0) return false;
    *dx = (double)(bg % G - W) * step;
    *dy = (double)(bg / G - W) * step;
    *rr = base + ((double)bb + 0.5) * step;
    return true;
}

// What the sphere's last step (last_step, outermost) needs of a circle's support
// rays (preprocess.py _ray_scores from its centre, +-support_flank_px), kept
// so that no ray is cast again: on each ray its colour step's peaks of at
// least ray_edge_min, their places and outer half-maxima (none on a ray that
// leaves the frame).
struct Rays {
    std::vector<int32_t> off;       // ray k's peaks: off[k] .. off[k + 1]
    std::vector<double> pos, outer; // their sub-pixel places, outer half-maxima
    std::vector<char> has;          // whether it has one (outer_half_max)
};

// The outer half-maximum of step peak i of scores sc (preprocess.py _rim):
// going outwards, the first place where the step falls to half the peak
// sample's, linear between samples; false when it does not within the
// window.
bool outer_half_max(const double *sc, const double *rho, long n, long i, double *o)
{
    const double hm = sc[i] / 2.0;
    long j = i;
    while (j + 1 < n && sc[j + 1] > hm) j++;
    if (j + 1 >= n) return false;
    *o = rho[j + 1] + (sc[j] - hm) / (sc[j] - sc[j + 1]) * 0.5;
    return true;
}

// The support's sides judged apart (preprocess.py _support): whether peak
// step c is at least ratio times the median of the quieter side's scores
// and at least every score of the busier one (the side of the higher
// median, outside on ties); sc the ray's scores, idx the flank's places,
// the ni inside r first, then the no outside it.
static bool sides_clear(const double *sc, const long *idx, size_t ni, size_t no, double ratio,
                        double c, std::vector<double> &tmp)
{
    tmp.resize(ni + no);
    for (size_t j = 0; j < ni + no; j++) tmp[j] = sc[(size_t)idx[j]];
    double in_max = tmp[0], out_max = tmp[ni];
    for (size_t j = 0; j < ni; j++) in_max = std::max(in_max, tmp[j]);
    for (size_t j = ni; j < ni + no; j++) out_max = std::max(out_max, tmp[j]);
    const double med_in = median_of(tmp.data(), ni), med_out = median_of(tmp.data() + ni, no);
    const double busy = med_in <= med_out ? out_max : in_max;
    return c >= ratio * std::min(med_in, med_out) && c >= busy;
}

// Support of a circle (preprocess.py _support): the fraction of all rays
// with a step peak within inlier_px of r of at least support_edge_min and
// support_ratio times the ray's median step 2 inlier_px to support_flank_px
// off r, or, inside and outside judged apart, at least support_ratio times
// the median of the quieter side (2 inlier_px to support_flank_px inside r,
// or outside it) and at least every step of the busier one (the side of the
// higher median, outside on ties): a busy backdrop's steps along the outer
// side hide in the whole flank's median a rim that stands out of the
// sphere's side. Each ray's peaks of at least ray_edge_min (sub-pixel place
// and outer half-maximum) go to *keep, for the sphere's last step. side
// (when not null): the sum of the supported rays' directions, in ray order
// (preprocess.py _tangent). only (when not null): the rays to look at; the
// others count as without support and keep no peaks, so such a *keep is
// never the sphere's (preprocess.py _beside_support).
double support(const Frame &f, const std::vector<double> &dirs, double cx, double cy, double r,
               const pp_params *p, Rays *keep, double side[2] = nullptr, const char *only = nullptr)
{
    const int K = (int)dirs.size() / 2;
    thread_local RayScores rs;
    thread_local std::vector<double> fl;
    thread_local std::vector<long> fi;
    thread_local std::vector<double> sides_tmp;
    thread_local std::vector<double> near;
    const double ratio = p->support_ratio;
    rs.setup(r, p->support_flank_px);
    const long n = rs.n;
    keep->off.assign((size_t)K + 1, 0);
    keep->pos.clear();
    keep->outer.clear();
    keep->has.clear();
    // the peaks of at least either threshold: those of the higher one are
    // among them (a peak is at least its threshold and its neighbours)
    const double thr = std::min(p->support_edge_min, p->ray_edge_min);
    // the flank's scores (the same places on every ray; the first ni of them
    // inside r, the others outside); none on a side: no ray has support,
    // whichever stay inside the frame
    fi.clear();
    for (long i = 0; i < n; i++)
        if (std::fabs(rs.rho[(size_t)i + 1] - r) >= 2.0 * p->inlier_px) fi.push_back(i);
    size_t ni = 0;
    while (ni < fi.size() && rs.rho[(size_t)fi[ni] + 1] - r < 0.0) ni++;
    const bool flank = ni > 0 && ni < fi.size();
    int cnt = 0;
    double sx = 0.0, sy = 0.0;
    // a supported ray: counted, its direction added in ray order (side)
    auto supported = [&](int k) {
        cnt++;
        sx += dirs[2 * (size_t)k];
        sy += dirs[2 * (size_t)k + 1];
    };
    for (int k = 0; k < K; k++) {
        keep->off[(size_t)k] = (int32_t)keep->pos.size();
        if (only && !only[k]) continue;
        if (!rs.ray(f, cx, cy, dirs[2 * (size_t)k], dirs[2 * (size_t)k + 1])) continue;
        // the peaks near the circle first: the median only for a ray with one
        near.clear();
        const long np = rs.peaks(thr);
        for (long m = 0; m < np; m++) {
            const long i = rs.pk[(size_t)m];
            const double c = rs.score[(size_t)i], pos = rs.peak_pos(i);
            if (c >= p->ray_edge_min) {
                double o = 0.0;
                keep->has.push_back(outer_half_max(rs.score.data(), rs.rho.data(), n, i, &o));
                keep->pos.push_back(pos);
                keep->outer.push_back(o);
            }
            if (c >= p->support_edge_min && std::fabs(pos - r) <= p->inlier_px) near.push_back(c);
        }
        if (!flank || near.empty()) continue;
        double cmax = near[0];
        for (const double c : near) cmax = std::max(cmax, c);
        const size_t nf = fi.size();
        fl.resize(nf);
        for (size_t j = 0; j < nf; j++) fl[j] = rs.score[(size_t)fi[j]];
        // ratio v grows with v (rounding is monotonic), so the flank values
        // with ratio v <= cmax are its smallest ones, and the threshold (ratio
        // times the mean of the middle two, (nf - 1) / 2 and nf / 2 in
        // order) lies between ratio times each of them: when both of them
        // are among those values the peak passes, when neither it fails;
        // counted, the median taken only otherwise
        bool whole;
        const size_t m = ratio >= 0.0 ? count_scaled_le(fl.data(), nf, ratio, cmax) : 0;
        if (ratio >= 0.0 && m >= nf / 2 + 1)
            whole = true;
        else if (ratio >= 0.0 && m < (nf - 1) / 2 + 1)
            whole = false;
        else
            whole = cmax >= ratio * median_of(fl.data(), nf);
        // else the flank's two sides judged apart
        if (whole || sides_clear(rs.score.data(), fi.data(), ni, nf - ni, ratio, cmax, sides_tmp))
            supported(k);
    }
    keep->off[(size_t)K] = (int32_t)keep->pos.size();
    if (side) {
        side[0] = sx;
        side[1] = sy;
    }
    return (double)cnt / K;
}

// Refine a coarse circle (preprocess.py _fine). False: none.
bool fine(const Frame &f, const std::vector<double> &dirs, const Cand &c, int s, const pp_params *p,
          Found *out, Rays *rays)
{
    double cx = c.cx, cy = c.cy, r = c.r;
    thread_local RayEdges re;
    for (int ps = 0; ps < p->fine_passes; ps++) {
        // first pass: the shift grid covers the coarse centre's error, the rays reach farther
        const double win = ps == 0 ? p->consensus_cells * s + p->consensus_px
                                   : p->fine_window_px + p->fine_window_frac * r;
        ray_edges(f, dirs, cx, cy, r, ps == 0 ? p->consensus_reach * win : win, p->ray_edge_min,
                  ps == 0 ? p->consensus_edge_ratio : 0.0, re);
        double sx = cx, sy = cy, sr = r;
        if (ps == 0) {
            double dx, dy, rr;
            if (!consensus(re, dirs, r, win, p->consensus_step_px, &dx, &dy, &rr)) return false;
            sx = cx + dx;
            sy = cy + dy;
            sr = rr;
        }
        if (!fit_rays(re, dirs, cx, cy, &sx, &sy, &sr, p)) return false;
        if (!(sr > 1.0)) return false;
        cx = sx;
        cy = sy;
        r = sr;
    }
    out->cx = cx;
    out->cy = cy;
    out->r = r;
    out->support = support(f, dirs, cx, cy, r, p, rays);
    return true;
}

// The weak fit's retries (grow, tangent) stop after this many rounds
// (training/preprocess.py GROW_ROUNDS: the same number): each round that
// moves raises the support, so they end anyway, but this bounds a frame's
// time.
constexpr int grow_rounds = 8;

// fine_passes - 1 passes, as after the first, from the circle (*cx, *cy, *r),
// which moves to the circle they reach (preprocess.py _passes). False: a fit
// failed.
bool passes_from(const Frame &f, const std::vector<double> &dirs, const pp_params *p, double *cx,
                 double *cy, double *r)
{
    thread_local RayEdges re;
    for (int ps = 0; ps < p->fine_passes - 1; ps++) {
        const double win = p->fine_window_px + p->fine_window_frac * *r;
        ray_edges(f, dirs, *cx, *cy, *r, win, p->ray_edge_min, 0.0, re);
        double sx = *cx, sy = *cy, sr = *r;
        if (!fit_rays(re, dirs, *cx, *cy, &sx, &sy, &sr, p) || !(sr > 1.0)) return false;
        *cx = sx;
        *cy = sy;
        *r = sr;
    }
    return true;
}

// A support that settles a fit, halfway from min_support to every ray: a
// weaker fit is tried again (grown, the first fit, tangent), and a coarse peak
// whose centre lies inside a fit this well supported is not refined
// (preprocess.py _decisive_support).
double decisive_support(const pp_params *p)
{
    return (1.0 + p->min_support) / 2.0;
}

// A weakly supported fit tried again from larger circles (preprocess.py
// _grow): from the same centre with the radius fine_window_px and 2
// fine_window_px larger, and when inward (a fit that was no sphere) then as
// much smaller too, fine_passes - 1 passes each; the best supported of the
// fit and these (the first on ties, the fit before them) is kept. True when
// one of these is. bank[slot] holds the support rays of fit (the slot-th
// fit) and then of the kept one, bank[spare] is free.
bool grow(const Frame &f, const std::vector<double> &dirs, const pp_params *p, Found *fit,
          std::vector<Rays> &bank, size_t slot, size_t spare, bool inward)
{
    bool moved = false;
    const Found start = *fit;
    static const int steps[4] = {1, 2, -1, -2};
    for (int t = 0; t < (inward ? 4 : 2); t++) {
        const int k = steps[t];
        double cx = start.cx, cy = start.cy, r = start.r + k * p->fine_window_px;
        if (!passes_from(f, dirs, p, &cx, &cy, &r)) continue;
        const double sup = support(f, dirs, cx, cy, r, p, &bank[spare]);
        if (sup > fit->support) {
            std::swap(bank[slot], bank[spare]);
            *fit = {cx, cy, r, sup};
            moved = true;
        }
    }
    return moved;
}

// *fit tried from grow's circles again and again (preprocess.py _grown): from
// the circle it moved to, while that is better supported and still below
// `until`, at most grow_rounds tries. bank[slot], bank[spare] as grow's.
void grown(const Frame &f, const std::vector<double> &dirs, const pp_params *p, Found *fit,
           std::vector<Rays> &bank, size_t slot, size_t spare, bool inward, double until)
{
    for (int k = 0; k < grow_rounds && fit->support < until &&
                    grow(f, dirs, p, fit, bank, slot, spare, inward);
         k++) {
    }
}

// The sphere's weakly supported fit tried again from larger circles
// internally tangent to it where its support lies (preprocess.py _tangent):
// where the limb darkens to the backdrop's level on one side, the fine passes
// can settle on a circle through that arc's inner steps and the rim on the lit
// side, off towards the lit side. The supported rays' directions, summed in
// ray order, point there; from the radius fine_window_px and 2
// fine_window_px larger with the centre as far the other way, fine_passes -
// 1 passes each, and that circle itself (where the dark arc's rim steps are
// weak, the passes from a circle on the rim slide back to the bands inside
// it: preprocess.py _tangent_tries), then the support; the best supported of
// the fit and these (the fit on ties, then the first) replaces it; again from
// the new circle while one replaced it and it is still below (1 +
// min_support) / 2, at most grow_rounds tries. For the sphere, after every decision, and in
// rescue, on a refused frame's best fit.
// *rays holds the support rays of *fit, and of the kept circle after;
// *spare is scratch.
void tangent(const Frame &f, const std::vector<double> &dirs, const pp_params *p, Found *fit,
             Rays *rays, Rays *spare)
{
    const double decisive = decisive_support(p);
    if (!(fit->support < decisive)) return;
    // the supported rays' directions: of the fit (its support again, the same value), then
    // of the circle that replaced it
    double side[2], tside[2];
    support(f, dirs, fit->cx, fit->cy, fit->r, p, spare, side);
    for (int t = 0; t < grow_rounds && fit->support < decisive; t++) {
        const double nm = std::sqrt(side[0] * side[0] + side[1] * side[1]);
        if (!(nm > 0.0)) break;
        const double ux = side[0] / nm, uy = side[1] / nm;
        const Found start = *fit;
        double nside[2] = {side[0], side[1]};
        bool moved = false;
        for (int k = 1; k <= 2; k++) {
            const double d = k * p->fine_window_px;
            const double sx = start.cx - d * ux, sy = start.cy - d * uy, sr = start.r + d;
            // the passes' circle, then the tangent circle itself
            for (int w = 0; w < 2; w++) {
                double cx = sx, cy = sy, r = sr;
                if (w == 0 && !passes_from(f, dirs, p, &cx, &cy, &r)) continue;
                const double sup = support(f, dirs, cx, cy, r, p, spare, tside);
                if (sup > fit->support) {
                    std::swap(*rays, *spare);
                    *fit = {cx, cy, r, sup};
                    nside[0] = tside[0];
                    nside[1] = tside[1];
                    moved = true;
                }
            }
        }
        if (!moved) break;
        side[0] = nside[0];
        side[1] = nside[1];
    }
}

// The sphere refitted through the outermost edges near it (preprocess.py
// _outermost), from its support's rays (from its centre, +-support_flank_px;
// none cast again): where an arc of the rim has no colour step, the rays there
// find a band inside it, and the fit through the candidates nearest it leans
// towards them. On each ray the outermost candidate from 1.5 inlier_px inside
// the current circle to `out` inlier_px outside, taken at the fit's first
// round and again at round irls_iters / 2 about the circle reached then, one
// robust fit through these, its last round at the floor scale (sigma_min_px)
// (the circle as it is when either pick has fewer than 8 rays or the fit
// fails; the previous round's when the last round would keep fewer than 8
// rays).
void outermost(const std::vector<double> &dirs, const pp_params *p, const Found &a,
               const Rays &rays, double out, double *ocx, double *ocy, double *orad)
{
    const int K = (int)dirs.size() / 2;
    thread_local std::vector<double> xs, ys, res, ares, wts;
    const double r = a.r, lo = -1.5 * p->inlier_px, hi = out * p->inlier_px;
    const int32_t *poff = rays.off.data();
    const double *pp = rays.pos.data();
    // one robust fit (as fit_rays), about the rays' origin, through on each
    // ray the outermost candidate within lo .. hi of the current circle, taken
    // at the first round and again after half the rounds
    double x = 0.0, y = 0.0, nr = r;
    bool fitted = true;
    for (int it = 0; it < p->irls_iters; it++) {
        res.clear();
        if (it == 0 || it == p->irls_iters / 2) {
            xs.clear();
            ys.clear();
            for (int k = 0; k < K; k++) {
                const double ux = dirs[2 * (size_t)k], uy = dirs[2 * (size_t)k + 1];
                bool any = false;
                double sx = 0.0, sy = 0.0, se = 0.0;
                for (int32_t m = poff[k]; m < poff[k + 1]; m++) {
                    const double c = pp[m];
                    const double px = c * ux - x, py = c * uy - y;
                    const double e = std::sqrt(px * px + py * py) - nr;
                    if (lo <= e && e <= hi) {
                        sx = c * ux;
                        sy = c * uy;
                        se = e;
                        any = true;
                    }
                }
                if (!any) continue;
                xs.push_back(sx);
                ys.push_back(sy);
                res.push_back(se);
            }
            if (xs.size() < 8) {
                fitted = false;
                break;
            }
        } else {
            res.resize(xs.size());
            residuals(xs.data(), ys.data(), xs.size(), x, y, nr, res.data());
        }
        if (it == p->irls_iters - 1) {
            // the last round at the floor scale (preprocess.py _tukey_floor_weights):
            // the circle now lies within the edges' noise of the rays that find the
            // rim, so a ray whose candidate is the limb's shading or a band tukey_c
            // sigma_min_px or more inside it drops out instead of pulling the circle
            // inwards; fewer than 8 rays left: the previous round's circle
            wts.resize(res.size());
            tukey_weights(res.data(), res.size(), p->tukey_c * p->sigma_min_px, wts.data());
            size_t kept = 0;
            for (double v : wts) kept += v > 0.0;
            if (kept < 8) break;
        } else {
            robust_weights(res, p, ares, wts);
        }
        if (!kasa(xs, ys, wts, &x, &y, &nr)) {
            fitted = false;
            break;
        }
    }
    *ocx = a.cx + x;
    *ocy = a.cy + y;
    *orad = nr;
    if (!fitted || !(nr > 1.0)) {
        *ocx = a.cx;
        *ocy = a.cy;
        *orad = r;
    }
}

// The sphere's circle, when supported below wide_below after tangent, is refitted
// through the outermost edges to wide_out inlier_px outside it, and the last step
// from that circle kept when more of its rims lie near its result (final_circle;
// a refused frame's best fit, in rescue: that circle when better supported)
// (preprocess.py WIDE_BELOW, WIDE_OUT: the same values, and their measured reason).
constexpr double wide_below = 0.86;
constexpr double wide_out = 3.0;

// A refused frame's best fit (rescue), when supported below wide_below,
// refitted through the outermost edges to wide_out inlier_px outside it
// (preprocess.py _wide): near the limb a texture band's edge runs along the
// rim a few pixels inside it, and the fit can settle on it along one arc.
// That circle replaces the fit when better supported (the sphere's is judged
// by its rims instead: final_circle). *rays holds the support rays of *fit,
// and of the kept circle after; *spare is scratch.
void wide(const Frame &f, const std::vector<double> &dirs, const pp_params *p, Found *fit,
          Rays *rays, Rays *spare)
{
    if (!(fit->support < wide_below)) return;
    double cx, cy, r;
    outermost(dirs, p, *fit, *rays, wide_out, &cx, &cy, &r);
    const double sup = support(f, dirs, cx, cy, r, p, spare);
    if (sup > fit->support) {
        std::swap(*rays, *spare);
        *fit = {cx, cy, r, sup};
    }
}

// The circle through the rims (xs, ys) (preprocess.py _through_rims), from the
// circle of radius *r about their origin: irls_iters rounds at the floor of
// the robust scale (a rim tukey_c sigma_min_px or more off drops out), each
// from the last; a round with fewer than 8 rims of weight or a failed fit ends
// it with the circle before. *x, *y, *r: the circle about the origin.
static void through_rims(const std::vector<double> &xs, const std::vector<double> &ys,
                         const pp_params *p, double *x, double *y, double *r)
{
    thread_local std::vector<double> res, wts;
    res.resize(xs.size());
    wts.resize(xs.size());
    *x = 0.0;
    *y = 0.0;
    for (int it = 0; it < p->irls_iters; it++) {
        residuals(xs.data(), ys.data(), xs.size(), *x, *y, *r, res.data());
        tukey_weights(res.data(), res.size(), p->tukey_c * p->sigma_min_px, wts.data());
        size_t used = 0;
        for (double v : wts) used += v > 0.0;
        double fx, fy, fr;
        if (used < 8 || !kasa(xs, ys, wts, &fx, &fy, &fr)) break;
        *x = fx;
        *y = fy;
        *r = fr;
    }
}

// Rims within rim_near inlier_px of the last step's circle judge it against
// another (preprocess.py RIM_NEAR: the same value, and its measured reason).
constexpr double rim_near = 0.5;

// The rims of rim() about the centre of circle (nx, ny, nr) (preprocess.py
// _rims), from the support rays of circle a (about a's centre): on each ray
// the peak nearest where the ray crosses the circle, its outer half-maximum
// less the edge half-width. xs, ys: the rims about (nx, ny); *r0: nr moved by
// the median of their distances from the circle. False with fewer than 8.
static bool rims(const std::vector<double> &dirs, const pp_params *p, const Found &a,
                 const Rays &rays, double nx, double ny, double nr, std::vector<double> &xs,
                 std::vector<double> &ys, double *r0)
{
    const int K = (int)dirs.size() / 2;
    thread_local std::vector<double> w, outer;
    const int32_t *poff = rays.off.data();
    const double *pp = rays.pos.data();
    // the rim, on each ray near where it crosses the new circle (outer: NaN
    // for a ray without)
    const double dx = nx - a.cx, dy = ny - a.cy;
    outer.assign((size_t)K, std::nan(""));
    w.clear();
    for (int k = 0; k < K; k++) {
        if (poff[k] == poff[k + 1]) continue;
        const double ux = dirs[2 * (size_t)k], uy = dirs[2 * (size_t)k + 1];
        const double du = dx * ux + dy * uy;
        const double q = du * du - (dx * dx + dy * dy) + nr * nr;
        if (!(q >= 0.0)) continue;
        const double t = du + std::sqrt(q);
        int32_t best = -1;
        double be = 0.0;
        for (int32_t m = poff[k]; m < poff[k + 1]; m++) {
            const double e = std::fabs(pp[m] - t);
            if (e <= p->inlier_px && (best < 0 || e < be)) {
                best = m;
                be = e;
            }
        }
        if (best < 0 || !rays.has[(size_t)best]) continue;
        outer[(size_t)k] = rays.outer[(size_t)best];
        w.push_back(rays.outer[(size_t)best] - pp[best]);
    }
    const size_t m = w.size();
    if (m < 8) return false;
    std::nth_element(w.begin(), w.begin() + (long)((m - 1) / 2), w.end());
    const double hw = w[(m - 1) / 2];
    w.clear();  // now the rims' distances from the circle, in ray order
    xs.clear(); // and the rims about the new centre
    ys.clear();
    for (int k = 0; k < K; k++)
        if (!std::isnan(outer[(size_t)k])) {
            const double ex = a.cx + (outer[(size_t)k] - hw) * dirs[2 * (size_t)k] - nx;
            const double ey = a.cy + (outer[(size_t)k] - hw) * dirs[2 * (size_t)k + 1] - ny;
            xs.push_back(ex);
            ys.push_back(ey);
            w.push_back(std::sqrt(ex * ex + ey * ey) - nr);
        }
    *r0 = nr + median_of(w.data(), w.size());
    return true;
}

// The covariance of the centre of circle (x, y, r) fitted through the rims
// (xs, ys) (preprocess.py _centre_covariance): s2 times the centre's block of
// (J^T W J)^-1, J each rim's residual's derivatives by x, y, r, W the Tukey
// weights at the floor of the robust scale, s2 the weighted mean square
// residual over sum(W) - 3. False with fewer than 8 rims of weight or no
// inverse.
static bool centre_covariance(const std::vector<double> &xs, const std::vector<double> &ys,
                              double x, double y, double r, const pp_params *p, double cov[3])
{
    thread_local std::vector<double> dist, res, wts;
    const size_t n = xs.size();
    dist.resize(n);
    res.resize(n);
    wts.resize(n);
    for (size_t i = 0; i < n; i++) {
        dist[i] = std::sqrt((xs[i] - x) * (xs[i] - x) + (ys[i] - y) * (ys[i] - y));
        res[i] = dist[i] - r;
    }
    tukey_weights(res.data(), n, p->tukey_c * p->sigma_min_px, wts.data());
    double a00 = 0.0, a01 = 0.0, a02 = 0.0, a11 = 0.0, a12 = 0.0, sw = 0.0, sq = 0.0;
    int used = 0;
    for (size_t i = 0; i < n; i++) {
        const double wi = wts[i];
        if (wi == 0.0) continue;
        used++;
        const double jx = -(xs[i] - x) / dist[i], jy = -(ys[i] - y) / dist[i]; // and -1 by r
        a00 += wi * jx * jx;
        a01 += wi * jx * jy;
        a02 -= wi * jx;
        a11 += wi * jy * jy;
        a12 -= wi * jy;
        sw += wi;
        sq += wi * res[i] * res[i];
    }
    if (used < 8 || !(sw > 3.0)) return false;
    const double c00 = a11 * sw - a12 * a12;
    const double c01 = a02 * a12 - a01 * sw;
    const double c11 = a00 * sw - a02 * a02;
    const double det = a00 * c00 + a01 * c01 + a02 * (a01 * a12 - a11 * a02);
    if (!(det > 0.0)) return false;
    const double s2 = sq / (sw - 3.0);
    cov[0] = s2 * c00 / det;
    cov[1] = s2 * c01 / det;
    cov[2] = s2 * c11 / det;
    return true;
}

// The circle (nx, ny, nr) moved to the rim (preprocess.py _rim): refitted
// through its rims (rims(); through_rims: the steps lean inwards where the
// limb darkens to the backdrop's level, the rims do not). Returns how many
// rims lie within rim_near inlier_px of the circle (0 with fewer than 8
// rims: the circle unchanged). cov (when not null): the refitted centre's
// covariance from the rims (centre_covariance), NaN when there is none.
static int rim(const std::vector<double> &dirs, const pp_params *p, const Found &a,
               const Rays &rays, double nx, double ny, double nr, double *ocx, double *ocy,
               double *orad, double *cov = nullptr)
{
    thread_local std::vector<double> xs, ys, w;
    *ocx = nx;
    *ocy = ny;
    *orad = nr;
    if (cov) cov[0] = cov[1] = cov[2] = std::nan("");
    double x, y, r;
    if (!rims(dirs, p, a, rays, nx, ny, nr, xs, ys, &r)) return 0;
    through_rims(xs, ys, p, &x, &y, &r);
    if (cov && !centre_covariance(xs, ys, x, y, r, p, cov)) cov[0] = cov[1] = cov[2] = std::nan("");
    *ocx = nx + x;
    *ocy = ny + y;
    *orad = r;
    // the rims near it
    w.resize(xs.size());
    residuals(xs.data(), ys.data(), xs.size(), x, y, r, w.data());
    int near = 0;
    for (double v : w) near += std::fabs(v) <= rim_near * p->inlier_px;
    return near;
}

// The last step from circle a (preprocess.py _last_step), from its support's
// rays: refitted through the outermost edges near it (outermost, to 2
// inlier_px outside), then that circle moved to the rim (rim). Returns rim's
// count of the rims near the result.
static int last_step(const std::vector<double> &dirs, const pp_params *p, const Found &a,
                     const Rays &rays, double *ocx, double *ocy, double *orad)
{
    double nx, ny, nr;
    outermost(dirs, p, a, rays, 2.0, &nx, &ny, &nr);
    return rim(dirs, p, a, rays, nx, ny, nr, ocx, ocy, orad);
}

// The sphere's circle (preprocess.py _final_circle, whose covariance the caller
// takes here from the same rays): the last step from its
// fit a and, when a is supported below wide_below, from a refitted through
// the outermost edges of the wider band (wide_out, about a's support's rays);
// the wider band's circle when more of its rims lie near it, else the fit's.
// Not tried when the wider refit failed (its circle is a's). rays: a's
// support's rays; *spare: scratch.
void final_circle(const Frame &f, const std::vector<double> &dirs, const pp_params *p,
                  const Found &a, const Rays &rays, Rays *spare, double *ocx, double *ocy,
                  double *orad)
{
    const int near = last_step(dirs, p, a, rays, ocx, ocy, orad);
    if (!(a.support < wide_below)) return;
    Found w = a;
    outermost(dirs, p, a, rays, wide_out, &w.cx, &w.cy, &w.r);
    if (w.cx == a.cx && w.cy == a.cy && w.r == a.r) return;
    // its own support's rays, as the fit's (the support itself decides nothing here)
    w.support = support(f, dirs, w.cx, w.cy, w.r, p, spare);
    double cx, cy, r;
    if (last_step(dirs, p, w, *spare, &cx, &cy, &r) > near) {
        *ocx = cx;
        *ocy = cy;
        *orad = r;
    }
}

// How much brighter a circle's inside is than its edge (preprocess.py
// _limb_shading): over the rays whose samples all lie in the frame, the
// median of each ray's brightest sample (largest channel) from r/4 to 3r/4
// (r/4 + i) over the median of its brightest from support_flank_px to 2
// inlier_px inside the circle (r - i/2), the latter at least 1. False with
// fewer than 8 such rays.
bool limb_shading(const Frame &f, const std::vector<double> &dirs, double cx, double cy, double r,
                  const pp_params *p, double *shade)
{
    const int K = (int)dirs.size() / 2;
    const long ni = ifloor(r * 0.5) + 1;
    const long e0 = (long)std::ceil(4.0 * p->inlier_px), e1 = ifloor(2.0 * p->support_flank_px);
    if (e1 < e0) return false;
    const size_t ns = (size_t)ni + (size_t)(e1 - e0 + 1);
    std::vector<double> rho(ns), fx(ns), fy(ns), v(3 * ns), inner, edge;
    std::vector<uint64_t> wa(ns), wb(ns);
    for (long i = 0; i < ni; i++) rho[(size_t)i] = r * 0.25 + (double)i;
    for (long i = e0; i <= e1; i++) rho[(size_t)(ni + i - e0)] = r - 0.5 * (double)i;
    for (int k = 0; k < K; k++) {
        const double ux = dirs[2 * (size_t)k], uy = dirs[2 * (size_t)k + 1];
        bool in = true;
        for (size_t j = 0; j < ns && in; j++) in = inside(f, cx + rho[j] * ux, cy + rho[j] * uy);
        if (!in) continue;
        ray_gather(f.p, (int64_t)f.stride, cx, cy, ux, uy, rho.data(), ns, fx.data(), fy.data(),
                   wa.data(), wb.data());
        bilinear3(wa.data(), wb.data(), fx.data(), fy.data(), ns, v.data());
        double bi = 0.0, be = 0.0;
        for (size_t j = 0; j < ns; j++) {
            const double b = std::max(std::max(v[j], v[ns + j]), v[2 * ns + j]);
            if (j < (size_t)ni)
                bi = j == 0 ? b : std::max(bi, b);
            else
                be = j == (size_t)ni ? b : std::max(be, b);
        }
        inner.push_back(bi);
        edge.push_back(be);
    }
    if (inner.size() < 8) return false;
    *shade =
        median_of(inner.data(), inner.size()) / std::max(1.0, median_of(edge.data(), edge.size()));
    return true;
}

// A second circle's shading above 1 below limb_share of the sphere's, when the
// sphere's is at least limb_min, is flat (preprocess.py LIMB_SHARE, LIMB_MIN:
// the same values, and their measured reason).
constexpr double limb_share = 0.25;
constexpr double limb_min = 1.25;

// Sphere a's and circle b's shading (limb_shading), to compare b's with a's
// (preprocess.py _shadings): false when a's is unknown or below limb_min (a
// sphere over-exposed to its rim shows none, and then nothing is told apart)
// or b's is unknown.
static bool shadings(const Frame &f, const std::vector<double> &dirs, const Found &a,
                     const Found &b, const pp_params *p, double *sa, double *sb)
{
    return limb_shading(f, dirs, a.cx, a.cy, a.r, p, sa) && *sa >= limb_min &&
           limb_shading(f, dirs, b.cx, b.cy, b.r, p, sb);
}

// Whether circle b's inside is flat where sphere a's darkens towards its rim
// (preprocess.py _flat): then b is no second sphere.
bool flat(const Frame &f, const std::vector<double> &dirs, const Found &a, const Found &b,
          const pp_params *p)
{
    double sa, sb;
    return shadings(f, dirs, a, b, p, &sa, &sb) && sb - 1.0 < limb_share * (sa - 1.0);
}

double rim_outside(double cx, double cy, double r, int h, int w)
{
    // the 256 directions, computed once per thread
    thread_local const std::vector<double> d = ray_dirs(256);
    int out = 0;
    for (int k = 0; k < 256; k++) {
        const double X = cx + r * d[2 * (size_t)k], Y = cy + r * d[2 * (size_t)k + 1];
        if (X < 0 || X > w - 1 || Y < 0 || Y > h - 1) out++;
    }
    return out / 256.0;
}

// A second sphere partly outside the frame is judged by its rays in the
// frame when at least this share of them are in it (training/preprocess.py
// SECOND_IN_FRAME: the same value, and its measured reason).
constexpr double second_in_frame = 0.7;

// The sphere's circle cut by the frame edge is named as one only when its
// inside is no darker than its edge (preprocess.py CUT_SHADE: the same)
// and it shows the texture's bands: texture_steps at least cut_texture, or
// too few rays in the frame to tell (preprocess.py CUT_TEXTURE: the same
// value, and its measured reason).
constexpr double cut_shade = 1.0;
constexpr double cut_texture = 2.0;

// A circle of the sphere's size beside it, supported by at least this share
// of the rays but below min_support, is tried again as the sphere's weak fit
// is before it is ruled out as a second sphere (preprocess.py SECOND_RETRY:
// the same value, and its measured reason).
constexpr double second_retry = 0.25;

// Such a circle still below min_support, with at least this share of
// support and of beside support, is a second sphere too when it looks like
// the sphere: shading above 1 at least weak_share of the sphere's, texture
// within texture_tol of it (preprocess.py SECOND_WEAK, WEAK_SHARE,
// TEXTURE_TOL: the same values, and their measured reason).
constexpr double second_weak = 0.30;
constexpr double weak_share = 0.5;
constexpr double texture_tol = 1.0;

// How many rays from (cx, cy) keep the support's samples (RayScores within
// support_flank_px of r) in the frame: both ends inside, as RayScores::ray
// tests them (preprocess.py _in_frame).
int in_frame(const Frame &f, const std::vector<double> &dirs, double cx, double cy, double r,
             const pp_params *p)
{
    const int K = (int)dirs.size() / 2;
    const long m = ifloor(p->support_flank_px * 2.0);
    const double r0 = r + (-1.0 - (double)m) * 0.5, r1 = r + (double)(m + 1) * 0.5;
    int n = 0;
    for (int k = 0; k < K; k++) {
        const double ux = dirs[2 * (size_t)k], uy = dirs[2 * (size_t)k + 1];
        n += inside(f, cx + r0 * ux, cy + r0 * uy) && inside(f, cx + r1 * ux, cy + r1 * uy);
    }
    return n;
}

// A support sup of circle c (a share of all its rays: its own, or its beside
// support) over its rays in the frame (*s; its supported rays are among
// them), when at least `share` of its rays are in the frame; false otherwise
// (preprocess.py _in_frame_support).
bool in_frame_support(const Frame &f, const std::vector<double> &dirs, const Found &c, double sup,
                      const pp_params *p, double share, double *s)
{
    const int K = (int)dirs.size() / 2;
    const int n = in_frame(f, dirs, c.cx, c.cy, c.r, p);
    if (n == 0 || n < share * K) return false;
    *s = sup * K / n;
    return true;
}

// Circle b's support with its rays whose point on b lies on sphere a's disc
// counted as without: there a's texture or rim is no rim of b's (a sphere
// behind a is hidden there, as the post hides the sphere's own rim). b's
// support itself when the circles do not overlap (preprocess.py
// _beside_support). *spare: scratch.
double beside_support(const Frame &f, const std::vector<double> &dirs, const Found &a,
                      const Found &b, const pp_params *p, Rays *spare)
{
    const double dx = b.cx - a.cx, dy = b.cy - a.cy;
    if (dx * dx + dy * dy >= (a.r + b.r) * (a.r + b.r)) return b.support;
    const int K = (int)dirs.size() / 2;
    thread_local std::vector<char> off;
    off.resize((size_t)K);
    for (int k = 0; k < K; k++) {
        const double X = b.cx + b.r * dirs[2 * (size_t)k], Y = b.cy + b.r * dirs[2 * (size_t)k + 1];
        off[(size_t)k] = (X - a.cx) * (X - a.cx) + (Y - a.cy) * (Y - a.cy) >= a.r * a.r;
    }
    return support(f, dirs, b.cx, b.cy, b.r, p, spare, nullptr, off.data());
}

// Whether circle c may be a lit sphere cut by the frame edge: its inside no
// darker than its edge, or too little of it in the frame to tell
// (preprocess.py _lit).
bool lit(const Frame &f, const std::vector<double> &dirs, const Found &c, const pp_params *p)
{
    double s;
    return !limb_shading(f, dirs, c.cx, c.cy, c.r, p, &s) || s >= cut_shade;
}

// Whether circles a and b may be two spheres by their geometry: neither
// centre inside the other circle, radii within a factor 1 + 2 r_tol
// (preprocess.py _apart).
bool apart(const Found &a, const Found &b, const pp_params *p)
{
    const double rr = std::max(a.r, b.r);
    if ((a.cx - b.cx) * (a.cx - b.cx) + (a.cy - b.cy) * (a.cy - b.cy) < rr * rr) return false;
    return std::max(a.r, b.r) <= (1.0 + 2.0 * p->r_tol) * std::min(a.r, b.r);
}

// A second circle is a second sphere only when its colours are the
// sphere's: the shares of colour_rings rings of samples at equal areas out
// to colour_reach r in 12 hue bins, dark or light, within colour_tol in all
// (preprocess.py COLOUR_RINGS ... COLOUR_TOL: the same values, and their
// measured reason).
constexpr int colour_rings = 8;
constexpr double colour_reach = 0.8;
constexpr double colour_in_frame = 0.9;
constexpr double colour_quantile = 0.95;
constexpr double colour_sat = 0.35;
constexpr double colour_dark = 0.35;
constexpr double colour_tol = 0.75;

// The shares of circle c's samples (bilinear, those in the frame) in the 14
// colour bins: a hue bin of 30 degrees when coloured (largest minus smallest
// channel above colour_sat of the largest), else dark (largest channel below
// colour_dark of the samples' colour_quantile quantile of it) or light
// (preprocess.py _colours). False with fewer than colour_in_frame of them in
// the frame.
static bool colours(const Frame &f, const std::vector<double> &dirs, const Found &c,
                    double share[14])
{
    const int K = (int)dirs.size() / 2;
    double rho[colour_rings], in_rho[colour_rings], fx[colour_rings], fy[colour_rings],
        v[3 * colour_rings];
    uint64_t wa[colour_rings], wb[colour_rings];
    thread_local std::vector<double> bgr, mx, srt;
    for (int i = 0; i < colour_rings; i++)
        rho[i] = c.r * colour_reach * std::sqrt((i + 0.5) / colour_rings);
    bgr.clear();
    for (int k = 0; k < K; k++) {
        const double ux = dirs[2 * (size_t)k], uy = dirs[2 * (size_t)k + 1];
        size_t m = 0;
        for (int i = 0; i < colour_rings; i++)
            if (inside(f, c.cx + rho[i] * ux, c.cy + rho[i] * uy)) in_rho[m++] = rho[i];
        if (!m) continue;
        ray_gather(f.p, (int64_t)f.stride, c.cx, c.cy, ux, uy, in_rho, m, fx, fy, wa, wb);
        bilinear3(wa, wb, fx, fy, m, v);
        for (size_t j = 0; j < m; j++) {
            bgr.push_back(v[j]);
            bgr.push_back(v[m + j]);
            bgr.push_back(v[2 * m + j]);
        }
    }
    const size_t n = bgr.size() / 3;
    if ((double)n < colour_in_frame * (double)(K * colour_rings)) return false;
    mx.resize(n);
    for (size_t j = 0; j < n; j++)
        mx[j] = std::max(std::max(bgr[3 * j], bgr[3 * j + 1]), bgr[3 * j + 2]);
    srt = mx;
    const size_t q = (size_t)std::floor(colour_quantile * (double)(n - 1));
    std::nth_element(srt.begin(), srt.begin() + (long)q, srt.end());
    const double vref = srt[q];
    long counts[14] = {0};
    for (size_t j = 0; j < n; j++) {
        const double b = bgr[3 * j], g = bgr[3 * j + 1], r = bgr[3 * j + 2], hi = mx[j];
        const double lo = std::min(std::min(b, g), r);
        if (hi - lo > colour_sat * hi) {
            const double d = hi - lo;
            double h = (hi == r   ? (g - b) / d
                        : hi == g ? 2.0 + (b - r) / d
                                  : 4.0 + (r - g) / d) *
                       60.0;
            if (h < 0.0) h += 360.0;
            counts[(int)std::min(std::floor(h / 30.0), 11.0)]++;
        } else if (hi < colour_dark * vref) {
            counts[12]++;
        } else {
            counts[13]++;
        }
    }
    for (int i = 0; i < 14; i++) share[i] = (double)counts[i] / (double)n;
    return true;
}

// Whether circle b's colours are sphere a's (colours within colour_tol, the
// shares' differences summed in order), or either circle has too few samples
// in the frame to tell (preprocess.py _alike).
static bool alike(const Frame &f, const std::vector<double> &dirs, const Found &a, const Found &b)
{
    double ca[14], cb[14];
    if (!colours(f, dirs, a, ca) || !colours(f, dirs, b, cb)) return true;
    double t = 0.0;
    for (int i = 0; i < 14; i++) t += std::fabs(ca[i] - cb[i]);
    return t <= colour_tol;
}

// Whether circle b is a second sphere beside sphere a: apart, b's inside not
// flat where a's is shaded, its colours a's (preprocess.py _second).
bool second(const Frame &f, const std::vector<double> &dirs, const Found &a, const Found &b,
            const pp_params *p)
{
    return apart(a, b, p) && !flat(f, dirs, a, b, p) && alike(f, dirs, a, b);
}

// second, and b's beside support at least min_support (computed last, only then: it is costly;
// preprocess.py _second_beside). *spare: scratch.
bool second_beside(const Frame &f, const std::vector<double> &dirs, const Found &a, const Found &b,
                   const pp_params *p, Rays *spare)
{
    return second(f, dirs, a, b, p) && beside_support(f, dirs, a, b, p, spare) >= p->min_support;
}

// The median, over circle c's rays that stay in the frame, of the number of
// colour steps (ray_edges' candidates) from 0.2 r to 0.8 r from its
// centre: the printed texture's bands; false with fewer than 8 such rays
// (preprocess.py _texture_steps).
bool texture_steps(const Frame &f, const std::vector<double> &dirs, const Found &c,
                   const pp_params *p, double *steps)
{
    const int K = (int)dirs.size() / 2;
    thread_local RayEdges re;
    thread_local std::vector<double> n;
    ray_edges(f, dirs, c.cx, c.cy, 0.5 * c.r, 0.3 * c.r, p->ray_edge_min, 0.0, re);
    n.clear();
    for (int k = 0; k < K; k++)
        if (re.ok[(size_t)k]) n.push_back((double)(re.off[(size_t)k + 1] - re.off[(size_t)k]));
    if (n.size() < 8) return false;
    *steps = median_of(n.data(), n.size());
    return true;
}

// Whether circle c may be a sphere by its inside: its texture steps at least
// cut_texture, or too few of its rays in the frame to tell (preprocess.py
// _textured).
bool textured(const Frame &f, const std::vector<double> &dirs, const Found &c, const pp_params *p)
{
    double t;
    return !texture_steps(f, dirs, c, p, &t) || t >= cut_texture;
}

// Whether circle b, below min_support, is a second sphere beside sphere a by
// its likeness to it: apart, lit as a is, textured and coloured as a is, and its beside
// support at least second_weak (computed last: it is costly; preprocess.py
// _weak_second). *spare: scratch.
bool weak_second(const Frame &f, const std::vector<double> &dirs, const Found &a, const Found &b,
                 const pp_params *p, Rays *spare)
{
    double sa, sb, ta, tb;
    if (!apart(a, b, p)) return false;
    if (!shadings(f, dirs, a, b, p, &sa, &sb) || !(sb - 1.0 >= weak_share * (sa - 1.0)))
        return false;
    if (!texture_steps(f, dirs, a, p, &ta) || !texture_steps(f, dirs, b, p, &tb) ||
        !(std::fabs(ta - tb) <= texture_tol) || !alike(f, dirs, a, b))
        return false;
    return beside_support(f, dirs, a, b, p, spare) >= second_weak;
}

// The first fit (of the strongest coarse peak that gave one) tried again as the best one is
// (grown), in place in all[0], when its support is below decisive_support, it is not the best
// (all[ib], after its tries), the best has at least min_support and holds its centre: a weaker
// peak's fit through part of the rim and the texture inside can beat the sphere's own weak fit
// before its tries (preprocess.py _grow_first: the same, and its measured reason). bank as
// grown's: bank[i] holds all[i]'s support rays, bank[all.size()] is free.
void grow_first(const Frame &f, const std::vector<double> &dirs, const pp_params *p,
                std::vector<Found> &all, std::vector<Rays> &bank, size_t ib)
{
    const double decisive = decisive_support(p);
    const Found &f0 = all[0], &fb = all[ib];
    const double dx = f0.cx - fb.cx, dy = f0.cy - fb.cy;
    if (ib != 0 && f0.support < decisive && fb.support >= p->min_support &&
        dx * dx + dy * dy < fb.r * fb.r)
        grown(f, dirs, p, &all[0], bank, 0, all.size(), f0.support < p->min_support, decisive);
}

// Whether a circle reached by a refused frame's tries may replace its fit (rescue, retry_rest),
// or be the sphere of find_sphere's second search: supported by at least min_support and its shading at least limb_min (preprocess.py
// _lit_sphere).
bool lit_sphere(const Frame &f, const std::vector<double> &dirs, const Found &c, const pp_params *p)
{
    double sh;
    return c.support >= p->min_support && limb_shading(f, dirs, c.cx, c.cy, c.r, p, &sh) &&
           sh >= limb_min;
}

// The best supported fit, when its support is from second_retry to below min_support after its
// tries, tried from the circles tangent to it on its supported arc (tangent), and the circle
// reached, when still below min_support, refitted through a wider band (wide); the circle
// replaces it only when it reaches min_support and its shading is at least limb_min
// (preprocess.py _rescue: the same, and its measured reason). *rays holds the support rays of
// *fit, and of the circle that replaced it after; when none did, they may be another circle's,
// unused: the frame is then refused (no fit has min_support). *spare is scratch.
void rescue(const Frame &f, const std::vector<double> &dirs, const pp_params *p, Found *fit,
            Rays *rays, Rays *spare)
{
    if (!(second_retry <= fit->support && fit->support < p->min_support)) return;
    Found t = *fit;
    tangent(f, dirs, p, &t, rays, spare);
    if (!(t.support >= p->min_support)) wide(f, dirs, p, &t, rays, spare);
    if (lit_sphere(f, dirs, t, p)) *fit = t;
}

void cut_message(double cut, const pp_params *p, char *err, size_t errlen)
{
    pi_seterrn(
        err, errlen,
        "sphere cut by the frame edge (%.0f %% of its rim outside the frame, at most %.0f %%)",
        100 * cut, 100 * p->max_cut);
}

void two_spheres(const Found &a, const Found &b, char *err, size_t errlen)
{
    pi_seterrn(err, errlen,
               "two spheres in frame (circles at (%.1f, %.1f) r %.1f and (%.1f, %.1f) r %.1f)",
               a.cx + 0.5, a.cy + 0.5, a.r, b.cx + 0.5, b.cy + 0.5, b.r);
}

// Whether radius r may be the sphere's: within [0.9 rmin, 1.1 rmax] (preprocess.py _sized).
bool sized(double r, double rmin, double rmax)
{
    return rmin * 0.9 <= r && r <= rmax * 1.1;
}

// When the best supported fit (all[ib]) is still below min_support after its tries and rescue
// (the frame would be refused), every other fit of the sphere's size supported by at least
// second_retry is tried as the best was (grown from larger and smaller circles until
// decisive_support, then rescue), in place in all; the circle reached replaces the fit only
// when it reaches min_support and its shading is at least limb_min (preprocess.py _retry_rest:
// the same, and its measured reason). bank as grown's; a slot whose fit was not replaced may
// hold another circle's rays after, unused: that fit stays below min_support.
void retry_rest(const Frame &f, const std::vector<double> &dirs, const pp_params *p,
                std::vector<Found> &all, std::vector<Rays> &bank, size_t ib, double rmin,
                double rmax)
{
    if (all[ib].support >= p->min_support) return;
    const double decisive = decisive_support(p);
    for (size_t i = 0; i < all.size(); i++) {
        if (i == ib || !(second_retry <= all[i].support && all[i].support < p->min_support) ||
            !sized(all[i].r, rmin, rmax))
            continue;
        Found g = all[i];
        grown(f, dirs, p, &g, bank, i, all.size(), true, decisive);
        rescue(f, dirs, p, &g, &bank[i], &bank[all.size()]);
        if (lit_sphere(f, dirs, g, p)) all[i] = g;
    }
}

// The error of a frame without the sphere (preprocess.py NO_SPHERE): find_sphere searches such
// a frame again.
constexpr char no_sphere_text[] = "no sphere found in frame";

// The error when no circle is the sphere (preprocess.py _no_sphere_message):
// the cut sphere's, of the best supported fit (first on ties) of a radius in
// range with more than max_cut of its rim outside the frame, at least half
// its rays in the frame, min_support of them supporting it and its inside no
// darker than its edge; without one, no sphere found.
void no_sphere(const Frame &f, const std::vector<double> &dirs, const std::vector<Found> &all,
               const pp_params *p, double rmin, double rmax, char *err, size_t errlen)
{
    long best = -1;
    double best_cut = 0.0;
    for (size_t i = 0; i < all.size(); i++) {
        const Found &c = all[i];
        if (best >= 0 && !(c.support > all[(size_t)best].support)) continue;
        if (!sized(c.r, rmin, rmax)) continue;
        const double cut = rim_outside(c.cx, c.cy, c.r, f.h, f.w);
        if (!(cut > p->max_cut)) continue;
        double s, sh;
        if (!in_frame_support(f, dirs, c, c.support, p, 0.5, &s) || !(s >= p->min_support))
            continue;
        if (!limb_shading(f, dirs, c.cx, c.cy, c.r, p, &sh) || !(sh >= cut_shade)) continue;
        if (!textured(f, dirs, c, p)) continue;
        best = (long)i;
        best_cut = cut;
    }
    if (best >= 0)
        cut_message(best_cut, p, err, errlen);
    else
        pi_seterrn(err, errlen, "%s", no_sphere_text);
}

} // namespace

int set_avx512(int on)
{
    avx512_forced = -1;
    const bool has = avx512();
    avx512_forced = on < 0 ? -1 : (on != 0 && has);
    return avx512();
}

int uses_avx512()
{
    return avx512();
}

std::vector<int32_t> row_edges_of(const int32_t *up, const int32_t *mc, const int32_t *dn,
                                  const int32_t *gx, const int32_t *gy, int gw, int32_t tmin)
{
    const size_t room = (size_t)gw + 16;
    std::vector<int32_t> keep((size_t)gw + 4, 0), x(room), y(room), ox(room), oy(room), out;
    const size_t n = row_edges_at(up, mc, dn, gx, gy, gw, tmin, 1, keep.data(), x.data(), y.data(),
                                  ox.data(), oy.data());
    for (size_t i = 0; i < n; i++) {
        out.push_back(x[i]);
        out.push_back(ox[i]);
        out.push_back(oy[i]);
    }
    return out;
}

std::vector<int32_t> peaks_of(const double *score, long n, double thr)
{
    RayScores rs;
    rs.n = n;
    rs.score.assign(score, score + n);
    const long m = rs.peaks(thr);
    return std::vector<int32_t>(rs.pk.begin(), rs.pk.begin() + m);
}

std::vector<double> ray_dirs(int k)
{
    const int q = k / 8;
    std::vector<double> bc((size_t)q + 1), bs((size_t)q + 1), d(2 * (size_t)k);
    const double quarter = M_PI / 4;
    for (int i = 0; i <= q; i++) {
        const double t = quarter * i / q;
        const double t2 = t * t;
        double c = 1.0, s = t, tc = 1.0, ts = t;
        for (int n = 1; n < 12; n++) {
            tc = -tc * t2 / (double)((2 * n - 1) * (2 * n));
            ts = -ts * t2 / (double)((2 * n) * (2 * n + 1));
            c += tc;
            s += ts;
        }
        bc[(size_t)i] = c;
        bs[(size_t)i] = s;
    }
    for (int i = 0; i < k; i++) {
        const int octant = i / q, j = i % q;
        double c, s;
        if (octant % 2 == 0) {
            c = bc[(size_t)j];
            s = bs[(size_t)j];
        } else {
            s = bc[(size_t)(q - j)];
            c = bs[(size_t)(q - j)];
        }
        double x, y;
        switch (octant / 2) {
        case 0:
            x = c;
            y = s;
            break;
        case 1:
            x = -s;
            y = c;
            break;
        case 2:
            x = -c;
            y = -s;
            break;
        default:
            x = s;
            y = -c;
            break;
        }
        d[2 * (size_t)i] = x;
        d[2 * (size_t)i + 1] = y;
    }
    return d;
}

// The fits of the weaker coarse peaks (weak_peak) whose circle is cut by the
// frame edge and whose centre lies outside sphere a's circle (s: the coarse
// scale), added to all (their support rays to bank) and, when well supported
// and of a sphere's size, to fits (preprocess.py _cut_peak_fits and the
// lines after it).
static void cut_peak_fits(const Frame &f, const std::vector<double> &dirs,
                          const std::vector<Cand> &weak, int s, const Found &a, const pp_params *p,
                          std::vector<Found> &all, std::vector<Rays> &bank,
                          std::vector<size_t> &fits, double rmin, double rmax)
{
    for (const Cand &c : weak) {
        if (!(rim_outside(c.cx, c.cy, c.r, f.h, f.w) > 0) ||
            (c.cx - a.cx) * (c.cx - a.cx) + (c.cy - a.cy) * (c.cy - a.cy) < a.r * a.r)
            continue;
        // a slot for its rays and one more for grow's tries
        if (bank.size() < all.size() + 2) bank.resize(all.size() + 2);
        Found fo;
        if (!fine(f, dirs, c, s, p, &fo, &bank[all.size()])) continue;
        all.push_back(fo);
        if (fo.support >= p->min_support && sized(fo.r, rmin, rmax)) fits.push_back(all.size() - 1);
    }
}

static double expected_radius(const pp_camera *cam)
{
    const double f = cam->focal_mm / cam->pixel_mm;
    const double R = cam->sphere_diameter_mm / 2.0, D = cam->distance_mm;
    return f * R / std::sqrt(D * D - R * R);
}

// The sphere's circle within radius range [rmin, rmax], the coarse peaks
// gap_r apart (preprocess.py _search); find_sphere's outputs and return.
// lit_only: the sphere only as a lit sphere (lit_sphere), else no sphere.
static int search(const uint8_t *bgr, int w, int h, size_t stride, const pp_params *p, double rmin,
                  double rmax, double gap_r, bool lit_only, double *ocx, double *ocy, double *orad,
                  double *cov, char *err, size_t errlen)
{
    int s = 1;
    std::vector<Cand> weak_peaks;
    const std::vector<Cand> cands = coarse(bgr, stride, w, h, p, rmin, rmax, gap_r, &s, weak_peaks);
    // the ray directions, computed again only when the count changes
    thread_local std::vector<double> dirs;
    if (dirs.size() != 2 * (size_t)p->rays) dirs = ray_dirs(p->rays);
    const Frame f = {bgr, stride, w, h};
    std::vector<Found> all;
    // the fits' support rays (bank[i]: all[i]'s), kept between frames; one more for grow's tries
    thread_local std::vector<Rays> bank;
    if (bank.size() < cands.size() + 1) bank.resize(cands.size() + 1);
    const double decisive = decisive_support(p);
    for (const Cand &c : cands) {
        // a peak whose centre lies inside a decisively supported fit is that circle again or
        // the texture's arcs inside it: neither a better sphere nor a second one (the check
        // below passes over circles whose centre lies inside the other), so it is not refined
        bool inside = false;
        for (const Found &a : all)
            inside = inside ||
                     (a.support >= decisive &&
                      (c.cx - a.cx) * (c.cx - a.cx) + (c.cy - a.cy) * (c.cy - a.cy) < a.r * a.r);
        if (inside) continue;
        Found fo;
        if (fine(f, dirs, c, s, p, &fo, &bank[all.size()])) all.push_back(fo);
    }
    // the best supported fit (first on ties), when weakly supported, tried from larger circles
    // (and from smaller ones too when below min_support)
    if (!all.empty()) {
        size_t ib = 0;
        for (size_t i = 1; i < all.size(); i++)
            if (all[i].support > all[ib].support) ib = i;
        // again from the circle it moved to, while that is better supported and still weak, at
        // most grow_rounds tries; a fit below min_support (no sphere) is tried from smaller
        // circles too, in every try
        grown(f, dirs, p, &all[ib], bank, ib, all.size(), all[ib].support < p->min_support,
              decisive);
        // and the first fit too
        grow_first(f, dirs, p, all, bank, ib);
        // a best fit still below min_support (the frame would be refused) tried from tangent
        // circles too, and through a wider band, kept only as a lit sphere
        rescue(f, dirs, p, &all[ib], &bank[ib], &bank[all.size()]);
        // and when it is still below, every other fit tried the same way
        retry_rest(f, dirs, p, all, bank, ib, rmin, rmax);
    }
    // the well supported fits of a radius in range: their indexes into all
    std::vector<size_t> fits;
    for (size_t i = 0; i < all.size(); i++)
        if (all[i].support >= p->min_support && sized(all[i].r, rmin, rmax)) fits.push_back(i);
    // the best supported circle (first on ties) is the sphere
    long ia = -1;
    for (size_t i = 0; i < fits.size(); i++)
        if (ia < 0 || all[fits[i]].support > all[fits[(size_t)ia]].support) ia = (long)i;
    if (ia < 0) {
        no_sphere(f, dirs, all, p, rmin, rmax, err, errlen);
        return -1;
    }
    // a copy: the weaker peaks' fits are added to all below
    const Found a = all[fits[(size_t)ia]];
    const double cut = rim_outside(a.cx, a.cy, a.r, h, w);
    if (cut > p->max_cut) {
        // a circle darker inside than at its edge, or smooth inside (a disk of the clutter), is
        // no cut sphere: the frame is then told as one without a sphere is (a lit, textured cut
        // sphere below it, or none)
        if (lit(f, dirs, a, p) && textured(f, dirs, a, p))
            cut_message(cut, p, err, errlen);
        else
            no_sphere(f, dirs, all, p, rmin, rmax, err, errlen);
        return -1;
    }
    // the weaker coarse peaks' circles cut by the frame edge judged with the
    // fits (weak_peak)
    cut_peak_fits(f, dirs, weak_peaks, s, a, p, all, bank, fits, rmin, rmax);
    // another well supported circle of about its size, neither centre inside
    // the other circle, its inside not flat where the sphere's is shaded, its
    // colours the sphere's: a second sphere
    for (size_t i = 0; i < fits.size(); i++)
        if ((long)i != ia && second_beside(f, dirs, a, all[fits[i]], p, &bank[all.size()])) {
            two_spheres(a, all[fits[i]], err, errlen);
            return -1;
        }
    // a second sphere partly outside the frame: judged by its rays in the
    // frame (second_in_frame)
    for (const Found &b : all) {
        // judged above, or not of a sphere's size
        if (b.support >= p->min_support || !sized(b.r, rmin, rmax)) continue;
        double s_in;
        // its beside support last: it is its own support unless the circles overlap, and
        // then costs a support's rays
        if (in_frame_support(f, dirs, b, b.support, p, second_in_frame, &s_in) &&
            s_in >= p->min_support && second(f, dirs, a, b, p) &&
            in_frame_support(f, dirs, b, beside_support(f, dirs, a, b, p, &bank[all.size()]), p,
                             second_in_frame, &s_in) &&
            s_in >= p->min_support) {
            two_spheres(a, b, err, errlen);
            return -1;
        }
    }
    // a second sphere whose fit settled on its texture: weak circles of the
    // sphere's size beside it tried again as the sphere's weak fit is
    // (second_retry), until min_support; one above that but below decisive, not
    // a second sphere as it is (above), until decisive; their support rays'
    // slots are not needed after this
    for (size_t i = 0; i < all.size(); i++) {
        const Found &b = all[i];
        if (i == fits[(size_t)ia] || !(second_retry <= b.support && b.support < decisive) ||
            !sized(b.r, rmin, rmax) || !apart(a, b, p))
            continue;
        const bool weak = b.support < p->min_support;
        Found g = b;
        grown(f, dirs, p, &g, bank, i, all.size(), true, weak ? p->min_support : decisive);
        const bool moved = g.cx != b.cx || g.cy != b.cy || g.r != b.r;
        if ((weak || moved) && g.support >= p->min_support && sized(g.r, rmin, rmax) &&
            second_beside(f, dirs, a, g, p, &bank[all.size()])) {
            two_spheres(a, g, err, errlen);
            return -1;
        }
        // still weak: a second sphere when it looks like the sphere (second_weak)
        if (second_weak <= g.support && g.support < p->min_support && sized(g.r, rmin, rmax) &&
            weak_second(f, dirs, a, g, p, &bank[all.size()])) {
            two_spheres(a, g, err, errlen);
            return -1;
        }
    }
    // a weakly supported sphere tried from larger circles tangent to it on its supported arc
    Found sp = a;
    tangent(f, dirs, p, &sp, &bank[fits[(size_t)ia]], &bank[all.size()]);
    if (lit_only && !lit_sphere(f, dirs, sp, p)) {
        pi_seterrn(err, errlen, "%s", no_sphere_text);
        return -1;
    }
    // refitted through the outermost edges near it, then moved to the rims and through them,
    // and from the wider band's circle too when weakly supported
    final_circle(f, dirs, p, sp, bank[fits[(size_t)ia]], &bank[all.size()], ocx, ocy, orad);
    // its centre's covariance, from its rims on the fit's rays (the refinement weighs it against
    // the refined centre: refine.h RF_CENTRE_FUSE_PX)
    if (cov) {
        double x, y, r;
        rim(dirs, p, sp, bank[fits[(size_t)ia]], *ocx, *ocy, *orad, &x, &y, &r, cov);
    }
    return 0;
}

int find_sphere(const uint8_t *bgr, int w, int h, size_t stride, const pp_params *p, double *ocx,
                double *ocy, double *orad, double *cov, char *err, size_t errlen)
{
    const double m = (double)std::min(h, w);
    double rmin = p->r_min_frac * m, rmax = p->r_max_frac * m;
    const double wide = rmin;
    if (p->cam.set) {
        const double r = expected_radius(&p->cam);
        rmin = r * (1.0 - p->r_tol);
        rmax = r * (1.0 + p->r_tol);
    }
    // the errors in a buffer of our own: the second search depends on the first's text
    char why[PI_ERR_LEN];
    if (search(bgr, w, h, stride, p, rmin, rmax, rmin, false, ocx, ocy, orad, cov, why,
               sizeof why) == 0)
        return 0;
    // no sphere found within a camera file's radius range: searched again with the coarse peaks
    // as close together as the wide search's, the sphere found so kept only as a lit sphere
    // (preprocess.py _find_sphere_v2 says why); the error is the first search's when the second
    // finds none either
    char again[PI_ERR_LEN];
    if (strcmp(why, no_sphere_text) == 0 && wide < rmin &&
        search(bgr, w, h, stride, p, rmin, rmax, wide, true, ocx, ocy, orad, cov, again,
               sizeof again) == 0)
        return 0;
    pi_seterrn(err, errlen, "%s", why);
    return -1;
}

int rim_from(const uint8_t *bgr, int w, int h, size_t stride, const pp_params *p, double cx,
             double cy, double r, double *ocx, double *ocy, double *orad, double *cov)
{
    thread_local std::vector<double> dirs;
    if (dirs.size() != 2 * (size_t)p->rays) dirs = ray_dirs(p->rays);
    thread_local Rays rays;
    const Frame f = {bgr, stride, w, h};
    // the circle's support rays (the support itself decides nothing here)
    const Found a = {cx, cy, r, support(f, dirs, cx, cy, r, p, &rays)};
    return rim(dirs, p, a, rays, cx, cy, r, ocx, ocy, orad, cov) > 0 ? 0 : -1;
}

void crop(const uint8_t *bgr, int w, int h, size_t stride, double cx, double cy, double r,
          const pp_params *p, uint8_t *out)
{
    const int S = p->size;
    const double half = r * p->margin;
    const long x0 = ifloor(cx - half + 0.5), y0 = ifloor(cy - half + 0.5);
    const long side = std::max(1L, ifloor(2 * half + 0.5));
    uint8_t fill[3];
    for (int c = 0; c < 3; c++)
        fill[c] = (uint8_t)std::min(255.0, std::max(0.0, std::floor(p->fill[c] + 0.5)));
    const cv::Mat frame(h, w, CV_8UC3, const_cast<uint8_t *>(bgr), stride);
    cv::Mat roi;
    const long ix0 = std::max(0L, x0), iy0 = std::max(0L, y0);
    const long ix1 = std::min((long)w, x0 + side), iy1 = std::min((long)h, y0 + side);
    if (x0 >= 0 && y0 >= 0 && ix1 == x0 + side && iy1 == y0 + side) {
        roi = frame(cv::Rect((int)x0, (int)y0, (int)side, (int)side));
    } else {
        roi = cv::Mat((int)side, (int)side, CV_8UC3, cv::Scalar(fill[0], fill[1], fill[2]));
        if (ix1 > ix0 && iy1 > iy0)
            frame(cv::Rect((int)ix0, (int)iy0, (int)(ix1 - ix0), (int)(iy1 - iy0)))
                .copyTo(roi(cv::Rect((int)(ix0 - x0), (int)(iy0 - y0), (int)(ix1 - ix0),
                                     (int)(iy1 - iy0))));
    }
    cv::Mat small(S, S, CV_8UC3, out);
    if (!kern::resize_area_c3(roi.data, (int)side, (int)side, roi.step[0], small.data, S, S,
                              small.step[0]))
        cv::resize(roi, small, cv::Size(S, S), 0, 0, cv::INTER_AREA);
    // everything farther than r (1 + mask_frac) from the centre: fill
    const double scale = (double)side / S;
    const double rm = r * (1.0 + p->mask_frac);
    std::vector<double> d2x((size_t)S), d2y((size_t)S);
    for (int i = 0; i < S; i++) {
        const double u = ((double)i + 0.5) * scale - 0.5;
        const double dx = ((double)x0 + u) - cx, dy = ((double)y0 + u) - cy;
        d2x[(size_t)i] = dx * dx;
        d2y[(size_t)i] = dy * dy;
    }
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++)
            if (d2y[(size_t)y] + d2x[(size_t)x] > rm * rm) {
                uint8_t *q = out + 3 * ((size_t)y * S + x);
                q[0] = fill[0];
                q[1] = fill[1];
                q[2] = fill[2];
            }
}

void undistort_map(const pp_camera *cam, int w, int h, UndistortMap *m)
{
    const double f = cam->focal_mm / cam->pixel_mm;
    const double cx = (cam->has_principal ? cam->principal[0] : cam->width / 2.0) - 0.5;
    const double cy = (cam->has_principal ? cam->principal[1] : cam->height / 2.0) - 0.5;
    const double k1 = cam->distortion[0], k2 = cam->distortion[1], p1 = cam->distortion[2],
                 p2 = cam->distortion[3], k3 = cam->distortion[4];
    const double big = 32.0 * (double)(1 << 24);
    m->w = w;
    m->h = h;
    m->mx.resize((size_t)w * h);
    m->my.resize((size_t)w * h);
    for (int j = 0; j < h; j++) {
        const double y = ((double)j - cy) / f;
        for (int i = 0; i < w; i++) {
            const double x = ((double)i - cx) / f;
            const double x2 = x * x, y2 = y * y, xy = x * y;
            const double r2 = x2 + y2;
            const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
            const double xd = x * radial + (2.0 * p1) * xy + p2 * (r2 + 2.0 * x2);
            const double yd = y * radial + p1 * (r2 + 2.0 * y2) + (2.0 * p2) * xy;
            double mx = std::floor((f * xd + cx) * 32.0 + 0.5),
                   my = std::floor((f * yd + cy) * 32.0 + 0.5);
            mx = std::min(big, std::max(-big, mx));
            my = std::min(big, std::max(-big, my));
            m->mx[(size_t)j * w + i] = (int64_t)mx;
            m->my[(size_t)j * w + i] = (int64_t)my;
        }
    }
    const size_t n = (size_t)w * h;
    m->x0.resize(n);
    m->y0.resize(n);
    m->ax.resize(n);
    m->ay.resize(n);
    m->inside.resize(n);
    for (size_t k = 0; k < n; k++) {
        // floor division by 32 (Python's >>), remainder in 0..31
        const int64_t mx = m->mx[k], my = m->my[k];
        const int64_t x0 = mx >= 0 ? mx / 32 : -((-mx + 31) / 32);
        const int64_t y0 = my >= 0 ? my / 32 : -((-my + 31) / 32);
        m->ax[k] = (uint8_t)(mx - x0 * 32);
        m->ay[k] = (uint8_t)(my - y0 * 32);
        m->inside[k] = x0 >= 0 && x0 + 1 < w && y0 >= 0 && y0 + 1 < h;
        // beyond the frame all four corners read 0: any position out there will do
        m->x0[k] = (int32_t)std::max<int64_t>(-2, std::min<int64_t>(x0, w + 1));
        m->y0[k] = (int32_t)std::max<int64_t>(-2, std::min<int64_t>(y0, h + 1));
    }
}

void remap(const uint8_t *bgr, size_t stride, const UndistortMap &m, uint8_t *out)
{
    const int w = m.w, h = m.h;
    for (int j = 0; j < h; j++) {
        for (int i = 0; i < w; i++) {
            const size_t k = (size_t)j * w + i;
            const int32_t ax = m.ax[k], ay = m.ay[k], x0 = m.x0[k], y0 = m.y0[k];
            const int32_t w00 = (32 - ax) * (32 - ay), w01 = ax * (32 - ay), w10 = (32 - ax) * ay,
                          w11 = ax * ay;
            uint8_t *o = out + 3 * k;
            if (m.inside[k]) {
                const uint8_t *a = bgr + (size_t)y0 * stride + 3 * (size_t)x0, *b = a + stride;
                for (int c = 0; c < 3; c++)
                    o[c] = (uint8_t)((a[c] * w00 + a[3 + c] * w01 + b[c] * w10 + b[3 + c] * w11 +
                                      512) >>
                                     10);
                continue;
            }
            // a corner outside the frame reads 0
            const bool in0x = x0 >= 0 && x0 < w, in1x = x0 + 1 >= 0 && x0 + 1 < w;
            const bool in0y = y0 >= 0 && y0 < h, in1y = y0 + 1 >= 0 && y0 + 1 < h;
            for (int c = 0; c < 3; c++) {
                const int32_t p00 =
                    in0x && in0y ? bgr[(size_t)y0 * stride + 3 * (size_t)x0 + c] : 0;
                const int32_t p01 =
                    in1x && in0y ? bgr[(size_t)y0 * stride + 3 * (size_t)(x0 + 1) + c] : 0;
                const int32_t p10 =
                    in0x && in1y ? bgr[(size_t)(y0 + 1) * stride + 3 * (size_t)x0 + c] : 0;
                const int32_t p11 =
                    in1x && in1y ? bgr[(size_t)(y0 + 1) * stride + 3 * (size_t)(x0 + 1) + c] : 0;
                o[c] = (uint8_t)((p00 * w00 + p01 * w01 + p10 * w10 + p11 * w11 + 512) >> 10);
            }
        }
    }
}

} // namespace crop2
