/* Unit test: the reference camera that pp_camera_load (pp_v2.c) gives a
 * camera file's missing keys is the one of the conventions' test vectors
 * (tests/data/conventions_vectors.json, "camera"), the one source of its
 * numbers (docs/conventions.md, "Camera"); sim/camera.py's REFERENCE is held
 * to the same file by tests/sim/test_reference_camera.py. */
#define _POSIX_C_SOURCE 200809L
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "json.h"
#include "poseinfer.h"
#include "shim.h"

/* The vectors file, found from this source file's path as the compiler saw
 * it (host/Makefile compiles ../tests/host/unit/test_camera_ref.c and runs
 * the test in host/). */
static void vectors_path(char *out, size_t len)
{
    const char *here = __FILE__, *cut = strstr(here, "host/unit/");
    assert_non_null(cut);
    snprintf(out, len, "%.*sdata/conventions_vectors.json", (int)(cut - here), here);
}

static char *slurp(const char *path)
{
    FILE *f = fopen(path, "rb");
    char *buf;
    long n;
    if (!f) fail_msg("%s: cannot open (the conventions' test vectors must be present)", path);
    assert_int_equal(fseek(f, 0, SEEK_END), 0);
    n = ftell(f);
    assert_true(n > 0);
    rewind(f);
    buf = malloc((size_t)n + 1);
    assert_non_null(buf);
    assert_int_equal(fread(buf, 1, (size_t)n, f), (size_t)n);
    buf[n] = '\0';
    fclose(f);
    return buf;
}

static void reference_camera_is_the_vectors(void **state)
{
    static const char *keys[] = {"width",    "height",      "focal_mm",
                                 "pixel_mm", "distance_mm", "sphere_diameter_mm"};
    char path[512], tmp[] = "/tmp/pi_camref_XXXXXX", err[PI_ERR_LEN], jerr[128];
    json_value root;
    const json_value *cam;
    pp_camera c;
    char *text;
    int fd;
    (void)state;

    /* An empty camera file: every key from the built-in reference camera. */
    fd = mkstemp(tmp);
    assert_true(fd >= 0);
    assert_int_equal(write(fd, "{}\n", 3), 3);
    close(fd);
    if (pp_camera_load(tmp, &c, err) < 0) fail_msg("%s", err);
    unlink(tmp);

    vectors_path(path, sizeof path);
    text = slurp(path);
    if (json_parse(text, &root, jerr, sizeof jerr) < 0) fail_msg("%s: %s", path, jerr);
    free(text);
    cam = json_get(&root, "camera");
    assert_non_null(cam);
    assert_int_equal(cam->type, JSON_OBJECT);
    /* The same keys on both sides: a key added to the vectors needs its default here. */
    assert_int_equal(cam->count, sizeof keys / sizeof keys[0]);
    const double got[] = {c.width,    c.height,      c.focal_mm,
                          c.pixel_mm, c.distance_mm, c.sphere_diameter_mm};
    for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++) {
        const json_value *v = json_get(cam, keys[i]);
        if (!v || v->type != JSON_NUMBER) fail_msg("%s: camera.%s missing", path, keys[i]);
        if (got[i] != v->number)
            fail_msg("reference camera %s: pp_v2.c %.17g, %s %.17g", keys[i], got[i], path,
                     v->number);
    }
    /* No calibration keys: the ideal pinhole camera, principal point at the centre. */
    assert_int_equal(c.has_principal, 0);
    assert_int_equal(c.distorted, 0);
    json_free(&root);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(reference_camera_is_the_vectors),
    };
    return cmocka_run_group_tests_name("camera_ref", tests, NULL, NULL);
}
