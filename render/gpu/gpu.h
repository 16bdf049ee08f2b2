/* gpu.h — the Vulkan layer (private to render/). Only gpu_*.c call vk*; the rest of the
 * renderer sees these small objects. Every create has a destroy; every VkResult is checked
 * in every build and an error names it (as a VkResult string) and maps it to ns_status.
 *
 *   gpu_device.c    instance, device, queue, debug messenger, pipeline cache, labels
 *   gpu_buffer.c    host-visible buffers: create/destroy, upload by mapping, readback, the
 *                   memory type each gets (host-cached for what the host reads back)
 *   gpu_pipeline.c  compute pipelines from the embedded SPIR-V
 *   gpu_dispatch.c  one-shot dispatch: descriptor set, command buffer, submit, wait; and
 *                   one-shot buffer copies on the device
 */
#ifndef NS_GPU_H
#define NS_GPU_H

#include <vulkan/vulkan.h>

#include "nscatter.h"


/* Embedded SPIR-V (generated registry: the build folder's shaders/shader_registry.c). */
const uint32_t *ns_shader_code(const char *name, size_t *size_bytes);

/* ---------------------------------------------------------------------------------------
 * Device
 * ------------------------------------------------------------------------------------- */
typedef struct gpu_device_desc {
    const char *device; /* NULL/"" = lavapipe if present, else first; index or name part */
    int validation;     /* enable VK_LAYER_KHRONOS_validation + messenger */
    const char *pipeline_cache_path; /* NULL = in-memory pipeline cache only */
} gpu_device_desc;

typedef struct gpu_device {
    VkInstance instance;
    VkDebugUtilsMessengerEXT messenger;
    VkPhysicalDevice physical;
    VkDevice device;
    VkQueue queue;
    uint32_t queue_family;
    uint32_t timestamp_bits; /* the queue family's timestampValidBits: 0 = no timestamps */
    VkCommandPool command_pool;
    VkPipelineCache pipeline_cache;
    VkPhysicalDeviceProperties properties;
    VkPhysicalDeviceMemoryProperties memory;
    ns_device_info info;
    PFN_vkSetDebugUtilsObjectNameEXT set_object_name; /* NULL without VK_EXT_debug_utils */
    int validation;
    /* lavapipe: every shader invocation stops its loops after 65535 iterations in all. */
    int loop_limited;
    /* lavapipe: the threads among which it splits a dispatch's workgroups, one contiguous run
     * each (LP_NUM_THREADS, else the CPUs this process may run on, at most 16, as Mesa
     * counts them); 0 on other devices. Shaders interleave their groups by it (groups.glsl). */
    uint32_t cpu_threads;
    /* Invocations per subgroup in compute shaders: the exact gather walks its hierarchy once
     * per subgroup (votes), and its CPU reference groups segments the same way. */
    uint32_t subgroup_size;
    /* Tests: buffers not created with host_reads report host_cached = 0, as on a discrete
     * GPU, so that lavapipe runs the paths that copy them out first (gpu_copy_buffer). */
    int pretend_uncached;
    /* Validation warnings/errors seen so far (written by the messenger callback). */
    uint32_t validation_messages;
    char last_validation_message[384];
    /* Buffers alive right now: a finished render must bring it back to where it was. */
    uint32_t live_buffers;
    /* Cancellation of the render in progress (ns_render_controlled sets it for the render's
     * duration and clears it on every path; NULL otherwise): while *cancel is nonzero
     * (written by another thread, read with an acquire load) gpu_cancel_check fails, and so
     * does every gpu_dispatch_many before it submits anything. `cancelled` records that the
     * flag was seen set (by a check, or by the render's progress reports), so that the render
     * reports nothing new after it and ends cancelled; the render clears it. */
    const int *cancel;
    int cancelled;
    /* The render's deadline on ns_now_ms()'s clock (0: none): past it gpu_cancel_check fails
     * as for a cancellation, and deadline_hit says why. */
    double deadline_ms;
    int deadline_hit;
    /* vkQueueSubmit calls made so far (the tests count what a cancelled render submitted). */
    uint64_t submissions;
} gpu_device;

int gpu_device_create(gpu_device *dev, const gpu_device_desc *desc, ns_error *err);
void gpu_device_destroy(gpu_device *dev);

/* How many threads lavapipe splits a dispatch's workgroups among (gpu_device.cpu_threads). */
uint32_t gpu_lavapipe_threads(void);

/* Maps a VkResult to ns_status and fills err with "<what>: VK_ERROR_...". VK_SUCCESS is 0. */
int gpu_check(VkResult result, const char *what, ns_error *err);
const char *gpu_result_name(VkResult result);

/* NS_ERR_CANCELLED (and dev->cancelled = 1) when dev->cancel is set and *dev->cancel is
 * nonzero, or dev->deadline_ms has passed (dev->deadline_hit = 1), or either was seen
 * before; NS_OK otherwise. The message says only "cancelled": the render names the stage
 * and tells a deadline from a cancellation. */
int gpu_cancel_check(gpu_device *dev, ns_error *err);

/* Attaches a debug label to a Vulkan object when VK_EXT_debug_utils is available. */
void gpu_set_label(const gpu_device *dev, VkObjectType type, uint64_t handle, const char *label);

/* Fails with NS_ERR_VULKAN (naming the last message) if the validation layer reported
 * anything since `before` (a previous value of dev->validation_messages). */
int gpu_validation_check(gpu_device *dev, uint32_t before, ns_error *err);
uint32_t gpu_validation_count(gpu_device *dev);

/* Writes the pipeline cache to path (atomically: temporary file, then rename). */
int gpu_pipeline_cache_save(gpu_device *dev, const char *path, ns_error *err);

/* ---------------------------------------------------------------------------------------
 * Buffers: host-visible and coherent (device-local too where the device offers it), mapped
 * for their whole life, so upload is a memcpy and readback reads the mapping.
 * ------------------------------------------------------------------------------------- */
typedef enum { GPU_BUFFER_STORAGE = 0, GPU_BUFFER_UNIFORM = 1 } gpu_buffer_kind;

typedef struct gpu_buffer_desc {
    VkDeviceSize size; /* bytes; 0 is rounded up to 16 so a binding is always valid */
    gpu_buffer_kind kind;
    const void *data; /* copied in when not NULL (data_size bytes); the rest is zeroed */
    VkDeviceSize data_size;
    int uninitialized; /* skip zeroing: the GPU writes every byte that is read back */
    /* The host reads this buffer in bulk (images, segments, reconstructed tables): it goes
     * in host-cached memory where the device offers it. On a discrete GPU the default,
     * device-local memory mapped through the BAR, is write-combined and uncached, and the
     * CPU's loops over it read a few MB/s (docs/bench.md, *On an NVIDIA GPU*); the GPU writes
     * such a buffer once, or once per dispatch, over PCIe. Leave it 0 for buffers the GPU
     * reads heavily or updates with atomics. lavapipe has one memory type: no change. */
    int host_reads;
    const char *label;
} gpu_buffer_desc;

typedef struct gpu_buffer {
    VkBuffer buffer;
    VkDeviceMemory memory;
    void *mapped;
    VkDeviceSize size;
    gpu_buffer_kind kind;
    /* The mapping is host-cached: the host may read it in bulk (lavapipe: every buffer). A
     * buffer without it is read through gpu_copy_buffer into a host_reads one. */
    int host_cached;
} gpu_buffer;

int gpu_buffer_create(gpu_device *dev, gpu_buffer *buf, const gpu_buffer_desc *desc, ns_error *err);
/* The memory type a buffer gets among those `allowed` (a bit per type): host-visible and
 * coherent always; of those, the first host-cached one for a buffer the host reads
 * (host_reads), else the first device-local one; else the first host-visible, coherent one.
 * 0 when there is none. */
int gpu_pick_memory_type(const VkPhysicalDeviceMemoryProperties *memory, uint32_t allowed,
                         int host_reads, uint32_t *index);
void gpu_buffer_destroy(gpu_device *dev, gpu_buffer *buf); /* zeroed or destroyed: no-op */
/* Copies the first `bytes` of src into dst on the device, submitted and waited for (one
 * command buffer, freed on every path), dst's writes visible to the host after. */
int gpu_copy_buffer(gpu_device *dev, const gpu_buffer *src, gpu_buffer *dst, VkDeviceSize bytes,
                    ns_error *err);
/* Creates bufs[0..count) from descs, stopping at the first failure. The buffers made
 * before it stay alive: the caller destroys all count of them on every path (a buffer that
 * was never made is zeroed, and destroying it is a no-op). */
int gpu_buffers_create(gpu_device *dev, gpu_buffer *bufs, const gpu_buffer_desc *descs, int count,
                       ns_error *err);

/* ---------------------------------------------------------------------------------------
 * Compute pipelines. Binding 0 is a uniform buffer, bindings 1..binding_count-1 are
 * storage buffers (the layout every shader in shaders/ follows).
 * ------------------------------------------------------------------------------------- */
#define GPU_MAX_BINDINGS 9 /* camera.comp's: the scene, pixels, segments, counters, added samples */

typedef struct gpu_pipeline_desc {
    const char *shader; /* name in the shader registry (file name without .comp) */
    uint32_t binding_count;
    uint32_t push_constant_size; /* bytes, 0 = none */
    /* Bit i: binding i is a storage texel buffer over the whole buffer (a readonly
     * uimageBuffer in the shader, read with imageLoad: on lavapipe cheaper than a uniform
     * texel buffer's texelFetch, docs/bench.md), not a storage buffer: of 16-byte texels
     * (VK_FORMAT_R32G32B32A32_UINT, rgba32ui), or of 4-byte ones (VK_FORMAT_R32_UINT, r32ui)
     * where the bit is also set in texel_r32_bindings. */
    uint32_t texel_bindings;
    uint32_t texel_r32_bindings;
} gpu_pipeline_desc;

typedef struct gpu_pipeline {
    VkDescriptorSetLayout set_layout;
    VkPipelineLayout layout;
    VkPipeline pipeline;
    uint32_t binding_count;
    uint32_t push_constant_size;
    uint32_t texel_bindings, texel_r32_bindings; /* as in gpu_pipeline_desc */
    char name[32];
} gpu_pipeline;

int gpu_pipeline_create(gpu_device *dev, gpu_pipeline *pipe, const gpu_pipeline_desc *desc,
                        ns_error *err);
/* The descriptor type of binding i: 0 a uniform buffer, a texel binding a storage texel
 * buffer, every other a storage buffer. */
VkDescriptorType gpu_binding_type(const gpu_pipeline *pipe, uint32_t i);
void gpu_pipeline_destroy(gpu_device *dev, gpu_pipeline *pipe);

/* Records one dispatch of pipe over groups[0..2] with buffers bound in order, submits it and
 * waits. Owns (and always frees) its descriptor pool, command buffer and fence. Fails with
 * NS_ERR_CANCELLED, having made and submitted nothing, when gpu_cancel_check does: the one
 * point where a render's cancellation stops the device work. */
int gpu_dispatch(gpu_device *dev, const gpu_pipeline *pipe, gpu_buffer *const *buffers,
                 uint32_t buffer_count, const uint32_t groups[3], ns_error *err);

/* The same, but dispatch_count dispatches in one submission, each with its own block of
 * pipe->push_constant_size bytes from push (dispatch_count blocks) and a barrier between
 * them so each sees the previous one's writes. */
typedef struct gpu_dispatch_desc {
    const gpu_pipeline *pipeline;
    gpu_buffer *const *buffers;
    uint32_t buffer_count;
    uint32_t groups[3];
    const void *push;
    uint32_t dispatch_count; /* 0 means 1 */
    /* Not NULL: set to the device time in ms from before the first dispatch to after the
     * last, read from two timestamp queries around them (benchmarks: bench/rays.c), or to
     * -1 where the queue has no timestamps. NULL (every render): no queries. */
    double *device_ms;
} gpu_dispatch_desc;

int gpu_dispatch_many(gpu_device *dev, const gpu_dispatch_desc *desc, ns_error *err);

/* Dispatches pipe once on small dummy buffers so the driver compiles it now (lavapipe
 * compiles on first use) rather than inside the first request. */
int gpu_pipeline_warm(gpu_device *dev, const gpu_pipeline *pipe, ns_error *err);

#endif
