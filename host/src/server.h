/* server.h -- poseinfer's long-running modes: the line-protocol server
 * (unix:PATH or tcp:HOST:PORT) and continuous capture; the JSON lines that
 * all modes print. */
#ifndef PI_SERVER_H
#define PI_SERVER_H

#include "config.h"
#include "json.h"
#include "poseinfer.h"

#define LAT_WINDOW 1024

typedef struct app {
    pi_ctx *ctx;
    pi_camera *cam;
    const pi_config *cfg;
    double started_ms;
    unsigned long requests, frames, errors, reloads;
    int clients;
    double lat[LAT_WINDOW];     /* last frame times (ms), a ring */
    unsigned long nlat;
} app;

/* Append a result line for `name` (without newline): {"file": ..., "x":
 * ..., "y": ..., "z": ..., "ms": ...} (+ rotmat, + timings when asked). */
void result_json(sbuf *s, const char *key, const char *name, const pi_result *r, int timings);

/* Append {"<key>": name, "error": msg}; key NULL gives {"error": msg}. */
void error_json(sbuf *s, const char *key, const char *name, const char *msg);

/* Handle one protocol line (without the newline); append the reply line
 * (with newline) to out. Returns 1 when the client asked to close. */
int proto_handle(app *a, const char *line, sbuf *out);

/* Percentile (0..100) of the recorded frame times; NAN when none. */
double app_percentile(const app *a, double pct);

/* Open a listening socket for "unix:PATH" or "tcp:HOST:PORT". */
int server_listen(const char *spec, char *err);

/* Install SIGTERM/SIGINT (stop) and SIGHUP (reload) handlers that wake poll. */
int signals_install(char *err);

/* Reload the model named in the config (SIGHUP, `reload`); keeps the old
 * one when the new one fails. */
int app_reload(app *a, char *err);

/* Serve the line protocol until SIGTERM/SIGINT. Returns 0, or -1 with err. */
int server_run(app *a, int lfd, const char *spec, char *err);

/* Continuous capture: one JSON line per frame on stdout until SIGTERM or
 * SIGINT, or cfg->count frames. */
int continuous_run(app *a, char *err);

/* Log a line to stderr: "poseinfer: ...". */
void log_msg(const char *fmt, ...) __attribute__((format(printf, 1, 2)));

#endif
