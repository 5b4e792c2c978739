/* access.c -- the daemon's access rules: allowed directories for `infer
 * PATH`, the TCP token, peer credentials. */
#define _GNU_SOURCE
#include "access.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <linux/openat2.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <unistd.h>

#include "internal.h"

#define MIN_TOKEN  16
#define OPEN_FLAGS (O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY)

char *access_read_token(const char *path, char *err)
{
    char buf[4097];
    struct stat sb;
    ssize_t n;
    size_t len;
    char *tok;
    int fd = open(path, OPEN_FLAGS);
    if (fd < 0) {
        pi_seterr(err, "token_file(%s): %s", path, strerror(errno));
        return NULL;
    }
    if (fstat(fd, &sb) < 0 || !S_ISREG(sb.st_mode)) {
        pi_seterr(err, "token_file(%s): not a regular file", path);
        close(fd);
        return NULL;
    }
    if (sb.st_mode & 0007) {
        pi_seterr(err, "token_file(%s): readable by every user (mode %04o); chmod 600 or 640 it",
                  path, (unsigned)(sb.st_mode & 07777));
        close(fd);
        return NULL;
    }
    n = read(fd, buf, sizeof buf - 1);
    close(fd);
    if (n < 0) {
        pi_seterr(err, "token_file(%s): %s", path, strerror(errno));
        return NULL;
    }
    buf[n] = '\0';
    len = strcspn(buf, "\r\n");
    buf[len] = '\0';
    for (size_t i = 0; i < len; i++) {
        if ((unsigned char)buf[i] <= ' ' || (unsigned char)buf[i] >= 0x7f) {
            pi_seterr(err, "token_file(%s): the token must be printable ASCII without spaces",
                      path);
            return NULL;
        }
    }
    if (len < MIN_TOKEN) {
        pi_seterr(err, "token_file(%s): the token on its first line must be at least %d characters",
                  path, MIN_TOKEN);
        return NULL;
    }
    tok = strdup(buf);
    if (!tok) pi_seterr(err, "token_file(%s): out of memory", path);
    explicit_bzero(buf, sizeof buf);
    return tok;
}

int access_init(access_policy *p, const pi_config *cfg, char *err)
{
    memset(p, 0, sizeof *p);
    if (cfg->n_allow_dirs > 0) {
        size_t n = (size_t)cfg->n_allow_dirs;
        p->given = calloc(n, sizeof *p->given);
        p->canon = calloc(n, sizeof *p->canon);
        p->fd = calloc(n, sizeof *p->fd);
        if (!p->given || !p->canon || !p->fd) {
            pi_seterr(err, "out of memory");
            goto fail;
        }
    }
    for (int i = 0; i < cfg->n_allow_dirs; i++) {
        const char *d = cfg->allow_dirs[i];
        struct stat sb;
        int fd = open(d, O_PATH | O_DIRECTORY | O_CLOEXEC);
        if (fd < 0 || fstat(fd, &sb) < 0) {
            pi_seterr(err, "allow_dir(%s): %s", d, strerror(errno));
            if (fd >= 0) close(fd);
            goto fail;
        }
        p->fd[p->n] = fd;
        p->given[p->n] = strdup(d);
        p->canon[p->n] = realpath(d, NULL);
        p->n++;
        if (!p->given[p->n - 1] || !p->canon[p->n - 1]) {
            pi_seterr(err, "allow_dir(%s): %s", d, strerror(errno ? errno : ENOMEM));
            goto fail;
        }
    }
    if (cfg->token_file) {
        p->token = access_read_token(cfg->token_file, err);
        if (!p->token) goto fail;
        p->token_len = strlen(p->token);
    }
    return 0;
fail:
    access_free(p);
    return -1;
}

void access_free(access_policy *p)
{
    for (int i = 0; i < p->n; i++) {
        if (p->fd[i] >= 0) close(p->fd[i]);
        free(p->given[i]);
        free(p->canon[i]);
    }
    free(p->given);
    free(p->canon);
    free(p->fd);
    if (p->token) explicit_bzero(p->token, p->token_len);
    free(p->token);
    memset(p, 0, sizeof *p);
}

/* The part of path below dir, or NULL when path is not below it (as text). */
static const char *below(const char *path, const char *dir)
{
    size_t n = strlen(dir);
    while (n > 1 && dir[n - 1] == '/') n--;
    if (n == 1 && dir[0] == '/')
        n = 0;
    else if (strncmp(path, dir, n) != 0 || path[n] != '/')
        return NULL;
    while (path[n] == '/') n++;
    return path + n;
}

/* The same check with a kernel that has no openat2 (before Linux 5.6):
 * resolve the whole path, and open the result without following links. */
static int open_resolved(const char *canon, const char *path)
{
    char *real = realpath(path, NULL);
    int fd = -1;
    if (!real) return -1;
    if (below(real, canon))
        fd = open(real, OPEN_FLAGS | O_NOFOLLOW);
    else
        errno = EXDEV;
    free(real);
    return fd;
}

int access_open(const access_policy *p, const char *path, char *err)
{
    if (p->n == 0) {
        pi_seterr(err,
                  "infer: reading files is off on this server (no allow_dir); send the image with "
                  "\"frame N\" and its N bytes");
        return -1;
    }
    if (path[0] != '/') {
        pi_seterr(err, "infer(%s): expected an absolute path", path);
        return -1;
    }
    for (int i = 0; i < p->n; i++) {
        const char *rel = below(path, p->given[i]);
        if (!rel) rel = below(path, p->canon[i]);
        if (!rel) continue;
        if (!*rel) rel = ".";
        struct open_how how;
        memset(&how, 0, sizeof how);
        how.flags = OPEN_FLAGS;
        how.resolve = RESOLVE_BENEATH | RESOLVE_NO_MAGICLINKS;
        int fd = (int)syscall(SYS_openat2, p->fd[i], rel, &how, sizeof how);
        if (fd < 0 && errno == ENOSYS) fd = open_resolved(p->canon[i], path);
        if (fd >= 0) return fd;
        if (errno == EXDEV || errno == ELOOP) break; /* a link or ".." that leads out */
        pi_seterr(err, "open(%s): %s", path, strerror(errno));
        return -1;
    }
    pi_seterr(err, "infer(%s): not in an allowed directory", path);
    return -1;
}

int access_token_ok(const access_policy *p, const char *tok)
{
    size_t n = strlen(tok);
    unsigned char diff = 0;
    if (!p->token) return 0;
    /* constant time in the token's content: no early exit */
    for (size_t i = 0; i < p->token_len; i++)
        diff |= (unsigned char)(p->token[i] ^ (i < n ? tok[i] : 0));
    return diff == 0 && n == p->token_len;
}

long access_peer_uid(int fd)
{
    struct ucred uc;
    socklen_t len = sizeof uc;
    if (getsockopt(fd, SOL_SOCKET, SO_PEERCRED, &uc, &len) < 0) return -1;
    return (long)uc.uid;
}
