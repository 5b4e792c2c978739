// Motion commands: the entry points from G-code into the planner.
#include <math.h>
#include "motion.h"
#include "config.h"
#include "codes.h"
#include "nuts.h"
#include "system.h"    // sys, exec flags
#include "settings.h"  // settings
#include "protocol.h"  // protocol_execute_realtime, protocol_buffer_synchronize
#include "stepper.h"   // st_go_idle
#include "limits.h"    // limits_soft_check
#include "board.h"     // board_idle

void mc_line(const float *target, plan_line_data_t *pl_data)
{
  uint8_t jog = pl_data->condition & PL_COND_FLAG_JOG;
  if (jog) sys.jog_cancelled = 0;
  if (sys.state != STATE_JOG && bit_istrue(settings.flags, BITFLAG_SOFT_LIMIT_ENABLE)) {
    limits_soft_check(target);
    if (sys.abort || sys.state == STATE_ALARM) return;
  }
  if (sys.state == STATE_CHECK_MODE) return;
  float start[N_AXIS];
  float piece[N_AXIS];
  float longest = 0.0f;
  float steps = 0.0f;
  plan_get_position(start);
  for (uint8_t i = 0; i < N_AXIS; i++) {
    float d = fabsf(target[i] - start[i]);
    longest = max(longest, d);
    steps = max(steps, d * settings.steps_per_deg[i]);
  }
  // Pieces of at most MAX_BLOCK_DEG; a move so long that their count would
  // overflow (tiny steps per degree, huge target) is cut into the most pieces
  // a uint16_t counts, each longer: the segment prep copes with long blocks
  // (and faults on one too long to count down in a float). At most one more
  // piece than the move has steps (n = floor(steps) + 1, so one piece for a
  // move under a step): below one step per MAX_BLOCK_DEG a piece would move
  // nothing, and thousands of them only keep this loop from the step queue's
  // waits and the watchdog (65535 took seconds on the chip).
  // Fine drives need more pieces: none may exceed MAX_BLOCK_STEPS, or the
  // prep's float step count rounds (at most 2e9 / MAX_BLOCK_STEPS = 125 pieces,
  // as targets stay within MAX_TARGET_STEPS).
  float pieces = max(min(longest / MAX_BLOCK_DEG, steps), steps / MAX_BLOCK_STEPS);
  uint16_t n = (pieces < 65534.0f) ? (uint16_t)pieces + 1 : 65535;
  for (uint16_t k = 1;; k++) {   // not k <= n: always true for n = 65535
    for (uint8_t i = 0; i < N_AXIS; i++)
      piece[i] = (k == n) ? target[i] : start[i] + (target[i] - start[i]) * k / n;
    uint8_t need = plan_backlash_blocks_needed(piece);
    for (;;) {
      protocol_execute_realtime();
      if (sys.abort) return;
      // A jog cancel (0x85, or '!' while jogging) taken while this jog line
      // waits for room, or still stopping when it came: the rest of the line
      // goes too. Queued after the cancel's flush it would run as a new jog.
      if (jog && (sys.jog_cancelled || (sys.suspend & SUSPEND_JOG_CANCEL))) {
        sys.jog_cancelled = 1;   // for the caller: keep the parser where the stage stops
        return;
      }
      // Full: start what is queued (a jog as a jog, protocol.c) to make room.
      if (plan_get_block_buffer_available() < need) protocol_auto_cycle_start();
      else break;
      board_idle();
    }
    plan_buffer_line(piece, pl_data);
    if (k == n) break;
  }
}

void mc_dwell(float seconds)
{
  if (sys.state == STATE_CHECK_MODE) return;
  protocol_buffer_synchronize();
  float ms = seconds * 1000.0f;
  while (ms > 0 && !sys.abort) {
    uint16_t chunk = ms > 60000.0f ? 60000 : (uint16_t)(ms + 0.5f);
    if (chunk == 0) break;
    delay_ms_rt(chunk);
    ms -= chunk;
  }
}

void mc_reset(void)
{
  if (bit_isfalse(sys_rt_exec_state, EXEC_RESET)) {
    system_set_exec_state_flag(EXEC_RESET);
    // Stop stepping now. Position stays what the step ISR counted, but a
    // motor stopped mid-move without deceleration may have lost steps.
    if ((sys.state & (STATE_CYCLE | STATE_HOMING | STATE_JOG)) ||
        (sys.step_control & (STEP_CONTROL_EXECUTE_HOLD | STEP_CONTROL_EXECUTE_SYS_MOTION))) {
      if (sys.state == STATE_HOMING) {
        if (!sys_rt_exec_alarm) system_set_exec_alarm(EXEC_ALARM_HOMING_FAIL_RESET);
      } else {
        system_set_exec_alarm(EXEC_ALARM_ABORT_CYCLE);
      }
      st_go_idle();
    }
  }
}
