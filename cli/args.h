/* args.h — argument checking shared by the subcommands (cli/cmd_*.c): the one place the
 * command line turns text into numbers, and one wording for usage errors, so every command
 * accepts the same numbers and names the bad argument the same way. */
#ifndef NS_CLI_ARGS_H
#define NS_CLI_ARGS_H

#include <stddef.h>
#include <stdint.h>

/* Prints "COMMAND: <message>" and a newline on stderr; returns 2, the exit status for bad
 * usage, so a caller can write `return cli_usage_error(...)`. */
int cli_usage_error(const char *command, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* ---------------------------------------------------------------------------------------
 * Checked parsers: on bad input they print a usage error that names `name` (the option)
 * and quotes the text, and return 2 with *out untouched; 0 on success.
 * ------------------------------------------------------------------------------------- */

/* The whole of `text` as a finite number in [lo, hi]. With lo = -INFINITY and hi = INFINITY
 * any finite number is taken (the range is checked later, by the code that knows it). */
int cli_parse_number(const char *command, const char *name, const char *text, double lo, double hi,
                     double *out);

/* The whole of `text` as a whole number in [lo, hi]: decimal digits, or a whole number
 * written with a fraction or exponent ("1e6", "2.0"), as counts of photons or collisions
 * are. No sign, no hex, no spaces: "-1" is refused, never read as a huge number. */
int cli_parse_uint(const char *command, const char *name, const char *text, uint64_t lo,
                   uint64_t hi, uint64_t *out);

/* A comma-separated list of numbers (cli_parse_number) or whole numbers (cli_parse_uint), at
 * most `cap` of them, into values[0..*count). An empty list, an empty item ("1,,2", a
 * trailing comma) and more than `cap` items are errors; after one, *count is untouched and
 * values may be partly written. */
int cli_parse_number_list(const char *command, const char *name, const char *text, double lo,
                          double hi, double *values, size_t cap, size_t *count);
int cli_parse_uint_list(const char *command, const char *name, const char *text, uint64_t lo,
                        uint64_t hi, uint64_t *values, size_t cap, size_t *count);

/* ---------------------------------------------------------------------------------------
 * Plain parsers, for an option whose condition or message is its own: no message, 0 or -1
 * (outputs untouched on -1).
 * ------------------------------------------------------------------------------------- */

/* The whole of `text` as a finite number (strtod's syntax; nothing after it; not NaN, not
 * infinite, not out of a double's range). */
int cli_number(const char *text, double *out);

/* "A:B": two such numbers separated by `separator`, e.g. --oversample-albedo 0.9:3. */
int cli_number_pair(const char *text, char separator, double *a, double *b);

/* Walks a comma-separated list: copies the next item into item[cap] and moves *cursor past
 * it. Start with *cursor = the list. Returns 1 for an item, 0 once the list is over, and -1
 * for an empty item or one of cap bytes or more. An empty list is one empty item. */
int cli_list_next(const char **cursor, char *item, size_t cap);

#endif
