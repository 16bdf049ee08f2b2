/* gpu_buffer.c — buffers in host-visible, coherent memory, mapped for their whole life.
 *
 * On lavapipe all memory is host memory, so a staging copy would only cost time. On a
 * discrete GPU a device-local + host-visible type is preferred when offered (resizable BAR);
 * otherwise the buffer lives in host memory the GPU reads over PCIe, which is correct but
 * slower (a staging path is future work, see docs/rendering.md). A buffer the host reads
 * back in bulk (gpu_buffer_desc.host_reads) prefers host-cached memory instead. */
#include <string.h>

#include "gpu.h"

int gpu_pick_memory_type(const VkPhysicalDeviceMemoryProperties *memory, uint32_t allowed,
                         int host_reads, uint32_t *index)
{
    const VkMemoryPropertyFlags required =
        VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    const VkMemoryPropertyFlags preferred =
        host_reads ? VK_MEMORY_PROPERTY_HOST_CACHED_BIT : VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT;
    int fallback = -1;
    for (uint32_t i = 0; i < memory->memoryTypeCount; i++) {
        VkMemoryPropertyFlags flags = memory->memoryTypes[i].propertyFlags;
        if (!(allowed & (1u << i)) || (flags & required) != required)
            continue;
        if ((flags & preferred) == preferred) {
            *index = i;
            return 1;
        }
        if (fallback < 0)
            fallback = (int)i;
    }
    if (fallback < 0)
        return 0;
    *index = (uint32_t)fallback;
    return 1;
}

int gpu_buffer_create(gpu_device *dev, gpu_buffer *buf, const gpu_buffer_desc *desc, ns_error *err)
{
    memset(buf, 0, sizeof *buf);
    VkDeviceSize size = desc->size < 16 ? 16 : (desc->size + 15) & ~(VkDeviceSize)15;
    VkDeviceSize limit = desc->kind == GPU_BUFFER_UNIFORM
                             ? dev->properties.limits.maxUniformBufferRange
                             : dev->properties.limits.maxStorageBufferRange;
    if (size > limit)
        return ns_fail(err, NS_ERR_LIMIT, "buffer '%s' needs %llu bytes; the device allows %llu",
                       desc->label ? desc->label : "?", (unsigned long long)size,
                       (unsigned long long)limit);
    buf->kind = desc->kind;
    buf->size = size;
    VkBufferCreateInfo info = {
        .sType = VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO,
        .size = size,
        /* A storage buffer may also be bound as a storage texel buffer (gpu_pipeline_desc's
         * texel_bindings), and copied from or into (gpu_copy_buffer). */
        .usage = desc->kind == GPU_BUFFER_UNIFORM
                     ? VK_BUFFER_USAGE_UNIFORM_BUFFER_BIT
                     : VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_STORAGE_TEXEL_BUFFER_BIT |
                           VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT,
        .sharingMode = VK_SHARING_MODE_EXCLUSIVE,
    };
    int status =
        gpu_check(vkCreateBuffer(dev->device, &info, NULL, &buf->buffer), "vkCreateBuffer", err);
    if (status)
        return status;
    __atomic_add_fetch(&dev->live_buffers, 1, __ATOMIC_SEQ_CST);
    gpu_set_label(dev, VK_OBJECT_TYPE_BUFFER, (uint64_t)buf->buffer, desc->label);

    VkMemoryRequirements req;
    vkGetBufferMemoryRequirements(dev->device, buf->buffer, &req);
    uint32_t type;
    if (!gpu_pick_memory_type(&dev->memory, req.memoryTypeBits, desc->host_reads, &type)) {
        gpu_buffer_destroy(dev, buf);
        return ns_fail(err, NS_ERR_VULKAN, "no host-visible coherent memory type for buffer '%s'",
                       desc->label ? desc->label : "?");
    }
    buf->host_cached =
        (dev->memory.memoryTypes[type].propertyFlags & VK_MEMORY_PROPERTY_HOST_CACHED_BIT) != 0 &&
        !(dev->pretend_uncached && !desc->host_reads);
    VkMemoryAllocateInfo alloc = {
        .sType = VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO,
        .allocationSize = req.size,
        .memoryTypeIndex = type,
    };
    status = gpu_check(vkAllocateMemory(dev->device, &alloc, NULL, &buf->memory),
                       "vkAllocateMemory", err);
    if (!status)
        status = gpu_check(vkBindBufferMemory(dev->device, buf->buffer, buf->memory, 0),
                           "vkBindBufferMemory", err);
    if (!status)
        status = gpu_check(vkMapMemory(dev->device, buf->memory, 0, VK_WHOLE_SIZE, 0, &buf->mapped),
                           "vkMapMemory", err);
    if (status) {
        gpu_buffer_destroy(dev, buf);
        return status;
    }
    gpu_set_label(dev, VK_OBJECT_TYPE_DEVICE_MEMORY, (uint64_t)buf->memory, desc->label);
    VkDeviceSize copied = 0;
    if (desc->data && desc->data_size) {
        copied = desc->data_size < size ? desc->data_size : size;
        memcpy(buf->mapped, desc->data, copied);
    }
    if (!desc->uninitialized)
        memset((char *)buf->mapped + copied, 0, size - copied);
    return NS_OK;
}

void gpu_buffer_destroy(gpu_device *dev, gpu_buffer *buf)
{
    if (buf->mapped)
        vkUnmapMemory(dev->device, buf->memory);
    if (buf->buffer) {
        vkDestroyBuffer(dev->device, buf->buffer, NULL);
        __atomic_sub_fetch(&dev->live_buffers, 1, __ATOMIC_SEQ_CST);
    }
    if (buf->memory)
        vkFreeMemory(dev->device, buf->memory, NULL);
    memset(buf, 0, sizeof *buf);
}

int gpu_buffers_create(gpu_device *dev, gpu_buffer *bufs, const gpu_buffer_desc *descs, int count,
                       ns_error *err)
{
    for (int i = 0; i < count; i++)
        memset(&bufs[i], 0, sizeof bufs[i]);
    for (int i = 0; i < count; i++) {
        int status = gpu_buffer_create(dev, &bufs[i], &descs[i], err);
        if (status)
            return status;
    }
    return NS_OK;
}
