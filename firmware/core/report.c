// Everything the firmware prints: ok/error, alarms, messages, reports.
// Line endings are "\r\n" as in GRBL 1.1.
#include <stddef.h>
#include <string.h>
#include "report.h"
#include "pgmspace.h"
#include "config.h"
#include "codes.h"
#include "nuts.h"
#include "serial.h"    // serial_write
#include "system.h"    // sys, sys_position
#include "settings.h"  // settings
#include "gcode.h"     // gc_state
#include "planner.h"   // plan_get_block_buffer_available
#include "stepper.h"   // st_get_realtime_rate
#include "limits.h"    // limits_get_state

void printString(const char *s)
{
  while (*s) serial_write(*s++);
}

void printPgmString(const char *s)
{
  char c;
  while ((c = pgm_read_byte(s++))) serial_write(c);
}

void print_uint32(uint32_t n)
{
  // Through printFloat: one digit loop in flash instead of two. Exact below
  // 2^24, and nothing printed here comes near it (codes, setting numbers and
  // values, buffer counts, overrides).
  printFloat((float)n, 0);
}

void printFloat(float n, uint8_t decimals)
{
  if (n < 0) { serial_write('-'); n = -n; }
  uint8_t d = decimals;
  while (d >= 2) { n *= 100; d -= 2; }
  if (d) n *= 10;
  n += 0.5f;
  if (n > 4.0e9f) n = 4.0e9f;   // clamp: keeps the integer conversion defined
  uint32_t a = (uint32_t)n;
  char buf[13];
  uint8_t i = 0;
  while (a > 0 || i <= decimals) {
    if (decimals && i == decimals) buf[i++] = '.';
    buf[i++] = '0' + a % 10;
    a /= 10;
  }
  if (decimals && buf[i - 1] == '.') buf[i++] = '0';
  while (i > 0) serial_write(buf[--i]);
}

// "a,b" (Bf, Ov, OPT)
static void print_uint_pair(uint8_t a, uint8_t b)
{
  print_uint32(a);
  serial_write(',');
  print_uint32(b);
}

static void print_axis_values(const float *v)
{
  for (uint8_t i = 0; i < N_AXIS; i++) {
    printFloat(v[i], N_DECIMAL_COORDVALUE);
    if (i < N_AXIS - 1) serial_write(',');
  }
}

static void report_eol(void)
{
  serial_write('\r');
  serial_write('\n');
}

void report_status_message(uint8_t status)
{
  if (status == STATUS_OK) {
    printPgmString(PSTR("ok\r\n"));
  } else {
    printPgmString(PSTR("error:"));
    print_uint32(status);
    report_eol();
  }
}

void report_alarm_message(uint8_t alarm)
{
  printPgmString(PSTR("ALARM:"));
  print_uint32(alarm);
  report_eol();
}

// The [MSG:...] texts by number (MESSAGE_* in report.h, from 1; 6 unused),
// one string with NUL between them: smaller than a switch of calls.
static const char feedback_messages[] PROGMEM =
  "Reset to continue\0"                                   // 1 MESSAGE_CRITICAL_EVENT
  "'$H'|'$X' to unlock\0"                                 // 2 MESSAGE_ALARM_LOCK
  "Caution: Unlocked\0"                                   // 3 MESSAGE_ALARM_UNLOCK
  "Enabled\0"                                             // 4 MESSAGE_ENABLED
  "Disabled\0"                                            // 5 MESSAGE_DISABLED
  "\0"                                                    // 6
  "Check Limits\0"                                        // 7 MESSAGE_CHECK_LIMITS
  "Pgm End\0"                                             // 8 MESSAGE_PROGRAM_END
  "Restoring defaults\0"                                  // 9 MESSAGE_RESTORE_DEFAULTS
  "EEPROM settings failed CRC check, defaults restored\0" // 10 MESSAGE_SETTINGS_CRC
  "Fault: watchdog reset, drivers disabled\0"             // 11 MESSAGE_FAULT_WATCHDOG
  "Fault: internal error, drivers disabled\0"             // 12 MESSAGE_FAULT_INTERNAL
  "Coordinate data failed CRC check, cleared";            // 13 MESSAGE_COORD_CRC

// The n-th (from 0) of the NUL-separated strings in flash at list.
static void print_pgm_nth(const char *list, uint8_t n)
{
  while (n--) while (pgm_read_byte(list++)) {}
  printPgmString(list);
}

void report_feedback_message(uint8_t message)
{
  printPgmString(PSTR("[MSG:"));
  print_pgm_nth(feedback_messages, message - 1);
  printPgmString(PSTR("]\r\n"));
}

void report_init_message(void)
{
  printPgmString(PSTR("\r\nGrbl " GRBL_VERSION " ['$' for help]\r\n"));
  printPgmString(PSTR("[MSG:" FIRMWARE_NAME ", units: degrees]\r\n"));
}

void report_grbl_help(void)
{
  printPgmString(PSTR("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $C $X $H $HX $HY $HZ $RST= ~ ! ? ctrl-x]\r\n"));
}

// "$n=value": integer settings print through printFloat too (0 decimals).
static void report_setting(uint8_t n, float v, uint8_t decimals)
{
  serial_write('$');
  print_uint32(n);
  serial_write('=');
  printFloat(v, decimals);
  report_eol();
}

void report_grbl_settings(void)
{
  // '$0'..'$27' from the settings table (a call per setting costs more flash)
  const uint8_t *base = (const uint8_t *)&settings;
  for (uint8_t i = 0; i < N_SETTINGS_TABLE; i++) {
    uint8_t n = pgm_read_byte(&settings_table[i][0]);
    uint8_t kind = pgm_read_byte(&settings_table[i][1]);
    uint8_t arg = pgm_read_byte(&settings_table[i][2]);
    float f;
    uint8_t decimals = 0;
    if (kind == SET_FLOAT) {
      memcpy(&f, base + arg, sizeof(f));
      decimals = N_DECIMAL_SETTINGVALUE;
    } else {
      uint16_t v = base[arg];
      if (kind == SET_U16) v |= base[arg + 1] << 8;
      if (kind == SET_FLAG) v = (settings.flags & arg) != 0;
      f = v;
    }
    report_setting(n, f, decimals);
  }
  // '$100'..'$142': the five per-axis float groups that open settings_t
  // (settings.h), walked as bytes: one pointer instead of a table of five
  for (uint8_t n = 100; n < 150; n += 10) {
    for (uint8_t i = 0; i < N_AXIS; i++) {
      float f;
      memcpy(&f, base, sizeof(f));
      base += sizeof(f);
      report_setting(n + i, f, N_DECIMAL_SETTINGVALUE);
    }
  }
}

static void report_coord(const char *pname, const float *v)
{
  serial_write('[');
  printPgmString(pname);
  serial_write(':');
  print_axis_values(v);
  printPgmString(PSTR("]\r\n"));
}

uint8_t report_ngc_parameters(void)
{
  float coord[N_AXIS];
  for (uint8_t i = 0; i < SETTING_INDEX_NCOORD; i++) {
    if (!settings_read_coord_data(i, coord)) return STATUS_SETTING_READ_FAIL;
    serial_write('[');
    if (i < N_COORDINATE_SYSTEM) {
      serial_write('G');
      print_uint32(54 + i);
    } else {
      printPgmString(i == SETTING_INDEX_G28 ? PSTR("G28") : PSTR("G30"));
    }
    serial_write(':');
    print_axis_values(coord);
    printPgmString(PSTR("]\r\n"));
  }
  report_coord(PSTR("G92"), gc_state.coord_offset);
  printPgmString(PSTR("[TLO:0.000]\r\n[PRB:0.000,0.000,0.000:0]\r\n"));
  return STATUS_OK;
}

void report_gcode_modes(void)
{
  printPgmString(PSTR("[GC:G"));
  print_uint32(gc_state.modal.motion == MOTION_MODE_NONE ? 80 : gc_state.modal.motion);
  printPgmString(PSTR(" G"));
  print_uint32(54 + gc_state.modal.coord_select);
  printPgmString(PSTR(" G17 G21 G"));
  print_uint32(gc_state.modal.distance ? 91 : 90);
  printPgmString(PSTR(" G94"));
  if (gc_state.modal.program_flow) {
    printPgmString(PSTR(" M"));
    print_uint32(gc_state.modal.program_flow);
  }
  printPgmString(PSTR(" M5 M9 T0 F"));
  printFloat(gc_state.feed_rate, 0);
  printPgmString(PSTR(" S0]\r\n"));
}

void report_startup_line(uint8_t n, const char *line)
{
  printPgmString(PSTR("$N"));
  print_uint32(n);
  serial_write('=');
  printString(line);
  report_eol();
}

void report_execute_startup_message(const char *line, uint8_t status)
{
  serial_write('>');
  printString(line);
  serial_write(':');
  report_status_message(status);
}

void report_build_info(const char *info)
{
  printPgmString(PSTR("[VER:" GRBL_VERSION "." GRBL_VERSION_BUILD ":"));
  printString(info);
  printPgmString(PSTR("]\r\n[OPT:H,"));
  print_uint_pair(BLOCK_BUFFER_SIZE - 1, RX_BUFFER_SIZE);
  printPgmString(PSTR("]\r\n"));
}

// sys.state's names, by bit number + 1 (0: Idle), as GRBL writes them
_Static_assert(STATE_ALARM == 1 << 0 && STATE_CHECK_MODE == 1 << 1 && STATE_HOMING == 1 << 2 &&
               STATE_CYCLE == 1 << 3 && STATE_HOLD == 1 << 4 && STATE_JOG == 1 << 5, "state bits moved");
static const char state_names[] PROGMEM = "Idle\0Alarm\0Check\0Home\0Run\0Hold:\0Jog";

void report_realtime_status(void)
{
  int32_t steps[N_AXIS];
  float pos[N_AXIS];
  float wco[N_AXIS];
  system_get_position(steps);
  system_convert_array_steps_to_mpos(pos, steps);

  // The state's name by its bit (STATE_*: 0 or one bit), from one string.
  serial_write('<');
  uint8_t state = sys.state;
  if (state == STATE_HOLD && (sys.suspend & SUSPEND_JOG_CANCEL)) state = STATE_JOG;  // a jog cancel reports Jog
  uint8_t k = 0;
  for (uint8_t b = state; b; b >>= 1) k++;
  print_pgm_nth(state_names, k);
  if (state == STATE_HOLD) serial_write(sys.suspend & SUSPEND_HOLD_COMPLETE ? '0' : '1');   // "Hold:0" / "Hold:1"

  for (uint8_t i = 0; i < N_AXIS; i++) {
    wco[i] = gc_state.coord_system[i] + gc_state.coord_offset[i];
    if (!(settings.status_report_mask & 1)) pos[i] -= wco[i];
  }
  printPgmString(settings.status_report_mask & 1 ? PSTR("|MPos:") : PSTR("|WPos:"));
  print_axis_values(pos);

  if (settings.status_report_mask & 2) {
    printPgmString(PSTR("|Bf:"));
    print_uint_pair(plan_get_block_buffer_available(), serial_get_rx_buffer_available());
  }

  printPgmString(PSTR("|FS:"));
  printFloat(st_get_realtime_rate(), 0);
  printPgmString(PSTR(",0"));

  uint8_t lim = limits_get_state();
  if (lim) {
    printPgmString(PSTR("|Pn:"));
    for (uint8_t i = 0; i < N_AXIS; i++)
      if (lim & bit(i)) serial_write('X' + i);
  }

  if (sys.report_wco_counter > 0) {
    sys.report_wco_counter--;
  } else {
    sys.report_wco_counter = (sys.state & (STATE_HOMING | STATE_CYCLE | STATE_HOLD | STATE_JOG))
                                 ? REPORT_WCO_REFRESH_BUSY_COUNT - 1 : REPORT_WCO_REFRESH_IDLE_COUNT - 1;
    if (sys.report_ovr_counter == 0) sys.report_ovr_counter = 1;  // Ov on the next report
    printPgmString(PSTR("|WCO:"));
    print_axis_values(wco);
  }
  if (sys.report_ovr_counter > 0) {
    sys.report_ovr_counter--;
  } else {
    sys.report_ovr_counter = (sys.state & (STATE_HOMING | STATE_CYCLE | STATE_HOLD | STATE_JOG))
                                 ? REPORT_OVR_REFRESH_BUSY_COUNT - 1 : REPORT_OVR_REFRESH_IDLE_COUNT - 1;
    printPgmString(PSTR("|Ov:"));
    print_uint_pair(sys.f_override, sys.r_override);
    printPgmString(PSTR(",100"));   // spindle: none
  }
  printPgmString(PSTR(">\r\n"));
}
