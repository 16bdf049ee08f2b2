/* args.h — argument checking shared by the subcommands (cli/cmd_*.c):
 * one wording for usage errors, so every command names the bad argument the same way. */
#ifndef NS_CLI_ARGS_H
#define NS_CLI_ARGS_H

/* Prints "COMMAND: <message>" and a newline on stderr; returns 2, the exit status for bad
 * usage, so a caller can write `return cli_usage_error(...)`. */
int cli_usage_error(const char *command, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* Parses the whole of `text` as a finite number in [lo, hi] into *out; otherwise reports a
 * usage error naming `name` and returns 2 (*out untouched). */
int cli_parse_number(const char *command, const char *name, const char *text, double lo, double hi,
                     double *out);

#endif
