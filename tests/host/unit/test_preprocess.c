/* Unit tests: the preprocessing shim (sphere-crop-v1), header probing, the
 * metadata parameters, and the library's argument checks. */
#define _GNU_SOURCE
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "internal.h"
#include "poseinfer.h"
#include "shim.h"

/* A w x h BGR frame of colour bg with a filled disc of colour fg. */
static uint8_t *disc_frame(int w, int h, double cx, double cy, double r, const uint8_t bg[3],
                           const uint8_t fg[3])
{
    uint8_t *p = malloc((size_t)w * h * 3);
    assert_non_null(p);
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            int in = (x + 0.5 - cx) * (x + 0.5 - cx) + (y + 0.5 - cy) * (y + 0.5 - cy) <= r * r;
            memcpy(p + ((size_t)y * w + x) * 3, in ? fg : bg, 3);
        }
    return p;
}

static const uint8_t BG[3] = {40, 50, 60}, FG[3] = {200, 120, 30};

/* A sphere-crop-v1 parameter set as an export writes it: every key
 * (training/preprocess.py DEFAULTS_V1; the C side has no defaults). */
#define V1_KEYS(X)                                                           \
    X("size", "128")                                                         \
    X("margin", "1.15")                                                      \
    X("fg_threshold", "40") X("border_frac", "0.02") X("close_frac", "0.03") \
        X("min_area_frac", "0.002") X("mean", "[0.485, 0.456, 0.406]")       \
            X("std", "[0.229, 0.224, 0.225]")
#define V1_JSON_KEY(k, v) ", \"" k "\": " v
static const char V1_FULL[] = "{\"name\": \"sphere-crop-v1\"" V1_KEYS(V1_JSON_KEY) "}";

static void v1_params(pp_params *p)
{
    char err[PI_ERR_LEN];
    assert_int_equal(pi_parse_preprocess(V1_FULL, p, err, "m.onnx"), 0);
}

static void finds_the_disc(void **state)
{
    pp_params p;
    pp_circle c;
    char err[PI_ERR_LEN];
    float *out;
    (void)state;
    v1_params(&p);
    out = malloc(sizeof(float) * 3 * p.size * p.size);
    uint8_t *img = disc_frame(640, 480, 300, 200, 100, BG, FG);
    pi_frame f = {img, 640, 480, 3, 0, 0};
    assert_int_equal(shim_preprocess(&f, &p, out, &c, err), 0);
    assert_true(fabs(c.cx - 300) < 1.5 && fabs(c.cy - 200) < 1.5 && fabs(c.r - 100) < 2);
    assert_true(c.bg[0] == 40 && c.bg[1] == 50 && c.bg[2] == 60);
    /* the centre of the crop is the disc colour, normalised: R channel first */
    int S = p.size, mid = S / 2 * S + S / 2;
    float want_r = ((float)FG[2] / 255.0f - p.mean[0]) / p.std[0];
    float want_b = ((float)FG[0] / 255.0f - p.mean[2]) / p.std[2];
    assert_true(fabs(out[mid] - want_r) < 1e-6);
    assert_true(fabs(out[2 * S * S + mid] - want_b) < 1e-6);
    /* the corner is background */
    float bg_g = ((float)BG[1] / 255.0f - p.mean[1]) / p.std[1];
    assert_true(fabs(out[S * S] - bg_g) < 1e-6);
    free(img);
    free(out);
}

static void disc_partly_outside_fills_with_background(void **state)
{
    pp_params p;
    pp_circle c;
    char err[PI_ERR_LEN];
    (void)state;
    v1_params(&p);
    float *out = malloc(sizeof(float) * 3 * p.size * p.size);
    uint8_t *img = disc_frame(320, 240, 10, 20, 60, BG, FG);
    pi_frame f = {img, 320, 240, 3, 0, 0};
    assert_int_equal(shim_preprocess(&f, &p, out, &c, err), 0);
    float bg_r = ((float)BG[2] / 255.0f - p.mean[0]) / p.std[0];
    assert_true(fabs(out[0] - bg_r) < 1e-6); /* top-left of the crop lies outside the frame */
    free(img);
    free(out);
}

static void stride_and_channels(void **state)
{
    pp_params p;
    pp_circle c1, c2;
    char err[PI_ERR_LEN];
    (void)state;
    v1_params(&p);
    size_t n = (size_t)3 * p.size * p.size;
    float *a = malloc(n * sizeof(float)), *b = malloc(n * sizeof(float));
    uint8_t *img = disc_frame(200, 150, 90, 80, 40, BG, FG);
    /* the same frame with 16 bytes of padding per row */
    size_t stride = 200 * 3 + 16;
    uint8_t *padded = calloc(150, stride);
    for (int y = 0; y < 150; y++) memcpy(padded + y * stride, img + (size_t)y * 600, 600);
    pi_frame f1 = {img, 200, 150, 3, 0, 0}, f2 = {padded, 200, 150, 3, stride, 0};
    assert_int_equal(shim_preprocess(&f1, &p, a, &c1, err), 0);
    assert_int_equal(shim_preprocess(&f2, &p, b, &c2, err), 0);
    assert_memory_equal(a, b, n * sizeof(float));
    pi_frame bad = {img, 200, 150, 2, 0, 0};
    assert_int_equal(shim_preprocess(&bad, &p, a, &c1, err), -1);
    pi_frame tiny = {img, 4, 4, 3, 0, 0};
    assert_int_equal(shim_preprocess(&tiny, &p, a, &c1, err), -1);
    free(a);
    free(b);
    free(img);
    free(padded);
}

static void no_sphere(void **state)
{
    pp_params p;
    pp_circle c;
    char err[PI_ERR_LEN];
    (void)state;
    v1_params(&p);
    float *out = malloc(sizeof(float) * 3 * p.size * p.size);
    uint8_t *img = disc_frame(320, 240, 100, 100, 0, BG, FG);
    pi_frame f = {img, 320, 240, 3, 0, 0};
    assert_int_equal(shim_preprocess(&f, &p, out, &c, err), -1);
    assert_string_equal(err, "preprocess: no sphere found in frame");
    free(img);
    /* a speck below min_area_frac is no sphere either */
    img = disc_frame(320, 240, 100, 100, 3, BG, FG);
    f.data = img;
    assert_int_equal(shim_preprocess(&f, &p, out, &c, err), -1);
    free(img);
    free(out);
}

static void probes_headers(void **state)
{
    unsigned char png[24] = {0x89, 'P', 'N', 'G', 0x0d, 0x0a, 0x1a, 0x0a, 0, 0, 0,    13,
                             'I',  'H', 'D', 'R', 0,    0,    0x0a, 0x00, 0, 0, 0x05, 0x00};
    unsigned char bmp[26] = {'B', 'M'};
    unsigned char jpg_trunc[16] = {0xff, 0xd8, 0xff, 0xe0, 0, 16};
    long w = 0, h = 0;
    char err[PI_ERR_LEN];
    (void)state;
    assert_int_equal(shim_probe_size(png, sizeof png, &w, &h, err), 0);
    assert_int_equal(w, 2560);
    assert_int_equal(h, 1280);
    assert_int_equal(shim_probe_size(png, 20, &w, &h, err), -1);
    bmp[18] = 0x40;
    bmp[22] = 0xff;
    bmp[23] = 0xff;
    bmp[24] = 0xff;
    bmp[25] = 0xff; /* height -1: top-down */
    assert_int_equal(shim_probe_size(bmp, sizeof bmp, &w, &h, err), 0);
    assert_int_equal(w, 64);
    assert_int_equal(h, 1);
    assert_int_equal(shim_probe_size(jpg_trunc, sizeof jpg_trunc, &w, &h, err), -1);
    assert_non_null(strstr(err, "truncated JPEG"));
    assert_int_equal(
        shim_probe_size((const unsigned char *)"P6\n# c\n 30 20\n255\n", 19, &w, &h, err), 0);
    assert_int_equal(w, 30);
    assert_int_equal(h, 20);
    assert_int_equal(shim_probe_size((const unsigned char *)"GIF89a", 6, &w, &h, err), 1);
}

static void decode_refuses_garbage_and_huge(void **state)
{
    shim_mat *m = shim_mat_new();
    pi_frame f;
    char err[PI_ERR_LEN];
    unsigned char png[24] = {0x89, 'P', 'N', 'G', 0x0d, 0x0a, 0x1a, 0x0a, 0, 0, 0, 13,
                             'I',  'H', 'D', 'R', 0,    1,    0,    0,    0, 1, 0, 0};
    (void)state;
    assert_int_equal(shim_decode(m, "hello", 5, PI_DEFAULT_MAX_PIXELS, &f, err), -1);
    assert_non_null(strstr(err, "cannot decode"));
    assert_int_equal(shim_decode(m, "", 0, PI_DEFAULT_MAX_PIXELS, &f, err), -1);
    assert_int_equal(shim_decode(m, png, sizeof png, PI_DEFAULT_MAX_PIXELS, &f, err), -1);
    assert_non_null(strstr(err, "65536x65536"));
    shim_mat_free(m);
}

static void roundtrip_through_save_and_decode(void **state)
{
    char err[PI_ERR_LEN], path[] = "/tmp/pi_unit_XXXXXX.png";
    unsigned char *buf = NULL;
    size_t cap = 0, len = 0;
    shim_mat *m = shim_mat_new();
    pi_frame g;
    (void)state;
    uint8_t *img = disc_frame(64, 48, 30, 20, 10, BG, FG);
    pi_frame f = {img, 64, 48, 3, 0, 0};
    int fd = mkstemps(path, 4);
    assert_true(fd >= 0);
    close(fd);
    assert_int_equal(pi_frame_save(&f, path, err), 0);
    assert_int_equal(pi_read_file(path, &buf, &cap, &len, err), 0);
    assert_int_equal(shim_decode(m, buf, len, PI_DEFAULT_MAX_PIXELS, &g, err), 0);
    assert_int_equal(g.width, 64);
    assert_int_equal(g.height, 48);
    assert_int_equal(g.channels, 3);
    for (int y = 0; y < 48; y++)
        assert_memory_equal(g.data + y * g.stride, img + y * 64 * 3, 64 * 3);
    assert_int_equal(pi_read_file("/nonexistent.png", &buf, &cap, &len, err), -1);
    assert_non_null(strstr(err, "open(/nonexistent.png): No such file"));
    assert_int_equal(pi_read_file("/tmp", &buf, &cap, &len, err), -1);
    remove(path);
    free(buf);
    free(img);
    shim_mat_free(m);
}

static void preprocess_metadata(void **state)
{
    pp_params p;
    char err[PI_ERR_LEN];
    (void)state;
    assert_int_equal(pi_parse_preprocess(V1_FULL, &p, err, "m.onnx"), 0);
    assert_int_equal(p.version, 1);
    assert_int_equal(p.size, 128);
    assert_true(p.margin == 1.15 && p.fg_threshold == 40 && p.min_area_frac == 0.002);
    assert_true(p.mean[1] == 0.456f && p.std[2] == 0.225f);
    assert_int_equal(
        pi_parse_preprocess("{\"name\": \"sphere-crop-v1\", \"size\": 96, \"margin\": 1.15, "
                            "\"fg_threshold\": 25.5, \"border_frac\": 0.02, \"close_frac\": 0.03, "
                            "\"min_area_frac\": 0.002, \"mean\": [0, 0, 0], \"std\": [1, 1, 1]}",
                            &p, err, "m.onnx"),
        0);
    assert_int_equal(p.size, 96);
    assert_true(p.std[2] == 1.0f && p.fg_threshold == 25.5);
    static const char *bad[] = {"[]",
                                "{\"name\": \"other\"}",
                                "{\"size\": 96.5}",
                                "{\"size\": 0}",
                                "{\"std\": [1, 0, 1]}",
                                "{\"mean\": [1, 2]}",
                                "{\"margin\": \"big\"}",
                                "{",
                                NULL};
    for (int i = 0; bad[i]; i++) {
        assert_int_equal(pi_parse_preprocess(bad[i], &p, err, "m.onnx"), -1);
        assert_non_null(strstr(err, "pi_open(m.onnx): metadata spherepose.preprocess"));
    }
}

/* A v1 model whose metadata lacks a key is refused, naming it: the C side
 * fills no defaults (one source, training/preprocess.py). */
static void preprocess_metadata_v1_needs_every_key(void **state)
{
    static const char *keys[] = {
#define V1_NAME(k, v) k,
        V1_KEYS(V1_NAME)
#undef V1_NAME
    };
    pp_params p;
    char err[PI_ERR_LEN], want[64];
    (void)state;
    assert_int_equal(pi_parse_preprocess("{}", &p, err, "m.onnx"), -1);
    assert_string_equal(err,
                        "pi_open(m.onnx): metadata spherepose.preprocess: needs key \"name\" (the "
                        "preprocessing, \"sphere-crop-v1\" or \"sphere-crop-v2\")");
    for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++) {
        /* the full set less keys[i] */
        char json[512] = "{\"name\": \"sphere-crop-v1\"";
#define V1_ADD(k, v) \
    if (strcmp(k, keys[i])) strcat(json, V1_JSON_KEY(k, v));
        V1_KEYS(V1_ADD)
#undef V1_ADD
        strcat(json, "}");
        assert_int_equal(pi_parse_preprocess(json, &p, err, "m.onnx"), -1);
        snprintf(want, sizeof want, "sphere-crop-v1 needs key \"%s\"", keys[i]);
        assert_non_null(strstr(err, "pi_open(m.onnx): metadata spherepose.preprocess: "));
        assert_non_null(strstr(err, want));
    }
}

static void library_argument_checks(void **state)
{
    char err[PI_ERR_LEN];
    pi_options o;
    (void)state;
    pi_options_init(&o);
    assert_int_equal(o.warmup_runs, 1);
    assert_null(pi_open(NULL, NULL, err));
    assert_null(pi_open("/nonexistent/model.onnx", &o, err));
    assert_string_equal(err, "pi_open(/nonexistent/model.onnx): No such file or directory");
    assert_null(pi_open("/tmp", &o, err));
    assert_non_null(strstr(err, "not a regular file"));
    pi_close(NULL);
    assert_int_equal(pi_input_size(NULL), 0);
    assert_null(pi_metadata(NULL, "x"));
    assert_int_equal(pi_infer_file(NULL, "x.png", NULL, err), -1);
    assert_int_equal(pi_infer_memory(NULL, "x", 1, NULL, err), -1);
    uint8_t px[3] = {0, 0, 0};
    assert_int_equal(pi_infer_bgr(NULL, px, 1, 1, 0, NULL, err), -1);
    assert_int_equal(pi_infer_camera(NULL, NULL, NULL, err), -1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(finds_the_disc),
        cmocka_unit_test(disc_partly_outside_fills_with_background),
        cmocka_unit_test(stride_and_channels),
        cmocka_unit_test(no_sphere),
        cmocka_unit_test(probes_headers),
        cmocka_unit_test(decode_refuses_garbage_and_huge),
        cmocka_unit_test(roundtrip_through_save_and_decode),
        cmocka_unit_test(preprocess_metadata),
        cmocka_unit_test(preprocess_metadata_v1_needs_every_key),
        cmocka_unit_test(library_argument_checks),
    };
    return cmocka_run_group_tests_name("preprocess", tests, NULL, NULL);
}
