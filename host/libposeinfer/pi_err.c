/* pi_err.c -- the error helper of host/ (pi_err.h). */
#include "pi_err.h"

#include <stdarg.h>
#include <stdio.h>

void pi_seterrn(char *err, size_t len, const char *fmt, ...)
{
    va_list ap;
    if (!err || !len) return;
    va_start(ap, fmt);
    vsnprintf(err, len, fmt, ap);
    va_end(ap);
}

void pi_seterr(char *err, const char *fmt, ...)
{
    va_list ap;
    if (!err) return;
    va_start(ap, fmt);
    vsnprintf(err, PI_ERR_LEN, fmt, ap);
    va_end(ap);
}
