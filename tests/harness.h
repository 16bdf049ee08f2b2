/* harness.h — a tiny test harness in the spirit of cmark's: checks survive NDEBUG, a
 * failure prints the expression, the expected and the actual value and the place, and the
 * program ends with "N passed, N failed" and a non-zero exit status if anything failed.
 *
 *   static void test_something(void) { CHECK(x == 1); CHECK_NEAR(got, want, 1e-6); }
 *   int main(void) { RUN(test_something); return harness_report(); }
 */
#ifndef NS_TEST_HARNESS_H
#define NS_TEST_HARNESS_H

#include <math.h>
#include <stdio.h>
#include <string.h>

static int harness_passed, harness_failed;
static const char *harness_current = "";

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

#define RUN(fn)                                                                              \
    do {                                                                                     \
        harness_current = #fn;                                                               \
        int before_ = harness_failed;                                                        \
        fn();                                                                                \
        fprintf(stderr, "%s %s\n", harness_failed == before_ ? "ok  " : "FAIL", #fn);        \
    } while (0)

static inline int harness_report(void)
{
    printf("%d passed, %d failed\n", harness_passed, harness_failed);
    return harness_failed ? 1 : 0;
}

#endif
