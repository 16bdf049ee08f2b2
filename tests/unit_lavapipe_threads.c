/* unit_lavapipe_threads.c — the thread count by which the shaders interleave their workgroups
 * on lavapipe (shaders/groups.glsl): Mesa's own rule, LP_NUM_THREADS when it starts with a
 * number, else the CPUs this process may run on, within [1, 16]. A wrong count would only unbalance
 * lavapipe's threads; the GPU tests run again under other counts (tests/CMakeLists.txt) to
 * show that every workgroup is still computed once whatever it is. */
#define _GNU_SOURCE /* sched_getaffinity, CPU_COUNT */
#include <sched.h>
#include <stdlib.h>

#include "gpu.h"
#include "harness.h"

static uint32_t cpus(void)
{
    cpu_set_t set;
    int n = sched_getaffinity(0, sizeof set, &set) == 0 ? CPU_COUNT(&set) : 1;
    return n < 1 ? 1u : n > 16 ? 16u : (uint32_t)n;
}

static void test_environment(void)
{
    setenv("LP_NUM_THREADS", "3", 1);
    CHECK_INT(gpu_lavapipe_threads(), 3);
    setenv("LP_NUM_THREADS", "1", 1);
    CHECK_INT(gpu_lavapipe_threads(), 1);
    setenv("LP_NUM_THREADS", "40", 1); /* Mesa's LP_MAX_THREADS */
    CHECK_INT(gpu_lavapipe_threads(), 16);
    setenv("LP_NUM_THREADS", "0", 1); /* Mesa runs on the calling thread: one run */
    CHECK_INT(gpu_lavapipe_threads(), 1);
    setenv("LP_NUM_THREADS", "-2", 1);
    CHECK_INT(gpu_lavapipe_threads(), 1);
    setenv("LP_NUM_THREADS", "3x", 1); /* strtol's number, as Mesa reads it */
    CHECK_INT(gpu_lavapipe_threads(), 3);
}

static void test_without_environment(void)
{
    unsetenv("LP_NUM_THREADS");
    CHECK_INT(gpu_lavapipe_threads(), cpus());
    setenv("LP_NUM_THREADS", "", 1);
    CHECK_INT(gpu_lavapipe_threads(), cpus());
    setenv("LP_NUM_THREADS", "four", 1); /* not a number: the CPUs */
    CHECK_INT(gpu_lavapipe_threads(), cpus());
}

int main(void)
{
    RUN(test_environment);
    RUN(test_without_environment);
    return harness_report();
}
