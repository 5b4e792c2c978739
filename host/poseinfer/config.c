/* config.c -- the key = value config file and the setting of keys. */
#define _POSIX_C_SOURCE 200809L
#include "config.h"

#include <ctype.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <unistd.h>

#include "pi_err.h"
#include "poseinfer.h"

void config_init(pi_config *c)
{
    memset(c, 0, sizeof *c);
    c->threads = 1;
    c->warmup = 1;
    c->max_pixels = PI_DEFAULT_MAX_PIXELS;
    c->refine = 1;
    c->timeout_ms = 5000;
    c->socket_mode = 0660;
    c->workers = 2;
    c->max_clients = 64;
    c->idle_timeout_ms = 60000;
    c->max_file_bytes = 64L * 1024 * 1024;
}

void config_clear_allow_dirs(pi_config *c)
{
    for (int i = 0; i < c->n_allow_dirs; i++) free(c->allow_dirs[i]);
    free(c->allow_dirs);
    c->allow_dirs = NULL;
    c->n_allow_dirs = 0;
}

static int add_allow_dir(pi_config *c, const char *v, char *err)
{
    char **n;
    if (v[0] != '/') {
        pi_seterr(err, "allow_dir: expected an absolute directory, got \"%.64s\"", v);
        return -1;
    }
    n = realloc(c->allow_dirs, (size_t)(c->n_allow_dirs + 1) * sizeof *n);
    if (!n) {
        pi_seterr(err, "out of memory");
        return -1;
    }
    c->allow_dirs = n;
    if (!(n[c->n_allow_dirs] = strdup(v))) {
        pi_seterr(err, "out of memory");
        return -1;
    }
    c->n_allow_dirs++;
    return 0;
}

/* An octal mode such as 0660 or 660, at most hi (0777). */
static int set_mode(int *dst, const char *key, const char *v, long hi, char *err)
{
    char *end;
    long n;
    errno = 0;
    n = strtol(v, &end, 8);
    if (errno || end == v || *end != '\0' || n < 0 || n > hi) {
        pi_seterr(err, "%s: expected an octal mode such as 0660, got \"%.64s\"", key, v);
        return -1;
    }
    *dst = (int)n;
    return 0;
}

void config_free(pi_config *c)
{
    free(c->model);
    free(c->serve);
    free(c->camera);
    free(c->camera_file);
    free(c->dump_tensor);
    free(c->save_frames);
    free(c->socket_group);
    free(c->token_file);
    config_clear_allow_dirs(c);
    memset(c, 0, sizeof *c);
}

static int set_str(char **dst, const char *v, char *err)
{
    char *s = strdup(v);
    if (!s) {
        pi_seterr(err, "out of memory");
        return -1;
    }
    free(*dst);
    *dst = s;
    return 0;
}

static int set_long(long *dst, const char *key, const char *v, long lo, long hi, char *err)
{
    char *end;
    long n;
    errno = 0;
    n = strtol(v, &end, 10);
    if (errno || end == v || *end != '\0' || n < lo || n > hi) {
        pi_seterr(err, "%s: expected an integer in [%ld, %ld], got \"%.64s\"", key, lo, hi, v);
        return -1;
    }
    *dst = n;
    return 0;
}

static int set_int(int *dst, const char *key, const char *v, long lo, long hi, char *err)
{
    long n;
    if (set_long(&n, key, v, lo, hi, err) < 0) return -1;
    *dst = (int)n;
    return 0;
}

static int set_bool(int *dst, const char *key, const char *v, char *err)
{
    if (!strcasecmp(v, "yes") || !strcasecmp(v, "true") || !strcmp(v, "1") || !strcasecmp(v, "on"))
        *dst = 1;
    else if (!strcasecmp(v, "no") || !strcasecmp(v, "false") || !strcmp(v, "0") ||
             !strcasecmp(v, "off"))
        *dst = 0;
    else {
        pi_seterr(err, "%s: expected yes or no, got \"%.64s\"", key, v);
        return -1;
    }
    return 0;
}

/* The keys, one table: config_set reads it, config_key lists it (the unit
 * test holds it to docs/poseinfer.md's table of keys and defaults). */
enum key_kind { K_STR, K_BOOL, K_INT, K_LONG, K_MODE, K_DIR };
static const struct key_def {
    const char *name;
    enum key_kind kind;
    size_t off; /* of the field in pi_config */
    long lo, hi;
} keys[] = {
    {"model", K_STR, offsetof(pi_config, model), 0, 0},
    {"serve", K_STR, offsetof(pi_config, serve), 0, 0},
    {"camera", K_STR, offsetof(pi_config, camera), 0, 0},
    {"camera_file", K_STR, offsetof(pi_config, camera_file), 0, 0},
    {"continuous", K_BOOL, offsetof(pi_config, continuous), 0, 0},
    {"timings", K_BOOL, offsetof(pi_config, timings), 0, 0},
    {"refine", K_BOOL, offsetof(pi_config, refine), 0, 0},
    {"count", K_LONG, offsetof(pi_config, count), 0, LONG_MAX},
    {"save_frames", K_STR, offsetof(pi_config, save_frames), 0, 0},
    {"interval_ms", K_INT, offsetof(pi_config, interval_ms), 0, 3600000},
    {"threads", K_INT, offsetof(pi_config, threads), 1, 256},
    {"warmup", K_INT, offsetof(pi_config, warmup), 0, 100},
    {"max_pixels", K_LONG, offsetof(pi_config, max_pixels), 64, 1L << 34},
    {"timeout_ms", K_INT, offsetof(pi_config, timeout_ms), 1, 3600000},
    {"socket_mode", K_MODE, offsetof(pi_config, socket_mode), 0, 0777},
    {"socket_group", K_STR, offsetof(pi_config, socket_group), 0, 0},
    {"allow_dir", K_DIR, offsetof(pi_config, allow_dirs), 0, 0},
    {"tcp_remote", K_BOOL, offsetof(pi_config, tcp_remote), 0, 0},
    {"token_file", K_STR, offsetof(pi_config, token_file), 0, 0},
    {"workers", K_INT, offsetof(pi_config, workers), 1, 64},
    {"max_clients", K_INT, offsetof(pi_config, max_clients), 1, 4096},
    {"idle_timeout_ms", K_INT, offsetof(pi_config, idle_timeout_ms), 100, 86400000},
    {"max_file_bytes", K_LONG, offsetof(pi_config, max_file_bytes), 1024, 1L << 31},
};

const char *config_key(int i)
{
    return i >= 0 && (size_t)i < sizeof keys / sizeof keys[0] ? keys[i].name : NULL;
}

int config_set(pi_config *c, const char *key_in, const char *v, char *err)
{
    char key[64];
    size_t i;
    for (i = 0; key_in[i] && i < sizeof key - 1; i++) key[i] = key_in[i] == '-' ? '_' : key_in[i];
    key[i] = '\0';
    for (i = 0; i < sizeof keys / sizeof keys[0]; i++) {
        const struct key_def *d = &keys[i];
        void *field = (char *)c + d->off;
        if (strcmp(key, d->name)) continue;
        switch (d->kind) {
        case K_STR: return set_str(field, v, err);
        case K_BOOL: return set_bool(field, key, v, err);
        case K_INT: return set_int(field, key, v, d->lo, d->hi, err);
        case K_LONG: return set_long(field, key, v, d->lo, d->hi, err);
        case K_MODE: return set_mode(field, key, v, d->hi, err);
        case K_DIR: return add_allow_dir(c, v, err);
        }
    }
    pi_seterr(err,
              "unknown key \"%.64s\" (the keys: poseinfer --help, and docs/poseinfer.md, \"Config "
              "file\")",
              key_in);
    return -1;
}

static char *trim(char *s)
{
    char *e;
    while (isspace((unsigned char)*s)) s++;
    e = s + strlen(s);
    while (e > s && isspace((unsigned char)e[-1])) *--e = '\0';
    return s;
}

/* Open a config file for reading: O_NONBLOCK and fstat first, so that a FIFO
 * or a device given as the file is refused, not waited on. */
static FILE *open_regular(const char *path, char *err)
{
    struct stat sb;
    FILE *f;
    int fd = open(path, O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY);
    if (fd < 0) {
        pi_seterr(err, "config(%s): %s", path, strerror(errno));
        return NULL;
    }
    if (fstat(fd, &sb) < 0 || !S_ISREG(sb.st_mode)) {
        pi_seterr(err, "config(%s): not a regular file", path);
        close(fd);
        return NULL;
    }
    f = fdopen(fd, "r");
    if (!f) {
        pi_seterr(err, "config(%s): %s", path, strerror(errno));
        close(fd);
    }
    return f;
}

int config_load(pi_config *c, const char *path, char *err)
{
    FILE *f = open_regular(path, err);
    char line[1024], why[PI_ERR_LEN];
    int lineno = 0;
    if (!f) return -1;
    while (fgets(line, sizeof line, f)) {
        char *k, *v, *eq;
        lineno++;
        if (!strchr(line, '\n') && !feof(f)) {
            pi_seterr(err, "config(%s:%d): line too long", path, lineno);
            goto fail;
        }
        k = trim(line);
        if (*k == '\0' || *k == '#') continue;
        eq = strchr(k, '=');
        if (!eq) {
            pi_seterr(err, "config(%s:%d): expected key = value", path, lineno);
            goto fail;
        }
        *eq = '\0';
        k = trim(k);
        v = trim(eq + 1);
        if (config_set(c, k, v, why) < 0) {
            pi_seterr(err, "config(%.100s:%d): %.130s", path, lineno, why);
            goto fail;
        }
    }
    if (ferror(f)) {
        pi_seterr(err, "config(%s): read error", path);
        goto fail;
    }
    fclose(f);
    return 0;
fail:
    fclose(f);
    return -1;
}
