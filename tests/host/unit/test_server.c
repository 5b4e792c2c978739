/* Unit tests: the line protocol (server.c) without a model, and the unix:
 * frame-server client (camera.c) against a scripted server in a child. */
#define _GNU_SOURCE
#include <math.h>
#include <setjmp.h>
#include <signal.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmocka.h>

#include "config.h"
#include "internal.h"
#include "json.h"
#include "poseinfer.h"
#include "server.h"

static void reply(app *a, const char *line, sbuf *out, const char *want_substr, int want_rc)
{
    sb_reset(out);
    assert_int_equal(proto_handle(a, line, out), want_rc);
    assert_non_null(out->buf);
    if (!strstr(out->buf, want_substr)) fail_msg("reply to \"%s\" is %s", line, out->buf);
    assert_true(out->len > 0 && out->buf[out->len - 1] == '\n');
    /* every reply is one line of valid JSON */
    json_value v;
    char err[128];
    out->buf[out->len - 1] = '\0';
    assert_int_equal(json_parse(out->buf, &v, err, sizeof err), 0);
    assert_int_equal(v.type, JSON_OBJECT);
    json_free(&v);
}

static void protocol_without_model(void **state)
{
    pi_config cfg;
    app a;
    sbuf out;
    (void)state;
    config_init(&cfg);
    cfg.model = strdup("m \"1\".onnx");
    memset(&a, 0, sizeof a);
    a.cfg = &cfg;
    sb_init(&out);
    reply(&a, "ping", &out, "{\"pong\": true}", 0);
    reply(&a, "  ping  ", &out, "pong", 0);
    reply(&a, "", &out, "empty command", 0);
    reply(&a, "pingpong", &out, "unknown command \\\"pingpong\\\"", 0);
    reply(&a, "infer", &out, "expected a path", 0);
    reply(&a, "infer /x.png", &out, "no model loaded", 0);
    reply(&a, "grab", &out, "no camera", 0);
    reply(&a, "stats", &out, "\"requests\": 8", 0);
    reply(&a, "stats", &out, "\"ms_p50\": null", 0);
    reply(&a, "quit", &out, "bye", 1);
    sb_free(&out);
    config_free(&cfg);
}

static void percentiles(void **state)
{
    app a;
    (void)state;
    memset(&a, 0, sizeof a);
    assert_true(isnan(app_percentile(&a, 50)));
    for (int i = 1; i <= 100; i++) a.lat[a.nlat++] = i;
    assert_true(app_percentile(&a, 50) == 50);
    assert_true(app_percentile(&a, 99) == 99);
    assert_true(app_percentile(&a, 100) == 100);
}

static void listen_specs(void **state)
{
    char err[PI_ERR_LEN];
    (void)state;
    assert_int_equal(server_listen("udp:1", err), -1);
    assert_int_equal(server_listen("tcp:localhost:80", err), -1);
    assert_non_null(strstr(err, "IPV4"));
    assert_int_equal(server_listen("tcp:127.0.0.1:99999", err), -1);
    assert_int_equal(server_listen("unix:", err), -1);
    int fd = server_listen("tcp:127.0.0.1:0", err);
    assert_true(fd >= 0);
    close(fd);
}

/* A scripted frame server: answers each "grab" with the next reply. */
static pid_t serve_script(const char *path, const char *const *replies, int n)
{
    struct sockaddr_un sa;
    int ls = socket(AF_UNIX, SOCK_STREAM, 0);
    pid_t pid;
    memset(&sa, 0, sizeof sa);
    sa.sun_family = AF_UNIX;
    strcpy(sa.sun_path, path);
    unlink(path);
    assert_int_equal(bind(ls, (struct sockaddr *)&sa, sizeof sa), 0);
    assert_int_equal(listen(ls, 4), 0);
    pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        int c = accept(ls, NULL, NULL);
        char buf[64];
        for (int i = 0; i < n; i++) {
            ssize_t r = read(c, buf, sizeof buf);
            if (r <= 0) break;
            if (replies[i][0] == '\0') { sleep(5); break; } /* silent */
            if (write(c, replies[i], strlen(replies[i])) < 0) break;
        }
        _exit(0);
    }
    close(ls);
    return pid;
}

static void frame_server_client(void **state)
{
    char err[PI_ERR_LEN], path[64];
    pi_frame f;
    static const char *const replies[] = {"ERROR lens cap on\n", "FRAME 5\nhello", "NONSENSE\n"};
    (void)state;
    snprintf(path, sizeof path, "/tmp/pi_unit_cam_%d.sock", (int)getpid());
    pid_t pid = serve_script(path, replies, 3);
    char spec[80];
    snprintf(spec, sizeof spec, "unix:%s", path);
    pi_camera *cam = pi_camera_open(spec, 2000, err);
    assert_non_null(cam);
    assert_int_equal(pi_camera_grab(cam, &f, err), -1);
    assert_non_null(strstr(err, "lens cap on"));
    assert_int_equal(pi_camera_grab(cam, &f, err), -1); /* 5 bytes that are no image */
    assert_non_null(strstr(err, "cannot decode"));
    assert_int_equal(pi_camera_grab(cam, &f, err), -1);
    assert_non_null(strstr(err, "unexpected reply"));
    pi_camera_close(cam);
    waitpid(pid, NULL, 0);
    unlink(path);
}

static void frame_server_timeout_and_bad_size(void **state)
{
    char err[PI_ERR_LEN], path[64], spec[80];
    pi_frame f;
    static const char *const silent[] = {""};
    static const char *const huge[] = {"FRAME 99999999999\n"};
    (void)state;
    snprintf(path, sizeof path, "/tmp/pi_unit_cam2_%d.sock", (int)getpid());
    snprintf(spec, sizeof spec, "unix:%s", path);
    pid_t pid = serve_script(path, silent, 1);
    pi_camera *cam = pi_camera_open(spec, 200, err);
    assert_non_null(cam);
    double t0 = pi_now_ms();
    assert_int_equal(pi_camera_grab(cam, &f, err), -1);
    assert_non_null(strstr(err, "timed out"));
    assert_true(pi_now_ms() - t0 < 2000);
    pi_camera_close(cam);
    kill(pid, SIGKILL);
    waitpid(pid, NULL, 0);
    pid = serve_script(path, huge, 1);
    cam = pi_camera_open(spec, 2000, err);
    assert_non_null(cam);
    assert_int_equal(pi_camera_grab(cam, &f, err), -1);
    assert_non_null(strstr(err, "bad frame size"));
    pi_camera_close(cam);
    waitpid(pid, NULL, 0);
    unlink(path);
    assert_null(pi_camera_open(spec, 100, err)); /* nobody there */
    assert_non_null(strstr(err, "connect("));
    assert_null(pi_camera_open("", 100, err));
    assert_null(pi_camera_open("rtsp://cam", 100, err));
    assert_non_null(strstr(err, "unknown source"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(protocol_without_model),
        cmocka_unit_test(percentiles),
        cmocka_unit_test(listen_specs),
        cmocka_unit_test(frame_server_client),
        cmocka_unit_test(frame_server_timeout_and_bad_size),
    };
    signal(SIGPIPE, SIG_IGN);
    return cmocka_run_group_tests_name("server", tests, NULL, NULL);
}
