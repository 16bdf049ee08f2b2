/* bench.h — `nscatter bench` (docs/bench.md): the paper's experiments (Ge et al. 2021,
 * Tables 2-4) on built-in scenes, against path-traced references cached outside git.
 * bench.c defines what is measured (methods, reference sets, the paper's figures);
 * cmd_bench.c runs the renders and keeps the results in the structs below; bench_report.c
 * turns them into report.md and contact_sheet.png. Both use bench.c, and only cmd_bench.c
 * calls bench_report.c. Everything here is private to the bench command.
 */
#ifndef NS_BENCH_H
#define NS_BENCH_H

#include <stdint.h>

#include <jansson.h>

#include "image_metrics.h"
#include "nscatter.h"

/* The rows of a scene, in the order they run (vrl after nn_full: it matches its time). */
typedef enum {
    BENCH_NN_SURFACE = 0, /* the camera pass alone: a check of the bench against pt's order 0 */
    BENCH_NN_MULTIPLE,
    BENCH_NN_DOUBLE, /* double + multiple */
    BENCH_NN_FULL,   /* surface + single + double + multiple */
    BENCH_TABLE,
    BENCH_DIPOLE,
    BENCH_VRL,
    BENCH_PT, /* a few short pt renders: the cost of pt's quality */
    BENCH_METHOD_COUNT
} bench_method_id;

#define BENCH_ALL NS_COMPONENT_ALL /* the full solution */

typedef struct bench_method_info {
    const char *name;    /* --methods name and report label */
    ns_method method;
    uint32_t components; /* NS_COMPONENT_* */
    const char *vrls_key; /* key of the manifest's "vrls" object; NULL: none */
    const char *label;
} bench_method_info;

extern const bench_method_info bench_methods[BENCH_METHOD_COUNT];

/* Reference component sets: one pt image per distinct set that a method compares with. */
#define BENCH_REF_SETS 4
extern const uint32_t bench_ref_components[BENCH_REF_SETS];
int bench_ref_index(uint32_t components); /* index into bench_ref_components, or -1 */
const char *bench_components_name(uint32_t components); /* "full", "multiple", ... */

typedef struct bench_reference {
    int wanted, ok, generated;
    char error[512];
    char path[4096];
    uint32_t spp;
    double ms; /* render time when it was made (from its .json when cached) */
    char device[256];
    ns_image image;
    /* pt's per-sample variance of this component set, the mean over pixels and channels
     * (from a short independent render: MSE = variance (1/BENCH_NOISE_SPP + 1/spp)), and
     * what it caps: the reference's own mean squared error variance / spp, and the PSNR a
     * noise-free image would score against it. 0 / NaN when not measured. */
    double variance, noise_mse, ceiling_db;
    /* Progressive references (--ref-ceiling): spp = chunks * chunk_spp, and the noise above
     * comes from the chunks' spread instead (cmd_bench.c). 0 for a reference of fixed spp. */
    uint32_t chunk_spp;
    /* Progressive references from BENCH_REF_TAIL_CHUNKS chunks on: the ceiling's rise from
     * half the chunks to all of them, and what a finite variance gives (10 log10 2); NaN
     * otherwise. */
    double ceiling_rise_db, ceiling_rise_expected_db;
} bench_reference;

#define BENCH_NOISE_SPP 16u

/* From this many chunks on, the ceiling's rise since half as many says whether pt's noise
 * falls as it should: its mean square error as 1 / chunks, 10 log10(2) = 3 dB per doubling,
 * for a finite variance. A heavy tail (fireflies that keep coming: the bumpy sphere's and the
 * candle's multiple scattering, docs/bench.md) rises less or falls, and more chunks may
 * never reach the target; below half the rise the run says so (cmd_bench.c), and the
 * report's References table gives the rise (bench_report.c). */
#define BENCH_REF_TAIL_CHUNKS 16u

typedef struct bench_result {
    int ran, ok;
    char error[512];
    uint32_t vrls;      /* render.vrls used */
    uint32_t spp;       /* camera samples per pixel */
    double ms;          /* median wall time of the warm renders (all renders if --repeat 1) */
    double cold_ms;     /* the first render: includes table reconstruction and accumulation */
    double camera_ms;   /* the camera pass (stages ray_pass and adaptive) that the first render
                           traced and the warm renders kept: a new camera pays it on top of ms;
                           0 when they kept none, NaN when the first render took a kept one */
    ns_render_stats stats;      /* of the last render */
    ns_render_stats cold_stats; /* of the first render */
    image_metrics metrics;      /* against the reference with the same components */
    double psnr_denoised;       /* PSNR with the reference's own noise taken out of the MSE
                                   (NaN when it is not known or the rest is within it) */
    double equal_time_ratio;    /* vrl: ms / nn_full's ms; 0 when there was none to match */
    /* --seeds: the renders on other seeds (0 without), counting the row's own */
    uint32_t seeds;
    double seed_ratio_mean[3], seed_ratio_sd[3]; /* mean / ref per channel over the seeds */
    double seed_psnr_median, seed_psnr_min, seed_psnr_max;
    double seed_mse_mean;       /* the MSE averaged over the seeds: the row's expected error, which
                                   the targets read (one seed's is one draw of it) */
    ns_image image;             /* the last render */
} bench_result;

#define BENCH_MAX_LADDER 8
#define BENCH_MAX_SEEDS 64
typedef struct bench_pt_point {
    uint32_t spp;
    double ms, pass_ms, mse, psnr;
    int ok;
} bench_pt_point;

/* pt's cost of quality, from renders at a few spp against the long reference (docs/bench.md):
 * MSE(spp) = variance * (1/spp + 1/ref_spp) (independent seeds), time = pass_ms_per_spp * spp. */
typedef struct bench_pt_estimate {
    int ok;
    double variance;        /* per-sample variance, mean over pixels and channels */
    double pass_ms_per_spp; /* pt_pass time per sample per pixel */
    double nn_mse_true;     /* nn full's MSE with the reference's own noise taken out */
    double pt_ms_equal;     /* pt time to reach nn full's error against the truth */
    double speedup;         /* pt_ms_equal / nn full's time */
    double speedup_frame;   /* pt_ms_equal / (nn full's time + its camera pass): a new view */
    int lower_bound;        /* nn full is within the reference's noise: speedup is at least */
} bench_pt_estimate;

typedef struct bench_scene {
    char name[64], figure[128], paper_row[32];
    json_t *scene;    /* the scene JSON with the bench's size applied */
    json_t *manifest; /* its manifest entry (borrowed from the manifest) */
    int skipped;
    char skip_reason[512];
    uint32_t width, height, ref_spp;
    float exposure;
    bench_reference refs[BENCH_REF_SETS];
    bench_result results[BENCH_METHOD_COUNT];
    bench_pt_point ladder[BENCH_MAX_LADDER];
    uint32_t ladder_count;
    bench_pt_estimate pt;
} bench_scene;

typedef struct bench_run {
    int methods[BENCH_METHOD_COUNT]; /* selected */
    bench_scene *scenes;
    uint32_t scene_count;
    int diff_method; /* the method shown in the contact sheet's difference column */
    char command[2048], date[64], device[256], driver[256];
    double total_s;
    uint32_t repeat;
    uint32_t seeds; /* --seeds */
    double mc_collisions;
    const char *boundary; /* --boundary; NULL: each scene file's render.boundary (default walks) */
} bench_run;

/* Writes DIR/report.md and DIR/contact_sheet.png. 0 or 1 after printing why. */
int bench_write_report(const bench_run *run, const char *dir);

/* A row's error as the targets read it: with --seeds, the MSE averaged over the seeds (the
 * expected error, of which one seed's is one draw) and its PSNR; else the row's own. */
double bench_result_mse(const bench_result *r);
double bench_result_psnr(const bench_result *r); /* NaN when not compared */

/* Paper value at manifest path paper.<method>.<field>, NaN when absent (bench.c). */
double bench_paper_value(const bench_scene *s, const char *method, const char *field);

#endif
