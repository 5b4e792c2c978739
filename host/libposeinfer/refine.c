/* refine.c -- render-and-compare refinement (training/refine.py in C).
 *
 * Each step renders the texture analytically into the frame's geometry at
 * the sampled pixels (pinhole ray, sphere intersection, body direction R^T n,
 * bilinear texture lookup), fits the photometric model per channel by least
 * squares (I ~ T (a0 + a.n) + b), and takes a Levenberg-Marquardt step over
 * the rotation (3), the circle's centre (2) and radius (1), with the
 * photometric coefficients projected out. Coarse to fine on 2x2 box levels of
 * the frame's crop and of the texture. Every step follows the Python file, so
 * that both land on the same pose (docs/refine.md).
 *
 * The per-pixel work runs in float over arrays of the sampled pixels (one
 * array per quantity), in loops that the compiler vectorises; the sums that
 * decide a step (the photometric fit and its sum of squares) are taken in
 * double. The poses agree with the double-precision arithmetic of the
 * reference within about 2e-5 degrees (docs/refine.md, cost). */
#define _DEFAULT_SOURCE /* madvise */
#define _POSIX_C_SOURCE 200809L
#include "refine.h"
#include "pi_err.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#include <immintrin.h>
#endif

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

/* The per-pixel loops come in versions (refine.h RF_VERSION_LIST) picked at
 * run time (rf_version): on x86-64 with GCC, AVX-512, AVX2, the x86-64
 * baseline and the portable one; elsewhere (and with clang) the portable one
 * alone. Every version does the same operations in the same order (no sums
 * reordered: the lanes are written out); the AVX-512 version fuses a
 * multiply and an add where the expression has one, the others fuse none:
 * their loops say so whatever the flags (-mfma, -march=native would otherwise
 * let the compiler fuse there too; on aarch64 compilers fuse by default:
 * below), and the code they share relies on ISO C mode (-std=c11, in which
 * GCC fuses nothing unless told to; checked below), so that they give the
 * same bits and the AVX-512 version differs
 * from them by rounding (docs/refine.md, cost). A loop is written once, as NAME_body, and
 * RF_VERSIONS makes NAME, which calls the version rf_version picks: NAME_v2
 * (AVX-512), NAME_v1 (AVX2), NAME_v0 (the baseline and the portable version:
 * SSE2 is x86-64's own, so the generic loops compile the same for both).
 * Where GCC's generic vectors split into too many registers and spill (the
 * lookups, the fit's and the colour ratio's sums), an x86-64 version has its
 * own loop with the same operations lane by lane (the lookups: NAME_avx512,
 * NAME_avx2, NAME_sse2; the fit's sums: NAME_avx2, NAME_sse2; the colour
 * ratio: NAME_avx2), beside the portable loop, and NAME calls it in place
 * of NAME_v1 (RF_VERSIONS_HAND: the fit's sums and the colour ratio, whose
 * NAME_v1 is not built; the lookups are picked in evaluate); the versions' test
 * (test_refine_versions) holds the AVX2, baseline and portable ones to the
 * same bits. */
#ifndef RF_VL
#define RF_VL 16 /* lanes of the vector operations (RF_LANES a multiple) */
#endif
#define RF_BODY static inline __attribute__((always_inline))
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define RF_X86_GCC 1
/* The AVX-512 build of a loop's body (fused multiply-adds allowed) and the
 * baseline one (none fused), shared by RF_VERSIONS and RF_VERSIONS_HAND */
#define RF_V2(ret, name, params, args)                                                           \
    __attribute__((target("avx512f"), optimize("fp-contract=fast"))) static ret name##_v2 params \
    {                                                                                            \
        return name##_body args;                                                                 \
    }
#define RF_V0(ret, name, params, args)                                       \
    __attribute__((optimize("fp-contract=off"))) static ret name##_v0 params \
    {                                                                        \
        return name##_body args;                                             \
    }
#define RF_VERSIONS(ret, name, params, args)                                                 \
    RF_V2(ret, name, params, args)                                                           \
    __attribute__((target("avx2"), optimize("fp-contract=off"))) static ret name##_v1 params \
    {                                                                                        \
        return name##_body args;                                                             \
    }                                                                                        \
    RF_V0(ret, name, params, args)                                                           \
    static ret name params                                                                   \
    {                                                                                        \
        int v_ = rf_version();                                                               \
        return v_ == RF_V_AVX512 ? name##_v2 args                                            \
               : v_ == RF_V_AVX2 ? name##_v1 args                                            \
                                 : name##_v0 args;                                           \
    }
#if RF_VL == 16
/* RF_VERSIONS for a loop whose AVX2 version (avx2) and baseline one (base,
 * or NAME_v0 where the baseline has none of its own) are written by hand:
 * NAME_v2 and NAME_v0 alone are built from the body */
#define RF_VERSIONS_HAND(ret, name, params, args, avx2, base) \
    RF_V2(ret, name, params, args)                            \
    RF_V0(ret, name, params, args)                            \
    static ret name params                                    \
    {                                                         \
        int v_ = rf_version();                                \
        return v_ == RF_V_AVX512     ? name##_v2 args         \
               : v_ == RF_V_AVX2     ? avx2 args              \
               : v_ == RF_V_BASELINE ? base args              \
                                     : name##_v0 args;        \
    }
#endif
#else
#define RF_VERSIONS(ret, name, params, args) \
    static ret name params                   \
    {                                        \
        return name##_body args;             \
    }
#endif
#ifndef RF_VERSIONS_HAND /* no hand-written versions: other processors, clang, RF_VL not 16 */
#define RF_VERSIONS_HAND(ret, name, params, args, avx2, base) RF_VERSIONS(ret, name, params, args)
#endif

/* Where the portable version is the only one (other processors, clang), no
 * multiply-add is fused anywhere in the file, whatever the flags: aarch64 has
 * fused multiply-adds, which clang uses within an expression by default and
 * GCC anywhere unless -std=c11, and the answers would then differ from the
 * x86-64 versions' (docs/refine.md). On x86-64 with GCC the versions'
 * attributes say it. */
#if defined(RF_X86_GCC) && defined(__FMA__) && !defined(__STRICT_ANSI__)
/* GNU C mode lets GCC fuse across statements in the code the versions
 * share, and the x86-64 versions' bits would then differ from other
 * processors' */
#error \
    "refine.c: build with -std=c11 (host/Makefile): GNU C mode with FMA changes the answers' bits"
#endif
#if defined(__GNUC__) && !defined(__clang__) && !defined(__x86_64__)
#pragma GCC optimize("fp-contract=off")
#endif
#ifdef __clang__
#pragma clang fp contract(off)
#endif
#ifdef RF_X86_GCC
#define RF_NOFUSE __attribute__((optimize("fp-contract=off")))
#else
#define RF_NOFUSE
#endif

static int rf_forced = -1; /* rf_set_version */

/* The best version the processor has (AVX-512: F and BW, which the
 * hand-written lookups need), or the one rf_set_version chose */
static int rf_version(void)
{
#ifdef RF_X86_GCC
    if (rf_forced >= 0) return rf_forced;
    if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw")) return RF_V_AVX512;
    return __builtin_cpu_supports("avx2") ? RF_V_AVX2 : RF_V_BASELINE;
#else
    return RF_V_PORTABLE;
#endif
}

int rf_version_in_use(void)
{
    return rf_version();
}

int rf_set_version(int v)
{
    rf_forced = -1;
    int best = rf_version();
    rf_forced = v < 0 ? -1 : v < best ? v : best;
    return rf_version();
}

/* Lanes of the written-out sums; the sample arrays are padded to a multiple. */
#define RF_LANES 16

/* Texels are stored in tiles of RF_TILE_W x RF_TILE_H, one 64-byte cache
 * line each (8 texels of 8 bytes), the tiles row by row: a bilinear lookup's
 * 2 x 2 texels lie in one line for 3 of 8 positions and in 1.875 lines on
 * average, against 2.25 for rows of texels (its texels are read after the
 * network has run, mostly from memory). Texel (I, J) of a level (border
 * included) is at RF_TILE_OFF(I, J, tr), tr: texels a row of tiles. */
#define RF_TILE_W             4
#define RF_TILE_H             2
#define RF_TILE_OFF(I, J, tr) (((J) >> 1) * (tr) + ((I) >> 2) * 8 + ((J)&1) * 4 + ((I)&3))
/* From texel (I, J)'s offset o to (I + 1, J)'s and to (I, J + 1)'s: I & 3 is
 * o & 3 and J & 1 is bit 2 of o (tr is a multiple of 8). */
#define RF_TILE_DX(o)         (1 + ((((o)&3) + 1) & 4))
#define RF_TILE_DY(o, tr)     ((o)&4 ? (tr)-4 : 4)
/* A level whose values fit in 10 bits (any level at most one 2 x 2 reduction
 * from the given texture: level 0 of one 2048 wide, levels 0 and 1 of one
 * 1024 wide) is stored as pairs instead: entry (I, J) holds texels (I, J)
 * and (I + 1, J), 10 bits a channel (B | G << 10 | R << 20, the right texel
 * in the upper 32 bits), so that a bilinear lookup reads two entries, (I, J)
 * and (I, J + 1). The entries lie in columns of 8 rows, one 64-byte cache
 * line each, the columns of a band of 8 rows side by side: both entries lie
 * in one line for 7 of 8 rows (1.125 lines a lookup against 1.875 for the
 * tiles). Entry (I, J) is at RF_PAIR_OFF(I, J, tr), tr: entries a band. */
#define RF_PAIR_OFF(I, J, tr) (((J) >> 3) * (tr) + (I)*8 + ((J)&7))
#define RF_PAIR_DY(o, tr)     (((o)&7) == 7 ? (tr)-7 : 1)

struct rf_texture {
    int w[RF_LEVELS], h[RF_LEVELS];
    int tr[RF_LEVELS]; /* texels a row of tiles, or entries a band for pairs */
    /* 16-bit B, G, R, 0 texels (8 bytes a texel: one 64-bit load; a third
     * less memory than three floats), in tiles (above) of the level's
     * [h + 2][w + 2] texels; a texel's value is px * scale. A level's values are
     * 8-bit values / 4^k (2x2 box means), so px = value * 4^k is exact for
     * k <= 4 (the scale a power of two), which covers textures up to 4096
     * wide; wider ones are rounded to 1/256. A border of one texel (the
     * longitude wrapped, the latitude clamped) so that a bilinear lookup reads
     * texels (i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1) without a test. */
    uint16_t *px[RF_LEVELS];
    uint64_t *pairs[RF_LEVELS]; /* the level as pairs (above) instead of px, or NULL */
    float scale[RF_LEVELS];
};

/* The arrays of the sampled pixels (float, RF_LANES-padded, one block). */
enum {
    A_X,
    A_Y, /* pixel centre minus the level's first circle centre */
    A_O0,
    A_O1,
    A_O2, /* observed B, G, R */
    A_NX,
    A_NY,
    A_NZ, /* the sphere's normal (world) */
    A_T,  /* the ray's length to the sphere */
    A_FX,
    A_FY, /* bilinear weights */
    A_V0,
    A_V1,
    A_V2, /* texture values */
    A_DU0,
    A_DU1,
    A_DU2, /* d value / d u texel */
    A_DV0,
    A_DV1,
    A_DV2, /* d value / d v texel */
    A_COUNT
};

/* The photometric fit of one evaluation (per channel, 5 coefficients). */
typedef struct rf_fit {
    double AtA[3][6][6], Atb[3][6], coef[3][6];
    double sse;
} rf_fit;

struct rf_work {
    int w[RF_LEVELS], h[RF_LEVELS]; /* the crop's size at each level */
    const rf_image *frame;          /* the frame, the crop's corner at (x0, y0) */
    int gray;                       /* a gray frame: the texture is seen as its luma */
    int x0, y0;
    float *a[A_COUNT];  /* the sample arrays, within buf */
    float *ja[A_COUNT]; /* the Jacobian pass's samples (jac_samples), within buf */
    int32_t *off;       /* texel offsets */
    int32_t *idx;       /* the Jacobian pass's samples (jac_samples) */
    long nact;          /* their count (the lookups choose them) */
    void *buf;
    size_t cap;           /* samples the arrays hold */
    long np, npad;        /* samples of the current level, and padded */
    double c0x, c0y;      /* the level's first circle centre (A_X, A_Y's origin) */
    double sst;           /* the sampled pixels' variance sum (pixel_set) */
    double so[3], soo[3]; /* the sampled pixels' sums of obs and obs^2 per channel (exact) */
    float gp[6];          /* the last value pass's geometry_pass parameters (GEO_*) */
    uint8_t pack[256][8]; /* gather_pass_avx2: the lanes set in a mask of 8, in order */
};

static const int rf_iters[RF_LEVELS] = RF_ITERS_INIT;
static const int rf_strides[RF_LEVELS] = RF_STRIDES_INIT;

/* ---- conversions ------------------------------------------------------------ */

void rf_matrix_to_euler(const double R[3][3], double e[3])
{
    double s = R[2][0] < -1 ? -1 : R[2][0] > 1 ? 1 : R[2][0];
    e[1] = -asin(s) * 180.0 / M_PI;
    e[0] = atan2(R[2][1], R[2][2]) * 180.0 / M_PI;
    e[2] = atan2(R[1][0], R[0][0]) * 180.0 / M_PI;
}

/* Rodrigues: rotation by |w| radians about w. */
static void rotvec_to_matrix(const double w[3], double M[3][3])
{
    double th = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    if (th < 1e-15) {
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) M[i][j] = i == j;
        return;
    }
    double k[3] = {w[0] / th, w[1] / th, w[2] / th};
    double K[3][3] = {{0, -k[2], k[1]}, {k[2], 0, -k[0]}, {-k[1], k[0], 0}};
    double s = sin(th), c = 1 - cos(th);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double kk = 0;
            for (int m = 0; m < 3; m++) kk += K[i][m] * K[m][j];
            M[i][j] = (i == j) + s * K[i][j] + c * kk;
        }
}

int rf_base64_decode(const char *text, unsigned char **out, size_t *len)
{
    size_t n = strlen(text), o = 0;
    unsigned acc = 0;
    int bits = 0, pad = 0;
    unsigned char *buf = malloc(n / 4 * 3 + 3);
    if (!buf) return -1;
    for (size_t i = 0; i < n; i++) {
        int c = (unsigned char)text[i], v;
        if (c >= 'A' && c <= 'Z')
            v = c - 'A';
        else if (c >= 'a' && c <= 'z')
            v = c - 'a' + 26;
        else if (c >= '0' && c <= '9')
            v = c - '0' + 52;
        else if (c == '+')
            v = 62;
        else if (c == '/')
            v = 63;
        else if (c == '=') {
            pad++;
            continue;
        } else
            goto bad;
        if (pad) goto bad; /* data after padding */
        acc = (acc << 6) | (unsigned)v;
        bits += 6;
        if (bits >= 8) {
            bits -= 8;
            buf[o++] = (unsigned char)(acc >> bits);
            acc &= (1u << bits) - 1;
        }
    }
    if (pad > 2 || (n % 4) != 0) goto bad;
    *out = buf;
    *len = o;
    return 0;
bad:
    free(buf);
    return -1;
}

/* ---- pyramids ------------------------------------------------------------------ */

/* 2x2 box reduction, in the order of training/refine.py's reduce2 (exact in
 * float for the values it sees). */
static void reduce2(const float *src, int w, int h, float *dst)
{
    int w2 = w / 2, h2 = h / 2;
    for (int j = 0; j < h2; j++)
        for (int i = 0; i < w2; i++)
            for (int c = 0; c < 3; c++) {
                const float *a = src + ((size_t)(2 * j) * w + 2 * i) * 3 + c;
                const float *b = a + (size_t)w * 3;
                dst[((size_t)j * w2 + i) * 3 + c] = ((a[0] + a[3]) + (b[0] + b[3])) * 0.25f;
            }
}

/* Pixel (i, j) of an 8-bit image as BGR doubles (gray replicated, alpha dropped). */
static inline void load_px(const rf_image *im, int i, int j, double *out)
{
    const uint8_t *p = im->data + (size_t)j * im->stride + (size_t)i * im->channels;
    if (im->channels == 1)
        out[0] = out[1] = out[2] = p[0];
    else {
        out[0] = p[0];
        out[1] = p[1];
        out[2] = p[2];
    }
}

/* The texture's levels are read at scattered places, mostly out of the
 * caches (the network ran in between): in 2 MB pages where the system gives
 * them (Linux), a lookup seldom misses the TLB as well. */
static void *tex_alloc(size_t bytes)
{
    void *p = NULL;
#ifdef MADV_HUGEPAGE
    size_t huge = (size_t)2 << 20;
    if (bytes >= huge / 2) {
        size_t n = (bytes + huge - 1) / huge * huge;
        if (posix_memalign(&p, huge, n)) return NULL;
        madvise(p, n, MADV_HUGEPAGE);
        return p;
    }
#endif
    return posix_memalign(&p, 64, bytes) ? NULL : p; /* a tile a cache line */
}

rf_texture *rf_texture_new(const rf_image *img, char *err)
{
    int w = img->width, h = img->height, unit = RF_TEXTURE_WIDTH >> (RF_LEVELS - 1);
    float *lv[RF_LEVELS] = {NULL};
    if (w != 2 * h || h < 8) {
        pi_seterrn(err, RF_TEXTURE_ERR_LEN, "texture is %dx%d, expected width = 2 x height", w, h);
        return NULL;
    }
    if (w % unit || w < RF_TEXTURE_WIDTH) {
        pi_seterrn(err, RF_TEXTURE_ERR_LEN,
                   "texture width %d must be a multiple of %d and at least %d", w, unit,
                   RF_TEXTURE_WIDTH);
        return NULL;
    }
    if (img->channels != 1 && img->channels != 3 && img->channels != 4) {
        pi_seterrn(err, RF_TEXTURE_ERR_LEN, "texture must have 1, 3 or 4 channels");
        return NULL;
    }
    rf_texture *t = calloc(1, sizeof *t);
    float *full = malloc((size_t)w * h * 3 * sizeof(float));
    if (!t || !full) goto oom;
    for (int j = 0; j < h; j++)
        for (int i = 0; i < w; i++) {
            double px[3];
            load_px(img, i, j, px);
            for (int c = 0; c < 3; c++) full[((size_t)j * w + i) * 3 + c] = (float)px[c];
        }
    while (w > RF_TEXTURE_WIDTH) {
        float *half = malloc((size_t)(w / 2) * (h / 2) * 3 * sizeof(float));
        if (!half) goto oom;
        reduce2(full, w, h, half);
        free(full);
        full = half;
        w /= 2;
        h /= 2;
    }
    lv[0] = full;
    full = NULL;
    t->w[0] = w;
    t->h[0] = h;
    for (int l = 1; l < RF_LEVELS; l++) {
        t->w[l] = t->w[l - 1] / 2;
        t->h[l] = t->h[l - 1] / 2;
        lv[l] = malloc((size_t)t->w[l] * t->h[l] * 3 * sizeof(float));
        if (!lv[l]) goto oom;
        reduce2(lv[l - 1], t->w[l - 1], t->h[l - 1], lv[l]);
    }
    /* each level with its border: column -1 is column w - 1, column w is
     * column 0 (the longitude wraps); row -1 is row 0, row h is row h - 1
     * (training/refine.py sample clamps the latitude) */
    for (int l = 0; l < RF_LEVELS; l++) {
        int lw = t->w[l], lh = t->h[l];
        int tiles_w = (lw + 2 + RF_TILE_W - 1) / RF_TILE_W,
            tiles_h = (lh + 2 + RF_TILE_H - 1) / RF_TILE_H;
        t->tr[l] = tiles_w * RF_TILE_W * RF_TILE_H;
        size_t bytes = (size_t)tiles_w * tiles_h * RF_TILE_W * RF_TILE_H * 4 * sizeof(uint16_t);
        uint16_t *p = tex_alloc(bytes);
        if (!p) goto oom;
        memset(p, 0, bytes);
        /* 4^k, k the 2x2 reductions from the given texture to this level */
        float mul = 1;
        for (int ww = img->width; ww > t->w[l] && mul < 256; ww /= 2) mul *= 4;
        t->scale[l] = 1.0f / mul;
        int fits = 1;
        for (int j = -1; j <= lh; j++) {
            int sj = j < 0 ? 0 : j >= lh ? lh - 1 : j;
            const float *src = lv[l] + (size_t)sj * lw * 3;
            for (int i = -1; i <= lw; i++) {
                int si = i < 0 ? lw - 1 : i >= lw ? 0 : i;
                uint16_t *q = p + (size_t)RF_TILE_OFF(i + 1, j + 1, t->tr[l]) * 4;
                for (int c = 0; c < 3; c++) {
                    q[c] = (uint16_t)lrintf(src[(size_t)si * 3 + c] * mul);
                    fits &= q[c] < 1024;
                }
            }
        }
        t->px[l] = p;
        if (!fits) continue;
        /* the same texels as pairs: entries (I, J), I <= w (the lookup's
         * left column), J <= h + 1, in bands of 8 rows */
        int cols = lw + 1, bands = (lh + 2 + 7) / 8, tr = cols * 8;
        uint64_t *e = tex_alloc((size_t)bands * tr * sizeof(uint64_t));
        if (!e) goto oom;
        memset(e, 0, (size_t)bands * tr * sizeof(uint64_t));
        for (int J = 0; J < lh + 2; J++)
            for (int I = 0; I < cols; I++) {
                uint64_t v[2];
                for (int x = 0; x < 2; x++) {
                    const uint16_t *q = p + (size_t)RF_TILE_OFF(I + x, J, t->tr[l]) * 4;
                    v[x] = q[0] | (uint64_t)q[1] << 10 | (uint64_t)q[2] << 20;
                }
                e[RF_PAIR_OFF(I, J, tr)] = v[0] | v[1] << 32;
            }
        free(p);
        t->px[l] = NULL;
        t->pairs[l] = e;
        t->tr[l] = tr;
    }
    for (int l = 0; l < RF_LEVELS; l++) free(lv[l]);
    return t;
oom:
    free(full);
    for (int l = 0; l < RF_LEVELS; l++) free(lv[l]);
    rf_texture_free(t);
    pi_seterrn(err, RF_TEXTURE_ERR_LEN, "texture: out of memory");
    return NULL;
}

void rf_texture_free(rf_texture *t)
{
    if (!t) return;
    for (int l = 0; l < RF_LEVELS; l++) free(t->px[l]), free(t->pairs[l]);
    free(t);
}

rf_work *rf_work_new(void)
{
    rf_work *w = calloc(1, sizeof(rf_work));
    if (w)
        for (int m = 0; m < 256; m++)
            for (int l = 0, n = 0; l < 8; l++)
                if (m >> l & 1) w->pack[m][n++] = (uint8_t)l;
    return w;
}

void rf_work_free(rf_work *w)
{
    if (!w) return;
    free(w->buf);
    free(w);
}

/* Room for n samples (rounded up to RF_LANES) in the sample arrays; the
 * Jacobian's arrays and idx one vector longer (whole vectors are stored
 * past their last sample: gather_pass_avx512, gather_pass_avx2). */
static int reserve(rf_work *w, size_t n)
{
    n = (n + RF_LANES - 1) / RF_LANES * RF_LANES;
    if (n <= w->cap) return 0;
    size_t js = n + RF_LANES;
    void *p = NULL;
    if (posix_memalign(&p, 64, (n + js) * (A_COUNT * sizeof(float) + sizeof(int32_t)))) return -1;
    free(w->buf);
    w->buf = p;
    w->cap = n;
    for (int k = 0; k < A_COUNT; k++) {
        w->a[k] = (float *)p + (size_t)k * n;
        w->ja[k] = (float *)p + (size_t)A_COUNT * n + (size_t)k * js;
    }
    w->off = (int32_t *)((float *)p + (size_t)A_COUNT * (n + js));
    w->idx = w->off + n;
    return 0;
}

/* The square around the circle (training/refine.py frame_pyramid). Its
 * levels are not built: a level-l pixel is the mean of a 2^l x 2^l block of
 * the frame, summed where a sampled pixel needs it (sums of 8-bit values are
 * exact in any order, so this equals the Python pyramid's values). */
static int frame_crop(rf_work *w, const rf_image *f, double cx, double cy, double r, int *x0,
                      int *y0)
{
    double half = r + RF_CROP_PAD;
    int step = 1 << (RF_LEVELS - 1);
    int xa = (int)floor((cx - half) / step) * step, ya = (int)floor((cy - half) / step) * step;
    int xb = (int)ceil((cx + half) / step) * step, yb = (int)ceil((cy + half) / step) * step;
    if (xa < 0) xa = 0;
    if (ya < 0) ya = 0;
    if (xb > f->width) xb = f->width;
    if (yb > f->height) yb = f->height;
    if (xb <= xa || yb <= ya) return -2;
    w->frame = f;
    w->x0 = xa;
    w->y0 = ya;
    /* one channel, or three equal ones over the crop */
    w->gray = 1;
    if (f->channels != 1)
        for (int j = ya; j < yb && w->gray; j++) {
            const uint8_t *p = f->data + (size_t)j * f->stride + (size_t)xa * f->channels;
            for (int i = xa; i < xb; i++, p += f->channels)
                if (p[0] != p[1] || p[1] != p[2]) {
                    w->gray = 0;
                    break;
                }
        }
    w->w[0] = xb - xa;
    w->h[0] = yb - ya;
    for (int l = 1; l < RF_LEVELS; l++) {
        w->w[l] = w->w[l - 1] / 2;
        w->h[l] = w->h[l - 1] / 2;
    }
    *x0 = xa;
    *y0 = ya;
    return 0;
}

/* ---- geometry ------------------------------------------------------------------- */

static inline double focal_of(double r, double fixed_f)
{
    return fixed_f > 0 ? fixed_f : r * sqrt(RF_REF_D_OVER_R * RF_REF_D_OVER_R - 1.0);
}

/* The per-pixel loops work on RF_LANES samples at a time in GCC's generic
 * vectors, which each version compiles to its widest registers (the baseline
 * to four SSE2 operations). */
/* (static helpers only, always inlined: no vector crosses a call, so
 * GCC's note on the vector ABI does not apply) */
#pragma GCC diagnostic ignored "-Wpsabi"
typedef float vf __attribute__((vector_size(RF_VL * sizeof(float))));
typedef int32_t vi __attribute__((vector_size(RF_VL * sizeof(int32_t))));

typedef float vh __attribute__((vector_size(RF_VL / 2 * sizeof(float))));
typedef double vd __attribute__((vector_size(RF_VL / 2 * sizeof(double))));
typedef struct vf2 {
    vh lo, hi;
} vf2;                /* a vf's halves */
#define RF_JBLOCK 256 /* samples per float block of the Jacobian sums */

/* RF_VL / 2 samples as doubles (p: a multiple of that) */
static inline vd vdload(const float *p)
{
    return __builtin_convertvector(*(const vh *)p, vd);
}

static inline vf vload(const float *p) /* p: RF_VL-aligned sample arrays */
{
    return *(const vf *)p;
}

/* Lane masks come from sign bits, not from comparisons: GCC splits a vector
 * wider than the machine's into halves, but not a comparison's mask. */
static inline vi vneg(vf x) /* all ones where x < 0 (also -0) */
{
    return (vi)x >> 31;
}

/* m ? a : b lane by lane (m: all ones or zero) */
static inline vf vsel(vi m, vf a, vf b)
{
    return (vf)(((vi)a & m) | ((vi)b & ~m));
}

static inline vi vimax(vi a, int b) /* |a - b| < 2^31 */
{
    vi m = (b - a) >> 31;
    return (a & m) | (b & ~m);
}

static inline vi vimin(vi a, int b)
{
    vi m = (a - b) >> 31;
    return (a & m) | (b & ~m);
}

static inline vf vabs(vf x)
{
    return (vf)((vi)x & 0x7fffffff);
}

/* 1 / sqrt(x), x >= 0, within 2e-7: a bit-level first guess and three Newton
 * steps (sqrtf does not vectorise without -fno-math-errno). */
static inline vf vrsqrt(vf x)
{
    vf h = 0.5f * x, y = (vf)(0x5f3759df - ((vi)x >> 1));
    y = y * (1.5f - h * y * y);
    y = y * (1.5f - h * y * y);
    y = y * (1.5f - h * y * y);
    return y;
}

/* atan2 (Cephes' atanf on |t| <= tan(pi/8), and atan(t) = pi/4 +
 * atan((t - 1) / (t + 1)) above; the quadrant from the signs): within 2e-7
 * rad, a hundredth of a texel's width at the finest level. */
static inline vf vatan2(vf y, vf x)
{
    vf ax = vabs(x), ay = vabs(y);
    vi swap = vneg(ax - ay); /* ay > ax */
    vf mx = vsel(swap, ay, ax), mn = vsel(swap, ax, ay);
    /* t = mn / mx in [0, 1] (0 at the origin); above tan(pi/8) the reduced
     * argument (t - 1) / (t + 1) = (mn - mx) / (mn + mx): one division */
    vi big = vneg(0.41421356f * mx - mn);
    vf u = vsel(big, mn - mx, mn) / (vsel(big, mn, (vf){0}) + mx + 1e-30f);
    vf z = u * u;
    vf p = ((8.05374449538e-2f * z - 1.38776856032e-1f) * z + 1.99777106478e-1f) * z -
           3.33329491539e-1f;
    vf a = vsel(big, (vf){0} + (float)(M_PI / 4), (vf){0}) + (p * z * u + u);
    a = vsel(swap, (float)(M_PI / 2) - a, a);
    a = vsel(vneg(x), (float)M_PI - a, a);
    return vsel(vneg(y), -a, a);
}

/* The two pieces of geometry both the value pass and the Jacobian compute
 * (the Jacobian again, for its own samples: see geometry_pass), written once
 * so that the two give the same bits. The ray through pixel (ax, ay): its
 * image-plane slope (x, y), p2 = x^2 + y^2, inv = 1 / |(x, y, -1)|. */
static inline __attribute__((always_inline)) void
ray_slope(vf ax, vf ay, float dcx, float dcy, float inv_f, vf *x, vf *y, vf *p2, vf *inv)
{
    *x = (ax - dcx) * inv_f;
    *y = -(ay - dcy) * inv_f;
    *p2 = *x * *x + *y * *y;
    *inv = vrsqrt(*p2 + 1.0f);
}

/* The body frame's x and z of the normal n (R^T n), and rho2 = bx^2 + bz^2
 * kept off 0 (the texture's pole). */
static inline __attribute__((always_inline)) void body_xz(const float R[9], vf n0, vf n1, vf n2,
                                                          vf *bx, vf *bz, vf *rho2)
{
    *bx = R[0] * n0 + R[3] * n1 + R[6] * n2;
    *bz = R[2] * n0 + R[5] * n1 + R[8] * n2;
    vf r2 = *bx * *bx + *bz * *bz;
    *rho2 = vsel(vneg(1e-12f - r2), r2, (vf){0} + 1e-12f);
}

/* Where each sample's ray meets the sphere (training/refine.py normals), the
 * body direction b = R^T n, and where b reads the texture (sample's first
 * half): texel offset, bilinear weights. gp (GEO_*): the circle's centre
 * minus the arrays' origin, 1 / f, camera to centre (unit sphere), texels a
 * radian along u and along v; tw, th: the texture level's size, tr its
 * texels a row of tiles (pair: entries a band of the pairs' layout). The
 * ray and d (u, v) / d b, which only the Jacobian reads, are not kept:
 * jac_sums_n computes them again for its few samples (writing them for
 * every sample cost more). */
enum { GEO_DCX, GEO_DCY, GEO_INVF, GEO_DIST, GEO_KW, GEO_KH };
RF_BODY void geometry_pass_body(rf_work *w, long n, const float R[9], const float gp[6], int tw,
                                int th, int tr, int pair)
{
    const float dcx = gp[GEO_DCX], dcy = gp[GEO_DCY], inv_f = gp[GEO_INVF], dist = gp[GEO_DIST];
    const float dist2 = dist * dist, kw = gp[GEO_KW], kh = gp[GEO_KH];
    const float u0 = (float)(tw / 2.0 - 0.5), v0 = (float)(th / 2.0 - 0.5);
    for (long k = 0; k < n; k += RF_VL) {
        vf x, y, p2, inv;
        ray_slope(vload(w->a[A_X] + k), vload(w->a[A_Y] + k), dcx, dcy, inv_f, &x, &y, &p2, &inv);
        vf inv2 = inv * inv;
        /* disc = (O.d)^2 - |O|^2 + 1 written without the cancellation of the
         * two large terms: 1 - dist^2 sin^2 of the ray's angle */
        vf disc = 1.0f - dist2 * p2 * inv2;
        disc = vsel(vneg(disc), (vf){0}, disc);
        vf sd = disc * vrsqrt(disc);
        vf t = dist * inv - sd;
        vf n0 = t * x * inv, n1 = t * y * inv, n2 = dist * p2 * inv2 + sd * inv;
        vf bx, bz, rho2;
        body_xz(R, n0, n1, n2, &bx, &bz, &rho2);
        vf by = R[1] * n0 + R[4] * n1 + R[7] * n2;
        vf irho = vrsqrt(rho2), rho = rho2 * irho;
        vf ut = vatan2(bx, bz) * kw + u0;
        vf vt = v0 - vatan2(by, rho) * kh;
        /* floor (x86-64's baseline has no rounding instruction) */
        vi i0 = __builtin_convertvector(ut, vi), j0 = __builtin_convertvector(vt, vi);
        i0 += vneg(ut - __builtin_convertvector(i0, vf)); /* -1 where i0 > ut */
        j0 += vneg(vt - __builtin_convertvector(j0, vf));
        *(vf *)(w->a[A_FX] + k) = ut - __builtin_convertvector(i0, vf);
        *(vf *)(w->a[A_FY] + k) = vt - __builtin_convertvector(j0, vf);
        /* ut lies in [-0.5, tw - 0.5], vt in [-0.5, th - 0.5]: the border */
        i0 = vimin(vimax(i0, -1), tw - 1);
        j0 = vimin(vimax(j0, -1), th - 1);
        i0 += 1;
        j0 += 1;
        *(vi *)(w->off + k) = pair ? RF_PAIR_OFF(i0, j0, tr) : RF_TILE_OFF(i0, j0, tr);
        *(vf *)(w->a[A_T] + k) = t;
        *(vf *)(w->a[A_NX] + k) = n0;
        *(vf *)(w->a[A_NY] + k) = n1;
        *(vf *)(w->a[A_NZ] + k) = n2;
    }
}
RF_VERSIONS(void, geometry_pass,
            (rf_work * w, long n, const float R[9], const float gp[6], int tw, int th, int tr,
             int pair),
            (w, n, R, gp, tw, th, tr, pair))
#ifdef RF_X86_GCC
/* The bilinear lookups below, 16 samples at a time with AVX-512: each
 * texel's three channels in one 64-bit load (a pair of texels where the
 * level is stored as pairs), the loads of a block gathered together, and the
 * texels of the block after next asked for (after the network has run, the
 * texture is mostly out of the caches); the arithmetic is the loop's, lane
 * by lane. Only the values are kept for every sample: the derivatives, which
 * only the Jacobian reads, go straight to its arrays (w->ja) for the samples
 * that have one (np: samples before the padding), with the values and the
 * indices in w->idx, as jac_samples would pick them; returns their count. */
__attribute__((target("avx512f,avx512bw"))) static long
gather_pass_avx512(rf_work *w, long n, long np, const void *restrict tex, int pair, int tr,
                   float scale)
{
    const int32_t *restrict off = w->off;
    const float *restrict fx = w->a[A_FX], *restrict fy = w->a[A_FY];
    const long long *base = (const long long *)tex;
    __m512i pick[3]; /* word c of the 8 texels of each half, in sample order */
    for (int c = 0; c < 3; c++) {
        short ix[32];
        for (int l = 0; l < 32; l++)
            ix[l] = (short)(l < 8 ? 4 * l + c : l < 16 ? 32 + 4 * (l - 8) + c : 0);
        pick[c] = _mm512_loadu_si512(ix);
    }
    const __m512i lodw =
                      _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30),
                  hidw = _mm512_add_epi32(lodw, _mm512_set1_epi32(1)),
                  ten = _mm512_set1_epi32(0x3ff);
    const __m512 sc = _mm512_set1_ps(scale);
    const __m256i one = _mm256_set1_epi32(1), three = _mm256_set1_epi32(3),
                  four = _mm256_set1_epi32(4), seven = _mm256_set1_epi32(7),
                  down = _mm256_set1_epi32(tr - 8); /* (tr - 7 = 1 + down: RF_PAIR_DY) */
    const __m512i lane = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15),
                  nosign = _mm512_set1_epi32(0x7fffffff);
    long m = 0;
    for (long k = 0; k < n; k += 16) {
        /* the texels of the samples two blocks on (the cell's top and bottom
         * rows): their misses overlap this block's (the gather alone waits
         * for each block in turn) */
        if (k + 32 < n)
            for (int l = 0; l < 16; l++) {
                int32_t o = off[k + 32 + l];
                const long long *p = base + o;
                __builtin_prefetch(p);
                __builtin_prefetch(p + (pair ? RF_PAIR_DY(o, tr) : RF_TILE_DY(o, tr)));
            }
        __m256i lo = _mm256_load_si256((const __m256i *)(off + k)),
                hi = _mm256_load_si256((const __m256i *)(off + k + 8));
        __m256i o[2] = {lo, hi};
        __m512 v[3][4]; /* channel c's texels (i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1) */
        if (pair) {
            __m512i g[2][2];
            for (int h = 0; h < 2; h++) {
                /* RF_PAIR_DY lane by lane: 1, or tr - 7 in a band's last row */
                __m256i last = _mm256_cmpeq_epi32(_mm256_and_si256(o[h], seven), seven);
                __m256i dy = _mm256_add_epi32(one, _mm256_and_si256(last, down));
                g[0][h] = _mm512_i32gather_epi64(o[h], base, 8);
                g[1][h] = _mm512_i32gather_epi64(_mm256_add_epi32(o[h], dy), base, 8);
            }
            for (int r = 0; r < 2; r++) {
                __m512i left = _mm512_permutex2var_epi32(g[r][0], lodw, g[r][1]),
                        right = _mm512_permutex2var_epi32(g[r][0], hidw, g[r][1]);
                for (int c = 0; c < 3; c++) {
                    __m512i l = _mm512_and_si512(_mm512_srli_epi32(left, 10 * c), ten),
                            q = _mm512_and_si512(_mm512_srli_epi32(right, 10 * c), ten);
                    v[c][2 * r] = _mm512_mul_ps(_mm512_cvtepi32_ps(l), sc);
                    v[c][2 * r + 1] = _mm512_mul_ps(_mm512_cvtepi32_ps(q), sc);
                }
            }
        } else {
            __m512i g[4][2];
            for (int h = 0; h < 2; h++) {
                /* RF_TILE_DX, RF_TILE_DY lane by lane */
                __m256i dx = _mm256_add_epi32(
                    one,
                    _mm256_and_si256(_mm256_add_epi32(_mm256_and_si256(o[h], three), one), four));
                __m256i dy = _mm256_add_epi32(
                    four,
                    _mm256_and_si256(_mm256_srai_epi32(_mm256_slli_epi32(o[h], 29), 31), down));
                __m256i o01 = _mm256_add_epi32(o[h], dy);
                g[0][h] = _mm512_i32gather_epi64(o[h], base, 8);
                g[1][h] = _mm512_i32gather_epi64(_mm256_add_epi32(o[h], dx), base, 8);
                g[2][h] = _mm512_i32gather_epi64(o01, base, 8);
                g[3][h] = _mm512_i32gather_epi64(_mm256_add_epi32(o01, dx), base, 8);
            }
            for (int c = 0; c < 3; c++)
                for (int q = 0; q < 4; q++) {
                    __m512i x = _mm512_permutex2var_epi16(g[q][0], pick[c], g[q][1]);
                    v[c][q] = _mm512_mul_ps(
                        _mm512_cvtepi32_ps(_mm512_cvtepu16_epi32(_mm512_castsi512_si256(x))), sc);
                }
        }
        __m512 a = _mm512_load_ps(fx + k), b = _mm512_load_ps(fy + k), du[3], dv[3], val[3];
        __m512i any = _mm512_setzero_si512();
        for (int c = 0; c < 3; c++) {
            __m512 a00 = v[c][0], a10 = v[c][1], a01 = v[c][2], a11 = v[c][3];
            __m512 d0 = _mm512_sub_ps(a10, a00), d1 = _mm512_sub_ps(a11, a01);
            /* fused as the other AVX-512 loops fuse (the scaling is exact) */
            __m512 top = _mm512_fmadd_ps(a, d0, a00), bot = _mm512_fmadd_ps(a, d1, a01);
            dv[c] = _mm512_sub_ps(bot, top);
            du[c] = _mm512_fmadd_ps(b, _mm512_sub_ps(d1, d0), d0);
            val[c] = _mm512_fmadd_ps(b, dv[c], top);
            _mm512_store_ps(w->a[A_V0 + c] + k, val[c]);
            any = _mm512_or_si512(
                any, _mm512_or_si512(_mm512_castps_si512(du[c]), _mm512_castps_si512(dv[c])));
        }
        /* the Jacobian's samples: a derivative nonzero (-0 is 0), not padding */
        __mmask16 act = _mm512_test_epi32_mask(any, nosign);
        if (k + 16 > np) act &= (__mmask16)(np > k ? (1u << (np - k)) - 1 : 0);
        if (act) {
            _mm512_storeu_si512(w->idx + m,
                                _mm512_maskz_compress_epi32(
                                    act, _mm512_add_epi32(_mm512_set1_epi32((int)k), lane)));
            for (int c = 0; c < 3; c++) {
                _mm512_storeu_ps(w->ja[A_V0 + c] + m, _mm512_maskz_compress_ps(act, val[c]));
                _mm512_storeu_ps(w->ja[A_DU0 + c] + m, _mm512_maskz_compress_ps(act, du[c]));
                _mm512_storeu_ps(w->ja[A_DV0 + c] + m, _mm512_maskz_compress_ps(act, dv[c]));
            }
            m += __builtin_popcount(act);
        }
    }
    return m;
}
#endif

#ifdef RF_X86_GCC
/* gather_pass_avx512 with AVX2, 8 samples at a time, and the operations of
 * the baseline's gather_pass lane by lane (nothing fused): the AVX2 and
 * baseline versions give the same bits. The compressed stores take their
 * lanes from w->pack. */
__attribute__((target("avx2"), optimize("fp-contract=off"))) static long
gather_pass_avx2(rf_work *w, long n, long np, const void *restrict tex, int pair, int tr,
                 float scale)
{
    const int32_t *restrict off = w->off;
    const float *restrict fx = w->a[A_FX], *restrict fy = w->a[A_FY];
    const long long *base = (const long long *)tex;
    const __m256 sc = _mm256_set1_ps(scale);
    const __m256i one = _mm256_set1_epi32(1), three = _mm256_set1_epi32(3),
                  four = _mm256_set1_epi32(4), seven = _mm256_set1_epi32(7),
                  down = _mm256_set1_epi32(tr - 8), ten = _mm256_set1_epi32(0x3ff),
                  word = _mm256_set1_epi32(0xffff), nosign = _mm256_set1_epi32(0x7fffffff),
                  lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    long m = 0;
    for (long k = 0; k < n; k += 8) {
        if (k + 32 < n)
            for (int l = 0; l < 8; l++) {
                int32_t o = off[k + 32 + l];
                const long long *p = base + o;
                __builtin_prefetch(p);
                __builtin_prefetch(p + (pair ? RF_PAIR_DY(o, tr) : RF_TILE_DY(o, tr)));
            }
        __m256i o = _mm256_load_si256((const __m256i *)(off + k));
        __m256 v[3][4]; /* channel c's texels (i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1) */
#define RF_GATHER8(dst, idx)                                                                 \
    do {                                                                                     \
        __m256 a_ = _mm256_castsi256_ps(                                                     \
                   _mm256_i32gather_epi64(base, _mm256_castsi256_si128(idx), 8)),            \
               b_ = _mm256_castsi256_ps(                                                     \
                   _mm256_i32gather_epi64(base, _mm256_extracti128_si256(idx, 1), 8));       \
        /* each 64-bit word's low and high halves, in sample order */                        \
        dst[0] = _mm256_castpd_si256(                                                        \
            _mm256_permute4x64_pd(_mm256_castps_pd(_mm256_shuffle_ps(a_, b_, 0x88)), 0xd8)); \
        dst[1] = _mm256_castpd_si256(                                                        \
            _mm256_permute4x64_pd(_mm256_castps_pd(_mm256_shuffle_ps(a_, b_, 0xdd)), 0xd8)); \
    } while (0)
        if (pair) {
            __m256i last = _mm256_cmpeq_epi32(_mm256_and_si256(o, seven), seven);
            __m256i dy = _mm256_add_epi32(one, _mm256_and_si256(last, down));
            for (int r = 0; r < 2; r++) {
                __m256i g[2]; /* the left and right texels */
                RF_GATHER8(g, r ? _mm256_add_epi32(o, dy) : o);
                for (int c = 0; c < 3; c++)
                    for (int x = 0; x < 2; x++)
                        v[c][2 * r + x] = _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_and_si256(
                                                            _mm256_srli_epi32(g[x], 10 * c), ten)),
                                                        sc);
            }
        } else {
            __m256i dx = _mm256_add_epi32(
                one, _mm256_and_si256(_mm256_add_epi32(_mm256_and_si256(o, three), one), four));
            __m256i dy = _mm256_add_epi32(
                four, _mm256_and_si256(_mm256_srai_epi32(_mm256_slli_epi32(o, 29), 31), down));
            for (int q = 0; q < 4; q++) {
                __m256i oq = o, g[2]; /* B | G << 16 and R of each texel */
                if (q & 1) oq = _mm256_add_epi32(oq, dx);
                if (q & 2) oq = _mm256_add_epi32(oq, dy);
                RF_GATHER8(g, oq);
                __m256i ch[3] = {_mm256_and_si256(g[0], word), _mm256_srli_epi32(g[0], 16),
                                 _mm256_and_si256(g[1], word)};
                for (int c = 0; c < 3; c++) v[c][q] = _mm256_mul_ps(_mm256_cvtepi32_ps(ch[c]), sc);
            }
        }
#undef RF_GATHER8
        __m256 a = _mm256_load_ps(fx + k), b = _mm256_load_ps(fy + k), du[3], dv[3], val[3];
        __m256i any = _mm256_setzero_si256();
        for (int c = 0; c < 3; c++) {
            __m256 a00 = v[c][0], a10 = v[c][1], a01 = v[c][2], a11 = v[c][3];
            __m256 d0 = _mm256_sub_ps(a10, a00), d1 = _mm256_sub_ps(a11, a01);
            __m256 top = _mm256_add_ps(a00, _mm256_mul_ps(a, d0)),
                   bot = _mm256_add_ps(a01, _mm256_mul_ps(a, d1));
            val[c] = _mm256_add_ps(top, _mm256_mul_ps(b, _mm256_sub_ps(bot, top)));
            du[c] = _mm256_add_ps(d0, _mm256_mul_ps(b, _mm256_sub_ps(d1, d0)));
            dv[c] = _mm256_sub_ps(bot, top);
            _mm256_store_ps(w->a[A_V0 + c] + k, val[c]);
            any = _mm256_or_si256(
                any, _mm256_or_si256(_mm256_castps_si256(du[c]), _mm256_castps_si256(dv[c])));
        }
        /* the Jacobian's samples: a derivative nonzero (-0 is 0), not padding */
        unsigned act = ~(unsigned)_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(
                           _mm256_and_si256(any, nosign), _mm256_setzero_si256()))) &
                       0xff;
        if (k + 8 > np) act &= np > k ? (1u << (np - k)) - 1 : 0;
        if (act) {
            __m256i perm = _mm256_cvtepu8_epi32(_mm_loadl_epi64((const __m128i *)w->pack[act]));
            _mm256_storeu_si256((__m256i *)(w->idx + m),
                                _mm256_permutevar8x32_epi32(
                                    _mm256_add_epi32(_mm256_set1_epi32((int)k), lane), perm));
            for (int c = 0; c < 3; c++) {
                _mm256_storeu_ps(w->ja[A_V0 + c] + m, _mm256_permutevar8x32_ps(val[c], perm));
                _mm256_storeu_ps(w->ja[A_DU0 + c] + m, _mm256_permutevar8x32_ps(du[c], perm));
                _mm256_storeu_ps(w->ja[A_DV0 + c] + m, _mm256_permutevar8x32_ps(dv[c], perm));
            }
            m += __builtin_popcount(act);
        }
    }
    return m;
}
#endif

/* The bilinear lookups (sample's second half): the texture's values for
 * every sample, and for the samples with a derivative along the texel axes
 * (the Jacobian's: jac_samples) their values and derivatives per channel,
 * compressed into w->ja with their indices in w->idx; returns their count.
 * Where the texture is flat over a sample's 2 x 2 texels (most of the
 * paper's textures: bars of one colour) its derivatives are exactly 0 in
 * every channel, and so is all it adds to J^T J, J^T A and J^T e: the
 * Jacobian pass skips it. tr: texels a row of tiles; pairs: the level as
 * pairs (tr: entries a band), else NULL. This is the portable version's;
 * each x86-64 version has its own, which does the same lane by lane:
 * gather_pass_avx512, gather_pass_avx2, gather_pass_sse2 (the baseline). */
RF_NOFUSE static long gather_pass(rf_work *w, long n, long np, const uint16_t *restrict tex,
                                  const uint64_t *restrict pairs, int tr, float scale)
{
    const int32_t *restrict off = w->off;
    const float *restrict fx = w->a[A_FX], *restrict fy = w->a[A_FY];
    long m = 0;
    for (long k = 0; k < n; k++) {
        int32_t o = off[k];
        if (k + 32 < n) {
            int32_t f = off[k + 32];
            if (pairs) {
                __builtin_prefetch(pairs + f);
                __builtin_prefetch(pairs + f + RF_PAIR_DY(f, tr));
            } else {
                __builtin_prefetch(tex + (long)f * 4);
                __builtin_prefetch(tex + ((long)f + RF_TILE_DY(f, tr)) * 4);
            }
        }
        float val[3], du[3], dv[3];
        uint32_t any = 0;
        for (int c = 0; c < 3; c++) {
            float a00, a10, a01, a11;
            if (pairs) {
                uint64_t p0 = pairs[o] >> 10 * c, p1 = pairs[o + RF_PAIR_DY(o, tr)] >> 10 * c;
                a00 = (float)(p0 & 0x3ff) * scale;
                a10 = (float)(p0 >> 32 & 0x3ff) * scale;
                a01 = (float)(p1 & 0x3ff) * scale;
                a11 = (float)(p1 >> 32 & 0x3ff) * scale;
            } else {
                long dx = (long)RF_TILE_DX(o) * 4, dy = (long)RF_TILE_DY(o, tr) * 4;
                const uint16_t *p = tex + (long)o * 4 + c;
                a00 = p[0] * scale;
                a10 = p[dx] * scale;
                a01 = p[dy] * scale;
                a11 = p[dy + dx] * scale;
            }
            float a = fx[k], b = fy[k];
            float top = a00 + a * (a10 - a00), bot = a01 + a * (a11 - a01);
            val[c] = top + b * (bot - top);
            du[c] = (a10 - a00) + b * ((a11 - a01) - (a10 - a00));
            dv[c] = bot - top;
            w->a[A_V0 + c][k] = val[c];
            uint32_t bu, bv;
            memcpy(&bu, &du[c], 4);
            memcpy(&bv, &dv[c], 4);
            any |= (bu | bv) & 0x7fffffff; /* -0 is 0 */
        }
        if (any && k < np) {
            w->idx[m] = (int32_t)k;
            for (int c = 0; c < 3; c++) {
                w->ja[A_V0 + c][m] = val[c];
                w->ja[A_DU0 + c][m] = du[c];
                w->ja[A_DV0 + c][m] = dv[c];
            }
            m++;
        }
    }
    return m;
}
#ifdef RF_X86_GCC
/* gather_pass_avx2 for the baseline (SSE2), 4 samples at a time: no gathers,
 * each texel entry loaded on its own; the lanes of the Jacobian's samples
 * copied one by one. */
__attribute__((optimize("fp-contract=off"))) static long
gather_pass_sse2(rf_work *w, long n, long np, const uint16_t *restrict tex,
                 const uint64_t *restrict pairs, int tr, float scale)
{
    const int32_t *restrict off = w->off;
    const float *restrict fx = w->a[A_FX], *restrict fy = w->a[A_FY];
    /* read as 64-bit entries what was written as uint16_t tiles or uint64_t
     * pairs: may_alias keeps that defined under strict aliasing */
    typedef long long __attribute__((may_alias)) entry64;
    const entry64 *base = pairs ? (const entry64 *)pairs : (const entry64 *)tex;
    const __m128 sc = _mm_set1_ps(scale);
    const __m128i ten = _mm_set1_epi32(0x3ff), word = _mm_set1_epi32(0xffff),
                  nosign = _mm_set1_epi32(0x7fffffff);
    long m = 0;
    for (long k = 0; k < n; k += 4) {
        if (k + 32 < n)
            for (int l = 0; l < 4; l++) {
                int32_t o = off[k + 32 + l];
                const entry64 *p = base + o;
                __builtin_prefetch(p);
                __builtin_prefetch(p + (pairs ? RF_PAIR_DY(o, tr) : RF_TILE_DY(o, tr)));
            }
        __m128 v[3][4]; /* channel c's texels (i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1) */
        /* the entries at o[l] + d[l] of the 4 samples: their low and high 32 bits */
#define RF_LOAD4(dst, d)                                                                  \
    do {                                                                                  \
        __m128 a_ = _mm_castsi128_ps(                                                     \
                   _mm_set_epi64x(base[off[k + 1] + (d)[1]], base[off[k] + (d)[0]])),     \
               b_ = _mm_castsi128_ps(                                                     \
                   _mm_set_epi64x(base[off[k + 3] + (d)[3]], base[off[k + 2] + (d)[2]])); \
        dst[0] = _mm_castps_si128(_mm_shuffle_ps(a_, b_, 0x88));                          \
        dst[1] = _mm_castps_si128(_mm_shuffle_ps(a_, b_, 0xdd));                          \
    } while (0)
        if (pairs) {
            int32_t d[2][4];
            for (int l = 0; l < 4; l++) d[0][l] = 0, d[1][l] = RF_PAIR_DY(off[k + l], tr);
            for (int r = 0; r < 2; r++) {
                __m128i g[2]; /* the left and right texels */
                RF_LOAD4(g, d[r]);
                for (int c = 0; c < 3; c++)
                    for (int x = 0; x < 2; x++)
                        v[c][2 * r + x] = _mm_mul_ps(
                            _mm_cvtepi32_ps(_mm_and_si128(_mm_srli_epi32(g[x], 10 * c), ten)), sc);
            }
        } else {
            int32_t d[4][4];
            for (int l = 0; l < 4; l++) {
                int32_t o = off[k + l], dx = RF_TILE_DX(o), dy = RF_TILE_DY(o, tr);
                d[0][l] = 0, d[1][l] = dx, d[2][l] = dy, d[3][l] = dy + dx;
            }
            for (int q = 0; q < 4; q++) {
                __m128i g[2]; /* B | G << 16 and R of each texel */
                RF_LOAD4(g, d[q]);
                __m128i ch[3] = {_mm_and_si128(g[0], word), _mm_srli_epi32(g[0], 16),
                                 _mm_and_si128(g[1], word)};
                for (int c = 0; c < 3; c++) v[c][q] = _mm_mul_ps(_mm_cvtepi32_ps(ch[c]), sc);
            }
        }
#undef RF_LOAD4
        __m128 a = _mm_load_ps(fx + k), b = _mm_load_ps(fy + k);
        float out[3][3][4]; /* val, du, dv per channel */
        __m128i any = _mm_setzero_si128();
        for (int c = 0; c < 3; c++) {
            __m128 a00 = v[c][0], a10 = v[c][1], a01 = v[c][2], a11 = v[c][3];
            __m128 d0 = _mm_sub_ps(a10, a00), d1 = _mm_sub_ps(a11, a01);
            __m128 top = _mm_add_ps(a00, _mm_mul_ps(a, d0)),
                   bot = _mm_add_ps(a01, _mm_mul_ps(a, d1));
            __m128 val = _mm_add_ps(top, _mm_mul_ps(b, _mm_sub_ps(bot, top)));
            __m128 du = _mm_add_ps(d0, _mm_mul_ps(b, _mm_sub_ps(d1, d0)));
            __m128 dv = _mm_sub_ps(bot, top);
            _mm_store_ps(w->a[A_V0 + c] + k, val);
            _mm_storeu_ps(out[c][0], val);
            _mm_storeu_ps(out[c][1], du);
            _mm_storeu_ps(out[c][2], dv);
            any = _mm_or_si128(any, _mm_or_si128(_mm_castps_si128(du), _mm_castps_si128(dv)));
        }
        /* the Jacobian's samples: a derivative nonzero (-0 is 0), not padding */
        unsigned act = ~(unsigned)_mm_movemask_ps(_mm_castsi128_ps(
                           _mm_cmpeq_epi32(_mm_and_si128(any, nosign), _mm_setzero_si128()))) &
                       0xf;
        if (k + 4 > np) act &= np > k ? (1u << (np - k)) - 1 : 0;
        for (int l = 0; act; l++, act >>= 1) {
            if (!(act & 1)) continue;
            w->idx[m] = (int32_t)(k + l);
            for (int c = 0; c < 3; c++) {
                w->ja[A_V0 + c][m] = out[c][0][l];
                w->ja[A_DU0 + c][m] = out[c][1][l];
                w->ja[A_DV0 + c][m] = out[c][2][l];
            }
            m++;
        }
    }
    return m;
}
#endif

/* A gray frame sees the texture as its luma, in channel 0: its three
 * channels are equal, so the passes after this one take channel 0 alone and
 * count it three times. */
static void luma_pass(float *const *a, int first, long n)
{
    float *b = a[first], *g = a[first + 1], *r = a[first + 2];
    for (long k = 0; k < n; k++)
        b[k] = (float)(b[k] * RF_LUMA_B + g[k] * RF_LUMA_G + r[k] * RF_LUMA_R);
}

/* Per channel, the sums of the photometric fit over the samples (double
 * lanes: the sum of squares it leaves is a small difference of them):
 * T^2 m (m = 1, nx, ny, nz, nx nx, nx ny, nx nz, ny ny, ny nz, nz nz),
 * T (1, n), T obs (1, n) (the sums of obs and obs^2 come from pixel_set). */
RF_BODY void fit_sums_body(const rf_work *w, long npad, int nch, double q[3][20])
{
    /* the normals and their products, shared by the channels, once per block
     * of RF_JBLOCK samples; each channel's lanes add in sample order, as a
     * loop over all samples per channel would */
    enum { NB = RF_JBLOCK / (RF_VL / 2) };
    vd nn[9][NB], acc[3][18];
    for (int c = 0; c < 3; c++)
        for (int i = 0; i < 18; i++) acc[c][i] = (vd){0};
    for (long k0 = 0; k0 < npad; k0 += RF_JBLOCK) {
        int nb = (int)((npad - k0 < RF_JBLOCK ? npad - k0 : RF_JBLOCK) / (RF_VL / 2));
        for (int b = 0; b < nb; b++) {
            long k = k0 + (long)b * (RF_VL / 2);
            vd n0 = vdload(w->a[A_NX] + k), n1 = vdload(w->a[A_NY] + k),
               n2 = vdload(w->a[A_NZ] + k);
            nn[0][b] = n0;
            nn[1][b] = n1;
            nn[2][b] = n2;
            nn[3][b] = n0 * n0;
            nn[4][b] = n0 * n1;
            nn[5][b] = n0 * n2;
            nn[6][b] = n1 * n1;
            nn[7][b] = n1 * n2;
            nn[8][b] = n2 * n2;
        }
        for (int c = 0; c < nch; c++) {
            vd a[18];
            memcpy(a, acc[c], sizeof a);
            for (int b = 0; b < nb; b++) {
                long k = k0 + (long)b * (RF_VL / 2);
                vd t = vdload(w->a[A_V0 + c] + k), o = vdload(w->a[A_O0 + c] + k);
                vd n0 = nn[0][b], n1 = nn[1][b], n2 = nn[2][b];
                vd t2 = t * t, to = t * o;
                a[0] += t2;
                a[1] += t2 * n0;
                a[2] += t2 * n1;
                a[3] += t2 * n2;
                a[4] += t2 * nn[3][b];
                a[5] += t2 * nn[4][b];
                a[6] += t2 * nn[5][b];
                a[7] += t2 * nn[6][b];
                a[8] += t2 * nn[7][b];
                a[9] += t2 * nn[8][b];
                a[10] += t;
                a[11] += t * n0;
                a[12] += t * n1;
                a[13] += t * n2;
                a[14] += to;
                a[15] += to * n0;
                a[16] += to * n1;
                a[17] += to * n2;
            }
            memcpy(acc[c], a, sizeof a);
        }
    }
    for (int c = 0; c < nch; c++)
        for (int i = 0; i < 18; i++) {
            double sum = 0;
            for (int l = 0; l < RF_VL / 2; l++) sum += acc[c][i][l];
            q[c][i] = sum;
        }
}
#if defined(RF_X86_GCC) && RF_VL == 16
/* fit_sums_body with AVX2 (its 8 double lanes as two vectors of 4) and for
 * the baseline, SSE2 (four vectors of 2): one body, refine_fit_sums.h. */
#define FS_NAME    fit_sums_avx2
#define FS_ATTR    __attribute__((target("avx2"), optimize("fp-contract=off")))
#define FS_VD      __m256d
#define FS_W       4
#define FS_LOAD(p) _mm256_cvtps_pd(_mm_load_ps(p))
#define FS_ZERO    _mm256_setzero_pd()
#include "refine_fit_sums.h"

typedef double vd2 __attribute__((vector_size(2 * sizeof(double))));
typedef float vf2x __attribute__((vector_size(2 * sizeof(float))));
static inline vd2 vd2load(const float *p)
{
    return __builtin_convertvector(*(const vf2x *)p, vd2);
}
#define FS_NAME    fit_sums_sse2
#define FS_ATTR    __attribute__((optimize("fp-contract=off")))
#define FS_VD      vd2
#define FS_W       2
#define FS_LOAD(p) vd2load(p)
#define FS_ZERO    ((vd2){0})
#include "refine_fit_sums.h"
#endif
RF_VERSIONS_HAND(void, fit_sums, (const rf_work *w, long npad, int nch, double q[3][20]),
                 (w, npad, nch, q), fit_sums_avx2, fit_sums_sse2)

/* A x = b for symmetric positive semi-definite A (k <= 6), with the tiny ridge
 * of training/refine.py _solve_spd; Gaussian elimination with partial pivoting. */
static void solve_spd_n(int k, const double A[6][6], int m, const double *b, int bs, double *x,
                        int xs)
{
    /* m right-hand sides b + r bs, solutions x + r xs (r < m <= 6): one
     * elimination, each column as a lone solve would treat it */
    double M[6][12], tr = 0;
    int n = k + m;
    for (int i = 0; i < k; i++) tr += A[i][i];
    double ridge = 1e-9 * (tr / k > 1.0 ? tr / k : 1.0);
    for (int i = 0; i < k; i++) {
        for (int j = 0; j < k; j++) M[i][j] = A[i][j] + (i == j ? ridge : 0);
        for (int r = 0; r < m; r++) M[i][k + r] = b[r * bs + i];
    }
    for (int c = 0; c < k; c++) {
        int p = c;
        for (int i = c + 1; i < k; i++)
            if (fabs(M[i][c]) > fabs(M[p][c])) p = i;
        if (p != c)
            for (int j = 0; j < n; j++) {
                double t = M[c][j];
                M[c][j] = M[p][j];
                M[p][j] = t;
            }
        double d = M[c][c];
        if (d == 0) d = 1e-300;
        for (int i = c + 1; i < k; i++) {
            double f = M[i][c] / d;
            for (int j = c; j < n; j++) M[i][j] -= f * M[c][j];
        }
    }
    for (int r = 0; r < m; r++) {
        double *xr = x + r * xs;
        for (int i = k - 1; i >= 0; i--) {
            double sum = M[i][k + r];
            for (int j = i + 1; j < k; j++) sum -= M[i][j] * xr[j];
            xr[i] = sum / (M[i][i] != 0 ? M[i][i] : 1e-300);
        }
    }
}

static void solve_spd(int k, const double A[6][6], const double *b, double *x)
{
    solve_spd_n(k, A, 1, b, 0, x, 0);
}

#ifdef RF_X86_GCC
/* solve_spd_n for the three channels' systems at once, channel c in lane c
 * (lane 3 repeats channel 0): each lane does channel c's operations in
 * their order, its own pivots included (selected lane by lane), and fuses
 * nothing, so that its bits are a lone solve's. */
typedef double vd4 __attribute__((vector_size(4 * sizeof(double))));
typedef int64_t vl4 __attribute__((vector_size(4 * sizeof(int64_t))));
static inline vd4 vd4_sel(vl4 m, vd4 a, vd4 b) /* m ? a : b, m all ones or zero */
{
    return (vd4)(((vl4)a & m) | ((vl4)b & ~m));
}
RF_BODY void solve_spd_n3_body(int k, const double A[3][6][6], int m, const double *const b[3],
                               int bs, double *const x[3], int xs)
{
    vd4 M[6][12], tr = {0};
    int n = k + m;
    for (int i = 0; i < k; i++) tr += (vd4){A[0][i][i], A[1][i][i], A[2][i][i], A[0][i][i]};
    vd4 trk = tr / k;
    vd4 ridge = 1e-9 * vd4_sel(trk > 1.0, trk, (vd4){0} + 1.0);
    for (int i = 0; i < k; i++) {
        for (int j = 0; j < k; j++)
            M[i][j] =
                (vd4){A[0][i][j], A[1][i][j], A[2][i][j], A[0][i][j]} + (i == j ? ridge : (vd4){0});
        for (int r = 0; r < m; r++)
            M[i][k + r] =
                (vd4){b[0][r * bs + i], b[1][r * bs + i], b[2][r * bs + i], b[0][r * bs + i]};
    }
    const vl4 nosign = (vl4){0} + INT64_MAX;
    for (int c = 0; c < k; c++) {
        /* lane by lane: the first row below c with the largest |M[i][c]|,
         * swapped with row c */
        vd4 best = (vd4)((vl4)M[c][c] & nosign);
        vl4 p = (vl4){0} + c;
        for (int i = c + 1; i < k; i++) {
            vd4 v = (vd4)((vl4)M[i][c] & nosign);
            vl4 gt = v > best;
            best = vd4_sel(gt, v, best);
            p = (gt & i) | (~gt & p);
        }
        for (int i = c + 1; i < k; i++) {
            vl4 sw = p == i;
            for (int j = 0; j < n; j++) {
                vd4 t = M[c][j];
                M[c][j] = vd4_sel(sw, M[i][j], t);
                M[i][j] = vd4_sel(sw, t, M[i][j]);
            }
        }
        vd4 d = M[c][c];
        d = vd4_sel(d == 0, (vd4){0} + 1e-300, d);
        for (int i = c + 1; i < k; i++) {
            vd4 f = M[i][c] / d;
            for (int j = c; j < n; j++) M[i][j] -= f * M[c][j];
        }
    }
    for (int r = 0; r < m; r++) {
        vd4 xr[6];
        for (int i = k - 1; i >= 0; i--) {
            vd4 sum = M[i][k + r];
            for (int j = i + 1; j < k; j++) sum -= M[i][j] * xr[j];
            xr[i] = sum / vd4_sel(M[i][i] != 0, M[i][i], (vd4){0} + 1e-300);
        }
        for (int i = 0; i < k; i++)
            for (int c = 0; c < 3; c++) x[c][r * xs + i] = xr[i][c];
    }
}
__attribute__((target("avx2"), optimize("fp-contract=off"))) static void
solve_spd_n3_v1(int k, const double A[3][6][6], int m, const double *const b[3], int bs,
                double *const x[3], int xs)
{
    solve_spd_n3_body(k, A, m, b, bs, x, xs);
}
#endif
static void solve_spd_n3(int k, const double A[3][6][6], int m, const double *const b[3], int bs,
                         double *const x[3], int xs)
{
#ifdef RF_X86_GCC
    if (rf_version() >= RF_V_AVX2) {
        solve_spd_n3_v1(k, A, m, b, bs, x, xs);
        return;
    }
#endif
    /* (the baseline's 2-lane vectors gain nothing: one channel at a time) */
    for (int c = 0; c < 3; c++) solve_spd_n(k, A[c], m, b[c], bs, x[c], xs);
}

/* The samples of rows j0.. and columns i0.. (stride apart) within rm of
 * (cx, cy) at level lev: centres relative to (cx, cy), observed values (a
 * level-l pixel is the mean of a 2^l x 2^l block of the frame, summed here:
 * the crop's levels are not built), and the block sums' moments s[c], q[c]
 * (exact integers). ch: the frame's channels, a constant where inlined. */
static inline __attribute__((always_inline)) long fill_samples(rf_work *w, int lev, int i0, int i1,
                                                               int j0, int j1, int stride,
                                                               double cx, double cy, double rm,
                                                               int ch, uint64_t s[3], uint64_t q[3])
{
    const rf_image *f = w->frame;
    int k = 1 << lev;
    float sc = 1.0f / (float)(k * k); /* a power of two: exact */
    float *X = w->a[A_X], *Y = w->a[A_Y], *o0 = w->a[A_O0], *o1 = w->a[A_O1], *o2 = w->a[A_O2];
    long n = 0;
    for (int j = j0; j < j1; j += stride) {
        double v = j + 0.5, dy2 = (v - cy) * (v - cy);
        const uint8_t *row = f->data + (size_t)(w->y0 + j * k) * f->stride + (size_t)w->x0 * ch;
        for (int i = i0; i < i1; i += stride) {
            double u = i + 0.5;
            if ((u - cx) * (u - cx) + dy2 > rm * rm) continue;
            uint32_t s0 = 0, s1 = 0, s2 = 0;
            for (int dj = 0; dj < k; dj++) {
                const uint8_t *p = row + (size_t)dj * f->stride + (size_t)i * k * ch;
                for (int di = 0; di < k; di++, p += ch) {
                    s0 += p[0];
                    if (ch > 1) {
                        s1 += p[1];
                        s2 += p[2];
                    }
                }
            }
            if (ch == 1) s1 = s2 = s0;
            X[n] = (float)(u - cx);
            Y[n] = (float)(v - cy);
            o0[n] = (float)s0 * sc;
            o1[n] = (float)s1 * sc;
            o2[n] = (float)s2 * sc;
            s[0] += s0;
            s[1] += s1;
            s[2] += s2;
            q[0] += (uint64_t)s0 * s0;
            q[1] += (uint64_t)s1 * s1;
            q[2] += (uint64_t)s2 * s2;
            n++;
        }
    }
    return n;
}

/* Sampled pixels of a level (training/refine.py pixel_set): fills the sample
 * arrays' centres (relative to the circle's centre (cx, cy), which becomes
 * their origin) and observed values, pads them to RF_LANES with the circle's
 * centre, observed 0; returns the count (or -1 out of memory). */
static long pixel_set(rf_work *w, int lev, double cx, double cy, double r, int stride)
{
    int W = w->w[lev], H = w->h[lev];
    double rm = RF_RHO_MAX * r;
    int j0 = (int)floor(cy - rm), j1 = (int)ceil(cy + rm) + 1;
    int i0 = (int)floor(cx - rm), i1 = (int)ceil(cx + rm) + 1;
    if (j0 < 0) j0 = 0;
    if (i0 < 0) i0 = 0;
    if (j1 > H) j1 = H;
    if (i1 > W) i1 = W;
    j0 = (j0 + stride - 1) / stride * stride;
    i0 = (i0 + stride - 1) / stride * stride;
    size_t most =
        (j1 > j0 && i1 > i0) ? (size_t)((j1 - j0) / stride + 1) * ((i1 - i0) / stride + 1) : 0;
    if (reserve(w, most + 1) < 0) return -1;
    uint64_t s[3] = {0, 0, 0}, q[3] = {0, 0, 0};
    long n;
    switch (w->frame->channels) {
    case 1: n = fill_samples(w, lev, i0, i1, j0, j1, stride, cx, cy, rm, 1, s, q); break;
    case 3: n = fill_samples(w, lev, i0, i1, j0, j1, stride, cx, cy, rm, 3, s, q); break;
    default: n = fill_samples(w, lev, i0, i1, j0, j1, stride, cx, cy, rm, 4, s, q); break;
    }
    w->np = n;
    w->npad = (n + RF_LANES - 1) / RF_LANES * RF_LANES;
    for (int m = A_X; m <= A_O2; m++)
        for (long k = n; k < w->npad; k++) w->a[m][k] = 0;
    w->c0x = cx;
    w->c0y = cy;
    /* the frame's variance sum over them, the residual's denominator, from
     * the exact moments of the block sums */
    double sst = 0, kk = (double)(1 << lev) * (1 << lev);
    for (int c = 0; c < 3; c++) {
        w->so[c] = (double)s[c] / kk; /* exact: the block sums over a power of two */
        w->soo[c] = (double)q[c] / (kk * kk);
    }
    for (int c = 0; c < 3 && n > 0; c++) sst += (double)q[c] - (double)s[c] * (double)s[c] / n;
    w->sst = sst / (kk * kk);
    return n;
}

/* Channel c > 0's photometric system is channel 0's: its A^T A, and its
 * right-hand sides, rhs + c * size (size bytes a channel), are the same bits
 * (a gray frame's channels), and so is what follows from them. */
static int same_as_channel0(const rf_fit *fit, int c, const void *rhs, size_t size)
{
    const char *r = rhs;
    return c > 0 && !memcmp(fit->AtA[c], fit->AtA[0], sizeof fit->AtA[0]) &&
           !memcmp(r + c * size, r, size);
}

/* The value pass of an evaluation at (R, cx, cy, r) (the level's
 * coordinates): renders the texture at the sampled pixels (kept in the
 * arrays for the Jacobian pass) and fits the photometric model; fit->sse is
 * the sum of squares it leaves. */
static void evaluate(const rf_texture *t, int lev, rf_work *w, const double R[3][3], double cx,
                     double cy, double r, double fixed_f, rf_fit *fit)
{
    const uint16_t *tex = t->px[lev];
    const uint64_t *pairs = t->pairs[lev];
    int tw = t->w[lev], th = t->h[lev], tr = t->tr[lev];
    long np = w->np, npad = w->npad;
    double f = focal_of(r, fixed_f), tan_a = r / f, dist = sqrt(1.0 + tan_a * tan_a) / tan_a;
    float Rf[9];
    for (int i = 0; i < 9; i++) Rf[i] = (float)R[i / 3][i % 3];
    w->gp[GEO_DCX] = (float)(cx - w->c0x);
    w->gp[GEO_DCY] = (float)(cy - w->c0y);
    w->gp[GEO_INVF] = (float)(1.0 / f);
    w->gp[GEO_DIST] = (float)dist;
    w->gp[GEO_KW] = (float)(tw / (2 * M_PI));
    w->gp[GEO_KH] = (float)(th / M_PI);
    geometry_pass(w, npad, Rf, w->gp, tw, th, tr, pairs != NULL);
#ifdef RF_X86_GCC
    if (rf_version() == RF_V_AVX512)
        w->nact = gather_pass_avx512(w, npad, np, pairs ? (const void *)pairs : tex, pairs != NULL,
                                     tr, t->scale[lev]);
    else if (rf_version() == RF_V_AVX2)
        w->nact = gather_pass_avx2(w, npad, np, pairs ? (const void *)pairs : tex, pairs != NULL,
                                   tr, t->scale[lev]);
    else if (rf_version() == RF_V_BASELINE)
        w->nact = gather_pass_sse2(w, npad, np, tex, pairs, tr, t->scale[lev]);
    else
#endif
        w->nact = gather_pass(w, npad, np, tex, pairs, tr, t->scale[lev]);
    if (w->gray) {
        luma_pass(w->a, A_V0, npad); /* the fit's values */
        /* the Jacobian's samples, which the lookups chose (a derivative of
         * any channel nonzero: where the luma's is) and wrote */
        for (int m = A_V0; m <= A_DV0; m += 3) luma_pass(w->ja, m, w->nact);
    }
    /* the padding takes no part: no texture there */
    for (int m = A_V0; m <= A_V2; m++)
        for (long k = np; k < npad; k++) w->a[m][k] = 0;
    double q[3][20], oo[3];
    fit_sums(w, npad, w->gray ? 1 : 3, q);
    if (w->gray) memcpy(q[1], q[0], sizeof q[0]), memcpy(q[2], q[0], sizeof q[0]);
    memset(fit, 0, sizeof *fit);
    for (int c = 0; c < 3; c++) {
        double(*M)[6] = fit->AtA[c];
        /* rows (T, T nx, T ny, T nz, 1): T^2 m[...] above the diagonal, T m[...] in the
         * last column */
        static const int idx[4][4] = {{0, 1, 2, 3}, {1, 4, 5, 6}, {2, 5, 7, 8}, {3, 6, 8, 9}};
        for (int i = 0; i < 4; i++) {
            for (int j = i; j < 4; j++) M[i][j] = q[c][idx[i][j]];
            M[i][4] = q[c][10 + i];
            fit->Atb[c][i] = q[c][14 + i];
        }
        M[4][4] = (double)np;
        fit->Atb[c][4] = w->so[c];
        oo[c] = w->soo[c];
    }
    /* |obs - A coef|^2 = obs.obs - 2 coef.A^T obs + coef.A^T A coef (training/refine.py
     * photometric_fit): no second pass over the pixels */
    for (int c = 0; c < 3; c++)
        for (int i = 0; i < 5; i++)
            for (int j = 0; j < i; j++) fit->AtA[c][i][j] = fit->AtA[c][j][i];
    const double *atb[3] = {fit->Atb[0], fit->Atb[1], fit->Atb[2]};
    double *coef[3] = {fit->coef[0], fit->coef[1], fit->coef[2]};
    solve_spd_n3(5, fit->AtA, 1, atb, 0, coef, 0);
    double qq0 = 0, xb0 = 0; /* channel 0's */
    for (int c = 0; c < 3; c++) {
        double(*M)[6] = fit->AtA[c];
        double *x = fit->coef[c];
        if (same_as_channel0(fit, c, fit->Atb, sizeof fit->Atb[0])) {
            fit->sse += oo[c] - 2 * xb0 + qq0;
            continue;
        }
        double qq = 0, xb = 0;
        for (int i = 0; i < 5; i++) {
            double mx = 0;
            for (int j = 0; j < 5; j++) mx += M[i][j] * x[j];
            qq += x[i] * mx;
            xb += x[i] * fit->Atb[c][i];
        }
        if (c == 0) qq0 = qq, xb0 = xb;
        fit->sse += oo[c] - 2 * xb + qq;
    }
}

/* The Jacobian's sums (float lanes; training/refine.py _eval): per sample the
 * derivatives of the rendering J (channel x 6: rotation, centre, radius), and
 * over the samples J^T J (21: the upper triangle), per channel J^T A (6 x 5)
 * and J^T e (6, summed over the channels). k: (inv_f, cr, dDr) the ray's
 * derivatives (see jacobian), gp the value pass's geometry (geometry_pass),
 * R the rotation, a the photometric coefficients. */
#define RF_JSUMS (21 + 90 + 6)
static inline __attribute__((always_inline)) void jac_sums_n(float *const *q, long npad,
                                                             const float R[9], const float kd[3],
                                                             const float gp[6], const float a[3][5],
                                                             double out[RF_JSUMS], int nch)
{
    const float inv_f = kd[0], cr = kd[1], dDr = kd[2];
    const float dcx = gp[GEO_DCX], dcy = gp[GEO_DCY], g_invf = gp[GEO_INVF];
    const float kw = gp[GEO_KW], kh = gp[GEO_KH];
    /* float lanes over RF_JBLOCK samples each, then double: H is nearly
     * singular along rotations that mimic a shift of the circle, so its sums
     * need more than float's seven digits */
    vf acc[RF_JSUMS];
    vd tot[RF_JSUMS][2];
    memset(tot, 0, sizeof tot);
    for (long k = 0; k < npad; k += RF_VL) {
        if (k % RF_JBLOCK == 0)
            for (int i = 0; i < RF_JSUMS; i++) acc[i] = (vf){0};
        /* the ray and d (u, v) / d b of the value pass, computed again for
         * these samples alone through geometry_pass's own ray_slope and
         * body_xz (the same bits). t is kept: written out again, GCC fuses one
         * of its multiply-adds otherwise and its bits move. */
        vf x, y, p2, inv, t = vload(q[A_T] + k);
        ray_slope(vload(q[A_X] + k), vload(q[A_Y] + k), dcx, dcy, g_invf, &x, &y, &p2, &inv);
        vf n0 = vload(q[A_NX] + k), n1 = vload(q[A_NY] + k), n2 = vload(q[A_NZ] + k);
        vf bx, bz, rho2;
        body_xz(R, n0, n1, n2, &bx, &bz, &rho2);
        vf irho = vrsqrt(rho2), krho = kw * (irho * irho);
        vf e0 = x * inv, e1 = y * inv, e2 = -inv; /* the ray's direction d */
        /* n.d = -cos of the angle of incidence: about -0.4 at the samples'
         * rim; where a step has moved the circle so far that a ray only
         * grazes or misses the sphere (n.d near 0), the derivatives are not
         * finite in float: such a sample takes no part in the step (J = 0) */
        vf nd = n0 * e0 + n1 * e1 + n2 * e2;
        vi meets = vneg(nd + 1e-3f);
        vf ind = vsel(meets, 1.0f / nd, (vf){0});
        /* d n / d (cx, cy, r) (training/refine.py normals_and_derivs):
         * dd = (dq - d (d.dq)) / L, dt = -(n.dO + t n.dd) / (n.d), dn = dO + dt d + t dd */
        vf dn[3][3];
        {
            vf ddq = -e0 * inv_f;
            vf a0 = (-inv_f - e0 * ddq) * inv, a1 = -e1 * ddq * inv, a2 = -e2 * ddq * inv;
            vf dt = -(t * (n0 * a0 + n1 * a1 + n2 * a2)) * ind;
            dn[0][0] = dt * e0 + t * a0;
            dn[0][1] = dt * e1 + t * a1;
            dn[0][2] = dt * e2 + t * a2;
        }
        {
            vf ddq = e1 * inv_f;
            vf a0 = -e0 * ddq * inv, a1 = (inv_f - e1 * ddq) * inv, a2 = -e2 * ddq * inv;
            vf dt = -(t * (n0 * a0 + n1 * a1 + n2 * a2)) * ind;
            dn[1][0] = dt * e0 + t * a0;
            dn[1][1] = dt * e1 + t * a1;
            dn[1][2] = dt * e2 + t * a2;
        }
        {
            vf ddq = cr * (x * e0 + y * e1);
            vf a0 = (cr * x - e0 * ddq) * inv, a1 = (cr * y - e1 * ddq) * inv, a2 = -e2 * ddq * inv;
            vf dt = -(n2 * dDr + t * (n0 * a0 + n1 * a1 + n2 * a2)) * ind;
            dn[2][0] = dt * e0 + t * a0;
            dn[2][1] = dt * e1 + t * a1;
            dn[2][2] = dt * e2 + t * a2 + dDr;
        }
        /* the world-frame gradient of channel c is du_c P + dv_c Q: P, Q are
         * R times the texel axes' d (u, v) / d b; the rendering's derivatives
         * are linear in it (rotation: g x n, circle: g . dn) */
        vf d0 = bz * krho, d2 = -bx * krho, d1 = -kh * irho;
        vf P[3], Q[3], JP[6], JQ[6];
        for (int i = 0; i < 3; i++) {
            P[i] = R[3 * i] * d0 + R[3 * i + 2] * d2;
            Q[i] = R[3 * i + 1] * d1;
        }
        JP[0] = P[1] * n2 - P[2] * n1;
        JP[1] = P[2] * n0 - P[0] * n2;
        JP[2] = P[0] * n1 - P[1] * n0;
        JQ[0] = Q[1] * n2 - Q[2] * n1;
        JQ[1] = Q[2] * n0 - Q[0] * n2;
        JQ[2] = Q[0] * n1 - Q[1] * n0;
        for (int m = 0; m < 3; m++) {
            JP[3 + m] = P[0] * dn[m][0] + P[1] * dn[m][1] + P[2] * dn[m][2];
            JQ[3 + m] = Q[0] * dn[m][0] + Q[1] * dn[m][1] + Q[2] * dn[m][2];
        }
        vf J[3][6], e[3];
        for (int c = 0; c < nch; c++) {
            vf tv = vload(q[A_V0 + c] + k);
            vf sh = a[c][0] + a[c][1] * n0 + a[c][2] * n1 + a[c][3] * n2;
            vf al = vsel(meets, sh * vload(q[A_DU0 + c] + k), (vf){0});
            vf be = vsel(meets, sh * vload(q[A_DV0 + c] + k), (vf){0});
            e[c] = vload(q[A_O0 + c] + k) - (tv * sh + a[c][4]);
            for (int i = 0; i < 6; i++) J[c][i] = al * JP[i] + be * JQ[i];
            vf ab[5] = {tv, tv * n0, tv * n1, tv * n2, (vf){0} + 1.0f};
            for (int i = 0; i < 6; i++)
                for (int j = 0; j < 5; j++) acc[21 + c * 30 + i * 5 + j] += J[c][i] * ab[j];
        }
        int h = 0;
        if (nch == 3) {
            for (int i = 0; i < 6; i++)
                for (int j = i; j < 6; j++, h++)
                    acc[h] += J[0][i] * J[0][j] + J[1][i] * J[1][j] + J[2][i] * J[2][j];
            for (int i = 0; i < 6; i++)
                acc[111 + i] += J[0][i] * e[0] + J[1][i] * e[1] + J[2][i] * e[2];
        } else {
            for (int i = 0; i < 6; i++)
                for (int j = i; j < 6; j++, h++) acc[h] += J[0][i] * J[0][j];
            for (int i = 0; i < 6; i++) acc[111 + i] += J[0][i] * e[0];
        }
        if ((k + RF_VL) % RF_JBLOCK == 0 || k + RF_VL >= npad)
            for (int i = 0; i < RF_JSUMS; i++) {
                vf2 half;
                memcpy(&half, &acc[i], sizeof half);
                tot[i][0] += __builtin_convertvector(half.lo, vd);
                tot[i][1] += __builtin_convertvector(half.hi, vd);
            }
    }
    for (int i = 0; i < RF_JSUMS; i++) {
        double s = 0;
        for (int l = 0; l < RF_VL / 2; l++) s += tot[i][0][l] + tot[i][1][l];
        out[i] = s;
    }
}

RF_BODY void jac_sums3_body(float *const *q, long npad, const float R[9], const float kd[3],
                            const float gp[6], const float a[3][5], double out[RF_JSUMS])
{
    jac_sums_n(q, npad, R, kd, gp, a, out, 3);
}
RF_VERSIONS(void, jac_sums3,
            (float *const *q, long npad, const float R[9], const float kd[3], const float gp[6],
             const float a[3][5], double out[RF_JSUMS]),
            (q, npad, R, kd, gp, a, out))

/* a gray frame: channel 0 alone (the sums of the others are the same) */
RF_BODY void jac_sums1_body(float *const *q, long npad, const float R[9], const float kd[3],
                            const float gp[6], const float a[3][5], double out[RF_JSUMS])
{
    jac_sums_n(q, npad, R, kd, gp, a, out, 1);
}
RF_VERSIONS(void, jac_sums1,
            (float *const *q, long npad, const float R[9], const float kd[3], const float gp[6],
             const float a[3][5], double out[RF_JSUMS]),
            (q, npad, R, kd, gp, a, out))

#ifdef RF_X86_GCC
/* dst[k] = src[idx[k]], k < m (idx padded to RF_LANES with valid indices) */
__attribute__((target("avx512f"))) static void pick_avx512(float *dst, const float *src,
                                                           const int32_t *idx, long m)
{
    for (long k = 0; k < m; k += 16)
        _mm512_store_ps(dst + k,
                        _mm512_i32gather_ps(_mm512_load_si512((const void *)(idx + k)), src, 4));
}

__attribute__((target("avx2"))) static void pick_avx2(float *dst, const float *src,
                                                      const int32_t *idx, long m)
{
    for (long k = 0; k < m; k += 8)
        _mm256_store_ps(dst + k,
                        _mm256_i32gather_ps(src, _mm256_load_si256((const __m256i *)(idx + k)), 4));
}
#endif

/* The Jacobian's samples (those the lookups chose, w->idx), copied into
 * w->ja beside the values and derivatives the lookups wrote there, padded
 * with zeros to RF_LANES; returns their count, padded. */
static long jac_samples(rf_work *w)
{
    /* the arrays the Jacobian reads beside those: all channels', or a gray
     * frame's channel 0 (jac_sums1): the geometry's 6, then each channel's
     * observed value */
    enum { KEEP_GEO = 6 };
    static const int keep[2][6] = {{A_NX, A_NY, A_NZ, A_X, A_Y, A_T}, {A_O0, A_O1, A_O2}};
    int nch = w->gray ? 1 : 3;
    long m = w->nact;
    long mp = (m + RF_LANES - 1) / RF_LANES * RF_LANES;
    int NK = KEEP_GEO + nch;
    int32_t *idx = w->idx;
    for (long k = m; k < mp; k++) idx[k] = 0; /* read, then zeroed below */
    for (int i = A_V0; i <= A_DV2; i++)
        for (long k = m; k < mp; k++) w->ja[i][k] = 0;
    for (int i = 0; i < NK; i++) {
        int a = keep[i / KEEP_GEO][i % KEEP_GEO];
        const float *src = w->a[a];
        float *dst = w->ja[a];
#ifdef RF_X86_GCC
        if (rf_version() == RF_V_AVX512)
            pick_avx512(dst, src, idx, mp);
        else if (rf_version() == RF_V_AVX2)
            pick_avx2(dst, src, idx, mp);
        else
#endif
            for (long k = 0; k < m; k++) dst[k] = src[idx[k]];
        for (long k = m; k < mp; k++) dst[k] = 0;
    }
#ifdef RF_TRACE
    fprintf(stderr, "JAC active %ld of %ld\n", m, w->np);
#endif
    return mp;
}

/* The Jacobian pass at the pose and circle of the last value pass: the normal
 * equations H d = g of a step, with the photometric coefficients projected out. */
static void jacobian(rf_work *w, const double R[3][3], double r, double fixed_f, const rf_fit *fit,
                     double H[6][6], double g[6])
{
    double f = focal_of(r, fixed_f), tan_a = r / f, sec = sqrt(1.0 + tan_a * tan_a);
    /* the ray's derivatives: d q / d cx = (-1/f, 0), d q / d cy = (0, 1/f);
     * r moves the camera away when f is fixed (d dist / d r), else it scales
     * the rays (d q / d r = -q / r) */
    float kd[3] = {(float)(1.0 / f), fixed_f > 0 ? 0.0f : (float)(-1.0 / r),
                   fixed_f > 0 ? (float)(-(1.0 / f) / (tan_a * tan_a * sec)) : 0.0f};
    float Rf[9], a[3][5];
    double s[RF_JSUMS];
    for (int i = 0; i < 9; i++) Rf[i] = (float)R[i / 3][i % 3];
    for (int c = 0; c < 3; c++)
        for (int i = 0; i < 5; i++) a[c][i] = (float)fit->coef[c][i];
    long nj = jac_samples(w);
    if (w->gray) {
        jac_sums1(w->ja, nj, Rf, kd, w->gp, a, s);
        /* the three equal channels: J^T J and J^T e three times channel 0's,
         * J^T A the same for each */
        for (int i = 0; i < 21; i++) s[i] *= 3;
        for (int i = 0; i < 6; i++) s[111 + i] *= 3;
        memcpy(s + 51, s + 21, 30 * sizeof s[0]);
        memcpy(s + 81, s + 21, 30 * sizeof s[0]);
    } else
        jac_sums3(w->ja, nj, Rf, kd, w->gp, a, s);
    double JtA[3][6][5];
    int h = 0;
    for (int i = 0; i < 6; i++)
        for (int j = i; j < 6; j++, h++) H[i][j] = s[h];
    for (int c = 0; c < 3; c++)
        for (int i = 0; i < 6; i++)
            for (int j = 0; j < 5; j++) JtA[c][i][j] = s[21 + c * 30 + i * 5 + j];
    for (int i = 0; i < 6; i++) g[i] = s[111 + i];
    /* variable projection (training/refine.py _eval): take out of J^T J what
     * the refitted photometric coefficients absorb, J^T A (A^T A)^-1 A^T J */
    double X[3][6][5];
    const double *jta[3] = {JtA[0][0], JtA[1][0], JtA[2][0]};
    double *xs[3] = {X[0][0], X[1][0], X[2][0]};
    solve_spd_n3(5, fit->AtA, 6, jta, 5, xs, 5);
    double P0[6][6], Pc[6][6]; /* channel 0's and channel c's J^T A (A^T A)^-1 A^T J */
    for (int c = 0; c < 3; c++) {
        double(*P)[6] = c == 0 ? P0 : Pc;
        if (same_as_channel0(fit, c, JtA, sizeof JtA[0]))
            P = P0;
        else {
            for (int i = 0; i < 6; i++)
                for (int j = i; j < 6; j++) {
                    double qq = 0;
                    for (int k = 0; k < 5; k++) qq += JtA[c][i][k] * X[c][j][k];
                    P[i][j] = qq;
                }
        }
        for (int i = 0; i < 6; i++)
            for (int j = i; j < 6; j++) H[i][j] -= P[i][j];
    }
    for (int i = 0; i < 6; i++)
        for (int j = 0; j < i; j++) H[i][j] = H[j][i];
}

/* 1 - the largest eigenvalue of a symmetric 3x3 matrix over its trace
 * (training/refine.py colour_share): the trigonometric solution of its
 * characteristic cubic. */
static double off_axis_share(const double C[3][3])
{
    double tr = C[0][0] + C[1][1] + C[2][2];
    if (!(tr > 0)) return 0;
    double q = tr / 3, p1 = C[0][1] * C[0][1] + C[0][2] * C[0][2] + C[1][2] * C[1][2];
    double p2 = (C[0][0] - q) * (C[0][0] - q) + (C[1][1] - q) * (C[1][1] - q) +
                (C[2][2] - q) * (C[2][2] - q) + 2 * p1;
    double p = sqrt(p2 / 6), top = q;
    if (p > 0) {
        double B[3][3];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) B[i][j] = (C[i][j] - (i == j ? q : 0)) / p;
        double det = B[0][0] * (B[1][1] * B[2][2] - B[1][2] * B[2][1]) -
                     B[0][1] * (B[1][0] * B[2][2] - B[1][2] * B[2][0]) +
                     B[0][2] * (B[1][0] * B[2][1] - B[1][1] * B[2][0]);
        double h = det / 2;
        h = h < -1 ? -1 : h > 1 ? 1 : h;
        top = q + 2 * p * cos(acos(h) / 3);
    }
    return 1 - top / tr;
}

/* The colour ratio from the sums of colour_ratio_body (S: o o^T, m m^T, o, m) */
RF_BODY double colour_of_sums(const rf_work *w, const rf_fit *fit, const double S[18])
{
    long np = w->np;
    double pad = (double)(w->npad - np), Co[3][3], Cm[3][3];
    int h = 0;
    for (int i = 0; i < 3; i++)
        for (int j = i; j < 3; j++, h++) {
            double bi = fit->coef[i][4], bj = fit->coef[j][4];
            double mo = S[12 + i] * S[12 + j] / np;
            double mm = (S[15 + i] - pad * bi) * (S[15 + j] - pad * bj) / np;
            Co[i][j] = Co[j][i] = S[h] - mo;
            Cm[i][j] = Cm[j][i] = S[6 + h] - pad * bi * bj - mm;
        }
    double sm_share = off_axis_share(Cm);
    return sm_share > 0 ? off_axis_share(Co) / sm_share : NAN;
}

/* The frame's colour share over the fitted rendering's, on the pixels of the
 * last value pass (NaN when the rendering has no colour). */
RF_BODY double colour_ratio_body(const rf_work *w, const rf_fit *fit)
{
    /* one pass: the sums of o, m, o o^T and m m^T (double lanes), then
     * C = sum x x^T - n mean mean^T; the observed values are exact, the
     * means a few times the spread at most */
    vd acc[18];
    for (int i = 0; i < 18; i++) acc[i] = (vd){0};
    for (long k = 0; k < w->npad; k += RF_VL / 2) {
        vd n0 = vdload(w->a[A_NX] + k), n1 = vdload(w->a[A_NY] + k), n2 = vdload(w->a[A_NZ] + k);
        vd o[3], m[3];
        for (int c = 0; c < 3; c++) {
            const double *a = fit->coef[c];
            /* the padding's texture is 0 and its offset a[4]: taken out below */
            m[c] = vdload(w->a[A_V0 + c] + k) * (a[0] + a[1] * n0 + a[2] * n1 + a[3] * n2) + a[4];
            o[c] = vdload(w->a[A_O0 + c] + k);
        }
        int h = 0;
        for (int i = 0; i < 3; i++) {
            acc[12 + i] += o[i];
            acc[15 + i] += m[i];
            for (int j = i; j < 3; j++, h++) {
                acc[h] += o[i] * o[j];
                acc[6 + h] += m[i] * m[j];
            }
        }
    }
    double S[18];
    for (int i = 0; i < 18; i++) {
        S[i] = 0;
        for (int l = 0; l < RF_VL / 2; l++) S[i] += acc[i][l];
    }
    return colour_of_sums(w, fit, S);
}
#if defined(RF_X86_GCC) && RF_VL == 16
/* colour_ratio_body with AVX2: its 8 double lanes as two vectors of 4, each
 * half on its own, the sums of the frame apart from those of the rendering
 * (as fit_sums_avx2). Each lane adds the same values in the same order. */
__attribute__((target("avx2"), optimize("fp-contract=off"))) static double
colour_ratio_avx2(const rf_work *w, const rf_fit *fit)
{
    __m256d acc[2][18];
    for (int h = 0; h < 2; h++) {
        __m256d so[9], sm[9]; /* o o^T (6), o (3); m m^T, m */
        for (int i = 0; i < 9; i++) so[i] = sm[i] = _mm256_setzero_pd();
        for (long k = 4 * h; k < w->npad; k += 8) {
            __m256d o[3];
            for (int c = 0; c < 3; c++) o[c] = _mm256_cvtps_pd(_mm_load_ps(w->a[A_O0 + c] + k));
            for (int i = 0, p = 0; i < 3; i++) {
                so[6 + i] += o[i];
                for (int j = i; j < 3; j++, p++) so[p] += o[i] * o[j];
            }
        }
        for (long k = 4 * h; k < w->npad; k += 8) {
            __m256d n0 = _mm256_cvtps_pd(_mm_load_ps(w->a[A_NX] + k)),
                    n1 = _mm256_cvtps_pd(_mm_load_ps(w->a[A_NY] + k)),
                    n2 = _mm256_cvtps_pd(_mm_load_ps(w->a[A_NZ] + k)), m[3];
            for (int c = 0; c < 3; c++) {
                const double *a = fit->coef[c];
                m[c] = _mm256_cvtps_pd(_mm_load_ps(w->a[A_V0 + c] + k)) *
                           (a[0] + a[1] * n0 + a[2] * n1 + a[3] * n2) +
                       a[4];
            }
            for (int i = 0, p = 0; i < 3; i++) {
                sm[6 + i] += m[i];
                for (int j = i; j < 3; j++, p++) sm[p] += m[i] * m[j];
            }
        }
        /* colour_ratio_body's order: o o^T, m m^T, o, m */
        for (int i = 0; i < 6; i++) acc[h][i] = so[i], acc[h][6 + i] = sm[i];
        for (int i = 0; i < 3; i++) acc[h][12 + i] = so[6 + i], acc[h][15 + i] = sm[6 + i];
    }
    double S[18];
    for (int i = 0; i < 18; i++) {
        S[i] = 0;
        for (int l = 0; l < 8; l++) S[i] += acc[l / 4][i][l % 4];
    }
    return colour_of_sums(w, fit, S);
}
#endif
/* (the baseline's colour ratio is the generic loop, colour_ratio_v0) */
RF_VERSIONS_HAND(double, colour_ratio, (const rf_work *w, const rf_fit *fit), (w, fit),
                 colour_ratio_avx2, colour_ratio_v0)

int rf_refine(const rf_texture *t, rf_work *w, const rf_image *frame, double cx, double cy,
              double r, const double R0[3][3], double focal_px, int steps, rf_out *out, char *err,
              size_t errlen)
{
    double R[3][3];
    int x0, y0, total = 0, have_final = 0, at_final = 0;
    double final_sse = 0, final_sst = 0;
    rf_fit fit0; /* the finest level's fit at the final pose, when at_final */
    memcpy(R, R0, sizeof R);
    if (!t || !w || !frame || !frame->data || !(r > 2) || !isfinite(cx) || !isfinite(cy) ||
        !isfinite(r)) {
        pi_seterrn(err, errlen, "refine: no texture, frame or circle");
        return -1;
    }
    int rc = frame_crop(w, frame, cx, cy, r, &x0, &y0);
    if (rc == -1) {
        pi_seterrn(err, errlen, "refine: out of memory");
        return -1;
    }
    if (rc == -2) {
        pi_seterrn(err, errlen, "refine: circle outside the frame");
        return -1;
    }
    cx -= x0;
    cy -= y0;
    for (int lev = RF_LEVELS - 1; lev >= 0 && steps; lev--) {
        double s = 1.0 / (1 << lev);
        double ff = focal_px > 0 ? focal_px * s : 0;
        int li = RF_LEVELS - 1 - lev;
        long np = pixel_set(w, lev, cx * s, cy * s, r * s, rf_strides[li]);
        if (np < 0) {
            pi_seterrn(err, errlen, "refine: out of memory");
            return -1;
        }
        if (np < 50) continue;
        if (!rf_iters[li]) continue;
        /* Levenberg-Marquardt (training/refine.py): a step is kept only when it
         * lowers this level's sum of squares, else the damping grows. A step's
         * candidate gets its value pass only; the Jacobian pass follows when it
         * is kept and another step comes. */
        double H[6][6], g[6], lam = RF_DAMPING;
        rf_fit fit, fc;
        evaluate(t, lev, w, R, cx * s, cy * s, r * s, ff, &fit);
        at_final = 1;
        jacobian(w, R, r * s, ff, &fit, H, g);
        for (int it = 0; it < rf_iters[li]; it++) {
            double Hd[6][6], d[6], M[3][3], Rc[3][3];
            memcpy(Hd, H, sizeof Hd);
            for (int i = 0; i < 6; i++) Hd[i][i] *= 1.0 + lam;
            solve_spd(6, Hd, g, d);
            double ang = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            double lim = RF_MAX_STEP_DEG * M_PI / 180.0;
            if (ang > lim)
                for (int i = 0; i < 6; i++) d[i] *= lim / ang;
            rotvec_to_matrix(d, M);
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                    Rc[i][j] = M[i][0] * R[0][j] + M[i][1] * R[1][j] + M[i][2] * R[2][j];
            double cxc = cx + d[3] / s, cyc = cy + d[4] / s, rc_ = r + d[5] / s;
            if (lev > 0 && it + 1 == rf_iters[li]) {
                /* a coarse level's last step is taken without its value pass:
                 * the next level starts there and checks its own steps
                 * (training/refine.py) */
                memcpy(R, Rc, sizeof R);
                cx = cxc;
                cy = cyc;
                r = rc_;
                total++;
                break;
            }
            evaluate(t, lev, w, Rc, cxc * s, cyc * s, rc_ * s, ff, &fc);
            at_final = fc.sse <= fit.sse; /* w->pix holds the candidate's rendering */
            if (fc.sse <= fit.sse) {
                memcpy(R, Rc, sizeof R);
                cx = cxc;
                cy = cyc;
                r = rc_;
                fit = fc;
                lam = lam * 0.1 > RF_DAMPING ? lam * 0.1 : RF_DAMPING;
                total++;
                if (it + 1 < rf_iters[li]) jacobian(w, R, r * s, ff, &fit, H, g);
            } else {
                lam *= 10.0;
            }
        }
        if (lev == 0) {
            have_final = 1;
            final_sse = fit.sse;
            final_sst = w->sst;
            fit0 = fit;
        }
    }
    /* the residual: the finest level's pixels (chosen where that level began),
     * at the final pose (training/refine.py) */
    if (!have_final) {
        long np = pixel_set(w, 0, cx, cy, r, rf_strides[RF_LEVELS - 1]);
        if (np < 0) {
            pi_seterrn(err, errlen, "refine: out of memory");
            return -1;
        }
        if (np < 50) {
            pi_seterrn(err, errlen, "refine: circle too small or outside the frame");
            return -1;
        }
        evaluate(t, 0, w, R, cx, cy, r, focal_px, &fit0);
        final_sse = fit0.sse;
        final_sst = w->sst;
        at_final = 1;
    }
    out->residual = final_sst > 0 ? final_sse / final_sst : 1.0;
    /* the colour ratio on the same pixels at the final pose (training/refine.py):
     * the last step's candidate, when it was not kept, is rendered over */
    out->colour = NAN;
    if (!w->gray) {
        if (!at_final) evaluate(t, 0, w, R, cx, cy, r, focal_px, &fit0);
        out->colour = colour_ratio(w, &fit0);
    }
    memcpy(out->R, R, sizeof R);
    rf_matrix_to_euler(R, out->euler);
    out->cx = cx + x0;
    out->cy = cy + y0;
    out->r = r;
    out->iterations = total;
    return 0;
}

/* ---- the convergence check (docs/refine.md, step 6) ----------------------------- */

double rf_rotation_deg(const double A[3][3], const double B[3][3])
{
    /* |A - B| (Frobenius) = 2 sqrt(2) sin(t / 2): exact near 0, where acos of
     * the trace is not */
    double d = 0;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) d += (A[i][j] - B[i][j]) * (A[i][j] - B[i][j]);
    double s = sqrt(d) / (2.0 * sqrt(2.0));
    return 2.0 * asin(s > 1 ? 1 : s) * 180.0 / M_PI;
}

int rf_refine_checked(const rf_texture *t, rf_work *w, const rf_image *frame, double cx, double cy,
                      double r, const double R0[3][3], double focal_px, int steps,
                      double converge_max_deg, rf_out *out, double *moved, char *err, size_t errlen)
{
    *moved = NAN;
    if (rf_refine(t, w, frame, cx, cy, r, R0, focal_px, steps, out, err, errlen) < 0) return -1;
    if (!steps) return 0;
    /* one pass of the steps does not reach the minimum from several degrees
     * off: a gray frame (the network was trained on colour) and a start the
     * first pass moved far are refined again from the answer */
    double shift = hypot(out->cx - cx, out->cy - cy), dr = fabs(out->r - r);
    if (dr > shift) shift = dr;
    if (!isnan(out->colour) && shift <= RF_CHECK_PX && rf_rotation_deg(out->R, R0) <= RF_CHECK_DEG)
        return 0;
    for (int n = 1; n < RF_CHECK_PASSES; n++) {
        rf_out next;
        char perr[RF_TEXTURE_ERR_LEN];
        /* a circle that ran off (another texture): the answer so far, not converged */
        if (rf_refine(t, w, frame, out->cx, out->cy, out->r, out->R, focal_px, steps, &next, perr,
                      sizeof perr) < 0 ||
            !isfinite(next.cx) || !isfinite(next.cy) || !isfinite(next.r)) {
            *moved = INFINITY;
            return 0;
        }
        *moved = rf_rotation_deg(next.R, out->R);
        next.iterations += out->iterations;
        *out = next;
        if (*moved <= converge_max_deg) break;
    }
    return 0;
}

void rf_fused_centre(double cx, double cy, const double cov[3], double fx, double fy, double *ox,
                     double *oy)
{
    const double t2 = RF_CENTRE_FUSE_PX * RF_CENTRE_FUSE_PX;
    const double a = cov[0] + t2, b = cov[1], d = cov[2] + t2;
    const double det = a * d - b * b;
    const double gx = fx - cx, gy = fy - cy;
    const double ux = (d * gx - b * gy) / det, uy = (a * gy - b * gx) / det;
    *ox = cx + cov[0] * ux + cov[1] * uy;
    *oy = cy + cov[1] * ux + cov[2] * uy;
}
