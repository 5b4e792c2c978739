/* The stage client (host/rig/stage.c) against a scripted fake GRBL on a pty
 * (tests/host/rig_fake.py): replies, errors, alarms, garbage, timeouts, a
 * vanished port, resets. Each test plays one script; the fake checks every
 * line the client sends and exits non-zero on a mismatch.
 * Environment: RIG_FAKE (path of rig_fake.py), RIG_PYTHON, RIG_TRACE=1 to
 * trace the traffic on stderr. */
#define _DEFAULT_SOURCE
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "stage.h"

#define BANNER "send Grbl 1.1h ['$' for help]\n"

typedef struct {
    pid_t pid;
    char pty[256];
    char script[64];
} fake;

static long long now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (long long)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

/* Start the fake on a script; fills f->pty. */
static void fake_start(fake *f, const char *script)
{
    const char *py = getenv("RIG_PYTHON"), *prog = getenv("RIG_FAKE");
    int fds[2], fd;
    char buf[240];
    size_t got = 0;
    long long deadline;

    if (!py) py = "python3";
    if (!prog) prog = "tests/host/rig_fake.py";
    snprintf(f->script, sizeof(f->script), "/tmp/rig_fake_XXXXXX");
    fd = mkstemp(f->script);
    assert_true(fd >= 0);
    assert_int_equal(write(fd, script, strlen(script)), (ssize_t)strlen(script));
    close(fd);
    assert_int_equal(pipe(fds), 0);
    f->pid = fork();
    assert_true(f->pid >= 0);
    if (f->pid == 0) {
        dup2(fds[1], 1);
        close(fds[0]);
        close(fds[1]);
        execlp(py, py, prog, f->script, (char *)NULL);
        _exit(127);
    }
    close(fds[1]);
    deadline = now_ms() + 10000;
    while (got < sizeof(buf) - 1 && !memchr(buf, '\n', got)) {
        struct pollfd p = {fds[0], POLLIN, 0};
        ssize_t n;
        assert_true(poll(&p, 1, (int)(deadline - now_ms())) == 1);
        n = read(fds[0], buf + got, sizeof(buf) - 1 - got);
        assert_true(n > 0);
        got += (size_t)n;
        buf[got] = '\0';
    }
    close(fds[0]);
    assert_int_equal(strncmp(buf, "PTY ", 4), 0);
    *strchr(buf, '\n') = '\0';
    snprintf(f->pty, sizeof(f->pty), "%s", buf + 4);
}

/* Stop the fake; its exit status (0: every expectation held, script done). */
static int fake_stop(fake *f)
{
    int st = 0;
    kill(f->pid, SIGTERM);
    waitpid(f->pid, &st, 0);
    unlink(f->script);
    return WIFEXITED(st) ? WEXITSTATUS(st) : 100 + WTERMSIG(st);
}

static void fast_opts(stage_opts *o)
{
    stage_opts_default(o);
    o->banner_timeout_ms = 600;
    o->reply_timeout_ms = 400;
    o->poll_ms = 20;
    o->move_timeout_ms = 2000;
    o->home_timeout_ms = 2000;
    if (getenv("RIG_TRACE")) o->log = stderr;
}

static void open_ok(stage *s, fake *f, const char *script)
{
    stage_opts o;
    char err[RIG_ERR_LEN];
    fast_opts(&o);
    fake_start(f, script);
    if (stage_open(s, f->pty, &o, err) != 0) fail_msg("stage_open: %s", err);
    /* A pty is not a port libserialport 0.1.1 opens: the termios path. */
    assert_true(s->via_termios);
}

static void test_open_settings(void **state)
{
    fake f;
    stage s;
    stage_setting set[8];
    char err[RIG_ERR_LEN];
    int n = 0;
    (void)state;
    open_ok(&s, &f,
            BANNER "polls 1\n"
                   "expect $$\n"
                   "send $0=10\nsend $100=800.000\nsend $110=720.000 (x max rate)\nsend ok\n"
                   "expect $101=812.5\nsend ok\nend\n");
    assert_string_equal(s.banner, "Grbl 1.1h ['$' for help]");
    assert_int_equal(s.defaults_restored, 0);
    assert_int_equal(stage_get_settings(&s, set, 8, &n, err), 0);
    assert_int_equal(n, 3);
    assert_int_equal(set[1].n, 100);
    assert_float_equal(set[1].value, 800.0, 1e-9);
    assert_float_equal(set[2].value, 720.0, 1e-9);
    assert_int_equal(stage_set_setting(&s, 101, 812.5, err), 0);
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_move_wait_idle(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN];
    double xyz[3] = {10, -5.5, 0.125};
    (void)state;
    open_ok(&s, &f,
            BANNER "polls 1\n"
                   "expect G90 G0 X10 Y-5.5 Z0.125\nsend ok\n"
                   "expect G4 P0\nstate <Run|MPos:4.000,-2.000,0.050|FS:720,0>\nsend ok\n"
                   "polls 2\nstate <Idle|MPos:10.000,-5.500,0.125|FS:0,0>\npolls 1\nend\n");
    if (stage_move_wait(&s, xyz, 0, err) != 0) fail_msg("%s", err);
    assert_string_equal(s.last.state, "Idle");
    assert_float_equal(s.last.mpos[0], 10.0, 1e-9);
    assert_float_equal(s.last.mpos[1], -5.5, 1e-9);
    assert_float_equal(s.last.mpos[2], 0.125, 1e-9);
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_error_reply(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN];
    double xyz[3] = {1, 2, 3};
    (void)state;
    open_ok(&s, &f, BANNER "polls 1\nexpect G90 G1 F90 X1 Y2 Z3\nsend error:9\nend\n");
    assert_int_equal(stage_move(&s, xyz, 90, err), -1);
    assert_non_null(strstr(err, "error:9"));
    assert_non_null(strstr(err, "locked out"));
    assert_int_equal(s.last_error, 9);
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_alarm_then_recover_rehome(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN];
    double xyz[3] = {30, 0, 0};
    (void)state;
    open_ok(&s, &f,
            BANNER
            "polls 1\n"
            "expect G90 G0 X30 Y0 Z0\nsend ok\nexpect G4 P0\n"
            "state <Run|MPos:3.000,0.000,0.000|FS:720,0>\n"
            "send ALARM:1\nsend [MSG:Reset to continue]\n"
            "state <Alarm|MPos:3.000,0.000,0.000|FS:0,0>\n"
            "expect_rt 18\n" BANNER "send [MSG:'$H'|'$X' to unlock]\npolls 1\n"
            "expect $H\nstate <Idle|MPos:0.000,0.000,0.000|FS:0,0>\nsend ok\npolls 1\nend\n");
    assert_int_equal(stage_move_wait(&s, xyz, 0, err), -1);
    assert_non_null(strstr(err, "ALARM:1"));
    assert_non_null(strstr(err, "Hard limit"));
    assert_int_equal(s.last_alarm, 1);
    if (stage_recover(&s, 1, err) != 0) fail_msg("%s", err);
    assert_string_equal(s.last.state, "Idle");
    assert_int_equal(s.last_alarm, 0);
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_recover_needs_rehome(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN];
    (void)state;
    open_ok(&s, &f,
            BANNER "polls 1\nsend ALARM:3\nstate <Alarm|MPos:0,0,0>\n"
                   "expect_rt 18\n" BANNER "polls 1\nend\n");
    assert_int_equal(stage_recover(&s, 0, err), -1);
    assert_non_null(strstr(err, "home it"));
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_recover_soft_limit_unlocks(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN];
    double xyz[3] = {400, 0, 0};
    (void)state;
    open_ok(&s, &f,
            BANNER "polls 1\nexpect G90 G0 X400 Y0 Z0\nsend ALARM:2\n"
                   "state <Alarm|MPos:0,0,0>\nsend error:9\n"
                   "expect_rt 18\n" BANNER "polls 1\nexpect $X\nsend [MSG:Caution: Unlocked]\n"
                   "state <Idle|MPos:0,0,0>\nsend ok\nend\n");
    assert_int_equal(stage_move(&s, xyz, 0, err), -1);
    assert_non_null(strstr(err, "ALARM:2"));
    if (stage_recover(&s, 0, err) != 0) fail_msg("%s", err);
    assert_int_equal(s.last_alarm, 0);
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_reply_timeout(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN];
    long long t0;
    (void)state;
    open_ok(&s, &f, BANNER "polls 1\nexpect $X\nend\n");
    t0 = now_ms();
    assert_int_equal(stage_unlock(&s, err), -1);
    assert_true(now_ms() - t0 < 1500);
    assert_non_null(strstr(err, "no reply within 400 ms"));
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_late_reply_not_taken_for_next(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN];
    struct pollfd late_ok;
    (void)state;
    /* The ok of a timed-out command arrives late; the next command must
     * wait for its own reply (error:9 here), not take the stale ok. The ok
     * comes 1.1 s after the client's 400 ms timeout, so a stalled client
     * still times out first; the next command goes once it is there. */
    open_ok(&s, &f,
            BANNER "polls 1\nexpect $X\nsleep 1500\nsend ok\n"
                   "expect $X\nsend error:9\nend\n");
    assert_int_equal(stage_unlock(&s, err), -1);
    late_ok = (struct pollfd){s.fd, POLLIN, 0};
    assert_int_equal(poll(&late_ok, 1, 10000), 1);
    assert_int_equal(stage_unlock(&s, err), -1);
    assert_non_null(strstr(err, "error:9"));
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_garbage_ignored(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN];
    (void)state;
    open_ok(&s, &f,
            "garbage 40\n" BANNER "garbage 700\npolls 1\n"
            "expect $X\ngarbage 300\nraw 00ff0d0a\nsend <Idle|MPos:bogus>\n"
            "send [MSG:Caution: Unlocked]\nsend ok\nend\n");
    if (stage_unlock(&s, err) != 0) fail_msg("%s", err);
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

/* Bytes an earlier client left without a newline ("G0 X") would be glued
 * onto the first command ("G0 X$X": refused). The client's line break on
 * connecting ends them as a line of their own; their error reply is read
 * then, not taken for the first command's. */
static void test_stray_bytes_ended_on_connect(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN];
    (void)state;
    open_ok(&s, &f,
            "junk G0 X\n" BANNER "expect G0 X\nsend error:2\npolls 1\n"
            "expect $X\nsend ok\nend\n");
    assert_int_equal(s.last_error, 0);
    if (stage_unlock(&s, err) != 0) fail_msg("%s", err);
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

/* A controller whose EEPROM failed its CRC check says so once, after its
 * boot banner, and runs on defaults: the client keeps the fact for its
 * callers (stagectl reports it, poserig refuses to measure). */
static void test_eeprom_defaults_noted(void **state)
{
    fake f;
    stage s;
    (void)state;
    open_ok(&s, &f,
            BANNER "send [MSG:EEPROM settings failed CRC check, defaults restored]\n"
                   "polls 1\nend\n");
    assert_int_equal(s.defaults_restored, 1);
    assert_string_equal(s.restored_msg,
                        "[MSG:EEPROM settings failed CRC check, defaults restored]");
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_port_vanishes(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN];
    double xyz[3] = {1, 1, 1};
    long long t0;
    (void)state;
    open_ok(&s, &f, BANNER "polls 1\nexpect G90 G0 X1 Y1 Z1\nclose\n");
    t0 = now_ms();
    assert_int_equal(stage_move_wait(&s, xyz, 0, err), -1);
    assert_true(now_ms() - t0 < 1000); /* noticed at once, not at the deadline */
    assert_non_null(strstr(err, "vanished"));
    assert_true(s.dead);
    assert_int_equal(stage_status(&s, NULL, err), -1);
    assert_non_null(strstr(err, "earlier failure"));
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_no_banner_but_answers(void **state)
{
    fake f;
    stage s;
    (void)state;
    /* An earlier client took the banner: the controller answers '?'. */
    open_ok(&s, &f, "polls 2\nend\n");
    assert_string_equal(s.banner, "");
    assert_string_equal(s.last.state, "Idle");
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_silent_until_reset(void **state)
{
    fake f;
    stage s;
    (void)state;
    open_ok(&s, &f, "mute\nexpect_rt 18\nunmute\n" BANNER "polls 1\nend\n");
    assert_string_equal(s.banner, "Grbl 1.1h ['$' for help]");
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_dead_controller(void **state)
{
    fake f;
    stage s;
    stage_opts o;
    char err[RIG_ERR_LEN];
    long long t0;
    (void)state;
    fast_opts(&o);
    fake_start(&f, "mute\nend\n");
    t0 = now_ms();
    assert_int_equal(stage_open(&s, f.pty, &o, err), -1);
    assert_true(now_ms() - t0 < 4000);
    assert_non_null(strstr(err, "no GRBL banner"));
    assert_int_equal(s.fd, -1);
    fake_stop(&f);
}

static void test_reset_during_command(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN];
    double xyz[3] = {5, 5, 5};
    (void)state;
    open_ok(&s, &f, BANNER "polls 1\nexpect G90 G0 X5 Y5 Z5\n" BANNER "end\n");
    assert_int_equal(stage_move(&s, xyz, 0, err), -1);
    assert_non_null(strstr(err, "reset"));
    assert_true(s.reset_seen);
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_wait_idle_deadline(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN];
    long long t0;
    (void)state;
    open_ok(&s, &f, BANNER "polls 1\nstate <Run|MPos:1.000,0.000,0.000|FS:720,0>\nend\n");
    t0 = now_ms();
    assert_int_equal(stage_wait_idle(&s, 300, err), -1);
    assert_true(now_ms() - t0 < 1500);
    assert_non_null(strstr(err, "still Run after 300 ms"));
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_feed_hold_and_reset(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN];
    (void)state;
    open_ok(&s, &f,
            BANNER "polls 1\nexpect_rt 21\nstate <Hold:0|MPos:1,0,0>\n"
                   "expect_rt 18\nsend ALARM:3\n" BANNER "send [MSG:'$H'|'$X' to unlock]\n"
                   "state <Alarm|MPos:1,0,0>\npolls 1\nend\n");
    assert_int_equal(stage_feed_hold(&s, err), 0);
    assert_int_equal(stage_reset(&s, err), 0);
    assert_string_equal(s.last.state, "Alarm");
    assert_true(s.needs_unlock);
    assert_int_equal(s.last_alarm, 3);
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_bad_lines_refused(void **state)
{
    fake f;
    stage s;
    char err[RIG_ERR_LEN], big[100];
    (void)state;
    open_ok(&s, &f, BANNER "polls 1\nend\n");
    memset(big, 'G', sizeof(big) - 1);
    big[sizeof(big) - 1] = '\0';
    assert_int_equal(stage_command(&s, big, 0, NULL, NULL, err), -1);
    assert_int_equal(stage_command(&s, "G0 X1\nG0 X2", 0, NULL, NULL, err), -1);
    assert_int_equal(stage_command(&s, "", 0, NULL, NULL, err), -1);
    stage_close(&s);
    assert_int_equal(fake_stop(&f), 0);
}

static void test_open_missing_port(void **state)
{
    stage s;
    stage_opts o;
    char err[RIG_ERR_LEN];
    (void)state;
    fast_opts(&o);
    assert_int_equal(stage_open(&s, "/nonexistent/tty", &o, err), -1);
    assert_non_null(strstr(err, "/nonexistent/tty"));
    /* A regular file is not a terminal. */
    assert_int_equal(stage_open(&s, "/dev/null", &o, err), -1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_open_settings),
        cmocka_unit_test(test_move_wait_idle),
        cmocka_unit_test(test_error_reply),
        cmocka_unit_test(test_alarm_then_recover_rehome),
        cmocka_unit_test(test_recover_needs_rehome),
        cmocka_unit_test(test_recover_soft_limit_unlocks),
        cmocka_unit_test(test_reply_timeout),
        cmocka_unit_test(test_late_reply_not_taken_for_next),
        cmocka_unit_test(test_garbage_ignored),
        cmocka_unit_test(test_stray_bytes_ended_on_connect),
        cmocka_unit_test(test_eeprom_defaults_noted),
        cmocka_unit_test(test_port_vanishes),
        cmocka_unit_test(test_no_banner_but_answers),
        cmocka_unit_test(test_silent_until_reset),
        cmocka_unit_test(test_dead_controller),
        cmocka_unit_test(test_reset_during_command),
        cmocka_unit_test(test_wait_idle_deadline),
        cmocka_unit_test(test_feed_hold_and_reset),
        cmocka_unit_test(test_bad_lines_refused),
        cmocka_unit_test(test_open_missing_port),
    };
    signal(SIGPIPE, SIG_IGN);
    return cmocka_run_group_tests_name("rig_client", tests, NULL, NULL);
}
