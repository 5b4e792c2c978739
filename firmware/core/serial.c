// Serial ring buffers and the real-time command filter (portable part).
// The board's UART interrupts call serial_rx_isr / serial_tx_isr.
#include "serial.h"
#include "config.h"
#include "board.h"    // board_uart_tx_kick, board_idle
#include "system.h"   // exec flags, sys.state
#include "motion.h"   // mc_reset

static uint8_t rx_buffer[RX_BUFFER_SIZE];
static volatile uint8_t rx_head;
static volatile uint8_t rx_tail;
static uint8_t tx_buffer[TX_BUFFER_SIZE];
static volatile uint8_t tx_head;
static volatile uint8_t tx_tail;

void serial_init(void)
{
  rx_head = rx_tail = 0;
  tx_head = tx_tail = 0;
}

uint8_t serial_get_rx_buffer_available(void)
{
  uint8_t rtail = rx_tail;
  uint8_t head = rx_head;
  if (head >= rtail) return RX_BUFFER_SIZE - 1 - (head - rtail);
  return rtail - head - 1;
}

void serial_write(uint8_t c)
{
  uint8_t head = tx_head;
  uint8_t next = head + 1;
  if (next == TX_BUFFER_SIZE) next = 0;
  while (next == tx_tail) {
    // A reset empties the queue so a stalled host cannot wedge the loop.
    if (sys_rt_exec_state & EXEC_RESET) return;
    board_idle();
  }
  tx_buffer[head] = c;
  tx_head = next;
  board_uart_tx_kick();
}

int16_t serial_tx_isr(void)
{
  uint8_t tail = tx_tail;
  if (tail == tx_head) return -1;
  uint8_t c = tx_buffer[tail];
  if (++tail == TX_BUFFER_SIZE) tail = 0;
  tx_tail = tail;
  return c;
}

uint8_t serial_read(void)
{
  uint8_t tail = rx_tail;
  if (tail == rx_head) return SERIAL_NO_DATA;
  uint8_t c = rx_buffer[tail];
  if (++tail == RX_BUFFER_SIZE) tail = 0;
  rx_tail = tail;
  return c;
}

void serial_reset_read_buffer(void)
{
  rx_tail = rx_head;
}

void serial_rx_isr(uint8_t c)
{
  switch (c) {
    case CMD_RESET: mc_reset(); return;
    case CMD_STATUS_REPORT: system_set_exec_state_flag(EXEC_STATUS_REPORT); return;
    case CMD_CYCLE_START: system_set_exec_state_flag(EXEC_CYCLE_START); return;
    case CMD_FEED_HOLD: system_set_exec_state_flag(EXEC_FEED_HOLD); return;
  }
  if (c > 0x7f) {
    // Extended real-time commands; unknown ones are dropped, as GRBL does.
    if (c == CMD_JOG_CANCEL && sys.state == STATE_JOG)
      system_set_exec_state_flag(EXEC_MOTION_CANCEL);
    return;
  }
  uint8_t head = rx_head;
  uint8_t next = head + 1;
  if (next == RX_BUFFER_SIZE) next = 0;
  if (next != rx_tail) {   // full: the byte is lost, as in GRBL (senders count characters)
    rx_buffer[head] = c;
    rx_head = next;
  }
}
