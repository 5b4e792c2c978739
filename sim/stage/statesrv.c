#define _GNU_SOURCE
/* statesrv.c: see statesrv.h. A client that sends an overlong line gets an
 * error line and is dropped; a client that does not read its answers is
 * dropped once its output buffer is full, so it can never stall the
 * simulation. */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include "statesrv.h"

static void client_drop(struct srv_client *c)
{
    if (c->fd >= 0) close(c->fd);
    c->fd = -1;
    c->in_len = c->out_len = 0;
}

int srv_open(struct statesrv *s, const char *path, srv_handler h, void *ctx, char *err)
{
    struct sockaddr_un sa;

    memset(s, 0, sizeof(*s));
    s->fd = -1;
    for (int i = 0; i < SRV_CLIENTS; i++) s->client[i].fd = -1;
    s->handler = h;
    s->ctx = ctx;
    if (strlen(path) >= sizeof(sa.sun_path)) {
        snprintf(err, ERR_LEN, "--state-socket %s: path too long (max %zu)", path,
                 sizeof(sa.sun_path) - 1);
        return -1;
    }
    memset(&sa, 0, sizeof(sa));
    sa.sun_family = AF_UNIX;
    strcpy(sa.sun_path, path);
    s->fd = socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (s->fd < 0) {
        snprintf(err, ERR_LEN, "socket: %s", strerror(errno));
        goto fail;
    }
    unlink(path); /* a stale socket from a killed run */
    if (bind(s->fd, (struct sockaddr *)&sa, sizeof(sa)) < 0) {
        snprintf(err, ERR_LEN, "bind(%s): %s", path, strerror(errno));
        goto fail;
    }
    if (listen(s->fd, 8) < 0) {
        snprintf(err, ERR_LEN, "listen(%s): %s", path, strerror(errno));
        unlink(path);
        goto fail;
    }
    strcpy(s->path, path);
    return 0;
fail:
    if (s->fd >= 0) close(s->fd);
    s->fd = -1;
    return -1;
}

int srv_pollfds(struct statesrv *s, struct pollfd *fds)
{
    int n = 0;

    if (s->fd < 0) return 0;
    fds[n].fd = s->fd;
    fds[n].events = POLLIN;
    n++;
    for (int i = 0; i < SRV_CLIENTS; i++) {
        struct srv_client *c = &s->client[i];
        if (c->fd < 0) continue;
        fds[n].fd = c->fd;
        fds[n].events = (short)(POLLIN | (c->out_len ? POLLOUT : 0));
        n++;
    }
    return n;
}

static void client_answer(struct statesrv *s, struct srv_client *c, const char *line)
{
    char buf[SRV_OUT];
    size_t n = s->handler(s->ctx, line, buf, sizeof(buf));

    if (n > sizeof(c->out) - c->out_len) {
        client_drop(c); /* not reading its answers */
        return;
    }
    memcpy(c->out + c->out_len, buf, n);
    c->out_len += n;
}

static void client_service(struct statesrv *s, struct srv_client *c)
{
    for (;;) {
        ssize_t n = read(c->fd, c->in + c->in_len, sizeof(c->in) - c->in_len);
        if (n == 0 || (n < 0 && errno != EAGAIN && errno != EINTR)) {
            client_drop(c);
            return;
        }
        if (n < 0) {
            if (errno == EINTR) continue;
            break;
        }
        c->in_len += (size_t)n;
        for (;;) {
            char *nl = memchr(c->in, '\n', c->in_len);
            if (!nl) break;
            *nl = 0;
            if (nl > c->in && nl[-1] == '\r') nl[-1] = 0;
            client_answer(s, c, c->in);
            if (c->fd < 0) return;
            size_t used = (size_t)(nl - c->in) + 1;
            memmove(c->in, c->in + used, c->in_len - used);
            c->in_len -= used;
        }
        if (c->in_len == sizeof(c->in)) {
            static const char msg[] = "{\"error\": \"request line too long\"}\n";
            (void)!write(c->fd, msg, sizeof(msg) - 1);
            client_drop(c);
            return;
        }
    }
    while (c->out_len) {
        ssize_t n = write(c->fd, c->out, c->out_len);
        if (n > 0) {
            memmove(c->out, c->out + n, c->out_len - (size_t)n);
            c->out_len -= (size_t)n;
            continue;
        }
        if (n < 0 && errno == EINTR) continue;
        if (n < 0 && errno != EAGAIN) client_drop(c);
        break;
    }
}

void srv_service(struct statesrv *s)
{
    if (s->fd < 0) return;
    for (;;) {
        int fd = accept4(s->fd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd < 0) break;
        int slot = -1;
        for (int i = 0; i < SRV_CLIENTS; i++)
            if (s->client[i].fd < 0) {
                slot = i;
                break;
            }
        if (slot < 0) {
            static const char msg[] = "{\"error\": \"too many clients\"}\n";
            (void)!write(fd, msg, sizeof(msg) - 1);
            close(fd);
            continue;
        }
        s->client[slot].fd = fd;
        s->client[slot].in_len = s->client[slot].out_len = 0;
    }
    for (int i = 0; i < SRV_CLIENTS; i++)
        if (s->client[i].fd >= 0) client_service(s, &s->client[i]);
}

void srv_close(struct statesrv *s)
{
    for (int i = 0; i < SRV_CLIENTS; i++)
        if (s->client[i].fd >= 0) client_drop(&s->client[i]);
    if (s->fd >= 0) {
        close(s->fd);
        unlink(s->path);
    }
    s->fd = -1;
}
