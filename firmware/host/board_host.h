// Host port of the board interface: a deterministic simulated board for
// unit tests, protocol scripts and the fuzzer. Time advances only inside
// board_idle() (the core calls it in every wait), stepping the step timer.
#ifndef BOARD_HOST_H
#define BOARD_HOST_H

#include <stdint.h>
#include <stddef.h>

#define HOST_EEPROM_SIZE 1024

extern uint8_t host_eeprom[HOST_EEPROM_SIZE];
extern int32_t host_motor_steps[3];     // integrated from STEP/DIR edges
extern uint8_t host_limit_raw;          // limit pin levels (bit i = axis i, 1 = high = open)
extern int32_t host_limit_at[3];        // model: switch closes when motor steps >= this (INT32_MAX = none)
extern uint8_t host_stepper_enabled;
extern uint8_t host_enabled_in_fault;   // tests: drivers switched on while a fault stood (must never be)
extern uint64_t host_cycles;            // simulated CPU cycles
extern uint32_t host_max_step_rate_hz;  // highest step rate seen (from timer periods)
extern uint8_t host_watchdog_reset;     // what board_reset_cause_watchdog reports
extern uint8_t host_stack_ok;           // what board_stack_ok reports (0: simulate a stack overflow)
extern void (*host_idle_hook)(void);    // tests: called on every board_idle (fuzzer time budget)

void host_reset_board(void);                      // tests: power-on state (EEPROM kept)
void host_set_limit_raw(uint8_t raw);             // tests: drive the limit pins (a pin change interrupts)
void host_schedule_byte(uint32_t at_ms, uint8_t c); // tests: a byte "received" at simulated time
size_t host_output(char *buf, size_t n);          // tests: copy and clear what the firmware sent
void host_advance_ms(uint32_t ms);                // tests: let time pass (steps run)
uint8_t host_timer_running(void);                 // tests

#endif
