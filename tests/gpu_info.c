/* gpu_info.c — `nscatter info`: the default device (lavapipe) and its driver, as text and
 * as JSON; exit 1 with a message naming the problem when the asked-for device does not
 * exist; exit 2 on bad usage. Runs the real binary ($NSCATTER_BIN, set by ctest). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>

#include "harness.h"

static const char *bin;

/* Runs `$NSCATTER_BIN args 2>&1`, returns the exit status and the output in out. */
static int run(const char *args, char *out, size_t size)
{
    char cmd[1024];
    snprintf(cmd, sizeof cmd, "'%s' %s 2>&1", bin, args);
    FILE *p = popen(cmd, "r");
    if (!p)
        return -1;
    size_t n = fread(out, 1, size - 1, p);
    out[n] = '\0';
    int status = pclose(p);
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

/* Whether lavapipe is installed, so the default device: on a machine with only a GPU's
 * driver (docs/bench.md, *On an NVIDIA GPU*) only what every device prints is checked. */
static int on_lavapipe(void)
{
    char out[4096];
    return run("info --device llvmpipe", out, sizeof out) == 0;
}

/* lavapipe's subgroup: one lane per 32 bits of its vectors, which its name gives
 * ("llvmpipe (LLVM 15.0.6, 256 bits)": 8 lanes); 0 when the name does not say. */
static unsigned lavapipe_lanes(const char *out)
{
    const char *bits = strstr(out, " bits)");
    if (!bits)
        return 0;
    const char *digits = bits;
    while (digits > out && digits[-1] >= '0' && digits[-1] <= '9')
        digits--;
    return (unsigned)strtoul(digits, NULL, 10) / 32u;
}

static void test_text(void)
{
    char out[4096];
    CHECK_INT(run("info", out, sizeof out), 0);
    CHECK_STR_CONTAINS(out, "driver:");
    CHECK_STR_CONTAINS(out, "api version:  1.");
    CHECK_STR_CONTAINS(out, "subgroup size: ");
    CHECK_STR_CONTAINS(out, "ray query:    ");
    CHECK_STR_CONTAINS(out, "memory types: ");
    if (!on_lavapipe())
        return;
    CHECK_STR_CONTAINS(out, "device:       llvmpipe");
    CHECK_STR_CONTAINS(out, "type:         cpu");
    /* lavapipe 22.3: a subgroup is a vector's lanes, and there are no ray queries. */
    unsigned lanes = lavapipe_lanes(out);
    char want[64];
    snprintf(want, sizeof want, "subgroup size: %u\n", lanes);
    CHECK(lanes >= 4);
    CHECK_STR_CONTAINS(out, want);
    CHECK_STR_CONTAINS(out, "ray query:    no");
    CHECK_STR_CONTAINS(out, "device memory:");
    /* One memory type with every property: every buffer gets it (render/gpu/gpu_buffer.c). */
    CHECK_STR_CONTAINS(out, "memory types: device-local+host-visible+coherent+cached\n");
}

static void test_json(void)
{
    char out[4096];
    if (!on_lavapipe())
        SKIP("lavapipe is not installed here (a GPU's machine): nothing of its to check");
    CHECK_INT(run("info --json --device llvmpipe", out, sizeof out), 0);
    CHECK_STR_CONTAINS(out, "\"device\":\"llvmpipe");
    CHECK_STR_CONTAINS(out, "\"is_cpu\":true");
    CHECK_STR_CONTAINS(out, "\"api_version\":\"1.");
    char want[64];
    snprintf(want, sizeof want, "\"subgroup_size\":%u,", lavapipe_lanes(out));
    CHECK_STR_CONTAINS(out, want);
    CHECK_STR_CONTAINS(out, "\"ray_query\":false");
    CHECK_STR_CONTAINS(out, "\"ray_tracing_pipeline\":false");
    CHECK_STR_CONTAINS(out, "\"device_local_bytes\":");
    CHECK_STR_CONTAINS(out, "\"memory_types\":[\"device-local+host-visible+coherent+cached\"]");
}

static void test_missing_device(void)
{
    char out[4096];
    CHECK_INT(run("info --device no-such-gpu-anywhere", out, sizeof out), 1);
    CHECK_STR_CONTAINS(out, "no Vulkan device named like 'no-such-gpu-anywhere'");
    CHECK_INT(run("info --device 99", out, sizeof out), 1);
    CHECK_STR_CONTAINS(out, "device index 99 out of range");
}

static void test_bad_usage(void)
{
    char out[4096];
    CHECK_INT(run("info --frobnicate", out, sizeof out), 2);
    CHECK_STR_CONTAINS(out, "usage: nscatter info");
    CHECK_INT(run("info --device", out, sizeof out), 2);
}

int main(void)
{
    /* The binary under test, never whatever `nscatter` the PATH holds. */
    bin = getenv("NSCATTER_BIN");
    if (!bin || !*bin) {
        fprintf(stderr, "FAIL: NSCATTER_BIN is not set: run this test through ctest\n");
        return 1;
    }
    /* These checks are about the default device, and the binary would read NSCATTER_DEVICE
     * (set by whoever runs the tests on another device) as a choice of device: its children
     * must not see it. */
    unsetenv("NSCATTER_DEVICE");
    RUN(test_text);
    RUN(test_json);
    RUN(test_missing_device);
    RUN(test_bad_usage);
    return harness_report();
}
