// The main loop: line reader, real-time command execution, cycle control.
#ifndef PROTOCOL_H
#define PROTOCOL_H

#include <stdint.h>

void protocol_init(void);               // main: once at power-up, before the first protocol_reset
void protocol_reset(void);              // main: (re)initialise the core after power-up or 0x18, print the banner
void protocol_main_loop(void);          // main: read lines until a reset (sys.abort)
void protocol_poll(void);               // main loop / host tests: one pass: read available bytes, run lines
void protocol_process_char(uint8_t c);  // main loop / fuzzer: feed one received byte to the line reader
void protocol_execute_realtime(void);   // main loop, inside every wait: act on EXEC_* flags and alarms
void protocol_buffer_synchronize(void); // main loop: wait until all queued motion is done
void protocol_auto_cycle_start(void);   // main loop: start motion when blocks are queued

#endif
