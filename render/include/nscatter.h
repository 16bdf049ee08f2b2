/* nscatter.h — the render library's public interface.
 *
 * This is the only header the server (HTTP, JSON, encoders, CLI) includes from render/.
 * render/ never sees HTTP or JSON: a scene arrives here already parsed and validated into
 * the plain structs below, in scene units, and an image leaves as linear RGB floats.
 *
 * Ownership: the caller owns every ns_scene and its arrays; ns_render() only reads them.
 * ns_render() allocates the output image's pixels; free them with ns_image_free().
 * Results are 0 for success or a negative ns_status.
 */
#ifndef NSCATTER_H
#define NSCATTER_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define NS_VERSION "0.1.0"

/* ---------------------------------------------------------------------------------------
 * Status codes. One table generates the codes, their stable names, a default message and
 * the HTTP status the server answers with (render/ only carries the number).
 * ------------------------------------------------------------------------------------- */
#define NS_STATUS_TABLE(X)                                                                   \
    X(NS_OK, 0, "ok", "success", 200)                                                         \
    X(NS_ERR_INVALID_ARGUMENT, -1, "invalid_argument", "invalid argument", 422)               \
    X(NS_ERR_NOT_AVAILABLE, -2, "not_available", "not available in this build", 422)         \
    X(NS_ERR_OUT_OF_HOST_MEMORY, -3, "out_of_host_memory", "out of host memory", 503)         \
    X(NS_ERR_OUT_OF_DEVICE_MEMORY, -4, "out_of_device_memory", "out of device memory", 503)   \
    X(NS_ERR_DEVICE_LOST, -5, "device_lost", "the Vulkan device was lost", 500)               \
    X(NS_ERR_VULKAN, -6, "vulkan_error", "Vulkan call failed", 500)                           \
    X(NS_ERR_NO_DEVICE, -7, "no_device", "no suitable Vulkan device", 500)                    \
    X(NS_ERR_IO, -8, "io_error", "input/output error", 500)                                   \
    X(NS_ERR_LIMIT, -9, "limit_exceeded", "a size limit was exceeded", 422)                   \
    X(NS_ERR_INTERNAL, -10, "internal_error", "internal error", 500)                           \
    X(NS_ERR_CANCELLED, -11, "cancelled", "the render was cancelled", 409)                    \
    X(NS_ERR_DEADLINE, -12, "deadline_exceeded", "the render ran past its deadline", 503)

typedef enum {
#define NS_X_ENUM(code, value, name, message, http) code = value,
    NS_STATUS_TABLE(NS_X_ENUM)
#undef NS_X_ENUM
} ns_status;

const char *ns_status_name(int status);    /* "invalid_argument"; "unknown" if not a status */
const char *ns_status_message(int status); /* default human text */
int ns_status_http(int status);            /* HTTP status the server answers with */

/* Error detail filled by calls that can fail; message is one line, NUL-terminated. */
typedef struct ns_error {
    int status;
    char message[512];
} ns_error;

/* Fills err (when not NULL) with status and a printf-formatted message; returns status.
 * Shared by render/, the offline tools and the server. */
int ns_fail(ns_error *err, int status, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

/* ---------------------------------------------------------------------------------------
 * Limits the parser enforces and the renderer relies on.
 * ------------------------------------------------------------------------------------- */
#define NS_MAX_IMAGE_SIDE 8192
#define NS_MAX_PIXELS (4096u * 4096u)
#define NS_MAX_SPP 4096
#define NS_MAX_DEPTH 64
#define NS_MAX_SCATTER 100000 /* render.max_scatter */
/* What "pt" estimates: bumped whenever a change to shaders/pt.comp changes its expected
 * image, so that caches of reference images (nscatter bench) do not serve stale ones.
 * 2: specular connection for single scattering; no light reflected by diffuse surfaces
 * into media. */
#define NS_PT_ESTIMATOR_VERSION 2
#define NS_MAX_MATERIALS 256
#define NS_MAX_OBJECTS 4096
#define NS_MAX_LIGHTS 256
#define NS_MAX_TRIANGLES (4u * 1024u * 1024u)
#define NS_NAME_MAX 64

/* ---------------------------------------------------------------------------------------
 * Scene model (scene units throughout; see docs/scene.md for the JSON that maps onto it).
 * ------------------------------------------------------------------------------------- */
typedef struct ns_camera {
    float position[3];
    float look_at[3];
    float up[3];
    float fov_deg; /* horizontal field of view, degrees, in (0, 180) */
    uint32_t width, height;
} ns_camera;

typedef enum { NS_MATERIAL_DIFFUSE = 0, NS_MATERIAL_MEDIUM = 1 } ns_material_type;

typedef struct ns_material {
    ns_material_type type;
    char name[NS_NAME_MAX];
    float reflectance[3]; /* diffuse: albedo of the Lambertian surface, in [0, 1] */
    /* medium: coefficients per scene unit, already resolved from albedo/mfp, presets and
     * scale by the parser, so the renderer sees one form only. */
    float sigma_s[3];
    float sigma_a[3];
    float g;   /* Henyey-Greenstein, (-1, 1), shared by the three channels */
    float ior; /* >= 1; exactly 1 means index matched (no refraction, no Fresnel) */
} ns_material;

typedef enum {
    NS_SHAPE_SPHERE = 0,
    NS_SHAPE_PLANE = 1,
    NS_SHAPE_BOX = 2,
    NS_SHAPE_MESH = 3,
} ns_shape;

typedef struct ns_object {
    ns_shape shape;
    uint32_t material; /* index into ns_scene.materials */
    float center[3];   /* sphere */
    float radius;      /* sphere */
    float point[3];    /* plane: a point on it */
    float normal[3];   /* plane: unit normal (normalised by the parser) */
    float min[3];      /* box, axis aligned */
    float max[3];
    /* mesh: triangles [first_triangle, first_triangle + triangle_count) of
     * ns_scene.triangles, already transformed to world space by the parser. A closed mesh
     * with a medium material bounds that medium. */
    uint32_t first_triangle;
    uint32_t triangle_count;
} ns_object;

typedef struct ns_triangle {
    float v[3][3]; /* world-space vertices, counter-clockwise seen from outside */
    /* Shading normals at the vertices (unit, outward), blended across the triangle for
     * shading, reflection and refraction: a smooth mesh. All nine zero: flat, the geometric
     * normal everywhere. Where the blended normal faces away from the ray while the
     * geometric one faces it, or would mirror the ray into the surface, the geometric normal
     * is used (docs/rendering.md, "Smooth meshes"). */
    float n[3][3];
} ns_triangle;

/* 1 when the triangle carries shading normals (any component not zero). */
static inline int ns_triangle_is_smooth(const ns_triangle *t)
{
    for (int v = 0; v < 3; v++)
        for (int k = 0; k < 3; k++)
            if (t->n[v][k] != 0.0f)
                return 1;
    return 0;
}

typedef enum {
    NS_LIGHT_DIRECTIONAL = 0,
    NS_LIGHT_POINT = 1,
    NS_LIGHT_SPHERE = 2,
    NS_LIGHT_ENVIRONMENT = 3,
} ns_light_type;

typedef struct ns_light {
    ns_light_type type;
    float direction[3]; /* directional: unit direction the light travels */
    float position[3];  /* point: position; sphere: centre */
    float radius;       /* sphere */
    /* directional: irradiance W/m^2 on a surface facing the light; point: intensity W/sr;
     * sphere and environment: radiance W/(m^2 sr). */
    float color[3];
} ns_light;

/* Render methods and scattering components: one table each generates the values and the
 * names that the scene JSON, the HTTP API and the command line use (ns_method_name,
 * ns_component_name and their parse functions below), so a name is spelt once.
 * X(NAME, value, "name"); a component's value is its bit number. */
#define NS_METHODS(X)                                                                        \
    X(NS_METHOD_NN, 0, "nn")         /* the paper's method: tables from the network */      \
    X(NS_METHOD_TABLE, 1, "table")   /* same pipeline, Monte Carlo tables of the material */ \
    X(NS_METHOD_VRL, 2, "vrl")       /* Novak et al. 2012 brute-force VRLs */                \
    X(NS_METHOD_DIPOLE, 3, "dipole") /* Jensen et al. 2001 */                                \
    X(NS_METHOD_PT, 4, "pt")         /* reference volumetric path tracer */

#define NS_COMPONENTS(X)                                                                     \
    X(NS_COMPONENT_SURFACE, 0, "surface")                                                    \
    X(NS_COMPONENT_SINGLE, 1, "single")                                                      \
    X(NS_COMPONENT_DOUBLE, 2, "double")                                                      \
    X(NS_COMPONENT_MULTIPLE, 3, "multiple")

typedef enum {
#define NS_X_METHOD(code, value, name) code = value,
    NS_METHODS(NS_X_METHOD)
#undef NS_X_METHOD
} ns_method;

enum {
#define NS_X_COMPONENT(code, bit, name) code = 1u << (bit),
    NS_COMPONENTS(NS_X_COMPONENT)
#undef NS_X_COMPONENT
};

/* How many methods and components there are, and every component bit together. */
enum {
#define NS_X_COUNT(code, value, name) +1
    NS_METHOD_COUNT = 0 NS_METHODS(NS_X_COUNT),
    NS_COMPONENT_COUNT = 0 NS_COMPONENTS(NS_X_COUNT),
#undef NS_X_COUNT
#define NS_X_BIT(code, bit, name) | code
    NS_COMPONENT_ALL = 0 NS_COMPONENTS(NS_X_BIT),
#undef NS_X_BIT
};

/* "nn", "table", ...; "unknown" for a value that is not a method. */
const char *ns_method_name(ns_method method);
/* The method called exactly `name` (case-sensitive, as in the scene JSON): 0 and *out, or
 * NS_ERR_INVALID_ARGUMENT with *out untouched. */
int ns_method_parse(const char *name, ns_method *out);
/* "surface", "single", ... for one NS_COMPONENT_* bit; "unknown" for anything else. */
const char *ns_component_name(uint32_t component);
/* The NS_COMPONENT_* bit called exactly `name`: 0 and *out, or NS_ERR_INVALID_ARGUMENT. */
int ns_component_parse(const char *name, uint32_t *out);

/* How a camera segment reads the accumulated table: exactly, A(entry) - e^{-s Lc} A(exit)
 * (DESIGN.md section 2), or the paper's 5-mfp table with its length weight W (Eq. 5). */
typedef enum { NS_ACCUMULATION_EXACT = 0, NS_ACCUMULATION_PAPER = 1 } ns_accumulation;
/* How a material's tables are made (nn only; docs/rendering.md, *Interpolated tables*):
 * exact, the networks evaluated and accumulated at the material's own albedos; or
 * interpolated, blended from tables made once per g at fixed albedos (nodes), so that a new
 * albedo at a g seen before costs a blend instead of a reconstruction and an accumulation;
 * or auto (the scene parser's default): exact where the exact table is cached, interpolated
 * where the nodes it needs exist (in the context or its table folder), and otherwise exact
 * for the first four albedos at a g, after which the context makes that g's nodes (about
 * four exact materials' work) and blends every later albedo. Other methods than nn take
 * auto as exact. */
typedef enum { NS_TABLES_EXACT = 0, NS_TABLES_INTERPOLATED = 1, NS_TABLES_AUTO = 2 } ns_tables_mode;
/* The beams of the table methods' VRLs: endless, as the paper's tables assume, or bounded by
 * the medium (each VRL ends where its beam leaves; the beam's internal reflections are VRLs
 * of their own). docs/scattering.md. */
typedef enum { NS_VRL_BEAMS_ENDLESS = 0, NS_VRL_BEAMS_BOUNDED = 1 } ns_vrl_beams;

/* The boundary-crossing correction of double and multiple scattering (render.boundary; nn and
 * table only; docs/scattering.md, "The object's boundary"): off, the paper's infinite-medium
 * model (with render.vrl_beams); walks, light walks inside the object add a negative source
 * where scattered light leaves it and a positive one where the boundary reflects it back,
 * each gathered through the tables with its orders shifted. Walks imply bounded beams. */
typedef enum { NS_BOUNDARY_OFF = 0, NS_BOUNDARY_WALKS = 1 } ns_boundary;
/* Whether the method gathers through tables (nn, table): the ones that take vrl_beams and
 * boundary. */
int ns_method_uses_tables(ns_method method);
/* A scene's render.boundary where it does not say: walks where the method takes it, else off
 * (the scene parser; the library's own 0 is off). */
ns_boundary ns_default_boundary(ns_method method);
/* "off", "walks" ("unknown" outside the enum). */
const char *ns_boundary_name(ns_boundary boundary);
/* "exact", "interpolated", "auto" ("unknown" outside the enum). */
const char *ns_tables_name(ns_tables_mode tables);

#define NS_MAX_VRLS 1000000u
#define NS_MAX_GATHER_TILE 16u
#define NS_MAX_GATHER_LEVELS 4u
#define NS_MAX_SINGLE_SAMPLES 4096u
#define NS_MAX_LIGHT_SAMPLES 64u
#define NS_MAX_ADAPTIVE_SPP 64u
/* A pixel takes at most this many times render.spp added camera samples (render.adaptive_spp). */
#define NS_ADAPTIVE_PIXEL_FACTOR 32u
#define NS_MAX_DEADLINE_MS 86400000u /* render.deadline_ms: a day */

/* The defaults of the render settings (docs/scene.md lists the same). */
#define NS_DEFAULT_COMPONENTS NS_COMPONENT_ALL
#define NS_DEFAULT_SPP 1u
#define NS_DEFAULT_SEED 1u
#define NS_DEFAULT_MAX_DEPTH 8u
#define NS_DEFAULT_LIGHT_SAMPLES 2u
/* The scene parser's default for render.adaptive_spp at spp >= 2; the library's 0 adds none. */
#define NS_DEFAULT_ADAPTIVE_SPP 2.0f
#define NS_DEFAULT_VRLS 10000u
#define NS_DEFAULT_GATHER_TILE 2u
/* The scene parser's default for render.gather_levels; the library's 0 gathers every tile. */
#define NS_DEFAULT_GATHER_LEVELS 2u
#define NS_DEFAULT_GATHER_TOLERANCE 0.05f
#define NS_DEFAULT_SINGLE_SAMPLES 64u
/* The scene parser's defaults for render.single_levels and single_tolerance; the library's 0
 * levels computes every pixel (ns_render_settings). */
#define NS_DEFAULT_SINGLE_LEVELS 2u
#define NS_DEFAULT_SINGLE_TOLERANCE 0.05f
/* The scene parser's default for render.gather_camera_samples; the library's 0 gathers every
 * camera sample's segments. */
#define NS_DEFAULT_GATHER_CAMERA_SAMPLES 1u

/* How to render. A field left 0 means its default: ns_render replaces it once, first
 * (ns_render_settings_resolve), so a caller sets only what it wants changed and a zeroed
 * struct renders with every default. Where the default is itself 0 (method, exposure,
 * max_scatter, gather_levels, gather_camera_samples, single_levels, accumulation, tables,
 * vrl_beams, boundary, cull_solid_angle, adaptive_spp) nothing needs replacing in the
 * library. Eight fields are exceptions. seed, gather_tolerance and single_tolerance keep a
 * 0 as given (0 is a value of their own there), and their defaults (NS_DEFAULT_SEED,
 * NS_DEFAULT_GATHER_TOLERANCE, NS_DEFAULT_SINGLE_TOLERANCE) are applied by the scene
 * parser, which knows whether the key was written; boundary is 0 (off) here, and the parser's default is
 * ns_default_boundary(method): walks for nn and table; single_levels is 0 (every pixel)
 * here, and the parser's default is NS_DEFAULT_SINGLE_LEVELS; gather_levels likewise (every
 * tile here, NS_DEFAULT_GATHER_LEVELS in the parser); gather_camera_samples is 0 (every
 * sample) here, and the parser's default is NS_DEFAULT_GATHER_CAMERA_SAMPLES; adaptive_spp
 * is 0 (none) here, and the parser's default is NS_DEFAULT_ADAPTIVE_SPP where spp >= 2. */
typedef struct ns_render_settings {
    ns_method method;    /* 0: NS_METHOD_NN, the default */
    uint32_t components; /* NS_COMPONENT_* bits; 0: NS_DEFAULT_COMPONENTS (all four) */
    uint32_t spp;        /* jittered camera samples per pixel, 1..NS_MAX_SPP; 0: NS_DEFAULT_SPP */
    /* Random seed, any value: 0 is a seed like the others and stays 0 (the parser's default
     * for an absent key is NS_DEFAULT_SEED). */
    uint32_t seed;
    /* Surface/boundary bounces of a camera path, 1..NS_MAX_DEPTH; 0: NS_DEFAULT_MAX_DEPTH. */
    uint32_t max_depth;
    /* Shadow rays per light, and directions towards the environment, at each diffuse surface
     * a camera path ends on (the surface component of every method but pt, whose paths take
     * one per vertex), 1..NS_MAX_LIGHT_SAMPLES; 0: NS_DEFAULT_LIGHT_SAMPLES. A pixel's
     * spp x light_samples directions towards each light are spread evenly (low-discrepancy
     * points), so the soft shadows' and the environment's noise falls faster than 1 / spp. */
    uint32_t light_samples;
    /* Camera samples added per pixel on average, 0..NS_MAX_ADAPTIVE_SPP, after the spp of
     * every pixel: they go to the pixels whose neighbours' samples spread most, in proportion
     * to that spread (at most NS_ADAPTIVE_PIXEL_FACTOR x spp to one pixel), and add to the
     * surface light only (they record no segments for the scattering stages). A pixel's
     * count is read from its neighbours' samples (the 24 within 2 pixels), never from its
     * own, so its mean stays unbiased (docs/rendering.md, *Adaptive camera samples*).
     * Needs spp >= 2 (a
     * spread); pt ignores it. 0 = none, the library's default; the scene parser's for an
     * absent key is NS_DEFAULT_ADAPTIVE_SPP where spp >= 2. */
    float adaptive_spp;
    float exposure;       /* stops; applied by the encoders, not by the renderer; 0: none */
    uint32_t max_scatter; /* pt only: paths with more scattering events add nothing; 0 = no limit */
    /* Scattering stages (nn, table, vrl, dipole; docs/rendering.md): */
    uint32_t vrls;           /* light paths traced towards the media, 1..NS_MAX_VRLS (VRLs
                                stored <= this, or 4x with bounded beams: vrl_beams); 0:
                                NS_DEFAULT_VRLS */
    uint32_t gather_tile;    /* one gathered camera pixel per tile x tile block,
                                1..NS_MAX_GATHER_TILE; 0: NS_DEFAULT_GATHER_TILE */
    /* Adaptive gather: the tiles are first gathered on a lattice 2^gather_levels tiles apart;
     * a tile between gathered ones is interpolated when they agree within gather_tolerance
     * (relative, per channel) and see the same surface, else gathered. gather_levels 0 =
     * every tile, the library's default (as the paper); the scene parser's for an absent key
     * is NS_DEFAULT_GATHER_LEVELS. gather_tolerance 0 is a tolerance of its own (interpolate only
     * where the estimated error is exactly 0) and stays 0: a caller that sets gather_levels
     * sets it too, e.g. to NS_DEFAULT_GATHER_TOLERANCE as the parser does. With boundary
     * walks, at any gather_levels, the correction has a lattice one level coarser and is
     * interpolated within 2 x gather_tolerance of the pixels' totals (0: at every tile). */
    uint32_t gather_levels;
    float gather_tolerance;
    /* How many of a gathered pixel's camera samples the gather takes, 0..NS_MAX_SPP: the
     * segments of the N samples that start nearest its centre, where every sample's first
     * segment sees the same surface (else every sample's); the pixel's other samples take
     * their radiance per unit throughput. Double and multiple scattering vary over a mean free path, and the
     * samples of a pixel lie a fraction of a pixel apart. 0 = every sample, the library's
     * default; the scene parser's is NS_DEFAULT_GATHER_CAMERA_SAMPLES. The vrl method, whose
     * estimate is independent per segment, gathers every sample. */
    uint32_t gather_camera_samples;
    /* Samples per camera segment for single scattering, 1..NS_MAX_SINGLE_SAMPLES;
     * 0: NS_DEFAULT_SINGLE_SAMPLES. */
    uint32_t single_samples;
    /* Adaptive single scattering, the adaptive gather's rule at every pixel: single
     * scattering is first computed on a lattice of pixels 2^single_levels apart, and a pixel
     * between computed ones takes a value interpolated from them (a cubic, or a parabola
     * near a silhouette) where they see its surface and the error of their mean is within
     * single_tolerance (relative, per channel) or, at 2 samples per pixel or more, within
     * the noise that computing it would leave (the estimate's variance, from the spread of
     * the pixels' camera samples; docs/scattering.md, *Noisy estimates*), else it is
     * computed. single_levels 0 =
     * every pixel, the library's default; the scene parser's for an absent key is
     * NS_DEFAULT_SINGLE_LEVELS (as boundary's). single_tolerance keeps its 0, as
     * gather_tolerance does (the parser's default: NS_DEFAULT_SINGLE_TOLERANCE). */
    uint32_t single_levels;
    float single_tolerance;
    ns_accumulation accumulation; /* 0: NS_ACCUMULATION_EXACT, the default */
    ns_tables_mode tables;        /* nn only; 0: NS_TABLES_EXACT (the parser's: AUTO) */
    ns_vrl_beams vrl_beams;       /* nn and table only; 0: NS_VRL_BEAMS_ENDLESS, the default */
    ns_boundary boundary;         /* nn and table only; 0: NS_BOUNDARY_OFF (scene JSON without
                                     the key: walks for nn and table, set by its parser) */
    float cull_solid_angle; /* sr; 0 = exact, the default (only cells beyond the table's reach
                               are culled) */
    /* Milliseconds the render may take, from when it starts (waiting for the context does
     * not count); past it the render stops before its next device submission, frees what it
     * made and returns NS_ERR_DEADLINE. 0: no deadline, the default. */
    uint32_t deadline_ms;
} ns_render_settings;

/* `settings` with each field left 0 replaced by its default (ns_render_settings above says
 * which); every other field as given, in range or not (ns_render checks them). ns_render
 * calls it before anything else reads the settings. Callers that report settings call it
 * to report the values rendered: the scene parser returns its settings resolved, so that an
 * image's metadata and `nscatter render --timings` name the effective spp, max_depth and
 * components. */
ns_render_settings ns_render_settings_resolve(ns_render_settings settings);

/* Whether render.adaptive_spp can add samples with this method at this spp: not for pt, which
 * ignores it, and not at spp 1, where there is no spread to place them by. */
int ns_adaptive_spp_applies(ns_method method, uint32_t spp);
/* Whether asking for adaptive_spp > 0 is refused: samples that could go nowhere (spp 1),
 * whatever the method but pt, which ignores the setting. The scene parser and the library's
 * scene check both refuse it, each naming the field its own way. */
int ns_adaptive_spp_refused(ns_method method, uint32_t spp, float adaptive_spp);
/* render.adaptive_spp as a render with these resolved settings uses it: 0 where it adds
 * nothing (where it does not apply, or without the surface component, whose light is all
 * that the added samples add). What an image's metadata reports. */
float ns_adaptive_spp_used(const ns_render_settings *resolved);

typedef struct ns_scene {
    ns_camera camera;
    const ns_material *materials;
    uint32_t material_count;
    const ns_object *objects;
    uint32_t object_count;
    const ns_triangle *triangles;
    uint32_t triangle_count;
    const ns_light *lights;
    uint32_t light_count;
    ns_render_settings render;
} ns_scene;

/* ---------------------------------------------------------------------------------------
 * Context: instance, device, queue, pipelines and pipeline cache, made once at start-up.
 * One context may be used by one render at a time (the server serialises renders).
 * ------------------------------------------------------------------------------------- */
typedef struct ns_context ns_context;

/* Monte Carlo tables for method "table", supplied by the caller (the render library does not
 * link the offline tracer): fills j_double and j_multiple, NS_TABLE_CELLS floats each on the
 * default grid (shaders/scatter_shared.h), for one channel (g, albedo). */
typedef int (*ns_mc_tables_fn)(void *user, double g, double albedo, float *j_double,
                               float *j_multiple, ns_error *err);

typedef struct ns_context_desc {
    /* Device to use: NULL or "" picks lavapipe when present (else the first device);
     * otherwise a decimal index into the enumeration or a case-insensitive substring of
     * the device name. The NSCATTER_DEVICE environment variable is read when NULL. */
    const char *device;
    int validation; /* 1: enable VK_LAYER_KHRONOS_validation; any validation message
                       then fails the call that caused it. Also NSCATTER_VALIDATION=1. */
    const char *pipeline_cache_path; /* NULL: no on-disk pipeline cache */
    ns_mc_tables_fn mc_tables;        /* NULL: method "table" is not available */
    void *mc_user;
    uint64_t table_cache_bytes;       /* bound on cached tables; 0: 1 GiB */
    /* Folder where tables that outlive a material are kept between processes, checked on
     * every read (e.g. ns_cache_dir's): the albedo nodes of interpolated tables
     * (render.tables). NULL or "": memory only.
     * Their files there are kept within table_dir_bytes (0: 2 GiB), the least recently used
     * removed first. */
    const char *table_node_dir;
    uint64_t table_dir_bytes;
} ns_context_desc;

int ns_context_create(const ns_context_desc *desc, ns_context **out, ns_error *err);
void ns_context_destroy(ns_context *ctx); /* NULL is allowed */

/* ns_device_info.memory_types' bits (Vulkan's VkMemoryPropertyFlagBits, which they equal). */
enum {
    NS_MEMORY_DEVICE_LOCAL = 1u << 0,
    NS_MEMORY_HOST_VISIBLE = 1u << 1,
    NS_MEMORY_HOST_COHERENT = 1u << 2,
    NS_MEMORY_HOST_CACHED = 1u << 3,
};

typedef struct ns_device_info {
    char device_name[256];
    char driver_name[256];
    char driver_info[256];
    uint32_t api_version;
    uint32_t vendor_id, device_id;
    int is_cpu; /* 1 for lavapipe and other CPU devices */
    uint32_t subgroup_size;
    uint64_t device_local_bytes; /* the largest device-local memory heap */
    /* The memory types in the device's order, each as NS_MEMORY_* bits: which one a buffer
     * gets depends on them (docs/rendering.md, *Device choice*). */
    uint32_t memory_type_count;
    uint32_t memory_types[32];
    /* What the device offers for hardware traversal (VK_KHR_ray_query, and ray-tracing
     * pipelines), each with VK_KHR_acceleration_structure. Reported, not used: every stage
     * traces through the compute BVH (trace.glsl) on every device. */
    int ray_query, ray_tracing_pipeline;
} ns_device_info;

void ns_context_device_info(const ns_context *ctx, ns_device_info *out);

/* Device buffers alive now that a render made (buffers the context keeps on purpose, such as
 * cached tables, are not counted): every finished, failed or cancelled render brings it back
 * to where it was, so a service can watch for leaks. Safe to call while a render runs. */
uint32_t ns_context_live_buffers(const ns_context *ctx);

/* Bytes the context's table cache holds now (the J tables in host memory and the A tables
 * on the device), at most ns_context_desc.table_cache_bytes but for one table larger than
 * that alone. Safe to call while a render runs; 0 for NULL. */
uint64_t ns_context_table_cache_bytes(const ns_context *ctx);

/* Work a context can do while it has nothing to render (nscatter serve's worker asks when
 * its queue has been empty for a moment): it makes the albedo nodes of a g whose albedos are
 * being explored, so that the next albedo there blends its tables in tens of milliseconds
 * instead of making exact ones (docs/rendering.md, *Nodes made between renders*). A g
 * qualifies once render.tables "auto" has made exact tables at two or more of its albedos
 * (per accumulation mode); its nodes are those the blends of those albedos read, then one
 * more on each side, made three at a time (one call: about one material's exact tables),
 * kept in the table cache and the table folder. First the g of the material that auto last
 * made exact tables for. Only where the cache has room for them without evicting anything.
 * *made: the nodes made by this call, 0 when nothing is left to make (the caller can stop
 * asking until the next render). cancel: as in ns_render_control (a render that arrives
 * sets it); the call stops at its next device submission and returns NS_ERR_CANCELLED,
 * keeping nothing half made (set after its last submission, the nodes are kept but not
 * written to the table folder). Takes the context's lock, as a render does. */
int ns_context_idle_work(ns_context *ctx, const int *cancel, uint32_t *made, ns_error *err);

/* ---------------------------------------------------------------------------------------
 * Rendering.
 * ------------------------------------------------------------------------------------- */
typedef struct ns_image {
    uint32_t width, height;
    float *rgb; /* linear radiance, 3 floats per pixel, row 0 at the top; owned by the image */
} ns_image;

void ns_image_free(ns_image *img); /* frees rgb and zeroes the struct; NULL is allowed */

#define NS_MAX_STAGES 24
typedef struct ns_stage_time {
    char name[32]; /* e.g. "upload", "bvh", "ray_pass", "readback" */
    double ms;
} ns_stage_time;

typedef struct ns_render_stats {
    ns_stage_time stages[NS_MAX_STAGES];
    uint32_t stage_count;
    uint64_t camera_segments; /* stretches of camera paths inside media */
    uint64_t bvh_nodes;
    uint64_t primitives;
    /* Scattering stages (0 when not run). */
    uint64_t vrl_paths;           /* light paths traced */
    uint64_t vrl_count;           /* VRLs stored */
    uint64_t boundary_sources;    /* render.boundary: sources (ghost and reflected beams) gathered */
    uint64_t gather_segments;     /* camera segments gathered (after tiling) */
    uint64_t tiles_interpolated;  /* tiles interpolated from coarser ones (render.gather_levels) */
    uint64_t single_interpolated; /* pixels whose single scattering was interpolated
                                     (render.single_levels) */
    uint64_t corrections_interpolated; /* render.boundary: tiles that gathered their VRLs and took
                                          the correction from coarser ones */
    uint64_t interactions;        /* VRL-segment pairs evaluated by the gather */
    uint64_t cells_culled;        /* hierarchy nodes skipped with their subtrees: beyond the table's reach */
    uint64_t cells_represented;   /* hierarchy nodes replaced by their representative VRL */
    uint64_t weights_bytes;       /* network weights used (nn) */
    uint64_t table_bytes;         /* scattering tables held on the device for this render */
    /* What this render took from the context's caches instead of making it again, so a
     * sweep of materials over one geometry can say what it reused. A table counts once per
     * render, however many gather rounds or camera batches ask for it. */
    uint64_t tables_reused;       /* scattering tables (A or J of one key) found in the cache */
    uint64_t tables_made;         /* scattering tables reconstructed or accumulated */
    /* Scattering tables (A of one material and one set of orders) blended from albedo nodes
     * rather than made exact: render.tables "interpolated", or "auto" where it chose to
     * blend. Two renders of one scene with "auto" can differ within the blend's error
     * (0.35%); this says which blended. */
    uint64_t tables_blended;
    /* Camera samples added to the pixels whose neighbours spread most (render.adaptive_spp);
     * 0 when the camera pass was kept from an earlier render (which added them). */
    uint64_t adaptive_samples;
    /* 1: the BVH of the same geometry (the spheres', boxes' and triangles' numbers, bit for
     * bit; materials, lights, camera and planes may differ) was kept from the context's last
     * render that built one. The stage "bvh" is still listed, with the time of the
     * comparison. The image is the same either way. */
    uint32_t bvh_reused;
    /* 1: the camera pass (surface image and segments) was kept from one of the context's last
     * two renders, which made the same one: same geometry, camera, lights, planes, samples and
     * seed, and media that differ at most in what the camera pass does not read (sigma_s
     * and g: albedo at a fixed extinction, and g). No stage "ray_pass" is listed then. The
     * image is the same, bit for bit (render/camera_keep.c). */
    uint32_t camera_reused;
    /* 1: the light's sources (the VRLs and, with render.boundary, the boundary sources of
     * the table and dipole methods) were kept from one of the context's last two renders, which
     * made the same ones: same geometry, media, lights, seed and VRL count (and components, with
     * the boundary correction), whatever the camera. No stage "vrl" or "boundary" is listed then.
     * The image is the same, bit for bit (render/source_keep.c). */
    uint32_t sources_reused;
    /* 1: single scattering's image was kept with that camera pass (camera_reused is 1 too)
     * from the render that made it, whose inputs per unit sigma_s were the same: another
     * albedo of one medium at the same extinction, as a sweep makes (render/camera_keep.c
     * says exactly when). The image is the same, bit for bit; no stage "single" is listed
     * then, and single_interpolated stays 0. */
    uint32_t single_reused;
} ns_render_stats;

/* Renders scene into *out (allocated here). Render settings left 0 take their defaults
 * (ns_render_settings). Checks the scene's structural invariants
 * again (indices in range, finite numbers) and fails with NS_ERR_INVALID_ARGUMENT rather
 * than trusting the caller. Requested components that this build cannot render yet fail
 * with NS_ERR_NOT_AVAILABLE and a message naming them. stats may be NULL; else it is cleared
 * first and holds this render's figures alone. */
int ns_render(ns_context *ctx, const ns_scene *scene, ns_image *out, ns_render_stats *stats,
              ns_error *err);

/* Progress and cancellation of one render (ns_render_controlled).
 *
 * Progress reports come on the rendering thread, synchronously, in this order: a
 * STAGE_START when a stage begins (stage names as in ns_render_stats: "pt_pipeline", "bvh",
 * "upload", "ray_pass", "pt_pass", "single", "vrl", "boundary", "grid", "reconstruct", "accumulate",
 * "gather_pipeline", "gather", "composite", "readback"; a stage that runs once per camera
 * batch, medium or gather round starts and ends each time), TICKs while a long stage runs
 * (after every submission of pt_pass, single and the vrl method's gather, after each gather
 * submission, between Monte Carlo table channels), and a STAGE_END with the time of that run
 * of the stage; the END times of a stage add up to its time in ns_render_stats, and every
 * stage listed there is reported. Stages do not nest. `fraction` estimates the part of the
 * whole render done: in [0, 1], never decreasing within a render, exactly 1 at the last
 * STAGE_END ("readback"); pt's counts the samples finished, the other methods' come from
 * nominal shares (docs/rendering.md). The callback must be quick and must not call into the
 * context. */
typedef enum {
    NS_PROGRESS_STAGE_START = 0,
    NS_PROGRESS_STAGE_END = 1,
    NS_PROGRESS_TICK = 2,
} ns_progress_kind;

typedef struct ns_progress {
    ns_progress_kind kind;
    const char *stage; /* valid during the call only */
    double fraction;   /* of the whole render */
    double stage_ms;   /* STAGE_END: how long this run of the stage took; else 0 */
} ns_progress;

typedef void (*ns_progress_fn)(void *user, const ns_progress *progress);

typedef struct ns_render_control {
    /* When not NULL and *cancel becomes nonzero (set from any thread, and left set; read
     * with an acquire load), the render stops before its next device submission (or at the
     * next check between stages): nothing waits for the whole render, every buffer it made
     * is freed, nothing half made enters the context's caches, and it returns
     * NS_ERR_CANCELLED with a message naming where ("cancelled during pt_pass", "cancelled
     * after bvh", "cancelled before the first stage"). From the moment the render sees the
     * flag it reports only the STAGE_ENDs of the stages it leaves. A flag set after the
     * render's last check leaves the render to finish normally. The context stays usable:
     * the next render is the same as on a fresh context. */
    const int *cancel;
    ns_progress_fn progress; /* NULL: no reports */
    void *user;
} ns_render_control;

/* ns_render with progress reports and a cancellation flag; control may be NULL, or have
 * every field 0 (then it is ns_render exactly: the same image, bit for bit). */
int ns_render_controlled(ns_context *ctx, const ns_scene *scene, const ns_render_control *control,
                         ns_image *out, ns_render_stats *stats, ns_error *err);

/* Whether `method` can render medium material m at all: the network of method "nn" covers g
 * in [0, 1) and single-scattering albedo in [0, 1). Returns 0, or NS_ERR_INVALID_ARGUMENT
 * with *field the parameter at fault ("g" or "albedo") and err saying why. The parser uses it
 * to refuse such a scene with a pointer to the material before anything renders. */
int ns_material_supported(ns_method method, const ns_material *m, const char **field,
                          ns_error *err);

/* Which of `components` (NS_COMPONENT_* bits) this build can render with `method`:
 * returns the subset it cannot (0 when all can be rendered). The parser uses it to reject
 * a request early with a pointer to the component, never to ignore one silently. */
uint32_t ns_unsupported_components(ns_method method, uint32_t components);

/* Adds a named stage time to stats: to the stage of that name when there is one (a stage
 * that runs several times adds up), else as a new stage (ignored when full). Also used by
 * the server to report parse and encode stages in the same list. */
void ns_stats_add_stage(ns_render_stats *stats, const char *name, double ms);

/* Monotonic clock in milliseconds, for stage timings. */
double ns_now_ms(void);

/* ---------------------------------------------------------------------------------------
 * Files.
 * ------------------------------------------------------------------------------------- */
/* Replaces the file at path with `size` bytes of data, atomically: they go to a new
 * temporary file beside it (PATH.tmp.XXXXXX, mode 0644), which is flushed to the disk
 * (fsync) and renamed over path, and then the folder is flushed too. A reader sees the old
 * file or the whole new one, never a part, also after a crash; on any failure the old file
 * is left as it was and the temporary file is removed. Returns 0, or NS_ERR_IO with a
 * message that names the path and errno as the failing call set it
 * (NS_ERR_OUT_OF_HOST_MEMORY when out of memory). */
int ns_write_file_atomic(const char *path, const void *data, size_t size, ns_error *err);

/* The same for a file made of several pieces written one after the other (a header, then
 * the data it describes), without copying them into one buffer first. */
typedef struct ns_file_part {
    const void *data;
    size_t size;
} ns_file_part;
int ns_write_file_atomic_parts(const char *path, const ns_file_part *parts, size_t count,
                               ns_error *err);

/* The folder of nscatter's caches on disk (Monte Carlo tables, albedo nodes): `given` when
 * not NULL or empty, else $NSCATTER_CACHE_DIR, else $XDG_CACHE_HOME/nscatter, else
 * $HOME/.cache/nscatter; written into dir (cap bytes). `what` names the cache in messages.
 * NS_ERR_INVALID_ARGUMENT when none is set or the name does not fit. */
int ns_cache_dir(const char *given, const char *what, char *dir, size_t cap, ns_error *err);
/* mkdir -p dir, then checks that it is a folder; NS_ERR_IO naming `what` and the path. */
int ns_make_dirs(const char *dir, const char *what, ns_error *err);

#ifdef __cplusplus
}
#endif
#endif
