// The board interface: everything the portable core needs from a chip.
// Implemented by avr/board_avr.c (ATmega328P) and host/board_host.c (tests).
#ifndef BOARD_H
#define BOARD_H

#include <stdint.h>

void board_init(void);                    // main, once at power-up: pins, UART, timers, watchdog
uint8_t board_irq_save(void);             // any context: disable interrupts, return previous state
void board_irq_restore(uint8_t flag);     // any context: restore what board_irq_save returned
void board_irq_enable(void);              // step ISR only: allow nesting (pulse end, UART)
void board_irq_disable(void);             // step ISR only: end of the nested section

void board_uart_tx_kick(void);            // main loop: a byte is queued; enable the TX interrupt
uint32_t board_millis(void);              // any context: milliseconds since power-up (wraps)
void board_idle(void);                    // main loop, inside every wait: kicks the watchdog
void board_watchdog_kick(void);           // main loop: kicks the watchdog, no wait (once per line read)
uint8_t board_reset_cause_watchdog(void); // main, at boot: 1 when the last reset was the watchdog
uint8_t board_stack_ok(void);             // main loop: 0 once the stack has grown into static data

uint8_t board_eeprom_read(uint16_t addr);           // main loop: one EEPROM byte
void board_eeprom_write(uint16_t addr, uint8_t v);  // main loop: one byte, waits for the write

void board_stepper_enable(uint8_t on);    // any context: drivers on (1) / off (0); invert applied here
void board_stepper_config(uint8_t pulse_us, uint8_t step_idle_bits, uint8_t enable_invert); // main loop: after settings change
void board_step_write(uint8_t axis_bits); // step ISR: step pins = axis bits (bit 0 = X), inversion done by caller
void board_step_pulse_start(void);        // step ISR, right after board_step_write: end the pulse $0 us from now
void board_dir_write(uint8_t axis_bits);  // step ISR / main: direction pins, inversion done by caller
void board_step_timer_set(uint16_t ticks, uint8_t prescale); // step ISR / main: period in ticks of 1 (1), 8 (2) or 64 (3) cycles
void board_step_timer_start(void);        // main loop: start the step interrupt (first tick after one period)
void board_step_timer_stop(void);         // any context: stop the step interrupt, step pins idle

uint8_t board_limits_read(void);          // any context: raw limit pin levels, bit 0 = X, 1 = high
void board_limits_irq(uint8_t on);        // main loop: pin-change interrupt for hard limits on/off

#endif
