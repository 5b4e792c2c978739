/* refine.c -- render-and-compare refinement (training/refine.py in C).
 *
 * Each step renders the texture analytically into the frame's geometry at
 * the sampled pixels (pinhole ray, sphere intersection, body direction R^T n,
 * bilinear texture lookup), fits the photometric model per channel by least
 * squares (I ~ T (a0 + a.n) + b), and takes a Levenberg-Marquardt step over
 * the rotation (3), the circle's centre (2) and radius (1), with the
 * photometric coefficients projected out. Coarse to fine on 2x2 box levels of
 * the frame's crop and of the texture. Every step follows the Python file, so
 * that both land on the same pose (docs/refine.md). */
#define _POSIX_C_SOURCE 200809L
#include "refine.h"
#include "pi_err.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

struct rf_texture {
    int w[RF_LEVELS], h[RF_LEVELS];
    float *px[RF_LEVELS]; /* [h][w][3], BGR; exact (8-bit values / 4^k) */
};

/* Where a sampled pixel reads the texture (tex_coords). */
typedef struct rf_tc {
    uint32_t o[4]; /* offsets of texels (i0, j0), (i1, j0), (i0, j1), (i1, j1) */
    double fx, fy, dut0, dut2, dvt1;
} rf_tc;

/* Per sampled pixel: what a step's Jacobian pass needs from its value pass. */
typedef struct rf_pix {
    double obs[3], val[3], n[3];
    double grad[3][3]; /* d val_c / d b, the body direction */
    double t;          /* the ray's length to the sphere */
    int flat;          /* the texture is constant around it: J = 0 */
    rf_tc tc;
} rf_pix;

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
    rf_pix *pix;
    size_t pcap;
    double sst; /* the sampled pixels' variance sum (pixel_set) */
};

static const int rf_iters[RF_LEVELS] = RF_ITERS_INIT;
static const int rf_strides[RF_LEVELS] = RF_STRIDES_INIT;

/* ---- conversions ------------------------------------------------------------ */

void rf_euler_to_matrix(const double e[3], double R[3][3])
{
    const double d = M_PI / 180.0;
    double cx = cos(e[0] * d), sx = sin(e[0] * d), cy = cos(e[1] * d), sy = sin(e[1] * d);
    double cz = cos(e[2] * d), sz = sin(e[2] * d);
    R[0][0] = cz * cy;
    R[0][1] = cz * sy * sx - sz * cx;
    R[0][2] = cz * sy * cx + sz * sx;
    R[1][0] = sz * cy;
    R[1][1] = sz * sy * sx + cz * cx;
    R[1][2] = sz * sy * cx - cz * sx;
    R[2][0] = -sy;
    R[2][1] = cy * sx;
    R[2][2] = cy * cx;
}

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

rf_texture *rf_texture_new(const rf_image *img, char *err)
{
    int w = img->width, h = img->height, unit = RF_TEXTURE_WIDTH >> (RF_LEVELS - 1);
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
    t->px[0] = full;
    full = NULL;
    t->w[0] = w;
    t->h[0] = h;
    for (int l = 1; l < RF_LEVELS; l++) {
        t->w[l] = t->w[l - 1] / 2;
        t->h[l] = t->h[l - 1] / 2;
        t->px[l] = malloc((size_t)t->w[l] * t->h[l] * 3 * sizeof(float));
        if (!t->px[l]) goto oom;
        reduce2(t->px[l - 1], t->w[l - 1], t->h[l - 1], t->px[l]);
    }
    return t;
oom:
    free(full);
    rf_texture_free(t);
    pi_seterrn(err, RF_TEXTURE_ERR_LEN, "texture: out of memory");
    return NULL;
}

void rf_texture_free(rf_texture *t)
{
    if (!t) return;
    for (int l = 0; l < RF_LEVELS; l++) free(t->px[l]);
    free(t);
}

rf_work *rf_work_new(void)
{
    return calloc(1, sizeof(rf_work));
}

void rf_work_free(rf_work *w)
{
    if (!w) return;
    free(w->pix);
    free(w);
}

static int grow(void **p, size_t *cap, size_t need)
{
    if (need <= *cap) return 0;
    void *q = realloc(*p, need);
    if (!q) return -1;
    *p = q;
    *cap = need;
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

/* Pixel (i, j) of level lev of the crop. */
static inline void level_px(const rf_work *w, int lev, int i, int j, double out[3])
{
    int k = 1 << lev;
    double acc[3] = {0, 0, 0}, px[3];
    for (int dj = 0; dj < k; dj++)
        for (int di = 0; di < k; di++) {
            load_px(w->frame, w->x0 + i * k + di, w->y0 + j * k + dj, px);
            acc[0] += px[0];
            acc[1] += px[1];
            acc[2] += px[2];
        }
    double s = 1.0 / (k * k);
    out[0] = acc[0] * s;
    out[1] = acc[1] * s;
    out[2] = acc[2] * s;
}

/* ---- geometry ------------------------------------------------------------------- */

static inline double focal_of(double r, double fixed_f)
{
    return fixed_f > 0 ? fixed_f : r * sqrt(RF_REF_D_OVER_R * RF_REF_D_OVER_R - 1.0);
}

/* What the normals of one evaluation share: the circle and the camera. */
typedef struct rf_geom {
    double cx, cy, inv_f, dist, dist2m1; /* dist: camera to centre, unit sphere */
} rf_geom;

static inline void geom_init(rf_geom *g, double cx, double cy, double r, double f)
{
    double tan_a = r / f;
    g->cx = cx;
    g->cy = cy;
    g->inv_f = 1.0 / f;
    g->dist = sqrt(1.0 + tan_a * tan_a) / tan_a;
    g->dist2m1 = g->dist * g->dist - 1.0;
}

/* Unit normal of the sphere point seen through (u, v) (training/refine.py normals). */
static inline void normal_at(double u, double v, const rf_geom *g, double n[3], double *t_out)
{
    double x = (u - g->cx) * g->inv_f, y = -(v - g->cy) * g->inv_f;
    double inv = 1.0 / sqrt(x * x + y * y + 1.0);
    double dx = x * inv, dy = y * inv, dz = -inv;
    double od = g->dist * dz;
    double disc = od * od - g->dist2m1;
    if (disc < 0) disc = 0;
    double t = -od - sqrt(disc);
    *t_out = t;
    n[0] = t * dx;
    n[1] = t * dy;
    n[2] = g->dist + t * dz;
}

/* d n / d (cx, cy, r) at pixel (u, v), n given (training/refine.py
 * normals_and_derivs: dt = -(n.dO + t n.dd) / (n.d), dn = dO + dt d + t dd). */
static inline void normal_derivs(double u, double v, double cx, double cy, double r, double f,
                                 int fixed, const double n[3], double t, double dn[3][3])
{
    double x = (u - cx) / f, y = -(v - cy) / f;
    double tan_a = r / f, sec = sqrt(1.0 + tan_a * tan_a);
    double L = sqrt(x * x + y * y + 1.0), inv = 1.0 / L;
    double d[3] = {x * inv, y * inv, -inv};
    double nd = n[0] * d[0] + n[1] * d[1] + n[2] * d[2];
    double dqs[3][3] = {{-1.0 / f, 0, 0}, {0, 1.0 / f, 0}, {0, 0, 0}}, dDs[3] = {0, 0, 0};
    if (fixed)
        dDs[2] = -(1.0 / f) / (tan_a * tan_a * sec);
    else {
        dqs[2][0] = -x / r;
        dqs[2][1] = -y / r;
    }
    for (int k = 0; k < 3; k++) {
        const double *dq = dqs[k];
        double ddq = d[0] * dq[0] + d[1] * dq[1] + d[2] * dq[2], dd[3];
        for (int i = 0; i < 3; i++) dd[i] = (dq[i] - d[i] * ddq) * inv;
        double ndd = n[0] * dd[0] + n[1] * dd[1] + n[2] * dd[2];
        double dt = -(n[2] * dDs[k] + t * ndd) / nd;
        for (int i = 0; i < 3; i++) dn[k][i] = dt * d[i] + t * dd[i];
        dn[k][2] += dDs[k];
    }
}

/* atan2 (x86-64's libm takes about a sixth of refinement's time in it):
 * Cephes' atan, a rational function on |t| <= 0.66 and atan(t) = pi/4 +
 * atan((t - 1) / (t + 1)) above, within 2.3e-16 of libm on [-1, 1]; the
 * quadrant from the signs. */
static inline double atan2_fast(double y, double x)
{
    static const double P[5] = {-8.750608600031904122785e-1, -1.615753718733365076637e1,
                                -7.500855792314704667340e1, -1.228866684490136173410e2,
                                -6.485021904942025371773e1};
    static const double Q[5] = {2.485846490142306297962e1, 1.650270098316988542046e2,
                                4.328810604912902668951e2, 4.853903996359136964868e2,
                                1.945506571482613964425e2};
    double ax = fabs(x), ay = fabs(y);
    if (ax == 0 && ay == 0) return atan2(y, x);
    int swap = ay > ax;
    double t = swap ? ax / ay : ay / ax, base = 0; /* t in [0, 1] */
    if (t > 0.66) {
        t = (t - 1) / (t + 1);
        base = M_PI / 4;
    }
    double z = t * t;
    double pz = (((P[0] * z + P[1]) * z + P[2]) * z + P[3]) * z + P[4];
    double qz = ((((z + Q[0]) * z + Q[1]) * z + Q[2]) * z + Q[3]) * z + Q[4];
    double a = base + (t * (z * pz / qz) + t); /* atan(min / max) */
    if (swap) a = M_PI / 2 - a;
    if (x < 0) a = M_PI - a;
    return y < 0 ? -a : a;
}

/* Where body direction b reads the texture: the four texels' offsets, the
 * bilinear weights and d (u, v) / d b. The first half of a bilinear lookup;
 * tex_gather is the second, so that the texels can be fetched ahead. */
static inline void tex_coords(int w, int h, const double b[3], rf_tc *tc)
{
    double bx = b[0], by = b[1], bz = b[2];
    double rho2 = bx * bx + bz * bz;
    if (rho2 < 1e-12) rho2 = 1e-12;
    double rho = sqrt(rho2);
    double lon = atan2_fast(bx, bz);
    double lat = asin(by < -1 ? -1 : by > 1 ? 1 : by);
    double ut = (lon + M_PI) * (w / (2 * M_PI)) - 0.5;
    double vt = (M_PI / 2 - lat) * (h / M_PI) - 0.5;
    /* floor without libm (x86-64's baseline has no rounding instruction), and
     * the wrap without a division: ut lies in [-0.5, w - 0.5] */
    long i0 = (long)ut, j0 = (long)vt;
    if ((double)i0 > ut) i0--;
    if ((double)j0 > vt) j0--;
    tc->fx = ut - (double)i0;
    tc->fy = vt - (double)j0;
    if (i0 < 0) i0 += w;
    if (i0 >= w) i0 -= w;
    long i1 = i0 + 1 == w ? 0 : i0 + 1, j1 = j0 + 1;
    if (j1 > h - 1) j1 = h - 1;
    if (j1 < 0) j1 = 0;
    if (j0 > h - 1) j0 = h - 1;
    if (j0 < 0) j0 = 0;
    tc->o[0] = (uint32_t)((j0 * w + i0) * 3);
    tc->o[1] = (uint32_t)((j0 * w + i1) * 3);
    tc->o[2] = (uint32_t)((j1 * w + i0) * 3);
    tc->o[3] = (uint32_t)((j1 * w + i1) * 3);
    double kw = w / (2 * M_PI), kh = -h / M_PI, krho = kw / rho2;
    tc->dut0 = bz * krho;
    tc->dut2 = -bx * krho;
    tc->dvt1 = kh / rho;
}

/* Bilinear value (3 channels) and d value / d b (training/refine.py sample). */
static inline void tex_gather(const float *tex, const rf_tc *tc, double val[3], double grad[3][3])
{
    const float *t00 = tex + tc->o[0], *t10 = tex + tc->o[1];
    const float *t01 = tex + tc->o[2], *t11 = tex + tc->o[3];
    double fx = tc->fx, fy = tc->fy;
    for (int c = 0; c < 3; c++) {
        double a00 = t00[c], a10 = t10[c], a01 = t01[c], a11 = t11[c];
        double top = a00 + fx * (a10 - a00);
        double bot = a01 + fx * (a11 - a01);
        val[c] = top + fy * (bot - top);
        double du = (a10 - a00) + fy * ((a11 - a01) - (a10 - a00));
        double dv = bot - top;
        grad[c][0] = du * tc->dut0;
        grad[c][1] = dv * tc->dvt1;
        grad[c][2] = du * tc->dut2;
    }
}

/* A x = b for symmetric positive semi-definite A (k <= 6), with the tiny ridge
 * of training/refine.py _solve_spd; Gaussian elimination with partial pivoting. */
static void solve_spd(int k, double A[6][6], const double *b, double *x)
{
    double M[6][7], tr = 0;
    for (int i = 0; i < k; i++) tr += A[i][i];
    double ridge = 1e-9 * (tr / k > 1.0 ? tr / k : 1.0);
    for (int i = 0; i < k; i++) {
        for (int j = 0; j < k; j++) M[i][j] = A[i][j] + (i == j ? ridge : 0);
        M[i][k] = b[i];
    }
    for (int c = 0; c < k; c++) {
        int p = c;
        for (int i = c + 1; i < k; i++)
            if (fabs(M[i][c]) > fabs(M[p][c])) p = i;
        if (p != c)
            for (int j = 0; j <= k; j++) {
                double t = M[c][j];
                M[c][j] = M[p][j];
                M[p][j] = t;
            }
        double d = M[c][c];
        if (d == 0) d = 1e-300;
        for (int i = c + 1; i < k; i++) {
            double f = M[i][c] / d;
            for (int j = c; j <= k; j++) M[i][j] -= f * M[c][j];
        }
    }
    for (int i = k - 1; i >= 0; i--) {
        double s = M[i][k];
        for (int j = i + 1; j < k; j++) s -= M[i][j] * x[j];
        x[i] = s / (M[i][i] != 0 ? M[i][i] : 1e-300);
    }
}

/* Sampled pixels of a level (training/refine.py pixel_set): fills w->pix[].obs
 * and the pixel centres; returns the count (or -1 out of memory). */
static long pixel_set(rf_work *w, int lev, double cx, double cy, double r, int stride, double **uv)
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
    if (grow((void **)&w->pix, &w->pcap, (most + 1) * (sizeof(rf_pix) + 2 * sizeof(double))) < 0)
        return -1;
    /* the pixel centres live after the rf_pix records in the same block */
    *uv = (double *)(w->pix + most + 1);
    long n = 0;
    for (int j = j0; j < j1; j += stride)
        for (int i = i0; i < i1; i += stride) {
            double u = i + 0.5, v = j + 0.5;
            if ((u - cx) * (u - cx) + (v - cy) * (v - cy) > rm * rm) continue;
            level_px(w, lev, i, j, w->pix[n].obs);
            (*uv)[2 * n] = u;
            (*uv)[2 * n + 1] = v;
            n++;
        }
    /* the frame's variance sum over them: the residual's denominator */
    double sum[3] = {0, 0, 0}, sst = 0;
    for (long k = 0; k < n; k++)
        for (int c = 0; c < 3; c++) sum[c] += w->pix[k].obs[c];
    for (long k = 0; k < n; k++)
        for (int c = 0; c < 3; c++) {
            double d = w->pix[k].obs[c] - sum[c] / n;
            sst += d * d;
        }
    w->sst = sst;
    return n;
}

/* The value pass of an evaluation at (R, cx, cy, r): renders the texture at
 * the sampled pixels (kept in w->pix for the Jacobian pass) and fits the
 * photometric model; fit->sse is the sum of squares it leaves. */
static void evaluate(const rf_texture *t, int lev, rf_work *w, const double *uv, long np,
                     const double R[3][3], double cx, double cy, double r, double fixed_f,
                     rf_fit *fit)
{
    const float *tex = t->px[lev];
    int tw = t->w[lev], th = t->h[lev];
    rf_geom geo;
    geom_init(&geo, cx, cy, r, focal_of(r, fixed_f));
    double oo[3], acc[3][20];
    memset(fit, 0, sizeof *fit);
    memset(acc, 0, sizeof acc);
    /* first where every pixel reads the texture, asking for those texels
     * ahead: they are mostly out of the caches after the network has run */
    for (long k = 0; k < np; k++) {
        rf_pix *p = &w->pix[k];
        double b[3];
        normal_at(uv[2 * k], uv[2 * k + 1], &geo, p->n, &p->t);
        for (int i = 0; i < 3; i++)
            b[i] = p->n[0] * R[0][i] + p->n[1] * R[1][i] + p->n[2] * R[2][i];
        tex_coords(tw, th, b, &p->tc);
        __builtin_prefetch(tex + p->tc.o[0]);
        __builtin_prefetch(tex + p->tc.o[2]);
    }
    for (long k = 0; k < np; k++) {
        rf_pix *p = &w->pix[k];
        tex_gather(tex, &p->tc, p->val, p->grad);
        if (w->gray) {
            double y = p->val[0] * RF_LUMA_B + p->val[1] * RF_LUMA_G + p->val[2] * RF_LUMA_R;
            for (int i = 0; i < 3; i++) {
                double gi = p->grad[0][i] * RF_LUMA_B + p->grad[1][i] * RF_LUMA_G +
                            p->grad[2][i] * RF_LUMA_R;
                p->grad[0][i] = p->grad[1][i] = p->grad[2][i] = gi;
            }
            p->val[0] = p->val[1] = p->val[2] = y;
        }
        p->flat = 1;
        for (int c = 0; c < 3 && p->flat; c++)
            p->flat = p->grad[c][0] == 0 && p->grad[c][1] == 0 && p->grad[c][2] == 0;
        /* A^T A and A^T obs of the rows a = (T, T nx, T ny, T nz, 1), written
         * out: the products of the normal are shared by the channels */
        double n0 = p->n[0], n1 = p->n[1], n2 = p->n[2];
        double m[10] = {1, n0, n1, n2, n0 * n0, n0 * n1, n0 * n2, n1 * n1, n1 * n2, n2 * n2};
        for (int c = 0; c < 3; c++) {
            double tv = p->val[c], o = p->obs[c], t2 = tv * tv, to = tv * o;
            double *q = acc[c];
            for (int i = 0; i < 10; i++) q[i] += t2 * m[i];
            q[10] += tv;
            q[11] += tv * n0;
            q[12] += tv * n1;
            q[13] += tv * n2;
            q[14] += to;
            q[15] += to * n0;
            q[16] += to * n1;
            q[17] += to * n2;
            q[18] += o;
            q[19] += o * o;
        }
    }
    for (int c = 0; c < 3; c++) {
        const double *q = acc[c];
        double(*M)[6] = fit->AtA[c];
        /* rows (T, T nx, T ny, T nz, 1): T^2 m[...] above the diagonal, T m[...] in the
         * last column */
        static const int idx[4][4] = {{0, 1, 2, 3}, {1, 4, 5, 6}, {2, 5, 7, 8}, {3, 6, 8, 9}};
        for (int i = 0; i < 4; i++) {
            for (int j = i; j < 4; j++) M[i][j] = q[idx[i][j]];
            M[i][4] = q[10 + i];
            fit->Atb[c][i] = q[14 + i];
        }
        M[4][4] = (double)np;
        fit->Atb[c][4] = q[18];
        oo[c] = q[19];
    }
    /* |obs - A coef|^2 = obs.obs - 2 coef.A^T obs + coef.A^T A coef (training/refine.py
     * photometric_fit): no second pass over the pixels */
    for (int c = 0; c < 3; c++) {
        double(*M)[6] = fit->AtA[c];
        for (int i = 0; i < 5; i++)
            for (int j = 0; j < i; j++) M[i][j] = M[j][i];
        double *x = fit->coef[c];
        solve_spd(5, M, fit->Atb[c], x);
        double q = 0, xb = 0;
        for (int i = 0; i < 5; i++) {
            double mx = 0;
            for (int j = 0; j < 5; j++) mx += M[i][j] * x[j];
            q += x[i] * mx;
            xb += x[i] * fit->Atb[c][i];
        }
        fit->sse += oo[c] - 2 * xb + q;
    }
}

/* The Jacobian pass at the pose and circle of the last value pass: the normal
 * equations H d = g of a step, with the photometric coefficients projected out. */
static void jacobian(rf_work *w, const double *uv, long np, const double R[3][3], double cx,
                     double cy, double r, double fixed_f, const rf_fit *fit, double H[6][6],
                     double g[6])
{
    double f = focal_of(r, fixed_f), JtA[3][6][5];
    memset(H, 0, sizeof(double) * 36);
    memset(g, 0, sizeof(double) * 6);
    memset(JtA, 0, sizeof JtA);
    for (long k = 0; k < np; k++) {
        const rf_pix *p = &w->pix[k];
        if (p->flat) continue;
        const double *n = p->n;
        double dn[3][3];
        normal_derivs(uv[2 * k], uv[2 * k + 1], cx, cy, r, f, fixed_f > 0, n, p->t, dn);
        for (int c = 0; c < 3; c++) {
            const double *a = fit->coef[c];
            double gw[3], J[6], tv = p->val[c];
            for (int i = 0; i < 3; i++)
                gw[i] = R[i][0] * p->grad[c][0] + R[i][1] * p->grad[c][1] + R[i][2] * p->grad[c][2];
            double shade = a[0] + a[1] * n[0] + a[2] * n[1] + a[3] * n[2];
            double e = p->obs[c] - (tv * shade + a[4]);
            J[0] = (gw[1] * n[2] - gw[2] * n[1]) * shade;
            J[1] = (gw[2] * n[0] - gw[0] * n[2]) * shade;
            J[2] = (gw[0] * n[1] - gw[1] * n[0]) * shade;
            for (int q = 0; q < 3; q++)
                J[3 + q] = (gw[0] * dn[q][0] + gw[1] * dn[q][1] + gw[2] * dn[q][2]) * shade;
            double ab[5] = {tv, tv * n[0], tv * n[1], tv * n[2], 1.0};
            for (int i = 0; i < 6; i++) {
                for (int j = i; j < 6; j++) H[i][j] += J[i] * J[j];
                for (int j = 0; j < 5; j++) JtA[c][i][j] += J[i] * ab[j];
                g[i] += J[i] * e;
            }
        }
    }
    /* variable projection (training/refine.py _eval): take out of J^T J what
     * the refitted photometric coefficients absorb, J^T A (A^T A)^-1 A^T J */
    for (int c = 0; c < 3; c++) {
        double X[6][5], M[6][6];
        memcpy(M, fit->AtA[c], sizeof M);
        for (int i = 0; i < 6; i++) solve_spd(5, M, JtA[c][i], X[i]);
        for (int i = 0; i < 6; i++)
            for (int j = i; j < 6; j++) {
                double q = 0;
                for (int k = 0; k < 5; k++) q += JtA[c][i][k] * X[j][k];
                H[i][j] -= q;
            }
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

/* The frame's colour share over the fitted rendering's, on the pixels of the
 * last value pass (NaN when the rendering has no colour). */
static double colour_ratio(const rf_work *w, long np, const rf_fit *fit)
{
    double so[3] = {0, 0, 0}, sm[3] = {0, 0, 0}, Co[3][3], Cm[3][3];
    memset(Co, 0, sizeof Co);
    memset(Cm, 0, sizeof Cm);
    for (int pass = 0; pass < 2; pass++)
        for (long k = 0; k < np; k++) {
            const rf_pix *p = &w->pix[k];
            double o[3], m[3];
            for (int c = 0; c < 3; c++) {
                const double *a = fit->coef[c];
                double shade = a[0] + a[1] * p->n[0] + a[2] * p->n[1] + a[3] * p->n[2];
                m[c] = p->val[c] * shade + a[4];
                o[c] = p->obs[c];
            }
            if (pass == 0) {
                for (int c = 0; c < 3; c++) {
                    so[c] += o[c];
                    sm[c] += m[c];
                }
                continue;
            }
            for (int c = 0; c < 3; c++) {
                o[c] -= so[c] / np;
                m[c] -= sm[c] / np;
            }
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                    Co[i][j] += o[i] * o[j];
                    Cm[i][j] += m[i] * m[j];
                }
        }
    double sm_share = off_axis_share(Cm);
    return sm_share > 0 ? off_axis_share(Co) / sm_share : NAN;
}

int rf_refine(const rf_texture *t, rf_work *w, const rf_image *frame, double cx, double cy,
              double r, const double R0[3][3], double focal_px, int steps, rf_out *out, char *err,
              size_t errlen)
{
    double R[3][3];
    int x0, y0, total = 0, have_final = 0, at_final = 0;
    double *uv, final_sse = 0, final_sst = 0;
    long np0 = 0;
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
        long np = pixel_set(w, lev, cx * s, cy * s, r * s, rf_strides[li], &uv);
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
        evaluate(t, lev, w, uv, np, R, cx * s, cy * s, r * s, ff, &fit);
        at_final = 1;
        jacobian(w, uv, np, R, cx * s, cy * s, r * s, ff, &fit, H, g);
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
            evaluate(t, lev, w, uv, np, Rc, cxc * s, cyc * s, rc_ * s, ff, &fc);
            at_final = fc.sse <= fit.sse; /* w->pix holds the candidate's rendering */
            if (fc.sse <= fit.sse) {
                memcpy(R, Rc, sizeof R);
                cx = cxc;
                cy = cyc;
                r = rc_;
                fit = fc;
                lam = lam * 0.1 > RF_DAMPING ? lam * 0.1 : RF_DAMPING;
                total++;
                if (it + 1 < rf_iters[li])
                    jacobian(w, uv, np, R, cx * s, cy * s, r * s, ff, &fit, H, g);
            } else {
                lam *= 10.0;
            }
        }
        if (lev == 0) {
            have_final = 1;
            final_sse = fit.sse;
            final_sst = w->sst;
            np0 = np;
            fit0 = fit;
        }
    }
    /* the residual: the finest level's pixels (chosen where that level began),
     * at the final pose (training/refine.py) */
    if (!have_final) {
        long np = pixel_set(w, 0, cx, cy, r, rf_strides[RF_LEVELS - 1], &uv);
        if (np < 0) {
            pi_seterrn(err, errlen, "refine: out of memory");
            return -1;
        }
        if (np < 50) {
            pi_seterrn(err, errlen, "refine: circle too small or outside the frame");
            return -1;
        }
        evaluate(t, 0, w, uv, np, R, cx, cy, r, focal_px, &fit0);
        final_sse = fit0.sse;
        final_sst = w->sst;
        np0 = np;
        at_final = 1;
    }
    out->residual = final_sst > 0 ? final_sse / final_sst : 1.0;
    /* the colour ratio on the same pixels at the final pose (training/refine.py):
     * the last step's candidate, when it was not kept, is rendered over */
    out->colour = NAN;
    if (!w->gray) {
        if (!at_final) evaluate(t, 0, w, uv, np0, R, cx, cy, r, focal_px, &fit0);
        out->colour = colour_ratio(w, np0, &fit0);
    }
    memcpy(out->R, R, sizeof R);
    rf_matrix_to_euler(R, out->euler);
    out->cx = cx + x0;
    out->cy = cy + y0;
    out->r = r;
    out->iterations = total;
    return 0;
}
