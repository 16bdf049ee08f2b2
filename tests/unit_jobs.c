/* unit_jobs.c — the job store's rules that need no server: the quiet the worker waits for
 * before its idle work (server/jobs.h, job_idle_quiet_next_ms). */
#include "harness.h"
#include "jobs.h"

/* Stopped calls double the quiet, 1 s, 2, 4, 8, 16 s and no further; a call that ends brings
 * it back to 1 s from anywhere. */
static void test_idle_quiet_doubles_and_resets(void)
{
    double quiet = JOB_IDLE_AFTER_MS;
    const double expected[] = {2000, 4000, 8000, 16000, 16000, 16000};
    for (size_t i = 0; i < sizeof expected / sizeof expected[0]; i++) {
        quiet = job_idle_quiet_next_ms(quiet, 1);
        CHECK_NEAR(quiet, expected[i], 0);
    }
    CHECK_NEAR(job_idle_quiet_next_ms(quiet, 0), JOB_IDLE_AFTER_MS, 0);
    CHECK_NEAR(job_idle_quiet_next_ms(JOB_IDLE_AFTER_MS, 0), JOB_IDLE_AFTER_MS, 0);
    CHECK_NEAR(job_idle_quiet_next_ms(3000, 0), JOB_IDLE_AFTER_MS, 0);
    /* A quiet between the steps (none is, but the rule must not care) is capped the same. */
    CHECK_NEAR(job_idle_quiet_next_ms(12000, 1), JOB_IDLE_AFTER_MAX_MS, 0);
}

int main(void)
{
    RUN(test_idle_quiet_doubles_and_resets);
    return harness_report();
}
