// '$' settings kept in EEPROM behind a CRC-16, and the stored coordinate data.
// GRBL protects each block with an 8-bit additive checksum that misses many
// errors; here every block carries a CRC-16/CCITT-FALSE, and the settings
// block also a version byte.
#include <stddef.h>
#include <string.h>
#include "settings.h"
#include "pgmspace.h"
#include "codes.h"
#include "nuts.h"
#include "board.h"     // board_eeprom_*, board_stepper_config, board_limits_irq
#include "stepper.h"   // st_generate_step_dir_invert_masks
#include "limits.h"    // limits_init

settings_t settings;
uint8_t settings_restored;

// Defaults: 200 steps x 16 microsteps x 90:1 worm / 360 deg = 800 steps/deg.
static const settings_t settings_defaults PROGMEM = {
  .steps_per_deg = {800.0f, 800.0f, 800.0f},
  .max_rate = {1800.0f, 1800.0f, 1800.0f},        // 30 deg/s = 24 kHz
  .acceleration = {90.0f, 90.0f, 90.0f},          // deg/s^2
  .max_travel = {360.0f, 360.0f, 360.0f},
  .backlash = {0.0f, 0.0f, 0.0f},
  .junction_deviation = 0.01f,
  .homing_feed_rate = 60.0f,
  .homing_seek_rate = 600.0f,
  .homing_pulloff = 1.0f,
  .homing_debounce_delay = 250,
  .pulse_microseconds = 10,
  .stepper_idle_lock_time = 25,
  .step_invert_mask = 0,
  .dir_invert_mask = 0,
  .status_report_mask = 1,
  .homing_dir_mask = 0,
  .flags = 0,
};

#define SET_AT(field) offsetof(settings_t, field)
const uint8_t settings_table[N_SETTINGS_TABLE][4] PROGMEM = {
  {0, SET_U8, SET_AT(pulse_microseconds), 0},      // 3..100
  {1, SET_U8, SET_AT(stepper_idle_lock_time), 0},  // 0..255
  {2, SET_U8, SET_AT(step_invert_mask), 7},
  {3, SET_U8, SET_AT(dir_invert_mask), 7},
  {4, SET_FLAG, BITFLAG_INVERT_ST_ENABLE, 0},
  {5, SET_FLAG, BITFLAG_INVERT_LIMIT_PINS, 0},
  {10, SET_U8, SET_AT(status_report_mask), 3},
  {11, SET_FLOAT, SET_AT(junction_deviation), 0},
  {13, SET_FLAG, BITFLAG_REPORT_INCHES, 0},        // inches: never (degrees)
  {20, SET_FLAG, BITFLAG_SOFT_LIMIT_ENABLE, 0},    // needs homing
  {21, SET_FLAG, BITFLAG_HARD_LIMIT_ENABLE, 0},
  {22, SET_FLAG, BITFLAG_HOMING_ENABLE, 0},        // off: soft limits off too
  {23, SET_U8, SET_AT(homing_dir_mask), 7},
  {24, SET_FLOAT, SET_AT(homing_feed_rate), 1},
  {25, SET_FLOAT, SET_AT(homing_seek_rate), 1},
  {26, SET_U16, SET_AT(homing_debounce_delay), 0},
  {27, SET_FLOAT, SET_AT(homing_pulloff), 0},
};

void settings_store_block(uint16_t addr, const void *data, uint16_t size)
{
  const uint8_t *p = data;
  uint16_t crc = crc16_ccitt(0xffff, p, size);
  for (uint16_t i = 0; i < size; i++) {
    if (board_eeprom_read(addr + i) != p[i]) board_eeprom_write(addr + i, p[i]);
    board_idle();
  }
  board_eeprom_write(addr + size, crc & 0xff);
  board_eeprom_write(addr + size + 1, crc >> 8);
}

uint8_t settings_load_block(uint16_t addr, void *data, uint16_t size)
{
  uint8_t *p = data;
  for (uint16_t i = 0; i < size; i++) p[i] = board_eeprom_read(addr + i);
  uint16_t crc = crc16_ccitt(0xffff, p, size);
  uint16_t stored = board_eeprom_read(addr + size) | ((uint16_t)board_eeprom_read(addr + size + 1) << 8);
  return crc == stored;
}

typedef struct {
  uint8_t version;
  settings_t s;
} settings_record_t;

static void settings_write_global(void)
{
  settings_record_t rec;
  rec.version = SETTINGS_VERSION;
  memcpy(&rec.s, &settings, sizeof(settings));
  settings_store_block(EEPROM_ADDR_GLOBAL, &rec, sizeof(rec));
}

void settings_write_coord_data(uint8_t index, const float *coord)
{
  settings_store_block(EEPROM_ADDR_PARAMETERS + index * (N_AXIS * sizeof(float) + 2), coord, N_AXIS * sizeof(float));
}

uint8_t settings_read_coord_data(uint8_t index, float *coord)
{
  if (!settings_load_block(EEPROM_ADDR_PARAMETERS + index * (N_AXIS * sizeof(float) + 2), coord, N_AXIS * sizeof(float))) {
    memset(coord, 0, N_AXIS * sizeof(float));
    settings_write_coord_data(index, coord);
    return 0;
  }
  return 1;
}

#define BUILD_INFO_SIZE 41   // 40 characters + NUL

// Text records ($I, $N0, $N1): the string padded with NULs, then a CRC.
static void store_string(uint16_t addr, const char *line, uint8_t size)
{
  char buf[LINE_BUFFER_SIZE];
  memset(buf, 0, sizeof(buf));
  strncpy(buf, line, size - 1);
  settings_store_block(addr, buf, size);
}

// A bad record reads as empty and is rewritten empty.
static uint8_t read_string(uint16_t addr, char *line, uint8_t size)
{
  if (!settings_load_block(addr, line, size)) {
    store_string(addr, "", size);
    line[0] = 0;
    return 0;
  }
  line[size - 1] = 0;
  return 1;
}

void settings_store_build_info(const char *line)
{
  store_string(EEPROM_ADDR_BUILD_INFO, line, BUILD_INFO_SIZE);
}

uint8_t settings_read_build_info(char *line)
{
  return read_string(EEPROM_ADDR_BUILD_INFO, line, BUILD_INFO_SIZE);
}

#define STARTUP_ADDR(n) (EEPROM_ADDR_STARTUP_BLOCK + (n) * (LINE_BUFFER_SIZE + 2))

void settings_store_startup_line(uint8_t n, const char *line)
{
  store_string(STARTUP_ADDR(n), line, LINE_BUFFER_SIZE);
}

uint8_t settings_read_startup_line(uint8_t n, char *line)
{
  return read_string(STARTUP_ADDR(n), line, LINE_BUFFER_SIZE);
}

void settings_restore(uint8_t restore_flag)
{
  if (restore_flag & SETTINGS_RESTORE_DEFAULTS) {
    memcpy_P(&settings, &settings_defaults, sizeof(settings));
    settings_write_global();
  }
  if (restore_flag & SETTINGS_RESTORE_PARAMETERS) {
    float coord[N_AXIS] = {0};
    for (uint8_t i = 0; i < SETTING_INDEX_NCOORD; i++) settings_write_coord_data(i, coord);
  }
  if (restore_flag & SETTINGS_RESTORE_BUILD_INFO) settings_store_build_info("");
  if (restore_flag & SETTINGS_RESTORE_STARTUP_LINES)
    for (uint8_t n = 0; n < N_STARTUP_LINE; n++) settings_store_startup_line(n, "");
  settings_apply();
}

void settings_apply(void)
{
  st_generate_step_dir_invert_masks();
  limits_init();
}

// Below a floor (config.h), as $0=101 is above its range. Decimal input reads
// up to a float step off ("0.10" lands a step below 0.1f): two float steps
// under the floor (floor * 0.9999998f, folded at compile time; avr-libc has no
// nextafterf) are let through, three and more are below it (and NaN).
static uint8_t below_floor(float value, float floor)
{
  return !(value >= floor * 0.9999998f);
}

// A record written before the floors (config.h) can hold $100-$102 below
// MINIMUM_STEPS_PER_DEG or $120-$122 below MINIMUM_ACCELERATION, which the
// settings check refuses now. Those are raised to the floor, not taken as a
// corrupt record: restoring defaults would also drop the direction and limit
// inversions, homing and travel the stage was set up with, and be reported
// as a CRC failure it was not. The planner already used the acceleration
// floor, so motion is unchanged and '$$' now reports what is used; no drive
// is that coarse (a step per 100 deg), and below it the segment prep passed
// for long without a step. Exactly the values the check refuses (zero and
// NaN too); one it let through stays as entered. Only in RAM: the next
// stored setting writes the raised values.
static void settings_raise_to_floors(void)
{
  for (uint8_t i = 0; i < N_AXIS; i++) {
    if (below_floor(settings.steps_per_deg[i], MINIMUM_STEPS_PER_DEG)) settings.steps_per_deg[i] = MINIMUM_STEPS_PER_DEG;
    if (below_floor(settings.acceleration[i], MINIMUM_ACCELERATION)) settings.acceleration[i] = MINIMUM_ACCELERATION;
  }
}

void settings_init(void)
{
  settings_record_t rec;
  settings_restored = 0;
  if (!settings_load_block(EEPROM_ADDR_GLOBAL, &rec, sizeof(rec)) || rec.version != SETTINGS_VERSION) {
    settings_restored = 1;
    settings_restore(SETTINGS_RESTORE_ALL);
  } else {
    memcpy(&settings, &rec.s, sizeof(settings));
    settings_raise_to_floors();
    settings_apply();
  }
}

// An axis' fastest step rate stays within MAX_STEP_RATE_HZ. The planner
// raises slower feeds to MINIMUM_FEED_RATE, also past a lower $110: with a
// huge $100 that floor alone would ask for MHz (a segment of more steps than
// it counts).
static uint8_t settings_step_rate_ok(float steps_per_deg, float max_rate)
{
  return steps_per_deg * max(max_rate, MINIMUM_FEED_RATE) <= MAX_STEP_RATE_HZ * 60.0f;
}

uint8_t settings_store_global_setting(uint8_t parameter, float value)
{
  if (value < 0.0f) return STATUS_NEGATIVE_VALUE;
  if (parameter >= 100) {
    // $100-$142: parameter = 100 + 10 * set_idx + idx, set_idx picking one of
    // the five per-axis float groups that open settings_t (in this order).
    uint8_t idx = parameter - 100;
    uint8_t set_idx = 0;
    while (idx >= 10) {
      idx -= 10;
      set_idx++;
    }
    if (set_idx >= 5 || idx >= N_AXIS) return STATUS_INVALID_STATEMENT;
    if (set_idx <= 1) {
      // $10x and $11x: the step rate with the new value in its place
      float steps_per_deg = set_idx ? settings.steps_per_deg[idx] : value;
      float max_rate = set_idx ? value : settings.max_rate[idx];
      if (!settings_step_rate_ok(steps_per_deg, max_rate) || value <= 0.0f) return STATUS_MAX_STEP_RATE_EXCEEDED;
    }
    switch (set_idx) {
      case 0:
        if (below_floor(value, MINIMUM_STEPS_PER_DEG)) return STATUS_INVALID_STATEMENT;
        break;
      case 2:
        if (value <= 0.0f) return STATUS_NEGATIVE_VALUE;
        // the two float steps let through are raised by the planner
        if (below_floor(value, MINIMUM_ACCELERATION)) return STATUS_INVALID_STATEMENT;
        break;
      case 4:
        if (value * settings.steps_per_deg[idx] > 30000.0f) return STATUS_MAX_STEP_RATE_EXCEEDED;
        break;
    }
    memcpy((uint8_t *)&settings + (N_AXIS * set_idx + idx) * sizeof(float), &value, sizeof(value));
  } else {
    if (value > 65535.0f) return STATUS_INVALID_STATEMENT;
    uint16_t int_value = (uint16_t)(value + 0.5f);
    uint8_t i = 0;
    while (pgm_read_byte(&settings_table[i][0]) != parameter)
      if (++i == N_SETTINGS_TABLE) return STATUS_INVALID_STATEMENT;
    uint8_t kind = pgm_read_byte(&settings_table[i][1]);
    uint8_t arg = pgm_read_byte(&settings_table[i][2]);
    uint8_t lim = pgm_read_byte(&settings_table[i][3]);
    uint8_t *field = (uint8_t *)&settings + arg;
    if (kind == SET_FLOAT) {
      if (lim && value <= 0.0f) return STATUS_NEGATIVE_VALUE;
      memcpy(field, &value, sizeof(value));
    } else if (kind == SET_U16) {
      memcpy(field, &int_value, sizeof(int_value));
    } else if (kind == SET_U8) {
      if (parameter == 0 && int_value < 3) return STATUS_SETTING_STEP_PULSE_MIN;
      if (int_value > (parameter ? 255 : 100)) {
        if (!lim) return STATUS_INVALID_STATEMENT;
      }
      *field = lim ? (int_value & lim) : int_value;
    } else if (int_value) {   // SET_FLAG on
      if (arg == BITFLAG_REPORT_INCHES) return STATUS_SETTING_DISABLED;
      if (arg == BITFLAG_SOFT_LIMIT_ENABLE && bit_isfalse(settings.flags, BITFLAG_HOMING_ENABLE)) return STATUS_SOFT_LIMIT_ERROR;
      settings.flags |= arg;
    } else {                  // SET_FLAG off; homing off takes soft limits with it
      settings.flags &= ~(arg == BITFLAG_HOMING_ENABLE ? arg | BITFLAG_SOFT_LIMIT_ENABLE : arg);
    }
  }
  settings_write_global();
  settings_apply();
  return STATUS_OK;
}
