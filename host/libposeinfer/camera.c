/* camera.c -- frame sources: OpenCV VideoCapture (V4L2, GStreamer) through
 * the shim, and the `unix:` frame-server client (docs/interfaces.md):
 * send "grab\n", read "FRAME <n>\n" + n bytes of PNG, or "ERROR <msg>\n". */
#define _POSIX_C_SOURCE 200809L
#include "poseinfer.h"

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include "internal.h"
#include "shim.h"

#define CAM_DEFAULT_TIMEOUT_MS 5000
#define CAM_MAX_FRAME_BYTES    (256L * 1024 * 1024)
#define CAM_MAX_HEADER         512

struct pi_camera {
    char *spec;
    int timeout_ms;
    /* unix: */
    char *path;
    int fd;
    unsigned char *buf;
    size_t cap;
    shim_mat *mat;
    /* VideoCapture */
    shim_cap *cap_cv;
};

static int unix_connect(pi_camera *cam, char *err)
{
    struct sockaddr_un sa;
    int fd;
    if (strlen(cam->path) >= sizeof sa.sun_path) {
        pi_seterr(err, "connect(%s): path too long", cam->path);
        return -1;
    }
    memset(&sa, 0, sizeof sa);
    sa.sun_family = AF_UNIX;
    memcpy(sa.sun_path, cam->path, strlen(cam->path) + 1);
    fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) {
        pi_seterr(err, "socket: %s", strerror(errno));
        return -1;
    }
    /* Connecting to a Unix socket does not block for long (it fails at once
     * with ECONNREFUSED or EAGAIN when the backlog is full). */
    if (connect(fd, (struct sockaddr *)&sa, sizeof sa) < 0) {
        pi_seterr(err, "connect(%s): %s", cam->path, strerror(errno));
        close(fd);
        return -1;
    }
    fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
    cam->fd = fd;
    return 0;
}

static void unix_disconnect(pi_camera *cam)
{
    if (cam->fd >= 0) close(cam->fd);
    cam->fd = -1;
}

/* Wait for fd to be ready for `events` until deadline (ms, monotonic). */
static int wait_fd(pi_camera *cam, short events, double deadline, char *err)
{
    for (;;) {
        double left = deadline - pi_now_ms();
        struct pollfd pfd = {cam->fd, events, 0};
        int r;
        if (left <= 0) {
            pi_seterr(err, "frame server %s: timed out after %d ms", cam->path, cam->timeout_ms);
            return -1;
        }
        r = poll(&pfd, 1, (int)left + 1);
        if (r < 0 && errno == EINTR) {
            pi_seterr(err, "frame server %s: interrupted", cam->path);
            return -1;
        }
        if (r < 0) {
            pi_seterr(err, "poll(%s): %s", cam->path, strerror(errno));
            return -1;
        }
        if (r > 0) return 0;
    }
}

static int send_all(pi_camera *cam, const char *s, size_t n, double deadline, char *err)
{
    while (n > 0) {
        ssize_t w = send(cam->fd, s, n, MSG_NOSIGNAL);
        if (w < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
            if (wait_fd(cam, POLLOUT, deadline, err) < 0) return -1;
            continue;
        }
        if (w < 0 && errno == EINTR) continue;
        if (w < 0) {
            pi_seterr(err, "send(%s): %s", cam->path, strerror(errno));
            return -1;
        }
        s += w;
        n -= (size_t)w;
    }
    return 0;
}

/* Read exactly n bytes (n > 0) into dst. */
static int recv_exact(pi_camera *cam, unsigned char *dst, size_t n, double deadline, char *err)
{
    size_t got = 0;
    while (got < n) {
        ssize_t r = recv(cam->fd, dst + got, n - got, 0);
        if (r < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
            if (wait_fd(cam, POLLIN, deadline, err) < 0) return -1;
            continue;
        }
        if (r < 0 && errno == EINTR) continue;
        if (r < 0) {
            pi_seterr(err, "recv(%s): %s", cam->path, strerror(errno));
            return -1;
        }
        if (r == 0) {
            pi_seterr(err, "frame server %s: connection closed after %zu of %zu bytes", cam->path,
                      got, n);
            return -1;
        }
        got += (size_t)r;
    }
    return 0;
}

/* Read the reply line byte by byte: it is short, and the image that follows
 * must stay in the socket for recv_exact. */
static int recv_line(pi_camera *cam, char *line, size_t max, double deadline, char *err)
{
    size_t n = 0;
    for (;;) {
        unsigned char c;
        if (recv_exact(cam, &c, 1, deadline, err) < 0) return -1;
        if (c == '\n') break;
        if (n + 1 >= max) {
            pi_seterr(err, "frame server %s: reply line too long", cam->path);
            return -1;
        }
        line[n++] = (char)c;
    }
    if (n > 0 && line[n - 1] == '\r') n--;
    line[n] = '\0';
    return 0;
}

static int unix_grab(pi_camera *cam, pi_frame *frame, char *err)
{
    char line[CAM_MAX_HEADER];
    double deadline = pi_now_ms() + cam->timeout_ms;
    long n;
    char *end;
    double t0;

    if (cam->fd < 0 && unix_connect(cam, err) < 0) return -1;
    if (send_all(cam, "grab\n", 5, deadline, err) < 0) goto fail;
    if (recv_line(cam, line, sizeof line, deadline, err) < 0) goto fail;
    if (strncmp(line, "ERROR", 5) == 0) {
        const char *msg = line + 5;
        while (*msg == ' ') msg++;
        pi_seterr(err, "frame server %s: %s", cam->path, *msg ? msg : "error");
        /* The connection stays usable: the server answered in protocol. */
        return -1;
    }
    if (strncmp(line, "FRAME ", 6) != 0) {
        pi_seterr(err, "frame server %s: unexpected reply \"%.64s\"", cam->path, line);
        goto fail;
    }
    errno = 0;
    n = strtol(line + 6, &end, 10);
    if (errno || end == line + 6 || *end != '\0' || n <= 0 || n > CAM_MAX_FRAME_BYTES) {
        pi_seterr(err, "frame server %s: bad frame size in \"%.64s\"", cam->path, line);
        goto fail;
    }
    if ((size_t)n > cam->cap) {
        unsigned char *nb = realloc(cam->buf, (size_t)n);
        if (!nb) {
            pi_seterr(err, "frame server %s: out of memory for %ld bytes", cam->path, n);
            goto fail;
        }
        cam->buf = nb;
        cam->cap = (size_t)n;
    }
    if (recv_exact(cam, cam->buf, (size_t)n, deadline, err) < 0) goto fail;
    t0 = pi_now_ms();
    if (shim_decode(cam->mat, cam->buf, (size_t)n, PI_DEFAULT_MAX_PIXELS, frame, err) < 0)
        return -1;
    frame->decode_ms = pi_now_ms() - t0;
    return 0;
fail:
    /* Out of step with the server: start afresh on the next grab. */
    unix_disconnect(cam);
    return -1;
}

pi_camera *pi_camera_open(const char *spec, int timeout_ms, char *err)
{
    pi_camera *cam;
    if (!spec || !*spec) {
        pi_seterr(err, "pi_camera_open: empty camera spec");
        return NULL;
    }
    cam = calloc(1, sizeof *cam);
    if (!cam) {
        pi_seterr(err, "pi_camera_open: out of memory");
        return NULL;
    }
    cam->fd = -1;
    cam->timeout_ms = timeout_ms > 0 ? timeout_ms : CAM_DEFAULT_TIMEOUT_MS;
    cam->spec = strdup(spec);
    if (!cam->spec) {
        pi_seterr(err, "pi_camera_open: out of memory");
        goto fail;
    }
    if (strncmp(spec, "unix:", 5) == 0) {
        cam->path = strdup(spec + 5);
        cam->mat = shim_mat_new();
        if (!cam->path || !cam->mat) {
            pi_seterr(err, "pi_camera_open: out of memory");
            goto fail;
        }
        if (!cam->path[0]) {
            pi_seterr(err, "pi_camera_open(%s): empty socket path", spec);
            goto fail;
        }
        if (unix_connect(cam, err) < 0) goto fail;
    } else {
        cam->cap_cv = shim_cap_open(spec, err);
        if (!cam->cap_cv) goto fail;
    }
    return cam;
fail:
    pi_camera_close(cam);
    return NULL;
}

int pi_camera_grab(pi_camera *cam, pi_frame *frame, char *err)
{
    if (!cam || !frame) {
        pi_seterr(err, "pi_camera_grab: no camera");
        return -1;
    }
    memset(frame, 0, sizeof *frame);
    if (cam->path) return unix_grab(cam, frame, err);
    return shim_cap_grab(cam->cap_cv, frame, err);
}

int pi_infer_camera(pi_ctx *ctx, pi_camera *cam, pi_result *res, char *err)
{
    pi_frame f;
    pi_result tmp;
    if (!res) res = &tmp;
    memset(res, 0, sizeof *res);
    if (pi_camera_grab(cam, &f, err) < 0) return -1;
    return pi_infer_frame(ctx, &f, res, err);
}

void pi_camera_close(pi_camera *cam)
{
    if (!cam) return;
    unix_disconnect(cam);
    if (cam->cap_cv) shim_cap_close(cam->cap_cv);
    shim_mat_free(cam->mat);
    free(cam->buf);
    free(cam->path);
    free(cam->spec);
    free(cam);
}
