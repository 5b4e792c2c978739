/* stage.h -- client for the stage firmware's GRBL 1.1 serial protocol.
 *
 * One stage per serial port. Every function returns 0 on success or -1 with
 * err (RIG_ERR_LEN bytes, rig_err.h) filled as "call: reason"; none aborts
 * on what the controller sends, and every wait has a deadline (stage_opts).
 *
 * Ports: real serial ports are found and opened through libserialport
 * (115200 8N1, no flow control). libserialport 0.1.1 refuses pseudo-terminals
 * (it wants a sysfs entry and the modem-line ioctls), and the simulated stage
 * is one, so a path libserialport cannot open is opened with plain termios.
 * Either way the bytes then go through the same poll(2)/read(2)/write(2) code
 * on the port's file descriptor, which is what the tests exercise. */
#ifndef STAGE_H
#define STAGE_H

#include <signal.h>
#include <stdio.h>
#include "stage_proto.h"

#define STAGE_MAX_SETTINGS 128

typedef struct {
    int baud;              /* 115200 */
    int banner_timeout_ms; /* wait for "Grbl ..." after open or reset (an Uno's bootloader takes ~2 s) */
    int reply_timeout_ms; /* wait for ok/error after a command line */
    int poll_ms;          /* period of '?' status queries while waiting for Idle */
    int move_timeout_ms;  /* deadline of one move until Idle */
    int home_timeout_ms;  /* deadline of a homing cycle */
    int reset_on_open;    /* 1: always soft-reset after opening (clears a half-sent line) */
    FILE *log;            /* traffic trace ("> line", "< line"), NULL for none */
    volatile sig_atomic_t
        *cancel; /* when set non-zero (by a signal handler), waits end with "interrupted" */
} stage_opts;

typedef struct {
    int n;
    double value;
} stage_setting;

typedef struct {
    int fd;          /* the port; -1 when closed or vanished */
    void *sp;        /* struct sp_port * when libserialport opened it */
    int via_termios; /* 1 when opened with plain termios */
    char path[256];
    stage_opts o;
    char banner[96]; /* last banner seen, "" if none */
    char rbuf[512];  /* bytes received and not yet split into lines */
    size_t rlen;
    int last_error;        /* N of the last error:N, 0 if none */
    int last_alarm;        /* N of the last ALARM:N, 0 if none or cleared */
    int reset_seen;        /* a banner arrived unasked: the controller restarted */
    int needs_unlock;      /* the controller said "'$H'|'$X' to unlock" */
    int defaults_restored; /* the controller said its EEPROM failed its CRC check and it now runs on
                                  defaults (steps/degree, limits, rates, offsets): not the rig's values */
    char restored_msg[96]; /* that message, as it came */
    double wco[STAGE_AXES];   /* last work offset seen in a status report */
    stage_status_report last; /* last status report */
    int dead;                 /* the port vanished: every call fails fast */
} stage;

/* Defaults for the options above. */
void stage_opts_default(stage_opts *o);

/* List serial ports libserialport sees, one per line on out: name, VID:PID,
 * description. Returns the count, or -1 with err. */
int stage_list_ports(FILE *out, char *err);

/* Find the first port whose USB VID:PID is a known Arduino or clone
 * (2341:0043 Uno, 2341:0001, 2A03:0043, 1A86:7523 CH340, 0403:6001 FTDI).
 * Fills path (len bytes). Returns 0, or -1 with err when none. */
int stage_find_arduino(char *path, int len, char *err);

/* Open port ("auto" = stage_find_arduino), wait for the banner (probing with
 * '?' and then a soft reset if none comes), then send a line break and read
 * its reply, so that bytes left on the line without one are not glued onto
 * the first command. o may be NULL for defaults. A boot message that the
 * EEPROM failed its CRC check sets defaults_restored (callers report it). */
int stage_open(stage *s, const char *port, const stage_opts *o, char *err);

/* Close the port (idempotent). */
void stage_close(stage *s);

/* Send one line and wait for its ok. error:N, ALARM:N, a reset banner,
 * a vanished port or the deadline fail with err naming the line. Lines of
 * $$ / $# output are passed to on_line (may be NULL). timeout_ms <= 0 means
 * the reply timeout of the options. */
int stage_command(stage *s, const char *line, int timeout_ms,
                  void (*on_line)(void *ctx, const char *line), void *ctx, char *err);

/* Query one status report ('?') into *st (may be NULL; s->last always). */
int stage_status(stage *s, stage_status_report *st, char *err);

/* Poll '?' every poll_ms until the state is Idle; fail on Alarm, an ALARM:N
 * line, a reset or after timeout_ms (<= 0: move_timeout_ms). */
int stage_wait_idle(stage *s, int timeout_ms, char *err);

/* Homing cycle ($H) and wait until Idle. */
int stage_home(stage *s, char *err);

/* Absolute move (G90) to xyz degrees in work coordinates: G0 when feed <= 0,
 * else G1 at feed deg/min. Does not wait for the end of motion. */
int stage_move(stage *s, const double xyz[STAGE_AXES], double feed, char *err);

/* stage_move then stage_wait_idle. */
int stage_move_wait(stage *s, const double xyz[STAGE_AXES], double feed, char *err);

/* Read all settings ($$) into out (max entries); *n gets the count. */
int stage_get_settings(stage *s, stage_setting *out, int max, int *n, char *err);

/* Set one setting ($N=value). */
int stage_set_setting(stage *s, int n, double value, char *err);

/* Unlock an alarm ($X). */
int stage_unlock(stage *s, char *err);

/* Feed hold ('!'), a real-time byte: decelerates without losing position. */
int stage_feed_hold(stage *s, char *err);

/* Soft reset (0x18) and wait for the banner. The controller then may be in
 * Alarm (GRBL enters it after a reset in motion or with homing enabled). */
int stage_reset(stage *s, char *err);

/* Bring a stage back to Idle after an alarm or reset: soft reset, then
 * re-home when the alarm lost the position and rehome is 1, else unlock ($X).
 * Fails when the position was lost and rehome is 0, so that no measurement
 * is taken against an unknown zero. */
int stage_recover(stage *s, int rehome, char *err);

#endif
