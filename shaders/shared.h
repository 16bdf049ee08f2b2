/* shared.h — GPU structs and constants, included by both the C code and the GLSL shaders so
 * that a layout or a constant cannot drift between them (niagara's config.h idea).
 *
 * Every struct is laid out for std430 (storage buffers) and, because it uses only 16-byte
 * members or a vec3 followed by one 4-byte scalar, is also valid std140 (uniform buffers).
 * The C side checks sizes and offsets with _Static_assert at the bottom of this file.
 */
#ifndef NS_SHADERS_SHARED_H
#define NS_SHADERS_SHARED_H

#if defined(__STDC__) || defined(__cplusplus)
#include <stddef.h>
#include <stdint.h>
typedef float ns_vec3[3];
typedef float ns_vec4[4];
typedef uint32_t ns_uint;
typedef uint32_t ns_uvec4[4];
#define NS_CONST(type, name, value) enum { name = value }
#else
#define ns_vec3 vec3
#define ns_vec4 vec4
#define ns_uint uint
#define ns_uvec4 uvec4
#define NS_CONST(type, name, value) const type name = value
/* Zero, in a form no compiler can see through. Every uniform and push-constant block is
 * declared as an array of one and read at index NS_OPAQUE_ZERO (`#define params
 * ns_params[NS_OPAQUE_ZERO]`), so that no load from it has a constant offset. Mesa 22.3's
 * lavapipe (Debian 12's) "inlines uniforms": a compute shader with an `if` or a loop bound on
 * a value loaded at a constant offset is compiled again, with those values as constants, at
 * every bind of its pipeline, and the compiled variant is never freed: about 2 MiB of
 * process memory for every render, without end (tests/http_load.py found it; docs/http.md,
 * "Load and soak"). Same values, same pixels; the one extra integer compare is free. */
#define NS_OPAQUE_ZERO uint(gl_NumWorkGroups.x == 0u)
#endif

/* Specialisation constant ids that every pipeline is given (render/gpu/gpu_pipeline.c). */
NS_CONST(uint, NS_SPEC_CPU_THREADS, 0); /* lavapipe's threads; 0 on other devices */

/* Workgroup shape of the camera pass (one invocation per pixel) and of the BVH test. */
NS_CONST(uint, NS_CAMERA_GROUP_X, 8);
NS_CONST(uint, NS_CAMERA_GROUP_Y, 8);
NS_CONST(uint, NS_TRACE_GROUP, 64);

/* Traversal stack depth. The builder's surface-area splits stop at NS_BVH_MAX_DEPTH; a leaf
 * there with more than NS_BVH_LEAF_ENTRY_MAX primitives is halved further (at most 20 more
 * levels for NS_BVH_MAX_PRIMS primitives: leaves at depth 80 at most, root = 1), and a
 * traversal holds at most one entry per level plus one, so the stack cannot overflow. */
NS_CONST(uint, NS_BVH_STACK, 84);
NS_CONST(uint, NS_BVH_MAX_DEPTH, 60);
NS_CONST(uint, NS_BVH_LEAF_MAX, 4);
/* The traversal's stack entry of a leaf holds its first primitive below bit
 * NS_BVH_ENTRY_COUNT_SHIFT and its count in the 6 bits above (trace.glsl, node_entry): no
 * leaf holds more, no BVH more primitives. */
NS_CONST(uint, NS_BVH_ENTRY_COUNT_SHIFT, 25);
NS_CONST(uint, NS_BVH_LEAF_ENTRY_MAX, 63);
NS_CONST(uint, NS_BVH_MAX_PRIMS, 33554432);

/* Deferred Fresnel branches a camera path may hold (see camera.comp: split deterministically
 * while there is room, choose by the Fresnel probability when full). */
NS_CONST(uint, NS_BRANCH_STACK, 6);

/* Primitive kinds in GpuPrim.info.x. Planes are kept after the BVH primitives. */
NS_CONST(uint, NS_PRIM_SPHERE, 0);
NS_CONST(uint, NS_PRIM_BOX, 1);
NS_CONST(uint, NS_PRIM_TRIANGLE, 2);
NS_CONST(uint, NS_PRIM_PLANE, 3);
NS_CONST(uint, NS_PRIM_SMOOTH, 1); /* GpuPrim.info.w bits */
NS_CONST(uint, NS_PRIM_SHADOW_PASSES, 2); /* an index-matched medium's boundary: shadow rays cross it */
NS_CONST(uint, NS_PRIM_REFRACTS, 4); /* a refracting medium's boundary: single scattering crosses it */

/* Light kinds in GpuLight.info.x (same values as ns_light_type). */
NS_CONST(uint, NS_GPU_LIGHT_DIRECTIONAL, 0);
NS_CONST(uint, NS_GPU_LIGHT_POINT, 1);
NS_CONST(uint, NS_GPU_LIGHT_SPHERE, 2);
NS_CONST(uint, NS_GPU_LIGHT_ENVIRONMENT, 3);

/* "No hit" primitive id and "outside every medium", and the flag in GpuSegment.depth (too
 * large for a C enum constant). */
#if defined(__STDC__) || defined(__cplusplus)
#define NS_NONE 0xffffffffu
#define NS_SEGMENT_ENTERED 0x80000000u
#define NS_MIN_SEGMENT_THROUGHPUT 1e-3f
#else
const uint NS_NONE = 0xffffffffu;
const uint NS_SEGMENT_ENTERED = 0x80000000u;
const float NS_MIN_SEGMENT_THROUGHPUT = 1e-3;
#endif

/* Camera paths split at every Fresnel boundary, and inside a medium most of their stretches
 * come from internal reflections whose throughput falls by the Fresnel reflectance each time
 * (3.4% at normal incidence for ior 1.45). A stretch whose throughput is below
 * NS_MIN_SEGMENT_THROUGHPUT in every channel can add at most that fraction of what a fully
 * transmitted one adds to the scattering components: it is not recorded (its Beer-Lambert
 * surface light is still followed). docs/scattering.md measures the effect. */

/* Camera pass parameters (uniform buffer, binding 0). */
struct GpuParams {
    ns_vec4 cam_position; /* xyz; w = tan(horizontal fov / 2) */
    ns_vec4 cam_right;    /* unit; w = tan(vertical fov / 2) */
    ns_vec4 cam_up;       /* unit */
    ns_vec4 cam_forward;  /* unit */
    ns_vec4 environment;  /* summed environment radiance (rgb); w unused */
    ns_uvec4 image;       /* width, height, spp, seed */
    ns_uvec4 counts;      /* max_depth, light_count, segment_capacity, node_count */
    ns_uvec4 prims;       /* bvh prim count, plane count, material count, ray count (tests) */
    ns_uvec4 limits;      /* x = loop iterations an invocation may run (0 = no limit) */
    ns_uvec4 surface;     /* x = render.light_samples: camera.comp's shadow rays per light
                             (and the environment) at each diffuse surface; y = the bits of
                             render.adaptive_spp as used (ns_adaptive_spp_used: 0 where it
                             adds nothing; no shader reads it: it is here so
                             that a camera pass kept for a later render, which includes the
                             added samples, is kept only for the same setting); z = 1 when an
                             object is a box of a refracting medium that scatters
                             (render/single.c then
                             takes single_box_faces.comp; no shader reads it); w unused */
};

/* Push constants of the camera pass: which samples this dispatch takes. The pass may be
 * split into several dispatches (see render.c: lavapipe's loop limit). With added_count > 0
 * the dispatch takes the added samples instead (render.adaptive_spp): one invocation per
 * entry [first_sample, first_sample + added_count) of the added-sample buffer, which says
 * which pixel and sample index (GpuAddedSample) and gets the sample's radiance back. */
struct GpuSamplePush {
    ns_uint first_sample;
    ns_uint sample_count;
    ns_uint pad0;
    ns_uint added_count;
};

/* One added camera sample (binding 8 of the camera pass): render.c writes which pixel and
 * which sample index (spp and up: points of the pixel's low-discrepancy sequence and random
 * streams that its first spp samples did not take) in x and y; camera.comp overwrites the
 * entry with the sample's surface radiance, the bits of its r, g, b in x, y, z (integers,
 * not floats, both ways: a pixel index read as a float would be a denormal, which a device
 * may flush to zero). */
struct GpuAddedSample {
    ns_uvec4 words;
};

/* Push constants of single scattering (single.comp): samples [first_sample, first_sample +
 * sample_count) of the `samples` strata along each of segment_count segments. The
 * samples are split across dispatches (render/single.c: lavapipe's loop limit); a dispatch
 * with first_sample 0 writes its segments' outputs, later ones add to them. */
struct GpuSinglePush {
    ns_uint first_sample;
    ns_uint sample_count;
    ns_uint samples; /* all samples of a segment (N: the strata of the distance CDF) */
    ns_uint segment_count;
};

/* lavapipe (llvmpipe) stops any loop after 65535 iterations in one shader invocation
 * (gallivm's LP_MAX_TGSI_LOOP_ITERATIONS), silently. The camera pass counts its own loop
 * iterations and reports (counter NS_COUNTER_LOOP_LIMIT) rather than return a wrong image;
 * the budget leaves room for SIMD lanes that diverge. */
NS_CONST(uint, NS_LAVAPIPE_LOOP_BUDGET, 24000);

/* BVH node: an interior node has count 0 and children first, first + 1; a leaf has count
 * primitives starting at first (in GpuPrim order). */
struct GpuNode {
    ns_vec3 bmin;
    ns_uint first;
    ns_vec3 bmax;
    ns_uint count;
};

/* One primitive. sphere: a = centre, radius in a.w; box: a = min, b = max; triangle: a, b, c
 * the vertices (counter-clockwise seen from outside); plane: a = point, b = unit normal.
 * info = kind, material index, object index, flag bits (NS_PRIM_SHADOW_PASSES: the boundary
 * of an index-matched medium; NS_PRIM_REFRACTS: of a refracting one; NS_PRIM_SMOOTH: a
 * triangle whose a.w, b.w, c.w hold its vertices' shading normals, octahedral in 2 x 16
 * bits; scene_gpu.c). */
struct GpuPrim {
    ns_vec4 a;
    ns_vec4 b;
    ns_vec4 c;
    ns_uvec4 info;
};

/* reflectance.w = 1 for a medium, 0 for diffuse; sigma_t.w = ior; sigma_s.w = g. */
struct GpuMaterial {
    ns_vec4 reflectance;
    ns_vec4 sigma_t;
    ns_vec4 sigma_s;
};

/* position.w = sphere radius; direction = unit travel direction (directional);
 * color = irradiance / intensity / radiance; info.x = kind. */
struct GpuLight {
    ns_vec4 position;
    ns_vec4 direction;
    ns_vec4 color;
    ns_uvec4 info;
};

/* A stretch of a camera path inside a medium, for the scattering passes: entry and exit
 * points, unit direction, the path throughput at the entry (before Beer-Lambert along this
 * stretch, not divided by spp), the medium's material index, and where it came from.
 * depth = boundary bounces before the stretch, with NS_SEGMENT_ENTERED set when the path
 * crossed into the medium from outside just before it (the dipole's exit points). */
struct GpuSegment {
    ns_vec3 entry;
    ns_uint pixel;
    ns_vec3 exit;
    ns_uint material;
    ns_vec3 direction;
    ns_uint sample_index;
    ns_vec3 throughput;
    ns_uint depth;
};

/* counters[0] = segments recorded (may exceed capacity), counters[1] = overflowed,
 * counters[2] = invocations that ran out of loop budget. */
NS_CONST(uint, NS_COUNTER_SEGMENTS, 0);
NS_CONST(uint, NS_COUNTER_OVERFLOW, 1);
NS_CONST(uint, NS_COUNTER_LOOP_LIMIT, 2);
NS_CONST(uint, NS_COUNTER_COUNT, 4);

/* BVH test shader: one ray in, the nearest hit out. */
/* A ray of trace_test.comp: direction.w = 1 asks the shadow rays' any-hit query, 0 the
 * nearest hit. */
struct GpuRay {
    ns_vec4 origin; /* w = tmax */
    ns_vec4 direction;
};

struct GpuHit {
    float t;
    ns_uint prim;    /* index into GpuPrim order, NS_NONE for a miss; any-hit: 0 if blocked */
    ns_uint front;
    ns_uint crossed; /* any-hit only: 1 if what it met is an NS_PRIM_SHADOW_PASSES primitive */
};

#if defined(__STDC__) || defined(__cplusplus)
typedef struct GpuParams GpuParams;
typedef struct GpuNode GpuNode;
typedef struct GpuPrim GpuPrim;
typedef struct GpuMaterial GpuMaterial;
typedef struct GpuLight GpuLight;
typedef struct GpuSegment GpuSegment;
typedef struct GpuRay GpuRay;
typedef struct GpuHit GpuHit;
typedef struct GpuSamplePush GpuSamplePush;
typedef struct GpuAddedSample GpuAddedSample;
typedef struct GpuSinglePush GpuSinglePush;
_Static_assert(sizeof(GpuParams) == 160, "GpuParams std430 size");
_Static_assert(sizeof(GpuSamplePush) == 16, "GpuSamplePush size");
_Static_assert(sizeof(GpuSinglePush) == 16 && offsetof(GpuSinglePush, segment_count) == 12,
               "GpuSinglePush layout");
_Static_assert(offsetof(GpuParams, image) == 80, "GpuParams.image offset");
_Static_assert(offsetof(GpuParams, prims) == 112, "GpuParams.prims offset");
_Static_assert(NS_BVH_MAX_PRIMS == 1u << NS_BVH_ENTRY_COUNT_SHIFT &&
                   NS_BVH_LEAF_ENTRY_MAX == 0xffffffffu >> (NS_BVH_ENTRY_COUNT_SHIFT + 1),
               "a leaf's stack entry: first primitive, count, the leaf flag in bit 31");
_Static_assert(sizeof(GpuNode) == 32 && offsetof(GpuNode, bmax) == 16, "GpuNode layout");
_Static_assert(offsetof(GpuNode, first) == 12 && offsetof(GpuNode, count) == 28, "GpuNode");
_Static_assert(sizeof(GpuPrim) == 64 && offsetof(GpuPrim, info) == 48, "GpuPrim layout");
_Static_assert(sizeof(GpuMaterial) == 48 && offsetof(GpuMaterial, sigma_s) == 32, "GpuMaterial");
_Static_assert(sizeof(GpuLight) == 64 && offsetof(GpuLight, info) == 48, "GpuLight layout");
_Static_assert(sizeof(GpuSegment) == 64, "GpuSegment std430 size");
_Static_assert(offsetof(GpuSegment, pixel) == 12 && offsetof(GpuSegment, exit) == 16, "GpuSegment");
_Static_assert(offsetof(GpuSegment, material) == 28 && offsetof(GpuSegment, direction) == 32,
               "GpuSegment");
_Static_assert(offsetof(GpuSegment, throughput) == 48 && offsetof(GpuSegment, depth) == 60,
               "GpuSegment");
_Static_assert(sizeof(GpuRay) == 32 && sizeof(GpuHit) == 16, "GpuRay/GpuHit layout");
#endif

#endif
