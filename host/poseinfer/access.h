/* access.h -- who may ask the daemon for what (docs/poseinfer.md, "Who may
 * ask for what"): the directories `infer PATH` may read, the TCP token, the
 * uid of a unix: client. */
#ifndef PI_ACCESS_H
#define PI_ACCESS_H

#include <stddef.h>

#include "config.h"

typedef struct access_policy {
    int n;        /* allowed directories (0: `infer PATH` is off) */
    char **given; /* each as configured */
    char **canon; /* each with its symbolic links resolved */
    int *fd;      /* an O_PATH descriptor of each, opened at start */
    char *token;  /* NULL when no token_file is configured */
    size_t token_len;
} access_policy;

/* Resolve and open the allowed directories, read the token file. Errors name
 * the directory or file: "allow_dir(/x): No such file or directory". */
int access_init(access_policy *p, const pi_config *cfg, char *err);

void access_free(access_policy *p);

/* Open PATH for `infer`: a descriptor (O_NONBLOCK, to be fstat'ed by the
 * reader), or -1 with err. PATH must name a file beneath an allowed
 * directory, with every symbolic link and ".." resolved inside it (openat2
 * RESOLVE_BENEATH). A path outside gets the same answer whether it exists or
 * not, so replies tell nothing about the rest of the machine. */
int access_open(const access_policy *p, const char *path, char *err);

/* 1 when tok is the configured token (compared in constant time). */
int access_token_ok(const access_policy *p, const char *tok);

/* The uid of the process at the other end of a unix: socket, or -1. */
long access_peer_uid(int fd);

/* Read a token file: a regular file that others cannot read, its first line
 * (at least 16 characters) the token. Returns a new string, or NULL + err. */
char *access_read_token(const char *path, char *err);

#endif
