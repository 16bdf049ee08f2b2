/* scatter.h — (private to render/) the scattering stages of issue 5 and how render.c strings
 * them together after the camera pass:
 *
 *   tables   scatter_tables.c + shaders/accumulate.comp   J (network or Monte Carlo) -> A
 *   VRLs     vrl.c + shaders/vrl.comp + vrl_grid.c         light tracing -> VRLs -> grid
 *   gather   gather.c + shaders/gather.comp                A x VRL cells x camera segments
 *   single   single.c + shaders/single.comp                camera segments x lights
 *   vrl      vrl_method.c + shaders/vrl_*.comp             Novak et al. 2012 brute force
 *
 * Every stage writes, per camera segment, the radiance arriving at the segment's entry point
 * from inside the medium (RGB, vec4 per segment, w unused), before the segment's throughput,
 * the 1/spp and the boundary's radiance factor: render.c composes those into pixels.
 */
#ifndef NS_RENDER_SCATTER_H
#define NS_RENDER_SCATTER_H

#include "internal.h"
#include "scatter_shared.h"

/* ---------------------------------------------------------------------------------------
 * Tables (scatter_tables.c): the accumulated camera-side tables A of one material, for the
 * three channels, cached in the context (least recently used, bounded bytes).
 * ------------------------------------------------------------------------------------- */
/* An order beyond the components: the blurred first order of the boundary correction
 * (boundary.h), for light that has left a source unscattered. A source group's orders carry
 * it (ns_boundary_orders); it has no table: the gather computes it (gather.glsl,
 * first_order; until 2026-12-01 it was read from a table composed per material, whose
 * angular and radial reads missed it by factors of 0.3-2 at g 0.9), and ns_tables_get
 * refuses it. */
#define NS_TABLE_FIRST_BLURRED (1u << 16)

typedef struct ns_table_key {
    ns_method source;     /* NS_METHOD_NN (network) or NS_METHOD_TABLE (Monte Carlo) */
    float g;              /* shared by the channels */
    float albedo[3];      /* per channel */
    uint32_t orders;      /* NS_COMPONENT_DOUBLE and/or NS_COMPONENT_MULTIPLE (summed) */
    ns_accumulation accumulation; /* exact: A to infinity; paper: A over 5 mfp */
    ns_tables_mode tables;        /* exact, or blended from albedo nodes (nn only) */
    /* Where A is read (ns_table_reach_bins): a render reads it only between points of its
     * medium's objects, so cells beyond need no walk; 0 (or NS_TABLE_NRHO): every cell. A
     * cached table that reaches as far or farther serves the key. */
    uint32_t reach_bins;
} ns_table_key;

/* The table bins (each side of the source's plane in z, and in rho from the axis) that hold
 * every cell the gather reads for points up to reach_mfp apart (mfp, in |z| and in rho), with
 * a margin: NS_TABLE_NRHO (every cell) at or beyond the table's extent, or for a reach that
 * is not a number. */
uint32_t ns_table_reach_bins(double reach_mfp);

typedef struct ns_scatter_tables {
    gpu_buffer a;      /* float [3][NS_TABLE_CELLS]: A per channel, mfp units */
    float scale;       /* spatial edges: scale * sinh(step * i) (mfp) */
    float inv_step;    /* 1 / step */
    float extent;      /* outermost edge (mfp) */
    uint64_t bytes;    /* device bytes of a */
} ns_scatter_tables;

typedef struct ns_table_stats {
    double reconstruct_ms; /* network or Monte Carlo; 0 on a cache hit */
    double accumulate_ms;  /* 0 on a cache hit */
    int reconstructed;     /* some channel's J was made now (the stage "reconstruct" ran) */
    int accumulated;       /* A was accumulated now (the stage "accumulate" ran) */
    int cache_hit;
    uint64_t weights_bytes;
    /* Tables (A of the key, J of each distinct channel albedo) found in the cache and made
     * now; each table counts once per render (ns_run.serial), however often it is asked for. */
    uint32_t tables_reused, tables_made;
    /* The key's A is a blend of albedo nodes (render.tables "interpolated", or "auto"'s
     * choice): 1 the first time a render asks for it, else 0. */
    uint32_t tables_blended;
} ns_table_stats;

/* Returns the tables for key, computing and caching them when absent. The pointer stays
 * valid until the next call (the context lock is held by the caller throughout a render).
 * NS_METHOD_TABLE needs ctx's Monte Carlo provider (ns_context_desc.mc_tables), else
 * NS_ERR_NOT_AVAILABLE. Only whole tables enter the cache: a J or A whose making failed or
 * was cancelled is never cached. Inside a render the stages "reconstruct" and "accumulate"
 * report progress and take halves of the current span; the render's cancellation is checked
 * before each Monte Carlo channel (the provider runs on the CPU). */
int ns_tables_get(ns_context *ctx, const ns_table_key *key, const ns_scatter_tables **out,
                  ns_table_stats *stats, ns_error *err);

/* The albedos of the nodes that interpolated tables (ns_table_key.tables) are blended from,
 * for the context's networks, in increasing order (scatter_tables.c says how they are
 * placed); NS_ERR_NOT_AVAILABLE without networks. */
#define NS_TABLE_ALBEDO_NODES 15u
int ns_tables_node_albedos(ns_context *ctx, double albedo[NS_TABLE_ALBEDO_NODES], ns_error *err);

/* Context hooks (context.c): the networks (built-in weights) and their pipeline, created and
 * warmed at start-up, and the empty cache. A build without weights still makes a context;
 * NS_METHOD_NN then fails with NS_ERR_NOT_AVAILABLE naming the reason. */
int ns_tables_init(ns_context *ctx, ns_error *err);
void ns_tables_destroy(ns_context *ctx); /* frees the cache and the networks; safe twice */

/* The edges of the default table grid (render/include/table_grid.h, the grid offline/mc.c
 * fills; rebuilt here because render/ does not link offline/), in file order z, rho, theta,
 * phi. */
typedef struct ns_table_grid {
    double z[NS_TABLE_NZ + 1], rho[NS_TABLE_NRHO + 1];
    double theta[NS_TABLE_NTHETA + 1], phi[NS_TABLE_NPHI + 1];
    double scale, step, extent; /* spatial edges: scale * sinh(step * i) */
} ns_table_grid;
void ns_table_grid_default(ns_table_grid *g);

/* Accumulation of a given J (float [3][NS_TABLE_CELLS], host memory) into A (internal; the
 * tests feed synthetic tables). out->a is created here; free with ns_scatter_tables_free.
 * steps (may be NULL): bins walked in all, the unit of work (one J lookup per channel). */
int ns_tables_accumulate(ns_context *ctx, const float *j, ns_accumulation accumulation,
                         ns_scatter_tables *out, uint64_t *steps, ns_error *err);
/* The same with A in memory the host reads fast (gpu_buffer_desc.host_reads), for a table
 * read on the CPU, as the interpolated tables' nodes are; a gather would read it over PCIe
 * on a discrete GPU. */
int ns_tables_accumulate_for_host(ns_context *ctx, const float *j, ns_accumulation accumulation,
                                  ns_scatter_tables *out, uint64_t *steps, ns_error *err);
/* The same, told the rho bin from which J is 0 everywhere (ns_tables_accumulate finds it in
 * j; NS_TABLE_NRHO walks every cell's line): cells whose lines never come inside that radius
 * are 0 without a walk, exactly as a walk would make them (the test compares both). */
int ns_tables_accumulate_within(ns_context *ctx, const float *j, ns_accumulation accumulation,
                                uint32_t zero_from_rho, ns_scatter_tables *out, uint64_t *steps,
                                ns_error *err);
/* The same with the second three walked beside the three (shaders/accumulate_shared.h):
 * second_j float [3][NS_TABLE_CELLS], their A created in *second_out (both NULL: none). Each
 * set comes out as its own accumulation would make it, bit for bit; steps counts the bins of
 * the one walk, which lasts as long as its longer set. Only the cells within reach_bins
 * (ns_table_reach_bins; NS_TABLE_NRHO: all) are walked, each as in the whole table, bit for
 * bit; the others are 0. */
int ns_tables_accumulate_parts(ns_context *ctx, const float *j, const float *second_j,
                               ns_accumulation accumulation, uint32_t reach_bins,
                               ns_scatter_tables *out, ns_scatter_tables *second_out,
                               uint64_t *steps, ns_error *err);
void ns_scatter_tables_free(ns_context *ctx, ns_scatter_tables *t);
/* A copy of t's A (float [3][NS_TABLE_CELLS]) in out, read through a host-cached buffer
 * where t's own mapping is not host-cached (a discrete GPU's device memory: reading it
 * directly took seconds). */
int ns_scatter_tables_read(ns_context *ctx, const ns_scatter_tables *t, float *out, ns_error *err);
/* Says that the render about to run reads tables of these orders (double and/or multiple;
 * other bits are ignored) for its materials: an exact table it makes of
 * one announced set is walked together with that of another not cached yet, which then
 * waits in the cache (accumulate_shared.h, the second three). A render of multiple
 * scattering alone with boundary walks reads multiple for its VRLs and double + multiple for
 * the sources after an event (their orders shift by it: ns_boundary_orders): one walk
 * instead of two. */
void ns_tables_expect_orders(ns_context *ctx, uint32_t orders);

/* What the cache holds now (tests): bytes (device + host) and entries (J and A). */
void ns_tables_cache_usage(const ns_context *ctx, uint64_t *bytes, uint32_t *entries);
/* The cached J of one channel (tests): order 0 double, 1 multiple; NULL when not cached. */
const float *ns_tables_cached_j(const ns_context *ctx, ns_method source, float g, float albedo,
                                uint32_t order);

/* ---------------------------------------------------------------------------------------
 * Virtual Ray Lights (vrl.c, vrl_grid.c)
 * ------------------------------------------------------------------------------------- */
typedef struct ns_vrl_set {
    GpuVrl *vrls; /* malloc'd */
    /* The light's walks (ns_vrl_method_trace with NS_VRL_TRACE_ENDS): per stretch, the
     * reflection at its end (vrl_method_shared.h: the mirror direction, scaled by the
     * chord ahead for unscattered light, and F), 4 floats each, malloc'd; else NULL. */
    float *ends;
    uint32_t count;
    uint64_t paths; /* light paths traced */
} ns_vrl_set;

/* Traces `paths` light paths from the scene's lights towards its media (every light kind,
 * Fresnel-transmitted through smooth boundaries, power-correct) and keeps the first stretch
 * of each inside a medium, then up to chain - 1 internal reflections of its unscattered
 * beam (chain in [1, NS_VRL_MAX_CHAIN]; vrl.comp). A path's stretches are consecutive in
 * out->vrls. scene_buffers: the five scene buffers (ns_gpu_scene_buffer_descs) already on
 * the device. */
int ns_vrl_generate(ns_context *ctx, const ns_scene *scene, const ns_gpu_scene *gs,
                    gpu_buffer *scene_buffers, uint32_t paths, uint32_t chain, uint32_t seed,
                    ns_vrl_set *out, ns_error *err);
void ns_vrl_set_free(ns_vrl_set *set);

/* Power (mean of RGB) a scene light sends through a sphere (xyz centre, w radius): how both
 * VRL generators share their light paths out among lights and media. */
double ns_vrl_light_power(const GpuLight *light, const float sphere[4]);

/* The sphere light paths aim at for a medium object (xyz centre, w radius): a sphere
 * itself, else the sphere around its box, slightly enlarged. Not for planes. */
void ns_vrl_target_sphere(const ns_scene *scene, const ns_object *o, float out[4]);

/* A scattering medium object the light paths of both VRL generators aim at. */
typedef struct ns_vrl_target {
    float sphere[4]; /* centre, radius (ns_vrl_target_sphere) */
    uint32_t object;
} ns_vrl_target;

/* The scene's scattering medium objects (empty meshes skipped), into out (room for
 * scene->object_count). A plane of such a material is a half-space with no sphere to aim
 * at: NS_ERR_NOT_AVAILABLE naming the object, with `who` (the stage) in the message. */
int ns_vrl_targets(const ns_scene *scene, const char *who, ns_vrl_target *out, uint32_t *count,
                   ns_error *err);

/* Systematic sampling of light paths over strata: one offset xi in [0, 1) per seed
 * (splitmix64), and the first path of the stratum whose cumulative probability starts at
 * cdf: the smallest i with (i + xi) / paths >= cdf. */
double ns_vrl_seed_offset(uint32_t seed);
uint64_t ns_vrl_first_path_at(double cdf, uint32_t paths, double xi);

/* One stratum of light paths: paths [first_path, the next stratum's first_path or paths)
 * start at scene light `light` (gs->lights) and aim at targets[target]; p is the stratum's
 * share of the paths, so a path's flux weight is 1 / (p paths). */
typedef struct ns_vrl_stratum {
    uint32_t light, target, first_path, path_count;
    double p;
} ns_vrl_stratum;

/* The light-path stratification both VRL generators use (vrl.c, vrl_method.c): `paths`
 * paths spread over the (light, target) pairs by systematic sampling with the seed's offset,
 * in proportion to ns_vrl_light_power. *out (malloc'd, free it) holds the strata that got at
 * least one path, in path order; none (NULL, 0) when no light sends power through a target.
 * who names the stage in an out-of-memory message. */
int ns_vrl_stratify(const ns_gpu_scene *gs, const ns_vrl_target *targets, uint32_t target_count,
                    uint32_t paths, uint32_t seed, const char *who, ns_vrl_stratum **out,
                    uint32_t *count, ns_error *err);

/* The grid hierarchy of one medium's VRLs (paper Section 4.3): the cells of the chosen
 * (leaf) level, and the tree of every level from the coarsest down to it that the gather
 * walks (GpuVrlNode, shaders/scatter_shared.h). */
typedef struct ns_vrl_grid {
    GpuVrl *vrls;            /* the medium's VRLs, sorted by cell */
    uint32_t vrl_count;
    GpuVrlCell *cells;       /* non-empty cells of the chosen level only */
    GpuVrl *representatives; /* one per cell, same index */
    uint32_t cell_count;
    uint32_t level;          /* chosen level in the hierarchy, 0 = finest */
    uint32_t level_count;    /* levels built (2 to 5) */
    float cell_size;         /* edge of a cell of the chosen level (scene units) */
    GpuVrlNode *nodes;       /* depth first; the leaves are `cells`, in the same order */
    GpuVrl *node_representatives; /* one per node, same index */
    uint32_t node_count;     /* 0 for a grid made by hand (tests): the gather walks `cells` */
} ns_vrl_grid;

/* Builds the hierarchy over the VRLs of `material` for a medium whose smallest mean free
 * path is mfp_min (scene units); the leaves are the finest level whose cells hold leaf_fill
 * VRLs on average (0: NS_VRL_CELL_FILL, for the exact gather; NS_VRL_LEAF_FILL_REPRESENTED
 * when far nodes stand in for their VRLs). */
#define NS_VRL_CELL_FILL 16u
#define NS_VRL_LEAF_FILL_REPRESENTED 4u
int ns_vrl_grid_build(const ns_vrl_set *set, uint32_t material, float mfp_min, uint32_t leaf_fill,
                      ns_vrl_grid *out, ns_error *err);
void ns_vrl_grid_free(ns_vrl_grid *grid);

/* The representative of vrls[0, count) (count >= 1): total power, power-weighted (mean of
 * RGB) mean origin and direction, the longest length. Used for grid cells and for the
 * pieces the gather cuts large cells into. */
GpuVrl ns_vrl_representative(const GpuVrl *vrls, uint32_t count);

/* ---------------------------------------------------------------------------------------
 * Gather (gather.c, shaders/gather.comp): one medium's segments x its VRL grid.
 * ------------------------------------------------------------------------------------- */
/* Fills the gather's uniform block for a medium (material m), a mode (NS_GATHER_MODE_*), the
 * tables (NULL in dipole mode), the solid-angle threshold (0 = exact) and the beam model
 * (bounded_beams: each VRL's beam ends at its length, render.vrl_beams). */
void ns_gather_params(GpuGatherParams *p, const GpuMaterial *m, uint32_t mode,
                      const ns_scatter_tables *tables, float cull_solid_angle, int bounded_beams);
/* Makes the form add the boundary sources' blurred first order, computed (gather.glsl,
 * first_order): NS_GATHER_MODE_FIRST has it alone, the exact mode with endless beams besides
 * its table (gather_exact_first.comp). */
void ns_gather_params_first(GpuGatherParams *p, const GpuMaterial *m);

typedef struct ns_gather_desc {
    GpuGatherParams params;       /* counts.x/y/z are filled by ns_gather_run */
    gpu_buffer *segments;         /* GpuSegment buffer; this medium's are a contiguous range */
    uint32_t first_segment, segment_count;
    const ns_vrl_grid *grid;
    const gpu_buffer *table;      /* A per channel; NULL in dipole mode */
    gpu_buffer *out;              /* vec4 per segment of the whole buffer (same indices) */
    int add;                      /* 1: add to what out holds (a second form on the same grid) */
} ns_gather_desc;

typedef struct ns_gather_counts {
    uint64_t interactions, cells_culled, cells_represented;
    uint32_t dispatches;
} ns_gather_counts;

int ns_gather_run(ns_context *ctx, const ns_gather_desc *desc, ns_gather_counts *counts,
                  ns_error *err);

/* Each form of the gather (mode x bounded beams x first order) has its own shader (gather.glsl says
 * why). The default (exact, endless) is made with the context; the others are made and compiled by
 * the first gather that needs them and kept. Points *pipeline at the form's pipeline;
 * *made_ms = the time spent making it now (0 if it was there). ns_gather_run calls it;
 * renders call it first to report that time as the stage "gather_pipeline". */
int ns_gather_pipeline(ns_context *ctx, const GpuGatherParams *params, gpu_pipeline **pipeline,
                       double *made_ms, ns_error *err);

/* The nodes the gather walks: the grid's tree (depth first, GpuVrlNode.skip past each
 * subtree) with every leaf too large for one dispatch under lavapipe's loop budget cut into
 * pieces, and a representative VRL per node. ns_gather_run builds them for the GPU; the
 * CPU reference of the tests (tests/oracles/gather_cpu.c) builds the same ones, so that
 * both walk the same nodes. Build returns 0, or -1 out of memory (out freed). */
typedef struct ns_gather_nodes {
    GpuVrlNode *nodes;
    GpuVrl *representatives;
    uint32_t count;
} ns_gather_nodes;

int ns_gather_nodes_build(const ns_vrl_grid *grid, ns_gather_nodes *out);
void ns_gather_nodes_free(ns_gather_nodes *n);

/* Node ranges [first_cell, first_cell + cell_count) of tree for the dispatches, written into
 * push (room for tree->count + 1): each a run of whole subtrees whose walk stays within
 * `budget` loop iterations even if it culls and represents nothing (every node visited,
 * every leaf's VRLs evaluated). A subtree too large for one range is left out and its
 * children are placed instead: its representative is then never used, and its light comes
 * from the children. budget 0: one range. Returns the number of ranges. */
uint32_t ns_gather_ranges(const ns_gather_nodes *tree, uint32_t budget, GpuGatherPush *push);

/* ---------------------------------------------------------------------------------------
 * Single scattering (single.c): up to `samples` strata along every segment (fewer where its
 * throughput is low), points drawn from the camera's transmittance, connected to the
 * environment at each and to the other lights at one in four (refracted at a smooth boundary
 * as in Jensen et al. 2001), Beer-Lambert inside the medium, Henyey-Greenstein phase.
 * out: vec4 per segment.
 * ------------------------------------------------------------------------------------- */
int ns_single_scatter(ns_context *ctx, gpu_buffer *scene_buffers, gpu_buffer *segments,
                      uint32_t segment_count, uint32_t samples, gpu_buffer *out, ns_error *err);

/* Single scattering per unit sigma_s (render/camera_keep.c says why): reference[c] := the
 * largest of the materials' sigma_s in channel c (0 where all are 0); unit[i] := materials[i]
 * with sigma_s divided by it, or 0 where it is 0, g kept. Every quotient lies in [0, 1] (no
 * overflow), and a scene's one medium has exactly 1 wherever it scatters. */
void ns_single_unit_materials(const GpuMaterial *materials, uint32_t count, GpuMaterial *unit,
                              float reference[3]);

/* The order in which to hand `count` segments to ns_single_scatter: by their strata, most
 * first (stable, so segments of one count keep their order). lavapipe runs the lanes of a SIMD
 * group in lockstep, and a group pays for its longest segment's strata: in pixel order the
 * bench's bumpy sphere mixes segments of 62 strata with internal reflections of 1, and 60% of
 * the lanes' strata were idle. Fills order[count]; returns -1 when out of memory. */
int ns_single_order(const GpuSegment *segs, uint32_t count, uint32_t samples, uint32_t *order);

/* ---------------------------------------------------------------------------------------
 * The `vrl` method (vrl_method.c): VRLs from every light-path stretch in the media, ray-to-ray
 * transport by sampling, no tables. out_double / out_multiple: vec4 per segment (orders 2
 * and >= 3). stats gets vrl_paths, vrl_count, interactions.
 * ------------------------------------------------------------------------------------- */
int ns_vrl_method_gather(ns_context *ctx, const ns_scene *scene, const ns_gpu_scene *gs,
                         gpu_buffer *scene_buffers, gpu_buffer *segments, uint32_t segment_count,
                         gpu_buffer *out_double, gpu_buffer *out_multiple, ns_render_stats *stats,
                         ns_error *err);

/* ---------------------------------------------------------------------------------------
 * The whole scattering part of a render (scatter_render.c), after the camera pass: single
 * scattering at every camera segment, double and multiple gathered for one pixel per
 * render.gather_tile block (plus every pixel that no neighbouring gathered pixel can stand
 * for: edge-aware upsampling), composed into pixels (3 floats each, added to).
 * ------------------------------------------------------------------------------------- */
typedef struct ns_scatter_inputs {
    const ns_scene *scene;
    const ns_gpu_scene *gs;
    gpu_buffer *scene_buffers; /* the five scene buffers on the device */
    gpu_buffer *segments;      /* the camera pass's GpuSegment buffer */
    uint32_t segment_count;    /* recorded in it */
    float *pixels;             /* linear RGB, 3 floats per pixel */
    /* Single scattering (render_single): the materials per unit sigma_s and each channel's
     * reference (ns_single_unit_materials; NULL only without the component), and its image
     * per unit (3 floats per pixel) or NULL. With single_given the stage takes that image
     * (render.c: kept with the camera pass, made from the same inputs) instead of computing
     * it, else it computes the batch's into it; the pixels get it times the reference. */
    const GpuMaterial *single_materials;
    float single_reference[3];
    float *single_image;
    int single_given;
} ns_scatter_inputs;

/* Squared distance, in pixels, from the centre of pixel p of a width x height image to where
 * the camera of `cam` (the camera pass's pinhole: cam_position.w = tan of half the horizontal
 * field, cam_right.w of the vertical) sees point x; INFINITY behind the camera. The gather
 * takes the camera samples nearest a pixel's centre by it (render.gather_camera_samples). */
float ns_from_pixel_centre(const GpuParams *cam, uint32_t width, uint32_t height, uint32_t p, const float x[3]);

/* Adaptive single scattering's noise (scatter_render.c), for the tests too. Per pixel, sums
 * over its camera samples j of what sample j added (X_j, the sum of its segments'
 * throughput * L / spp with the exit factor) and of its weight (W_j, the sum of their
 * throughput / spp): X_j^2, X_j W_j and W_j^2, per channel. */
typedef struct ns_sample_moments {
    float xx[3], xw[3], ww[3];
} ns_sample_moments;
/* Adds each pixel's samples' moments into moments[pixel]: `segs` holds each pixel's
 * segments together (any order within), added[i] and weight[i] are segment i's parts of X
 * and W, and a sample's segments are summed before they are squared. Returns 0, or -1 out of
 * memory. */
int ns_sample_moments_add(const GpuSegment *segs, const float (*added)[3],
                          const float (*weight)[3], uint32_t count, ns_sample_moments *moments);
/* The variance of Lbar = sum_x / w in channel c from the pixel's moments m, over spp camera
 * samples (0 where it cannot be told: spp < 2, w 0, not finite). */
float ns_ratio_variance(float sum_x, float w, const ns_sample_moments *m, int c, uint32_t spp);

/* The adaptive gather's decisions (render.gather_levels; scatter_render.c) on a width x
 * height image of tile x tile tiles (tile >= 1), for the tests: pixel p sees `material[p]`
 * (NS_NONE: nothing) at camera distance `distance[p]`; gather(p, radiance, field) gives the
 * radiance of a pixel the rounds gather, from the caller's field (a struct the test
 * defines: the library only passes it on). Fills every pixel's radiance (gathered,
 * interpolated, or upsampled from its tiles' representatives as the render composes it) and
 * interpolated[p]. curved: the interpolated values of adaptive single
 * scattering (a cubic or a parabola through the outer samples) instead of the gather's
 * means. other (NULL: none): per pixel, the light it shows besides the gathered part, in the
 * gather's units, which the tolerance counts too (the render's single scattering). variance
 * (NULL: none): per pixel, the variance of the value gather() gives it (adaptive single
 * scattering's rule for noisy values, noisy_line_agrees). Returns 0, or -1 out of memory. */
typedef struct ns_tile_field ns_tile_field;
int ns_adaptive_tiles(uint32_t width, uint32_t height, uint32_t tile, uint32_t levels,
                      float tolerance, int curved, const uint32_t *material, const float *distance,
                      const float (*other)[3], const float (*variance)[3],
                      void (*gather)(uint32_t pixel, float radiance[3], ns_tile_field *field),
                      ns_tile_field *field, float (*radiance)[3], uint8_t *interpolated);

int ns_scatter_render(ns_context *ctx, const ns_scatter_inputs *in, ns_render_stats *stats,
                      ns_error *err);

/* How a camera batch's part of the render's progress is shared out (scatter_render.c, by
 * nominal costs): the ray pass [0, shares[0]], single scattering [shares[0], shares[1]],
 * double and multiple [shares[1], 1]. ns_scatter_render is called in the batch's span. */
void ns_batch_shares(const ns_scene *scene, double shares[2]);

#endif
