/* gpu_pipeline.c — compute pipelines from the embedded SPIR-V, and their warm-up. */
#include <stdio.h>
#include <string.h>

#include "gpu.h"
#include "shared.h" /* NS_SPEC_CPU_THREADS */

VkDescriptorType gpu_binding_type(const gpu_pipeline *pipe, uint32_t i)
{
    if (i == 0)
        return VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER;
    return (pipe->texel_bindings >> i) & 1u ? VK_DESCRIPTOR_TYPE_STORAGE_TEXEL_BUFFER
                                            : VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
}

static int create_set_layout(gpu_device *dev, gpu_pipeline *pipe, ns_error *err)
{
    VkDescriptorSetLayoutBinding bindings[GPU_MAX_BINDINGS];
    for (uint32_t i = 0; i < pipe->binding_count; i++) {
        bindings[i] = (VkDescriptorSetLayoutBinding){
            .binding = i,
            .descriptorType = gpu_binding_type(pipe, i),
            .descriptorCount = 1,
            .stageFlags = VK_SHADER_STAGE_COMPUTE_BIT,
        };
    }
    VkDescriptorSetLayoutCreateInfo info = {
        .sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO,
        .bindingCount = pipe->binding_count,
        .pBindings = bindings,
    };
    return gpu_check(vkCreateDescriptorSetLayout(dev->device, &info, NULL, &pipe->set_layout),
                     "vkCreateDescriptorSetLayout", err);
}

int gpu_pipeline_create(gpu_device *dev, gpu_pipeline *pipe, const gpu_pipeline_desc *desc,
                        ns_error *err)
{
    memset(pipe, 0, sizeof *pipe);
    if (desc->binding_count == 0 || desc->binding_count > GPU_MAX_BINDINGS ||
        desc->push_constant_size > 128 || desc->push_constant_size % 4)
        return ns_fail(err, NS_ERR_INTERNAL, "pipeline %s: %u bindings", desc->shader,
                       desc->binding_count);
    size_t code_size = 0;
    const uint32_t *code = ns_shader_code(desc->shader, &code_size);
    if (!code)
        return ns_fail(err, NS_ERR_INTERNAL, "shader '%s' is not embedded in this build",
                       desc->shader);
    snprintf(pipe->name, sizeof pipe->name, "%s", desc->shader);
    pipe->binding_count = desc->binding_count;
    pipe->push_constant_size = desc->push_constant_size;
    pipe->texel_bindings = desc->texel_bindings;
    pipe->texel_r32_bindings = desc->texel_r32_bindings & desc->texel_bindings;

    int status = create_set_layout(dev, pipe, err);
    VkPushConstantRange push = {VK_SHADER_STAGE_COMPUTE_BIT, 0, desc->push_constant_size};
    VkPipelineLayoutCreateInfo layout = {
        .sType = VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO,
        .setLayoutCount = 1,
        .pSetLayouts = &pipe->set_layout,
        .pushConstantRangeCount = desc->push_constant_size ? 1 : 0,
        .pPushConstantRanges = &push,
    };
    if (!status)
        status = gpu_check(vkCreatePipelineLayout(dev->device, &layout, NULL, &pipe->layout),
                           "vkCreatePipelineLayout", err);
    VkShaderModule module = VK_NULL_HANDLE;
    VkShaderModuleCreateInfo module_info = {
        .sType = VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO,
        .codeSize = code_size,
        .pCode = code,
    };
    if (!status)
        status = gpu_check(vkCreateShaderModule(dev->device, &module_info, NULL, &module),
                           "vkCreateShaderModule", err);
    /* Every pipeline gets the device's specialisation constants (a shader that declares none
     * ignores them): constant_id NS_SPEC_CPU_THREADS, lavapipe's threads (groups.glsl). */
    uint32_t spec_values[1] = {dev->cpu_threads};
    VkSpecializationMapEntry spec_entries[1] = {
        {.constantID = NS_SPEC_CPU_THREADS, .offset = 0, .size = sizeof(uint32_t)}};
    VkSpecializationInfo spec = {.mapEntryCount = 1,
                                 .pMapEntries = spec_entries,
                                 .dataSize = sizeof spec_values,
                                 .pData = spec_values};
    if (!status) {
        VkComputePipelineCreateInfo info = {
            .sType = VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO,
            .stage =
                {
                    .sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO,
                    .stage = VK_SHADER_STAGE_COMPUTE_BIT,
                    .module = module,
                    .pName = "main",
                    .pSpecializationInfo = &spec,
                },
            .layout = pipe->layout,
        };
        status = gpu_check(vkCreateComputePipelines(dev->device, dev->pipeline_cache, 1, &info,
                                                    NULL, &pipe->pipeline),
                           "vkCreateComputePipelines", err);
    }
    if (module)
        vkDestroyShaderModule(dev->device, module, NULL);
    if (status) {
        gpu_pipeline_destroy(dev, pipe);
        return status;
    }
    char label[64];
    snprintf(label, sizeof label, "ns.pipeline.%s", pipe->name);
    gpu_set_label(dev, VK_OBJECT_TYPE_PIPELINE, (uint64_t)pipe->pipeline, label);
    snprintf(label, sizeof label, "ns.layout.%s", pipe->name);
    gpu_set_label(dev, VK_OBJECT_TYPE_PIPELINE_LAYOUT, (uint64_t)pipe->layout, label);
    gpu_set_label(dev, VK_OBJECT_TYPE_DESCRIPTOR_SET_LAYOUT, (uint64_t)pipe->set_layout, label);
    return NS_OK;
}

void gpu_pipeline_destroy(gpu_device *dev, gpu_pipeline *pipe)
{
    if (pipe->pipeline)
        vkDestroyPipeline(dev->device, pipe->pipeline, NULL);
    if (pipe->layout)
        vkDestroyPipelineLayout(dev->device, pipe->layout, NULL);
    if (pipe->set_layout)
        vkDestroyDescriptorSetLayout(dev->device, pipe->set_layout, NULL);
    memset(pipe, 0, sizeof *pipe);
}

int gpu_pipeline_warm(gpu_device *dev, const gpu_pipeline *pipe, ns_error *err)
{
    /* All-zero buffers: every shader reads its sizes from binding 0 and returns at once when
     * they are zero, but the driver still has to compile the whole pipeline to run it. */
    gpu_buffer buffers[GPU_MAX_BINDINGS];
    gpu_buffer *bound[GPU_MAX_BINDINGS];
    memset(buffers, 0, sizeof buffers);
    int status = NS_OK;
    for (uint32_t i = 0; i < pipe->binding_count && !status; i++) {
        status = gpu_buffer_create(
            dev, &buffers[i],
            &(gpu_buffer_desc){.size = 256,
                               .kind = i == 0 ? GPU_BUFFER_UNIFORM : GPU_BUFFER_STORAGE,
                               .label = "ns.warm"},
            err);
        bound[i] = &buffers[i];
    }
    uint8_t zeros[128] = {0};
    if (!status)
        status = gpu_dispatch_many(dev,
                                   &(gpu_dispatch_desc){.pipeline = pipe,
                                                        .buffers = bound,
                                                        .buffer_count = pipe->binding_count,
                                                        .groups = {1, 1, 1},
                                                        .push = zeros},
                                   err);
    for (uint32_t i = 0; i < pipe->binding_count; i++)
        gpu_buffer_destroy(dev, &buffers[i]);
    return status;
}
