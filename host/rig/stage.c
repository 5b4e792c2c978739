/* stage.c -- GRBL 1.1 client for the stage firmware (see stage.h). */
#define _DEFAULT_SOURCE
#include "stage.h"

#include <errno.h>
#include <fcntl.h>
#include <libserialport.h>
#include <poll.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#define RT_STATUS '?'
#define RT_HOLD   '!'
#define RT_RESET  0x18

static long long now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (long long)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

/* Trace one line of traffic with control bytes escaped, so a log of a
 * garbled exchange shows what really came. */
static void trace(stage *s, const char *dir, const char *line)
{
    const unsigned char *p;
    if (!s->o.log) return;
    fputs(dir, s->o.log);
    for (p = (const unsigned char *)line; *p; p++) {
        if (*p >= 0x20 && *p < 0x7f)
            fputc(*p, s->o.log);
        else
            fprintf(s->o.log, "\\x%02x", *p);
    }
    fputc('\n', s->o.log);
    fflush(s->o.log);
}

void stage_opts_default(stage_opts *o)
{
    memset(o, 0, sizeof(*o));
    o->baud = 115200;
    o->banner_timeout_ms = 5000;
    o->reply_timeout_ms = 2000;
    o->poll_ms = 100;
    o->move_timeout_ms = 120000;
    o->home_timeout_ms = 300000;
    o->reset_on_open = 0;
    o->log = NULL;
}

/* ---- ports ------------------------------------------------------------ */

static const struct {
    int vid, pid;
    const char *what;
} arduino_ids[] = {
    {0x2341, 0x0043, "Arduino Uno"},
    {0x2341, 0x0001, "Arduino Uno (early)"},
    {0x2A03, 0x0043, "Arduino Uno (arduino.org)"},
    {0x2341, 0x0243, "Arduino Uno R3 (16U2)"},
    {0x1A86, 0x7523, "CH340 (Uno clone)"},
    {0x0403, 0x6001, "FTDI FT232 (clone)"},
};

static const char *arduino_name(int vid, int pid)
{
    size_t i;
    for (i = 0; i < sizeof(arduino_ids) / sizeof(arduino_ids[0]); i++)
        if (arduino_ids[i].vid == vid && arduino_ids[i].pid == pid) return arduino_ids[i].what;
    return NULL;
}

int stage_list_ports(FILE *out, char *err)
{
    struct sp_port **ports = NULL;
    int i, n = 0;
    if (sp_list_ports(&ports) != SP_OK) {
        char *m = sp_last_error_message();
        rig_seterr(err, "sp_list_ports: %s", m ? m : "failed");
        sp_free_error_message(m);
        return -1;
    }
    for (i = 0; ports[i]; i++, n++) {
        int vid = 0, pid = 0;
        const char *desc = sp_get_port_description(ports[i]);
        const char *ard = NULL;
        if (sp_get_port_transport(ports[i]) == SP_TRANSPORT_USB &&
            sp_get_port_usb_vid_pid(ports[i], &vid, &pid) == SP_OK)
            ard = arduino_name(vid, pid);
        fprintf(out, "%s\t%04x:%04x\t%s%s%s\n", sp_get_port_name(ports[i]), vid, pid,
                desc ? desc : "", ard ? "\t" : "", ard ? ard : "");
    }
    sp_free_port_list(ports);
    return n;
}

int stage_find_arduino(char *path, int len, char *err)
{
    struct sp_port **ports = NULL;
    int i, found = 0;
    if (sp_list_ports(&ports) != SP_OK) {
        char *m = sp_last_error_message();
        rig_seterr(err, "sp_list_ports: %s", m ? m : "failed");
        sp_free_error_message(m);
        return -1;
    }
    for (i = 0; ports[i] && !found; i++) {
        int vid, pid;
        if (sp_get_port_transport(ports[i]) != SP_TRANSPORT_USB) continue;
        if (sp_get_port_usb_vid_pid(ports[i], &vid, &pid) != SP_OK) continue;
        if (!arduino_name(vid, pid)) continue;
        snprintf(path, (size_t)len, "%s", sp_get_port_name(ports[i]));
        found = 1;
    }
    sp_free_port_list(ports);
    if (!found) {
        rig_seterr(err, "stage_find_arduino: no serial port with a known Arduino USB VID:PID "
                        "(2341:0043, 2341:0001, 1A86:7523, ...); give --port PATH");
        return -1;
    }
    return 0;
}

/* Open through libserialport: the path for real USB/UART ports. */
static int open_libserialport(stage *s, char *why, size_t whylen)
{
    struct sp_port *p = NULL;
    enum sp_return r;
    int fd = -1;

    if ((r = sp_get_port_by_name(s->path, &p)) != SP_OK) goto fail;
    if ((r = sp_open(p, SP_MODE_READ_WRITE)) != SP_OK) goto fail;
    if ((r = sp_set_baudrate(p, s->o.baud)) != SP_OK || (r = sp_set_bits(p, 8)) != SP_OK ||
        (r = sp_set_parity(p, SP_PARITY_NONE)) != SP_OK || (r = sp_set_stopbits(p, 1)) != SP_OK ||
        (r = sp_set_flowcontrol(p, SP_FLOWCONTROL_NONE)) != SP_OK) {
        sp_close(p);
        goto fail;
    }
    if ((r = sp_get_port_handle(p, &fd)) != SP_OK) {
        sp_close(p);
        goto fail;
    }
    /* The descriptor is used with poll(2), which libserialport's docs allow;
     * non-blocking so that a read never outlives its deadline. */
    fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
    s->sp = p;
    s->fd = fd;
    return 0;
fail : {
    char *m = sp_last_error_message();
    snprintf(why, whylen, "%s", (r == SP_ERR_FAIL && m) ? m : "not a port libserialport handles");
    sp_free_error_message(m);
}
    if (p) sp_free_port(p);
    return -1;
}

static speed_t baud_const(int baud)
{
    switch (baud) {
    case 9600: return B9600;
    case 19200: return B19200;
    case 38400: return B38400;
    case 57600: return B57600;
    case 230400: return B230400;
    default: return B115200;
    }
}

/* Open with plain termios: pseudo-terminals (the simulated stage) and any
 * tty libserialport refuses. Raw 8N1, and no TCSAFLUSH: a flush would drop
 * a banner the controller already wrote. */
static int open_termios(stage *s, char *err)
{
    struct termios t;
    int fd = open(s->path, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (fd == -1) {
        rig_seterr(err, "open(%s): %s", s->path, strerror(errno));
        return -1;
    }
    if (tcgetattr(fd, &t) == -1) {
        rig_seterr(err, "tcgetattr(%s): %s", s->path, strerror(errno));
        close(fd);
        return -1;
    }
    cfmakeraw(&t);
    t.c_cflag |= CLOCAL | CREAD;
    t.c_cflag &= ~(CSTOPB | PARENB | CRTSCTS);
    t.c_cc[VMIN] = 0;
    t.c_cc[VTIME] = 0;
    cfsetispeed(&t, baud_const(s->o.baud));
    cfsetospeed(&t, baud_const(s->o.baud));
    if (tcsetattr(fd, TCSANOW, &t) == -1) {
        rig_seterr(err, "tcsetattr(%s): %s", s->path, strerror(errno));
        close(fd);
        return -1;
    }
    s->fd = fd;
    s->via_termios = 1;
    return 0;
}

void stage_close(stage *s)
{
    if (s->sp) {
        sp_close((struct sp_port *)s->sp);
        sp_free_port((struct sp_port *)s->sp);
        s->sp = NULL;
    } else if (s->fd >= 0) {
        close(s->fd);
    }
    s->fd = -1;
}

/* ---- bytes and lines -------------------------------------------------- */

static int vanished(stage *s, const char *call, char *err, int e)
{
    rig_seterr(err, "%s(%s): port vanished (%s)", call, s->path, e ? strerror(e) : "hang-up");
    s->dead = 1;
    return -1;
}

static int write_all(stage *s, const char *buf, size_t len, char *err)
{
    long long deadline = now_ms() + s->o.reply_timeout_ms;
    size_t off = 0;
    if (s->dead || s->fd < 0) {
        rig_seterr(err, "write(%s): port closed after an earlier failure", s->path);
        return -1;
    }
    while (off < len) {
        ssize_t n = write(s->fd, buf + off, len - off);
        if (n > 0) {
            off += (size_t)n;
            continue;
        }
        if (n == -1 && errno == EINTR) continue;
        if (n == -1 && errno == EAGAIN) {
            struct pollfd pfd = {s->fd, POLLOUT, 0};
            long long left = deadline - now_ms();
            if (left <= 0) {
                rig_seterr(err, "write(%s): output blocked for %d ms", s->path,
                           s->o.reply_timeout_ms);
                return -1;
            }
            if (poll(&pfd, 1, (int)left) == 1 && (pfd.revents & (POLLHUP | POLLERR)))
                return vanished(s, "write", err, 0);
            continue;
        }
        return vanished(s, "write", err, n == -1 ? errno : 0);
    }
    return 0;
}

/* Take one complete line out of rbuf; 1 when one was there. */
static int take_line(stage *s, char *line, size_t size)
{
    char *nl = memchr(s->rbuf, '\n', s->rlen);
    size_t n, i, o = 0;
    if (!nl) {
        /* A buffer full of bytes without a newline is garbage: hand it on
         * as one line rather than wedge. */
        if (s->rlen < sizeof(s->rbuf)) return 0;
        nl = s->rbuf + s->rlen - 1;
    }
    n = (size_t)(nl - s->rbuf) + 1;
    for (i = 0; i < n && o + 1 < size; i++) {
        char c = s->rbuf[i];
        if (c == '\n' || c == '\r') continue;
        line[o++] = c ? c : '?'; /* a NUL would cut the C string short */
    }
    line[o] = '\0';
    memmove(s->rbuf, s->rbuf + n, s->rlen - n);
    s->rlen -= n;
    return 1;
}

/* Book-keeping every received line gets, whoever waits for it. */
static stage_line_kind note_line(stage *s, const char *line, int *code)
{
    char perr[RIG_ERR_LEN];
    int c = 0;
    stage_line_kind k = stage_parse_line(line, &c);
    if (code) *code = c;
    if (k != STAGE_LINE_STATUS) trace(s, "< ", line);
    switch (k) {
    case STAGE_LINE_BANNER:
        snprintf(s->banner, sizeof(s->banner), "%s", line);
        s->reset_seen = 1;
        break;
    case STAGE_LINE_ALARM: s->last_alarm = c; break;
    case STAGE_LINE_ERROR: s->last_error = c; break;
    case STAGE_LINE_MSG:
        if (strstr(line, "to unlock")) s->needs_unlock = 1;
        /* "[MSG:EEPROM settings failed CRC check, defaults restored]" (or the
         * coordinate data's): said once, after the boot banner; kept until close. */
        if (strstr(line, "failed CRC check")) {
            s->defaults_restored = 1;
            snprintf(s->restored_msg, sizeof(s->restored_msg), "%s", line);
        }
        break;
    case STAGE_LINE_STATUS: {
        stage_status_report st;
        if (stage_parse_status(line, s->wco, &st, perr) == 0) {
            if (st.has_wco) memcpy(s->wco, st.wco, sizeof(s->wco));
            s->last = st;
        } else {
            trace(s, "< (bad status) ", line);
            k = STAGE_LINE_OTHER;
        }
        break;
    }
    default: break;
    }
    return k;
}

/* Wait for one line until deadline (ms, monotonic). Returns 1 with a line,
 * 0 on timeout, -1 when the port vanished. */
static int read_line(stage *s, char *line, size_t size, long long deadline, char *err)
{
    for (;;) {
        struct pollfd pfd;
        long long left;
        ssize_t n;
        int r;
        if (take_line(s, line, size)) return 1;
        if (s->o.cancel && *s->o.cancel) {
            rig_seterr(err, "read(%s): interrupted", s->path);
            return -1;
        }
        if (s->dead || s->fd < 0) {
            rig_seterr(err, "read(%s): port closed after an earlier failure", s->path);
            return -1;
        }
        left = deadline - now_ms();
        if (left < 0) left = 0;
        pfd.fd = s->fd;
        pfd.events = POLLIN;
        pfd.revents = 0;
        r = poll(&pfd, 1, (int)left);
        if (r == -1 && errno == EINTR) continue; /* the loop top sees a cancel */
        if (r == -1) {
            rig_seterr(err, "poll(%s): %s", s->path, strerror(errno));
            return -1;
        }
        if (r == 0) return 0;
        n = read(s->fd, s->rbuf + s->rlen, sizeof(s->rbuf) - s->rlen);
        if (n > 0) {
            s->rlen += (size_t)n;
            continue;
        }
        if (n == -1 && (errno == EAGAIN || errno == EINTR)) {
            if (pfd.revents & (POLLHUP | POLLERR)) return vanished(s, "read", err, 0);
            continue;
        }
        /* EOF or EIO: a pty whose other side closed, a USB port unplugged. */
        return vanished(s, "read", err, n == -1 ? errno : 0);
    }
}

/* Consume whatever already arrived, so that a late reply of an earlier,
 * failed command is never taken for the reply of the next one. */
static int drain(stage *s, char *err)
{
    char line[256];
    int r;
    while ((r = read_line(s, line, sizeof(line), now_ms(), err)) == 1) {
        trace(s, "  (stale) ", line);
        note_line(s, line, NULL);
    }
    return r < 0 ? -1 : 0;
}

static int send_rt(stage *s, char byte, char *err)
{
    char b = byte;
    if (s->o.log && byte != RT_STATUS)
        fprintf(s->o.log, "> \\x%02x (real-time)\n", (unsigned char)byte);
    return write_all(s, &b, 1, err);
}

/* ---- commands --------------------------------------------------------- */

int stage_command(stage *s, const char *cmd, int timeout_ms,
                  void (*on_line)(void *ctx, const char *line), void *ctx, char *err)
{
    char buf[128], line[256], derr[RIG_ERR_LEN];
    long long deadline;
    size_t len = strlen(cmd);
    int code;

    if (len == 0 || len > 80 || strpbrk(cmd, "\r\n")) {
        rig_seterr(err, "stage_command(%.40s): line empty, over 80 characters or multi-line", cmd);
        return -1;
    }
    if (drain(s, derr) != 0) {
        rig_seterr(err, "stage_command(%s): %s", cmd, derr);
        return -1;
    }
    s->reset_seen = 0;
    trace(s, "> ", cmd);
    memcpy(buf, cmd, len);
    buf[len] = '\n';
    if (write_all(s, buf, len + 1, derr) != 0) {
        rig_seterr(err, "stage_command(%s): %s", cmd, derr);
        return -1;
    }
    if (timeout_ms <= 0) timeout_ms = s->o.reply_timeout_ms;
    deadline = now_ms() + timeout_ms;
    for (;;) {
        int r = read_line(s, line, sizeof(line), deadline, derr);
        if (r < 0) {
            rig_seterr(err, "stage_command(%s): %s", cmd, derr);
            return -1;
        }
        if (r == 0) {
            rig_seterr(err, "stage_command(%s): no reply within %d ms", cmd, timeout_ms);
            return -1;
        }
        switch (note_line(s, line, &code)) {
        case STAGE_LINE_OK: return 0;
        case STAGE_LINE_ERROR:
            rig_seterr(err, "stage_command(%s): error:%d (%s)", cmd, code, stage_error_text(code));
            return -1;
        case STAGE_LINE_ALARM:
            rig_seterr(err, "stage_command(%s): ALARM:%d (%s)", cmd, code, stage_alarm_text(code));
            return -1;
        case STAGE_LINE_BANNER:
            rig_seterr(err, "stage_command(%s): the controller reset before replying ('%s')", cmd,
                       line);
            return -1;
        case STAGE_LINE_EMPTY:
        case STAGE_LINE_STATUS: break;
        default:
            if (on_line) on_line(ctx, line);
            break;
        }
    }
}

int stage_status(stage *s, stage_status_report *st, char *err)
{
    char line[256], derr[RIG_ERR_LEN];
    long long deadline;
    if (drain(s, derr) != 0 || send_rt(s, RT_STATUS, derr) != 0) {
        rig_seterr(err, "stage_status: %s", derr);
        return -1;
    }
    deadline = now_ms() + s->o.reply_timeout_ms;
    for (;;) {
        int r = read_line(s, line, sizeof(line), deadline, derr);
        if (r < 0) {
            rig_seterr(err, "stage_status: %s", derr);
            return -1;
        }
        if (r == 0) {
            rig_seterr(err, "stage_status(%s): no status report within %d ms", s->path,
                       s->o.reply_timeout_ms);
            return -1;
        }
        if (note_line(s, line, NULL) == STAGE_LINE_STATUS) {
            if (st) *st = s->last;
            return 0;
        }
    }
}

int stage_wait_idle(stage *s, int timeout_ms, char *err)
{
    char line[256], derr[RIG_ERR_LEN];
    long long start = now_ms(), deadline;
    int alarm0 = s->last_alarm;

    if (timeout_ms <= 0) timeout_ms = s->o.move_timeout_ms;
    deadline = start + timeout_ms;
    s->reset_seen = 0;
    for (;;) {
        long long next;
        if (stage_status(s, NULL, derr) != 0) {
            rig_seterr(err, "stage_wait_idle: %s", derr);
            return -1;
        }
        if (s->reset_seen) {
            rig_seterr(err, "stage_wait_idle: the controller reset during motion ('%s')",
                       s->banner);
            return -1;
        }
        if (s->last_alarm && s->last_alarm != alarm0) {
            rig_seterr(err, "stage_wait_idle: ALARM:%d (%s)", s->last_alarm,
                       stage_alarm_text(s->last_alarm));
            return -1;
        }
        if (strcmp(s->last.state, "Idle") == 0) return 0;
        if (strcmp(s->last.state, "Alarm") == 0) {
            rig_seterr(err, "stage_wait_idle: stage in Alarm%s%s", s->last_alarm ? ": " : "",
                       s->last_alarm ? stage_alarm_text(s->last_alarm)
                                     : " (unlock with $X or home with $H)");
            return -1;
        }
        if (strcmp(s->last.state, "Check") == 0) {
            rig_seterr(err, "stage_wait_idle: stage in check mode ($C), it does not move");
            return -1;
        }
        if (now_ms() >= deadline) {
            rig_seterr(err, "stage_wait_idle: still %s after %d ms (MPos %.3f,%.3f,%.3f)",
                       s->last.state, timeout_ms, s->last.mpos[0], s->last.mpos[1],
                       s->last.mpos[2]);
            return -1;
        }
        /* Between polls, keep reading so that an ALARM line is seen now. */
        next = now_ms() + s->o.poll_ms;
        if (next > deadline) next = deadline;
        for (;;) {
            int r = read_line(s, line, sizeof(line), next, derr);
            if (r < 0) {
                rig_seterr(err, "stage_wait_idle: %s", derr);
                return -1;
            }
            if (r == 0) break;
            note_line(s, line, NULL);
        }
    }
}

int stage_home(stage *s, char *err)
{
    char derr[RIG_ERR_LEN];
    /* GRBL answers $H only when the cycle is over, so the deadline is the
     * homing one, not the reply one. */
    if (stage_command(s, "$H", s->o.home_timeout_ms, NULL, NULL, derr) != 0 ||
        stage_wait_idle(s, s->o.reply_timeout_ms + s->o.poll_ms * 4, derr) != 0) {
        rig_seterr(err, "stage_home: %s", derr);
        return -1;
    }
    s->last_alarm = 0;
    s->needs_unlock = 0;
    return 0;
}

int stage_move(stage *s, const double xyz[STAGE_AXES], double feed, char *err)
{
    char line[96], a[24], b[24], c[24], f[24];
    int i;
    for (i = 0; i < STAGE_AXES; i++) {
        if (!(xyz[i] > -1e5 && xyz[i] < 1e5)) {
            rig_seterr(err, "stage_move: axis %c target %g out of range", 'X' + i, xyz[i]);
            return -1;
        }
    }
    stage_fmt_number(a, sizeof(a), xyz[0]);
    stage_fmt_number(b, sizeof(b), xyz[1]);
    stage_fmt_number(c, sizeof(c), xyz[2]);
    if (feed > 0)
        snprintf(line, sizeof(line), "G90 G1 F%s X%s Y%s Z%s", stage_fmt_number(f, sizeof(f), feed),
                 a, b, c);
    else
        snprintf(line, sizeof(line), "G90 G0 X%s Y%s Z%s", a, b, c);
    return stage_command(s, line, 0, NULL, NULL, err);
}

int stage_move_wait(stage *s, const double xyz[STAGE_AXES], double feed, char *err)
{
    char derr[RIG_ERR_LEN];
    if (stage_move(s, xyz, feed, err) != 0) return -1;
    /* G4 P0 is GRBL's sync barrier: its ok comes once the planner is empty.
     * Polling alone could see a stale Idle in the instant between the move's
     * ok and the start of the motion. */
    if (stage_command(s, "G4 P0", s->o.move_timeout_ms, NULL, NULL, derr) != 0 ||
        stage_wait_idle(s, 0, derr) != 0) {
        rig_seterr(err, "stage_move_wait: %s", derr);
        return -1;
    }
    return 0;
}

struct settings_ctx {
    stage_setting *out;
    int max, n, bad;
};

static void collect_setting(void *ctx, const char *line)
{
    struct settings_ctx *c = ctx;
    char perr[RIG_ERR_LEN];
    int n;
    double v;
    if (stage_parse_line(line, NULL) != STAGE_LINE_SETTING) return;
    if (stage_parse_setting(line, &n, &v, perr) != 0) {
        c->bad++;
        return;
    }
    if (c->n < c->max) {
        c->out[c->n].n = n;
        c->out[c->n].value = v;
        c->n++;
    }
}

int stage_get_settings(stage *s, stage_setting *out, int max, int *n, char *err)
{
    struct settings_ctx c = {out, max, 0, 0};
    if (stage_command(s, "$$", 0, collect_setting, &c, err) != 0) return -1;
    if (c.bad) {
        rig_seterr(err, "stage_get_settings: %d malformed setting line(s) in the $$ dump", c.bad);
        return -1;
    }
    *n = c.n;
    return 0;
}

int stage_set_setting(stage *s, int n, double value, char *err)
{
    char line[64], v[32];
    if (n < 0 || n > 9999) {
        rig_seterr(err, "stage_set_setting: setting number %d out of range", n);
        return -1;
    }
    snprintf(line, sizeof(line), "$%d=%s", n, stage_fmt_number(v, sizeof(v), value));
    return stage_command(s, line, 0, NULL, NULL, err);
}

int stage_unlock(stage *s, char *err)
{
    if (stage_command(s, "$X", 0, NULL, NULL, err) != 0) return -1;
    s->last_alarm = 0;
    s->needs_unlock = 0;
    return 0;
}

int stage_feed_hold(stage *s, char *err)
{
    char derr[RIG_ERR_LEN];
    if (send_rt(s, RT_HOLD, derr) != 0) {
        rig_seterr(err, "stage_feed_hold: %s", derr);
        return -1;
    }
    return 0;
}

/* Wait for a banner until the deadline. 1 seen, 0 not, -1 port vanished. */
static int wait_banner(stage *s, int timeout_ms, char *err)
{
    char line[256];
    long long deadline = now_ms() + timeout_ms;
    for (;;) {
        int r = read_line(s, line, sizeof(line), deadline, err);
        if (r <= 0) return r;
        if (note_line(s, line, NULL) == STAGE_LINE_BANNER) return 1;
    }
}

/* Wait until the controller shows it runs: its banner (it just started, as
 * an Uno does when the port opens) or, when the banner went to an earlier
 * client, an answer to '?' probes sent after a short silence. A board still
 * in its bootloader takes the stray '?' as a reason to start the program.
 * 1 banner, 2 status report, 0 neither before the deadline, -1 vanished. */
static int wait_alive(stage *s, int timeout_ms, char *err)
{
    char line[256];
    long long deadline = now_ms() + timeout_ms, next_probe = now_ms() + 200;
    for (;;) {
        long long until = next_probe < deadline ? next_probe : deadline;
        int r = read_line(s, line, sizeof(line), until, err);
        if (r < 0) return -1;
        if (r == 1) {
            stage_line_kind k = note_line(s, line, NULL);
            if (k == STAGE_LINE_BANNER) return 1;
            if (k == STAGE_LINE_STATUS) return 2;
            continue;
        }
        if (now_ms() >= deadline) return 0;
        if (send_rt(s, RT_STATUS, err) != 0) return -1;
        next_probe = now_ms() + 500;
    }
}

int stage_reset(stage *s, char *err)
{
    char derr[RIG_ERR_LEN];
    int r;
    if (send_rt(s, RT_RESET, derr) != 0) goto fail;
    /* Bytes before the new banner belong to the old session. */
    r = wait_banner(s, s->o.banner_timeout_ms, derr);
    if (r < 0) goto fail;
    if (r == 0) {
        snprintf(derr, sizeof(derr), "no banner within %d ms after the reset",
                 s->o.banner_timeout_ms);
        goto fail;
    }
    s->reset_seen = 0;
    s->last_error = 0;
    if (stage_status(s, NULL, derr) != 0) goto fail;
    if (strcmp(s->last.state, "Alarm") == 0) s->needs_unlock = 1;
    return 0;
fail:
    rig_seterr(err, "stage_reset: %s", derr);
    return -1;
}

int stage_recover(stage *s, int rehome, char *err)
{
    char derr[RIG_ERR_LEN];
    int alarm = s->last_alarm;
    if (stage_reset(s, derr) != 0) goto fail;
    if (alarm == 0) alarm = s->last_alarm;
    if (strcmp(s->last.state, "Alarm") != 0) {
        s->last_alarm = 0;
        return 0;
    }
    /* GRBL reports no alarm code after a reset that lost the position
     * (ALARM:3 comes before the banner, if at all), so Alarm without a known
     * harmless code counts as a lost position. */
    if (alarm == 0 || stage_alarm_loses_position(alarm)) {
        if (!rehome) {
            snprintf(derr, sizeof(derr),
                     "stage in Alarm%s%s%s; the position may be lost: "
                     "home it ($H) before measuring",
                     alarm ? " (" : "", alarm ? stage_alarm_text(alarm) : "", alarm ? ")" : "");
            goto fail;
        }
        if (stage_home(s, derr) != 0) goto fail;
        return 0;
    }
    if (stage_unlock(s, derr) != 0) goto fail;
    return 0;
fail:
    rig_seterr(err, "stage_recover: %s", derr);
    return -1;
}

/* End what an earlier client or line noise left in the controller's line
 * buffer without a newline: it would be glued onto our first command
 * ("G0 X" + "$X" = "G0 X$X", an error for a command that was fine). The line
 * break makes it a line of its own, and its reply (ok for an empty buffer,
 * error:N for junk) is read here, never taken for the next command's. */
static int end_stray_line(stage *s, char *err)
{
    char line[256];
    long long deadline;
    int code;
    trace(s, "> ", "(line break)");
    if (write_all(s, "\n", 1, err) != 0) return -1;
    deadline = now_ms() + s->o.reply_timeout_ms;
    for (;;) {
        int r = read_line(s, line, sizeof(line), deadline, err);
        if (r < 0) return -1;
        if (r == 0) {
            rig_seterr(err, "no reply to a line break within %d ms", s->o.reply_timeout_ms);
            return -1;
        }
        switch (note_line(s, line, &code)) {
        case STAGE_LINE_OK: return 0;
        case STAGE_LINE_ERROR:
            if (s->o.log)
                fprintf(s->o.log,
                        "stage: bytes left on the line before this session were refused "
                        "(error:%d)\n",
                        code);
            s->last_error = 0;
            return 0;
        default: break;
        }
    }
}

int stage_open(stage *s, const char *port, const stage_opts *o, char *err)
{
    char why[RIG_ERR_LEN], derr[RIG_ERR_LEN];
    int r;

    memset(s, 0, sizeof(*s));
    s->fd = -1;
    if (o)
        s->o = *o;
    else
        stage_opts_default(&s->o);
    if (strcmp(port, "auto") == 0) {
        if (stage_find_arduino(s->path, sizeof(s->path), err) != 0) return -1;
    } else {
        snprintf(s->path, sizeof(s->path), "%s", port);
    }
    if (open_libserialport(s, why, sizeof(why)) != 0) {
        if (s->o.log)
            fprintf(s->o.log, "stage: libserialport: %s: %s; using termios\n", s->path, why);
        if (open_termios(s, err) != 0) return -1;
    } else if (s->o.log) {
        fprintf(s->o.log, "stage: opened %s with libserialport\n", s->path);
    }
    if (s->o.reset_on_open) {
        if (send_rt(s, RT_RESET, derr) != 0) goto fail;
        r = wait_banner(s, s->o.banner_timeout_ms, derr);
    } else {
        r = wait_alive(s, s->o.banner_timeout_ms, derr);
    }
    if (r < 0) goto fail;
    if (r == 0 && stage_reset(s, derr) != 0) {
        if (s->dead) goto fail;
        snprintf(derr, sizeof(derr),
                 "no GRBL banner within %d ms, no answer to '?' or to a "
                 "soft reset (is this the stage, at %d baud?)",
                 s->o.banner_timeout_ms, s->o.baud);
        goto fail;
    }
    if (r == 2 && s->o.log) fprintf(s->o.log, "stage: no banner, but the controller answers\n");
    if (end_stray_line(s, derr) != 0) goto fail;
    s->reset_seen = 0;
    if (stage_status(s, NULL, derr) != 0) goto fail;
    if (strcmp(s->last.state, "Alarm") == 0) s->needs_unlock = 1;
    return 0;
fail:
    rig_seterr(err, "stage_open(%s): %s", s->path, derr);
    stage_close(s);
    return -1;
}
