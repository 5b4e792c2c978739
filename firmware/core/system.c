// System state, real-time execution flags and the '$' commands.
#include <string.h>
#include "system.h"
#include "codes.h"
#include "nuts.h"
#include "board.h"     // board_irq_save/restore, board_stepper_enable
#include "settings.h"  // settings, settings_store_*
#include "report.h"    // report_*
#include "gcode.h"     // gc_execute_line, gc_state
#include "planner.h"   // plan_sync_position
#include "stepper.h"   // st_go_idle
#include "limits.h"    // limits_go_home
#include "protocol.h"  // protocol_buffer_synchronize
#include "motion.h"    // mc_reset

system_t sys;
volatile int32_t sys_position[N_AXIS];
volatile uint8_t sys_rt_exec_state;
volatile uint8_t sys_rt_exec_alarm;
volatile uint8_t sys_rt_exec_motion_override;
uint8_t sys_fault;

void system_set_exec_state_flag(uint8_t mask)
{
  uint8_t s = board_irq_save();
  sys_rt_exec_state |= mask;
  board_irq_restore(s);
}

void system_clear_exec_state_flag(uint8_t mask)
{
  uint8_t s = board_irq_save();
  sys_rt_exec_state &= ~mask;
  board_irq_restore(s);
}

void system_set_exec_alarm(uint8_t code)
{
  uint8_t s = board_irq_save();
  sys_rt_exec_alarm = code;
  board_irq_restore(s);
}

void system_clear_exec_alarm(void)
{
  uint8_t s = board_irq_save();
  sys_rt_exec_alarm = 0;
  board_irq_restore(s);
}

void system_get_position(int32_t *steps)
{
  uint8_t s = board_irq_save();
  for (uint8_t i = 0; i < N_AXIS; i++) steps[i] = sys_position[i];
  board_irq_restore(s);
}

float system_convert_axis_steps_to_mpos(const int32_t *steps, uint8_t idx)
{
  return steps[idx] / settings.steps_per_deg[idx];
}

void system_convert_array_steps_to_mpos(float *position, const int32_t *steps)
{
  for (uint8_t i = 0; i < N_AXIS; i++) position[i] = system_convert_axis_steps_to_mpos(steps, i);
}

uint8_t system_check_travel_limits(const float *target)
{
  // Machine space is [-max_travel, 0] after homing, as in GRBL.
  for (uint8_t i = 0; i < N_AXIS; i++) {
    if (target[i] > 0 || target[i] < -settings.max_travel[i]) return 1;
  }
  return 0;
}

void system_fault(uint8_t cause)
{
  // The one fault path: stop stepping, drivers off, report, stay in alarm.
  board_step_timer_stop();
  board_stepper_enable(0);
  sys_fault = cause;
  system_set_exec_alarm(EXEC_ALARM_FAULT);
}

static uint8_t system_axis_letter(char c)
{
  switch (c) {
    case 'X': return X_AXIS;
    case 'Y': return Y_AXIS;
    case 'Z': return Z_AXIS;
  }
  return 0xff;
}

void system_execute_startup(void)
{
  char block[LINE_BUFFER_SIZE];
  for (uint8_t n = 0; n < N_STARTUP_LINE; n++) {
    if (!settings_read_startup_line(n, block)) {
      report_status_message(STATUS_SETTING_READ_FAIL);   // as GRBL; the block now reads empty
    } else if (block[0]) {
      report_execute_startup_message(block, gc_execute_line(block, 0));
    }
  }
}

uint8_t system_execute_line(char *line)
{
  uint8_t char_counter = 1;
  float parameter, value;
  switch (line[char_counter]) {
    case 0: report_grbl_help(); break;
    case 'J':
      // Jogging: only from idle or while jogging.
      if (sys.state != STATE_IDLE && sys.state != STATE_JOG) return STATUS_IDLE_ERROR;
      if (line[2] != '=') return STATUS_INVALID_STATEMENT;
      return gc_execute_line(line + 3, 1);
    case '$': case 'G': case 'C': case 'X': case '#':
      if (line[2] != 0) return STATUS_INVALID_STATEMENT;
      switch (line[1]) {
        // '$$', '$#' and '$G' only read, so they answer mid-stream too:
        // senders poll them while streaming (GRBL refuses '$$' and '$#'
        // with error:8 unless idle). A long reply keeps the step segments
        // prepared while it waits for the UART (serial_write).
        case '$': report_grbl_settings(); break;
        case '#': return report_ngc_parameters();
        case 'G': report_gcode_modes(); break;
        case 'C':
          if (sys.state == STATE_CHECK_MODE) {
            mc_reset();
            report_feedback_message(MESSAGE_DISABLED);
          } else {
            if (sys.state) return STATUS_IDLE_ERROR;
            sys.state = STATE_CHECK_MODE;
            report_feedback_message(MESSAGE_ENABLED);
          }
          break;
        case 'X':
          if (sys.state == STATE_ALARM) {
            report_feedback_message(MESSAGE_ALARM_UNLOCK);
            sys.state = STATE_IDLE;
            gc_sync_position();   // a soft-limit alarm left the parser at the refused target
          }
          break;
      }
      break;
    default:
      // Everything else requires idle or alarm, and queued moves done first:
      // they were planned with the settings they were sent under.
      if (sys.state & ~STATE_ALARM) return STATUS_IDLE_ERROR;
      protocol_buffer_synchronize();
      if (sys.abort) return STATUS_OK;
      switch (line[1]) {
        case 'H': {
          if (bit_isfalse(settings.flags, BITFLAG_HOMING_ENABLE)) return STATUS_SETTING_DISABLED;
          uint8_t mask = HOMING_CYCLE_MASK;
          if (line[2] != 0) {
            uint8_t a = system_axis_letter(line[2]);
            if (a == 0xff || line[3] != 0) return STATUS_INVALID_STATEMENT;
            mask = bit(a);
          }
          sys.state = STATE_HOMING;
          limits_go_home(mask);
          if (!sys.abort) {
            sys.state = STATE_IDLE;
            st_go_idle();
            if (line[2] == 0) system_execute_startup();   // as GRBL: a full homing cycle runs them
          }
          break;
        }
        case 'I':
          if (line[2] == 0) {
            char info[LINE_BUFFER_SIZE];
            settings_read_build_info(info);   // a bad record reads as empty
            report_build_info(info);
          } else if (line[2] == '=') {
            if (strlen(line + 3) > 40) return STATUS_LINE_LENGTH_EXCEEDED;
            settings_store_build_info(line + 3);
          } else {
            return STATUS_INVALID_STATEMENT;
          }
          break;
        case 'N':
          if (line[2] == 0) {
            char block[LINE_BUFFER_SIZE];
            for (uint8_t n = 0; n < N_STARTUP_LINE; n++) {
              if (!settings_read_startup_line(n, block)) return STATUS_SETTING_READ_FAIL;
              report_startup_line(n, block);
            }
            break;
          }
          // Storing runs the block once to check it, as GRBL: not in alarm.
          if (sys.state != STATE_IDLE) return STATUS_IDLE_ERROR;
          if (line[2] < '0' || line[2] >= '0' + N_STARTUP_LINE || line[3] != '=') return STATUS_INVALID_STATEMENT;
          {
            uint8_t status = gc_execute_line(line + 4, 0);
            if (status != STATUS_OK) return status;
          }
          settings_store_startup_line(line[2] - '0', line + 4);
          break;
        case 'R':
          if (strncmp(line + 2, "ST=", 3) != 0 || line[6] != 0) return STATUS_INVALID_STATEMENT;
          switch (line[5]) {
            case '$': settings_restore(SETTINGS_RESTORE_DEFAULTS); break;
            case '#': settings_restore(SETTINGS_RESTORE_PARAMETERS); break;
            case '*': settings_restore(SETTINGS_RESTORE_ALL); break;
            default: return STATUS_INVALID_STATEMENT;
          }
          report_feedback_message(MESSAGE_RESTORE_DEFAULTS);
          mc_reset();
          break;
        default:
          // $N=value
          if (!read_float(line, &char_counter, &parameter)) return STATUS_BAD_NUMBER_FORMAT;
          if (line[char_counter++] != '=') return STATUS_INVALID_STATEMENT;
          if (!read_float(line, &char_counter, &value)) return STATUS_BAD_NUMBER_FORMAT;
          if (line[char_counter] != 0 || parameter > 255 || parameter < 0) return STATUS_INVALID_STATEMENT;
          if (parameter - (uint8_t)parameter != 0) return STATUS_INVALID_STATEMENT;
          return settings_store_global_setting((uint8_t)parameter, value);
      }
  }
  return STATUS_OK;
}
