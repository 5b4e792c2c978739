// '$' settings kept in EEPROM behind a CRC-16, and the stored coordinate data.
#ifndef SETTINGS_H
#define SETTINGS_H

#include <stddef.h>
#include <stdint.h>
#include "config.h"

#define SETTINGS_VERSION 1   // bump when settings_t changes: old blocks fail the check

// settings.flags
#define BITFLAG_INVERT_ST_ENABLE (1 << 0)
#define BITFLAG_INVERT_LIMIT_PINS (1 << 1)
#define BITFLAG_SOFT_LIMIT_ENABLE (1 << 2)
#define BITFLAG_HARD_LIMIT_ENABLE (1 << 3)
#define BITFLAG_HOMING_ENABLE (1 << 4)
#define BITFLAG_REPORT_INCHES (1 << 5)  // never set: degrees only

#define SETTINGS_RESTORE_DEFAULTS (1 << 0)
#define SETTINGS_RESTORE_PARAMETERS (1 << 1)
#define SETTINGS_RESTORE_BUILD_INFO (1 << 2)
#define SETTINGS_RESTORE_STARTUP_LINES (1 << 3)
#define SETTINGS_RESTORE_ALL 0xff

// EEPROM layout: [version][settings_t][crc16] at 0, coordinate records
// (3 floats + crc16) from 128, build info (string + crc16) from 256, the
// $N0/$N1 startup blocks (line + crc16 each) from 320.
#define EEPROM_ADDR_GLOBAL 0U
#define EEPROM_ADDR_PARAMETERS 128U
#define EEPROM_ADDR_BUILD_INFO 256U
#define EEPROM_ADDR_STARTUP_BLOCK 320U
#define N_STARTUP_LINE 2
#define SETTING_INDEX_G28 N_COORDINATE_SYSTEM
#define SETTING_INDEX_G30 (N_COORDINATE_SYSTEM + 1)
#define SETTING_INDEX_NCOORD (N_COORDINATE_SYSTEM + 2)

// The five per-axis groups come first and in this order: '$$' and
// settings_store_global_setting reach $1g0 + i at float N_AXIS * g + i.
typedef struct {
  float steps_per_deg[N_AXIS];   // $100-$102 steps/deg
  float max_rate[N_AXIS];        // $110-$112 deg/min
  float acceleration[N_AXIS];    // $120-$122 deg/s^2 (stored as entered)
  float max_travel[N_AXIS];      // $130-$132 deg, positive
  float backlash[N_AXIS];        // $140-$142 deg (not GRBL)
  float junction_deviation;      // $11 deg
  float homing_feed_rate;        // $24 deg/min
  float homing_seek_rate;        // $25 deg/min
  float homing_pulloff;          // $27 deg
  uint16_t homing_debounce_delay; // $26 ms
  uint8_t pulse_microseconds;    // $0 us
  uint8_t stepper_idle_lock_time; // $1 ms, 255 = keep enabled
  uint8_t step_invert_mask;      // $2
  uint8_t dir_invert_mask;       // $3
  uint8_t status_report_mask;    // $10
  uint8_t homing_dir_mask;       // $23
  uint8_t flags;                 // $4 $5 $20 $21 $22 as BITFLAG_*
} settings_t;
_Static_assert(offsetof(settings_t, steps_per_deg) == 0 && offsetof(settings_t, max_rate) == N_AXIS * sizeof(float) &&
               offsetof(settings_t, acceleration) == 2 * N_AXIS * sizeof(float) &&
               offsetof(settings_t, max_travel) == 3 * N_AXIS * sizeof(float) &&
               offsetof(settings_t, backlash) == 4 * N_AXIS * sizeof(float), "the per-axis groups open settings_t");

// '$0'..'$27': {number, SET_*, offset in settings_t or flag bit, limit}, in
// program memory; the limit is the mask of a SET_U8 (0: checked in code) and
// 1 for a SET_FLOAT that must be above 0.
enum { SET_U8, SET_U16, SET_FLAG, SET_FLOAT };
#define N_SETTINGS_TABLE 17
extern const uint8_t settings_table[N_SETTINGS_TABLE][4];

extern settings_t settings;
extern uint8_t settings_restored;  // 1 when the last load failed the check (reported after the banner)

void settings_init(void);                                  // main, at boot: load or restore defaults
void settings_restore(uint8_t restore_flag);               // main loop: write defaults (SETTINGS_RESTORE_*)
uint8_t settings_store_global_setting(uint8_t parameter, float value); // main loop: $N=value; status code
uint8_t settings_read_coord_data(uint8_t index, float *coord); // main loop: 1 when the record's CRC is good
void settings_write_coord_data(uint8_t index, const float *coord); // main loop
uint8_t settings_read_build_info(char *line);              // main loop: 1 when the CRC is good
void settings_store_build_info(const char *line);          // main loop
uint8_t settings_read_startup_line(uint8_t n, char *line); // main loop: $Nn into line[LINE_BUFFER_SIZE]; 1 when the CRC is good
void settings_store_startup_line(uint8_t n, const char *line); // main loop
uint8_t settings_load_block(uint16_t addr, void *data, uint16_t size); // main loop: read + check CRC; 1 when good
void settings_store_block(uint16_t addr, const void *data, uint16_t size); // main loop: write data + CRC
void settings_apply(void);                                 // main loop: push step/limit settings to the board

#endif
