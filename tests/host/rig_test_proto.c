/* Unit tests of the GRBL reply parsers (host/rig/stage_proto.c). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>
#include <math.h>
#include <string.h>

#include "stage_proto.h"

static void test_line_kinds(void **state)
{
    int code = -1;
    (void)state;
    assert_int_equal(stage_parse_line("", NULL), STAGE_LINE_EMPTY);
    assert_int_equal(stage_parse_line("ok", NULL), STAGE_LINE_OK);
    assert_int_equal(stage_parse_line("error:9", &code), STAGE_LINE_ERROR);
    assert_int_equal(code, 9);
    assert_int_equal(stage_parse_line("ALARM:3", &code), STAGE_LINE_ALARM);
    assert_int_equal(code, 3);
    assert_int_equal(stage_parse_line("Grbl 1.1h ['$' for help]", NULL), STAGE_LINE_BANNER);
    assert_int_equal(stage_parse_line("<Idle|MPos:0.000,0.000,0.000|FS:0,0>", NULL),
                     STAGE_LINE_STATUS);
    assert_int_equal(stage_parse_line("$100=800.000", NULL), STAGE_LINE_SETTING);
    assert_int_equal(stage_parse_line("[MSG:'$H'|'$X' to unlock]", NULL), STAGE_LINE_MSG);
    assert_int_equal(stage_parse_line("[G54:0.000,0.000,0.000]", NULL), STAGE_LINE_FEEDBACK);
    assert_int_equal(stage_parse_line("[VER:1.1h.20190825:]", NULL), STAGE_LINE_FEEDBACK);
}

static void test_line_malformed(void **state)
{
    int code = 77;
    (void)state;
    /* Near misses are noise, never a code the client would act on. */
    assert_int_equal(stage_parse_line("error:", &code), STAGE_LINE_OTHER);
    assert_int_equal(stage_parse_line("error:x", &code), STAGE_LINE_OTHER);
    assert_int_equal(stage_parse_line("error:9junk", &code), STAGE_LINE_OTHER);
    assert_int_equal(stage_parse_line("error:-1", &code), STAGE_LINE_OTHER);
    assert_int_equal(stage_parse_line("ALARM:", &code), STAGE_LINE_OTHER);
    assert_int_equal(stage_parse_line("ALARM:99999999999999", &code), STAGE_LINE_OTHER);
    assert_int_equal(code, 77);
    assert_int_equal(stage_parse_line("okay", NULL), STAGE_LINE_OTHER);
    assert_int_equal(stage_parse_line("Grbl", NULL), STAGE_LINE_OTHER);
    assert_int_equal(stage_parse_line("<Idle", NULL), STAGE_LINE_OTHER);
    assert_int_equal(stage_parse_line("$$", NULL), STAGE_LINE_OTHER);
    assert_int_equal(stage_parse_line("\x01\xff garbage", NULL), STAGE_LINE_OTHER);
}

static void test_status_mpos(void **state)
{
    stage_status_report st;
    char err[RIG_ERR_LEN];
    (void)state;
    assert_int_equal(
        stage_parse_status("<Run|MPos:10.000,-5.500,0.125|FS:720,0|Pn:XZ>", NULL, &st, err), 0);
    assert_string_equal(st.state, "Run");
    assert_int_equal(st.substate, -1);
    assert_true(st.has_mpos);
    assert_false(st.has_wpos);
    assert_float_equal(st.mpos[0], 10.0, 1e-9);
    assert_float_equal(st.mpos[1], -5.5, 1e-9);
    assert_float_equal(st.mpos[2], 0.125, 1e-9);
    assert_float_equal(st.wpos[1], -5.5, 1e-9); /* no offset known: WPos = MPos */
    assert_float_equal(st.feed, 720, 1e-9);
    assert_string_equal(st.pins, "XZ");
}

static void test_status_wpos_wco(void **state)
{
    stage_status_report st;
    char err[RIG_ERR_LEN];
    double wco[3] = {1, 2, 3};
    (void)state;
    /* WPos with the report's own WCO: MPos = WPos + WCO. */
    assert_int_equal(
        stage_parse_status("<Idle|WPos:1.000,1.000,1.000|Bf:15,128|FS:0,0|WCO:0.500,-1.000,2.000>",
                           NULL, &st, err),
        0);
    assert_float_equal(st.mpos[0], 1.5, 1e-9);
    assert_float_equal(st.mpos[1], 0.0, 1e-9);
    assert_float_equal(st.mpos[2], 3.0, 1e-9);
    assert_int_equal(st.buf_blocks, 15);
    assert_int_equal(st.buf_bytes, 128);
    /* WPos alone: the last offset seen applies. */
    assert_int_equal(stage_parse_status("<Idle|WPos:0.000,0.000,0.000|FS:0,0>", wco, &st, err), 0);
    assert_float_equal(st.mpos[2], 3.0, 1e-9);
    /* MPos alone with a known offset: WPos = MPos - WCO. */
    assert_int_equal(stage_parse_status("<Idle|MPos:1.000,2.000,3.000>", wco, &st, err), 0);
    assert_float_equal(st.wpos[0], 0.0, 1e-9);
}

static void test_status_substate_and_extra_axes(void **state)
{
    stage_status_report st;
    char err[RIG_ERR_LEN];
    (void)state;
    assert_int_equal(
        stage_parse_status("<Hold:1|MPos:0.000,0.000,0.000,9.000|F:100|Ov:100,100,100>", NULL, &st,
                           err),
        0);
    assert_string_equal(st.state, "Hold");
    assert_int_equal(st.substate, 1);
    assert_float_equal(st.feed, 100, 1e-9);
    assert_int_equal(stage_parse_status("<Alarm|MPos:0,0,0>", NULL, &st, err), 0);
    assert_string_equal(st.state, "Alarm");
}

static void test_status_malformed(void **state)
{
    stage_status_report st;
    char err[RIG_ERR_LEN];
    static const char *bad[] = {
        "",
        "<>",
        "<Idle>",
        "Idle|MPos:0,0,0",
        "<Idle|MPos:0,0>",
        "<Idle|MPos:0,0,x>",
        "<Idle|MPos:1e999,0,0>",
        "<Idle|MPos:nan,0,0>",
        "<|MPos:0,0,0>",
        "<Id1e|MPos:0,0,0>",
        "<Hold:|MPos:0,0,0>",
        "<Hold:x|MPos:0,0,0>",
        "<Idle|MPos:0,0,0junk>",
        "<Idle|FS:0,0>",
        "<ThisStateNameIsFarTooLong|MPos:0,0,0>",
        "<Idle|MPos:,,>",
    };
    size_t i;
    (void)state;
    for (i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
        err[0] = '\0';
        assert_int_equal(stage_parse_status(bad[i], NULL, &st, err), -1);
        assert_non_null(strstr(err, "stage_parse_status: "));
    }
}

static void test_settings(void **state)
{
    char err[RIG_ERR_LEN];
    int n;
    double v;
    (void)state;
    assert_int_equal(stage_parse_setting("$100=800.000", &n, &v, err), 0);
    assert_int_equal(n, 100);
    assert_float_equal(v, 800.0, 1e-9);
    assert_int_equal(stage_parse_setting("$0=10", &n, &v, err), 0);
    assert_int_equal(n, 0);
    assert_int_equal(stage_parse_setting("$130=-1.5 (x max travel, deg)", &n, &v, err), 0);
    assert_float_equal(v, -1.5, 1e-9);
    assert_int_equal(stage_parse_setting("$x=1", &n, &v, err), -1);
    assert_int_equal(stage_parse_setting("$1=", &n, &v, err), -1);
    assert_int_equal(stage_parse_setting("$1=abc", &n, &v, err), -1);
    assert_int_equal(stage_parse_setting("$1 =5", &n, &v, err), -1);
    assert_int_equal(stage_parse_setting("$1=5junk", &n, &v, err), -1);
    assert_int_equal(stage_parse_setting("$N0=G21", &n, &v, err),
                     -1); /* startup lines are not numbers */
    assert_non_null(strstr(err, "stage_parse_setting"));
}

/* The texts are the descriptions of firmware/doc/error_codes.csv and
 * alarm_codes.csv, generated at build time. */
static void test_code_texts(void **state)
{
    (void)state;
    assert_string_equal(stage_error_text(1),
                        "G-code words consist of a letter and a value. Letter was not found.");
    assert_non_null(strstr(stage_error_text(9), "locked out"));
    assert_non_null(strstr(stage_error_text(20), "Unsupported"));
    assert_string_equal(stage_error_text(0), "unknown error code");
    assert_string_equal(stage_error_text(18), "unknown error code");
    assert_string_equal(stage_error_text(1000), "unknown error code");
    assert_string_equal(stage_error_text(-3), "unknown error code");
    assert_non_null(strstr(stage_alarm_text(1), "Hard limit"));
    assert_non_null(strstr(stage_alarm_text(9), "Homing"));
    assert_non_null(strstr(stage_alarm_text(10), "watchdog")); /* this firmware's own code */
    assert_string_equal(stage_alarm_text(42), "unknown alarm code");
    assert_true(stage_alarm_loses_position(1));
    assert_true(stage_alarm_loses_position(3));
    assert_false(stage_alarm_loses_position(2));
    assert_true(stage_alarm_loses_position(42));
}

static void test_fmt_number(void **state)
{
    char b[32];
    (void)state;
    assert_string_equal(stage_fmt_number(b, sizeof(b), 800), "800");
    assert_string_equal(stage_fmt_number(b, sizeof(b), 0.01), "0.01");
    assert_string_equal(stage_fmt_number(b, sizeof(b), -12.5), "-12.5");
    assert_string_equal(stage_fmt_number(b, sizeof(b), -0.00001), "0");
    assert_string_equal(stage_fmt_number(b, sizeof(b), 7.125), "7.125");
    assert_string_equal(stage_fmt_number(b, sizeof(b), 1.23456), "1.2346");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_line_kinds),
        cmocka_unit_test(test_line_malformed),
        cmocka_unit_test(test_status_mpos),
        cmocka_unit_test(test_status_wpos_wco),
        cmocka_unit_test(test_status_substate_and_extra_axes),
        cmocka_unit_test(test_status_malformed),
        cmocka_unit_test(test_settings),
        cmocka_unit_test(test_code_texts),
        cmocka_unit_test(test_fmt_number),
    };
    return cmocka_run_group_tests_name("rig_proto", tests, NULL, NULL);
}
