// Unit tests: sphere-crop-v2 in C++ (host/libposeinfer/crop2.cpp, pp_v2.c) on
// synthetic frames drawn with OpenCV: the circle with a post and clutter,
// the errors, the crop's mask, the undistortion map, the parameter and
// camera-file checks, the AVX-512 steps against their portable versions.
// (Bit-identity with the Python reference is tests/host/test_parity.py's.)
#include <cmath>
#include <csetjmp>
#include <cstdarg>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <unistd.h>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "crop2.h"
#include "json.h"
#include "shim.h"

extern "C" int pi_parse_preprocess(const char *text, pp_params *p, char *err, const char *model);

// last: cmocka defines macros (fail) that clash with the C++ headers
extern "C" {
#include <cmocka.h>
}

// The v2 defaults, as training/preprocess.py DEFAULTS_V2 writes them.
static const char *V2 =
    "{\"name\": \"sphere-crop-v2\", \"size\": 128, \"margin\": 1.15, \"mean\": [0.485, 0.456, "
    "0.406], "
    "\"std\": [0.229, 0.224, 0.225], \"r_min_frac\": 0.05, \"r_max_frac\": 0.5, \"r_tol\": 0.15, "
    "\"coarse_size\": 170, \"coarse_rbin\": 0.08, \"edge_min\": 24, \"candidates\": 4, "
    "\"cand_frac\": 0.35, \"cand_gap\": 0.25, "
    "\"rays\": 128, \"ray_edge_min\": 12, \"consensus_cells\": 4, \"consensus_px\": 4, "
    "\"consensus_step_px\": 2, "
    "\"consensus_reach\": 1.5, \"consensus_edge_ratio\": 2.0, \"fine_passes\": 3, "
    "\"fine_window_px\": 3, \"fine_window_frac\": 0.02, "
    "\"irls_iters\": 6, \"tukey_c\": 4.0, \"sigma_min_px\": 0.3, \"inlier_px\": 1.0, "
    "\"support_edge_min\": 8, "
    "\"support_ratio\": 2.5, \"support_flank_px\": 8, \"min_support\": 0.42, "
    "\"max_cut\": 0.15, \"mask_frac\": 0.02, \"fill\": [128, 128, 128]}";

static pp_params v2(void)
{
    pp_params p;
    char err[256];
    if (pi_parse_preprocess(V2, &p, err, "test.onnx") != 0) fail_msg("%s", err);
    return p;
}

// Clutter: rectangles and lines of random colours on a gradient.
static cv::Mat clutter(std::mt19937 &rng, int w, int h)
{
    std::uniform_int_distribution<int> u(0, 255);
    cv::Mat m(h, w, CV_8UC3);
    for (int y = 0; y < h; y++) m.row(y).setTo(cv::Scalar(60 + y * 80 / h, 70, 90 - y * 40 / h));
    for (int i = 0; i < 30; i++) {
        const cv::Scalar c(u(rng), u(rng), u(rng));
        const cv::Point a(u(rng) * w / 256, u(rng) * h / 256),
            b(u(rng) * w / 256, u(rng) * h / 256);
        if (i % 2)
            cv::rectangle(m, a, a + cv::Point(10 + u(rng) / 3, 10 + u(rng) / 4), c, cv::FILLED);
        else
            cv::line(m, a, b, c, 1 + u(rng) % 4, cv::LINE_AA);
    }
    return m;
}

// A textured, anti-aliased disc of centre (cx, cy) (pixel centres at
// integers) and radius r, drawn at 1/16 px.
static void disc(cv::Mat &m, double cx, double cy, double r, std::mt19937 &rng, int blobs = 10)
{
    std::uniform_int_distribution<int> u(0, 255);
    const int S = 16;
    cv::circle(m, cv::Point((int)std::lround(cx * S), (int)std::lround(cy * S)),
               (int)std::lround(r * S), cv::Scalar(200, 190, 170), cv::FILLED, cv::LINE_AA, 4);
    for (int i = 0; i < blobs; i++) {
        const double a = u(rng) / 256.0 * 6.283, d = u(rng) / 256.0 * r * 0.7;
        cv::circle(m, cv::Point((int)(cx + d * std::cos(a)), (int)(cy + d * std::sin(a))),
                   (int)(r * 0.12), cv::Scalar(u(rng) / 2, u(rng) / 2, u(rng) / 2), cv::FILLED,
                   cv::LINE_AA);
    }
}

static int find(const cv::Mat &m, const pp_params *p, double *cx, double *cy, double *r,
                std::string *why)
{
    char err[256] = "";
    const int rc = crop2::find_sphere(m.data, m.cols, m.rows, m.step[0], p, cx, cy, r, nullptr, err,
                                      sizeof err);
    *why = err;
    return rc;
}

static void circle_with_post_and_clutter(void **state)
{
    (void)state;
    const pp_params p = v2();
    std::mt19937 rng(3);
    const double cases[][4] = {
        {320.25, 250.5, 120.0, 90}, {180.0, 330.75, 95.5, 0}, {450.5, 160.0, 110.0, 225}};
    for (const auto &c : cases) {
        cv::Mat m = clutter(rng, 640, 512);
        // the post: from the centre outward, drawn before the sphere
        const double a = c[3] * M_PI / 180;
        cv::line(m, cv::Point((int)c[0], (int)c[1]),
                 cv::Point((int)(c[0] + 900 * std::cos(a)), (int)(c[1] + 900 * std::sin(a))),
                 cv::Scalar(40, 45, 50), (int)(c[2] * 0.4), cv::LINE_AA);
        disc(m, c[0], c[1], c[2], rng);
        double cx, cy, r;
        std::string why;
        assert_int_equal(find(m, &p, &cx, &cy, &r, &why), 0);
        assert_true(std::hypot(cx - c[0], cy - c[1]) < 0.5);
        assert_true(std::fabs(r - (c[2] + 0.5)) <
                    0.3); // cv::circle's anti-aliased edge lies at r + 0.5
    }
}

// The steps written with AVX-512 intrinsics (crop2.cpp) and their portable
// versions, which a processor without AVX-512 runs, give the same answers:
// every circle to the bit, every error the same text. Frames of several
// sizes (widths not a multiple of 16, a stride wider than the row), with a
// post, clutter, noise, a faint rim, and the three errors.
static void avx512_and_portable_agree(void **state)
{
    (void)state;
    const pp_params p = v2();
    if (!crop2::set_avx512(1)) {
        crop2::set_avx512(-1);
        skip(); // only the portable versions here: the other tests run them
    }
    std::mt19937 rng(5);
    std::vector<cv::Mat> frames;
    // {width, height, cx, cy, r, post angle (deg; < 0 none), noise sd, rim contrast}
    const double cases[][8] = {
        {640, 512, 320.25, 250.5, 120.0, 90, 0, 1},
        {517, 389, 260.5, 190.25, 95.0, 30, 6, 1},
        {800, 600, 410.75, 300.5, 150.0, 200, 0, 1},
        {1280, 1024, 655.5, 500.0, 260.0, 300, 10, 1},
        {1023, 767, 500.0, 383.5, 180.0, -1, 25, 1},
        {640, 512, 300.0, 260.0, 110.0, 135, 4, 0.25},
        {733, 541, 380.25, 270.75, 130.5, 45, 14, 0.5},
        {640, 480, 160.0, 240.0, 100.0, 270, 3, 1},
    };
    for (const auto &c : cases) {
        const int w = (int)c[0], h = (int)c[1];
        cv::Mat m = clutter(rng, w, h);
        if (c[5] >= 0) {
            const double a = c[5] * M_PI / 180;
            cv::line(
                m, cv::Point((int)c[2], (int)c[3]),
                cv::Point((int)(c[2] + 2 * w * std::cos(a)), (int)(c[3] + 2 * w * std::sin(a))),
                cv::Scalar(40, 45, 50), (int)(c[4] * 0.4), cv::LINE_AA);
        }
        cv::Mat d = m.clone();
        disc(d, c[2], c[3], c[4], rng);
        cv::addWeighted(d, c[7], m, 1 - c[7], 0, m); // a faint rim: the disc blended in
        if (c[6] > 0) {
            cv::Mat n(h, w, CV_16SC3);
            cv::randn(n, 0, c[6]);
            cv::Mat s16;
            m.convertTo(s16, CV_16SC3);
            s16 += n;
            s16.convertTo(m, CV_8UC3); // saturated
        }
        frames.push_back(m);
    }
    // a stride wider than the row: the frame inside a larger one
    cv::Mat big = clutter(rng, 700, 540);
    disc(big, 380, 270, 115, rng);
    frames.push_back(big(cv::Rect(37, 11, 611, 497)));
    // the errors: none, two, cut
    frames.push_back(cv::Mat(512, 640, CV_8UC3, cv::Scalar(90, 90, 90)));
    cv::Mat two = clutter(rng, 640, 512);
    disc(two, 170, 250, 100, rng);
    disc(two, 470, 260, 104, rng);
    frames.push_back(two);
    cv::Mat cut = clutter(rng, 640, 512);
    disc(cut, 639 - 120 * std::cos(M_PI / 4), 250, 120, rng);
    frames.push_back(cut);
    int found = 0;
    for (size_t i = 0; i < frames.size(); i++) {
        double a[3], b[3];
        std::string why_a, why_b;
        crop2::set_avx512(1);
        const int rc_a = find(frames[i], &p, &a[0], &a[1], &a[2], &why_a);
        crop2::set_avx512(0);
        assert_non_null(strstr(pi_cpu_paths(), "localisation portable")); // what the bench reports
        const int rc_b = find(frames[i], &p, &b[0], &b[1], &b[2], &why_b);
        crop2::set_avx512(-1);
        if (rc_a != rc_b || (rc_a == 0 && memcmp(a, b, sizeof a) != 0) || why_a != why_b)
            fail_msg("frame %zu: AVX-512 %d (%.17g, %.17g, %.17g) \"%s\", portable %d (%.17g, "
                     "%.17g, %.17g) \"%s\"",
                     i, rc_a, a[0], a[1], a[2], why_a.c_str(), rc_b, b[0], b[1], b[2],
                     why_b.c_str());
        found += rc_a == 0;
    }
    assert_true(found >= 8); // most frames have a circle to compare
}

static void clear_errors(void **state)
{
    (void)state;
    const pp_params p = v2();
    std::mt19937 rng(4);
    double cx, cy, r;
    std::string why;
    cv::Mat flat(512, 640, CV_8UC3, cv::Scalar(90, 90, 90));
    assert_int_equal(find(flat, &p, &cx, &cy, &r, &why), -1);
    assert_string_equal(why.c_str(), "no sphere found in frame");
    cv::Mat two = clutter(rng, 640, 512);
    disc(two, 170, 250, 100, rng);
    disc(two, 470, 260, 104, rng);
    assert_int_equal(find(two, &p, &cx, &cy, &r, &why), -1);
    assert_true(why.rfind("two spheres in frame (circles at (", 0) == 0);
    cv::Mat cut = clutter(rng, 640, 512);
    // a quarter of the rim outside; blobs enough for a printed texture's bands (cut_texture)
    disc(cut, 639 - 120 * std::cos(M_PI / 4), 250, 120, rng, 40);
    assert_int_equal(find(cut, &p, &cx, &cy, &r, &why), -1);
    assert_true(why.rfind("sphere cut by the frame edge (25 % of its rim outside the frame", 0) ==
                0);
}

// The AVX-512 steps and their portable versions step by step (see
// avx512_and_portable_agree): one row's coarse edges and a ray's step peaks
// on random rows of every width (score count) 1 to 80, so that each width's
// last block (masked loads, whole stores) is reached; whole frames leave
// most of them out, and a lost edge or peak need not move a circle.
static void avx512_steps_agree(void **state)
{
    (void)state;
    if (!crop2::set_avx512(1)) {
        crop2::set_avx512(-1);
        skip();
    }
    std::mt19937 rng(11);
    for (int rep = 0; rep < 40; rep++)
        for (int w = 1; w <= 80; w++) {
            const size_t P = (size_t)w + 2;
            std::vector<int32_t> M(3 * P), gx((size_t)w), gy((size_t)w);
            for (auto &v : M) v = (int32_t)(rng() % 50);
            for (size_t r = 0; r < 3; r++) M[r * P] = M[r * P + P - 1] = 0;
            for (auto &v : gx) v = (int32_t)(rng() % 21) - 10;
            for (auto &v : gy) v = (int32_t)(rng() % 21) - 10;
            const int32_t tmin = (int32_t)(rng() % 30) - 2;
            std::vector<double> score((size_t)w);
            for (auto &v : score) v = (double)(rng() % 8);
            const double thr = (double)(rng() % 6) - 0.5;
            std::vector<int32_t> e[2], k[2];
            for (int on = 1; on >= 0; on--) {
                crop2::set_avx512(on);
                e[on] = crop2::row_edges_of(&M[1], &M[P + 1], &M[2 * P + 1], gx.data(), gy.data(),
                                            w, tmin);
                k[on] = crop2::peaks_of(score.data(), w, thr);
            }
            crop2::set_avx512(-1);
            if (e[0] != e[1] || k[0] != k[1])
                fail_msg("width %d, round %d: edges %zu / %zu values, peaks %zu / %zu (AVX-512 / "
                         "portable)",
                         w, rep, e[1].size(), e[0].size(), k[1].size(), k[0].size());
        }
}

static void crop_keeps_only_the_circle(void **state)
{
    (void)state;
    const pp_params p = v2();
    cv::Mat m(512, 640, CV_8UC3, cv::Scalar(10, 250, 10));
    const int S = p.size;
    std::vector<uint8_t> out((size_t)S * S * 3);
    crop2::crop(m.data, m.cols, m.rows, m.step[0], 320.0, 256.0, 100.0, &p, out.data());
    // the kept disc spans S / (2 margin) (1 + mask_frac) output pixels of radius
    const double keep = S / 2.0 / p.margin * (1 + p.mask_frac);
    int inside = 0;
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++) {
            const uint8_t *q = &out[3 * ((size_t)y * S + x)];
            const double d = std::hypot(x + 0.5 - S / 2.0, y + 0.5 - S / 2.0);
            const bool filled = q[0] == 128 && q[1] == 128 && q[2] == 128;
            if (d > keep + 1) assert_true(filled);
            if (d < keep - 1) {
                assert_false(filled);
                inside++;
            }
        }
    assert_true(inside > 0);
}

static void undistortion_map(void **state)
{
    (void)state;
    pp_camera cam;
    memset(&cam, 0, sizeof cam);
    cam.set = 1;
    cam.width = 64;
    cam.height = 48;
    cam.focal_mm = 16;
    cam.pixel_mm = 0.0096;
    crop2::UndistortMap m;
    crop2::undistort_map(&cam, 64, 48, &m); // no distortion: the identity, in 1/32 px
    for (int y = 0; y < 48; y++)
        for (int x = 0; x < 64; x++) {
            assert_int_equal(m.mx[(size_t)y * 64 + x], 32 * x);
            assert_int_equal(m.my[(size_t)y * 64 + x], 32 * y);
        }
    cv::Mat f(48, 64, CV_8UC3), g(48, 64, CV_8UC3);
    cv::randu(f, 0, 256);
    crop2::remap(f.data, f.step[0], m, g.data);
    assert_int_equal(cv::norm(f, g, cv::NORM_INF), 0);
    // barrel distortion: the centre stays, a corner reads from farther in
    cam.distortion[0] = -0.3;
    cam.has_principal = 1;
    cam.principal[0] = 32;
    cam.principal[1] = 24;
    crop2::undistort_map(&cam, 64, 48, &m);
    assert_true(std::llabs(m.mx[(size_t)24 * 64 + 32] - 32 * 32) <= 1);
}

static void ray_directions(void **state)
{
    (void)state;
    const std::vector<double> d = crop2::ray_dirs(128);
    for (int k = 0; k < 128; k++) {
        const double a = 2 * M_PI * k / 128;
        assert_true(std::fabs(d[2 * (size_t)k] - std::cos(a)) < 1e-14);
        assert_true(std::fabs(d[2 * (size_t)k + 1] - std::sin(a)) < 1e-14);
    }
}

static void parameters_name_what_is_wrong(void **state)
{
    (void)state;
    pp_params p;
    char err[256];
    std::string t(V2);
    // a missing key
    std::string miss = t;
    miss.replace(miss.find("\"rays\": 128, "), strlen("\"rays\": 128, "), "");
    assert_int_equal(pi_parse_preprocess(miss.c_str(), &p, err, "m.onnx"), -1);
    assert_non_null(strstr(err, "\"rays\""));
    // an unknown key, a value out of range, rays not a multiple of 8
    std::string extra = t;
    extra.insert(1, "\"sharpen\": 1, ");
    assert_int_equal(pi_parse_preprocess(extra.c_str(), &p, err, "m.onnx"), -1);
    assert_non_null(strstr(err, "unknown sphere-crop-v2 key \"sharpen\""));
    std::string bad = t;
    bad.replace(bad.find("\"min_support\": 0.42"), strlen("\"min_support\": 0.42"),
                "\"min_support\": 2");
    assert_int_equal(pi_parse_preprocess(bad.c_str(), &p, err, "m.onnx"), -1);
    assert_non_null(strstr(err, "\"min_support\""));
    std::string r12 = t;
    r12.replace(r12.find("\"rays\": 128"), strlen("\"rays\": 128"), "\"rays\": 100");
    assert_int_equal(pi_parse_preprocess(r12.c_str(), &p, err, "m.onnx"), -1);
    assert_non_null(strstr(err, "multiple of 8"));
    assert_int_equal(pi_parse_preprocess(V2, &p, err, "m.onnx"), 0);
    assert_int_equal(p.version, 2);
    assert_int_equal(p.rays, 128);
    assert_true(p.consensus_reach == 1.5 && p.fill[2] == 128);
}

static int write_file(const char *path, const char *text)
{
    FILE *f = fopen(path, "w");
    if (!f) return -1;
    fputs(text, f);
    return fclose(f);
}

static void camera_file(void **state)
{
    (void)state;
    char path[] = "/tmp/test_crop2_camXXXXXX";
    const int fd = mkstemp(path);
    assert_true(fd >= 0);
    close(fd);
    pp_camera cam;
    char err[256];
    assert_int_equal(write_file(path,
                                "{\"width\": 800, \"height\": 600, \"principal_px\": [401, 299.5], "
                                "\"distortion\": [-0.1, 0.02, 0, 0, 0]}"),
                     0);
    assert_int_equal(pp_camera_load(path, &cam, err), 0);
    assert_true(cam.set && cam.width == 800 && cam.has_principal && cam.principal[1] == 299.5 &&
                cam.distorted);
    assert_true(cam.focal_mm == 16.0 &&
                cam.distance_mm == 250.0); // missing keys: the reference camera
    const char *bad[][2] = {{"{\"focal\": 16}", "unknown key \"focal\""},
                            {"{\"distortion\": [0.1]}", "\"distortion\" must be a list of 5"},
                            {"{\"width\": 640.5}", "\"width\" must be a whole number"},
                            {"{\"distance_mm\": 20}", "\"distance_mm\" (20) must exceed"},
                            {"[1, 2]", "expected a JSON object"},
                            {"{\"width\": ", "camera file"},
                            {"{\"distortion\": [-5.0, 0, 0, 0, 0]}", "fold the image over"},
                            {"{\"distortion\": [0, 0, 0.2, 0, 0]}", "tangential terms"}};
    for (const auto &b : bad) {
        assert_int_equal(write_file(path, b[0]), 0);
        assert_int_equal(pp_camera_load(path, &cam, err), -1);
        assert_non_null(strstr(err, b[1]));
        assert_non_null(strstr(err, path));
    }
    unlink(path);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(circle_with_post_and_clutter),
        cmocka_unit_test(clear_errors),
        cmocka_unit_test(avx512_and_portable_agree),
        cmocka_unit_test(avx512_steps_agree),
        cmocka_unit_test(crop_keeps_only_the_circle),
        cmocka_unit_test(undistortion_map),
        cmocka_unit_test(ray_directions),
        cmocka_unit_test(parameters_name_what_is_wrong),
        cmocka_unit_test(camera_file),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
