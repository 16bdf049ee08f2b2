/* gpu_dispatch.c — one compute dispatch, submitted and waited for. Everything it makes
 * (descriptor pool and set, command buffer, fence) is freed before it returns, on every
 * path, so a failed request leaves nothing behind. */
#include <string.h>

#include "gpu.h"

typedef struct dispatch_objects {
    VkDescriptorPool pool;
    VkBufferView views[GPU_MAX_BINDINGS]; /* of the texel bindings */
    VkCommandBuffer cmd;
    VkFence fence;
    VkQueryPool timestamps; /* two, around the dispatches, when the caller asks for the time */
} dispatch_objects;

static void destroy_objects(gpu_device *dev, dispatch_objects *o)
{
    if (o->fence)
        vkDestroyFence(dev->device, o->fence, NULL);
    if (o->cmd)
        vkFreeCommandBuffers(dev->device, dev->command_pool, 1, &o->cmd);
    if (o->pool)
        vkDestroyDescriptorPool(dev->device, o->pool, NULL); /* frees its sets */
    for (uint32_t i = 0; i < GPU_MAX_BINDINGS; i++)
        if (o->views[i])
            vkDestroyBufferView(dev->device, o->views[i], NULL);
    if (o->timestamps)
        vkDestroyQueryPool(dev->device, o->timestamps, NULL);
}

/* The two timestamps' query pool, made only when the caller asks for the device time and
 * the queue has timestamps. */
static int make_timestamps(gpu_device *dev, const gpu_dispatch_desc *desc, dispatch_objects *o,
                           ns_error *err)
{
    if (!desc->device_ms || !dev->timestamp_bits)
        return NS_OK;
    VkQueryPoolCreateInfo info = {
        .sType = VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO,
        .queryType = VK_QUERY_TYPE_TIMESTAMP,
        .queryCount = 2,
    };
    return gpu_check(vkCreateQueryPool(dev->device, &info, NULL, &o->timestamps),
                     "vkCreateQueryPool", err);
}

/* After the fence: the device time between the two timestamps, in ms. */
static int read_timestamps(gpu_device *dev, const dispatch_objects *o, double *device_ms,
                           ns_error *err)
{
    if (!o->timestamps) {
        *device_ms = -1.0;
        return NS_OK;
    }
    uint64_t ticks[2] = {0, 0};
    int status = gpu_check(vkGetQueryPoolResults(dev->device, o->timestamps, 0, 2, sizeof ticks,
                                                 ticks, sizeof ticks[0],
                                                 VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT),
                           "vkGetQueryPoolResults", err);
    if (status)
        return status;
    uint64_t mask = dev->timestamp_bits >= 64 ? ~0ull : (1ull << dev->timestamp_bits) - 1;
    uint64_t elapsed = ((ticks[1] & mask) - (ticks[0] & mask)) & mask;
    *device_ms = (double)elapsed * dev->properties.limits.timestampPeriod * 1e-6;
    return NS_OK;
}

static int write_descriptors(gpu_device *dev, const gpu_pipeline *pipe, dispatch_objects *o,
                             gpu_buffer *const *buffers, VkDescriptorSet *set, ns_error *err)
{
    VkDescriptorPoolSize sizes[3] = {
        {VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER, 1},
        {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, GPU_MAX_BINDINGS},
        {VK_DESCRIPTOR_TYPE_STORAGE_TEXEL_BUFFER, GPU_MAX_BINDINGS},
    };
    VkDescriptorPoolCreateInfo pool = {
        .sType = VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO,
        .maxSets = 1,
        .poolSizeCount = 3,
        .pPoolSizes = sizes,
    };
    int status = gpu_check(vkCreateDescriptorPool(dev->device, &pool, NULL, &o->pool),
                           "vkCreateDescriptorPool", err);
    if (status)
        return status;
    VkDescriptorSetAllocateInfo alloc = {
        .sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO,
        .descriptorPool = o->pool,
        .descriptorSetCount = 1,
        .pSetLayouts = &pipe->set_layout,
    };
    status = gpu_check(vkAllocateDescriptorSets(dev->device, &alloc, set),
                       "vkAllocateDescriptorSets", err);
    if (status)
        return status;
    VkDescriptorBufferInfo infos[GPU_MAX_BINDINGS];
    VkWriteDescriptorSet writes[GPU_MAX_BINDINGS];
    for (uint32_t i = 0; i < pipe->binding_count; i++) {
        VkDescriptorType type = gpu_binding_type(pipe, i);
        infos[i] = (VkDescriptorBufferInfo){buffers[i]->buffer, 0, VK_WHOLE_SIZE};
        writes[i] = (VkWriteDescriptorSet){
            .sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET,
            .dstSet = *set,
            .dstBinding = i,
            .descriptorCount = 1,
            .descriptorType = type,
            .pBufferInfo = &infos[i],
        };
        if (type != VK_DESCRIPTOR_TYPE_STORAGE_TEXEL_BUFFER)
            continue;
        /* Whole texels only: the view's range is a multiple of the texel (a buffer smaller
         * than one texel gets one, which its shader never reads). */
        int r32 = (pipe->texel_r32_bindings >> i) & 1u;
        VkDeviceSize texel_bytes = r32 ? 4 : 16, texels = buffers[i]->size / texel_bytes;
        VkBufferViewCreateInfo view = {
            .sType = VK_STRUCTURE_TYPE_BUFFER_VIEW_CREATE_INFO,
            .buffer = buffers[i]->buffer,
            .format = r32 ? VK_FORMAT_R32_UINT : VK_FORMAT_R32G32B32A32_UINT,
            .offset = 0,
            .range = (texels ? texels : 1) * texel_bytes,
        };
        if (texels > dev->properties.limits.maxTexelBufferElements)
            return ns_fail(err, NS_ERR_LIMIT,
                           "%s: binding %u holds %llu texels, the device's texel buffers %u",
                           pipe->name, i, (unsigned long long)texels,
                           dev->properties.limits.maxTexelBufferElements);
        status = gpu_check(vkCreateBufferView(dev->device, &view, NULL, &o->views[i]),
                           "vkCreateBufferView", err);
        if (status)
            return status;
        writes[i].pBufferInfo = NULL;
        writes[i].pTexelBufferView = &o->views[i];
    }
    vkUpdateDescriptorSets(dev->device, pipe->binding_count, writes, 0, NULL);
    return NS_OK;
}

/* A one-time command buffer, begun. */
static int begin_commands(gpu_device *dev, dispatch_objects *o, ns_error *err)
{
    VkCommandBufferAllocateInfo alloc = {
        .sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO,
        .commandPool = dev->command_pool,
        .level = VK_COMMAND_BUFFER_LEVEL_PRIMARY,
        .commandBufferCount = 1,
    };
    int status = gpu_check(vkAllocateCommandBuffers(dev->device, &alloc, &o->cmd),
                           "vkAllocateCommandBuffers", err);
    if (status)
        return status;
    VkCommandBufferBeginInfo begin = {
        .sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO,
        .flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT,
    };
    return gpu_check(vkBeginCommandBuffer(o->cmd, &begin), "vkBeginCommandBuffer", err);
}

/* Submits the recorded commands and waits for them. No timeout: the buffers may not be
 * freed while the device could still use them. */
static int submit_and_wait(gpu_device *dev, dispatch_objects *o, ns_error *err)
{
    VkFenceCreateInfo fence = {.sType = VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
    int status = gpu_check(vkCreateFence(dev->device, &fence, NULL, &o->fence), "vkCreateFence", err);
    VkSubmitInfo submit = {
        .sType = VK_STRUCTURE_TYPE_SUBMIT_INFO,
        .commandBufferCount = 1,
        .pCommandBuffers = &o->cmd,
    };
    if (!status)
        status = gpu_check(vkQueueSubmit(dev->queue, 1, &submit, o->fence), "vkQueueSubmit", err);
    if (!status)
        dev->submissions++;
    if (!status)
        status = gpu_check(vkWaitForFences(dev->device, 1, &o->fence, VK_TRUE, UINT64_MAX),
                           "vkWaitForFences", err);
    return status;
}

/* Every device submission starts here (a dispatch or a copy): a cancelled render stops
 * before its next one, with nothing made that would need freeing. The validation count is
 * taken to compare after. */
static int submission_begin(gpu_device *dev, dispatch_objects *o, uint32_t *validation_before,
                            ns_error *err)
{
    memset(o, 0, sizeof *o);
    *validation_before = gpu_validation_count(dev);
    return gpu_cancel_check(dev, err);
}

/* ... and ends here: what it made freed on every path, and any validation message since it
 * began turned into its error. */
static int submission_end(gpu_device *dev, dispatch_objects *o, int status,
                          uint32_t validation_before, ns_error *err)
{
    destroy_objects(dev, o);
    if (!status)
        status = gpu_validation_check(dev, validation_before, err);
    return status;
}

static int record(gpu_device *dev, const gpu_dispatch_desc *desc, dispatch_objects *o,
                  VkDescriptorSet set, ns_error *err)
{
    const gpu_pipeline *pipe = desc->pipeline;
    uint32_t count = desc->dispatch_count ? desc->dispatch_count : 1;
    int status = begin_commands(dev, o, err);
    if (status)
        return status;
    vkCmdBindPipeline(o->cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe->pipeline);
    vkCmdBindDescriptorSets(o->cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe->layout, 0, 1, &set, 0,
                            NULL);
    if (o->timestamps) {
        vkCmdResetQueryPool(o->cmd, o->timestamps, 0, 2);
        vkCmdWriteTimestamp(o->cmd, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, o->timestamps, 0);
    }
    /* Dispatches that follow one another read what the previous one wrote. */
    VkMemoryBarrier between = {
        .sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER,
        .srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT,
        .dstAccessMask = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT,
    };
    for (uint32_t i = 0; i < count; i++) {
        if (i > 0)
            vkCmdPipelineBarrier(o->cmd, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                                 VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, 0, 1, &between, 0, NULL, 0,
                                 NULL);
        if (pipe->push_constant_size)
            vkCmdPushConstants(o->cmd, pipe->layout, VK_SHADER_STAGE_COMPUTE_BIT, 0,
                               pipe->push_constant_size,
                               (const uint8_t *)desc->push + (size_t)i * pipe->push_constant_size);
        vkCmdDispatch(o->cmd, desc->groups[0], desc->groups[1], desc->groups[2]);
    }
    if (o->timestamps)
        vkCmdWriteTimestamp(o->cmd, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, o->timestamps, 1);
    /* Make the shader's writes visible to the host reads that follow the fence. */
    VkMemoryBarrier barrier = {
        .sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER,
        .srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT,
        .dstAccessMask = VK_ACCESS_HOST_READ_BIT,
    };
    vkCmdPipelineBarrier(o->cmd, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_PIPELINE_STAGE_HOST_BIT,
                         0, 1, &barrier, 0, NULL, 0, NULL);
    return gpu_check(vkEndCommandBuffer(o->cmd), "vkEndCommandBuffer", err);
}

int gpu_cancel_check(gpu_device *dev, ns_error *err)
{
    /* Once seen (here, or by a progress report), it stays seen: a passed deadline has no
     * flag of its own that would be read again. */
    if (!dev->cancelled) {
        if (dev->deadline_ms > 0 && ns_now_ms() >= dev->deadline_ms)
            dev->deadline_hit = 1;
        else if (!dev->cancel || !__atomic_load_n(dev->cancel, __ATOMIC_ACQUIRE))
            return NS_OK;
        dev->cancelled = 1;
    }
    return ns_fail(err, NS_ERR_CANCELLED, "cancelled");
}

int gpu_dispatch(gpu_device *dev, const gpu_pipeline *pipe, gpu_buffer *const *buffers,
                 uint32_t buffer_count, const uint32_t groups[3], ns_error *err)
{
    return gpu_dispatch_many(dev,
                             &(gpu_dispatch_desc){.pipeline = pipe,
                                                  .buffers = buffers,
                                                  .buffer_count = buffer_count,
                                                  .groups = {groups[0], groups[1], groups[2]}},
                             err);
}

int gpu_dispatch_many(gpu_device *dev, const gpu_dispatch_desc *desc, ns_error *err)
{
    const gpu_pipeline *pipe = desc->pipeline;
    gpu_buffer *const *buffers = desc->buffers;
    const uint32_t *groups = desc->groups;
    if (desc->buffer_count != pipe->binding_count)
        return ns_fail(err, NS_ERR_INTERNAL, "pipeline %s takes %u buffers, got %u", pipe->name,
                       pipe->binding_count, desc->buffer_count);
    if (pipe->push_constant_size && !desc->push)
        return ns_fail(err, NS_ERR_INTERNAL, "pipeline %s needs push constants", pipe->name);
    const uint32_t *max_groups = dev->properties.limits.maxComputeWorkGroupCount;
    for (int i = 0; i < 3; i++)
        if (groups[i] == 0 || groups[i] > max_groups[i])
            return ns_fail(err, NS_ERR_LIMIT,
                           "dispatch of %s: %u groups in dimension %d (device allows %u)",
                           pipe->name, groups[i], i, max_groups[i]);
    dispatch_objects o;
    uint32_t validation_before;
    int status = submission_begin(dev, &o, &validation_before, err);
    if (status)
        return status;
    VkDescriptorSet set = VK_NULL_HANDLE;
    status = write_descriptors(dev, pipe, &o, buffers, &set, err);
    if (!status)
        status = make_timestamps(dev, desc, &o, err);
    if (!status)
        status = record(dev, desc, &o, set, err);
    if (!status)
        status = submit_and_wait(dev, &o, err);
    if (!status && desc->device_ms)
        status = read_timestamps(dev, &o, desc->device_ms, err);
    return submission_end(dev, &o, status, validation_before, err);
}

int gpu_copy_buffer(gpu_device *dev, const gpu_buffer *src, gpu_buffer *dst, VkDeviceSize bytes,
                    ns_error *err)
{
    if (bytes > src->size || bytes > dst->size)
        return ns_fail(err, NS_ERR_INTERNAL, "copy of %llu bytes between buffers of %llu and %llu",
                       (unsigned long long)bytes, (unsigned long long)src->size,
                       (unsigned long long)dst->size);
    dispatch_objects o;
    uint32_t validation_before;
    int status = submission_begin(dev, &o, &validation_before, err);
    if (!status)
        status = begin_commands(dev, &o, err);
    if (!status) {
        /* The shaders' earlier writes to src (an earlier submission's) are made visible to
         * the copy; the host's writes are, by the submission itself. The copy's writes are
         * made visible to the host's reads after the fence. */
        VkMemoryBarrier before = {
            .sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER,
            .srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT,
            .dstAccessMask = VK_ACCESS_TRANSFER_READ_BIT,
        };
        vkCmdPipelineBarrier(o.cmd, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT,
                             0, 1, &before, 0, NULL, 0, NULL);
        vkCmdCopyBuffer(o.cmd, src->buffer, dst->buffer, 1,
                        &(VkBufferCopy){.srcOffset = 0, .dstOffset = 0, .size = bytes});
        VkMemoryBarrier barrier = {
            .sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER,
            .srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT,
            .dstAccessMask = VK_ACCESS_HOST_READ_BIT,
        };
        vkCmdPipelineBarrier(o.cmd, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_HOST_BIT, 0, 1,
                             &barrier, 0, NULL, 0, NULL);
        status = gpu_check(vkEndCommandBuffer(o.cmd), "vkEndCommandBuffer", err);
    }
    if (!status)
        status = submit_and_wait(dev, &o, err);
    return submission_end(dev, &o, status, validation_before, err);
}
