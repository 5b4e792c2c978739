/* stage_proto.c -- parsers for GRBL 1.1 replies (see stage_proto.h). */
#include "stage_proto.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* error_texts[] and alarm_texts[]: the descriptions of firmware/doc/
 * error_codes.csv and alarm_codes.csv (GRBL 1.1's numbers and texts, plus this
 * firmware's own), generated at build time by codes_from_csv.awk so that the
 * host shows what the firmware documents. */
#include "stage_codes.h"

#define NELEM(a) ((int)(sizeof(a) / sizeof((a)[0])))

const char *stage_error_text(int code)
{
    if (code > 0 && code < NELEM(error_texts) && error_texts[code]) return error_texts[code];
    return "unknown error code";
}

const char *stage_alarm_text(int code)
{
    if (code > 0 && code < NELEM(alarm_texts) && alarm_texts[code]) return alarm_texts[code];
    return "unknown alarm code";
}

int stage_alarm_loses_position(int code)
{
    switch (code) {
    case 2:
    case 4:
    case 5: return 0;
    default: return 1; /* unknown alarms: assume the worst */
    }
}

/* Parse a decimal integer that fills the rest of s; -1 if it does not. */
static int parse_code(const char *s, int *code)
{
    char *end;
    long v;
    if (!isdigit((unsigned char)*s)) return -1;
    errno = 0;
    v = strtol(s, &end, 10);
    if (errno || *end != '\0' || v > 100000) return -1;
    *code = (int)v;
    return 0;
}

stage_line_kind stage_parse_line(const char *line, int *code)
{
    int c = 0;
    if (line[0] == '\0') return STAGE_LINE_EMPTY;
    if (strcmp(line, "ok") == 0) return STAGE_LINE_OK;
    if (strncmp(line, "error:", 6) == 0) {
        if (parse_code(line + 6, &c) != 0) return STAGE_LINE_OTHER;
        if (code) *code = c;
        return STAGE_LINE_ERROR;
    }
    if (strncmp(line, "ALARM:", 6) == 0) {
        if (parse_code(line + 6, &c) != 0) return STAGE_LINE_OTHER;
        if (code) *code = c;
        return STAGE_LINE_ALARM;
    }
    /* Senders recognise the controller by "Grbl " at the start of a line. */
    if (strncmp(line, "Grbl ", 5) == 0) return STAGE_LINE_BANNER;
    if (line[0] == '<' && line[strlen(line) - 1] == '>') return STAGE_LINE_STATUS;
    if (line[0] == '$' && isdigit((unsigned char)line[1]) && strchr(line, '='))
        return STAGE_LINE_SETTING;
    if (strncmp(line, "[MSG:", 5) == 0) return STAGE_LINE_MSG;
    if (line[0] == '[' && line[strlen(line) - 1] == ']') return STAGE_LINE_FEEDBACK;
    return STAGE_LINE_OTHER;
}

/* Parse "a,b,c" (exactly n finite numbers, nothing after) into v. */
static int parse_vec(const char *s, size_t len, double *v, int n)
{
    char tmp[96], *p, *end;
    int i;
    if (len == 0 || len >= sizeof(tmp)) return -1;
    memcpy(tmp, s, len);
    tmp[len] = '\0';
    p = tmp;
    for (i = 0; i < n; i++) {
        errno = 0;
        v[i] = strtod(p, &end);
        if (end == p || errno || !isfinite(v[i])) return -1;
        if (i < n - 1) {
            if (*end != ',') return -1;
            p = end + 1;
        }
    }
    /* GRBL may report more axes than we use (A, B, C): ignore them. */
    return (*end == '\0' || *end == ',') ? 0 : -1;
}

int stage_parse_status(const char *line, const double *known_wco, stage_status_report *st,
                       char *err)
{
    size_t len = strlen(line);
    const char *p, *end, *bar;
    int i, field = 0;

    memset(st, 0, sizeof(*st));
    st->substate = -1;
    st->buf_blocks = st->buf_bytes = -1;
    if (len < 3 || line[0] != '<' || line[len - 1] != '>') {
        rig_seterr(err, "stage_parse_status: not a status report");
        return -1;
    }
    p = line + 1;
    end = line + len - 1;
    while (p < end) {
        size_t flen;
        bar = memchr(p, '|', (size_t)(end - p));
        if (!bar) bar = end;
        flen = (size_t)(bar - p);
        if (field == 0) {
            /* Machine state, optionally with ":N" substate. */
            const char *colon = memchr(p, ':', flen);
            size_t slen = colon ? (size_t)(colon - p) : flen;
            if (slen == 0 || slen >= sizeof(st->state)) goto bad;
            for (i = 0; i < (int)slen; i++)
                if (!isalpha((unsigned char)p[i])) goto bad;
            memcpy(st->state, p, slen);
            st->state[slen] = '\0';
            if (colon) {
                char tmp[8];
                size_t dl = flen - slen - 1;
                if (dl == 0 || dl >= sizeof(tmp)) goto bad;
                memcpy(tmp, colon + 1, dl);
                tmp[dl] = '\0';
                if (parse_code(tmp, &st->substate) != 0) goto bad;
            }
        } else if (flen > 5 && strncmp(p, "MPos:", 5) == 0) {
            if (parse_vec(p + 5, flen - 5, st->mpos, STAGE_AXES) != 0) goto bad;
            st->has_mpos = 1;
        } else if (flen > 5 && strncmp(p, "WPos:", 5) == 0) {
            if (parse_vec(p + 5, flen - 5, st->wpos, STAGE_AXES) != 0) goto bad;
            st->has_wpos = 1;
        } else if (flen > 4 && strncmp(p, "WCO:", 4) == 0) {
            if (parse_vec(p + 4, flen - 4, st->wco, STAGE_AXES) != 0) goto bad;
            st->has_wco = 1;
        } else if (flen > 3 && strncmp(p, "FS:", 3) == 0) {
            double fs[2];
            if (parse_vec(p + 3, flen - 3, fs, 2) != 0) goto bad;
            st->feed = fs[0];
            st->speed = fs[1];
        } else if (flen > 2 && strncmp(p, "F:", 2) == 0) {
            if (parse_vec(p + 2, flen - 2, &st->feed, 1) != 0) goto bad;
        } else if (flen > 3 && strncmp(p, "Bf:", 3) == 0) {
            double bf[2];
            if (parse_vec(p + 3, flen - 3, bf, 2) != 0) goto bad;
            st->buf_blocks = (int)bf[0];
            st->buf_bytes = (int)bf[1];
        } else if (flen > 3 && strncmp(p, "Pn:", 3) == 0) {
            size_t n = flen - 3 < sizeof(st->pins) - 1 ? flen - 3 : sizeof(st->pins) - 1;
            memcpy(st->pins, p + 3, n);
            st->pins[n] = '\0';
        }
        /* Other fields (Ln, Ov, A, ...) are legal and of no use here. */
        p = bar + 1;
        field++;
    }
    if (st->state[0] == '\0') goto bad;
    if (!st->has_mpos && !st->has_wpos) {
        rig_seterr(err, "stage_parse_status: no MPos or WPos in '%.80s'", line);
        return -1;
    }
    /* MPos = WPos + WCO (GRBL's definition); the offset of this report wins
     * over the last one seen, and none known means zero. */
    {
        double wco[STAGE_AXES] = {0, 0, 0};
        if (st->has_wco)
            memcpy(wco, st->wco, sizeof(wco));
        else if (known_wco)
            memcpy(wco, known_wco, sizeof(wco));
        for (i = 0; i < STAGE_AXES; i++) {
            if (st->has_mpos && !st->has_wpos) st->wpos[i] = st->mpos[i] - wco[i];
            if (st->has_wpos && !st->has_mpos) st->mpos[i] = st->wpos[i] + wco[i];
        }
    }
    return 0;
bad:
    rig_seterr(err, "stage_parse_status: malformed report '%.80s'", line);
    return -1;
}

int stage_parse_setting(const char *line, int *n, double *value, char *err)
{
    const char *eq;
    char *end;
    long num;
    double v;

    if (line[0] != '$' || !isdigit((unsigned char)line[1]) || !(eq = strchr(line, '='))) goto bad;
    errno = 0;
    num = strtol(line + 1, &end, 10);
    if (errno || end != eq || num < 0 || num > 100000) goto bad;
    errno = 0;
    v = strtod(eq + 1, &end);
    if (end == eq + 1 || errno || !isfinite(v)) goto bad;
    /* GRBL 1.1 with verbose settings appends " (description)"; accept it. */
    while (*end == ' ') end++;
    if (*end != '\0' && *end != '(') goto bad;
    *n = (int)num;
    *value = v;
    return 0;
bad:
    rig_seterr(err, "stage_parse_setting: malformed setting '%.80s'", line);
    return -1;
}

char *stage_fmt_number(char *buf, int len, double v)
{
    char *dot, *e;
    if (fabs(v) < 0.00005) v = 0.0; /* no "-0" */
    snprintf(buf, (size_t)len, "%.4f", v);
    dot = strchr(buf, '.');
    if (dot) {
        e = buf + strlen(buf) - 1;
        while (e > dot && *e == '0') *e-- = '\0';
        if (e == dot) *e = '\0';
    }
    return buf;
}
