// Host port of the board interface (see board_host.h).
#include <string.h>
#include <stdint.h>
#include "board_host.h"
#include "board.h"
#include "config.h"
#include "serial.h"   // serial_tx_isr, serial_rx_isr
#include "stepper.h"  // st_isr
#include "limits.h"   // limits_pin_change_isr
#include "system.h"   // sys_fault

uint8_t host_eeprom[HOST_EEPROM_SIZE];
int32_t host_motor_steps[3];
uint8_t host_limit_raw = 7;
int32_t host_limit_at[3] = {INT32_MAX, INT32_MAX, INT32_MAX};
uint8_t host_stepper_enabled;
uint8_t host_enabled_in_fault;
uint64_t host_cycles;
uint32_t host_max_step_rate_hz;
uint8_t host_watchdog_reset;
void (*host_idle_hook)(void);

static char out_buf[1 << 16];
static size_t out_len;
static uint8_t step_pins, dir_pins, step_idle;
static uint8_t timer_on;
static uint32_t timer_cycles;
static uint8_t limits_irq_on;
static uint8_t in_idle;
// Interrupts as the chip has them: off inside an ISR until it opens them, and
// a pin change seen meanwhile is taken when they open, not in the middle of
// the ISR's pin write (which the chip could never do).
static uint8_t irq_off;
static uint8_t limit_change_pending;

#define SCHED_MAX 64
static struct { uint64_t at; uint8_t c; } sched[SCHED_MAX];
static int n_sched;

void host_reset_board(void)
{
  out_len = 0;
  step_pins = dir_pins = step_idle = 0;
  timer_on = 0;
  n_sched = 0;
  host_stepper_enabled = 0;
  host_enabled_in_fault = 0;
  limits_irq_on = 0;
  in_idle = 0;
  irq_off = 0;
  limit_change_pending = 0;
}

void board_init(void) { host_reset_board(); }
uint8_t board_irq_save(void) { return 0; }
void board_irq_restore(uint8_t flag) { (void)flag; }
static void take_pending_limit_change(void)
{
  if (limit_change_pending && !irq_off) {
    limit_change_pending = 0;
    if (limits_irq_on) limits_pin_change_isr();
  }
}

void board_irq_enable(void) { irq_off = 0; take_pending_limit_change(); }
void board_irq_disable(void) { irq_off = 1; }
uint8_t board_reset_cause_watchdog(void) { return host_watchdog_reset; }
uint8_t host_stack_ok = 1;
uint8_t board_stack_ok(void) { return host_stack_ok; }
uint32_t board_millis(void) { return (uint32_t)(host_cycles / (F_CPU / 1000)); }

void board_uart_tx_kick(void)
{
  int16_t c;
  while ((c = serial_tx_isr()) >= 0) {
    if (out_len < sizeof(out_buf)) out_buf[out_len++] = (char)c;
  }
}

size_t host_output(char *buf, size_t n)
{
  size_t k = out_len < n - 1 ? out_len : n - 1;
  memcpy(buf, out_buf, k);
  buf[k] = 0;
  memmove(out_buf, out_buf + k, out_len - k);
  out_len -= k;
  return k;
}

uint8_t board_eeprom_read(uint16_t addr) { return addr < HOST_EEPROM_SIZE ? host_eeprom[addr] : 0xff; }
void board_eeprom_write(uint16_t addr, uint8_t v) { if (addr < HOST_EEPROM_SIZE) host_eeprom[addr] = v; }

void board_stepper_enable(uint8_t on)
{
  host_stepper_enabled = on;
  if (on && sys_fault) host_enabled_in_fault = 1;
}
void board_stepper_config(uint8_t pulse_us, uint8_t step_idle_bits, uint8_t enable_invert)
{
  step_idle = step_idle_bits;
  step_pins = step_idle;
}

static uint8_t limit_levels(void)
{
  uint8_t lv = host_limit_raw;
  for (int i = 0; i < 3; i++)
    if (host_limit_at[i] != INT32_MAX && host_motor_steps[i] >= host_limit_at[i]) lv &= ~(1 << i);
  return lv;
}

void board_step_write(uint8_t axis_bits)
{
  uint8_t before = limit_levels();
  uint8_t rising = (axis_bits ^ step_idle) & ~(step_pins ^ step_idle);
  for (int i = 0; i < 3; i++) {
    if (rising & (1 << i)) host_motor_steps[i] += (dir_pins & (1 << i)) ? -1 : 1;
  }
  step_pins = axis_bits;
  if (limits_irq_on && before != limit_levels()) {
    limit_change_pending = 1;
    take_pending_limit_change();
  }
}

void board_dir_write(uint8_t axis_bits) { dir_pins = axis_bits; }
void board_step_pulse_start(void) {}

void board_step_timer_set(uint16_t ticks, uint8_t prescale)
{
  static const uint8_t shift[4] = {0, 0, 3, 6};
  timer_cycles = (uint32_t)ticks << shift[prescale & 3];
  if (timer_cycles == 0) timer_cycles = 1;   // a CTC compare of 0 never fires in simavr; here it is a bug
  uint32_t hz = F_CPU / timer_cycles;
  if (hz > host_max_step_rate_hz) host_max_step_rate_hz = hz;
}

void board_step_timer_start(void) { timer_on = 1; }
void board_step_timer_stop(void) { timer_on = 0; step_pins = step_idle; }
uint8_t host_timer_running(void) { return timer_on; }

uint8_t board_limits_read(void) { return limit_levels(); }

void host_set_limit_raw(uint8_t raw)
{
  uint8_t before = limit_levels();
  host_limit_raw = raw;
  if (limits_irq_on && before != limit_levels()) {
    limit_change_pending = 1;
    take_pending_limit_change();
  }
}
void board_limits_irq(uint8_t on) { limits_irq_on = on; }

void host_schedule_byte(uint32_t at_ms, uint8_t c)
{
  if (n_sched < SCHED_MAX) {
    sched[n_sched].at = (uint64_t)at_ms * (F_CPU / 1000);
    sched[n_sched].c = c;
    n_sched++;
  }
}

static void deliver_scheduled(void)
{
  for (int i = 0; i < n_sched; i++) {
    if (host_cycles >= sched[i].at) {
      uint8_t c = sched[i].c;
      memmove(&sched[i], &sched[i + 1], (n_sched - i - 1) * sizeof(sched[0]));
      n_sched--;
      i--;
      serial_rx_isr(c);
    }
  }
}

// Advance simulated time by up to 1 ms: step ticks if the timer runs.
static void host_tick(void)
{
  uint64_t end = host_cycles + F_CPU / 1000;
  while (host_cycles < end) {
    if (timer_on) {
      host_cycles += timer_cycles;
      irq_off = 1;   // ISR entry
      st_isr();
      irq_off = 0;   // reti
      take_pending_limit_change();
      // Pulse end (the compare-B interrupt on the chip).
      step_pins = step_idle;
    } else {
      host_cycles = end;
    }
    deliver_scheduled();
  }
  irq_off = 1;   // the 1 kHz timer interrupt
  limits_tick_isr();
  irq_off = 0;
  take_pending_limit_change();
}

void board_watchdog_kick(void) {}

void board_idle(void)
{
  if (in_idle) return;   // the ISRs run from here; they never wait
  in_idle = 1;
  host_tick();
  if (host_idle_hook) host_idle_hook();
  in_idle = 0;
}

void host_advance_ms(uint32_t ms)
{
  while (ms--) board_idle();
}
