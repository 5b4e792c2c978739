// Serial ring buffers and the real-time command filter (portable part).
#ifndef SERIAL_H
#define SERIAL_H

#include <stdint.h>

#define SERIAL_NO_DATA 0xff

#define CMD_RESET 0x18
#define CMD_STATUS_REPORT '?'
#define CMD_CYCLE_START '~'
#define CMD_FEED_HOLD '!'
#define CMD_SAFETY_DOOR 0x84
#define CMD_JOG_CANCEL 0x85
#define CMD_FEED_OVR_RESET 0x90        // 0x90..0x94: feed 100 %, +10, -10, +1, -1
#define CMD_RAPID_OVR_RESET 0x95       // 0x95..0x97: rapid 100 %, 50 %, 25 %

void serial_init(void);                   // main: empty both buffers
void serial_write(uint8_t c);             // main loop: queue one byte, waits while the TX buffer is full
uint8_t serial_read(void);                // main loop: next received byte or SERIAL_NO_DATA
void serial_reset_read_buffer(void);      // main loop: drop unread input (soft reset)
uint8_t serial_get_rx_buffer_available(void); // any: free bytes in the RX buffer (Bf report)
void serial_rx_isr(uint8_t c);            // UART RX ISR: real-time commands act now, others are queued
int16_t serial_tx_isr(void);              // UART TX ISR: next byte to send, or -1 when empty

#endif
