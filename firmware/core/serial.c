// Serial ring buffers and the real-time command filter (portable part).
// The board's UART interrupts call serial_rx_isr / serial_tx_isr.
#include "serial.h"
#include "config.h"
#include "board.h"    // board_uart_tx_kick, board_idle
#include "system.h"   // exec flags, sys.state
#include "motion.h"   // mc_reset
#include "stepper.h"  // st_prep_buffer

static uint8_t rx_buffer[RX_RING_SIZE];
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
  // Against the advertised 127 of 128, as GRBL reports it: the headroom is
  // for senders that overfill, not room to count on.
  uint8_t rtail = rx_tail;
  uint8_t head = rx_head;
  uint8_t used = head >= rtail ? head - rtail : RX_RING_SIZE - (rtail - head);
  return used >= RX_BUFFER_SIZE - 1 ? 0 : RX_BUFFER_SIZE - 1 - used;
}

void serial_write(uint8_t c)
{
  uint8_t head = tx_head;
  uint8_t next = head + 1;
  if (next == TX_BUFFER_SIZE) next = 0;
  while (next == tx_tail) {
    // A reset empties the queue so a stalled host cannot wedge the loop.
    if (sys_rt_exec_state & EXEC_RESET) return;
    // A long reply ('$$' mid-stream) must not starve the stepper of segments.
    if (sys.state & (STATE_CYCLE | STATE_HOLD | STATE_JOG | STATE_HOMING)) st_prep_buffer();
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
  if (++tail == RX_RING_SIZE) tail = 0;
  rx_tail = tail;
  return c;
}

void serial_reset_read_buffer(void)
{
  rx_tail = rx_head;
}

// Senders written in languages with text strings send the extended
// real-time commands UTF-8 encoded: 0x85 (jog cancel) as C2 85. The code
// point U+0080..U+00BF is the command byte; other characters (lead byte and
// continuation bytes) are dropped whole, so their continuation bytes are
// never taken for commands.
static uint8_t utf8_left;   // continuation bytes still to come
static uint8_t utf8_c2;     // ... of a character that began with C2

void serial_rx_isr(uint8_t c)
{
  switch (c) {
    case CMD_RESET: mc_reset(); break;
    case CMD_STATUS_REPORT: system_set_exec_state_flag(EXEC_STATUS_REPORT); break;
    case CMD_CYCLE_START: system_set_exec_state_flag(EXEC_CYCLE_START); break;
    case CMD_FEED_HOLD: system_set_exec_state_flag(EXEC_FEED_HOLD); break;
    default:
      if (c > 0x7f) {
        if (c >= 0xc0) {   // a UTF-8 lead byte: never a command itself
          utf8_left = c >= 0xf0 ? 3 : (c >= 0xe0 ? 2 : 1);
          utf8_c2 = (c == 0xc2);
          return;
        }
        if (utf8_left) {   // a continuation byte
          utf8_left--;
          if (!utf8_c2) return;
          utf8_c2 = 0;
        }
        // Extended real-time commands; unknown ones are dropped, as GRBL does.
        if (c == CMD_JOG_CANCEL) {
          if (sys.state == STATE_JOG) system_set_exec_state_flag(EXEC_MOTION_CANCEL);
        } else if (c >= CMD_FEED_OVR_RESET && c <= CMD_RAPID_OVR_RESET + 2) {
          // one bit per byte, in the order of the EXEC_*_OVR_* bits
          sys_rt_exec_motion_override |= 1 << (c - CMD_FEED_OVR_RESET);   // ISR: no other writer runs
        }
        return;
      }
      uint8_t head = rx_head;
      uint8_t next = head + 1;
      if (next == RX_RING_SIZE) next = 0;
      if (next != rx_tail) {   // full even with the headroom: the byte is lost, as in GRBL
        rx_buffer[head] = c;
        rx_head = next;
      }
  }
  utf8_left = 0;   // an ASCII byte ends any unfinished character
}
