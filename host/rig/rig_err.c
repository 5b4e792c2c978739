/* rig_err.c -- see rig_err.h. */
#include "rig_err.h"

#include <stdarg.h>
#include <stdio.h>

void rig_seterr(char *err, const char *fmt, ...)
{
    va_list ap;
    if (!err) return;
    va_start(ap, fmt);
    vsnprintf(err, RIG_ERR_LEN, fmt, ap);
    va_end(ap);
}
