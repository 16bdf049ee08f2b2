/* bench_report.c — `nscatter bench`'s outputs: report.md (the paper's Tables 2-4, the targets
 * of issue 6, pt's cost of quality, the references) and contact_sheet.png (rows = scenes,
 * columns = the reference, the methods and a false-colour difference). docs/bench.md
 * explains every column. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench.h"
#include "encode.h"
#include "image_metrics.h"
#include "mc_provider.h"

/* ---------------------------------------------------------------------------------------
 * Formatting: one cell at a time; "n/a" for what was not measured.
 * ------------------------------------------------------------------------------------- */
typedef struct cell {
    char text[48];
} cell;

static cell num(double v, int decimals)
{
    cell c;
    if (isfinite(v))
        snprintf(c.text, sizeof c.text, "%.*f", decimals, v);
    else
        snprintf(c.text, sizeof c.text, "n/a");
    return c;
}

static cell sci(double v)
{
    cell c;
    if (isfinite(v))
        snprintf(c.text, sizeof c.text, "%.3e", v);
    else
        snprintf(c.text, sizeof c.text, "n/a");
    return c;
}

/* Error text inside a table cell: no pipes or newlines. */
static void put_escaped(FILE *f, const char *s)
{
    for (; *s; s++)
        fputc(*s == '|' ? '/' : *s == '\n' ? ' ' : *s, f);
}

static double stage(const ns_render_stats *st, const char *name)
{
    double ms = 0;
    int found = 0;
    for (uint32_t i = 0; i < st->stage_count; i++)
        if (!strcmp(st->stages[i].name, name)) {
            ms += st->stages[i].ms;
            found = 1;
        }
    return found ? ms : 0.0;
}

static const bench_result *result(const bench_scene *s, int m, const bench_run *run)
{
    return run->methods[m] && s->results[m].ok ? &s->results[m] : NULL;
}

static double psnr_of(const bench_result *r)
{
    return r && r->metrics.pixels ? r->metrics.psnr[3] : NAN;
}

/* The targets' PSNR: over the seeds where there are several (bench_result_psnr). */
static double target_psnr(const bench_result *r)
{
    return r ? bench_result_psnr(r) : NAN;
}

/* ---------------------------------------------------------------------------------------
 * Sections.
 * ------------------------------------------------------------------------------------- */
static void write_results(FILE *f, const bench_run *run)
{
    fprintf(
        f,
        "## Results\n\n"
        "One row per scene and method. PSNR, RMSE and relative error are against the pt "
        "reference with the same components (`nscatter compare`'s definitions). Time: median "
        "wall time of `ns_render` after the first render; first: the first render, which "
        "reconstructs and accumulates the tables; camera: the camera pass (stages ray_pass "
        "and adaptive) that the first render traced and the later ones kept, not in their "
        "time (a new view pays it on top). PSNR, ref noise out: with the reference's "
        "own noise (References) taken out of the MSE; n/a when the rest is within it. "
        "mean / ref: the image's mean over the reference's, per channel.\n\n"
        "| scene | method | components | status | render.vrls | VRLs | spp | time ms | first ms | "
        "camera ms | PSNR dB | PSNR, ref noise out dB | RMSE | rel. err | mean / ref R G B | "
        "interactions | table MB | weights KB |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (uint32_t i = 0; i < run->scene_count; i++) {
        const bench_scene *s = &run->scenes[i];
        if (s->skipped) {
            fprintf(f, "| %s | all | - | skipped: ", s->name);
            put_escaped(f, s->skip_reason);
            fprintf(f, " | n/a | n/a | n/a | n/a | n/a | n/a | n/a | n/a | n/a | n/a | n/a | n/a | "
                       "n/a | n/a |\n");
            continue;
        }
        for (int m = 0; m < BENCH_METHOD_COUNT; m++) {
            if (!run->methods[m])
                continue;
            const bench_result *r = &s->results[m];
            fprintf(f, "| %s | %s | %s | ", s->name, bench_methods[m].name,
                    bench_components_name(bench_methods[m].components));
            if (!r->ok) {
                fprintf(f, "not rendered: ");
                put_escaped(f, r->error[0] ? r->error : "not run");
                fprintf(f, " | n/a | n/a | n/a | n/a | n/a | n/a | n/a | n/a | n/a | n/a | n/a | "
                           "n/a | n/a | n/a |\n");
                continue;
            }
            int compared = r->metrics.pixels > 0;
            fprintf(f,
                    "%s | %u | %llu | %u | %s | %s | %s | %s | %s | %s | %s | %s %s %s | %llu | %s "
                    "| %s |\n",
                    compared ? "ok" : "ok, no reference", r->vrls,
                    (unsigned long long)r->stats.vrl_count, r->spp, num(r->ms, 1).text,
                    num(r->cold_ms, 1).text, num(r->camera_ms, 1).text,
                    num(compared ? r->metrics.psnr[3] : NAN, 2).text,
                    num(compared ? r->psnr_denoised : NAN, 2).text,
                    sci(compared ? r->metrics.rmse[3] : NAN).text,
                    num(compared ? r->metrics.relerr[3] : NAN, 4).text,
                    num(compared ? r->metrics.mean_ratio[0] : NAN, 3).text,
                    num(compared ? r->metrics.mean_ratio[1] : NAN, 3).text,
                    num(compared ? r->metrics.mean_ratio[2] : NAN, 3).text,
                    (unsigned long long)r->stats.interactions,
                    num(r->stats.table_bytes / 1048576.0, 1).text,
                    num(r->stats.weights_bytes / 1024.0, 1).text);
        }
    }
    fputc('\n', f);
}

/* --seeds N: each row's spread over seeds (its first seed is the Results row). */
static void write_seeds(FILE *f, const bench_run *run)
{
    if (run->seeds < 2)
        return;
    fprintf(f,
            "## Seeds\n\n"
            "Each row rendered on %u seeds (the scene's and those after it; light paths and "
            "camera samples change), each compared with the same reference: mean / ref per "
            "channel as the mean ± the standard deviation over the seeds, and the PSNR's "
            "median and range, and the PSNR of their mean squared error (the expected "
            "error, which the Targets read). One seed's mean / ref in Results is one draw "
            "from this spread.\n\n"
            "| scene | method | components | seeds | mean / ref R | G | B | PSNR dB median | "
            "min | max | PSNR of the mean MSE dB |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|\n",
            run->seeds);
    for (uint32_t i = 0; i < run->scene_count; i++) {
        const bench_scene *s = &run->scenes[i];
        for (int m = 0; m < BENCH_METHOD_COUNT && !s->skipped; m++) {
            const bench_result *r = &s->results[m];
            if (!run->methods[m] || !r->ok || r->seeds < 2)
                continue;
            fprintf(f, "| %s | %s | %s | %u |", s->name, bench_methods[m].name,
                    bench_components_name(bench_methods[m].components), r->seeds);
            for (int c = 0; c < 3; c++)
                fprintf(f, " %s ± %s |", num(r->seed_ratio_mean[c], 3).text,
                        num(r->seed_ratio_sd[c], 4).text);
            fprintf(f, " %s | %s | %s | %s |\n", num(r->seed_psnr_median, 2).text,
                    num(r->seed_psnr_min, 2).text, num(r->seed_psnr_max, 2).text,
                    num(bench_result_psnr(r), 2).text);
        }
    }
    fputc('\n', f);
}

static void table2_group(FILE *f, const bench_result *r)
{
    if (!r)
        fprintf(f, " n/a | n/a | n/a |");
    else
        fprintf(f, " %s | %s | %s |", num(r->stats.vrl_count / 1000.0, 1).text, num(r->ms, 1).text,
                num(psnr_of(r), 2).text);
}

static void write_table2(FILE *f, const bench_run *run)
{
    fprintf(f, "## Table 2: time, memory and error\n\n"
               "Shaped like the paper's Table 2 (VRLs in thousands stored, time in ms, PSNR in dB); "
               "table is the paper's [WH17] column, its memory the tables held on the device.\n\n"
               "| scene | resolution | M: VRLs K | M: ms | M: PSNR | M+D: VRLs K | M+D: ms | M+D: PSNR | "
               "full: VRLs K | full: ms | full: PSNR | table: VRLs K | table: PSNR | table: memory MB | "
               "vrl: VRLs K | vrl: PSNR | dipole: PSNR | reference spp | reference s |\n"
               "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (uint32_t i = 0; i < run->scene_count; i++) {
        const bench_scene *s = &run->scenes[i];
        if (s->skipped)
            continue;
        fprintf(f, "| %s | %u × %u |", s->name, s->width, s->height);
        table2_group(f, result(s, BENCH_NN_MULTIPLE, run));
        table2_group(f, result(s, BENCH_NN_DOUBLE, run));
        table2_group(f, result(s, BENCH_NN_FULL, run));
        const bench_result *t = result(s, BENCH_TABLE, run), *v = result(s, BENCH_VRL, run);
        const bench_result *d = result(s, BENCH_DIPOLE, run);
        const bench_reference *ref = &s->refs[bench_ref_index(bench_methods[BENCH_NN_FULL].components)];
        fprintf(f, " %s | %s | %s | %s | %s | %s | %u | %s |\n",
                num(t ? t->stats.vrl_count / 1000.0 : NAN, 1).text, num(psnr_of(t), 2).text,
                num(t ? t->stats.table_bytes / 1048576.0 : NAN, 1).text,
                num(v ? v->stats.vrl_count / 1000.0 : NAN, 2).text, num(psnr_of(v), 2).text,
                num(psnr_of(d), 2).text, ref->ok ? ref->spp : s->ref_spp,
                num(ref->ok ? ref->ms / 1000.0 : NAN, 1).text);
    }
    fputc('\n', f);
}

static void write_stages(FILE *f, const bench_run *run)
{
    fprintf(f, "## Tables 3 and 4: cost of each stage\n\n"
               "Milliseconds per stage of the render library (`ns_render_stats`). reconstruct and "
               "accumulate are from the first render (later renders find the tables cached); the "
               "others from the last. Table 3 is the nn double + multiple row, Table 4 the nn "
               "multiple-only row.\n\n"
               "| scene | method | reconstruct (first) | accumulate (first) | vrl | grid | ray_pass | "
               "gather | single | composite | total |\n"
               "|---|---|---|---|---|---|---|---|---|---|---|\n");
    static const int rows[] = {BENCH_NN_MULTIPLE, BENCH_NN_DOUBLE, BENCH_NN_FULL, BENCH_TABLE, BENCH_DIPOLE, BENCH_VRL};
    for (uint32_t i = 0; i < run->scene_count; i++)
        for (size_t k = 0; k < sizeof rows / sizeof rows[0]; k++) {
            const bench_scene *s = &run->scenes[i];
            const bench_result *r = result(s, rows[k], run);
            if (!r)
                continue;
            /* Single scattering kept with the camera pass: the first render's. */
            const ns_render_stats *single = r->stats.single_reused ? &r->cold_stats : &r->stats;
            fprintf(f, "| %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s |\n", s->name,
                    bench_methods[rows[k]].name, num(stage(&r->cold_stats, "reconstruct"), 1).text,
                    num(stage(&r->cold_stats, "accumulate"), 1).text,
                    num(stage(&r->stats, "vrl"), 1).text, num(stage(&r->stats, "grid"), 1).text,
                    num(stage(&r->stats, "ray_pass"), 1).text,
                    num(stage(&r->stats, "gather"), 1).text, num(stage(single, "single"), 1).text,
                    num(stage(&r->stats, "composite"), 1).text, num(r->ms, 1).text);
        }
    fputc('\n', f);
}

static const char *verdict(double v, double threshold, int at_least)
{
    if (!isfinite(v))
        return "not measured";
    return (at_least ? v >= threshold : v <= threshold) ? "met" : "missed";
}

static void write_targets(FILE *f, const bench_run *run)
{
    fprintf(
        f,
        "## Targets (issue 6; reported, not asserted)\n\n"
        "- nn full within 3 dB of table: Δ = PSNR(table) − PSNR(nn full) ≤ 3.\n"
        "- vrl at equal time at least 5 dB below nn: Δ = PSNR(nn full) − PSNR(vrl) ≥ 5; "
        "time ratio = vrl's time / nn full's.\n"
        "- nn at least 1000× faster than pt for the same error against the truth: pt's time "
        "to reach nn full's error, estimated from the short pt renders (below), over nn "
        "full's time (a frame of a view whose camera pass is kept), and over that time and "
        "the camera pass (a new view; the verdict's).\n"
        "- With --seeds, every row's error here (nn full's, table's, vrl's) is its mean "
        "squared error over the seeds (the Seeds section's last column), not one seed's draw; "
        "so is nn full's MSE in the pt estimate below.\n\n"
        "| scene | table − nn full dB | within 3 dB | nn full − vrl dB | vrl time ratio | ≥ 5 dB | "
        "pt time for nn's error s | speedup over pt | speedup, new view | ≥ 1000× |\n"
        "|---|---|---|---|---|---|---|---|---|---|\n");
    for (uint32_t i = 0; i < run->scene_count; i++) {
        const bench_scene *s = &run->scenes[i];
        if (s->skipped)
            continue;
        double nn = target_psnr(result(s, BENCH_NN_FULL, run));
        double tab = target_psnr(result(s, BENCH_TABLE, run));
        const bench_result *v = result(s, BENCH_VRL, run);
        double d1 = tab - nn, d2 = nn - target_psnr(v);
        double ratio = v && v->equal_time_ratio > 0 ? v->equal_time_ratio : NAN;
        const bench_pt_estimate *e = &s->pt;
        char speed[64], speed_frame[64];
        if (e->ok) {
            snprintf(speed, sizeof speed, "%s%.3g", e->lower_bound ? "≥ " : "", e->speedup);
            if (isfinite(e->speedup_frame))
                snprintf(speed_frame, sizeof speed_frame, "%s%.3g", e->lower_bound ? "≥ " : "",
                         e->speedup_frame);
            else
                snprintf(speed_frame, sizeof speed_frame, "n/a");
        } else {
            snprintf(speed, sizeof speed, "n/a");
            snprintf(speed_frame, sizeof speed_frame, "n/a");
        }
        fprintf(f, "| %s | %s | %s | %s | %s | %s | %s | %s | %s | %s |\n", s->name,
                num(d1, 2).text, verdict(d1, 3.0, 0), num(d2, 2).text, num(ratio, 2).text,
                verdict(d2, 5.0, 1), num(e->ok ? e->pt_ms_equal / 1000.0 : NAN, 1).text, speed,
                speed_frame, verdict(e->ok ? e->speedup_frame : NAN, 1000.0, 1));
    }
    fputc('\n', f);
}

static void write_paper(FILE *f, const bench_run *run)
{
    fprintf(f, "## Against the paper's Table 2\n\n"
               "The paper's PSNR (512×512 or 768×576, 6-hour UPBP references, a GPU) beside ours "
               "(this size, pt references of the spp above). docs/bench.md discusses the "
               "differences.\n\n"
               "| scene | paper row | column | paper PSNR | measured PSNR | measured − paper | paper ms | measured ms |\n"
               "|---|---|---|---|---|---|---|---|\n");
    static const int cols[] = {BENCH_NN_MULTIPLE, BENCH_NN_DOUBLE, BENCH_NN_FULL, BENCH_TABLE, BENCH_VRL};
    for (uint32_t i = 0; i < run->scene_count; i++) {
        const bench_scene *s = &run->scenes[i];
        if (s->skipped)
            continue;
        for (size_t k = 0; k < sizeof cols / sizeof cols[0]; k++) {
            const char *name = bench_methods[cols[k]].name;
            double paper = bench_paper_value(s, name, "psnr"), paper_ms = bench_paper_value(s, name, "ms");
            if (!isfinite(paper))
                continue;
            const bench_result *r = result(s, cols[k], run);
            double got = psnr_of(r);
            fprintf(f, "| %s | %s | %s | %s | %s | %s | %s | %s |\n", s->name, s->paper_row, name,
                    num(paper, 1).text, num(got, 2).text, num(got - paper, 2).text, num(paper_ms, 0).text,
                    num(r ? r->ms : NAN, 1).text);
        }
    }
    fputc('\n', f);
}

static void write_pt(FILE *f, const bench_run *run)
{
    if (!run->methods[BENCH_PT])
        return;
    fprintf(f, "## pt at a few samples per pixel\n\n"
               "Against the full reference (other seeds). The fit MSE(spp) = variance × (1/spp + "
               "1/reference spp) gives pt's per-sample variance; pt_pass time per spp is fitted "
               "through the origin.\n\n"
               "| scene | spp | time ms | pt_pass ms | MSE | PSNR dB |\n|---|---|---|---|---|---|\n");
    for (uint32_t i = 0; i < run->scene_count; i++) {
        const bench_scene *s = &run->scenes[i];
        for (uint32_t k = 0; k < s->ladder_count; k++) {
            const bench_pt_point *p = &s->ladder[k];
            if (p->ok)
                fprintf(f, "| %s | %u | %s | %s | %s | %s |\n", s->name, p->spp, num(p->ms, 1).text,
                        num(p->pass_ms, 1).text, sci(p->mse).text, num(p->psnr, 2).text);
        }
    }
    fprintf(
        f,
        "\n| scene | variance per sample | pt_pass ms per spp | nn full MSE (reference noise "
        "removed; over its seeds with --seeds) | pt ms for that error |\n|---|---|---|---|---|\n");
    for (uint32_t i = 0; i < run->scene_count; i++) {
        const bench_scene *s = &run->scenes[i];
        const bench_pt_estimate *e = &s->pt;
        if (s->ladder_count)
            fprintf(f, "| %s | %s | %s | %s | %s |\n", s->name, sci(e->variance).text,
                    num(e->pass_ms_per_spp, 2).text, e->ok ? sci(e->nn_mse_true).text : "n/a",
                    num(e->ok ? e->pt_ms_equal : NAN, 0).text);
    }
    fputc('\n', f);
}

static void write_references(FILE *f, const bench_run *run)
{
    fprintf(f,
            "## References\n\n"
            "pt renders cached outside git, keyed by a hash of the scene JSON (with method pt, "
            "the components, spp and seed) and its meshes; `nscatter bench --references` "
            "renders them again. Noise ceiling: the PSNR a noise-free image would score against "
            "the reference, from pt's per-sample variance of the same components (a "
            "%u-spp render on another seed; kept in the reference's .json): 20 log10(peak / "
            "sqrt(variance / spp)). A PSNR near it says the reference cannot tell. A reference "
            "with chunks (`--ref-ceiling`) is the mean of that many renders of the chunk's spp "
            "on successive seeds, and its noise comes from their spread instead; from %u chunks "
            "on, *ceiling rise* is its ceiling's rise from half the chunks to all of them, "
            "against the 3 dB of a finite variance (far less: pt's noise has a heavy tail "
            "there, and more chunks may not help).\n\n"
            "| scene | components | spp | chunks | time s | noise ceiling dB | ceiling rise dB | "
            "device | this run | file |\n"
            "|---|---|---|---|---|---|---|---|---|---|\n",
            BENCH_NOISE_SPP, BENCH_REF_TAIL_CHUNKS);
    for (uint32_t i = 0; i < run->scene_count; i++) {
        const bench_scene *s = &run->scenes[i];
        for (int set = 0; set < BENCH_REF_SETS; set++) {
            const bench_reference *r = &s->refs[set];
            if (!r->wanted)
                continue;
            char chunks[32] = "–";
            if (r->ok && r->chunk_spp)
                snprintf(chunks, sizeof chunks, "%u × %u", r->spp / r->chunk_spp, r->chunk_spp);
            char rise[48] = "–";
            if (r->ok && r->chunk_spp && isfinite(r->ceiling_rise_db))
                snprintf(rise, sizeof rise, "%+.1f (of %.1f)", r->ceiling_rise_db,
                         r->ceiling_rise_expected_db);
            fprintf(f, "| %s | %s | %u | %s | %s | %s | %s | %s | %s | ", s->name,
                    bench_components_name(bench_ref_components[set]), r->spp, chunks,
                    num(r->ok ? r->ms / 1000.0 : NAN, 1).text,
                    num(r->ok ? r->ceiling_db : NAN, 1).text, rise, r->ok ? r->device : "n/a",
                    !r->ok         ? "failed"
                    : r->generated ? "rendered"
                                   : "cached");
            if (r->ok)
                fprintf(f, "`%s` |\n", r->path);
            else {
                put_escaped(f, r->error);
                fprintf(f, " |\n");
            }
        }
    }
    fputc('\n', f);
}

/* ---------------------------------------------------------------------------------------
 * Contact sheet.
 * ------------------------------------------------------------------------------------- */
#define SHEET_GAP 2

typedef struct sheet_column {
    const char *name;
    int method;    /* >= 0: that method's image; -1: the reference; -2: the difference */
} sheet_column;

static void blit(ns_image *sheet, uint32_t x0, uint32_t y0, const ns_image *img, float scale)
{
    for (uint32_t y = 0; y < img->height && y0 + y < sheet->height; y++)
        for (uint32_t x = 0; x < img->width && x0 + x < sheet->width; x++)
            for (int c = 0; c < 3; c++)
                sheet->rgb[3 * ((size_t)(y0 + y) * sheet->width + x0 + x) + c] =
                    img->rgb[3 * ((size_t)y * img->width + x) + c] * scale;
}

/* A cell with no image: a dark diagonal hatch, so it cannot be mistaken for a black render. */
static void hatch(ns_image *sheet, uint32_t x0, uint32_t y0, uint32_t w, uint32_t h)
{
    for (uint32_t y = 0; y < h; y++)
        for (uint32_t x = 0; x < w; x++) {
            float v = ((x + y) / 6) % 2 ? 0.02f : 0.06f;
            float *p = &sheet->rgb[3 * ((size_t)(y0 + y) * sheet->width + x0 + x)];
            p[0] = v * 1.5f, p[1] = v, p[2] = v;
        }
}

/* The difference column: the chosen method, else the first full-solution method rendered. */
static int diff_source(const bench_scene *s, const bench_run *run)
{
    static const int fallback[] = {BENCH_NN_FULL, BENCH_TABLE, BENCH_DIPOLE, BENCH_VRL,
                                   BENCH_NN_DOUBLE, BENCH_NN_MULTIPLE, BENCH_NN_SURFACE};
    if (run->diff_method >= 0 && result(s, run->diff_method, run) &&
        s->results[run->diff_method].metrics.pixels)
        return run->diff_method;
    for (size_t k = 0; k < sizeof fallback / sizeof fallback[0]; k++)
        if (result(s, fallback[k], run) && s->results[fallback[k]].metrics.pixels)
            return fallback[k];
    return -1;
}

static int write_contact_sheet(const bench_run *run, const char *path, FILE *md)
{
    sheet_column cols[BENCH_METHOD_COUNT + 2];
    uint32_t ncols = 0, cell_w = 0, cell_h = 0, rows = 0;
    cols[ncols++] = (sheet_column){"reference (pt, full)", -1};
    for (int m = 0; m < BENCH_METHOD_COUNT; m++)
        if (run->methods[m])
            cols[ncols++] = (sheet_column){bench_methods[m].name, m};
    cols[ncols++] = (sheet_column){"difference", -2};
    for (uint32_t i = 0; i < run->scene_count; i++)
        if (!run->scenes[i].skipped) {
            rows++;
            cell_w = run->scenes[i].width > cell_w ? run->scenes[i].width : cell_w;
            cell_h = run->scenes[i].height > cell_h ? run->scenes[i].height : cell_h;
        }
    if (!rows)
        rows = 1, cell_w = cell_h = 16;
    ns_image sheet = {.width = ncols * (cell_w + SHEET_GAP) - SHEET_GAP,
                      .height = rows * (cell_h + SHEET_GAP) - SHEET_GAP};
    sheet.rgb = calloc((size_t)sheet.width * sheet.height * 3, sizeof(float));
    if (!sheet.rgb)
        return -1;
    for (size_t p = 0; p < (size_t)sheet.width * sheet.height * 3; p++)
        sheet.rgb[p] = 0.18f; /* the gaps: mid grey */
    fprintf(md, "## Contact sheet\n\n`contact_sheet.png`: one row per scene (");
    uint32_t row = 0;
    for (uint32_t i = 0; i < run->scene_count; i++) {
        const bench_scene *s = &run->scenes[i];
        if (s->skipped)
            continue;
        fprintf(md, "%s%s", row ? ", " : "", s->name);
        uint32_t y0 = row++ * (cell_h + SHEET_GAP);
        float scale = exp2f(s->exposure);
        for (uint32_t c = 0; c < ncols; c++) {
            uint32_t x0 = c * (cell_w + SHEET_GAP);
            const ns_image *img = NULL;
            ns_image diff = {0};
            if (cols[c].method == -1) {
                const bench_reference *r = &s->refs[bench_ref_index(bench_methods[BENCH_NN_FULL].components)];
                img = r->ok ? &r->image : NULL;
            } else if (cols[c].method >= 0) {
                const bench_result *r = result(s, cols[c].method, run);
                img = r ? &r->image : NULL;
            } else {
                int m = diff_source(s, run);
                if (m >= 0) {
                    const bench_result *r = &s->results[m];
                    const bench_reference *ref = &s->refs[bench_ref_index(bench_methods[m].components)];
                    double used;
                    ns_error err = {0};
                    /* The full ramp at 3 x RMSE: typical errors land mid-ramp. */
                    if (!image_diff_false_colour(&r->image, &ref->image, NULL, 3.0 * r->metrics.rmse[3], &diff,
                                                 &used, &err))
                        img = &diff;
                }
            }
            if (img)
                blit(&sheet, x0, y0, img, cols[c].method == -2 ? 1.0f : scale);
            else
                hatch(&sheet, x0, y0, cell_w, cell_h);
            ns_image_free(&diff);
        }
    }
    fprintf(md, "); columns, left to right: ");
    for (uint32_t c = 0; c < ncols; c++)
        fprintf(md, "%s%s", c ? ", " : "", cols[c].name);
    fprintf(md, ". The pt column is its longest short render. The difference column is |image − "
                "reference| of %s (else the first full-solution method rendered), false colour "
                "(black, blue, magenta, orange, yellow, white) with white at 3 × its RMSE. Hatched "
                "cells: not rendered.\n\n",
            run->diff_method >= 0 ? bench_methods[run->diff_method].name : "nn_full");
    encode_buffer png = {0};
    ns_error err = {0};
    int rc = encode_png(&sheet, 0.0f, NULL, 0, &png, &err);
    free(sheet.rgb);
    if (rc) {
        fprintf(stderr, "nscatter bench: contact sheet: %s\n", err.message);
        return -1;
    }
    FILE *f = fopen(path, "wb");
    int ok = f && fwrite(png.data, 1, png.size, f) == png.size;
    if (f && fclose(f))
        ok = 0;
    encode_buffer_free(&png);
    if (!ok)
        fprintf(stderr, "nscatter bench: cannot write '%s': %s\n", path, strerror(errno));
    return ok ? 0 : -1;
}

int bench_write_report(const bench_run *run, const char *dir)
{
    char path[4200], sheet_path[4200];
    snprintf(path, sizeof path, "%s/report.md", dir);
    snprintf(sheet_path, sizeof sheet_path, "%s/contact_sheet.png", dir);
    FILE *f = fopen(path, "w");
    if (!f) {
        fprintf(stderr, "nscatter bench: cannot write '%s': %s\n", path, strerror(errno));
        return 1;
    }
    fprintf(f, "# nscatter bench\n\n"
               "- command: `%s`\n- date: %s\n- device: %s (%s)\n- renders per method: %u (time = "
               "median after the first)\n- Monte Carlo collisions per order and channel (method "
               "table): %.3g\n- render.boundary of the nn and table rows: %s\n- whole run: %.1f s\n\n",
            run->command, run->date, run->device, run->driver, run->repeat, run->mc_collisions > 0 ? run->mc_collisions : NS_MC_PROVIDER_COLLISIONS,
            run->boundary ? run->boundary : "the scene files' (walks where they do not say)", run->total_s);
    write_results(f, run);
    write_seeds(f, run);
    write_table2(f, run);
    write_stages(f, run);
    write_targets(f, run);
    write_paper(f, run);
    write_pt(f, run);
    write_references(f, run);
    int rc = write_contact_sheet(run, sheet_path, f);
    if (fclose(f) || rc) {
        fprintf(stderr, "nscatter bench: cannot finish '%s'\n", rc ? sheet_path : path);
        return 1;
    }
    return 0;
}
