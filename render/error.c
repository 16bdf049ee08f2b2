/* error.c — filling ns_error in one line at the place a failure is detected. */
#include <stdarg.h>
#include <stdio.h>

#include "gpu.h"

int ns_fail(ns_error *err, int status, const char *fmt, ...)
{
    if (err) {
        va_list args;
        va_start(args, fmt);
        vsnprintf(err->message, sizeof err->message, fmt, args);
        va_end(args);
        err->status = status;
    }
    return status;
}
