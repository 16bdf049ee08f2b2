/* unit_memory_types.c — which memory type a buffer gets (gpu_pick_memory_type), on the
 * memory layouts of the two drivers nscatter has run on. On NVIDIA's (the H200, driver
 * 580) a buffer that the host reads back in bulk must land in host-cached system memory:
 * the device-local type it had before is mapped write-combined and uncached through the BAR,
 * and the CPU's loops over segments and images there made a 512² render take 21 s
 * (docs/bench.md, *On an NVIDIA GPU*). On lavapipe's single type nothing may change. */
#include "gpu.h"
#include "harness.h"

enum {
    LOCAL = VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT,
    VISIBLE = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT,
    CACHED = VK_MEMORY_PROPERTY_HOST_CACHED_BIT,
};

static VkPhysicalDeviceMemoryProperties layout(const VkMemoryPropertyFlags *flags, uint32_t count)
{
    VkPhysicalDeviceMemoryProperties m = {.memoryTypeCount = count, .memoryHeapCount = 1};
    for (uint32_t i = 0; i < count; i++)
        m.memoryTypes[i].propertyFlags = flags[i];
    return m;
}

static uint32_t pick(const VkPhysicalDeviceMemoryProperties *m, uint32_t allowed, int host_reads)
{
    uint32_t index = 99;
    return gpu_pick_memory_type(m, allowed, host_reads, &index) ? index : 99;
}

/* A discrete NVIDIA GPU with resizable BAR: device-only, host memory, host-cached host
 * memory, device memory mapped through the BAR. */
static void test_discrete_gpu(void)
{
    const VkMemoryPropertyFlags flags[] = {LOCAL, VISIBLE, VISIBLE | CACHED, LOCAL | VISIBLE};
    VkPhysicalDeviceMemoryProperties m = layout(flags, 4);
    CHECK_INT(pick(&m, 0xf, 0), 3); /* the GPU's buffers: its own memory, still mapped */
    CHECK_INT(pick(&m, 0xf, 1), 2); /* read back by the host: cached host memory */
    CHECK_INT(pick(&m, 0x3, 1), 1); /* no cached type allowed: the first mappable one */
    CHECK_INT(pick(&m, 0x3, 0), 1);
    CHECK_INT(pick(&m, 0x1, 0), 99); /* nothing mappable: refused, never a device-only type */
}

/* lavapipe: one type with every flag; both kinds of buffer get it. */
static void test_lavapipe(void)
{
    const VkMemoryPropertyFlags flags[] = {LOCAL | VISIBLE | CACHED};
    VkPhysicalDeviceMemoryProperties m = layout(flags, 1);
    CHECK_INT(pick(&m, 0x1, 0), 0);
    CHECK_INT(pick(&m, 0x1, 1), 0);
}

/* Without a resizable BAR (no device-local mappable type) everything is host memory. */
static void test_no_bar(void)
{
    const VkMemoryPropertyFlags flags[] = {LOCAL, VISIBLE | CACHED, VISIBLE};
    VkPhysicalDeviceMemoryProperties m = layout(flags, 3);
    CHECK_INT(pick(&m, 0x7, 0), 1);
    CHECK_INT(pick(&m, 0x7, 1), 1);
}

int main(void)
{
    RUN(test_discrete_gpu);
    RUN(test_lavapipe);
    RUN(test_no_bar);
    return harness_report();
}
