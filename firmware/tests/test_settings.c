// Settings unit tests: CRC-16, EEPROM round trip, corruption and version
// checks, value validation, and the code tables mirrored in doc/*.csv.
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

static int setup(void **state)
{
  h_erase_eeprom();
  h_boot();
  h_take();
  return 0;
}

static void test_crc16_check_value(void **state)
{
  // CRC-16/CCITT-FALSE check value.
  assert_int_equal(crc16_ccitt(0xffff, (const uint8_t *)"123456789", 9), 0x29b1);
  assert_int_equal(crc16_ccitt(0xffff, NULL, 0), 0xffff);
}

static void test_defaults_on_blank_eeprom(void **state)
{
  h_erase_eeprom();
  h_boot();
  assert_non_null(strstr(h_take(), "[MSG:EEPROM settings failed CRC check, defaults restored]"));
  assert_float_equal(settings.steps_per_deg[0], 800.0f, 0);
  assert_int_equal(settings.pulse_microseconds, 10);
  // The restored block is valid now: the next boot is quiet.
  h_boot();
  assert_null(strstr(h_take(), "CRC"));
}

static void test_round_trip(void **state)
{
  assert_int_equal(settings_store_global_setting(101, 123.5f), STATUS_OK);
  assert_int_equal(settings_store_global_setting(26, 100), STATUS_OK);
  memset(&settings, 0, sizeof(settings));
  settings_init();
  assert_int_equal(settings_restored, 0);
  assert_float_equal(settings.steps_per_deg[1], 123.5f, 0);
  assert_int_equal(settings.homing_debounce_delay, 100);
}

static void test_every_bit_flip_is_caught(void **state)
{
  // Any single-bit error in the block (version, data or CRC) restores defaults.
  assert_int_equal(settings_store_global_setting(100, 400), STATUS_OK);
  size_t n = 1 + sizeof(settings_t) + 2;
  for (size_t addr = 0; addr < n; addr++) {
    for (int b = 0; b < 8; b++) {
      uint8_t saved[128];
      memcpy(saved, host_eeprom, sizeof(saved));
      host_eeprom[addr] ^= (uint8_t)(1 << b);
      settings_init();
      if (!settings_restored) fail_msg("flip at byte %zu bit %d not detected", addr, b);
      assert_float_equal(settings.steps_per_deg[0], 800.0f, 0);
      memcpy(host_eeprom, saved, sizeof(saved));
    }
  }
}

static void test_version_mismatch(void **state)
{
  // A block written by another firmware version (valid CRC) is not used.
  uint8_t rec[1 + sizeof(settings_t)];
  memcpy(rec, host_eeprom, sizeof(rec));
  rec[0] = SETTINGS_VERSION + 1;
  settings_store_block(EEPROM_ADDR_GLOBAL, rec, sizeof(rec));
  settings_init();
  assert_int_equal(settings_restored, 1);
}

static void test_coord_records(void **state)
{
  float a[N_AXIS] = {1.5f, -2.25f, 3.0f}, b[N_AXIS];
  settings_write_coord_data(4, a);
  assert_int_equal(settings_read_coord_data(4, b), 1);
  assert_memory_equal(a, b, sizeof(a));
  host_eeprom[EEPROM_ADDR_PARAMETERS + 4 * 14 + 2] ^= 1;
  assert_int_equal(settings_read_coord_data(4, b), 0);
  assert_float_equal(b[0], 0.0f, 0);
  assert_int_equal(settings_read_coord_data(4, b), 1);   // cleared and rewritten
}

static void test_validation(void **state)
{
  assert_int_equal(settings_store_global_setting(0, 2), STATUS_SETTING_STEP_PULSE_MIN);
  assert_int_equal(settings_store_global_setting(0, 101), STATUS_INVALID_STATEMENT);
  // The rest of error:3's ranges (doc/error_codes.csv): $1 above 255, any
  // of $0-$27 above 65535; a mask above 255 is masked.
  assert_int_equal(settings_store_global_setting(1, 256), STATUS_INVALID_STATEMENT);
  assert_int_equal(settings_store_global_setting(26, 65536), STATUS_INVALID_STATEMENT);
  assert_int_equal(settings_store_global_setting(11, 65536), STATUS_INVALID_STATEMENT);
  assert_int_equal(settings_store_global_setting(3, 65536), STATUS_INVALID_STATEMENT);
  assert_int_equal(settings_store_global_setting(3, 256), STATUS_OK);
  assert_int_equal(settings.dir_invert_mask, 0);
  assert_int_equal(settings_store_global_setting(110, 4000), STATUS_MAX_STEP_RATE_EXCEEDED);
  assert_int_equal(settings_store_global_setting(100, 2000), STATUS_MAX_STEP_RATE_EXCEEDED);
  assert_int_equal(settings_store_global_setting(120, 0), STATUS_NEGATIVE_VALUE);
  // A $110 below MINIMUM_FEED_RATE runs at it (the planner's floor), so the
  // step rate check takes the floor's: 1 deg/min x 2.4e6 steps/deg = 40 kHz.
  assert_int_equal(settings_store_global_setting(110, 0.001f), STATUS_OK);
  assert_int_equal(settings_store_global_setting(100, 3e6f), STATUS_MAX_STEP_RATE_EXCEEDED);
  assert_int_equal(settings_store_global_setting(100, 2.4e6f), STATUS_OK);
  assert_int_equal(settings_store_global_setting(110, 0.5f), STATUS_OK);
  assert_int_equal(settings_store_global_setting(110, 1.5f), STATUS_MAX_STEP_RATE_EXCEEDED);
  assert_int_equal(settings_store_global_setting(100, 800), STATUS_OK);
  assert_int_equal(settings_store_global_setting(103, 1), STATUS_INVALID_STATEMENT);
  assert_int_equal(settings_store_global_setting(143, 1), STATUS_INVALID_STATEMENT);
  assert_int_equal(settings_store_global_setting(150, 1), STATUS_INVALID_STATEMENT);
  assert_int_equal(settings_store_global_setting(12, 1), STATUS_INVALID_STATEMENT);
  assert_int_equal(settings_store_global_setting(13, 0), STATUS_OK);
  assert_int_equal(settings_store_global_setting(13, 1), STATUS_SETTING_DISABLED);
  assert_int_equal(settings_store_global_setting(20, 1), STATUS_SOFT_LIMIT_ERROR);
  assert_int_equal(settings_store_global_setting(22, 1), STATUS_OK);
  assert_int_equal(settings_store_global_setting(20, 1), STATUS_OK);
  assert_int_equal(settings_store_global_setting(22, 0), STATUS_OK);
  assert_false(settings.flags & BITFLAG_SOFT_LIMIT_ENABLE);   // soft limits follow homing off
  assert_int_equal(settings_store_global_setting(140, 0.05f), STATUS_OK);
  assert_float_equal(settings.backlash[0], 0.05f, 0);
  assert_int_equal(settings_store_global_setting(2, 7), STATUS_OK);
  assert_int_equal(settings.step_invert_mask, 7);
}

static void test_steps_per_deg_floor(void **state)
{
  // Below MINIMUM_STEPS_PER_DEG the segment prep passes for long without a
  // step: refused as out of range; 0 keeps error:12.
  assert_int_equal(settings_store_global_setting(100, 1e-9f), STATUS_INVALID_STATEMENT);
  assert_int_equal(settings_store_global_setting(101, MINIMUM_STEPS_PER_DEG * 0.9f), STATUS_INVALID_STATEMENT);
  assert_int_equal(settings_store_global_setting(102, 0), STATUS_MAX_STEP_RATE_EXCEEDED);
  for (int i = 0; i < N_AXIS; i++) assert_float_equal(settings.steps_per_deg[i], 800.0f, 0);
  uint8_t at = 0;
  float v;
  assert_true(read_float("0.01", &at, &v));
  assert_int_equal(settings_store_global_setting(100, v), STATUS_OK);
  assert_float_equal(settings.steps_per_deg[0], v, 0);
  at = 0;
  assert_true(read_float("0.0099999", &at, &v));
  assert_int_equal(settings_store_global_setting(101, v), STATUS_INVALID_STATEMENT);
}

static void test_acceleration_floor(void **state)
{
  // Below MINIMUM_ACCELERATION the segment prep never gets a move going:
  // refused as out of range; 0 and negatives keep error:4.
  assert_int_equal(settings_store_global_setting(120, 5e-26f), STATUS_INVALID_STATEMENT);
  assert_int_equal(settings_store_global_setting(121, MINIMUM_ACCELERATION * 0.9f), STATUS_INVALID_STATEMENT);
  assert_int_equal(settings_store_global_setting(122, 0), STATUS_NEGATIVE_VALUE);
  assert_int_equal(settings_store_global_setting(122, -1), STATUS_NEGATIVE_VALUE);
  for (int i = 0; i < N_AXIS; i++) assert_float_equal(settings.acceleration[i], 90.0f, 0);
  // The floor itself, also as "0.10" reads it (a float step below 0.1f).
  assert_int_equal(settings_store_global_setting(120, MINIMUM_ACCELERATION), STATUS_OK);
  assert_float_equal(settings.acceleration[0], MINIMUM_ACCELERATION, 0);
  assert_int_equal(settings_store_global_setting(121, nextafterf(MINIMUM_ACCELERATION, 0)), STATUS_OK);
  // Two float steps under are let through, three are refused.
  float two_under = nextafterf(nextafterf(MINIMUM_ACCELERATION, 0), 0);
  assert_int_equal(settings_store_global_setting(121, two_under), STATUS_OK);
  assert_int_equal(settings_store_global_setting(121, nextafterf(two_under, 0)), STATUS_INVALID_STATEMENT);
  // As typed: the floor however many zeros follow, and nothing visibly below.
  static const char *const typed[] = {"0.1", "0.10", "0.100", "0.1000", "0.10000000", ".1"};
  for (size_t i = 0; i < sizeof(typed) / sizeof(typed[0]); i++) {
    uint8_t at = 0;
    float v;
    assert_true(read_float(typed[i], &at, &v));
    assert_int_equal(settings_store_global_setting(122, v), STATUS_OK);
  }
  static const char *const below[] = {"0.099999", "0.09999999"};
  for (size_t i = 0; i < sizeof(below) / sizeof(below[0]); i++) {
    uint8_t at = 0;
    float v;
    assert_true(read_float(below[i], &at, &v));
    assert_int_equal(settings_store_global_setting(122, v), STATUS_INVALID_STATEMENT);
  }
}

static void test_values_below_floors_raised_at_load(void **state)
{
  // An EEPROM written before the floors can hold what $100 and $120 refuse
  // now, with a good CRC and version. Loaded as is, '$$' showed the tiny
  // acceleration while the planner used MINIMUM_ACCELERATION, and a tiny
  // $100 kept the segment prep passing without a step. Raised to the
  // floors at load, the rest of the record kept.
  assert_int_equal(settings_store_global_setting(2, 5), STATUS_OK);
  struct {
    uint8_t version;
    settings_t s;
  } rec;
  assert_true(settings_load_block(EEPROM_ADDR_GLOBAL, &rec, sizeof(rec)));
  rec.s.steps_per_deg[0] = 1e-9f;
  rec.s.steps_per_deg[2] = 0.0f;
  rec.s.acceleration[1] = 5e-26f;
  rec.s.acceleration[2] = MINIMUM_ACCELERATION * 0.5f;
  settings_store_block(EEPROM_ADDR_GLOBAL, &rec, sizeof(rec));
  h_boot();
  const char *out = h_take();
  assert_null(strstr(out, "defaults restored"));
  assert_int_equal(settings.step_invert_mask, 5);
  assert_float_equal(settings.steps_per_deg[0], MINIMUM_STEPS_PER_DEG, 0);
  assert_float_equal(settings.steps_per_deg[1], 800.0f, 0);
  assert_float_equal(settings.steps_per_deg[2], MINIMUM_STEPS_PER_DEG, 0);
  assert_float_equal(settings.acceleration[0], 90.0f, 0);
  assert_float_equal(settings.acceleration[1], MINIMUM_ACCELERATION, 0);
  assert_float_equal(settings.acceleration[2], MINIMUM_ACCELERATION, 0);
  h_send("$$");
  out = h_take();
  assert_non_null(strstr(out, "$100=0.010\r\n$101=800.000\r\n$102=0.010\r\n"));
  assert_non_null(strstr(out, "$120=90.000\r\n$121=0.100\r\n$122=0.100\r\n"));
}

// doc/error_codes.csv and doc/alarm_codes.csv list exactly the codes of codes.h.
static void check_csv(const char *path, const int *codes, size_t n)
{
  FILE *f = fopen(path, "r");
  assert_non_null(f);
  char line[512];
  size_t seen = 0;
  assert_non_null(fgets(line, sizeof(line), f));   // header
  while (fgets(line, sizeof(line), f)) {
    int code = atoi(line + 1);
    if (seen >= n || code != codes[seen]) fail_msg("%s: row %zu has code %d", path, seen + 1, code);
    seen++;
  }
  fclose(f);
  assert_int_equal(seen, n);
}

static void test_code_tables(void **state)
{
  static const int errors[] = {
    STATUS_EXPECTED_COMMAND_LETTER, STATUS_BAD_NUMBER_FORMAT, STATUS_INVALID_STATEMENT, STATUS_NEGATIVE_VALUE,
    STATUS_SETTING_DISABLED, STATUS_SETTING_STEP_PULSE_MIN, STATUS_SETTING_READ_FAIL, STATUS_IDLE_ERROR,
    STATUS_SYSTEM_GC_LOCK, STATUS_SOFT_LIMIT_ERROR, STATUS_OVERFLOW, STATUS_MAX_STEP_RATE_EXCEEDED,
    STATUS_CHECK_DOOR, STATUS_LINE_LENGTH_EXCEEDED, STATUS_TRAVEL_EXCEEDED, STATUS_INVALID_JOG_COMMAND,
    STATUS_SETTING_DISABLED_LASER, STATUS_GCODE_UNSUPPORTED_COMMAND, STATUS_GCODE_MODAL_GROUP_VIOLATION,
    STATUS_GCODE_UNDEFINED_FEED_RATE, STATUS_GCODE_COMMAND_VALUE_NOT_INTEGER, STATUS_GCODE_AXIS_COMMAND_CONFLICT,
    STATUS_GCODE_WORD_REPEATED, STATUS_GCODE_NO_AXIS_WORDS, STATUS_GCODE_INVALID_LINE_NUMBER,
    STATUS_GCODE_VALUE_WORD_MISSING, STATUS_GCODE_UNSUPPORTED_COORD_SYS, STATUS_GCODE_G53_INVALID_MOTION_MODE,
    STATUS_GCODE_AXIS_WORDS_EXIST, STATUS_GCODE_NO_AXIS_WORDS_IN_PLANE, STATUS_GCODE_INVALID_TARGET,
    STATUS_GCODE_ARC_RADIUS_ERROR, STATUS_GCODE_NO_OFFSETS_IN_PLANE, STATUS_GCODE_UNUSED_WORDS,
    STATUS_GCODE_G43_DYNAMIC_AXIS_ERROR, STATUS_GCODE_MAX_VALUE_EXCEEDED,
  };
  static const int alarms[] = {
    EXEC_ALARM_HARD_LIMIT, EXEC_ALARM_SOFT_LIMIT, EXEC_ALARM_ABORT_CYCLE, EXEC_ALARM_PROBE_FAIL_INITIAL,
    EXEC_ALARM_PROBE_FAIL_CONTACT, EXEC_ALARM_HOMING_FAIL_RESET, EXEC_ALARM_HOMING_FAIL_DOOR,
    EXEC_ALARM_HOMING_FAIL_PULLOFF, EXEC_ALARM_HOMING_FAIL_APPROACH, EXEC_ALARM_FAULT,
  };
  check_csv("doc/error_codes.csv", errors, sizeof(errors) / sizeof(errors[0]));
  check_csv("doc/alarm_codes.csv", alarms, sizeof(alarms) / sizeof(alarms[0]));
}

int main(void)
{
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_crc16_check_value),
    cmocka_unit_test_setup(test_defaults_on_blank_eeprom, setup),
    cmocka_unit_test_setup(test_round_trip, setup),
    cmocka_unit_test_setup(test_every_bit_flip_is_caught, setup),
    cmocka_unit_test_setup(test_version_mismatch, setup),
    cmocka_unit_test_setup(test_coord_records, setup),
    cmocka_unit_test_setup(test_validation, setup),
    cmocka_unit_test_setup(test_acceleration_floor, setup),
    cmocka_unit_test_setup(test_steps_per_deg_floor, setup),
    cmocka_unit_test_setup(test_values_below_floors_raised_at_load, setup),
    cmocka_unit_test(test_code_tables),
  };
  return cmocka_run_group_tests_name("settings", tests, NULL, NULL);
}
