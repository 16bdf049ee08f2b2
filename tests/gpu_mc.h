/* gpu_mc.h — a GPU test's second context, with the Monte Carlo table provider attached (the
 * one `serve` and `render` pass): method "table" renders through it. Its tables are computed
 * once per material and kept in NSCATTER_CACHE_DIR, which ctest points at the build folder.
 * A program that includes this links nscatter_offline (tests/CMakeLists.txt). */
#ifndef NS_TEST_GPU_MC_H
#define NS_TEST_GPU_MC_H

#include "gpu_util.h"
#include "mc_provider.h"

static ns_context *mc_test_context_made;

/* Made on the first call; mc_test_context_destroy frees it before exit. */
static inline ns_context *mc_test_context(void)
{
    if (!mc_test_context_made) {
        ns_context_desc desc = {0};
        ns_mc_provider_attach(&desc);
        ns_error err = {0};
        int status = ns_context_create(&desc, &mc_test_context_made, &err);
        if (status) {
            fprintf(stderr, "ns_context_create: %s (%s)\n", err.message, ns_status_name(status));
            exit(1);
        }
    }
    return mc_test_context_made;
}

static inline void mc_test_context_destroy(void)
{
    if (mc_test_context_made)
        ns_context_destroy(mc_test_context_made);
    mc_test_context_made = NULL;
}

#endif
