// Planner profiles and step generation: junction speeds, trapezoids, move
// times, exact step counts, hold/resume, reset, backlash.
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <stdlib.h>
#include <math.h>
#include <cmocka.h>
#include "harness.h"
#include "nuts.h"
#include "codes.h"

#define ACCEL_DEG_MIN2 (90.0f * 3600.0f)

// Linked with -Wl,--wrap=plan_buffer_line (Makefile): every call into the
// planner from outside planner.c (mc_line's pieces, this file's queue())
// passes here and is counted.
static uint32_t buffer_line_calls;

uint8_t __real_plan_buffer_line(const float *target, const plan_line_data_t *pl_data);
uint8_t __wrap_plan_buffer_line(const float *target, const plan_line_data_t *pl_data)
{
  buffer_line_calls++;
  return __real_plan_buffer_line(target, pl_data);
}

static int setup(void **state)
{
  h_new_chip(state);
  host_max_step_rate_hz = 0;
  return 0;
}

static void queue(float x, float y, float z, float feed, uint8_t rapid)
{
  float t[N_AXIS] = {x, y, z};
  plan_line_data_t pl = {.feed_rate = feed, .condition = rapid ? PL_COND_FLAG_RAPID_MOTION : 0};
  assert_int_equal(plan_buffer_line(t, &pl), PLAN_OK);
}

static void test_single_block_profile(void **state)
{
  queue(10, 0, 0, 600, 0);
  plan_block_t *b = plan_peek_block(0);
  assert_non_null(b);
  assert_int_equal(b->step_event_count, 8000);
  assert_float_equal(b->millimeters, 10.0f, 1e-5);
  assert_float_equal(b->entry_speed_sqr, 0.0f, 0);
  assert_float_equal(plan_compute_profile_nominal_speed(b), 600.0f, 1e-4);
  assert_float_equal(b->acceleration, ACCEL_DEG_MIN2, 1);
}

static void test_collinear_blocks_keep_speed(void **state)
{
  queue(10, 0, 0, 600, 0);
  queue(20, 0, 0, 600, 0);
  plan_block_t *b = plan_peek_block(1);
  assert_float_equal(b->entry_speed_sqr, 600.0f * 600.0f, 1);
}

static void test_reversal_stops(void **state)
{
  queue(10, 0, 0, 600, 0);
  queue(0, 0, 0, 600, 0);
  assert_float_equal(plan_peek_block(1)->entry_speed_sqr, 0.0f, 0);
  assert_int_equal(plan_peek_block(1)->direction_bits, 1);
}

static void test_corner_junction_deviation(void **state)
{
  queue(10, 0, 0, 600, 0);
  queue(10, 10, 0, 600, 0);
  // GRBL's junction model: the centripetal acceleration along the bisector
  // (here both axes at once: sqrt 2 x one axis' limit) over the deviation.
  float s = sqrtf(0.5f);
  float v2 = ACCEL_DEG_MIN2 * sqrtf(2.0f) * 0.01f * s / (1.0f - s);
  assert_float_equal(plan_peek_block(1)->entry_speed_sqr, v2, v2 * 1e-4f);
}

static void test_short_blocks_limited_by_acceleration(void **state)
{
  // Three short collinear blocks at a high feed: the second can only be
  // entered at the speed reachable from rest over the first.
  queue(0.05f, 0, 0, 1800, 0);
  queue(0.10f, 0, 0, 1800, 0);
  queue(0.15f, 0, 0, 1800, 0);
  float v2 = 2 * ACCEL_DEG_MIN2 * 0.05f;
  assert_float_equal(plan_peek_block(1)->entry_speed_sqr, v2, v2 * 1e-4f);
  // The last block must stop: entry limited by its own length too.
  assert_true(plan_peek_block(2)->entry_speed_sqr <= 2 * ACCEL_DEG_MIN2 * 0.05f * 1.0001f);
}

static void test_rates_limited_per_axis(void **state)
{
  queue(10, 10, 0, 0, 1);   // rapid diagonal: each axis at its max rate
  plan_block_t *b = plan_peek_block(0);
  float v = 1800.0f * sqrtf(2.0f);
  assert_float_equal(plan_compute_profile_nominal_speed(b), v, v * 1e-4f);
  assert_float_equal(b->acceleration, ACCEL_DEG_MIN2 * sqrtf(2.0f), 10);
  queue(20, 10, 0, 99999, 0);   // feed above max rate is clamped
  assert_float_equal(plan_compute_profile_nominal_speed(plan_peek_block(1)), 1800.0f, 1e-3);
  queue(20, 10, 1, 0.01f, 0);   // feed below the minimum is raised
  assert_float_equal(plan_compute_profile_nominal_speed(plan_peek_block(2)), MINIMUM_FEED_RATE, 1e-4);
}

static void test_empty_move(void **state)
{
  float t[N_AXIS] = {0.0001f, 0, 0};   // below half a step
  plan_line_data_t pl = {.feed_rate = 100};
  assert_int_equal(plan_buffer_line(t, &pl), PLAN_EMPTY_BLOCK);
  assert_null(plan_get_current_block());
}

static uint64_t timed_move(const char *line)
{
  uint64_t t0 = host_cycles;
  h_send(line);
  return host_cycles - t0;
}

static void test_move_time_trapezoid(void **state)
{
  // 10 deg at 10 deg/s with 90 deg/s^2: 1.0 s cruise-equivalent + v/a.
  double t = timed_move("G1 X10 F600") / (double)F_CPU;
  assert_true(fabs(t - (1.0 + 10.0 / 90.0)) < 0.02);
  // 0.5 deg at a rapid: a triangle, 2 sqrt(d/a).
  t = timed_move("G0 X10.5") / (double)F_CPU;
  assert_true(fabs(t - 2 * sqrt(0.5 / 90.0)) < 0.01);
  assert_int_equal(host_motor_steps[0], 8400);
}

static void test_floor_acceleration_move_ends(void **state)
{
  // The slowest acceleration accepted, on the longest block (720 deg, where
  // a float step of the remaining distance is largest): the move ends, and
  // on time: a triangle of 2 sqrt(d/a) = 169.7 s, within 3 % (its first and
  // last steps, 1.4 s from rest, are where step timing rounds most).
  // 10 steps/deg keeps the simulation short.
  h_send("$100=10");
  h_send("$120=0.1");
  h_take();
  host_schedule_byte(board_millis() + 300000, 0x18);   // a fault waits for a reset: fail, not hang
  double t = timed_move("G1 X720 F1800") / (double)F_CPU;
  assert_string_equal(h_take(), "ok\r\n");
  assert_int_equal(host_motor_steps[0], 7200);
  assert_true(fabs(t / (2 * sqrt(720.0 / MINIMUM_ACCELERATION)) - 1) < 0.03);
}

static void test_acceleration_below_floor_is_raised(void **state)
{
  // An EEPROM written before the floor may hold a slower acceleration ($120
  // refuses it now; settings_init raises it, test_settings). The planner too
  // plans with the floor, and the move ends:
  // 1 deg as a triangle, 2 sqrt(1 / 0.1) = 6.3 s (within 3 %, as above).
  settings.acceleration[0] = 5e-26f;
  host_schedule_byte(board_millis() + 60000, 0x18);   // as above
  double t = timed_move("G1 X1 F60") / (double)F_CPU;
  assert_string_equal(h_take(), "ok\r\n");
  assert_int_equal(host_motor_steps[0], 800);
  assert_true(fabs(t / (2 * sqrt(1.0 / MINIMUM_ACCELERATION)) - 1) < 0.03);
}

static void test_step_counts_random_moves(void **state)
{
  srand(1234);
  float pos[3] = {0, 0, 0};
  for (int i = 0; i < 60; i++) {
    char line[96];
    for (int a = 0; a < 3; a++) pos[a] = (rand() % 60001 - 30000) / 1000.0f;
    int feed = 50 + rand() % 1700;
    snprintf(line, sizeof(line), "G%d X%.3f Y%.3f Z%.3f F%d", rand() % 2, pos[0], pos[1], pos[2], feed);
    h_send(line);
    assert_string_equal(h_take(), "ok\r\n");
    for (int a = 0; a < 3; a++) {
      int32_t want = nuts_lround(pos[a] * 800.0f);
      if (host_motor_steps[a] != want) fail_msg("move %d axis %d: %d steps, want %d", i, a, host_motor_steps[a], want);
      assert_int_equal(sys_position[a], want);
    }
  }
  // Never faster than the fastest axis allows (1800 deg/min x 800 steps/deg = 24 kHz).
  assert_true(host_max_step_rate_hz <= 24000 * 1.01);
}

static void test_streamed_short_moves(void **state)
{
  // Many short moves, sent as fast as the buffers take them.
  for (int i = 1; i <= 200; i++) {
    char line[32];
    snprintf(line, sizeof(line), "G1X%.3fF900\n", i * 0.037f);
    h_send_bytes(line, strlen(line));
  }
  h_run(600000);
  const char *out = h_take();
  int oks = 0;
  for (const char *p = out; (p = strstr(p, "ok\r\n")); p += 4) oks++;
  assert_int_equal(oks, 200);
  assert_int_equal(host_motor_steps[0], nuts_lround(200 * 0.037f * 800));
}

static void test_hold_decelerates_and_resume_completes(void **state)
{
  host_schedule_byte(board_millis() + 1000, '!');
  h_send("G1 X30 F600");
  assert_string_equal(h_take(), "ok\r\n");
  h_run(2000);
  assert_int_equal(sys.state, STATE_HOLD);
  assert_true(sys.suspend & SUSPEND_HOLD_COMPLETE);
  // At 1 s the stage is at ~9.44 deg; the segments already prepared (up to
  // 5 x 10 ms = 0.5 deg) run out, then it decelerates over v^2 / 2a = 0.56 deg.
  float x = host_motor_steps[0] / 800.0f;
  assert_true(x > 9.9f && x < 10.6f);
  host_advance_ms(500);
  assert_int_equal(host_motor_steps[0], (int32_t)(x * 800.0f + 0.5f));   // holds still
  h_send_bytes("~", 1);
  h_run(600000);
  assert_int_equal(sys.state, STATE_IDLE);
  assert_int_equal(host_motor_steps[0], 24000);
}

static void test_hold_where_a_block_starts(void **state)
{
  // A hold that stops where a block starts (the block before ended at rest)
  // prepares that block from rest with nothing to move. Here steps/deg times
  // degrees rounds above the block's step count (8002 / 10.0025f * 10.0025f
  // = 8002.0006), and that segment counted -1 steps into its uint16_t
  // (undefined; 65535 steps on the host). Set up as the prep meets it: the
  // block queued, the hold on, nothing prepared yet.
  queue(10.0025f, 0, 0, 600, 0);
  plan_block_t *b = plan_get_current_block();
  assert_true(ceilf((float)b->step_event_count / b->millimeters * b->millimeters) > b->step_event_count);
  sys.state = STATE_HOLD;
  sys.step_control = STEP_CONTROL_EXECUTE_HOLD;
  st_prep_buffer();
  assert_true(sys.step_control & STEP_CONTROL_END_MOTION);
  st_wake_up();
  h_run(2000);
  assert_true(sys.suspend & SUSPEND_HOLD_COMPLETE);
  assert_int_equal(host_motor_steps[0], 0);
  // '~' runs the whole block.
  h_send_bytes("~", 1);
  h_run(600000);
  assert_int_equal(sys.state, STATE_IDLE);
  assert_int_equal(host_motor_steps[0], 8002);
  assert_int_equal(sys_position[0], 8002);
}

// A fault from the segment prep: ALARM:10, nothing stepped; the reset that
// ends the critical alarm is scheduled first.
static void expect_prep_fault(const char *line)
{
  host_schedule_byte(board_millis() + 100, 0x18);
  h_send(line);
  const char *out = h_take();
  assert_non_null(strstr(out, "ALARM:10\r\n[MSG:Fault: internal error, drivers disabled]"));
  assert_int_equal(host_motor_steps[0], 0);
  assert_int_equal(sys_position[0], 0);
  // the drivers stay off from the fault to the reset (the cycle start that
  // prepared the faulting segment must not switch them on after it)
  assert_int_equal(host_enabled_in_fault, 0);
}

static void test_segment_beyond_its_step_count_faults(void **state)
{
  // Settings that $100/$110 refuse now, but an older firmware's EEPROM may
  // hold: 1e9 steps/deg and a $110 below MINIMUM_FEED_RATE, which the planner
  // raises to 1 deg/min. The whole 1e5-step block then falls in the first
  // 10 ms segment, more steps than n_step counts.
  settings.max_rate[0] = 0.001f;
  settings.steps_per_deg[0] = 1e9f;
  expect_prep_fault("G1 X0.0001 F1");
}

static void test_block_too_long_to_count_down_faults(void **state)
{
  // 1e-6 steps/deg lets a target of 1e14 deg through (1e8 steps), and mc_line
  // cuts it into 65535 blocks of 1.5e9 deg, where a float step is 128 deg.
  // The prep subtracts each part of a segment from the remaining distance on
  // its own, and at 1 deg/min even the longest segment's parts move at most
  // 43.7 deg (its last part, 2^18 x 10 ms; 87 deg in all), under half a
  // float step (64 deg): each rounds away and the block never shrinks. The
  // prep spun there. $100 refuses so coarse a drive now (MINIMUM_STEPS_PER_DEG)
  // and settings_init raises one an older firmware's EEPROM holds: the fault
  // stays as a guard.
  settings.steps_per_deg[0] = 0.000001f;
  expect_prep_fault("G1 X99999999999999 F1");
}

static void test_fault_while_homing_is_reported(void **state)
{
  // The same fault in a homing seek (1.5 deg of travel, as those settings
  // need, at 1e9 steps/deg), here after ~65 ms of accelerating at 0.1 deg/s^2
  // (the first segments count fewer steps). The prep stopped the motors, but
  // the homing loop only looked for a switch, the end of the move or a
  // reset: it waited for the reset, which said ALARM:6, and the fault came
  // only after the banner. Now the homing ends on the alarm, reported at
  // once as elsewhere (then a reset to continue).
  h_send("$22=1");
  h_send("$120=0.1");
  h_take();
  settings.max_travel[0] = 1.0f;
  settings.max_rate[0] = 0.001f;
  settings.steps_per_deg[0] = 1e9f;
  host_schedule_byte(board_millis() + 60000, 0x18);
  h_send("$HX");
  const char *out = h_take();
  const char *fault = strstr(out, "ALARM:10\r\n[MSG:Fault: internal error, drivers disabled]\r\n[MSG:Reset to continue]");
  const char *banner = strstr(out, "Grbl ");
  assert_non_null(fault);
  assert_non_null(banner);
  assert_true(fault < banner);
  assert_null(strstr(out, "ALARM:6"));
  assert_int_equal(sys.state, STATE_ALARM);
  assert_true(host_motor_steps[0] > 0);   // it faulted while moving
}

static void test_move_of_most_pieces_ends(void **state)
{
  // 5e7 deg: mc_line cuts it into its most pieces, 65535 (of 763 deg). Its
  // uint16_t piece counter wrapped after the last one and the move started
  // over from where it began, back and forth. 2e-3 steps/deg (1e5 steps, so
  // no piece is under a step) with a rate and an acceleration to match keep
  // it to seconds. (Below MINIMUM_STEPS_PER_DEG, as an older firmware's
  // EEPROM held before settings_init raised it.)
  settings.steps_per_deg[0] = 0.002f;
  h_send("$110=1000000000");
  h_send("$120=10000000000");
  h_take();
  host_schedule_byte(board_millis() + 60000, 0x18);   // a wrapped counter runs until reset: fail, not hang
  buffer_line_calls = 0;
  h_send("G1 X50000000 F1000000000");
  assert_string_equal(h_take(), "ok\r\n");
  assert_int_equal(buffer_line_calls, 65535);
  assert_int_equal(sys.state, STATE_IDLE);
  assert_int_equal(host_motor_steps[0], 100000);
  assert_int_equal(sys_position[0], 100000);
}

static void test_move_under_a_step_is_one_piece(void **state)
{
  // Less than a step in all, however far: one empty piece, not 65535 that
  // kept mc_line from any wait (and the chip's watchdog) for seconds. The
  // planner drops empty pieces and the host spends no simulated time on
  // them, so only their count tells. (Below MINIMUM_STEPS_PER_DEG, as an
  // older firmware's EEPROM held before settings_init raised it.)
  settings.steps_per_deg[0] = 0.000000000002f;
  buffer_line_calls = 0;
  h_send("G1 X999999999 F1");
  assert_int_equal(buffer_line_calls, 1);
  assert_string_equal(h_take(), "ok\r\n");
  assert_int_equal(host_motor_steps[0], 0);
  assert_null(plan_get_current_block());
}

static void test_block_over_2p24_steps_is_exact(void **state)
{
  // 719.5 deg at 23401 steps/deg (a fine drive: $110 keeps it under 40 kHz)
  // is under MAX_BLOCK_DEG but 16.8e6 steps, more than a float counts
  // exactly (2^24): the segment prep counted the block down from the step
  // count rounded to a float, and the motor made one step fewer than the
  // position wants (up to 64 at 2.4e6 steps/deg). Starting at an odd step
  // makes the step count odd, so the rounding shows.
  h_send("$110=100");
  h_send("$100=23401");
  h_send("G1 X-0.5 F100");
  assert_string_equal(h_take(), "ok\r\nok\r\nok\r\n");
  int32_t start = sys_position[0];
  int32_t want = nuts_lround(719.0f * 23401.0f);
  int32_t steps = want - start;
  assert_true(steps > (1L << 24) && (int32_t)(float)steps != steps);
  h_send("G1 X719 F100");
  assert_string_equal(h_take(), "ok\r\n");
  assert_int_equal(sys.state, STATE_IDLE);
  assert_int_equal(sys_position[0], want);
  assert_int_equal(host_motor_steps[0], want);
}

static void test_jog_longer_than_the_planner_is_a_jog(void **state)
{
  // 10 000 deg: 14 pieces of MAX_BLOCK_DEG, more than the planner holds
  // (BLOCK_BUFFER_SIZE - 1 = 9). mc_line waited for room with an automatic
  // cycle start, so the jog ran as a cycle ("Run") and 0x85, which only
  // cancels a jog, was ignored: the stage ran all 10 000 deg. Now it runs as
  // a jog while its line waits, and the cancel drops the pieces not yet
  // queued too (queued after the flush, they would run as a new jog).
  host_schedule_byte(board_millis() + 500, '?');
  host_schedule_byte(board_millis() + 600, CMD_JOG_CANCEL);
  h_send("$J=G91 X10000 F1800");
  const char *out = h_take();
  assert_non_null(strstr(out, "<Jog|"));
  assert_non_null(strstr(out, "ok\r\n"));
  assert_int_equal(sys.state, STATE_IDLE);
  assert_null(plan_get_current_block());
  // At most 30 deg/s for 0.6 s, then 5 deg to stop (v^2 / 2a).
  assert_true(host_motor_steps[0] > 0 && host_motor_steps[0] < 25 * 800);
  assert_int_equal(sys_position[0], host_motor_steps[0]);
  // The parser goes on from where the stage stopped, not from the target.
  assert_float_equal(gc_state.position[0], sys_position[0] / 800.0f, 1e-3);
}

static void test_reset_mid_move_keeps_position(void **state)
{
  host_schedule_byte(board_millis() + 700, 0x18);
  h_send("G1 X30 Y-10 F900");
  const char *out = h_take();
  assert_non_null(strstr(out, "ALARM:3"));
  assert_non_null(strstr(out, "[MSG:'$H'|'$X' to unlock]"));
  assert_int_equal(sys.state, STATE_ALARM);
  for (int a = 0; a < 3; a++) assert_int_equal(sys_position[a], host_motor_steps[a]);
  assert_true(host_motor_steps[0] > 0 && host_motor_steps[0] < 24000);
}

static void test_backlash_not_in_position(void **state)
{
  h_send("$141=0.125");
  h_send("G0 Y-1");   // first move negative: the last direction was positive -> take-up
  assert_int_equal(host_motor_steps[1], -900);
  assert_int_equal(sys_position[1], -800);
  h_send("G0 Y1");   // reversal: 2 deg + 0.125 deg take-up
  assert_int_equal(host_motor_steps[1], -900 + 1600 + 100);
  assert_int_equal(sys_position[1], 800);
  h_take();
}

static void test_idle_disables_drivers(void **state)
{
  h_send("G0 X1");
  host_advance_ms(30);
  protocol_poll();
  assert_int_equal(host_stepper_enabled, 0);
  h_send("$1=255");
  h_send("G0 X2");
  host_advance_ms(300);
  protocol_poll();
  assert_int_equal(host_stepper_enabled, 1);
}

int main(void)
{
  const struct CMUnitTest tests[] = {
    cmocka_unit_test_setup(test_single_block_profile, setup),
    cmocka_unit_test_setup(test_collinear_blocks_keep_speed, setup),
    cmocka_unit_test_setup(test_reversal_stops, setup),
    cmocka_unit_test_setup(test_corner_junction_deviation, setup),
    cmocka_unit_test_setup(test_short_blocks_limited_by_acceleration, setup),
    cmocka_unit_test_setup(test_rates_limited_per_axis, setup),
    cmocka_unit_test_setup(test_empty_move, setup),
    cmocka_unit_test_setup(test_move_time_trapezoid, setup),
    cmocka_unit_test_setup(test_floor_acceleration_move_ends, setup),
    cmocka_unit_test_setup(test_acceleration_below_floor_is_raised, setup),
    cmocka_unit_test_setup(test_step_counts_random_moves, setup),
    cmocka_unit_test_setup(test_streamed_short_moves, setup),
    cmocka_unit_test_setup(test_hold_decelerates_and_resume_completes, setup),
    cmocka_unit_test_setup(test_hold_where_a_block_starts, setup),
    cmocka_unit_test_setup(test_segment_beyond_its_step_count_faults, setup),
    cmocka_unit_test_setup(test_block_too_long_to_count_down_faults, setup),
    cmocka_unit_test_setup(test_fault_while_homing_is_reported, setup),
    cmocka_unit_test_setup(test_move_of_most_pieces_ends, setup),
    cmocka_unit_test_setup(test_move_under_a_step_is_one_piece, setup),
    cmocka_unit_test_setup(test_block_over_2p24_steps_is_exact, setup),
    cmocka_unit_test_setup(test_jog_longer_than_the_planner_is_a_jog, setup),
    cmocka_unit_test_setup(test_reset_mid_move_keeps_position, setup),
    cmocka_unit_test_setup(test_backlash_not_in_position, setup),
    cmocka_unit_test_setup(test_idle_disables_drivers, setup),
  };
  if (getenv("TEST_FILTER")) cmocka_set_test_filter(getenv("TEST_FILTER"));
  return cmocka_run_group_tests_name("motion", tests, NULL, NULL);
}
