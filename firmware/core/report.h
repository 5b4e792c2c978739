// Everything the firmware prints: ok/error, alarms, messages, reports.
#ifndef REPORT_H
#define REPORT_H

#include <stdint.h>

#define MESSAGE_CRITICAL_EVENT 1
#define MESSAGE_ALARM_LOCK 2
#define MESSAGE_ALARM_UNLOCK 3
#define MESSAGE_ENABLED 4
#define MESSAGE_DISABLED 5
#define MESSAGE_CHECK_LIMITS 7
#define MESSAGE_PROGRAM_END 8
#define MESSAGE_RESTORE_DEFAULTS 9
#define MESSAGE_SETTINGS_CRC 10
#define MESSAGE_FAULT_WATCHDOG 11
#define MESSAGE_COORD_CRC 13
#define MESSAGE_FAULT_INTERNAL 12

void printString(const char *s);          // main loop: RAM string
void printPgmString(const char *s);       // main loop: flash string (PSTR on AVR)
void print_uint32(uint32_t n);            // main loop: decimal
void printFloat(float n, uint8_t decimals); // main loop: fixed decimals, rounded
void report_status_message(uint8_t status);      // main loop: "ok" or "error:N"
void report_alarm_message(uint8_t alarm);        // main loop: "ALARM:N"
void report_feedback_message(uint8_t message);   // main loop: "[MSG:...]"
void report_init_message(void);                  // main loop: the banner after (re)start
void report_grbl_help(void);                     // main loop: "[HLP:...]"
void report_grbl_settings(void);                 // main loop: "$N=value" lines
uint8_t report_ngc_parameters(void);             // main loop: "$#" lines; status code
void report_gcode_modes(void);                   // main loop: "[GC:...]"
void report_build_info(const char *info);        // main loop: "$I" lines
void report_startup_line(uint8_t n, const char *line); // main loop: "$Nn=line"
void report_execute_startup_message(const char *line, uint8_t status); // main loop: ">line:ok"
void report_realtime_status(void);               // main loop: "<Idle|MPos:...>"

#endif
