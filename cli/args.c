/* args.c — see args.h. */
#include "args.h"

#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Longest item of a list, and longest half of a pair: far more than any number needs. */
#define CLI_ITEM_CAP 64

int cli_usage_error(const char *command, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "%s: ", command);
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\n");
    va_end(ap);
    return 2;
}

int cli_number(const char *text, double *out)
{
    char *end = NULL;
    errno = 0;
    double v = strtod(text, &end);
    if (!*text || *end || errno || !isfinite(v))
        return -1;
    *out = v;
    return 0;
}

/* 0 and the value; -1 when text is not a whole number; -2 when it is one past UINT64_MAX. */
static int whole_number(const char *text, uint64_t *out)
{
    /* A leading digit keeps out what strtoull would wrap ("-1") and what strtod alone would
     * take ("inf", " 5"); hex is kept out because nobody writes a count in it. */
    if (!(*text >= '0' && *text <= '9') || strpbrk(text, "xX"))
        return -1;
    char *end = NULL;
    errno = 0;
    unsigned long long u = strtoull(text, &end, 10);
    if (!*end) {
        if (errno == ERANGE)
            return -2;
        *out = u;
        return 0;
    }
    /* Not digits alone: "1e6" or "2.0", which must still be whole. */
    errno = 0;
    double v = strtod(text, &end);
    if (*end || errno || !isfinite(v) || v != floor(v))
        return -1;
    if (v >= 18446744073709551616.0) /* 2^64 */
        return -2;
    *out = (uint64_t)v;
    return 0;
}

/* A bound as a person writes it: 1e15 rather than 1000000000000000. */
static const char *bound_text(uint64_t v, char buf[32])
{
    int exponent = 0;
    uint64_t p = v;
    while (p >= 10 && p % 10 == 0) {
        p /= 10;
        exponent++;
    }
    if (p == 1 && exponent >= 6)
        snprintf(buf, 32, "1e%d", exponent);
    else
        snprintf(buf, 32, "%" PRIu64, v);
    return buf;
}

/* The same for a bound of a real range: whole ones as above (1e13, not 1e+13), others as %g. */
static const char *real_bound_text(double v, char buf[32])
{
    if (v == floor(v) && fabs(v) < 1e18) {
        char digits[32];
        snprintf(buf, 32, "%s%s", v < 0 ? "-" : "", bound_text((uint64_t)fabs(v), digits));
    } else {
        snprintf(buf, 32, "%g", v);
    }
    return buf;
}

int cli_parse_number(const char *command, const char *name, const char *text, double lo, double hi,
                     double *out)
{
    double v = 0;
    if (cli_number(text, &v) || v < lo || v > hi) {
        if (isinf(lo) && isinf(hi))
            return cli_usage_error(command, "%s: '%s' is not a number", name, text);
        char lo_text[32], hi_text[32];
        return cli_usage_error(command, "%s: '%s' must be a number in [%s, %s]", name, text,
                               real_bound_text(lo, lo_text), real_bound_text(hi, hi_text));
    }
    *out = v;
    return 0;
}

int cli_parse_uint(const char *command, const char *name, const char *text, uint64_t lo,
                   uint64_t hi, uint64_t *out)
{
    uint64_t v = 0;
    if (whole_number(text, &v) || v < lo || v > hi) {
        char lo_text[32], hi_text[32];
        return cli_usage_error(command, "%s: '%s' must be a whole number in [%s, %s]", name, text,
                               bound_text(lo, lo_text), bound_text(hi, hi_text));
    }
    *out = v;
    return 0;
}

int cli_number_pair(const char *text, char separator, double *a, double *b)
{
    const char *sep = strchr(text, separator);
    if (!sep || (size_t)(sep - text) >= CLI_ITEM_CAP)
        return -1;
    char first[CLI_ITEM_CAP];
    memcpy(first, text, (size_t)(sep - text));
    first[sep - text] = '\0';
    double x = 0, y = 0;
    if (cli_number(first, &x) || cli_number(sep + 1, &y))
        return -1;
    *a = x;
    *b = y;
    return 0;
}

int cli_list_next(const char **cursor, char *item, size_t cap)
{
    const char *s = *cursor;
    if (!s)
        return 0;
    size_t len = strcspn(s, ",");
    if (len == 0 || len >= cap)
        return -1;
    memcpy(item, s, len);
    item[len] = '\0';
    /* After the last item the cursor is NULL; after a comma it points at the next item, even
     * an empty one ("1," has an empty second item). */
    *cursor = s[len] == ',' ? s + len + 1 : NULL;
    return 1;
}

/* The checks every list shares; parse_item parses one item (reporting its own errors). */
static int parse_list(const char *command, const char *name, const char *text, size_t cap,
                      size_t *count, int (*parse_item)(const char *item, size_t index, void *user),
                      void *user)
{
    if (!*text)
        return cli_usage_error(command, "%s: empty list", name);
    const char *cursor = text;
    char item[CLI_ITEM_CAP];
    size_t n = 0;
    int r;
    while ((r = cli_list_next(&cursor, item, sizeof item)) != 0) {
        if (r < 0)
            return cli_usage_error(command, "%s: '%s' has an empty or overlong item", name, text);
        if (n == cap)
            return cli_usage_error(command, "%s: '%s' has more than %zu values", name, text, cap);
        if (parse_item(item, n, user))
            return 2;
        n++;
    }
    *count = n;
    return 0;
}

typedef struct {
    const char *command, *name;
    double lo, hi;
    double *values;
} number_list;

static int number_item(const char *item, size_t index, void *user)
{
    number_list *l = user;
    return cli_parse_number(l->command, l->name, item, l->lo, l->hi, &l->values[index]);
}

int cli_parse_number_list(const char *command, const char *name, const char *text, double lo,
                          double hi, double *values, size_t cap, size_t *count)
{
    number_list l = {command, name, lo, hi, values};
    return parse_list(command, name, text, cap, count, number_item, &l);
}

typedef struct {
    const char *command, *name;
    uint64_t lo, hi;
    uint64_t *values;
} uint_list;

static int uint_item(const char *item, size_t index, void *user)
{
    uint_list *l = user;
    return cli_parse_uint(l->command, l->name, item, l->lo, l->hi, &l->values[index]);
}

int cli_parse_uint_list(const char *command, const char *name, const char *text, uint64_t lo,
                        uint64_t hi, uint64_t *values, size_t cap, size_t *count)
{
    uint_list l = {command, name, lo, hi, values};
    return parse_list(command, name, text, cap, count, uint_item, &l);
}
