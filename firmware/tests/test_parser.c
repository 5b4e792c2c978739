// Parser unit tests: numbers, the line reader, every accepted command and
// the malformed lines that must be refused with GRBL's codes.
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>
#include <math.h>
#include <stdlib.h>
#include "harness.h"
#include "nuts.h"
#include "codes.h"

// Send one line through the whole path; return the status of its reply.
static uint8_t run_gc(const char *text)
{
  h_send(text);
  const char *out = h_take();
  const char *e = strstr(out, "error:");
  if (e) return (uint8_t)atoi(e + 6);
  if (!strstr(out, "ok\r\n")) fail_msg("\"%s\": no reply in \"%s\"", text, out);
  return STATUS_OK;
}

static void test_read_float(void **state)
{
  struct { const char *s; int ok; float v; uint8_t end; } cases[] = {
    {"1", 1, 1.0f, 1}, {"-2.5", 1, -2.5f, 4}, {"+.5", 1, 0.5f, 3}, {"0.001", 1, 0.001f, 5},
    {"12345678", 1, 12345678.0f, 8}, {"123456789", 1, 123456789.0f, 9}, {"1.5X", 1, 1.5f, 3},
    {"-", 0, 0, 0}, {".", 0, 0, 0}, {"", 0, 0, 0}, {"X", 0, 0, 0}, {"--1", 0, 0, 0},
    {"1e5", 1, 1.0f, 1}, {"99999999999999999999", 0, 0, 0}, {"0.000000000001", 1, 0.0f, 14},
  };
  for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
    uint8_t cc = 0;
    float v = 12345;
    int ok = read_float(cases[i].s, &cc, &v);
    assert_int_equal(ok, cases[i].ok);
    if (ok) {
      assert_float_equal(v, cases[i].v, fabsf(cases[i].v) * 1e-6f + 1e-6f);
      assert_int_equal(cc, cases[i].end);
    }
  }
}

static void test_line_reader_cleans(void **state)
{
  // Spaces, control bytes and NUL are dropped, lowercase upcased, comments removed.
  const char in[] = "g0 \x01x\x7f" "1\x00(comment)y2;rest\n";
  h_send_bytes(in, sizeof(in) - 1);
  h_run(600000);
  assert_string_equal(h_take(), "ok\r\n");
  assert_float_equal(gc_state.position[X_AXIS], 1.0f, 1e-6);
  assert_float_equal(gc_state.position[Y_AXIS], 2.0f, 1e-6);
}

static void test_line_reader_overflow(void **state)
{
  char line[200];
  memset(line, 'X', sizeof(line));
  line[0] = 'G'; line[1] = '4'; line[2] = 'P';
  memset(line + 3, '0', 150);
  line[153] = 0;
  h_send(line);
  assert_string_equal(h_take(), "error:11\r\n");
  // The next line is read normally.
  h_send("G4 P0");
  assert_string_equal(h_take(), "ok\r\n");
  // Exactly 80 characters pass, 81 overflow.
  memset(line, '0', sizeof(line));
  line[0] = 'G'; line[1] = '4'; line[2] = 'P'; line[80] = 0;
  h_send(line);
  assert_string_equal(h_take(), "ok\r\n");
  line[80] = '0'; line[81] = 0;
  h_send(line);
  assert_string_equal(h_take(), "error:11\r\n");
}

static void test_one_reply_per_line(void **state)
{
  const char *lines[] = {"G0X1", "", "(c)", "G1", "Q", "$$", "$G", "G4P0", "N5", "M2", "$#", "G0 X1 X2"};
  for (size_t i = 0; i < sizeof(lines) / sizeof(lines[0]); i++) {
    h_send(lines[i]);
    const char *out = h_take();
    int replies = 0;
    for (const char *p = out; (p = strstr(p, "\r\n")); p += 2) {
      const char *start = p;
      while (start > out && start[-1] != '\n') start--;
      if (!strncmp(start, "ok", 2) || !strncmp(start, "error:", 6)) replies++;
    }
    assert_int_equal(replies, 1);
  }
}

static void test_modal_commands(void **state)
{
  assert_int_equal(run_gc("G91"), STATUS_OK);
  assert_int_equal(gc_state.modal.distance, 1);
  assert_int_equal(run_gc("G90"), STATUS_OK);
  assert_int_equal(gc_state.modal.distance, 0);
  assert_int_equal(run_gc("G17 G21 G94 G61"), STATUS_OK);
  for (int i = 0; i < 6; i++) {
    char l[8];
    snprintf(l, sizeof(l), "G%d", 54 + i);
    assert_int_equal(run_gc(l), STATUS_OK);
    assert_int_equal(gc_state.modal.coord_select, i);
  }
  assert_int_equal(run_gc("G54"), STATUS_OK);
  assert_int_equal(run_gc("G1 F250"), STATUS_OK);
  assert_int_equal(gc_state.modal.motion, MOTION_MODE_LINEAR);
  assert_float_equal(gc_state.feed_rate, 250.0f, 1e-6);
  assert_int_equal(run_gc("G0"), STATUS_OK);
  assert_int_equal(gc_state.modal.motion, MOTION_MODE_SEEK);
  assert_int_equal(run_gc("G80"), STATUS_OK);
  assert_int_equal(gc_state.modal.motion, MOTION_MODE_NONE);
  assert_int_equal(run_gc("N123 G0"), STATUS_OK);
  assert_int_equal(gc_state.line_number, 123);
  assert_int_equal(run_gc("M5 M9"), STATUS_OK);
}

static void test_motion_and_offsets(void **state)
{
  assert_int_equal(run_gc("G0 X10 Y-5 Z2.5"), STATUS_OK);
  assert_int_equal(host_motor_steps[0], 8000);
  assert_int_equal(host_motor_steps[1], -4000);
  assert_int_equal(host_motor_steps[2], 2000);
  assert_int_equal(run_gc("G91 G1 X-1 F100"), STATUS_OK);
  assert_int_equal(host_motor_steps[0], 7200);
  assert_int_equal(run_gc("G90 G92 X0"), STATUS_OK);
  assert_float_equal(gc_state.coord_offset[X_AXIS], 9.0f, 1e-5);
  assert_int_equal(run_gc("G0 X1"), STATUS_OK);
  assert_int_equal(host_motor_steps[0], 8000);
  assert_int_equal(run_gc("G92.1"), STATUS_OK);
  assert_float_equal(gc_state.coord_offset[X_AXIS], 0.0f, 1e-6);
  assert_int_equal(run_gc("G10 L2 P1 X1"), STATUS_OK);
  assert_float_equal(gc_state.coord_system[X_AXIS], 1.0f, 1e-6);
  assert_int_equal(run_gc("G10 L20 P0 X0"), STATUS_OK);   // P0: the active system
  assert_float_equal(gc_state.coord_system[X_AXIS], 10.0f, 1e-5);
  assert_int_equal(run_gc("G53 G0 X0 Y0 Z0"), STATUS_OK);
  assert_int_equal(host_motor_steps[0], 0);
  assert_int_equal(run_gc("G28.1"), STATUS_OK);
  assert_int_equal(run_gc("G0 X5"), STATUS_OK);
  assert_int_equal(run_gc("G28"), STATUS_OK);
  assert_int_equal(host_motor_steps[0], 0);
  assert_int_equal(run_gc("G30.1"), STATUS_OK);
  assert_int_equal(run_gc("G30 Y-1"), STATUS_OK);
  assert_int_equal(host_motor_steps[1], 0);
  assert_int_equal(run_gc("G4 P0.01"), STATUS_OK);
  assert_int_equal(run_gc("M0"), STATUS_OK);
  assert_int_equal(sys.state, STATE_HOLD);
  serial_rx_isr('~');
  h_run(1000);
  assert_int_equal(sys.state, STATE_IDLE);
  assert_int_equal(run_gc("M30"), STATUS_OK);
  assert_int_equal(run_gc("M2"), STATUS_OK);
}

static void test_malformed(void **state)
{
  struct { const char *line; uint8_t status; } cases[] = {
    {"1", STATUS_EXPECTED_COMMAND_LETTER}, {"G", STATUS_BAD_NUMBER_FORMAT},
    {"X--1", STATUS_BAD_NUMBER_FORMAT}, {"G0 X1 X1", STATUS_GCODE_WORD_REPEATED},
    {"F1 F2", STATUS_GCODE_WORD_REPEATED}, {"G90 G91", STATUS_GCODE_MODAL_GROUP_VIOLATION},
    {"M0 M2", STATUS_GCODE_MODAL_GROUP_VIOLATION}, {"G0 G1", STATUS_GCODE_AXIS_COMMAND_CONFLICT},
    {"G2 X1", STATUS_GCODE_UNSUPPORTED_COMMAND}, {"G20", STATUS_GCODE_UNSUPPORTED_COMMAND},
    {"M7", STATUS_GCODE_UNSUPPORTED_COMMAND}, {"B1", STATUS_GCODE_UNSUPPORTED_COMMAND},
    {"G0.5", STATUS_GCODE_COMMAND_VALUE_NOT_INTEGER}, {"G4", STATUS_GCODE_VALUE_WORD_MISSING},
    {"G4 P-2", STATUS_NEGATIVE_VALUE}, {"G92", STATUS_GCODE_NO_AXIS_WORDS},
    {"N-5", STATUS_GCODE_INVALID_LINE_NUMBER}, {"G10 L2 P9 X0", STATUS_GCODE_UNSUPPORTED_COORD_SYS},
    {"G10 L2 P1.5 X0", STATUS_GCODE_UNSUPPORTED_COORD_SYS}, {"G59.1", STATUS_GCODE_UNSUPPORTED_COORD_SYS},
    {"G80 X1", STATUS_GCODE_AXIS_WORDS_EXIST}, {"G0 P1", STATUS_GCODE_UNUSED_WORDS},
    {"G1 X1 F0", STATUS_GCODE_UNDEFINED_FEED_RATE}, {"G10 L2 P1 G92 X1", STATUS_GCODE_AXIS_COMMAND_CONFLICT},
    {"G28 G92 X1", STATUS_GCODE_AXIS_COMMAND_CONFLICT}, {"G4 P1 G53", STATUS_GCODE_MODAL_GROUP_VIOLATION}, {"G80 G53 X1", STATUS_GCODE_G53_INVALID_MOTION_MODE},
    {"$J=X1", STATUS_GCODE_UNDEFINED_FEED_RATE}, {"$J=G1 X1 F1", STATUS_INVALID_JOG_COMMAND},
    {"$J X1", STATUS_INVALID_STATEMENT}, {"$XX", STATUS_INVALID_STATEMENT},
    {"$RST=", STATUS_INVALID_STATEMENT}, {"$300=1", STATUS_INVALID_STATEMENT},
    {"$0=1", STATUS_SETTING_STEP_PULSE_MIN}, {"$24=-1", STATUS_NEGATIVE_VALUE},
    {"$100=0", STATUS_MAX_STEP_RATE_EXCEEDED}, {"$H", STATUS_SETTING_DISABLED},
    {"$HA", STATUS_SETTING_DISABLED}, {"$20=1", STATUS_SOFT_LIMIT_ERROR},
  };
  for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
    uint8_t r = run_gc(cases[i].line);
    if (r != cases[i].status) fail_msg("\"%s\": got %d, want %d", cases[i].line, r, cases[i].status);
  }
  // Nothing above moved the stage.
  assert_int_equal(host_motor_steps[0], 0);
  assert_int_equal(host_motor_steps[1], 0);
  assert_int_equal(host_motor_steps[2], 0);
}

static void test_system_commands(void **state)
{
  const char *ok_lines[] = {"$", "$$", "$#", "$G", "$I", "$X", "$C", "$C", "$I=abc", "$RST=$", "$RST=#", "$RST=*"};
  for (size_t i = 0; i < sizeof(ok_lines) / sizeof(ok_lines[0]); i++) {
    h_send(ok_lines[i]);
    const char *out = h_take();
    if (!strstr(out, "ok\r\n")) fail_msg("\"%s\" gave \"%s\"", ok_lines[i], out);
  }
  h_send("$22=1");
  h_take();
  h_send("$HX");   // no switch modelled: seek runs out, ALARM:9
  assert_non_null(strstr(h_take(), "ALARM:9"));
  h_send("$X");
  h_send("$22=0");
  h_take();
}

int main(void)
{
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_read_float),
    cmocka_unit_test_setup(test_line_reader_cleans, h_new_chip),
    cmocka_unit_test_setup(test_line_reader_overflow, h_new_chip),
    cmocka_unit_test_setup(test_one_reply_per_line, h_new_chip),
    cmocka_unit_test_setup(test_modal_commands, h_new_chip),
    cmocka_unit_test_setup(test_motion_and_offsets, h_new_chip),
    cmocka_unit_test_setup(test_malformed, h_new_chip),
    cmocka_unit_test_setup(test_system_commands, h_new_chip),
  };
  return cmocka_run_group_tests_name("parser", tests, NULL, NULL);
}
