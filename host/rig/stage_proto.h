/* stage_proto.h -- pure parsers for the stage firmware's GRBL 1.1 replies.
 *
 * No I/O here: every function takes one received line (without its line
 * ending) so that the parsers can be unit-tested on strings (see
 * tests/host/rig_test_proto.c). The client in stage.c uses them. */
#ifndef STAGE_PROTO_H
#define STAGE_PROTO_H

#include "rig_err.h" /* err[] buffers: RIG_ERR_LEN bytes */

#define STAGE_AXES 3

/* What kind of line the controller sent. */
typedef enum {
    STAGE_LINE_EMPTY = 0,
    STAGE_LINE_OK,       /* "ok" */
    STAGE_LINE_ERROR,    /* "error:N" */
    STAGE_LINE_ALARM,    /* "ALARM:N" */
    STAGE_LINE_BANNER,   /* "Grbl 1.1h ['$' for help]": the controller (re)started */
    STAGE_LINE_STATUS,   /* "<Idle|MPos:...>" */
    STAGE_LINE_SETTING,  /* "$100=800.000" */
    STAGE_LINE_MSG,      /* "[MSG:...]" */
    STAGE_LINE_FEEDBACK, /* any other "[...]" ($#, $G, $I, echo) */
    STAGE_LINE_OTHER     /* anything else: noise, garbage, unknown */
} stage_line_kind;

/* One status report. Positions in degrees (the firmware's units). */
typedef struct {
    char state[16]; /* "Idle", "Run", "Hold", "Jog", "Alarm", "Door", "Check", "Home", "Sleep" */
    int substate;   /* the N of "Hold:N" / "Door:N", else -1 */
    int has_mpos, has_wpos, has_wco;
    double mpos[STAGE_AXES];   /* machine position (derived from WPos+WCO when only WPos came) */
    double wpos[STAGE_AXES];   /* work position (derived from MPos-WCO when only MPos came) */
    double wco[STAGE_AXES];    /* work coordinate offset, when the report carried it */
    double feed, speed;        /* FS:/F: fields, 0 if absent */
    int buf_blocks, buf_bytes; /* Bf: fields, -1 if absent */
    char pins[8];              /* Pn: field, "" if absent */
} stage_status_report;

/* Classify a received line; for ERROR/ALARM also return the code in *code
 * (may be NULL). A malformed "error:x" is STAGE_LINE_OTHER. */
stage_line_kind stage_parse_line(const char *line, int *code);

/* Parse "<State|MPos:x,y,z|...>" into *st. known_wco (may be NULL) is the last
 * work offset seen, used to derive MPos from a WPos-only report. Returns 0, or
 * -1 with err filled ("stage_parse_status: reason"). */
int stage_parse_status(const char *line, const double *known_wco, stage_status_report *st,
                       char *err);

/* Parse "$N=value" into *n and *value. Returns 0 or -1 with err. */
int stage_parse_setting(const char *line, int *n, double *value, char *err);

/* The meaning of error:N and ALARM:N as the firmware's tables give it
 * (firmware/doc/error_codes.csv, alarm_codes.csv); "unknown error code" or
 * "unknown alarm code" for a code they lack. */
const char *stage_error_text(int code);
const char *stage_alarm_text(int code);

/* 1 when ALARM:N means the machine position can no longer be trusted
 * (hard limit, reset in motion, homing failures): re-home before measuring. */
int stage_alarm_loses_position(int code);

/* Format a number for a G-code or $ line: fixed point, 4 decimals at most,
 * trailing zeros dropped ("800", "0.01", "-12.5"). Returns buf. */
char *stage_fmt_number(char *buf, int len, double v);

#endif
