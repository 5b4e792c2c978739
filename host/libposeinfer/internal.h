/* internal.h -- shared between the library's files (libposeinfer/) and the
 * program (poseinfer/), and the unit tests; not part of the public API
 * (include/poseinfer.h), and included from nowhere outside host/ and
 * tests/host/unit/. */
#ifndef PI_INTERNAL_H
#define PI_INTERNAL_H

#include <stddef.h>

#include "pi_err.h" /* pi_seterr: every err message */
#include "poseinfer.h"
#include "shim.h"

/* Parse the spherepose.preprocess JSON: its "name" and every key of that
 * algorithm, each in range (no defaults; a missing key is named in err);
 * `model` names the file in messages. */
int pi_parse_preprocess(const char *text, pp_params *p, char *err, const char *model);

/* Files over this many bytes are refused (default PI_DEFAULT_MAX_FILE_BYTES;
 * the program sets it once at start from max_file_bytes). */
#define PI_DEFAULT_MAX_FILE_BYTES (512L * 1024 * 1024)
extern long pi_max_file_bytes;

/* Read a whole regular file into *buf (grown as needed, capacity *cap). It is
 * opened O_NONBLOCK and checked with fstat before any read, so a FIFO or a
 * device is refused at once ("not a regular file (a FIFO)"), never waited on. */
int pi_read_file(const char *path, unsigned char **buf, size_t *cap, size_t *len, char *err);

/* The same from an open descriptor (closed in every case); path names it in
 * messages. */
int pi_read_fd(int fd, const char *path, unsigned char **buf, size_t *cap, size_t *len, char *err);

/* "a FIFO", "a directory", ... for a st_mode that is not a regular file. */
const char *pi_file_kind(unsigned mode);

/* pi_load_file (poseinfer.h) from an open descriptor (fd < 0: open path);
 * fd is closed. */
int pi_load_fd(pi_ctx *ctx, int fd, const char *path, pi_frame *f, char *err);

/* A context that shares base's session, parameters and metadata and has
 * buffers of its own: one per thread (ONNX Runtime's Run is thread-safe on
 * one session). Close it with pi_close, in any order with the base: the
 * session is freed with the last of them. */
pi_ctx *pi_clone(pi_ctx *base, char *err);

/* Free the read buffer and the decoded frame when either is over `over`
 * bytes (after a large frame, so the daemon does not keep it). 1 when it
 * freed something. */
int pi_release_large(pi_ctx *ctx, size_t over);

/* Read, decode and infer from an open descriptor (closed in every case). */
int pi_infer_fd(pi_ctx *ctx, int fd, const char *name, pi_result *res, char *err);

/* Decode an encoded image into m, timing it into f->decode_ms. */
int pi_decode_into(shim_mat *m, const void *buf, size_t len, long max_pixels, pi_frame *f,
                   char *err);

#endif
