/* statesrv.h: the state socket, a Unix stream server answering one JSON line
 * per request line. Non-blocking, served from the simulation thread between
 * avr_run calls, so every answer is a consistent snapshot. */
#ifndef STATESRV_H
#define STATESRV_H

#include <poll.h>
#include <stddef.h>
#include "err.h" /* ERR_LEN: err[] buffers */

#define SRV_CLIENTS 16
#define SRV_LINE    256
#define SRV_OUT     8192

/* Answer one request line (no newline) into out; returns the length. */
typedef size_t (*srv_handler)(void *ctx, const char *request, char *out, size_t len);

struct srv_client {
    int fd;
    char in[SRV_LINE];
    size_t in_len;
    char out[SRV_OUT];
    size_t out_len;
};

struct statesrv {
    int fd; /* listening socket, -1 when not serving */
    char path[108];
    srv_handler handler;
    void *ctx;
    struct srv_client client[SRV_CLIENTS];
};

/* Bind and listen on path (an existing socket file there is replaced). */
int srv_open(struct statesrv *s, const char *path, srv_handler h, void *ctx, char *err);

/* Add our descriptors to a poll set; returns how many were added (max 1 + SRV_CLIENTS). */
int srv_pollfds(struct statesrv *s, struct pollfd *fds);

/* Accept, read requests, answer, write. Never blocks. Main loop. */
void srv_service(struct statesrv *s);

/* Close every connection and remove the socket file. */
void srv_close(struct statesrv *s);

#endif
