/* gpu_device.c — instance, physical device choice, logical device and queue, the
 * validation messenger, debug labels and the pipeline cache. */
#define _GNU_SOURCE /* sched_getaffinity, CPU_COUNT */
#include <ctype.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gpu.h"

#define VALIDATION_LAYER "VK_LAYER_KHRONOS_validation"

/* =======================================================================================
 * VkResult names and their ns_status
 * ===================================================================================== */
const char *gpu_result_name(VkResult result)
{
    switch (result) {
#define R(x)                                                                                       \
    case x:                                                                                        \
        return #x;
        R(VK_SUCCESS)
        R(VK_NOT_READY) R(VK_TIMEOUT) R(VK_EVENT_SET) R(VK_EVENT_RESET) R(VK_INCOMPLETE)
            R(VK_ERROR_OUT_OF_HOST_MEMORY) R(VK_ERROR_OUT_OF_DEVICE_MEMORY)
                R(VK_ERROR_INITIALIZATION_FAILED) R(VK_ERROR_DEVICE_LOST)
                    R(VK_ERROR_MEMORY_MAP_FAILED) R(VK_ERROR_LAYER_NOT_PRESENT)
                        R(VK_ERROR_EXTENSION_NOT_PRESENT) R(VK_ERROR_FEATURE_NOT_PRESENT)
                            R(VK_ERROR_INCOMPATIBLE_DRIVER) R(VK_ERROR_TOO_MANY_OBJECTS)
                                R(VK_ERROR_FORMAT_NOT_SUPPORTED) R(VK_ERROR_FRAGMENTED_POOL)
                                    R(VK_ERROR_UNKNOWN) R(VK_ERROR_OUT_OF_POOL_MEMORY)
                                        R(VK_ERROR_INVALID_EXTERNAL_HANDLE)
                                            R(VK_ERROR_FRAGMENTATION)
                                                R(VK_ERROR_INVALID_OPAQUE_CAPTURE_ADDRESS)
                                                    R(VK_PIPELINE_COMPILE_REQUIRED)
                                                        R(VK_ERROR_VALIDATION_FAILED_EXT)
                                                            R(VK_ERROR_INVALID_SHADER_NV)
#undef R
                                                                default
            : return "VK_RESULT_UNKNOWN";
    }
}

int gpu_check(VkResult result, const char *what, ns_error *err)
{
    if (result == VK_SUCCESS)
        return NS_OK;
    int status;
    switch (result) {
    case VK_ERROR_OUT_OF_HOST_MEMORY:
        status = NS_ERR_OUT_OF_HOST_MEMORY;
        break;
    case VK_ERROR_OUT_OF_DEVICE_MEMORY:
        status = NS_ERR_OUT_OF_DEVICE_MEMORY;
        break;
    case VK_ERROR_DEVICE_LOST:
        status = NS_ERR_DEVICE_LOST;
        break;
    default:
        status = NS_ERR_VULKAN;
        break;
    }
    return ns_fail(err, status, "%s failed: %s (%d)", what, gpu_result_name(result), (int)result);
}

/* =======================================================================================
 * Validation messenger: counts warnings and errors so the call that caused them fails.
 * ===================================================================================== */
static VKAPI_ATTR VkBool32 VKAPI_CALL on_debug_message(
    VkDebugUtilsMessageSeverityFlagBitsEXT severity, VkDebugUtilsMessageTypeFlagsEXT types,
    const VkDebugUtilsMessengerCallbackDataEXT *data, void *user)
{
    gpu_device *dev = user;
    const char *text = data && data->pMessage ? data->pMessage : "(no message)";
    int counts = (severity & VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT) ||
                 ((severity & VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT) &&
                  (types & VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT));
    if (counts) {
        __atomic_add_fetch(&dev->validation_messages, 1, __ATOMIC_SEQ_CST);
        snprintf(dev->last_validation_message, sizeof dev->last_validation_message, "%s", text);
    }
    fprintf(stderr, "nscatter: vulkan %s: %s\n", counts ? "validation" : "message", text);
    return VK_FALSE;
}

uint32_t gpu_validation_count(gpu_device *dev)
{
    return __atomic_load_n(&dev->validation_messages, __ATOMIC_SEQ_CST);
}

int gpu_validation_check(gpu_device *dev, uint32_t before, ns_error *err)
{
    uint32_t now = gpu_validation_count(dev);
    if (now == before)
        return NS_OK;
    return ns_fail(err, NS_ERR_VULKAN, "Vulkan validation reported %u message(s); last: %s",
                   now - before, dev->last_validation_message);
}

void gpu_set_label(const gpu_device *dev, VkObjectType type, uint64_t handle, const char *label)
{
    if (!dev->set_object_name || !label || !handle)
        return;
    VkDebugUtilsObjectNameInfoEXT info = {
        .sType = VK_STRUCTURE_TYPE_DEBUG_UTILS_OBJECT_NAME_INFO_EXT,
        .objectType = type,
        .objectHandle = handle,
        .pObjectName = label,
    };
    /* A label is a debugging aid: failing to set one must not fail the caller. */
    (void)dev->set_object_name(dev->device, &info);
}

/* =======================================================================================
 * Instance
 * ===================================================================================== */
static int has_instance_layer(const char *name)
{
    uint32_t count = 0;
    if (vkEnumerateInstanceLayerProperties(&count, NULL) != VK_SUCCESS || count == 0)
        return 0;
    VkLayerProperties *layers = calloc(count, sizeof *layers);
    int found = 0;
    if (layers && vkEnumerateInstanceLayerProperties(&count, layers) == VK_SUCCESS)
        for (uint32_t i = 0; i < count && !found; i++)
            found = strcmp(layers[i].layerName, name) == 0;
    free(layers);
    return found;
}

/* Whether the instance (physical NULL) or a physical device offers the extension. */
static int has_extension(VkPhysicalDevice physical, const char *name)
{
    uint32_t count = 0;
    VkResult listed = physical ? vkEnumerateDeviceExtensionProperties(physical, NULL, &count, NULL)
                               : vkEnumerateInstanceExtensionProperties(NULL, &count, NULL);
    if (listed != VK_SUCCESS || count == 0)
        return 0;
    VkExtensionProperties *exts = calloc(count, sizeof *exts);
    int found = 0;
    if (exts)
        listed = physical ? vkEnumerateDeviceExtensionProperties(physical, NULL, &count, exts)
                          : vkEnumerateInstanceExtensionProperties(NULL, &count, exts);
    if (exts && listed == VK_SUCCESS)
        for (uint32_t i = 0; i < count && !found; i++)
            found = strcmp(exts[i].extensionName, name) == 0;
    free(exts);
    return found;
}

static VkDebugUtilsMessengerCreateInfoEXT messenger_info(gpu_device *dev)
{
    return (VkDebugUtilsMessengerCreateInfoEXT){
        .sType = VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT,
        .messageSeverity = VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT |
                           VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT,
        .messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT |
                       VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT |
                       VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT,
        .pfnUserCallback = on_debug_message,
        .pUserData = dev,
    };
}

static int create_instance(gpu_device *dev, ns_error *err)
{
    const char *layers[1];
    uint32_t layer_count = 0;
    if (dev->validation) {
        if (!has_instance_layer(VALIDATION_LAYER))
            return ns_fail(err, NS_ERR_NOT_AVAILABLE,
                           "validation requested but %s is not installed (Debian package "
                           "vulkan-validationlayers)",
                           VALIDATION_LAYER);
        layers[layer_count++] = VALIDATION_LAYER;
    }
    const char *extensions[1];
    uint32_t extension_count = 0;
    int debug_utils = has_extension(VK_NULL_HANDLE, VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
    if (debug_utils)
        extensions[extension_count++] = VK_EXT_DEBUG_UTILS_EXTENSION_NAME;
    else if (dev->validation)
        return ns_fail(err, NS_ERR_NOT_AVAILABLE, "validation needs %s, which the loader lacks",
                       VK_EXT_DEBUG_UTILS_EXTENSION_NAME);

    VkApplicationInfo app = {
        .sType = VK_STRUCTURE_TYPE_APPLICATION_INFO,
        .pApplicationName = "nscatter",
        .applicationVersion = VK_MAKE_VERSION(0, 1, 0),
        .pEngineName = "nscatter",
        .apiVersion = VK_API_VERSION_1_2,
    };
    VkDebugUtilsMessengerCreateInfoEXT debug = messenger_info(dev);
    VkInstanceCreateInfo info = {
        .sType = VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO,
        /* Chained so that instance creation itself is validated too. */
        .pNext = dev->validation ? &debug : NULL,
        .pApplicationInfo = &app,
        .enabledLayerCount = layer_count,
        .ppEnabledLayerNames = layers,
        .enabledExtensionCount = extension_count,
        .ppEnabledExtensionNames = extensions,
    };
    VkResult created = vkCreateInstance(&info, NULL, &dev->instance);
    if (created == VK_ERROR_INCOMPATIBLE_DRIVER)
        return ns_fail(err, NS_ERR_NO_DEVICE,
                       "no Vulkan driver found (vkCreateInstance: "
                       "VK_ERROR_INCOMPATIBLE_DRIVER); install mesa-vulkan-drivers for lavapipe");
    int status = gpu_check(created, "vkCreateInstance", err);
    if (status)
        return status;
    if (debug_utils)
        dev->set_object_name = (PFN_vkSetDebugUtilsObjectNameEXT)vkGetInstanceProcAddr(
            dev->instance, "vkSetDebugUtilsObjectNameEXT");
    if (dev->validation) {
        PFN_vkCreateDebugUtilsMessengerEXT create_messenger =
            (PFN_vkCreateDebugUtilsMessengerEXT)vkGetInstanceProcAddr(
                dev->instance, "vkCreateDebugUtilsMessengerEXT");
        if (!create_messenger)
            return ns_fail(err, NS_ERR_VULKAN, "vkCreateDebugUtilsMessengerEXT not found");
        status = gpu_check(create_messenger(dev->instance, &debug, NULL, &dev->messenger),
                           "vkCreateDebugUtilsMessengerEXT", err);
    }
    return status;
}

/* =======================================================================================
 * Physical device choice
 * ===================================================================================== */
static int contains_nocase(const char *haystack, const char *needle)
{
    size_t n = strlen(needle);
    for (const char *h = haystack; *h; h++) {
        size_t i = 0;
        while (i < n && h[i] && tolower((unsigned char)h[i]) == tolower((unsigned char)needle[i]))
            i++;
        if (i == n)
            return 1;
    }
    return n == 0;
}

static int is_decimal(const char *s)
{
    if (!*s)
        return 0;
    for (; *s; s++)
        if (!isdigit((unsigned char)*s))
            return 0;
    return 1;
}

static int compute_queue_family(VkPhysicalDevice physical, uint32_t *family,
                                uint32_t *timestamp_bits)
{
    uint32_t count = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(physical, &count, NULL);
    VkQueueFamilyProperties families[16];
    if (count > 16)
        count = 16;
    vkGetPhysicalDeviceQueueFamilyProperties(physical, &count, families);
    for (uint32_t i = 0; i < count; i++) {
        if (families[i].queueFlags & VK_QUEUE_COMPUTE_BIT) {
            *family = i;
            if (timestamp_bits)
                *timestamp_bits = families[i].timestampValidBits;
            return 1;
        }
    }
    return 0;
}

/* Subgroup size, or 0 when compute shaders lack subgroup votes, ballots or arithmetic (the
 * gather's walk needs the first two, the traversal's loop count subgroupMax; every desktop
 * driver and lavapipe has them). */
static uint32_t compute_subgroup_size(VkPhysicalDevice physical)
{
    VkPhysicalDeviceSubgroupProperties subgroup = {
        .sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_PROPERTIES};
    VkPhysicalDeviceProperties2 props2 = {.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2,
                                          .pNext = &subgroup};
    vkGetPhysicalDeviceProperties2(physical, &props2);
    VkSubgroupFeatureFlags need = VK_SUBGROUP_FEATURE_VOTE_BIT | VK_SUBGROUP_FEATURE_BALLOT_BIT |
                                  VK_SUBGROUP_FEATURE_ARITHMETIC_BIT;
    int ok = (subgroup.supportedStages & VK_SHADER_STAGE_COMPUTE_BIT) &&
             (subgroup.supportedOperations & need) == need;
    return ok ? subgroup.subgroupSize : 0;
}

static int usable(VkPhysicalDevice physical)
{
    VkPhysicalDeviceProperties props;
    vkGetPhysicalDeviceProperties(physical, &props);
    uint32_t family;
    return props.apiVersion >= VK_API_VERSION_1_1 && compute_queue_family(physical, &family, NULL) &&
           compute_subgroup_size(physical) > 0;
}

static int pick_physical_device(gpu_device *dev, const char *want, ns_error *err)
{
    uint32_t count = 0;
    int status = gpu_check(vkEnumeratePhysicalDevices(dev->instance, &count, NULL),
                           "vkEnumeratePhysicalDevices", err);
    if (status)
        return status;
    if (count == 0)
        return ns_fail(err, NS_ERR_NO_DEVICE,
                       "no Vulkan device found (is mesa-vulkan-drivers "
                       "installed? lavapipe is the default device)");
    VkPhysicalDevice devices[32];
    if (count > 32)
        count = 32;
    VkResult listed = vkEnumeratePhysicalDevices(dev->instance, &count, devices);
    if (listed != VK_INCOMPLETE && (status = gpu_check(listed, "vkEnumeratePhysicalDevices", err)))
        return status;

    int chosen = -1;
    if (want && *want && is_decimal(want)) {
        long index = strtol(want, NULL, 10);
        if (index >= (long)count)
            return ns_fail(err, NS_ERR_NO_DEVICE, "device index %ld out of range (%u devices)",
                           index, count);
        chosen = (int)index;
    } else {
        for (uint32_t i = 0; i < count && chosen < 0; i++) {
            VkPhysicalDeviceProperties props;
            vkGetPhysicalDeviceProperties(devices[i], &props);
            int match = (want && *want) ? contains_nocase(props.deviceName, want)
                                        : props.deviceType == VK_PHYSICAL_DEVICE_TYPE_CPU ||
                                              contains_nocase(props.deviceName, "llvmpipe");
            if (match && usable(devices[i]))
                chosen = (int)i;
        }
        if (chosen < 0 && want && *want)
            return ns_fail(err, NS_ERR_NO_DEVICE, "no Vulkan device named like '%s'", want);
        for (uint32_t i = 0; i < count && chosen < 0; i++)
            if (usable(devices[i]))
                chosen = (int)i;
    }
    if (chosen < 0 || !usable(devices[chosen]))
        return ns_fail(err, NS_ERR_NO_DEVICE,
                       "no Vulkan 1.1 device with a compute queue and subgroup votes, "
                       "ballots and arithmetic in compute shaders among %u device(s)",
                       count);
    dev->physical = devices[chosen];
    compute_queue_family(dev->physical, &dev->queue_family, &dev->timestamp_bits);
    vkGetPhysicalDeviceProperties(dev->physical, &dev->properties);
    vkGetPhysicalDeviceMemoryProperties(dev->physical, &dev->memory);
    return NS_OK;
}

/* How many threads lavapipe splits a dispatch among, by Mesa 22.3's rule (llvmpipe's screen:
 * the CPUs, or LP_NUM_THREADS read as debug_get_num_option reads numbers, at most
 * LP_MAX_THREADS = 16; 0 threads run a dispatch on the caller: one run). A wrong count costs
 * only the balance between the threads, never a result. */
uint32_t gpu_lavapipe_threads(void)
{
    cpu_set_t set;
    long n = sched_getaffinity(0, sizeof set, &set) == 0 ? CPU_COUNT(&set) : 1;
    const char *env = getenv("LP_NUM_THREADS");
    if (env) {
        char *end;
        long value = strtol(env, &end, 0);
        if (end != env) /* no digits: the default stands */
            n = value;
    }
    return n < 1 ? 1u : n > 16 ? 16u : (uint32_t)n;
}

static uint64_t largest_device_local_heap(const VkPhysicalDeviceMemoryProperties *memory)
{
    uint64_t largest = 0;
    for (uint32_t i = 0; i < memory->memoryHeapCount; i++)
        if ((memory->memoryHeaps[i].flags & VK_MEMORY_HEAP_DEVICE_LOCAL_BIT) &&
            memory->memoryHeaps[i].size > largest)
            largest = memory->memoryHeaps[i].size;
    return largest;
}

/* Hardware traversal as the device offers it: each extension with its feature bit (an
 * extension is listed on some drivers whose feature is off), both with acceleration
 * structures. Only extensions the device lists are chained into the query. */
static void ray_tracing_support(VkPhysicalDevice physical, int *ray_query, int *pipelines)
{
    *ray_query = *pipelines = 0;
    if (!has_extension(physical, VK_KHR_ACCELERATION_STRUCTURE_EXTENSION_NAME))
        return;
    int query_listed = has_extension(physical, VK_KHR_RAY_QUERY_EXTENSION_NAME);
    int pipeline_listed = has_extension(physical, VK_KHR_RAY_TRACING_PIPELINE_EXTENSION_NAME);
    VkPhysicalDeviceAccelerationStructureFeaturesKHR structures = {
        .sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_FEATURES_KHR};
    VkPhysicalDeviceRayQueryFeaturesKHR query = {
        .sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_QUERY_FEATURES_KHR};
    VkPhysicalDeviceRayTracingPipelineFeaturesKHR pipeline = {
        .sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_TRACING_PIPELINE_FEATURES_KHR};
    void *chain = &structures;
    if (query_listed) {
        query.pNext = chain;
        chain = &query;
    }
    if (pipeline_listed) {
        pipeline.pNext = chain;
        chain = &pipeline;
    }
    VkPhysicalDeviceFeatures2 features = {.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2,
                                          .pNext = chain};
    vkGetPhysicalDeviceFeatures2(physical, &features);
    int structures_on = structures.accelerationStructure == VK_TRUE;
    *ray_query = structures_on && query_listed && query.rayQuery == VK_TRUE;
    *pipelines = structures_on && pipeline_listed && pipeline.rayTracingPipeline == VK_TRUE;
}

static void fill_device_info(gpu_device *dev)
{
    ns_device_info *info = &dev->info;
    memset(info, 0, sizeof *info);
    snprintf(info->device_name, sizeof info->device_name, "%s", dev->properties.deviceName);
    info->api_version = dev->properties.apiVersion;
    info->vendor_id = dev->properties.vendorID;
    info->device_id = dev->properties.deviceID;
    info->is_cpu = dev->properties.deviceType == VK_PHYSICAL_DEVICE_TYPE_CPU;
    dev->loop_limited = contains_nocase(dev->properties.deviceName, "llvmpipe");
    dev->cpu_threads = dev->loop_limited ? gpu_lavapipe_threads() : 0;
    dev->subgroup_size = compute_subgroup_size(dev->physical);
    info->subgroup_size = dev->subgroup_size;
    info->device_local_bytes = largest_device_local_heap(&dev->memory);
    _Static_assert((uint32_t)NS_MEMORY_DEVICE_LOCAL == (uint32_t)VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT &&
                       (uint32_t)NS_MEMORY_HOST_VISIBLE == (uint32_t)VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT &&
                       (uint32_t)NS_MEMORY_HOST_COHERENT == (uint32_t)VK_MEMORY_PROPERTY_HOST_COHERENT_BIT &&
                       (uint32_t)NS_MEMORY_HOST_CACHED == (uint32_t)VK_MEMORY_PROPERTY_HOST_CACHED_BIT,
                   "NS_MEMORY_* are Vulkan's memory property bits");
    info->memory_type_count = dev->memory.memoryTypeCount < 32 ? dev->memory.memoryTypeCount : 32;
    for (uint32_t i = 0; i < info->memory_type_count; i++)
        info->memory_types[i] = dev->memory.memoryTypes[i].propertyFlags &
                                (NS_MEMORY_DEVICE_LOCAL | NS_MEMORY_HOST_VISIBLE |
                                 NS_MEMORY_HOST_COHERENT | NS_MEMORY_HOST_CACHED);
    ray_tracing_support(dev->physical, &info->ray_query, &info->ray_tracing_pipeline);
    /* Driver name/info are core in Vulkan 1.2; older devices report only the version. */
    if (dev->properties.apiVersion >= VK_API_VERSION_1_2) {
        VkPhysicalDeviceDriverProperties driver = {
            .sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DRIVER_PROPERTIES};
        VkPhysicalDeviceProperties2 props2 = {
            .sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, .pNext = &driver};
        vkGetPhysicalDeviceProperties2(dev->physical, &props2);
        snprintf(info->driver_name, sizeof info->driver_name, "%s", driver.driverName);
        snprintf(info->driver_info, sizeof info->driver_info, "%s", driver.driverInfo);
    } else {
        uint32_t v = dev->properties.driverVersion;
        snprintf(info->driver_name, sizeof info->driver_name, "vendor 0x%04x", info->vendor_id);
        snprintf(info->driver_info, sizeof info->driver_info, "driver version 0x%08x", v);
    }
}

/* =======================================================================================
 * Logical device, queue, command pool, pipeline cache
 * ===================================================================================== */
static int create_logical_device(gpu_device *dev, ns_error *err)
{
    float priority = 1.0f;
    VkDeviceQueueCreateInfo queue = {
        .sType = VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO,
        .queueFamilyIndex = dev->queue_family,
        .queueCount = 1,
        .pQueuePriorities = &priority,
    };
    VkDeviceCreateInfo info = {
        .sType = VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO,
        .queueCreateInfoCount = 1,
        .pQueueCreateInfos = &queue,
    };
    int status =
        gpu_check(vkCreateDevice(dev->physical, &info, NULL, &dev->device), "vkCreateDevice", err);
    if (status)
        return status;
    vkGetDeviceQueue(dev->device, dev->queue_family, 0, &dev->queue);
    gpu_set_label(dev, VK_OBJECT_TYPE_QUEUE, (uint64_t)(uintptr_t)dev->queue, "ns.queue.compute");

    VkCommandPoolCreateInfo pool = {
        .sType = VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO,
        .flags =
            VK_COMMAND_POOL_CREATE_TRANSIENT_BIT | VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT,
        .queueFamilyIndex = dev->queue_family,
    };
    status = gpu_check(vkCreateCommandPool(dev->device, &pool, NULL, &dev->command_pool),
                       "vkCreateCommandPool", err);
    if (!status)
        gpu_set_label(dev, VK_OBJECT_TYPE_COMMAND_POOL, (uint64_t)dev->command_pool,
                      "ns.command_pool");
    return status;
}

/* Reads the whole file; NULL (and *size 0) if it does not exist or cannot be read, which
 * simply means a cold cache. */
static void *read_file(const char *path, size_t *size)
{
    *size = 0;
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    void *data = NULL;
    if (fseek(f, 0, SEEK_END) == 0) {
        long n = ftell(f);
        if (n > 0 && n < (64L << 20) && fseek(f, 0, SEEK_SET) == 0 && (data = malloc((size_t)n))) {
            if (fread(data, 1, (size_t)n, f) == (size_t)n) {
                *size = (size_t)n;
            } else {
                free(data);
                data = NULL;
            }
        }
    }
    fclose(f);
    return data;
}

static int create_pipeline_cache(gpu_device *dev, const char *path, ns_error *err)
{
    size_t size = 0;
    void *data = path ? read_file(path, &size) : NULL;
    /* The driver checks the header (vendor, device, cache UUID) and ignores a stale file. */
    VkPipelineCacheCreateInfo info = {
        .sType = VK_STRUCTURE_TYPE_PIPELINE_CACHE_CREATE_INFO,
        .initialDataSize = size,
        .pInitialData = data,
    };
    VkResult result = vkCreatePipelineCache(dev->device, &info, NULL, &dev->pipeline_cache);
    if (result != VK_SUCCESS && data) {
        /* A corrupt file must not keep the service from starting: start cold instead. */
        info.initialDataSize = 0;
        info.pInitialData = NULL;
        result = vkCreatePipelineCache(dev->device, &info, NULL, &dev->pipeline_cache);
    }
    free(data);
    int status = gpu_check(result, "vkCreatePipelineCache", err);
    if (!status)
        gpu_set_label(dev, VK_OBJECT_TYPE_PIPELINE_CACHE, (uint64_t)dev->pipeline_cache,
                      "ns.pipeline_cache");
    return status;
}

int gpu_pipeline_cache_save(gpu_device *dev, const char *path, ns_error *err)
{
    size_t size = 0;
    int status = gpu_check(vkGetPipelineCacheData(dev->device, dev->pipeline_cache, &size, NULL),
                           "vkGetPipelineCacheData", err);
    if (status)
        return status;
    void *data = malloc(size ? size : 1);
    if (!data)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "pipeline cache: %zu bytes", size);
    status = gpu_check(vkGetPipelineCacheData(dev->device, dev->pipeline_cache, &size, data),
                       "vkGetPipelineCacheData", err);
    if (!status) {
        ns_error write_err = {0};
        status = ns_write_file_atomic(path, data, size, &write_err);
        if (status)
            ns_fail(err, status, "pipeline cache: %s", write_err.message);
    }
    free(data);
    return status;
}

/* =======================================================================================
 * Create / destroy
 * ===================================================================================== */
int gpu_device_create(gpu_device *dev, const gpu_device_desc *desc, ns_error *err)
{
    memset(dev, 0, sizeof *dev);
    dev->validation = desc->validation;
    int status = create_instance(dev, err);
    if (!status)
        status = pick_physical_device(dev, desc->device, err);
    if (!status) {
        fill_device_info(dev);
        status = create_logical_device(dev, err);
    }
    if (!status)
        status = create_pipeline_cache(dev, desc->pipeline_cache_path, err);
    if (status)
        gpu_device_destroy(dev);
    return status;
}

void gpu_device_destroy(gpu_device *dev)
{
    if (dev->device) {
        vkDeviceWaitIdle(dev->device); /* result irrelevant: everything is destroyed next */
        if (dev->pipeline_cache)
            vkDestroyPipelineCache(dev->device, dev->pipeline_cache, NULL);
        if (dev->command_pool)
            vkDestroyCommandPool(dev->device, dev->command_pool, NULL);
        vkDestroyDevice(dev->device, NULL);
    }
    if (dev->messenger) {
        PFN_vkDestroyDebugUtilsMessengerEXT destroy_messenger =
            (PFN_vkDestroyDebugUtilsMessengerEXT)vkGetInstanceProcAddr(
                dev->instance, "vkDestroyDebugUtilsMessengerEXT");
        if (destroy_messenger)
            destroy_messenger(dev->instance, dev->messenger, NULL);
    }
    if (dev->instance)
        vkDestroyInstance(dev->instance, NULL);
    uint32_t messages = dev->validation_messages;
    memset(dev, 0, sizeof *dev);
    dev->validation_messages = messages;
}
