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
#include <fcntl.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmocka.h>

#include "access.h"
#include "config.h"
#include "internal.h"
#include "json.h"
#include "poseinfer.h"
#include "server.h"

static void reply_as(app *a, peer *p, const char *line, sbuf *out, const char *want_substr,
                     int want_rc)
{
    int rc;
    sb_reset(out);
    rc = proto_handle(a, p, line, out);
    if (rc == 3) { /* work for a worker: done here, as a worker would */
        assert_non_null(p->job);
        proto_run(a, a->ctx, p->job);
        sb_puts(out, p->job->out.buf);
        job_free(p->job);
        p->job = NULL;
        rc = 0;
    }
    assert_int_equal(rc, want_rc);
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

static void reply(app *a, const char *line, sbuf *out, const char *want_substr, int want_rc)
{
    peer me = {(long)geteuid(), 0, 0, NULL};
    reply_as(a, &me, line, out, want_substr, want_rc);
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

/* Who may ask for what: reload from the daemon's own uid only, the token
 * before anything else on TCP, frame sizes bounded. */
static void protocol_access_rules(void **state)
{
    pi_config cfg;
    app a;
    sbuf out;
    access_policy acc;
    peer other = {(long)geteuid() + 1, 0, 0, NULL}, tcp = {-1, 0, 0, NULL};
    (void)state;
    config_init(&cfg);
    cfg.model = strdup("/nonexistent/m.onnx");
    memset(&a, 0, sizeof a);
    memset(&acc, 0, sizeof acc);
    a.cfg = &cfg;
    sb_init(&out);
    reply_as(&a, &other, "reload", &out, "only the daemon's user", 0);
    reply_as(&a, &tcp, "reload", &out, "only the daemon's user", 0);
    reply_as(&a, NULL, "reload", &out, "only the daemon's user", 0);
    reply(&a, "reload", &out, "No such file", 0); /* the owner may: it tries */
    reply(&a, "frame", &out, "expected \\\"frame N\\\"", 1);
    reply(&a, "frame -5", &out, "expected", 1);
    reply(&a, "frame 0", &out, "outside 1..", 1);
    reply(&a, "frame 99999999999999", &out, "max_file_bytes", 1);
    peer p = {(long)geteuid(), 0, 0, NULL};
    sb_reset(&out);
    assert_int_equal(proto_handle(&a, &p, "frame 1000", &out), 2);
    assert_int_equal(p.want, 1000);
    reply(&a, "auth whatever", &out, "no token", 0);
    a.acc = &acc;
    acc.token = strdup("0123456789abcdef-secret");
    acc.token_len = strlen(acc.token);
    reply_as(&a, &tcp, "ping", &out, "auth required", 1);
    reply_as(&a, &tcp, "auth 0123456789abcdef-secreT", &out, "wrong token", 1);
    reply_as(&a, &tcp, "auth 0123456789abcdef-secre", &out, "wrong token", 1);
    reply_as(&a, &tcp, "auth 0123456789abcdef-secret", &out, "{\"auth\": true}", 0);
    assert_true(tcp.authed);
    reply_as(&a, &tcp, "ping", &out, "pong", 0);
    reply(&a, "ping", &out, "pong", 0); /* unix: clients need no token */
    reply(&a, "infer /etc/passwd", &out, "no model loaded", 0);
    access_free(&acc);
    sb_free(&out);
    config_free(&cfg);
}

/* `infer PATH` reads only beneath the allowed directories, whatever links
 * and ".." say; outside, existing or not, the same answer. */
static void allowed_directories(void **state)
{
    char root[] = "/tmp/pi_unit_allow_XXXXXX", p[512], err[PI_ERR_LEN];
    pi_config cfg;
    access_policy acc;
    int fd;
    (void)state;
    assert_non_null(mkdtemp(root));
    snprintf(p, sizeof p, "%s/ok", root);
    assert_int_equal(mkdir(p, 0700), 0);
    snprintf(p, sizeof p, "%s/ok/sub", root);
    assert_int_equal(mkdir(p, 0700), 0);
    snprintf(p, sizeof p, "%s/secret", root);
    assert_int_equal(mkdir(p, 0700), 0);
    snprintf(p, sizeof p, "%s/secret/s.png", root);
    close(creat(p, 0600));
    snprintf(p, sizeof p, "%s/ok/sub/a.png", root);
    close(creat(p, 0600));
    char target[512];
    snprintf(target, sizeof target, "%s/secret/s.png", root);
    snprintf(p, sizeof p, "%s/ok/link.png", root);
    assert_int_equal(symlink(target, p), 0);
    snprintf(p, sizeof p, "%s/ok/inside.png", root);
    assert_int_equal(symlink("sub/a.png", p), 0);

    config_init(&cfg);
    assert_int_equal(access_init(&acc, &cfg, err), 0);
    assert_int_equal(access_open(&acc, target, err), -1);
    assert_non_null(strstr(err, "reading files is off"));
    access_free(&acc);

    snprintf(p, sizeof p, "%s/ok", root);
    assert_int_equal(config_set(&cfg, "allow_dir", p, err), 0);
    assert_int_equal(config_set(&cfg, "allow_dir", "relative/dir", err), -1);
    assert_int_equal(access_init(&acc, &cfg, err), 0);
    snprintf(p, sizeof p, "%s/ok/sub/a.png", root);
    fd = access_open(&acc, p, err);
    assert_true(fd >= 0);
    close(fd);
    snprintf(p, sizeof p, "%s/ok//sub/../inside.png", root); /* a link that stays inside */
    fd = access_open(&acc, p, err);
    assert_true(fd >= 0);
    close(fd);
    const char *outside[] = {"/ok/link.png",     "/ok/../secret/s.png", "/secret/s.png",
                             "/secret/none.png", "/okay/x.png",         NULL};
    for (size_t i = 0; i < sizeof outside / sizeof *outside; i++) {
        if (outside[i])
            snprintf(p, sizeof p, "%s%s", root, outside[i]);
        else
            snprintf(p, sizeof p, "/etc/passwd");
        assert_int_equal(access_open(&acc, p, err), -1);
        if (!strstr(err, "not in an allowed directory")) fail_msg("%s: %s", p, err);
    }
    snprintf(p, sizeof p, "%s/ok/missing.png", root);
    assert_int_equal(access_open(&acc, p, err), -1);
    assert_non_null(strstr(err, "No such file"));
    assert_int_equal(access_open(&acc, "ok/sub/a.png", err), -1);
    assert_non_null(strstr(err, "absolute"));
    access_free(&acc);
    config_clear_allow_dirs(&cfg);
    assert_int_equal(config_set(&cfg, "allow_dir", "/nonexistent/dir", err), 0);
    assert_int_equal(access_init(&acc, &cfg, err), -1);
    assert_non_null(strstr(err, "allow_dir(/nonexistent/dir)"));
    config_free(&cfg);
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", root);
    assert_int_equal(system(cmd), 0);
}

static void token_file_rules(void **state)
{
    char path[] = "/tmp/pi_unit_token_XXXXXX", err[PI_ERR_LEN];
    int fd;
    char *t;
    (void)state;
    fd = mkstemp(path);
    assert_true(fd >= 0);
    assert_int_equal(write(fd, "short\n", 6), 6);
    assert_null(access_read_token(path, err));
    assert_non_null(strstr(err, "at least 16"));
    assert_int_equal(ftruncate(fd, 0), 0);
    assert_int_equal(pwrite(fd, "0123456789abcdefXYZ\nsecond line\n", 32, 0), 32);
    t = access_read_token(path, err);
    assert_non_null(t);
    assert_string_equal(t, "0123456789abcdefXYZ");
    free(t);
    assert_int_equal(fchmod(fd, 0644), 0);
    assert_null(access_read_token(path, err));
    assert_non_null(strstr(err, "readable by every user"));
    close(fd);
    unlink(path);
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
    assert_int_equal(server_listen("udp:1", NULL, err), -1);
    assert_int_equal(server_listen("tcp:localhost:80", NULL, err), -1);
    assert_non_null(strstr(err, "IPV4"));
    assert_int_equal(server_listen("tcp:127.0.0.1:99999", NULL, err), -1);
    assert_int_equal(server_listen("unix:", NULL, err), -1);
    int fd = server_listen("tcp:127.0.0.1:0", NULL, err);
    assert_true(fd >= 0);
    close(fd);
    fd = server_listen("tcp:127.0.0.2:0", NULL, err); /* all of 127/8 is loopback */
    assert_true(fd >= 0);
    close(fd);
    /* anything else only when the config says so, and then with a token */
    assert_int_equal(server_listen("tcp:0.0.0.0:0", NULL, err), -1);
    assert_non_null(strstr(err, "not a loopback address"));
    listen_opts remote = {0660, NULL, 1, 0};
    assert_int_equal(server_listen("tcp:0.0.0.0:0", &remote, err), -1);
    assert_non_null(strstr(err, "token_file"));
    remote.has_token = 1;
    fd = server_listen("tcp:0.0.0.0:0", &remote, err);
    assert_true(fd >= 0);
    close(fd);
}

/* The unix: socket gets the configured mode whatever the umask. */
static void unix_socket_mode_and_group(void **state)
{
    char path[64], spec[80], err[PI_ERR_LEN];
    struct stat st;
    mode_t old = umask(0);
    (void)state;
    snprintf(path, sizeof path, "/tmp/pi_unit_mode_%d.sock", (int)getpid());
    snprintf(spec, sizeof spec, "unix:%s", path);
    int fd = server_listen(spec, NULL, err);
    assert_true(fd >= 0);
    assert_int_equal(stat(path, &st), 0);
    assert_int_equal(st.st_mode & 07777, 0660);
    close(fd);
    unlink(path);
    char gid[16];
    snprintf(gid, sizeof gid, "%d", (int)getegid());
    listen_opts o = {0600, gid, 0, 0};
    fd = server_listen(spec, &o, err);
    assert_true(fd >= 0);
    assert_int_equal(stat(path, &st), 0);
    assert_int_equal(st.st_mode & 07777, 0600);
    assert_int_equal(st.st_gid, getegid());
    close(fd);
    unlink(path);
    listen_opts bad = {0660, "no-such-group-here", 0, 0};
    assert_int_equal(server_listen(spec, &bad, err), -1);
    assert_non_null(strstr(err, "no group"));
    umask(old);
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
            if (replies[i][0] == '\0') {
                sleep(5);
                break;
            } /* silent */
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
        cmocka_unit_test(protocol_access_rules),
        cmocka_unit_test(allowed_directories),
        cmocka_unit_test(token_file_rules),
        cmocka_unit_test(listen_specs),
        cmocka_unit_test(unix_socket_mode_and_group),
        cmocka_unit_test(frame_server_client),
        cmocka_unit_test(frame_server_timeout_and_bad_size),
    };
    signal(SIGPIPE, SIG_IGN);
    return cmocka_run_group_tests_name("server", tests, NULL, NULL);
}
