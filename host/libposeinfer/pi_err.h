/* pi_err.h -- the one error convention of libposeinfer/ and poseinfer/ (the
 * library and the program): a function that fails returns -1 and fills its
 * caller's err buffer with "call: reason" on one line. Every message is
 * written through these two. */
#ifndef PI_ERR_H
#define PI_ERR_H

#include <stddef.h>

#include "poseinfer.h" /* PI_ERR_LEN */

#ifdef __cplusplus
extern "C" {
#endif

/* printf into err (PI_ERR_LEN bytes, truncated); nothing when err is NULL. */
void pi_seterr(char *err, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* The same into a buffer of len bytes, for the parts whose callers pass the
 * size with the buffer (refinement, the sphere-crop-v2 circle finder). */
void pi_seterrn(char *err, size_t len, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

#ifdef __cplusplus
}
#endif

#endif
