// shim.cpp -- OpenCV behind a C interface (shim.h). Every entry point
// catches everything: no C++ exception ever reaches C code.
#include "shim.h"
#include "crop2.h"
#include "kernels.h"
#include "pi_err.h"

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include <unistd.h>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

struct shim_mat {
    cv::Mat m;
};

struct shim_cap {
    cv::VideoCapture cap;
    cv::Mat frame;
    std::string spec;
};

// "call: why" through the one error helper (pi_err.h).
static void seterr(char *err, const char *call, const char *why)
{
    pi_seterr(err, "%s: %s", call, why);
}

// OpenCV exception text is multi-line ("OpenCV(4.6.0) file:line: error: ...");
// keep the part after "error: " on one line.
static std::string cv_message(const cv::Exception &e)
{
    std::string msg = e.err.empty() ? e.what() : e.err;
    std::replace(msg.begin(), msg.end(), '\n', ' ');
    return msg;
}

#define SHIM_CATCH(call)                            \
    catch (const cv::Exception &e)                  \
    {                                               \
        seterr(err, call, cv_message(e).c_str());   \
    }                                               \
    catch (const std::bad_alloc &)                  \
    {                                               \
        seterr(err, call, "out of memory");         \
    }                                               \
    catch (const std::exception &e)                 \
    {                                               \
        seterr(err, call, e.what());                \
    }                                               \
    catch (...)                                     \
    {                                               \
        seterr(err, call, "unknown C++ exception"); \
    }

extern "C" shim_mat *shim_mat_new(void)
{
    try {
        return new shim_mat();
    } catch (...) {
        return nullptr;
    }
}

extern "C" void shim_mat_free(shim_mat *m)
{
    delete m;
}

// ---- header probing: refuse huge images before allocating them -------------

static unsigned long be32(const unsigned char *p)
{
    return ((unsigned long)p[0] << 24) | ((unsigned long)p[1] << 16) | ((unsigned long)p[2] << 8) |
           p[3];
}

static long le32s(const unsigned char *p)
{
    unsigned long u = (unsigned long)p[0] | ((unsigned long)p[1] << 8) |
                      ((unsigned long)p[2] << 16) | ((unsigned long)p[3] << 24);
    return u >= 0x80000000UL ? -(long)(0x100000000UL - u) : (long)u;
}

// PNM header: magic, then width, height as ASCII with comments.
static int pnm_ints(const unsigned char *buf, size_t len, long *w, long *h)
{
    size_t i = 2;
    long v[2];
    for (int k = 0; k < 2; k++) {
        for (;;) {
            while (i < len && isspace(buf[i])) i++;
            if (i < len && buf[i] == '#') {
                while (i < len && buf[i] != '\n') i++;
                continue;
            }
            break;
        }
        if (i >= len || !isdigit(buf[i])) return -1;
        v[k] = 0;
        while (i < len && isdigit(buf[i])) {
            if (v[k] > 100000000L) return -1;
            v[k] = v[k] * 10 + (buf[i++] - '0');
        }
    }
    *w = v[0];
    *h = v[1];
    return 0;
}

extern "C" int shim_probe_size(const unsigned char *buf, size_t len, long *w, long *h, char *err)
{
    static const unsigned char png_sig[8] = {0x89, 'P', 'N', 'G', 0x0d, 0x0a, 0x1a, 0x0a};
    if (len >= 8 && memcmp(buf, png_sig, 8) == 0) {
        if (len < 24 || memcmp(buf + 12, "IHDR", 4) != 0) {
            seterr(err, "decode", "PNG header truncated or corrupt");
            return -1;
        }
        *w = (long)be32(buf + 16);
        *h = (long)be32(buf + 20);
        return 0;
    }
    if (len >= 3 && buf[0] == 0xff && buf[1] == 0xd8 && buf[2] == 0xff) {
        // A JPEG cut short still decodes (libjpeg pads it with gray and
        // warns); a frame with missing rows is no measurement, so refuse it.
        size_t tail = len > 64 ? len - 64 : 2, i;
        for (i = len - 1; i > tail; i--)
            if (buf[i - 1] == 0xff && buf[i] == 0xd9) break;
        if (i <= tail) {
            seterr(err, "decode", "truncated JPEG (no end-of-image marker)");
            return -1;
        }
        i = 2;
        while (i + 9 < len) {
            if (buf[i] != 0xff) {
                i++;
                continue;
            }
            unsigned char mk = buf[i + 1];
            if (mk == 0xff) {
                i++;
                continue;
            }
            if (mk == 0xd8 || mk == 0x01 || (mk >= 0xd0 && mk <= 0xd7)) {
                i += 2;
                continue;
            }
            size_t seglen = ((size_t)buf[i + 2] << 8) | buf[i + 3];
            if (mk >= 0xc0 && mk <= 0xcf && mk != 0xc4 && mk != 0xc8 && mk != 0xcc) {
                *h = ((long)buf[i + 5] << 8) | buf[i + 6];
                *w = ((long)buf[i + 7] << 8) | buf[i + 8];
                return 0;
            }
            if (seglen < 2) break;
            i += 2 + seglen;
        }
        return 1;
    }
    if (len >= 26 && buf[0] == 'B' && buf[1] == 'M') {
        *w = std::labs(le32s(buf + 18));
        *h = std::labs(le32s(buf + 22));
        return 0;
    }
    if (len >= 3 && buf[0] == 'P' && buf[1] >= '1' && buf[1] <= '6') {
        if (pnm_ints(buf, len, w, h) < 0) {
            seterr(err, "decode", "PNM header corrupt");
            return -1;
        }
        return 0;
    }
    return 1;
}

// The pi_frame view of an 8-bit image (no copy: valid while `m` is), for
// both frame sources, the decoder and VideoCapture.
static void frame_from_mat(const cv::Mat &m, pi_frame *out)
{
    out->data = m.data;
    out->width = m.cols;
    out->height = m.rows;
    out->channels = m.channels();
    out->stride = m.step[0];
    out->decode_ms = 0;
}

extern "C" int shim_decode(shim_mat *m, const void *buf, size_t len, long max_pixels, pi_frame *out,
                           char *err)
{
    try {
        long w = 0, h = 0;
        if (len == 0) {
            seterr(err, "decode", "empty file");
            return -1;
        }
        if (len > (size_t)INT_MAX) {
            seterr(err, "decode", "file too large");
            return -1;
        }
        int pr = shim_probe_size((const unsigned char *)buf, len, &w, &h, err);
        if (pr < 0) return -1;
        if (pr == 0 && (double)w * (double)h > (double)max_pixels) {
            pi_seterr(err, "decode: image is %ldx%ld, over the limit of %ld pixels", w, h,
                      max_pixels);
            return -1;
        }
        cv::Mat raw(1, (int)len, CV_8U, const_cast<void *>(buf));
        m->m.release();
        cv::imdecode(raw, cv::IMREAD_UNCHANGED, &m->m);
        if (m->m.empty()) {
            seterr(err, "decode", "cannot decode image (corrupt, truncated or not an image)");
            return -1;
        }
        if (m->m.depth() != CV_8U) {
            seterr(err, "decode", "expected 8-bit pixels");
            m->m.release();
            return -1;
        }
        if ((double)m->m.cols * m->m.rows > (double)max_pixels) {
            pi_seterr(err, "decode: image is %dx%d, over the limit of %ld pixels", m->m.cols,
                      m->m.rows, max_pixels);
            m->m.release();
            return -1;
        }
        if (m->m.channels() != 1 && m->m.channels() != 3 && m->m.channels() != 4) {
            seterr(err, "decode", "expected 1, 3 or 4 channels");
            m->m.release();
            return -1;
        }
        frame_from_mat(m->m, out);
        return 0;
    }
    SHIM_CATCH("decode")
    return -1;
}

// ---- preprocessing "sphere-crop-v1" (docs/interfaces.md) -------------------

// Median of a histogram of n values: the mean of the two middle values for
// an even count, as numpy.median.
static double hist_median(const unsigned long hist[256], unsigned long n)
{
    unsigned long lo = (n - 1) / 2, hi = n / 2, acc = 0;
    int vlo = -1, vhi = -1;
    for (int v = 0; v < 256; v++) {
        acc += hist[v];
        if (vlo < 0 && acc > lo) vlo = v;
        if (vhi < 0 && acc > hi) {
            vhi = v;
            break;
        }
    }
    return (vlo + vhi) / 2.0;
}

static void add_rows(const cv::Mat &bgr, int r0, int r1, int c0, int c1, unsigned long hist[3][256],
                     unsigned long *n)
{
    for (int r = r0; r < r1; r++) {
        const unsigned char *p = bgr.ptr<unsigned char>(r) + 3 * c0;
        for (int c = c0; c < c1; c++, p += 3) {
            hist[0][p[0]]++;
            hist[1][p[1]]++;
            hist[2][p[2]]++;
        }
        *n += (unsigned long)(c1 - c0);
    }
}

// Step 8: BGR -> RGB, /255, (v - mean) / std, CHW. Same float32 operations
// in the same order as the Python reference, through a table.
static void normalise(const unsigned char *small, size_t step, const pp_params *p, float *out)
{
    const int S = p->size;
    float lut[3][256];
    for (int c = 0; c < 3; c++)
        for (int v = 0; v < 256; v++) {
            float t = (float)v / 255.0f;
            t = t - p->mean[c];
            lut[c][v] = t / p->std[c];
        }
    const size_t plane = (size_t)S * S;
    for (int y = 0; y < S; y++) {
        const unsigned char *s = small + (size_t)y * step;
        float *dr = out + (size_t)y * S, *dg = dr + plane, *db = dg + plane;
        for (int x = 0; x < S; x++, s += 3) {
            dr[x] = lut[0][s[2]];
            dg[x] = lut[1][s[1]];
            db[x] = lut[2][s[0]];
        }
    }
}

// A frame of 1, 3 or 4 channels as BGR (a 3-channel frame itself, not copied).
static cv::Mat bgr_of(const pi_frame *f)
{
    const size_t stride = f->stride ? f->stride : (size_t)f->width * f->channels;
    const cv::Mat src(f->height, f->width, CV_8UC(f->channels), const_cast<uint8_t *>(f->data),
                      stride);
    if (f->channels == 3) return src;
    cv::Mat bgr;
    cv::cvtColor(src, bgr, f->channels == 1 ? cv::COLOR_GRAY2BGR : cv::COLOR_BGRA2BGR);
    return bgr;
}

// sphere-crop-v2: undistort (camera with distortion) into *und, find the
// circle, crop. *und is the caller's, so refinement can read the same image.
static int preprocess_v2(const cv::Mat &bgr0, const pp_params *p, float *out, pp_circle *circ,
                         cv::Mat *und, char *err)
{
    const cv::Mat *bgr = &bgr0;
    if (p->cam.set && (bgr0.cols != p->cam.width || bgr0.rows != p->cam.height)) {
        pi_seterr(err, "preprocess: frame is %dx%d, the camera file's calibration is for %dx%d",
                  bgr0.cols, bgr0.rows, p->cam.width, p->cam.height);
        return -1;
    }
    if (p->undistort) {
        const crop2::UndistortMap &m = *static_cast<const crop2::UndistortMap *>(p->undistort);
        und->create(bgr0.rows, bgr0.cols, CV_8UC3);
        crop2::remap(bgr0.data, bgr0.step[0], m, und->data);
        bgr = und;
    }
    double cx, cy, r;
    char why[200];
    const double t0 = pi_now_ms();
    if (crop2::find_sphere(bgr->data, bgr->cols, bgr->rows, bgr->step[0], p, &cx, &cy, &r,
                           circ->cov, why, sizeof why) < 0) {
        seterr(err, "preprocess", why);
        return -1;
    }
    circ->locate_ms = pi_now_ms() - t0;
    if (r * p->margin * 2 > 65536) {
        seterr(err, "preprocess", "sphere too large");
        return -1;
    }
    std::vector<unsigned char> small((size_t)p->size * p->size * 3);
    crop2::crop(bgr->data, bgr->cols, bgr->rows, bgr->step[0], cx, cy, r, p, small.data());
    normalise(small.data(), (size_t)p->size * 3, p, out);
    circ->cx = cx;
    circ->cy = cy;
    circ->r = r;
    for (int c = 0; c < 3; c++) circ->bg[c] = p->fill[c];
    return 0;
}

extern "C" int shim_rim_from(const pi_frame *f, const pp_params *p, double cx, double cy, double r,
                             double *ocx, double *ocy, double *orad, double *cov, char *err)
{
    try {
        const cv::Mat bgr = bgr_of(f);
        return crop2::rim_from(bgr.data, bgr.cols, bgr.rows, bgr.step[0], p, cx, cy, r, ocx, ocy,
                               orad, cov) < 0;
    }
    SHIM_CATCH("rim")
    return -1;
}

extern "C" int shim_crop2_avx512(void)
{
    return crop2::uses_avx512();
}

extern "C" int shim_camera_prepare(pp_params *p, char *err)
{
    try {
        shim_camera_free(p);
        if (!p->cam.set || !p->cam.distorted) return 0;
        crop2::UndistortMap *m = new crop2::UndistortMap();
        crop2::undistort_map(&p->cam, p->cam.width, p->cam.height, m);
        p->undistort = m;
        return 0;
    }
    SHIM_CATCH("camera")
    return -1;
}

extern "C" void shim_camera_free(pp_params *p)
{
    delete static_cast<const crop2::UndistortMap *>(p->undistort);
    p->undistort = nullptr;
}

extern "C" int shim_preprocess(const pi_frame *f, const pp_params *p, float *out, pp_circle *circ,
                               char *err)
{
    pi_frame seen;
    return shim_preprocess_seen(f, p, out, circ, nullptr, &seen, err);
}

extern "C" int shim_preprocess_seen(const pi_frame *f, const pp_params *p, float *out,
                                    pp_circle *circ, shim_mat *keep, pi_frame *seen, char *err)
{
    try {
        *seen = *f;
        const int h = f->height, w = f->width, S = p->size;
        if (!f->data || h < 8 || w < 8 ||
            (f->channels != 1 && f->channels != 3 && f->channels != 4)) {
            seterr(err, "preprocess", "frame too small or not 1, 3 or 4 channels of 8 bits");
            return -1;
        }
        const cv::Mat bgr = bgr_of(f);
        if (p->version == 2) {
            cv::Mat local;
            cv::Mat *und = keep ? &keep->m : &local;
            if (preprocess_v2(bgr, p, out, circ, und, err) < 0) return -1;
            // the undistorted frame, when there is one: the circle lies in it
            if (p->undistort && keep) {
                const double decode_ms = f->decode_ms;
                frame_from_mat(*und, seen);
                seen->decode_ms = decode_ms;
            }
            return 0;
        }

        // 1. Background: per-channel median of the border band.
        const int mn = std::min(h, w);
        const int b = std::max(2, (int)std::floor(p->border_frac * mn + 0.5));
        unsigned long hist[3][256] = {{0}}, n = 0;
        const int bb = std::min(b, h / 2), bc = std::min(b, w / 2);
        add_rows(bgr, 0, bb, 0, w, hist, &n);
        add_rows(bgr, h - bb, h, 0, w, hist, &n);
        add_rows(bgr, bb, h - bb, 0, bc, hist, &n);
        add_rows(bgr, bb, h - bb, w - bc, w, hist, &n);
        double bg[3];
        for (int c = 0; c < 3; c++) bg[c] = hist_median(hist[c], n);

        // 2. Foreground: max_c |I_c - bg_c| > threshold, i.e. any channel
        //    outside the closed interval of values within the threshold.
        //    The interval ends come from the same comparison, evaluated for
        //    every 8-bit value (l > u: every pixel is foreground).
        int lo[3], hi[3];
        for (int c = 0; c < 3; c++) {
            int l = 256, u = -1;
            for (int v = 0; v < 256; v++) {
                if (!(std::fabs((double)v - bg[c]) > p->fg_threshold)) {
                    l = std::min(l, v);
                    u = v;
                }
            }
            lo[c] = l;
            hi[c] = u;
        }
        int fx0, fy0, fx1, fy1;
        if (!kern::fg_bbox(bgr.data, w, h, bgr.step[0], lo, hi, &fx0, &fy0, &fx1, &fy1)) {
            seterr(err, "preprocess", "no sphere found in frame");
            return -1;
        }

        // 3. Close with an elliptic kernel. Only around the foreground: a
        //    closing changes nothing farther than k from it, so the result
        //    (and everything after) equals closing the whole frame, at a
        //    fraction of the cost. Contours come back in frame coordinates.
        const int k = 2 * (int)std::floor(p->close_frac * mn / 2) + 1;
        const int bx0 = std::max(0, fx0 - k - 1), by0 = std::max(0, fy0 - k - 1);
        const int bx1 = std::min(w, fx1 + k + 2), by1 = std::min(h, fy1 + k + 2);
        cv::Mat closed(by1 - by0, bx1 - bx0, CV_8U);
        kern::fg_mask(bgr.data, bgr.step[0], bx0, by0, closed.cols, closed.rows, lo, hi,
                      closed.data);
        if (k > 1) {
            cv::Mat kernel = cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(k, k));
            if (!kern::close_binary(closed.data, closed.cols, closed.rows, kernel.data, k))
                cv::morphologyEx(closed, closed, cv::MORPH_CLOSE, kernel);
        }

        // 4. Largest external contour (first on ties).
        std::vector<std::vector<cv::Point>> contours;
        cv::findContours(closed, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE,
                         cv::Point(bx0, by0));
        int best = -1;
        double best_area = -1.0;
        for (size_t i = 0; i < contours.size(); i++) {
            double a = cv::contourArea(contours[i]);
            if (a > best_area) {
                best = (int)i;
                best_area = a;
            }
        }
        if (best < 0 || best_area < p->min_area_frac * h * w) {
            seterr(err, "preprocess", "no sphere found in frame");
            return -1;
        }

        // 5. Enclosing circle, of the contour's convex hull: the same circle,
        //    from a tenth of the points.
        std::vector<cv::Point> hull;
        cv::convexHull(contours[best], hull);
        cv::Point2f centre;
        float radius;
        cv::minEnclosingCircle(hull, centre, radius);
        const double cx = centre.x, cy = centre.y, r = radius;

        // 6. Square crop; outside the frame is bg. Equivalent to
        //    copyMakeBorder + ROI, without copying the whole frame.
        const double half = r * p->margin;
        const long x0 = (long)std::floor(cx - half + 0.5);
        const long y0 = (long)std::floor(cy - half + 0.5);
        const long side = std::max(1L, (long)std::floor(2 * half + 0.5));
        if (side > 65536) {
            seterr(err, "preprocess", "sphere too large");
            return -1;
        }
        cv::Scalar fill;
        for (int c = 0; c < 3; c++)
            fill[c] = std::min(255.0, std::max(0.0, std::floor(bg[c] + 0.5)));
        cv::Mat roi;
        const long ix0 = std::max(0L, x0), iy0 = std::max(0L, y0);
        const long ix1 = std::min((long)w, x0 + side), iy1 = std::min((long)h, y0 + side);
        if (x0 >= 0 && y0 >= 0 && ix1 == x0 + side && iy1 == y0 + side) {
            roi = bgr(cv::Rect((int)x0, (int)y0, (int)side, (int)side));
        } else {
            roi = cv::Mat((int)side, (int)side, CV_8UC3, fill);
            if (ix1 > ix0 && iy1 > iy0)
                bgr(cv::Rect((int)ix0, (int)iy0, (int)(ix1 - ix0), (int)(iy1 - iy0)))
                    .copyTo(roi(cv::Rect((int)(ix0 - x0), (int)(iy0 - y0), (int)(ix1 - ix0),
                                         (int)(iy1 - iy0))));
        }

        // 7. Resize.
        cv::Mat small(S, S, CV_8UC3);
        if (!kern::resize_area_c3(roi.data, (int)side, (int)side, roi.step[0], small.data, S, S,
                                  small.step[0]))
            cv::resize(roi, small, cv::Size(S, S), 0, 0, cv::INTER_AREA);

        // 8. Normalise.
        normalise(small.data, small.step[0], p, out);
        circ->cx = cx;
        circ->cy = cy;
        circ->r = r;
        for (int c = 0; c < 3; c++) circ->bg[c] = bg[c];
        return 0;
    }
    SHIM_CATCH("preprocess")
    return -1;
}

// Written under a temporary name beside path (its extension kept: imwrite picks
// the format by it), then renamed: a run killed mid-write leaves no half image
// under the frame's name.
extern "C" int shim_save(const pi_frame *f, const char *path, char *err)
{
    std::string tmp;
    try {
        size_t stride = f->stride ? f->stride : (size_t)f->width * f->channels;
        cv::Mat m(f->height, f->width, CV_8UC(f->channels), const_cast<uint8_t *>(f->data), stride);
        const char *dot = strrchr(path, '.');
        const char *slash = strrchr(path, '/');
        std::string ext = dot && (!slash || dot > slash) ? dot : "";
        tmp = std::string(path) + ".tmp" + std::to_string((long)getpid()) + ext;
        if (!cv::imwrite(tmp, m)) {
            unlink(tmp.c_str());
            pi_seterr(err, "%s: cannot write (unknown extension or unwritable path)", path);
            return -1;
        }
        if (rename(tmp.c_str(), path) != 0) {
            int e = errno;
            unlink(tmp.c_str());
            pi_seterr(err, "%s: cannot write: %s", path, strerror(e));
            return -1;
        }
        return 0;
    }
    SHIM_CATCH("imwrite")
    if (!tmp.empty()) unlink(tmp.c_str());
    return -1;
}

// ---- VideoCapture ------------------------------------------------------------

extern "C" shim_cap *shim_cap_open(const char *spec, char *err)
{
    shim_cap *c = nullptr;
    try {
        c = new shim_cap();
        c->spec = spec;
        bool ok;
        char *end = nullptr;
        long idx = strtol(spec, &end, 10);
        if (*spec && end && *end == '\0') {
            ok = c->cap.open((int)idx, cv::CAP_V4L2);
        } else if (strncmp(spec, "/dev/", 5) == 0) {
            ok = c->cap.open(std::string(spec), cv::CAP_V4L2);
        } else if (strncmp(spec, "gst:", 4) == 0) {
            ok = c->cap.open(std::string(spec + 4), cv::CAP_GSTREAMER);
        } else {
            seterr(err, "camera",
                   "unknown source; expected /dev/videoN, an index, gst:<pipeline> or unix:<path>");
            delete c;
            return nullptr;
        }
        if (!ok || !c->cap.isOpened()) {
            pi_seterr(err, "VideoCapture(%s): cannot open", spec);
            delete c;
            return nullptr;
        }
        return c;
    }
    SHIM_CATCH("VideoCapture")
    delete c;
    return nullptr;
}

extern "C" int shim_cap_grab(shim_cap *c, pi_frame *out, char *err)
{
    try {
        if (!c->cap.read(c->frame) || c->frame.empty()) {
            pi_seterr(err, "VideoCapture(%s): no frame", c->spec.c_str());
            return -1;
        }
        if (c->frame.depth() != CV_8U) c->frame.convertTo(c->frame, CV_8U);
        frame_from_mat(c->frame, out);
        return 0;
    }
    SHIM_CATCH("VideoCapture.read")
    return -1;
}

extern "C" void shim_cap_close(shim_cap *c)
{
    delete c;
}
