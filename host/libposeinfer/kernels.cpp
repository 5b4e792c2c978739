// kernels.cpp -- see kernels.h. Plain loops written so that the compiler
// vectorises them (byte compares, byte max/min, float multiply and add);
// no intrinsics, so the file builds on any target OpenCV builds on.
// Built with -ffp-contract=off (Makefile): a fused multiply-add would round
// differently from OpenCV's separate multiply and add.
#include "kernels.h"

#include <algorithm>
#include <cfenv>
#include <cfloat>
#include <cmath>
#include <cstring>

// On x86-64, each entry point is also built for AVX2 and picked at load
// time by the CPU it runs on (twice the bytes per instruction in the byte
// loops); elsewhere the one generic build.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define KERN_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define KERN_CLONES
#endif

namespace kern
{

// ---- foreground test --------------------------------------------------------

// Per-byte bounds for an interleaved BGR row: byte i of a row is channel
// i % 3. An empty interval becomes (255, 0), which every value is outside.
struct Bounds {
    std::vector<uint8_t> lo, hi;
    Bounds(const int l[3], const int h[3], int pixels)
        : lo((size_t)pixels * 3), hi((size_t)pixels * 3)
    {
        uint8_t bl[3], bh[3];
        for (int c = 0; c < 3; c++) {
            int a = std::max(0, l[c]), b = std::min(255, h[c]);
            if (a > b) {
                a = 255;
                b = 0;
            }
            bl[c] = (uint8_t)a;
            bh[c] = (uint8_t)b;
        }
        for (size_t i = 0; i < lo.size(); i++) {
            lo[i] = bl[i % 3];
            hi[i] = bh[i % 3];
        }
    }
};

static inline uint8_t outside(uint8_t v, uint8_t lo, uint8_t hi)
{
    return (uint8_t)((v < lo) | (v > hi));
}

// Any byte of p[0..N) outside its bounds? N is a compile-time 64 in the
// hot path so that the loop vectorises without a remainder.
template <int N>
static inline bool any_outside(const uint8_t *p, const uint8_t *lo, const uint8_t *hi)
{
    uint8_t acc = 0;
    for (int i = 0; i < N; i++) acc |= outside(p[i], lo[i], hi[i]);
    return acc != 0;
}

enum { CHUNK = 64 };

// First byte index in [from, to) outside its bounds, or -1.
KERN_CLONES static long first_outside(const uint8_t *p, const uint8_t *lo, const uint8_t *hi,
                                      long from, long to)
{
    long i = from;
    for (; i + CHUNK <= to; i += CHUNK)
        if (any_outside<CHUNK>(p + i, lo + i, hi + i)) break;
    for (; i < to; i++)
        if (outside(p[i], lo[i], hi[i])) return i;
    return -1;
}

// Last byte index in [from, to) outside its bounds, or -1.
KERN_CLONES static long last_outside(const uint8_t *p, const uint8_t *lo, const uint8_t *hi,
                                     long from, long to)
{
    long i = to;
    for (; i - CHUNK >= from; i -= CHUNK)
        if (any_outside<CHUNK>(p + i - CHUNK, lo + i - CHUNK, hi + i - CHUNK)) break;
    for (; i > from; i--)
        if (outside(p[i - 1], lo[i - 1], hi[i - 1])) return i - 1;
    return -1;
}

KERN_CLONES bool fg_bbox(const uint8_t *bgr, int w, int h, size_t stride, const int lo[3],
                         const int hi[3], int *x0, int *y0, int *x1, int *y1)
{
    const Bounds b(lo, hi, w);
    const uint8_t *bl = b.lo.data(), *bh = b.hi.data();
    const long n = 3L * w;
    long bx0 = -1, bx1 = -1; // byte columns of the box so far; -1: no foreground yet
    int by0 = -1, by1 = -1;
    for (int y = 0; y < h; y++) {
        const uint8_t *p = bgr + (size_t)y * stride;
        long f, l;
        bool any;
        if (bx0 < 0) {
            f = first_outside(p, bl, bh, 0, n);
            if (f < 0) continue;
            l = last_outside(p, bl, bh, f, n);
            any = true;
        } else {
            // Only what could widen the box needs a full look: left of it
            // and right of it; inside, one foreground byte decides the row.
            f = first_outside(p, bl, bh, 0, bx0);
            l = last_outside(p, bl, bh, bx1 + 1, n);
            any = f >= 0 || l >= 0 || first_outside(p, bl, bh, bx0, bx1 + 1) >= 0;
        }
        if (!any) continue;
        if (f >= 0) bx0 = bx0 < 0 ? 3 * (f / 3) : std::min(bx0, 3 * (f / 3));
        if (l >= 0) bx1 = std::max(bx1, 3 * (l / 3) + 2);
        if (by0 < 0) by0 = y;
        by1 = y;
    }
    if (by0 < 0) return false;
    *x0 = (int)(bx0 / 3);
    *x1 = (int)(bx1 / 3);
    *y0 = by0;
    *y1 = by1;
    return true;
}

KERN_CLONES void fg_mask(const uint8_t *bgr, size_t stride, int rx, int ry, int rw, int rh,
                         const int lo[3], const int hi[3], uint8_t *mask)
{
    const Bounds b(lo, hi, rw);
    // flags per byte, then the OR of each byte with its next two (both
    // loops vectorise); a pixel's answer is that OR at its first byte
    const size_t nb = (size_t)rw * 3;
    std::vector<uint8_t> flag(nb + 2, 0), any(nb);
    for (int y = 0; y < rh; y++) {
        const uint8_t *p = bgr + (size_t)(ry + y) * stride + 3 * (size_t)rx;
        for (size_t i = 0; i < nb; i++) flag[i] = outside(p[i], b.lo[i], b.hi[i]);
        for (size_t i = 0; i < nb; i++)
            any[i] = (uint8_t)(0 - (flag[i] | flag[i + 1] | flag[i + 2]));
        uint8_t *m = mask + (size_t)y * rw;
        for (int x = 0; x < rw; x++) m[x] = any[3 * (size_t)x];
    }
}

// ---- binary closing -----------------------------------------------------------

// Masks are 0/255 bytes outside and one bit per pixel inside: bit x of a
// row is bit (x & 63) of word (x >> 6). A pass over a 300-pixel row is then
// a handful of word operations instead of 300 byte operations.
typedef uint64_t word;

struct ElemRow {
    int dy;  // row offset, 0..k-1, in padded coordinates
    int dx;  // first column of the run, 0..k-1, in padded coordinates
    int len; // run length
};

struct Bits {
    int nw; // words per row, including spare words that hold the border
    std::vector<word> v;
    word *row(int y)
    {
        return &v[(size_t)y * nw];
    }
    const word *row(int y) const
    {
        return &v[(size_t)y * nw];
    }
};

// Bit x of the result is bit x + t of src (t >= 0; src has the words it reads).
static inline word shr(const word *src, int j, int t)
{
    const int q = t >> 6, r = t & 63;
    return r ? (src[j + q] >> r) | (src[j + q + 1] << (64 - r)) : src[j + q];
}

static inline word ones_from(int lo, int hi) // bits [lo, hi) of one word, 0 <= lo <= hi <= 64
{
    const word up = hi >= 64 ? ~(word)0 : (((word)1 << hi) - 1);
    return up & ~(lo >= 64 ? ~(word)0 : (((word)1 << lo) - 1));
}

// dst rows [a, a + h) get src's w-bit rows shifted right by a bits (to x + a);
// everything else keeps dst's fill.
static void place(const Bits &src, int w, int h, int a, Bits &dst)
{
    for (int y = 0; y < h; y++) {
        const word *s = src.row(y);
        word *d = dst.row(y + a);
        for (int j = 0; j < dst.nw; j++) {
            const int lo = std::max(0, a - 64 * j), hi = std::min(64, a + w - 64 * j);
            if (hi <= lo) continue;
            // bit b of word j is pixel 64j + b - a of src
            const int x = 64 * j - a; // pixel of bit 0 (may be negative)
            word v;
            if (x >= 0) {
                v = shr(s, 0, x);
            } else {
                const int sh = -x; // < 64 when lo < hi and a < 64 * (j + 1)
                v = sh >= 64 ? 0 : s[0] << sh;
            }
            const word m = ones_from(lo, hi);
            d[j] = (d[j] & ~m) | (v & m);
        }
    }
}

// One dilation (Max) or erosion (Min) of the w x h bit image in, into out:
// out(y, x) = OP over element rows r of OP over pad(y + r.dy, x + r.dx ..
// x + r.dx + r.len - 1), pad being in with a border of `border` bits.
template <bool Max>
static void morph_bits(const Bits &in, int w, int h, int k, const std::vector<ElemRow> &rows,
                       Bits &out)
{
    const word fill = Max ? 0 : ~(word)0;
    const int a = k / 2, ph = h + 2 * a;
    Bits g;
    g.nw = (w + 2 * a + k + 63) / 64 + (k + 63) / 64 + 2;
    g.v.assign((size_t)g.nw * ph, fill);
    place(in, w, h, a, g);
    out.v.assign((size_t)out.nw * h, fill);
    // g(x) = OP pad(x .. x + len - 1), grown in place: widening windows of
    // len by up to len more (g(x) OP g(x + step)) reads only words not yet
    // updated, going left to right.
    int len = 1;
    const int nwo = (w + 63) / 64;
    for (const ElemRow &r : rows) {
        while (len < r.len) {
            const int step = std::min(len, r.len - len);
            const int q = step >> 6;
            for (int y = 0; y < ph; y++) {
                word *gr = g.row(y);
                for (int j = 0; j + q + 1 < g.nw; j++)
                    gr[j] = Max ? gr[j] | shr(gr, j, step) : gr[j] & shr(gr, j, step);
            }
            len += step;
        }
        for (int y = 0; y < h; y++) {
            const word *gr = g.row(y + r.dy);
            word *o = out.row(y);
            for (int j = 0; j < nwo; j++)
                o[j] = Max ? o[j] | shr(gr, j, r.dx) : o[j] & shr(gr, j, r.dx);
        }
    }
}

KERN_CLONES bool close_binary(uint8_t *mask, int w, int h, const uint8_t *elem, int k)
{
    if (k < 1 || k % 2 == 0 || w < 1 || h < 1) return false;
    std::vector<ElemRow> rows;
    for (int i = 0; i < k; i++) {
        const uint8_t *e = elem + (size_t)i * k;
        int first = -1, last = -1;
        for (int j = 0; j < k; j++)
            if (e[j]) {
                if (first < 0) first = j;
                last = j;
            }
        if (first < 0) continue;
        for (int j = first; j <= last; j++)
            if (!e[j]) return false; // not one run: leave it to OpenCV
        rows.push_back({i, first, last - first + 1});
    }
    if (rows.empty()) return false;
#if !defined(__BYTE_ORDER__) || __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
    return false; // the packing below reads words as bytes, little-endian
#endif
    std::sort(rows.begin(), rows.end(),
              [](const ElemRow &p, const ElemRow &q) { return p.len < q.len; });

    // pack: 8 bytes of 0/255 at a time; byte i of the little-endian load
    // lands on bit i (the multiplier sums each byte's low bit into the top byte)
    Bits m;
    m.nw = (w + 63) / 64 + 1;
    m.v.assign((size_t)m.nw * h, 0);
    for (int y = 0; y < h; y++) {
        const uint8_t *src = mask + (size_t)y * w;
        uint8_t *dst = reinterpret_cast<uint8_t *>(m.row(y));
        int x = 0;
        for (; x + 8 <= w; x += 8) {
            word v;
            memcpy(&v, src + x, 8);
            if ((v ^ (v >> 1)) & 0x7F7F7F7F7F7F7F7FULL)
                return false; // a byte with unequal bits: not 0 or 255
            v &= 0x0101010101010101ULL;
            dst[x >> 3] = (uint8_t)((v * 0x0102040810204080ULL) >> 56);
        }
        for (; x < w; x++) {
            if (src[x] != 0 && src[x] != 255) return false;
            if (src[x]) dst[x >> 3] |= (uint8_t)(1u << (x & 7));
        }
    }
    Bits d, e;
    d.nw = e.nw = (w + 63) / 64 + 1;
    morph_bits<true>(m, w, h, k, rows, d);
    morph_bits<false>(d, w, h, k, rows, e);
    // unpack: each bit back to 0 or 255
    for (int y = 0; y < h; y++) {
        const uint8_t *src = reinterpret_cast<const uint8_t *>(e.row(y));
        uint8_t *dst = mask + (size_t)y * w;
        int x = 0;
        for (; x + 8 <= w; x += 8) {
            word v = ((word)src[x >> 3] * 0x0101010101010101ULL) & 0x8040201008040201ULL;
            v = (((v + 0x7F7F7F7F7F7F7F7FULL) & 0x8080808080808080ULL) >> 7) * 0xFF;
            memcpy(dst + x, &v, 8);
        }
        for (; x < w; x++) dst[x] = (src[x >> 3] >> (x & 7)) & 1 ? 255 : 0;
    }
    return true;
}

// ---- INTER_AREA reduction -------------------------------------------------------

// Area weights along one axis: destination cell d covers source interval
// [d*scale, (d+1)*scale); each source sample it touches contributes the
// covered fraction over the cell width. Same cut-offs (1e-3) and float
// rounding of the weights as OpenCV, which the exactness depends on.
struct Weight {
    int d, s;
    float a;
};

static std::vector<Weight> area_weights(int ssize, int dsize, double scale)
{
    std::vector<Weight> t;
    t.reserve((size_t)ssize * 2);
    for (int d = 0; d < dsize; d++) {
        const double f1 = d * scale, f2 = f1 + scale;
        const double cell = std::min(scale, ssize - f1);
        int s1 = (int)std::ceil(f1), s2 = (int)std::floor(f2);
        s2 = std::min(s2, ssize - 1);
        s1 = std::min(s1, s2);
        if (s1 - f1 > 1e-3) t.push_back({d, s1 - 1, (float)((s1 - f1) / cell)});
        for (int s = s1; s < s2; s++) t.push_back({d, s, (float)(1.0 / cell)});
        if (f2 - s2 > 1e-3)
            t.push_back({d, s2, (float)(std::min(std::min(f2 - s2, 1.0), cell) / cell)});
    }
    return t;
}

// Nearest integer, ties to even, as cvRound in the default rounding mode:
// adding and subtracting 1.5 * 2^23 rounds a float in [-2^22, 2^22] to an
// integer exactly (the sums here lie in [0, 256)); then saturate to 8 bits.
static inline int32_t round_sat(float v)
{
    const float magic = 12582912.0f;
    const float r = (v + magic) - magic;
    return (int32_t)std::min(255.0f, std::max(0.0f, r));
}

KERN_CLONES bool resize_area_c3(const uint8_t *src, int sw, int sh, size_t sstride, uint8_t *dst,
                                int dw, int dh, size_t dstride)
{
    if (sw < 1 || sh < 1 || dw < 1 || dh < 1) return false;
    const double sx = 1.0 / ((double)dw / sw), sy = 1.0 / ((double)dh / sh);
    if (sx < 1 || sy < 1) return false;
    const int ix = (int)std::lrint(sx), iy = (int)std::lrint(sy);
    if (std::fabs(sx - ix) < DBL_EPSILON && std::fabs(sy - iy) < DBL_EPSILON) return false;
    if (std::fegetround() != FE_TONEAREST) return false;

    // One weight scales a whole pixel in one 4-lane multiply: a source row
    // is read 4 floats at a time from pixel x (lane 3, the next pixel's blue,
    // goes into a sum nobody reads), the sums are kept as 4 floats per pixel.
    // ROWS source rows go through together: independent chains of adds keep
    // the adder busy. Per channel the operations and their order are those
    // of 3-channel sums.
    enum { ROWS = 2 };
    const std::vector<Weight> xt = area_weights(sw, dw, sx), yt = area_weights(sh, dh, sy);
    const int n = 4 * dw, ne = (int)xt.size(), inw = 3 * sw + 1;
    std::vector<float> in((size_t)ROWS * inw, 0.0f), rows((size_t)ROWS * n), sum((size_t)n);
    std::vector<int32_t> out((size_t)n);
    int base = -1; // rows holds the horizontal sums of source rows base .. base + ROWS - 1
    size_t j = 0;
    for (int d = 0; d < dh; d++) {
        bool first = true;
        for (; j < yt.size() && yt[j].d == d; j++) {
            const int s_row = yt[j].s;
            if (base < 0 || s_row < base || s_row >= base + ROWS) {
                for (int r = 0; r < ROWS; r++) {
                    const uint8_t *p = src + (size_t)std::min(s_row + r, sh - 1) * sstride;
                    float *f = &in[(size_t)r * inw];
                    for (int x = 0; x < 3 * sw; x++) f[x] = p[x];
                }
                for (int d4 = 0, e = 0; d4 < n; d4 += 4) {
                    float acc[ROWS][4] = {};
                    for (; e < ne && 4 * xt[e].d == d4; e++) {
                        const float *q = &in[3 * (size_t)xt[e].s];
                        const float a = xt[e].a;
                        for (int r = 0; r < ROWS; r++)
                            for (int c = 0; c < 4; c++)
                                acc[r][c] = acc[r][c] + q[(size_t)r * inw + c] * a;
                    }
                    for (int r = 0; r < ROWS; r++)
                        for (int c = 0; c < 4; c++) rows[(size_t)r * n + d4 + c] = acc[r][c];
                }
                base = s_row;
            }
            const float *row = rows.data() + (size_t)(s_row - base) * n;
            const float beta = yt[j].a;
            float *__restrict sm = sum.data();
            const float *__restrict rw = row;
            if (first) {
                for (int i = 0; i < n; i++) sm[i] = beta * rw[i];
                first = false;
            } else {
                for (int i = 0; i < n; i++) sm[i] = sm[i] + beta * rw[i];
            }
        }
        for (int i = 0; i < n; i++) out[i] = round_sat(sum[i]); // vectorises; lane 3 unused
        uint8_t *o = dst + (size_t)d * dstride;
        for (int x = 0; x < dw; x++) {
            o[3 * x] = (uint8_t)out[4 * (size_t)x];
            o[3 * x + 1] = (uint8_t)out[4 * (size_t)x + 1];
            o[3 * x + 2] = (uint8_t)out[4 * (size_t)x + 2];
        }
    }
    return true;
}

} // namespace kern
