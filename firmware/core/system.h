// System state, real-time execution flags and the '$' commands.
#ifndef SYSTEM_H
#define SYSTEM_H

#include <stdint.h>
#include "config.h"

// sys_rt_exec_state bits (set from interrupts, acted on in protocol_execute_realtime)
#define EXEC_STATUS_REPORT (1 << 0)
#define EXEC_CYCLE_START   (1 << 1)
#define EXEC_CYCLE_STOP    (1 << 2)
#define EXEC_FEED_HOLD     (1 << 3)
#define EXEC_RESET         (1 << 4)
#define EXEC_MOTION_CANCEL (1 << 6)

// sys_rt_exec_motion_override bits (the override real-time bytes)
#define EXEC_FEED_OVR_RESET        (1 << 0)
#define EXEC_FEED_OVR_COARSE_PLUS  (1 << 1)
#define EXEC_FEED_OVR_COARSE_MINUS (1 << 2)
#define EXEC_FEED_OVR_FINE_PLUS    (1 << 3)
#define EXEC_FEED_OVR_FINE_MINUS   (1 << 4)
#define EXEC_RAPID_OVR_RESET       (1 << 5)
#define EXEC_RAPID_OVR_MEDIUM      (1 << 6)
#define EXEC_RAPID_OVR_LOW         (1 << 7)

// sys.state: one bit each, as GRBL
#define STATE_IDLE 0
#define STATE_ALARM (1 << 0)
#define STATE_CHECK_MODE (1 << 1)
#define STATE_HOMING (1 << 2)
#define STATE_CYCLE (1 << 3)
#define STATE_HOLD (1 << 4)
#define STATE_JOG (1 << 5)

// sys.suspend
#define SUSPEND_DISABLE 0
#define SUSPEND_HOLD_COMPLETE (1 << 0)
#define SUSPEND_MOTION_CANCEL (1 << 6)
#define SUSPEND_JOG_CANCEL (1 << 7)

// sys.step_control
#define STEP_CONTROL_NORMAL_OP 0
#define STEP_CONTROL_END_MOTION (1 << 0)
#define STEP_CONTROL_EXECUTE_HOLD (1 << 1)
#define STEP_CONTROL_EXECUTE_SYS_MOTION (1 << 2)

typedef struct {
  uint8_t state;             // STATE_*
  uint8_t abort;             // set on reset: the main loop re-initialises
  uint8_t suspend;           // SUSPEND_*
  uint8_t soft_limit;        // a soft-limit hold is in progress
  uint8_t step_control;      // STEP_CONTROL_*
  uint8_t homing_axis_lock;  // axes still allowed to step while homing (read by the step ISR)
  uint8_t report_wco_counter;
  uint8_t report_ovr_counter;
  uint8_t f_override;        // feed override, percent (10..200)
  uint8_t r_override;        // rapid override, percent (100, 50, 25)
  uint8_t jog_cancelled;     // a jog cancel was taken: mc_line stops queueing the jog line it is in
} system_t;

extern system_t sys;
extern volatile int32_t sys_position[N_AXIS];   // machine position in steps (step ISR writes)
extern volatile uint8_t sys_rt_exec_state;      // EXEC_* (ISRs set, main loop clears)
extern volatile uint8_t sys_rt_exec_alarm;      // EXEC_ALARM_* pending (ISRs set)
extern volatile uint8_t sys_rt_exec_motion_override; // EXEC_*_OVR_* (UART ISR sets, main loop clears)
extern uint8_t sys_fault;                       // fault code reported after the banner (0 = none)

void system_set_exec_state_flag(uint8_t mask);   // any context: atomically set EXEC_* bits
void system_clear_exec_state_flag(uint8_t mask); // main loop: atomically clear EXEC_* bits
void system_set_exec_alarm(uint8_t code);        // any context: raise ALARM:code
void system_clear_exec_alarm(void);              // main loop
uint8_t system_execute_line(char *line);         // main loop: run a '$' line; returns a status code
void system_execute_startup(void);               // main loop: run the $N0/$N1 blocks, each answered ">line:ok"
float system_convert_axis_steps_to_mpos(const int32_t *steps, uint8_t idx); // main loop: steps -> degrees
void system_convert_array_steps_to_mpos(float *position, const int32_t *steps); // main loop: all axes
void system_get_position(int32_t *steps);        // main loop: atomic copy of sys_position
uint8_t system_check_travel_limits(const float *target); // main loop: 1 when target (deg) is outside soft limits
void system_fault(uint8_t cause);                // any context: the fault path: drivers off, ALARM:10, locked

#define FAULT_WATCHDOG 1
#define FAULT_INTERNAL 2

#endif
