/* Unit tests: config.c (key = value file, flags). */
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

#include "config.h"
#include "poseinfer.h"

static char *write_tmp(const char *text)
{
    static char path[64];
    FILE *f;
    int fd;
    strcpy(path, "/tmp/pi_config_XXXXXX");
    fd = mkstemp(path);
    assert_true(fd >= 0);
    f = fdopen(fd, "w");
    fputs(text, f);
    fclose(f);
    return path;
}

static void defaults_and_keys(void **state)
{
    pi_config c;
    char err[PI_ERR_LEN];
    (void)state;
    config_init(&c);
    assert_int_equal(c.threads, 1);
    assert_int_equal(c.warmup, 1);
    assert_int_equal(c.timeout_ms, 5000);
    assert_int_equal(config_set(&c, "model", "m.onnx", err), 0);
    assert_int_equal(config_set(&c, "model", "n.onnx", err), 0);
    assert_string_equal(c.model, "n.onnx");
    assert_int_equal(config_set(&c, "interval-ms", "250", err), 0); /* '-' is '_' */
    assert_int_equal(c.interval_ms, 250);
    assert_int_equal(config_set(&c, "continuous", "Yes", err), 0);
    assert_int_equal(c.continuous, 1);
    assert_int_equal(config_set(&c, "continuous", "off", err), 0);
    assert_int_equal(c.continuous, 0);
    assert_int_equal(config_set(&c, "threads", "0", err), -1);
    assert_non_null(strstr(err, "threads"));
    assert_int_equal(config_set(&c, "threads", "4x", err), -1);
    assert_int_equal(config_set(&c, "count", "-1", err), -1);
    assert_int_equal(config_set(&c, "continuous", "maybe", err), -1);
    assert_int_equal(config_set(&c, "colour", "red", err), -1);
    assert_non_null(strstr(err, "unknown key \"colour\""));
    config_free(&c);
}

/* The daemon's access keys: octal socket_mode, allow_dir repeatable and
 * absolute, tcp_remote a yes/no. */
static void access_keys(void **state)
{
    pi_config c;
    char err[PI_ERR_LEN];
    (void)state;
    config_init(&c);
    assert_int_equal(c.socket_mode, 0660);
    assert_int_equal(c.n_allow_dirs, 0);
    assert_int_equal(config_set(&c, "socket_mode", "0600", err), 0);
    assert_int_equal(c.socket_mode, 0600);
    assert_int_equal(config_set(&c, "socket-mode", "666", err), 0);
    assert_int_equal(c.socket_mode, 0666);
    assert_int_equal(config_set(&c, "socket_mode", "0888", err), -1);
    assert_non_null(strstr(err, "octal"));
    assert_int_equal(config_set(&c, "socket_mode", "01777", err), -1);
    assert_int_equal(config_set(&c, "allow_dir", "/data/a", err), 0);
    assert_int_equal(config_set(&c, "allow-dir", "/data/b", err), 0);
    assert_int_equal(c.n_allow_dirs, 2);
    assert_string_equal(c.allow_dirs[1], "/data/b");
    assert_int_equal(config_set(&c, "allow_dir", "data", err), -1);
    assert_non_null(strstr(err, "absolute"));
    config_clear_allow_dirs(&c);
    assert_int_equal(c.n_allow_dirs, 0);
    assert_int_equal(config_set(&c, "tcp_remote", "yes", err), 0);
    assert_int_equal(c.tcp_remote, 1);
    assert_int_equal(config_set(&c, "socket_group", "video", err), 0);
    assert_int_equal(config_set(&c, "token_file", "/etc/poseinfer.token", err), 0);
    assert_string_equal(c.token_file, "/etc/poseinfer.token");
    config_free(&c);
}

static void loads_file(void **state)
{
    pi_config c;
    char err[PI_ERR_LEN];
    char *p = write_tmp("# poseinfer\n\n  model = /srv/m.onnx  \nserve=unix:/run/pi.sock\n"
                        "camera = gst:videotestsrc ! appsink\nthreads = 2 # not a comment\n");
    (void)state;
    config_init(&c);
    /* '#' after a value is part of it: threads gets "2 # not a comment" */
    assert_int_equal(config_load(&c, p, err), -1);
    assert_non_null(strstr(err, ":6)"));
    unlink(p);
    p = write_tmp("# poseinfer\n\n  model = /srv/m.onnx  \nserve=unix:/run/pi.sock\n"
                  "camera = gst:videotestsrc ! appsink\nthreads = 2\r\n");
    assert_int_equal(config_load(&c, p, err), 0);
    assert_string_equal(c.model, "/srv/m.onnx");
    assert_string_equal(c.serve, "unix:/run/pi.sock");
    assert_string_equal(c.camera, "gst:videotestsrc ! appsink");
    assert_int_equal(c.threads, 2);
    unlink(p);
    config_free(&c);
}

static void file_errors_name_the_line(void **state)
{
    pi_config c;
    char err[PI_ERR_LEN];
    char *p = write_tmp("model = a\nnonsense line\n");
    (void)state;
    config_init(&c);
    assert_int_equal(config_load(&c, p, err), -1);
    assert_non_null(strstr(err, ":2)"));
    assert_non_null(strstr(err, "key = value"));
    unlink(p);
    assert_int_equal(config_load(&c, "/nonexistent/pi.conf", err), -1);
    assert_non_null(strstr(err, "No such file"));
    config_free(&c);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(defaults_and_keys),
        cmocka_unit_test(access_keys),
        cmocka_unit_test(loads_file),
        cmocka_unit_test(file_errors_name_the_line),
    };
    return cmocka_run_group_tests_name("config", tests, NULL, NULL);
}
