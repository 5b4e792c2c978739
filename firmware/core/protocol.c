// The main loop: line reader, real-time command execution, cycle control.
#include <string.h>
#include "protocol.h"
#include "config.h"
#include "codes.h"
#include "nuts.h"
#include "board.h"     // board_idle, board_reset_cause_watchdog
#include "serial.h"    // serial_read
#include "system.h"    // sys, exec flags
#include "settings.h"  // settings, settings_restored
#include "report.h"    // report_*
#include "gcode.h"     // gc_execute_line, gc_init
#include "planner.h"   // plan_*
#include "stepper.h"   // st_*
#include "limits.h"    // limits_init
#include "motion.h"    // mc_reset

// Line reader flags
#define LINE_FLAG_OVERFLOW (1 << 0)
#define LINE_FLAG_COMMENT_PARENTHESES (1 << 1)
#define LINE_FLAG_COMMENT_SEMICOLON (1 << 2)

static char line[LINE_BUFFER_SIZE];
static uint8_t char_counter;
static uint8_t line_flags;
// The alarm that locked the machine, said again after a reset banner while
// still locked, so a client that connects later learns whether unlocking is
// safe (GRBL only says it once). Not again when the reset itself raised it
// (ALARM:3 and the homing failures come just before the banner).
static uint8_t alarm_kept;
static uint8_t alarm_by_reset;

static void protocol_exec_rt_system(void);

void protocol_init(void)
{
  memset(&sys, 0, sizeof(sys));
  sys.f_override = DEFAULT_FEED_OVERRIDE;
  sys.r_override = DEFAULT_RAPID_OVERRIDE;
  plan_init();
  sys.state = STATE_IDLE;
  if (board_reset_cause_watchdog()) sys_fault = FAULT_WATCHDOG;
  if (bit_istrue(settings.flags, BITFLAG_HOMING_ENABLE)) sys.state = STATE_ALARM;
  if (sys_fault) sys.state = STATE_ALARM;
}

void protocol_reset(void)
{
  uint8_t prior_state = sys.state;
  memset(&sys, 0, sizeof(sys));
  sys.state = prior_state;
  sys.f_override = DEFAULT_FEED_OVERRIDE;   // a reset restores them, as GRBL
  sys.r_override = DEFAULT_RAPID_OVERRIDE;
  sys_rt_exec_motion_override = 0;
  serial_reset_read_buffer();
  gc_init();
  plan_reset();
  st_reset();
  limits_init();
  plan_sync_position();
  gc_sync_position();
  sys_rt_exec_state = 0;
  sys_rt_exec_alarm = 0;
  char_counter = 0;
  line_flags = 0;

  report_init_message();
  if (settings_restored) {
    report_feedback_message(MESSAGE_SETTINGS_CRC);
    settings_restored = 0;
  }
  if (sys_fault) {
    report_feedback_message(sys_fault == FAULT_WATCHDOG ? MESSAGE_FAULT_WATCHDOG : MESSAGE_FAULT_INTERNAL);
    report_alarm_message(EXEC_ALARM_FAULT);
    sys_fault = 0;
    sys.state = STATE_ALARM;
  }
  if (sys.state & STATE_ALARM) {
    if (alarm_kept && !alarm_by_reset) report_alarm_message(alarm_kept);
    report_feedback_message(MESSAGE_ALARM_LOCK);
    sys.state = STATE_ALARM;
    alarm_by_reset = 0;
  } else {
    alarm_kept = alarm_by_reset = 0;
    sys.state = STATE_IDLE;
    system_execute_startup();   // $N0, $N1 after the banner, as GRBL (not while locked)
  }
}

static void protocol_execute_line(void)
{
  line[char_counter] = 0;
  if (line_flags & LINE_FLAG_OVERFLOW) {
    report_status_message(STATUS_OVERFLOW);
  } else if (line[0] == 0) {
    report_status_message(STATUS_OK);   // empty or comment-only line: ok, for sender sync
  } else if (line[0] == '$') {
    report_status_message(system_execute_line(line));
  } else if (sys.state & (STATE_ALARM | STATE_JOG)) {
    report_status_message(STATUS_SYSTEM_GC_LOCK);
  } else {
    report_status_message(gc_execute_line(line, 0));
  }
  char_counter = 0;
  line_flags = 0;
}

void protocol_process_char(uint8_t c)
{
  if (c == '\n' || c == '\r') {
    // A sender that keeps the receive buffer full of short moves the planner
    // takes at once can keep protocol_poll reading for longer than the
    // watchdog period without ever waiting: kick it once per line.
    board_watchdog_kick();
    protocol_execute_realtime();
    if (sys.abort) return;
    protocol_execute_line();
    return;
  }
  if (line_flags) {
    // Inside a comment or an overflowed line: drop until its end.
    if (c == ')' && (line_flags & LINE_FLAG_COMMENT_PARENTHESES)) line_flags &= ~LINE_FLAG_COMMENT_PARENTHESES;
    return;
  }
  if (c <= ' ' || c == 0x7f) return;    // whitespace and control bytes (NUL, DEL too) are dropped
  if (c == '/') return;                 // block delete: not supported, ignored as GRBL
  if (c == '(') { line_flags |= LINE_FLAG_COMMENT_PARENTHESES; return; }
  if (c == ';') { line_flags |= LINE_FLAG_COMMENT_SEMICOLON; return; }
  if (char_counter >= LINE_BUFFER_SIZE - 1) {
    line_flags |= LINE_FLAG_OVERFLOW;
    return;
  }
  if (c >= 'a' && c <= 'z') c -= 'a' - 'A';
  line[char_counter++] = c;
}

void protocol_poll(void)
{
  uint8_t c;
  while ((c = serial_read()) != SERIAL_NO_DATA) {
    protocol_process_char(c);
    if (sys.abort) return;
  }
  protocol_auto_cycle_start();
  if (!board_stack_ok() && !sys_fault) system_fault(FAULT_INTERNAL);
  protocol_execute_realtime();
  st_idle_poll();
  board_idle();
}

void protocol_main_loop(void)
{
  while (!sys.abort) protocol_poll();
}

void protocol_buffer_synchronize(void)
{
  protocol_auto_cycle_start();
  do {
    protocol_execute_realtime();
    if (sys.abort) return;
    board_idle();
  } while (plan_get_current_block() || (sys.state == STATE_CYCLE));
}

void protocol_auto_cycle_start(void)
{
  // Only from idle: a hold is resumed by '~' alone, never by queued input.
  if (sys.state == STATE_IDLE && plan_get_current_block() != NULL) system_set_exec_state_flag(EXEC_CYCLE_START);
}

void protocol_execute_realtime(void)
{
  protocol_exec_rt_system();
  if (sys.suspend) {
    // Hold: nothing to do but keep the segment buffer (the hold point) prepared.
  }
}

// A pending alarm: report it and lock; a critical one waits here for a reset.
static void protocol_exec_alarm(void)
{
  uint8_t rt_exec = sys_rt_exec_alarm;
  if (rt_exec) {
    sys.state = STATE_ALARM;
    report_alarm_message(rt_exec);
    alarm_kept = rt_exec;
    alarm_by_reset = (sys_rt_exec_state & EXEC_RESET) != 0;
    if (rt_exec == EXEC_ALARM_SOFT_LIMIT) report_feedback_message(MESSAGE_ALARM_LOCK);  // position kept: '$X' is safe
    if (rt_exec == EXEC_ALARM_HARD_LIMIT || rt_exec == EXEC_ALARM_FAULT) {
      // Critical: position may be lost or the machine is unsafe; only reset continues.
      if (rt_exec == EXEC_ALARM_FAULT)
        report_feedback_message(sys_fault == FAULT_WATCHDOG ? MESSAGE_FAULT_WATCHDOG : MESSAGE_FAULT_INTERNAL);
      report_feedback_message(MESSAGE_CRITICAL_EVENT);
      system_clear_exec_state_flag(EXEC_RESET);
      do {
        if (sys_rt_exec_state & EXEC_STATUS_REPORT) {
          system_clear_exec_state_flag(EXEC_STATUS_REPORT);
          report_realtime_status();
        }
        board_idle();
      } while (bit_isfalse(sys_rt_exec_state, EXEC_RESET));
      sys_fault = 0;
      alarm_by_reset = 0;
    }
    system_clear_exec_alarm();
  }
}

static void protocol_exec_rt_system(void)
{
  protocol_exec_alarm();

  uint8_t rt_exec = sys_rt_exec_state;
  if (rt_exec) {
    if (rt_exec & EXEC_RESET) {
      // mc_reset (UART ISR) raises EXEC_RESET and its alarm together: if it ran
      // after the alarm was read above, that alarm is reported and locks first,
      // or the reset would clear it and come up Idle after a lost move.
      protocol_exec_alarm();
      sys.abort = 1;
      return;
    }
    if (rt_exec & EXEC_STATUS_REPORT) {
      report_realtime_status();
      system_clear_exec_state_flag(EXEC_STATUS_REPORT);
    }

    if (rt_exec & (EXEC_MOTION_CANCEL | EXEC_FEED_HOLD)) {
      if (!(sys.state & (STATE_ALARM | STATE_CHECK_MODE))) {
        if (sys.state & (STATE_CYCLE | STATE_JOG)) {
          if (!(sys.suspend & (SUSPEND_MOTION_CANCEL | SUSPEND_JOG_CANCEL))) {
            st_update_plan_block_parameters();
            sys.step_control = STEP_CONTROL_EXECUTE_HOLD;
            if (sys.state == STATE_JOG) {
              sys.suspend |= SUSPEND_JOG_CANCEL;
              sys.jog_cancelled = 1;
            }
          }
        }
        if (sys.state == STATE_IDLE) sys.suspend = SUSPEND_HOLD_COMPLETE;
        if (rt_exec & EXEC_FEED_HOLD) {
          if (!(sys.state & STATE_JOG)) sys.state = STATE_HOLD;
        }
      }
      system_clear_exec_state_flag(EXEC_MOTION_CANCEL | EXEC_FEED_HOLD);
    }

    if (rt_exec & EXEC_CYCLE_START) {
      if (!(rt_exec & (EXEC_FEED_HOLD | EXEC_MOTION_CANCEL))) {
        if (sys.state == STATE_IDLE || (sys.state & STATE_HOLD && sys.suspend & SUSPEND_HOLD_COMPLETE)) {
          sys.step_control = STEP_CONTROL_NORMAL_OP;
          plan_block_t *block = plan_get_current_block();
          if (block && !(sys.suspend & SUSPEND_MOTION_CANCEL)) {
            sys.suspend = SUSPEND_DISABLE;
            // A jog too long for the planner starts here, from mc_line's
            // wait for room: it stays a jog (0x85 cancels it; G-code sent
            // meanwhile waits for the line, then gets error:9 until the jog ends, as
            // for any GRBL jog).
            sys.state = (block->condition & PL_COND_FLAG_JOG) ? STATE_JOG : STATE_CYCLE;
            st_prep_buffer();
            st_wake_up();
          } else {
            sys.suspend = SUSPEND_DISABLE;
            sys.state = STATE_IDLE;
          }
        }
      }
      system_clear_exec_state_flag(EXEC_CYCLE_START);
    }

    if ((rt_exec & EXEC_CYCLE_STOP) && sys.state != STATE_HOMING) {  // homing waits for it itself
      if ((sys.state & STATE_HOLD) && !sys.soft_limit && !(sys.suspend & SUSPEND_JOG_CANCEL)) {
        // Hold complete: the remaining moves stay queued for '~'.
        plan_cycle_reinitialize();
        if (sys.step_control & STEP_CONTROL_EXECUTE_HOLD) sys.suspend |= SUSPEND_HOLD_COMPLETE;
        sys.step_control &= ~(STEP_CONTROL_EXECUTE_HOLD | STEP_CONTROL_EXECUTE_SYS_MOTION);
      } else {
        if (sys.suspend & SUSPEND_JOG_CANCEL) {
          // Jog cancelled: drop what is left and resynchronise.
          sys.step_control = STEP_CONTROL_NORMAL_OP;
          plan_reset();
          st_reset();
          gc_sync_position();
          plan_sync_position();
        }
        if (sys.state & (STATE_CYCLE | STATE_JOG | STATE_HOLD)) {
          sys.suspend = SUSPEND_DISABLE;
          sys.state = STATE_IDLE;
        }
      }
      system_clear_exec_state_flag(EXEC_CYCLE_STOP);
    }
  }

  rt_exec = sys_rt_exec_motion_override;
  if (rt_exec) {
    uint8_t s = board_irq_save();
    sys_rt_exec_motion_override = 0;
    board_irq_restore(s);
    uint8_t f = sys.f_override;
    if (rt_exec & EXEC_FEED_OVR_RESET) f = DEFAULT_FEED_OVERRIDE;
    if (rt_exec & EXEC_FEED_OVR_COARSE_PLUS) f += FEED_OVERRIDE_COARSE_INCREMENT;
    if (rt_exec & EXEC_FEED_OVR_COARSE_MINUS) f -= FEED_OVERRIDE_COARSE_INCREMENT;
    if (rt_exec & EXEC_FEED_OVR_FINE_PLUS) f += FEED_OVERRIDE_FINE_INCREMENT;
    if (rt_exec & EXEC_FEED_OVR_FINE_MINUS) f -= FEED_OVERRIDE_FINE_INCREMENT;
    f = min(max(f, MIN_FEED_RATE_OVERRIDE), MAX_FEED_RATE_OVERRIDE);   // uint8_t: 200 + 10 still fits
    uint8_t r = sys.r_override;
    if (rt_exec & EXEC_RAPID_OVR_RESET) r = DEFAULT_RAPID_OVERRIDE;
    if (rt_exec & EXEC_RAPID_OVR_MEDIUM) r = RAPID_OVERRIDE_MEDIUM;
    if (rt_exec & EXEC_RAPID_OVR_LOW) r = RAPID_OVERRIDE_LOW;
    if (f != sys.f_override || r != sys.r_override) {
      sys.f_override = f;
      sys.r_override = r;
      sys.report_ovr_counter = 0;   // the next status report shows it
      // New speed limits for the queued moves; the one running slows down
      // or speeds up from where it is (the segment prep replans it).
      plan_update_velocity_profile_parameters();
      plan_cycle_reinitialize();
    }
  }

  if (sys.state & (STATE_CYCLE | STATE_HOLD | STATE_HOMING | STATE_JOG)) st_prep_buffer();
}
