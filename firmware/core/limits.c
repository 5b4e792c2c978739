// Limit switches: hard-limit alarm, soft limits, homing.
#include <string.h>
#include "limits.h"
#include "config.h"
#include "codes.h"
#include "nuts.h"
#include "board.h"     // board_limits_read, board_limits_irq
#include "system.h"    // sys, exec flags
#include "settings.h"  // settings
#include "planner.h"   // plan_buffer_line
#include "stepper.h"   // st_*
#include "protocol.h"  // protocol_execute_realtime
#include "motion.h"    // mc_reset
#include "gcode.h"     // gc_sync_position
#include "report.h"    // report_realtime_status

void limits_init(void)
{
  board_limits_irq(bit_istrue(settings.flags, BITFLAG_HARD_LIMIT_ENABLE));
}

uint8_t limits_get_state(void)
{
  uint8_t raw = board_limits_read() & 7;
  // Switches close to ground: a low pin is a triggered switch unless $5=1.
  if (bit_isfalse(settings.flags, BITFLAG_INVERT_LIMIT_PINS)) raw ^= 7;
  return raw;
}

static volatile uint8_t debounce_ms;   // a switch closed: look again when this runs out

// 1 when a closed switch now means a hard-limit alarm.
static uint8_t hard_limit_armed(void)
{
  return bit_istrue(settings.flags, BITFLAG_HARD_LIMIT_ENABLE) && sys.state != STATE_ALARM &&
         sys.state != STATE_HOMING && !sys_rt_exec_alarm && limits_get_state();
}

void limits_pin_change_isr(void)
{
  if (!debounce_ms && hard_limit_armed()) debounce_ms = HARD_LIMIT_DEBOUNCE_MS;
}

void limits_tick_isr(void)
{
  if (debounce_ms && --debounce_ms == 0 && hard_limit_armed()) {
    mc_reset();
    system_set_exec_alarm(EXEC_ALARM_HARD_LIMIT);
  }
}

void limits_soft_check(const float *target)
{
  if (!system_check_travel_limits(target)) return;
  sys.soft_limit = 1;
  // Stop smoothly if a cycle runs (or a hold is still slowing down), then
  // drop the queued motion and alarm. No reset: the position is exact, so
  // '$X' alone unlocks, as the alarm's text says (GRBL asks for a reset first).
  if (sys.state & (STATE_CYCLE | STATE_HOLD)) {
    system_set_exec_state_flag(EXEC_FEED_HOLD);
    do {
      protocol_execute_realtime();
      if (sys.abort) return;
      board_idle();
    } while (sys.state != STATE_IDLE && !(sys.suspend & SUSPEND_HOLD_COMPLETE));
  }
  plan_reset();
  st_reset();
  plan_sync_position();
  sys.step_control = STEP_CONTROL_NORMAL_OP;
  sys.suspend = SUSPEND_DISABLE;
  sys.soft_limit = 0;
  system_set_exec_alarm(EXEC_ALARM_SOFT_LIMIT);
  protocol_execute_realtime();
}

// One homing phase: move the axes in mask toward (approach) or away from the
// switches until they trip (approach) or the distance is done (pull-off).
// Returns 0 on success, an alarm code otherwise.
static uint8_t limits_homing_move(uint8_t mask, float distance, float rate, uint8_t approach)
{
  int32_t steps[N_AXIS];
  float target[N_AXIS];
  uint8_t n_active = 0;
  system_get_position(steps);
  system_convert_array_steps_to_mpos(target, steps);
  for (uint8_t i = 0; i < N_AXIS; i++) {
    if (!(mask & bit(i))) continue;
    n_active++;
    uint8_t negative = bit_istrue(settings.homing_dir_mask, bit(i));
    if (!approach) negative = !negative;
    target[i] += negative ? -distance : distance;
  }
  plan_line_data_t pl_data = {.feed_rate = rate * (n_active > 1 ? 1.7320508f : 1.0f),
                              .condition = PL_COND_FLAG_SYSTEM_MOTION | PL_COND_FLAG_NO_FEED_OVERRIDE};
  sys.homing_axis_lock = mask;
  plan_buffer_line(target, &pl_data);
  sys.step_control = STEP_CONTROL_EXECUTE_SYS_MOTION;
  st_prep_buffer();
  st_wake_up();

  uint8_t axislock = mask;
  uint8_t alarm = 0;
  for (;;) {
    if (approach) {
      uint8_t lim = limits_get_state();
      axislock &= ~(lim & mask);
      sys.homing_axis_lock = axislock;
    }
    st_prep_buffer();
    board_idle();
    // An alarm raised meanwhile (the segment prep's fault, ALARM:10) has
    // stopped the motors: no switch or end of move will come, so end here
    // with it rather than wait for a reset (which would say ALARM:6).
    if (sys_rt_exec_alarm) { alarm = sys_rt_exec_alarm; break; }
    uint8_t rt = sys_rt_exec_state;
    if (rt & EXEC_RESET) { alarm = EXEC_ALARM_HOMING_FAIL_RESET; break; }
    if (rt & EXEC_CYCLE_STOP) {
      system_clear_exec_state_flag(EXEC_CYCLE_STOP);
      if (approach && axislock) alarm = EXEC_ALARM_HOMING_FAIL_APPROACH;
      break;
    }
    if (approach && axislock == 0) break;
    if (rt & EXEC_STATUS_REPORT) {
      // Status only: the homing state keeps the motion, and a reset is taken above (the whole
      // realtime step here would report a Ctrl-X's alarm that the exit below reports again).
      system_clear_exec_state_flag(EXEC_STATUS_REPORT);
      report_realtime_status();
    }
  }
  st_reset();
  plan_reset();
  sys.step_control = STEP_CONTROL_NORMAL_OP;
  return alarm;
}

void limits_go_home(uint8_t cycle_mask)
{
  board_limits_irq(0);
  uint8_t alarm = 0;
  float max_travel = 0.0f;
  for (uint8_t i = 0; i < N_AXIS; i++)
    if (cycle_mask & bit(i)) max_travel = max(max_travel, settings.max_travel[i] * HOMING_AXIS_SEARCH_SCALAR);

  // Seek fast, back off, locate slowly, back off.
  alarm = limits_homing_move(cycle_mask, max_travel, settings.homing_seek_rate, 1);
  for (uint8_t n = 0; !alarm && n <= N_HOMING_LOCATE_CYCLE; n++) {
    delay_ms_rt(settings.homing_debounce_delay);
    alarm = limits_homing_move(cycle_mask, settings.homing_pulloff, settings.homing_seek_rate, 0);
    if (alarm || n == N_HOMING_LOCATE_CYCLE) break;
    delay_ms_rt(settings.homing_debounce_delay);
    alarm = limits_homing_move(cycle_mask, settings.homing_pulloff * HOMING_AXIS_LOCATE_SCALAR,
                               settings.homing_feed_rate, 1);
  }
  if (!alarm && (limits_get_state() & cycle_mask)) alarm = EXEC_ALARM_HOMING_FAIL_PULLOFF;
  if (sys.abort && !alarm) alarm = EXEC_ALARM_HOMING_FAIL_RESET;

  if (alarm) {
    mc_reset();
    system_set_exec_alarm(alarm);
    protocol_execute_realtime();
    return;
  }

  // Switch position minus pull-off, as GRBL: machine space is [-max_travel, 0].
  uint8_t s = board_irq_save();
  for (uint8_t i = 0; i < N_AXIS; i++) {
    if (!(cycle_mask & bit(i))) continue;
    if (bit_istrue(settings.homing_dir_mask, bit(i)))
      sys_position[i] = nuts_lround((-settings.max_travel[i] + settings.homing_pulloff) * settings.steps_per_deg[i]);
    else
      sys_position[i] = -nuts_lround(settings.homing_pulloff * settings.steps_per_deg[i]);
  }
  board_irq_restore(s);
  // The last move was the pull-off, away from the switch.
  plan_set_last_direction(cycle_mask, ~settings.homing_dir_mask);
  plan_sync_position();
  gc_sync_position();
  limits_init();
}
