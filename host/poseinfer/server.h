/* server.h -- poseinfer's long-running modes: the line-protocol server
 * (unix:PATH or tcp:HOST:PORT) and continuous capture; the JSON lines that
 * all modes print. */
#ifndef PI_SERVER_H
#define PI_SERVER_H

#include <pthread.h>

#include "access.h"
#include "config.h"
#include "json.h"
#include "poseinfer.h"

#define LAT_WINDOW 1024

/* Work that takes a frame's time (or a model load): done by a worker thread
 * (pool.h), its reply line then sent by the event loop. */
typedef enum { JOB_INFER, JOB_FRAME, JOB_GRAB, JOB_RELOAD } job_kind;

typedef struct job {
    struct job *next;
    job_kind kind;
    int client;           /* slot of the connection in the server; -1: none (SIGHUP) */
    unsigned long serial; /* that connection (a slot is reused) */
    char *arg;            /* JOB_INFER: the path; JOB_RELOAD: why it failed */
    unsigned char *img;   /* JOB_FRAME: the encoded image, len bytes */
    size_t len;
    sbuf out;   /* the reply line, with its newline */
    int failed; /* JOB_RELOAD: the load failed (reason in out) */
} job;

void job_free(job *j);

/* The client at the other end of one connection. */
typedef struct peer {
    long uid;    /* its uid (SO_PEERCRED) on unix:, -1 on tcp: */
    int authed;  /* sent the right "auth TOKEN" */
    size_t want; /* bytes of a "frame N" image still to come (proto_handle -> 2) */
    job *job;    /* the work of the last request (proto_handle -> 3) */
} peer;

typedef struct app {
    pi_ctx *ctx; /* the model; workers use clones of it (pi_clone) */
    pi_camera *cam;
    const pi_config *cfg;
    const access_policy *acc; /* NULL: nothing allowed (no files, no token) */
    double started_ms;
    unsigned long requests, frames, errors, reloads, busy_refusals, idle_closed;
    int clients, workers;
    double lat[LAT_WINDOW]; /* last frame times (ms), a ring */
    unsigned long nlat;
    unsigned long gen; /* bumped at each reload: workers re-clone */
    /* lock: ctx, gen and the counters (workers record frames); cam_lock: one
     * grab at a time; reload_lock: one model load at a time. Zeroed memory
     * is an unlocked mutex (glibc), so a zeroed app is ready. */
    pthread_mutex_t lock, cam_lock, reload_lock;
} app;

/* Append a result line for `name` (without newline): {"file": ..., "x":
 * ..., "y": ..., "z": ..., "ms": ...} (+ rotmat, + timings when asked). */
void result_json(sbuf *s, const char *key, const char *name, const pi_result *r, int timings);

/* Append {"<key>": name, "error": msg}; key NULL gives {"error": msg}. */
void error_json(sbuf *s, const char *key, const char *name, const char *msg);

/* Handle one protocol line (without the newline) from client p; append the
 * reply line (with newline) to out. Returns 0, or 1 when the connection is
 * to be closed after the reply, 2 when a "frame N" line asks for N bytes of
 * image (p->want; they make a JOB_FRAME), 3 when the request is work for a
 * worker (p->job, reply in p->job->out; p NULL: answered at once). */
int proto_handle(app *a, peer *p, const char *line, sbuf *out);

/* Do a job with the context ctx (a worker's clone): fills j->out. */
void proto_run(app *a, pi_ctx *ctx, job *j);

/* Percentile (0..100) of the recorded frame times; NAN when none. */
double app_percentile(const app *a, double pct);

/* How to listen: the unix: socket's mode and group, and whether a tcp:
 * address may be other than loopback (then only with a token). */
typedef struct listen_opts {
    int mode;          /* permissions of the socket file (0660) */
    const char *group; /* its group, a name or a number; NULL: the daemon's */
    int tcp_remote;    /* allow a non-loopback tcp: address */
    int has_token;     /* a token is configured (needed for tcp_remote) */
} listen_opts;

/* Open a listening socket for "unix:PATH" or "tcp:HOST:PORT"; o NULL: mode
 * 0660, loopback only. */
int server_listen(const char *spec, const listen_opts *o, char *err);

/* Install SIGTERM/SIGINT (stop) and SIGHUP (reload) handlers that wake poll. */
int signals_install(char *err);

/* Reload the model named in the config (SIGHUP, `reload`); keeps the old
 * one when the new one fails. */
int app_reload(app *a, char *err);

/* Serve the line protocol until SIGTERM/SIGINT: one event loop for the
 * sockets, cfg->workers threads for the frames. Returns 0, or -1 with err. */
int server_run(app *a, int lfd, const char *spec, char *err);

/* Continuous capture: one JSON line per frame on stdout until SIGTERM or
 * SIGINT, or cfg->count frames. */
int continuous_run(app *a, char *err);

/* Log a line to stderr: "poseinfer: ...". */
void log_msg(const char *fmt, ...) __attribute__((format(printf, 1, 2)));

#endif
