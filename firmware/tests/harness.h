// Test harness over the host port: boot the core, send lines, run until
// quiet, collect replies. Shared by the cmocka tests, the protocol-script
// runner and the fuzzer.
#ifndef HARNESS_H
#define HARNESS_H

#include <string.h>
#include <stdio.h>
#include "board.h"
#include "board_host.h"
#include "serial.h"
#include "settings.h"
#include "protocol.h"
#include "system.h"
#include "planner.h"
#include "stepper.h"
#include "gcode.h"

static char h_out[1 << 16];   // accumulated output not yet taken
static size_t h_out_len;

static inline void h_collect(void)
{
  h_out_len += host_output(h_out + h_out_len, sizeof(h_out) - h_out_len);
}

// Power-on: fresh board state, EEPROM kept (erase it first for a new chip).
static inline void h_boot(void)
{
  memset((void *)sys_position, 0, sizeof(sys_position));   // RAM is cleared at power-on
  board_init();
  serial_init();
  settings_init();
  protocol_init();
  host_watchdog_reset = 0;
  protocol_reset();
  h_collect();
}

static inline void h_erase_eeprom(void)
{
  memset(host_eeprom, 0xff, sizeof(host_eeprom));
}

static inline int h_busy(void)
{
  return serial_get_rx_buffer_available() < RX_BUFFER_SIZE - 1 || host_timer_running() ||
         (plan_get_current_block() != NULL && !(sys.state & (STATE_HOLD | STATE_ALARM))) ||
         sys_rt_exec_state != 0;
}

// Run the main loop until input is consumed and motion has stopped (or a
// hold has completed). Handles soft resets like main() does. max_ms bounds it.
static inline void h_run(uint32_t max_ms)
{
  uint32_t start = board_millis();
  for (;;) {
    protocol_poll();
    if (sys.abort) protocol_reset();
    if (!h_busy()) break;
    if ((uint32_t)(board_millis() - start) > max_ms) break;
  }
  h_collect();
}

// Send bytes as a sender would, feeding the RX buffer as it drains.
static inline void h_send_bytes(const char *s, size_t n)
{
  for (size_t i = 0; i < n; i++) {
    while (serial_get_rx_buffer_available() == 0) {
      protocol_poll();
      if (sys.abort) protocol_reset();
    }
    serial_rx_isr((uint8_t)s[i]);
  }
}

static inline void h_send(const char *line)
{
  h_send_bytes(line, strlen(line));
  h_send_bytes("\n", 1);
  h_run(600000);
}

// Take all output so far (the buffer stays valid until the next h_ call).
static inline const char *h_take(void)
{
  static char taken[sizeof(h_out)];
  h_collect();
  memcpy(taken, h_out, h_out_len);
  taken[h_out_len] = 0;
  h_out_len = 0;
  return taken;
}

// A new chip, powered on: EEPROM erased, no steps counted, the banner taken
// (the tests' cmocka setup).
static inline int h_new_chip(void **state)
{
  (void)state;
  h_erase_eeprom();
  memset(host_motor_steps, 0, sizeof(host_motor_steps));
  h_boot();
  h_take();
  return 0;
}

#endif
