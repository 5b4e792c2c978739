/* rig_err.h -- the one error convention of host/rig (stage client, rig
 * metrics, plans, reports, the programs): a function that fails returns -1
 * and fills its caller's err buffer, RIG_ERR_LEN bytes, with "call: reason". */
#ifndef RIG_ERR_H
#define RIG_ERR_H

#define RIG_ERR_LEN 256 /* size of every err[] buffer in host/rig */

/* printf into err (RIG_ERR_LEN bytes, truncated); nothing when err is NULL. */
void rig_seterr(char *err, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

#endif
