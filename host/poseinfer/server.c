/* server.c -- the daemon: a line protocol over a Unix or loopback TCP socket,
 * and continuous capture. One event-loop thread owns the sockets and waits
 * in poll(2) (with no timeout when no client is connected, so an idle
 * daemon uses no CPU); frames and model loads go to worker threads
 * (pool.c), so one slow frame holds only its own client. Protocol and
 * limits: docs/poseinfer.md. */
#define _GNU_SOURCE
#include "server.h"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <grp.h>
#include <limits.h>
#include <malloc.h>
#include <math.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include "internal.h"
#include "pool.h"

#define MAX_LINE 4096
#define MAX_OUT  (1024 * 1024)

static volatile sig_atomic_t got_stop, got_hup;
static int sig_pipe[2] = {-1, -1};

void log_msg(const char *fmt, ...)
{
    char buf[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    fprintf(stderr, "poseinfer: %s\n", buf);
}

static void on_signal(int sig)
{
    int saved = errno;
    if (sig == SIGHUP)
        got_hup = 1;
    else
        got_stop = 1;
    if (sig_pipe[1] >= 0) {
        ssize_t w = write(sig_pipe[1], "x", 1); /* wake poll; a full pipe is fine */
        (void)w;
    }
    errno = saved;
}

int signals_install(char *err)
{
    struct sigaction sa;
    if (sig_pipe[0] < 0 && pipe2(sig_pipe, O_CLOEXEC | O_NONBLOCK) < 0) {
        pi_seterr(err, "pipe2: %s", strerror(errno));
        return -1;
    }
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = 0; /* no SA_RESTART: a blocking call returns EINTR */
    if (sigaction(SIGTERM, &sa, NULL) < 0 || sigaction(SIGINT, &sa, NULL) < 0 ||
        sigaction(SIGHUP, &sa, NULL) < 0) {
        pi_seterr(err, "sigaction: %s", strerror(errno));
        return -1;
    }
    signal(SIGPIPE, SIG_IGN);
    return 0;
}

static void drain_sig_pipe(void)
{
    char buf[64];
    while (read(sig_pipe[0], buf, sizeof buf) > 0) {
    }
}

/* ---- JSON lines ------------------------------------------------------------ */

/* `{"key": "name", ` when the line names its input */
static void open_line(sbuf *s, const char *key, const char *name)
{
    sb_puts(s, "{");
    if (key) {
        sb_json_str(s, key);
        sb_puts(s, ": ");
        sb_json_str(s, name);
        sb_puts(s, ", ");
    }
}

/* `<label>number`, label being `, "key": ` */
static void put_num(sbuf *s, const char *label, double v, int decimals)
{
    sb_puts(s, label);
    sb_json_num(s, v, decimals);
}

/* `[a, b, ...]` */
static void put_nums(sbuf *s, const double *v, int n, int decimals)
{
    sb_puts(s, "[");
    for (int i = 0; i < n; i++) {
        if (i) sb_puts(s, ", ");
        sb_json_num(s, v[i], decimals);
    }
    sb_puts(s, "]");
}

void result_json(sbuf *s, const char *key, const char *name, const pi_result *r, int timings)
{
    open_line(s, key, name);
    put_num(s, "\"x\": ", r->x, 4);
    put_num(s, ", \"y\": ", r->y, 4);
    put_num(s, ", \"z\": ", r->z, 4);
    put_num(s, ", \"ms\": ", r->total_ms, 3);
    /* the sphere's circle, conventions' continuous pixels (docs/poseinfer.md) */
    sb_puts(s, ", \"circle\": ");
    put_nums(s, r->circle, 3, 3);
    /* docs/refine.md: null when the model carries no texture */
    sb_puts(s, r->has_confidence
                   ? (r->confident ? ", \"confident\": true" : ", \"confident\": false")
                   : ", \"confident\": null");
    put_num(s, ", \"residual\": ", r->has_confidence ? r->residual : NAN, 5);
    if (r->has_confidence && !r->confident) {
        sb_puts(s, ", \"note\": ");
        sb_json_str(s, r->note);
    }
    if (r->has_rotmat) {
        sb_puts(s, ", \"rotmat\": [");
        for (int i = 0; i < 3; i++) {
            if (i) sb_puts(s, ", ");
            put_nums(s, r->rotmat[i], 3, 6);
        }
        sb_puts(s, "]");
    }
    if (timings) {
        put_num(s, ", \"decode_ms\": ", r->decode_ms, 3);
        put_num(s, ", \"preprocess_ms\": ", r->preprocess_ms, 3);
        put_num(s, ", \"locate_ms\": ", r->locate_ms, 3);
        put_num(s, ", \"infer_ms\": ", r->infer_ms, 3);
        put_num(s, ", \"refine_ms\": ", r->refine_ms, 3);
        sb_puts(s, ", \"net\": ");
        put_nums(s, r->net, 3, 4);
        put_num(s, ", \"cx\": ", r->cx, 2);
        put_num(s, ", \"cy\": ", r->cy, 2);
        put_num(s, ", \"r\": ", r->r, 2);
    }
    sb_puts(s, "}");
}

void error_json(sbuf *s, const char *key, const char *name, const char *msg)
{
    open_line(s, key, name);
    sb_puts(s, "\"error\": ");
    sb_json_str(s, msg);
    sb_puts(s, "}");
}

/* ---- stats -------------------------------------------------------------------- */

static void record(app *a, int ok, double ms)
{
    pthread_mutex_lock(&a->lock);
    if (!ok) {
        a->errors++;
    } else {
        a->frames++;
        a->lat[a->nlat % LAT_WINDOW] = ms;
        a->nlat++;
    }
    pthread_mutex_unlock(&a->lock);
}

static int cmp_double(const void *x, const void *y)
{
    double a = *(const double *)x, b = *(const double *)y;
    return (a > b) - (a < b);
}

double app_percentile(const app *a, double pct)
{
    double tmp[LAT_WINDOW];
    size_t n = a->nlat < LAT_WINDOW ? a->nlat : LAT_WINDOW;
    size_t idx;
    if (n == 0) return NAN;
    memcpy(tmp, a->lat, n * sizeof(double));
    qsort(tmp, n, sizeof(double), cmp_double);
    idx = (size_t)ceil(pct / 100.0 * (double)n);
    if (idx > 0) idx--;
    if (idx >= n) idx = n - 1;
    return tmp[idx];
}

int app_reload(app *a, char *err)
{
    pi_options o;
    pi_ctx *n, *old;
    pthread_mutex_lock(&a->reload_lock);
    pi_options_init(&o);
    o.intra_threads = a->cfg->threads;
    o.warmup_runs = a->cfg->warmup;
    o.max_pixels = a->cfg->max_pixels;
    o.camera_file = a->cfg->camera_file;
    n = pi_open(a->cfg->model, &o, err);
    if (!n) {
        pthread_mutex_unlock(&a->reload_lock);
        return -1;
    }
    /* Workers still on the old model finish their frame with it: a clone
     * keeps the session alive (pi_clone), and they re-clone when gen moves. */
    pthread_mutex_lock(&a->lock);
    old = a->ctx;
    a->ctx = n;
    a->gen++;
    a->reloads++;
    pthread_mutex_unlock(&a->lock);
    pi_close(old);
    pthread_mutex_unlock(&a->reload_lock);
    return 0;
}

/* ---- protocol ------------------------------------------------------------------- */

static const char *skip_space(const char *s)
{
    while (*s == ' ' || *s == '\t') s++;
    return s;
}

#define COMMANDS "commands: ping, infer PATH, frame N, grab, stats, reload, auth TOKEN, quit"

static job *job_new(job_kind kind)
{
    job *j = calloc(1, sizeof *j);
    if (j) {
        j->kind = kind;
        j->client = -1;
        sb_init(&j->out);
    }
    return j;
}

/* The members of a result after ours: {"bytes": N, "x": ...}. */
static void result_after(sbuf *out, const pi_result *r)
{
    sbuf t;
    sb_init(&t);
    result_json(&t, NULL, NULL, r, 1);
    sb_puts(out, t.buf ? t.buf + 1 : "}");
    sb_free(&t);
}

void proto_run(app *a, pi_ctx *ctx, job *j)
{
    static const access_policy none;
    char err[PI_ERR_LEN];
    pi_result r;
    sbuf *out = &j->out;
    int fd;
    switch (j->kind) {
    case JOB_INFER:
        if (!ctx) {
            error_json(out, "file", j->arg, "no model loaded");
        } else if ((fd = access_open(a->acc ? a->acc : &none, j->arg, err)) < 0 ||
                   pi_infer_fd(ctx, fd, j->arg, &r, err) < 0) {
            record(a, 0, 0);
            error_json(out, "file", j->arg, err);
        } else {
            record(a, 1, r.total_ms);
            result_json(out, "file", j->arg, &r, 1);
        }
        break;
    case JOB_FRAME:
        sb_printf(out, "{\"bytes\": %zu, ", j->len);
        if (!j->img) {
            sb_puts(out, "\"error\": \"frame: busy, too many image bytes on their way at once; try "
                         "again\"}");
        } else if (!ctx) {
            sb_puts(out, "\"error\": \"no model loaded\"}");
        } else if (pi_infer_memory(ctx, j->img, j->len, &r, err) < 0) {
            record(a, 0, 0);
            sb_puts(out, "\"error\": ");
            sb_json_str(out, err);
            sb_puts(out, "}");
        } else {
            record(a, 1, r.total_ms);
            result_after(out, &r);
        }
        break;
    case JOB_GRAB:
        pthread_mutex_lock(&a->cam_lock); /* the frame belongs to the camera until the next grab */
        if (!ctx) {
            error_json(out, "camera", a->cfg->camera, "no model loaded");
        } else if (pi_infer_camera(ctx, a->cam, &r, err) < 0) {
            record(a, 0, 0);
            error_json(out, "camera", a->cfg->camera, err);
        } else {
            record(a, 1, r.total_ms);
            result_json(out, "camera", a->cfg->camera, &r, 1);
        }
        pthread_mutex_unlock(&a->cam_lock);
        break;
    case JOB_RELOAD:
        if (app_reload(a, err) < 0) {
            j->failed = 1;
            if (!j->arg) j->arg = strdup(err); /* for the log line of a SIGHUP */
            error_json(out, NULL, NULL, err);
        } else {
            sb_puts(out, "{\"reloaded\": true}");
        }
        break;
    }
    sb_puts(out, "\n");
}

/* Hand work to a worker (p->job), or, without a peer (tests), do it now. */
static int to_worker(app *a, peer *p, job *j, sbuf *out)
{
    if (!j) {
        error_json(out, NULL, NULL, "out of memory");
        sb_puts(out, "\n");
        return 0;
    }
    if (p) {
        p->job = j;
        return 3;
    }
    proto_run(a, a->ctx, j);
    sb_puts(out, j->out.buf ? j->out.buf : "");
    job_free(j);
    return 0;
}

int proto_handle(app *a, peer *p, const char *line, sbuf *out)
{
    static const peer nobody = {-1, 0, 0, NULL};
    char err[PI_ERR_LEN];
    const char *arg;
    size_t cmdlen;
    const peer *who = p ? p : &nobody;
    int have_model;

    pthread_mutex_lock(&a->lock);
    a->requests++;
    have_model = a->ctx != NULL;
    pthread_mutex_unlock(&a->lock);
    line = skip_space(line);
    cmdlen = strcspn(line, " \t");
    arg = skip_space(line + cmdlen);

#define IS(c) (cmdlen == strlen(c) && strncmp(line, c, cmdlen) == 0)
    /* A TCP client of a server with a token says it before anything else;
     * a wrong or missing token closes the connection. */
    if (a->acc && a->acc->token && who->uid < 0 && !who->authed && !IS("auth")) {
        error_json(out, NULL, NULL, "auth required: send \"auth TOKEN\" first");
        sb_puts(out, "\n");
        return 1;
    }
    if (cmdlen == 0) {
        error_json(out, NULL, NULL, "empty command; " COMMANDS);
    } else if (IS("ping")) {
        sb_puts(out, "{\"pong\": true}");
    } else if (IS("auth")) {
        if (!a->acc || !a->acc->token) {
            error_json(out, NULL, NULL, "auth: this server has no token (token_file)");
        } else if (!access_token_ok(a->acc, arg)) {
            error_json(out, NULL, NULL, "auth: wrong token");
            sb_puts(out, "\n");
            return 1;
        } else {
            if (p) p->authed = 1;
            sb_puts(out, "{\"auth\": true}");
        }
    } else if (IS("infer")) {
        job *j;
        if (!*arg) {
            error_json(out, NULL, NULL, "infer: expected a path");
        } else if (!have_model) {
            error_json(out, "file", arg, "no model loaded");
        } else {
            j = job_new(JOB_INFER);
            if (j && !(j->arg = strdup(arg))) {
                job_free(j);
                j = NULL;
            }
            return to_worker(a, p, j, out);
        }
    } else if (IS("frame")) {
        char *end;
        unsigned long long n;
        errno = 0;
        n = strtoull(arg, &end, 10);
        if (!*arg || *arg == '-' || errno || *skip_space(end) != '\0') {
            error_json(out, NULL, NULL,
                       "frame: expected \"frame N\" and then N bytes of an encoded image");
            sb_puts(out, "\n");
            return 1; /* the bytes that follow cannot be told from commands */
        }
        if (n == 0 || n > (unsigned long long)pi_max_file_bytes) {
            sb_printf(out,
                      "{\"bytes\": %llu, \"error\": \"frame: %llu bytes, outside 1..%ld "
                      "(max_file_bytes)\"}\n",
                      n, n, pi_max_file_bytes);
            return 1;
        }
        if (p) p->want = (size_t)n;
        return p ? 2 : 1;
    } else if (IS("grab")) {
        if (!a->cam)
            error_json(out, NULL, NULL, "grab: no camera (start with --camera SPEC)");
        else if (!have_model)
            error_json(out, NULL, NULL, "no model loaded");
        else
            return to_worker(a, p, job_new(JOB_GRAB), out);
    } else if (IS("stats")) {
        pthread_mutex_lock(&a->lock);
        sb_puts(out, "{\"model\": ");
        sb_json_str(out, a->cfg->model);
        sb_printf(out,
                  ", \"uptime_s\": %.1f, \"requests\": %lu, \"frames\": %lu, \"errors\": %lu, "
                  "\"reloads\": %lu, \"clients\": %d, \"workers\": %d, \"busy_refusals\": %lu, "
                  "\"idle_closed\": %lu, \"ms_p50\": ",
                  (pi_now_ms() - a->started_ms) / 1000.0, a->requests, a->frames, a->errors,
                  a->reloads, a->clients, a->workers, a->busy_refusals, a->idle_closed);
        sb_json_num(out, app_percentile(a, 50), 3);
        sb_puts(out, ", \"ms_p99\": ");
        sb_json_num(out, app_percentile(a, 99), 3);
        sb_puts(out, "}");
        pthread_mutex_unlock(&a->lock);
    } else if (IS("reload")) {
        /* Loading a model stalls the daemon; only its own user (or root)
         * may ask, over the unix: socket; others have SIGHUP. */
        if (who->uid < 0 || (who->uid != (long)geteuid() && who->uid != 0)) {
            pi_seterr(err,
                      "reload: only the daemon's user (uid %ld) may reload, over the unix: "
                      "socket, or with SIGHUP (systemctl reload poseinfer)",
                      (long)geteuid());
            error_json(out, NULL, NULL, err);
        } else {
            return to_worker(a, p, job_new(JOB_RELOAD), out);
        }
    } else if (IS("quit")) {
        sb_puts(out, "{\"bye\": true}\n");
        return 1;
    } else {
        char msg[160];
        snprintf(msg, sizeof msg, "unknown command \"%.*s\"; " COMMANDS,
                 (int)(cmdlen > 40 ? 40 : cmdlen), line);
        error_json(out, NULL, NULL, msg);
    }
#undef IS
    sb_puts(out, "\n");
    return 0;
}

/* ---- sockets -------------------------------------------------------------------- */

/* The gid of a group given by name or number; -1 with err. */
static long group_id(const char *g, char *err)
{
    char buf[4096], *end;
    struct group gr, *res = NULL;
    long n;
    errno = 0;
    n = strtol(g, &end, 10);
    if (*g && !*end && !errno && n >= 0) return n;
    if (getgrnam_r(g, &gr, buf, sizeof buf, &res) != 0 || !res) {
        pi_seterr(err, "socket_group: no group \"%.64s\"", g);
        return -1;
    }
    return (long)res->gr_gid;
}

int server_listen(const char *spec, const listen_opts *o, char *err)
{
    static const listen_opts defaults = {0660, NULL, 0, 0};
    int fd = -1, one = 1;
    if (!o) o = &defaults;
    if (strncmp(spec, "unix:", 5) == 0) {
        const char *path = spec + 5;
        struct sockaddr_un sa;
        struct stat st;
        if (!*path || strlen(path) >= sizeof sa.sun_path) {
            pi_seterr(err, "listen(%s): empty or too long path", spec);
            return -1;
        }
        memset(&sa, 0, sizeof sa);
        sa.sun_family = AF_UNIX;
        memcpy(sa.sun_path, path, strlen(path) + 1);
        fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
        if (fd < 0) {
            pi_seterr(err, "socket: %s", strerror(errno));
            return -1;
        }
        /* A socket file left by a daemon that died: remove it, but never
         * steal the address of one that still answers. */
        if (lstat(path, &st) == 0 && S_ISSOCK(st.st_mode)) {
            int probe = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
            int live = probe >= 0 && connect(probe, (struct sockaddr *)&sa, sizeof sa) == 0;
            if (probe >= 0) close(probe);
            if (live) {
                pi_seterr(err, "listen(%s): another server is listening there", spec);
                goto fail;
            }
            unlink(path);
        }
        {
            /* Created 0600 whatever the caller's umask, then opened up to
             * the configured mode, so that it is never wider for a moment. */
            long gid = o->group ? group_id(o->group, err) : -1;
            mode_t old;
            int rc;
            if (o->group && gid < 0) goto fail;
            old = umask(0177);
            rc = bind(fd, (struct sockaddr *)&sa, sizeof sa);
            umask(old);
            if (rc < 0) {
                pi_seterr(err, "bind(%s): %s", spec, strerror(errno));
                goto fail;
            }
            if (gid >= 0 && chown(path, (uid_t)-1, (gid_t)gid) < 0) {
                pi_seterr(err, "listen(%s): socket_group %s: %s", spec, o->group, strerror(errno));
                unlink(path);
                goto fail;
            }
            if (chmod(path, (mode_t)o->mode) < 0) {
                pi_seterr(err, "listen(%s): socket_mode %04o: %s", spec, (unsigned)o->mode,
                          strerror(errno));
                unlink(path);
                goto fail;
            }
        }
    } else if (strncmp(spec, "tcp:", 4) == 0) {
        char host[64];
        const char *colon = strrchr(spec + 4, ':');
        struct sockaddr_in sa;
        char *end;
        long port;
        if (!colon || (size_t)(colon - (spec + 4)) >= sizeof host) {
            pi_seterr(err, "listen(%s): expected tcp:HOST:PORT", spec);
            return -1;
        }
        memcpy(host, spec + 4, (size_t)(colon - (spec + 4)));
        host[colon - (spec + 4)] = '\0';
        port = strtol(colon + 1, &end, 10);
        memset(&sa, 0, sizeof sa);
        sa.sin_family = AF_INET;
        if (*end || end == colon + 1 || port < 0 || port > 65535 ||
            inet_pton(AF_INET, host, &sa.sin_addr) != 1) {
            pi_seterr(err, "listen(%s): expected tcp:IPV4:PORT, e.g. tcp:127.0.0.1:7070", spec);
            return -1;
        }
        sa.sin_port = htons((unsigned short)port);
        /* TCP has no file permissions and no peer uid: loopback only,
         * unless the config says otherwise, and then only with a token. */
        if ((ntohl(sa.sin_addr.s_addr) >> 24) != 127) {
            if (!o->tcp_remote) {
                pi_seterr(err,
                          "listen(%s): not a loopback address; to serve other machines set "
                          "tcp_remote = yes "
                          "and token_file in the config",
                          spec);
                return -1;
            }
            if (!o->has_token) {
                pi_seterr(
                    err,
                    "listen(%s): tcp_remote needs token_file (clients then send \"auth TOKEN\")",
                    spec);
                return -1;
            }
        }
        fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
        if (fd < 0) {
            pi_seterr(err, "socket: %s", strerror(errno));
            return -1;
        }
        setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        if (bind(fd, (struct sockaddr *)&sa, sizeof sa) < 0) {
            pi_seterr(err, "bind(%s): %s", spec, strerror(errno));
            goto fail;
        }
    } else {
        pi_seterr(err, "listen(%s): expected unix:PATH or tcp:HOST:PORT", spec);
        return -1;
    }
    if (listen(fd, 16) < 0) {
        pi_seterr(err, "listen(%s): %s", spec, strerror(errno));
        goto fail;
    }
    return fd;
fail:
    close(fd);
    return -1;
}

typedef struct client {
    int fd;
    unsigned long serial; /* which connection holds this slot */
    peer who;
    char in[MAX_LINE];
    size_t inlen;
    unsigned char *img; /* "frame N": the image coming in (NULL: over budget, discarded) */
    size_t imglen;
    size_t reserved; /* image bytes counted against the server's budget */
    sbuf out;
    size_t outoff;
    int closing; /* close once the replies are out */
    int eof;     /* the client sends no more */
    int busy;    /* a job of its is with the workers */
    double last; /* ms: connected, or its last request came or was answered */
} client;

typedef struct server {
    app *a;
    pool *pool;
    client *cl;
    int max;     /* max_clients */
    int idle_ms; /* idle_timeout_ms */
    unsigned long serial;
    size_t img_bytes; /* image bytes received or waiting for a worker */
    size_t img_budget;
} server;

static void client_close(server *s, client *c)
{
    close(c->fd);
    sb_free(&c->out);
    free(c->img);
    c->img = NULL;
    s->img_bytes -= c->reserved;
    c->reserved = 0;
    c->fd = -1;
    pthread_mutex_lock(&s->a->lock);
    s->a->clients--;
    pthread_mutex_unlock(&s->a->lock);
}

/* Write what can be written now; -1 when the client is gone. */
static int client_flush(client *c)
{
    while (c->outoff < c->out.len) {
        ssize_t w = send(c->fd, c->out.buf + c->outoff, c->out.len - c->outoff, MSG_NOSIGNAL);
        if (w < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) return 0;
        if (w < 0 && errno == EINTR) continue;
        if (w < 0) return -1;
        c->outoff += (size_t)w;
    }
    sb_reset(&c->out);
    c->outoff = 0;
    return 0;
}

static void submit(server *s, client *c, job *j)
{
    j->client = (int)(c - s->cl);
    j->serial = c->serial;
    c->busy = 1;
    pool_submit(s->pool, j);
}

/* All N bytes of a "frame N" image are in: a job for a worker. */
static void image_complete(server *s, client *c)
{
    job *j = calloc(1, sizeof *j);
    if (!j) {
        error_json(&c->out, NULL, NULL, "frame: out of memory");
        sb_puts(&c->out, "\n");
        c->closing = 1;
        return;
    }
    j->kind = JOB_FRAME;
    j->img = c->img; /* NULL when discarded: the worker answers "busy" */
    j->len = c->who.want;
    sb_init(&j->out);
    c->img = NULL;
    c->imglen = 0;
    c->who.want = 0;
    submit(s, c, j);
}

/* A "frame N" line: room for the image, or (over the budget of image bytes
 * in flight) read and drop it, then answer "busy". */
static void image_start(server *s, client *c)
{
    size_t n = c->who.want;
    c->imglen = 0;
    c->img = NULL;
    if (s->img_bytes + n <= s->img_budget && (c->img = malloc(n))) {
        c->reserved = n;
        s->img_bytes += n;
    }
}

/* Image bytes: kept (or dropped when discarded). */
static void image_bytes(server *s, client *c, const char *data, size_t n)
{
    if (c->img && n) memcpy(c->img + c->imglen, data, n);
    c->imglen += n;
    if (c->imglen == c->who.want) image_complete(s, c);
}

/* Answer the complete lines in c->in, one request at a time: stops while a
 * job of the client is with the workers (answers stay in order). */
static void client_lines(server *s, client *c)
{
    while (!c->busy && !c->closing) {
        char *nl;
        size_t n;
        int rc;
        if (c->who.want) { /* buffered bytes are the image's first */
            size_t take = c->who.want - c->imglen;
            if (take > c->inlen) take = c->inlen;
            if (take == 0) return;
            image_bytes(s, c, c->in, take);
            memmove(c->in, c->in + take, c->inlen - take);
            c->inlen -= take;
            continue;
        }
        nl = memchr(c->in, '\n', c->inlen);
        if (!nl) return;
        *nl = '\0';
        n = (size_t)(nl - c->in) + 1;
        if (nl > c->in && nl[-1] == '\r') nl[-1] = '\0';
        c->last = pi_now_ms();
        if (memchr(c->in, '\0', n - 1)) {
            /* a C string would end there: "infer /a\0junk" must not open /a */
            error_json(&c->out, NULL, NULL, "request contains a NUL byte");
            sb_puts(&c->out, "\n");
            rc = 0;
        } else {
            rc = proto_handle(s->a, &c->who, c->in, &c->out);
        }
        memmove(c->in, c->in + n, c->inlen - n);
        c->inlen -= n;
        if (rc == 1)
            c->closing = 1;
        else if (rc == 2)
            image_start(s, c);
        else if (rc == 3) {
            job *j = c->who.job;
            c->who.job = NULL;
            submit(s, c, j);
        }
    }
}

/* Read what is there and answer complete lines; -1 when the client is to be
 * dropped. Reads nothing while a job of the client is with the workers. */
static int client_read(server *s, client *c)
{
    while (!c->busy && !c->closing && !c->eof) {
        ssize_t r;
        if (c->who.want && c->inlen == 0) { /* straight into the image */
            char scratch[16384];
            size_t room = c->who.want - c->imglen;
            if (c->img)
                r = recv(c->fd, c->img + c->imglen, room, 0);
            else
                r = recv(c->fd, scratch, room < sizeof scratch ? room : sizeof scratch, 0);
            if (r > 0) {
                c->imglen += (size_t)r;
                if (c->imglen == c->who.want) image_complete(s, c);
                client_lines(s, c);
            }
        } else {
            r = recv(c->fd, c->in + c->inlen, sizeof c->in - c->inlen, 0);
            if (r > 0) {
                c->inlen += (size_t)r;
                client_lines(s, c);
            }
        }
        if (r == 0) {
            c->eof = 1;
            break;
        }
        if (r < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) break;
        if (r < 0 && errno == EINTR) continue;
        if (r < 0) return -1;
        if (c->inlen == sizeof c->in && !c->who.want && !c->busy) {
            error_json(&c->out, NULL, NULL, "line too long");
            sb_puts(&c->out, "\n");
            c->closing = 1;
        }
        if (c->out.len > MAX_OUT || c->out.oom) return -1; /* a client that never reads */
    }
    return 0;
}

/* Flush, and close when it is over: told to close, or the client sent no
 * more and everything it asked is answered. */
static void client_settle(server *s, client *c)
{
    if (client_flush(c) < 0) {
        client_close(s, c);
        return;
    }
    if (c->busy || c->out.len) return;
    if (c->closing || (c->eof && !c->who.want)) client_close(s, c);
}

/* Sleep up to ms, waking early on a signal. */
static void nap(int ms)
{
    struct pollfd p = {sig_pipe[0], POLLIN, 0};
    if (ms <= 0 || got_stop) return;
    if (poll(&p, 1, ms) > 0) drain_sig_pipe();
}

/* A new connection; over max_clients it gets an error line, not silence. */
static void accept_one(server *s, int lfd, int unix_sock)
{
    int fd = accept4(lfd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
    if (fd < 0) {
        /* Out of descriptors: the pending connection stays and poll would
         * report it at once; do not spin on it. */
        if (errno == EMFILE || errno == ENFILE) {
            log_msg("accept: %s", strerror(errno));
            nap(100);
        }
        return;
    }
    for (int i = 0; i < s->max; i++) {
        client *c = &s->cl[i];
        if (c->fd >= 0) continue;
        memset(c, 0, sizeof *c);
        c->fd = fd;
        c->serial = ++s->serial;
        c->who.uid = unix_sock ? access_peer_uid(fd) : -1;
        c->last = pi_now_ms();
        sb_init(&c->out);
        pthread_mutex_lock(&s->a->lock);
        s->a->clients++;
        pthread_mutex_unlock(&s->a->lock);
        return;
    }
    {
        char msg[160];
        int n = snprintf(msg, sizeof msg,
                         "{\"error\": \"busy: %d clients connected, the limit (max_clients); "
                         "try again later\"}\n",
                         s->max);
        ssize_t w = send(fd, msg, (size_t)n, MSG_NOSIGNAL | MSG_DONTWAIT); /* best effort */
        (void)w;
        close(fd);
        pthread_mutex_lock(&s->a->lock);
        s->a->busy_refusals++;
        pthread_mutex_unlock(&s->a->lock);
    }
}

/* Replies of finished jobs go to their clients (if still connected), whose
 * next buffered requests then go on. */
static void jobs_done(server *s)
{
    job *j = pool_done(s->pool), *next;
    for (; j; j = next) {
        next = j->next;
        if (j->client < 0) { /* SIGHUP */
            if (j->failed)
                log_msg("SIGHUP: reload failed, keeping the old model: %s", j->arg ? j->arg : "");
            else
                log_msg("SIGHUP: reloaded %s", s->a->cfg->model);
        } else {
            client *c = &s->cl[j->client];
            if (c->fd >= 0 && c->serial == j->serial) {
                sb_puts(&c->out, j->out.buf ? j->out.buf : "{\"error\": \"out of memory\"}\n");
                c->busy = 0;
                c->last = pi_now_ms();
                s->img_bytes -= c->reserved;
                c->reserved = 0;
                client_lines(s, c);
                client_settle(s, c);
            }
        }
        job_free(j);
    }
}

/* Close clients idle for idle_ms (no request, or one that never completes:
 * a line or an image sent a byte at a time counts as idle). */
static int close_idle(server *s, double now)
{
    int wait = -1;
    for (int i = 0; i < s->max; i++) {
        client *c = &s->cl[i];
        double left;
        if (c->fd < 0 || c->busy) continue;
        left = c->last + s->idle_ms - now;
        if (left <= 0) {
            sb_printf(&c->out, "{\"error\": \"idle for %d ms (idle_timeout_ms); closing\"}\n",
                      s->idle_ms);
            client_flush(c);
            client_close(s, c);
            pthread_mutex_lock(&s->a->lock);
            s->a->idle_closed++;
            pthread_mutex_unlock(&s->a->lock);
            continue;
        }
        if (wait < 0 || left + 1 < wait) wait = (int)left + 1;
    }
    return wait;
}

static void server_free(server *s, const char *spec)
{
    pool_stop(s->pool); /* the workers finish the frames they are on */
    s->pool = NULL;
    for (int i = 0; s->cl && i < s->max; i++)
        if (s->cl[i].fd >= 0) client_close(s, &s->cl[i]);
    free(s->cl);
    if (strncmp(spec, "unix:", 5) == 0) unlink(spec + 5);
}

int server_run(app *a, int lfd, const char *spec, char *err)
{
    server s;
    struct pollfd *pfd;
    int *idx;
    const int unix_sock = strncmp(spec, "unix:", 5) == 0;
    int rc = 0;

    memset(&s, 0, sizeof s);
    s.a = a;
    s.max = a->cfg->max_clients > 0 ? a->cfg->max_clients : 64;
    s.idle_ms = a->cfg->idle_timeout_ms > 0 ? a->cfg->idle_timeout_ms : 60000;
    s.img_budget = (size_t)pi_max_file_bytes * 4;
    a->workers = a->cfg->workers > 0 ? a->cfg->workers : 1;
    /* Large buffers straight from mmap, so that freeing one gives it back
     * (glibc's default threshold grows after the first large free, and the
     * heap then keeps such a frame's memory). */
    mallopt(M_MMAP_THRESHOLD, 4 * 1024 * 1024);
    s.cl = calloc((size_t)s.max, sizeof *s.cl);
    pfd = calloc((size_t)s.max + 3, sizeof *pfd);
    idx = calloc((size_t)s.max + 3, sizeof *idx);
    if (!s.cl || !pfd || !idx) {
        pi_seterr(err, "server: out of memory");
        free(pfd);
        free(idx);
        free(s.cl);
        return -1;
    }
    for (int i = 0; i < s.max; i++) s.cl[i].fd = -1;
    s.pool = pool_start(a, a->workers, err);
    if (!s.pool) {
        free(pfd);
        free(idx);
        free(s.cl);
        return -1;
    }

    while (!got_stop) {
        int n = 0, r, wait;
        wait = close_idle(&s, pi_now_ms());
        pfd[n].fd = sig_pipe[0];
        pfd[n].events = POLLIN;
        idx[n++] = -1;
        pfd[n].fd = lfd;
        pfd[n].events = POLLIN;
        idx[n++] = -2;
        pfd[n].fd = pool_fd(s.pool);
        pfd[n].events = POLLIN;
        idx[n++] = -3;
        for (int i = 0; i < s.max; i++) {
            client *c = &s.cl[i];
            if (c->fd < 0) continue;
            pfd[n].fd = c->fd;
            pfd[n].events = (short)((!c->busy && !c->closing && !c->eof ? POLLIN : 0) |
                                    (c->out.len > c->outoff ? POLLOUT : 0));
            idx[n++] = i;
        }
        r = poll(pfd, (nfds_t)n, wait); /* no client: no timeout, idle means asleep */
        if (r < 0 && errno == EINTR) continue;
        if (r < 0) {
            pi_seterr(err, "poll: %s", strerror(errno));
            rc = -1;
            break;
        }
        for (int k = 0; k < n; k++) {
            if (!pfd[k].revents) continue;
            if (idx[k] == -1) {
                drain_sig_pipe();
            } else if (idx[k] == -2) {
                for (int m = 0; m < 16; m++) accept_one(&s, lfd, unix_sock);
            } else if (idx[k] == -3) {
                jobs_done(&s);
            } else {
                client *c = &s.cl[idx[k]];
                if (c->fd < 0) continue;
                if (pfd[k].revents & (POLLHUP | POLLERR)) { /* gone: no one to answer */
                    client_close(&s, c);
                    continue;
                }
                if ((pfd[k].revents & POLLIN) && client_read(&s, c) < 0) {
                    client_close(&s, c);
                    continue;
                }
                client_settle(&s, c);
            }
        }
        if (got_hup) {
            job *j = calloc(1, sizeof *j);
            got_hup = 0;
            if (j) {
                j->kind = JOB_RELOAD;
                j->client = -1;
                sb_init(&j->out);
                pool_submit(s.pool, j);
            }
        }
    }
    log_msg("stopping");
    server_free(&s, spec);
    free(pfd);
    free(idx);
    return rc;
}

/* --save-frames: grab frame n, write it as DIR/frame_NNNNNN.png (saved: that
 * path, which fits: main.c bounds DIR's length; empty, and the reason logged,
 * when it cannot be written: the pose is still measured), and infer on it. 1
 * when a pose came back, 0 with e. */
static int grab_and_save(app *a, unsigned long n, char *saved, size_t len, pi_result *r, char *e)
{
    pi_frame f;
    char se[PI_ERR_LEN];
    memset(r, 0, sizeof *r);
    if (pi_camera_grab(a->cam, &f, e) < 0) return 0;
    snprintf(saved, len, "%s/frame_%06lu.png", a->cfg->save_frames, n);
    if (pi_frame_save(&f, saved, se) < 0) {
        log_msg("frame %lu: not saved: %s", n, se);
        saved[0] = '\0';
    }
    return pi_infer_frame(a->ctx, &f, r, e) == 0;
}

int continuous_run(app *a, char *err)
{
    sbuf s;
    char saved[PATH_MAX + 32];
    unsigned long n = 0;
    sb_init(&s);
    while (!got_stop && (a->cfg->count == 0 || n < (unsigned long)a->cfg->count)) {
        pi_result r;
        char e[PI_ERR_LEN];
        struct timespec ts;
        int ok;
        if (got_hup) {
            got_hup = 0;
            if (app_reload(a, e) < 0)
                log_msg("SIGHUP: reload failed, keeping the old model: %s", e);
            else
                log_msg("SIGHUP: reloaded %s", a->cfg->model);
        }
        saved[0] = '\0';
        if (a->cfg->save_frames)
            ok = grab_and_save(a, n, saved, sizeof saved, &r, e);
        else
            ok = pi_infer_camera(a->ctx, a->cam, &r, e) == 0;
        if (got_stop) break;
        clock_gettime(CLOCK_REALTIME, &ts);
        sb_reset(&s);
        sb_printf(&s, "{\"frame\": %lu, \"time\": %.3f, ", n, ts.tv_sec + ts.tv_nsec / 1e9);
        if (saved[0]) {
            sb_puts(&s, "\"saved\": ");
            sb_json_str(&s, saved);
            sb_puts(&s, ", ");
        }
        if (ok) {
            /* splice the result object's members after ours */
            sbuf t;
            sb_init(&t);
            result_json(&t, NULL, NULL, &r, a->cfg->timings);
            sb_puts(&s, t.buf ? t.buf + 1 : "}");
            sb_free(&t);
        } else {
            sb_puts(&s, "\"error\": ");
            sb_json_str(&s, e);
            sb_puts(&s, "}");
        }
        record(a, ok, ok ? r.total_ms : 0);
        if (s.buf) {
            fputs(s.buf, stdout);
            fputc('\n', stdout);
            fflush(stdout);
        }
        n++;
        /* After an error, never spin: wait at least 100 ms. */
        nap(ok ? a->cfg->interval_ms : (a->cfg->interval_ms > 100 ? a->cfg->interval_ms : 100));
    }
    sb_free(&s);
    (void)err;
    return 0;
}
