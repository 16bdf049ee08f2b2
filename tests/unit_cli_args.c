/* unit_cli_args.c — the command line's number parsers (cli/args.h): what each takes whole,
 * what it refuses (empty, trailing garbage, signs where a count is meant, NaN, infinities,
 * out of range), that a refusal returns 2 and leaves the output alone, and what the message
 * names. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "args.h"
#include "harness.h"

/* stderr of the last checked parser call, captured through a temporary file. */
static char captured[1024];

static FILE *capture_begin(int *saved)
{
    fflush(stderr);
    *saved = dup(fileno(stderr));
    FILE *f = tmpfile();
    if (f)
        dup2(fileno(f), fileno(stderr));
    return f;
}

static void capture_end(FILE *f, int saved)
{
    fflush(stderr);
    dup2(saved, fileno(stderr));
    close(saved);
    captured[0] = 0;
    if (!f)
        return;
    rewind(f);
    size_t n = fread(captured, 1, sizeof captured - 1, f);
    captured[n] = 0;
    fclose(f);
}

static int number(const char *text, double lo, double hi, double *out)
{
    int saved;
    FILE *f = capture_begin(&saved);
    int rc = cli_parse_number("nscatter test", "--x", text, lo, hi, out);
    capture_end(f, saved);
    return rc;
}

static int parse_u(const char *text, uint64_t lo, uint64_t hi, uint64_t *out)
{
    int saved;
    FILE *f = capture_begin(&saved);
    int rc = cli_parse_uint("nscatter test", "--n", text, lo, hi, out);
    capture_end(f, saved);
    return rc;
}

static void test_number(void)
{
    double v = 0;
    CHECK_INT(cli_number("0.25", &v), 0);
    CHECK(v == 0.25);
    CHECK_INT(cli_number("-3e-2", &v), 0);
    CHECK(v == -0.03);
    static const char *const bad[] = {"",    "abc", "1.5x",      "1,5",   "0.5 ", "nan",
                                      "NaN", "inf", "-infinity", "1e999", "--1"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        v = 42;
        CHECK_INT(cli_number(bad[i], &v), -1);
        CHECK(v == 42);
    }

    CHECK_INT(number("0.5", 0, 1, &v), 0);
    CHECK(v == 0.5);
    CHECK_INT(number("1", 0, 1, &v), 0); /* the bounds are inclusive */
    CHECK_INT(number("0", 0, 1, &v), 0);
    v = 42;
    CHECK_INT(number("1.0001", 0, 1, &v), 2);
    CHECK(v == 42);
    CHECK(!strcmp(captured, "nscatter test: --x: '1.0001' must be a number in [0, 1]\n"));
    CHECK_INT(number("nan", 0, 1, &v), 2);
    CHECK_INT(number("", 0, 1, &v), 2);
    CHECK_STR_CONTAINS(captured, "--x: ''");
    CHECK_INT(number("0.5abc", 0, 1, &v), 2);
    /* Whole bounds as a person writes them, others as %g. */
    CHECK_INT(number("5", 1e3, 1e13, &v), 2);
    CHECK_STR_CONTAINS(captured, "[1000, 1e13]");
    CHECK_INT(number("5", -0.5, 1e-3, &v), 2);
    CHECK_STR_CONTAINS(captured, "[-0.5, 0.001]");
    CHECK_INT(number("-5", -1e6, 0, &v), 0);
    CHECK_INT(number("-5e6", -1e6, INFINITY, &v), 2);
    CHECK_STR_CONTAINS(captured, "[-1e6, inf]");
    /* No range: any finite number, and the message says what is wrong. */
    CHECK_INT(number("-1e300", -INFINITY, INFINITY, &v), 0);
    CHECK_INT(number("inf", -INFINITY, INFINITY, &v), 2);
    CHECK(!strcmp(captured, "nscatter test: --x: 'inf' is not a number\n"));
}

static void test_uint(void)
{
    uint64_t u = 0;
    CHECK_INT(parse_u("42", 0, 100, &u), 0);
    CHECK_INT(u, 42);
    CHECK_INT(parse_u("007", 0, 100, &u), 0);
    CHECK_INT(u, 7);
    /* Counts written as scientific numbers are whole numbers too. */
    CHECK_INT(parse_u("1e6", 0, (uint64_t)1e15, &u), 0);
    CHECK_INT(u, 1000000);
    CHECK_INT(parse_u("2.0", 0, 10, &u), 0);
    CHECK_INT(u, 2);
    /* Exact beyond a double's 2^53, up to UINT64_MAX. */
    CHECK_INT(parse_u("9007199254740993", 0, UINT64_MAX, &u), 0);
    CHECK(u == 9007199254740993ull);
    CHECK_INT(parse_u("18446744073709551615", 0, UINT64_MAX, &u), 0);
    CHECK(u == UINT64_MAX);

    static const char *const too_large[] = {"18446744073709551616", "99999999999999999999999",
                                            "1e20"};
    static const char *const bad[] = {"",     "-1", "+1",  " 1",  "1 ",  "2.5",  "1e-1",
                                      "0x10", "1x", "abc", "nan", "inf", "1e999"};
    for (size_t i = 0; i < sizeof too_large / sizeof too_large[0]; i++) {
        u = 77;
        CHECK_INT(parse_u(too_large[i], 0, UINT64_MAX, &u), 2);
        CHECK_INT(u, 77);
    }
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        u = 77;
        CHECK_INT(parse_u(bad[i], 0, UINT64_MAX, &u), 2);
        CHECK_INT(u, 77);
        if (u != 77 || !strstr(captured, "whole number"))
            fprintf(stderr, "  for '%s': %s", bad[i], captured);
    }
    CHECK_INT(parse_u("0", 1, 256, &u), 2);
    CHECK(!strcmp(captured, "nscatter test: --n: '0' must be a whole number in [1, 256]\n"));
    CHECK_INT(parse_u("257", 1, 256, &u), 2);
    CHECK_INT(parse_u("256", 1, 256, &u), 0);
    /* Round powers of ten read as a person writes them. */
    CHECK_INT(parse_u("0", 1, (uint64_t)1e15, &u), 2);
    CHECK_STR_CONTAINS(captured, "[1, 1e15]");
    CHECK_INT(parse_u("0", 1, 1u << 20, &u), 2);
    CHECK_STR_CONTAINS(captured, "[1, 1048576]");
}

static void test_pair(void)
{
    double a = 0, b = 0;
    CHECK_INT(cli_number_pair("0.9:3", ':', &a, &b), 0);
    CHECK(a == 0.9 && b == 3);
    CHECK_INT(cli_number_pair("-1:2e1", ':', &a, &b), 0);
    CHECK(a == -1 && b == 20);
    static const char *const bad[] = {"",       ":",       "0.9",   "0.9:",  ":3",   "0.9:3x",
                                      "0.9x:3", "0.9:3:4", "nan:1", "1:inf", "0.9;3"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        a = b = 5;
        CHECK_INT(cli_number_pair(bad[i], ':', &a, &b), -1);
        CHECK(a == 5 && b == 5);
    }
    char longer[200];
    memset(longer, '1', sizeof longer);
    longer[150] = ':';
    longer[199] = 0;
    CHECK_INT(cli_number_pair(longer, ':', &a, &b), -1); /* a half too long to be a number */
}

static void test_list_next(void)
{
    char item[8];
    const char *cursor = "1,22,333";
    CHECK_INT(cli_list_next(&cursor, item, sizeof item), 1);
    CHECK(!strcmp(item, "1"));
    CHECK_INT(cli_list_next(&cursor, item, sizeof item), 1);
    CHECK(!strcmp(item, "22"));
    CHECK_INT(cli_list_next(&cursor, item, sizeof item), 1);
    CHECK(!strcmp(item, "333"));
    CHECK_INT(cli_list_next(&cursor, item, sizeof item), 0);
    CHECK_INT(cli_list_next(&cursor, item, sizeof item), 0); /* stays over */
    static const char *const bad[] = {"", ",1", "1,,2", "1,", "12345678"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        cursor = bad[i];
        int r;
        while ((r = cli_list_next(&cursor, item, sizeof item)) == 1)
            ;
        CHECK_INT(r, -1);
    }
}

static void test_lists(void)
{
    double v[4];
    size_t n = 99;
    int saved;
    FILE *f = capture_begin(&saved);
    CHECK_INT(cli_parse_number_list("nscatter test", "--g-values", "0.1,-0.5,0.9", -1, 1, v, 4, &n),
              0);
    CHECK_INT(n, 3);
    CHECK(v[0] == 0.1 && v[1] == -0.5 && v[2] == 0.9);
    n = 99;
    CHECK_INT(cli_parse_number_list("nscatter test", "--g-values", "0.1,2", -1, 1, v, 4, &n), 2);
    CHECK_INT(n, 99);
    CHECK_INT(cli_parse_number_list("nscatter test", "--g-values", "", -1, 1, v, 4, &n), 2);
    CHECK_INT(cli_parse_number_list("nscatter test", "--g-values", "0.1,,0.2", -1, 1, v, 4, &n), 2);
    CHECK_INT(cli_parse_number_list("nscatter test", "--g-values", "0.1,", -1, 1, v, 4, &n), 2);
    CHECK_INT(cli_parse_number_list("nscatter test", "--g-values", "0,0,0,0,0", -1, 1, v, 4, &n),
              2);
    capture_end(f, saved);
    CHECK_STR_CONTAINS(captured, "--g-values: '2' must be a number in [-1, 1]");
    CHECK_STR_CONTAINS(captured, "--g-values: empty list");
    CHECK_STR_CONTAINS(captured, "--g-values: '0.1,,0.2' has an empty or overlong item");
    CHECK_STR_CONTAINS(captured, "--g-values: '0,0,0,0,0' has more than 4 values");

    uint64_t u[8];
    f = capture_begin(&saved);
    CHECK_INT(cli_parse_uint_list("nscatter test", "--pt-spp", "1,4,16", 1, 4096, u, 8, &n), 0);
    CHECK_INT(n, 3);
    CHECK(u[0] == 1 && u[1] == 4 && u[2] == 16);
    CHECK_INT(cli_parse_uint_list("nscatter test", "--pt-spp", "1,4.5", 1, 4096, u, 8, &n), 2);
    CHECK_INT(cli_parse_uint_list("nscatter test", "--pt-spp", "1,0", 1, 4096, u, 8, &n), 2);
    CHECK_INT(cli_parse_uint_list("nscatter test", "--pt-spp", "1,-4", 1, 4096, u, 8, &n), 2);
    capture_end(f, saved);
    CHECK_STR_CONTAINS(captured, "--pt-spp: '4.5' must be a whole number in [1, 4096]");
    CHECK_STR_CONTAINS(captured, "--pt-spp: '-4'");
}

int main(void)
{
    RUN(test_number);
    RUN(test_uint);
    RUN(test_pair);
    RUN(test_list_next);
    RUN(test_lists);
    return harness_report();
}
