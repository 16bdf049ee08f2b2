/* harness.h — a tiny test harness in the spirit of cmark's: checks survive NDEBUG, a
 * failure prints the expression, the expected and the actual value and the place, and the
 * program ends with "N passed, N failed" and a non-zero exit status if anything failed.
 *
 *   static void test_something(void) { CHECK(x == 1); CHECK_NEAR(got, want, 1e-6); }
 *   int main(void) { RUN(test_something); return harness_report(); }
 *
 * A program that ran no check at all fails: a test whose every check was bypassed (an early
 * return, a helper that gave up) proves nothing and must not look green.
 *
 * Skips are for what a machine may truly lack (never lavapipe, which CI always has: a
 * missing default device must fail). SKIP("why") inside a RUN function skips that test
 * function; harness_skip("why") skips the whole program with exit status
 * HARNESS_SKIP_STATUS, which tests/CMakeLists.txt declares as SKIP_RETURN_CODE so that CTest
 * counts it as a skip, not a pass. Both print the reason.
 */
#ifndef NS_TEST_HARNESS_H
#define NS_TEST_HARNESS_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

/* CTest's SKIP_RETURN_CODE for every C test program (tests/CMakeLists.txt). */
#define HARNESS_SKIP_STATUS 77

static int harness_passed, harness_failed, harness_skipped;
static const char *harness_current = "";

/* Wall-clock seconds, for each test function's line: the suite's time budget is spent where
 * these say (docs/development.md, "Test time"). */
static inline double harness_seconds(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

#define CHECK(cond)                                                                          \
    do {                                                                                     \
        if (cond) {                                                                          \
            harness_passed++;                                                                \
        } else {                                                                             \
            harness_failed++;                                                                \
            fprintf(stderr, "FAIL %s (%s:%d): %s\n", harness_current, __FILE__, __LINE__,    \
                    #cond);                                                                  \
        }                                                                                    \
    } while (0)

/* |got - want| <= tol; NaN always fails. */
#define CHECK_NEAR(got, want, tol)                                                           \
    do {                                                                                     \
        double g_ = (double)(got), w_ = (double)(want), t_ = (double)(tol);                  \
        if (fabs(g_ - w_) <= t_) {                                                           \
            harness_passed++;                                                                \
        } else {                                                                             \
            harness_failed++;                                                                \
            fprintf(stderr, "FAIL %s (%s:%d): %s = %.9g, expected %s = %.9g within %.3g\n",  \
                    harness_current, __FILE__, __LINE__, #got, g_, #want, w_, t_);           \
        }                                                                                    \
    } while (0)

/* Relative tolerance: |got - want| <= rel * |want|. */
#define CHECK_REL(got, want, rel)                                                            \
    CHECK_NEAR((got), (want), (rel) * fabs((double)(want)))

#define CHECK_INT(got, want)                                                                 \
    do {                                                                                     \
        long long g_ = (long long)(got), w_ = (long long)(want);                             \
        if (g_ == w_) {                                                                      \
            harness_passed++;                                                                \
        } else {                                                                             \
            harness_failed++;                                                                \
            fprintf(stderr, "FAIL %s (%s:%d): %s = %lld, expected %lld\n", harness_current,  \
                    __FILE__, __LINE__, #got, g_, w_);                                       \
        }                                                                                    \
    } while (0)

#define CHECK_STR_CONTAINS(haystack, needle)                                                 \
    do {                                                                                     \
        const char *h_ = (haystack), *n_ = (needle);                                         \
        if (h_ && strstr(h_, n_)) {                                                          \
            harness_passed++;                                                                \
        } else {                                                                             \
            harness_failed++;                                                                \
            fprintf(stderr, "FAIL %s (%s:%d): \"%s\" does not contain \"%s\"\n",             \
                    harness_current, __FILE__, __LINE__, h_ ? h_ : "(null)", n_);            \
        }                                                                                    \
    } while (0)

/* Skips the rest of the current test function (a void function run by RUN), saying why. */
#define SKIP(reason)                                                                         \
    do {                                                                                     \
        harness_skipped++;                                                                   \
        fprintf(stderr, "skip %s (%s:%d): %s\n", harness_current, __FILE__, __LINE__,        \
                (reason));                                                                   \
        return;                                                                              \
    } while (0)

#define RUN(fn)                                                                              \
    do {                                                                                     \
        harness_current = #fn;                                                               \
        int before_ = harness_failed, skipped_ = harness_skipped;                            \
        double start_ = harness_seconds();                                                   \
        fn();                                                                                \
        fprintf(stderr, "%s %s (%.1f s)\n",                                                  \
                harness_failed != before_       ? "FAIL"                                     \
                : harness_skipped != skipped_ ? "skip"                                       \
                                              : "ok  ",                                      \
                #fn, harness_seconds() - start_);                                            \
    } while (0)

/* The summary line and the exit status: 1 if a check failed or none ran at all,
 * HARNESS_SKIP_STATUS if nothing was checked because everything was skipped, else 0. */
static inline int harness_report(void)
{
    if (harness_skipped)
        printf("%d passed, %d failed, %d skipped\n", harness_passed, harness_failed,
               harness_skipped);
    else
        printf("%d passed, %d failed\n", harness_passed, harness_failed);
    if (harness_failed)
        return 1;
    if (harness_passed == 0 && harness_skipped > 0) {
        printf("skipped: no check ran, every test was skipped (reasons above)\n");
        return HARNESS_SKIP_STATUS;
    }
    if (harness_passed == 0) {
        printf("FAIL: no check ran: a test program that checks nothing proves nothing\n");
        return 1;
    }
    return 0;
}

/* Skips the whole program: prints the reason and exits with HARNESS_SKIP_STATUS, unless a
 * check has already failed, which stays a failure. */
_Noreturn static inline void harness_skip(const char *reason)
{
    fflush(stderr);
    if (harness_failed) {
        printf("%d passed, %d failed; then skipped: %s\n", harness_passed, harness_failed,
               reason);
        exit(1);
    }
    printf("skipped: %s\n", reason);
    exit(HARNESS_SKIP_STATUS);
}

#endif
