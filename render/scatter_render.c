/* scatter_render.c — the scattering components of a render, after the camera pass (paper
 * Sections 3.8 and 4.1): single scattering at every camera segment (or, with
 * render.single_levels, at those of the pixels the adaptive rounds pick); double and multiple
 * scattering gathered from the VRLs (tables of the network or of Monte Carlo, the dipole,
 * or the brute-force `vrl` method) for one pixel per tile, then edge-aware upsampling; and
 * the composition into pixels.
 *
 * Composition. A stage gives, per segment, the radiance L arriving at the segment's entry
 * from inside the medium. The pixel gets throughput * L / spp, times 1/ior^2: radiance
 * leaving a medium of index n into vacuum is divided by n^2 (L / n^2 is invariant along a
 * refracted ray), which the camera pass's throughput (Fresnel only) leaves out because its
 * other paths enter and leave the medium and the factors cancel. The dipole's R_d already
 * gives radiance outside, so it takes no such factor.
 *
 * Upsampling. The gathered quantity per pixel is the radiance per unit throughput,
 * Lbar = sum(throughput * L) / sum(throughput) over the pixel's segments; a pixel that is
 * not gathered takes the bilinear mix of Lbar of the gathered pixels of the four nearest
 * tiles, using only those that see the same medium at a similar distance (their first
 * segment's material and entry distance), and multiplies by its own sum of throughputs
 * (so coverage and Fresnel stay its own). A pixel that no neighbour can stand for is
 * gathered itself: light never bleeds across silhouettes or between objects. With
 * render.gather_levels the tiles' own pixels are gathered coarse to fine and interpolated
 * where that is accurate (the adaptive gather, below); render.single_levels does the same
 * for single scattering with every pixel its own tile.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "boundary.h"
#include "source_keep.h"
#include "scatter.h"
#include "vrl_method.h"
#include "vrl_shared.h"

/* Two pixels see "the same surface" when their first stretches are in the same medium and
 * start at distances within this fraction of each other. */
#define SAME_SURFACE_DISTANCE 0.05f

/* The boundary correction is interpolated where its error estimate is within this many times
 * render.gather_tolerance of the pixels' totals. The estimate, a second difference of
 * neighbouring gathers, measures the ghosts' noise more than the correction's curvature, and
 * the mean of 2 or 4 neighbours has less of that noise than one gather: against the bumpy
 * sphere's 128-chunk reference the multiple-scattering image scores 27.51 dB with every
 * tile's correction gathered, 27.51 dB within 0.02 of the totals, 27.71 dB within 0.1 (the
 * gather 25.7, 22.9 and 17.4 s; docs/scattering.md, *The correction's own lattice*). 2 times
 * the default gather_tolerance (0.05) is that 0.1: the VRLs' own tolerance went from 0.02 to
 * 0.05 without moving the correction's (docs/bench.md, *A looser gather tolerance*). */
#define CORRECTION_TOLERANCE 2.0f

/* How many levels coarser than the VRLs' the correction's lattice starts. Against the same
 * reference, 1, 2 and 3 levels score 27.71, 27.75 and 28.47 dB (the interpolation averages
 * the ghosts' noise away) but move the image mean from 0.983 of the reference's (every tile)
 * to 0.979, 0.975 and 0.972, and on the bench's candle and bunny 2 levels save only 5 M
 * interactions more than 1, of 35-39 M. */
#define CORRECTION_LEVELS 1

typedef struct pixel_key {
    uint32_t material;   /* of the first participating segment; NS_NONE: none */
    uint32_t first_rank; /* (sample, depth) of that segment, to find the first */
    float distance;      /* camera to its entry point */
    float weight[3];     /* sum of throughput / spp over participating segments */
    /* Sum of throughput / spp over the segments the gather takes (every participating one,
     * or those of the camera samples choose_gathered_samples picked): Lbar's denominator. */
    float gather_weight[3];
} pixel_key;

/* How a pixel's double and multiple scattering is found. */
enum {
    PIXEL_UPSAMPLED = 0, /* at the end, from the four nearest tiles' representatives */
    PIXEL_GATHERED,      /* gathered itself */
    PIXEL_INTERPOLATED,  /* a tile's representative, interpolated from coarser tiles */
};

typedef struct tile_plan {
    uint32_t width, height, tile, tiles_x, tiles_y;
    uint32_t levels; /* coarser lattices above the tiles (render.gather_levels) */
    float tolerance; /* render.gather_tolerance */
    float correction_tolerance; /* the boundary correction's: CORRECTION_TOLERANCE times it */
    /* An interpolated value from the outer samples too (line_agrees): single scattering's. */
    int curved;
    pixel_key *keys;
    uint32_t *representative; /* per tile: the gathered pixel standing for it, or NS_NONE */
    uint8_t *state;           /* per pixel: PIXEL_* */
    float (*radiance)[3];     /* per gathered or interpolated pixel: Lbar (top of file) */
    /* render.boundary: the boundary sources' part of radiance, Lbar of the correction alone
     * (not clamped), which has a lattice of its own one level coarser (below); else NULL. */
    float (*correction)[3];
    /* The gather's: per pixel, the scattered light it already holds (single scattering, and
     * the camera batches before this one), per unit of its weight (what compose multiplies
     * Lbar by), so in Lbar's units; NULL: none. The error allowed is a fraction of the
     * pixel's whole value (line_agrees). */
    float (*other)[3];
    /* Single scattering's: per pixel, the variance of its Lbar (its Monte Carlo noise, from
     * the spread of its camera samples; interpolated: of the interpolation), for the rule
     * that an interpolation no noisier than computing the pixel may stand for it
     * (noisy_line_agrees); NULL: none, the tolerance alone decides. */
    float (*variance)[3];
    uint64_t corrections_interpolated; /* tiles that gathered their VRLs, not their correction */
    uint32_t *segment_start;  /* pixel -> its segments [start[p], start[p + 1]) in by_pixel */
    uint32_t *by_pixel;
    /* Per segment: whether the gather takes it (render.gather_camera_samples;
     * choose_gathered_samples); NULL: every participating segment. */
    uint8_t *taken;
} tile_plan;

static void tile_plan_free(tile_plan *t)
{
    free(t->keys);
    free(t->representative);
    free(t->state);
    free(t->radiance);
    free(t->correction);
    free(t->other);
    free(t->variance);
    free(t->segment_start);
    free(t->by_pixel);
    free(t->taken);
    memset(t, 0, sizeof *t);
}

/* The camera pass records no segment dimmer than this (shared.h); segments handed in by
 * other callers are held to the same rule. */
static int visible(const GpuSegment *s)
{
    return fmaxf(s->throughput[0], fmaxf(s->throughput[1], s->throughput[2])) >= NS_MIN_SEGMENT_THROUGHPUT;
}

static int participates(const GpuSegment *s, ns_method method)
{
    /* The dipole is a surface model: it lights the points where light leaves the medium,
     * i.e. the entries of camera paths coming from outside. */
    return visible(s) && (method != NS_METHOD_DIPOLE || (s->depth & NS_SEGMENT_ENTERED));
}

static float distance3(const float *a, const float *b)
{
    float d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
}

static int compatible(const pixel_key *a, const pixel_key *b)
{
    return a->material != NS_NONE && a->material == b->material &&
           fabsf(a->distance - b->distance) <= SAME_SURFACE_DISTANCE * fmaxf(a->distance, b->distance);
}

/* Where a tile's representative is looked for first along an axis of `size` pixels: pixel
 * tile / 2 of tile i, moved into the image in a last tile too short to hold it. */
static int representative_at(int i, uint32_t tile, uint32_t size)
{
    int at = i * (int)tile + (int)(tile / 2);
    return at < (int)size ? at : (int)size - 1;
}

/* Tile (tx, ty)'s representative: its pixel at representative_at along each axis, or the
 * first of its pixels with a participating segment when that one has none. */
static uint32_t choose_representative(const tile_plan *t, uint32_t tx, uint32_t ty)
{
    uint32_t x0 = tx * t->tile, y0 = ty * t->tile;
    uint32_t x1 = x0 + t->tile < t->width ? x0 + t->tile : t->width;
    uint32_t y1 = y0 + t->tile < t->height ? y0 + t->tile : t->height;
    uint32_t cx = (uint32_t)representative_at((int)tx, t->tile, t->width);
    uint32_t cy = (uint32_t)representative_at((int)ty, t->tile, t->height);
    if (t->keys[cy * t->width + cx].material != NS_NONE)
        return cy * t->width + cx;
    for (uint32_t y = y0; y < y1; y++)
        for (uint32_t x = x0; x < x1; x++)
            if (t->keys[y * t->width + x].material != NS_NONE)
                return y * t->width + x;
    return NS_NONE;
}

static int is_representative(const tile_plan *t, uint32_t x, uint32_t y)
{
    return t->representative[(y / t->tile) * t->tiles_x + x / t->tile] == y * t->width + x;
}

/* Along one axis: the tile i0 whose representative is at or before pixel x (-1 before the
 * first), and the weight of the next one, from their places. */
static float axis_weight(uint32_t x, uint32_t tile, uint32_t size, int *i0)
{
    int i = (int)floorf(((float)x - (float)(tile / 2)) / (float)tile);
    int last = (int)((size + tile - 1) / tile) - 1;
    if (i + 1 == last && representative_at(last, tile, size) <= (int)x)
        i = last; /* the last tile's representative was moved onto or before x */
    *i0 = i;
    int a = representative_at(i, tile, size), b = representative_at(i + 1, tile, size);
    return b > a ? ((float)x - (float)a) / (float)(b - a) : 0.0f;
}

/* Bilinear neighbours of pixel (x, y) among the tiles' representatives: up to 4 (pixel,
 * weight) pairs that see the same surface. Returns how many. A representative is weighed
 * where choose_representative looks first, pixel tile / 2 of its tile along each axis (in a
 * last tile too short for it, its last pixel), not at the tile's centre: for an even tile the
 * two are half a pixel apart, and taking one for the other shifted three quarters of a 2 x
 * 2-tiled image by half a pixel towards the top left, which took 6-11% off the mean of a
 * sphere whose light falls off within a pixel (docs/scattering.md, *The tiles there*;
 * unit_adaptive_gather's tiled linear field). */
static int upsample_sources(const tile_plan *t, uint32_t x, uint32_t y, uint32_t pixel[4], float weight[4])
{
    int tx0, ty0;
    float ax = axis_weight(x, t->tile, t->width, &tx0),
          ay = axis_weight(y, t->tile, t->height, &ty0);
    const pixel_key *self = &t->keys[y * t->width + x];
    float total = 0.0f;
    int n = 0;
    for (int j = 0; j < 2; j++)
        for (int i = 0; i < 2; i++) {
            int tx = tx0 + i, ty = ty0 + j;
            if (tx < 0 || ty < 0 || tx >= (int)t->tiles_x || ty >= (int)t->tiles_y)
                continue;
            uint32_t r = t->representative[(uint32_t)ty * t->tiles_x + (uint32_t)tx];
            if (r == NS_NONE || !compatible(self, &t->keys[r]))
                continue;
            pixel[n] = r;
            weight[n] = (i ? ax : 1.0f - ax) * (j ? ay : 1.0f - ay);
            total += weight[n++];
        }
    /* A pixel in line with representatives that cannot stand for it (its own row or column
     * of them) gives the others weight 0: its compatible neighbours then count alike. */
    for (int i = 0; i < n && total <= 0.0f; i++)
        weight[i] = 1.0f;
    return n;
}

/* Each tile's representative, from the pixels' keys; a pixel that no neighbouring
 * representative can stand for is marked to be gathered itself. */
static void choose_representatives(tile_plan *t)
{
    for (uint32_t ty = 0; ty < t->tiles_y; ty++)
        for (uint32_t tx = 0; tx < t->tiles_x; tx++)
            t->representative[ty * t->tiles_x + tx] = choose_representative(t, tx, ty);
    for (uint32_t y = 0; y < t->height; y++)
        for (uint32_t x = 0; x < t->width; x++) {
            uint32_t p = y * t->width + x, src[4];
            float w[4];
            if (t->keys[p].material != NS_NONE && !is_representative(t, x, y) &&
                upsample_sources(t, x, y, src, w) == 0)
                t->state[p] = PIXEL_GATHERED;
        }
}

/* An upsampled pixel's Lbar: the weighted mean of its sources' (none: 0). */
static void upsampled_radiance(const tile_plan *t, uint32_t x, uint32_t y, float out[3])
{
    uint32_t src[4];
    float w[4], total = 0;
    int n = upsample_sources(t, x, y, src, w);
    out[0] = out[1] = out[2] = 0.0f;
    for (int i = 0; i < n; i++) {
        for (int c = 0; c < 3; c++)
            out[c] += w[i] * t->radiance[src[i]][c];
        total += w[i];
    }
    for (int c = 0; c < 3 && total > 0; c++)
        out[c] /= total;
}

/* What a tile plan is for: the gather (double and multiple scattering, render.gather_*) or
 * single scattering (render.single_*; every pixel its own tile, every visible segment). */
typedef enum plan_use { PLAN_GATHER, PLAN_SINGLE } plan_use;

static int compare_u64(const void *a, const void *b)
{
    uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return (x > y) - (x < y);
}

/* Whether the gather takes segment i (choose_gathered_samples, below). */
static int gathered(const tile_plan *t, const GpuSegment *segs, uint32_t i, ns_method method)
{
    return participates(&segs[i], method) && (!t->taken || t->taken[i]);
}

float ns_from_pixel_centre(const GpuParams *cam, uint32_t width, uint32_t height, uint32_t p, const float x[3])
{
    float v[3] = {x[0] - cam->cam_position[0], x[1] - cam->cam_position[1], x[2] - cam->cam_position[2]};
    float z = v[0] * cam->cam_forward[0] + v[1] * cam->cam_forward[1] + v[2] * cam->cam_forward[2];
    if (!(z > 0.0f))
        return INFINITY;
    float r = (v[0] * cam->cam_right[0] + v[1] * cam->cam_right[1] + v[2] * cam->cam_right[2]) /
              (z * cam->cam_position[3]);
    float u = (v[0] * cam->cam_up[0] + v[1] * cam->cam_up[1] + v[2] * cam->cam_up[2]) / (z * cam->cam_right[3]);
    float dx = 0.5f * (r + 1.0f) * (float)width - ((float)(p % width) + 0.5f);
    float dy = 0.5f * (1.0f - u) * (float)height - ((float)(p / width) + 0.5f);
    return dx * dx + dy * dy;
}

/* Which segments of a pixel the gather takes (render.gather_camera_samples N > 0): those of
 * the N camera samples whose first segments start nearest the pixel's centre, where every
 * sample's first segment sees the same surface (same medium, entry within
 * SAME_SURFACE_DISTANCE); a pixel on a silhouette, whose samples see two media or one medium
 * at two depths, gathers every sample's. Double and multiple scattering vary over a mean free
 * path, many pixels; a pixel's samples lie a fraction of a pixel apart, and their paths
 * inside split alike, so Lbar (top of file) of some of them stands for Lbar of all of them as
 * a tile's representative stands for its tile. The nearest to the centre stand for the
 * pixel's mean best: a sample's place in its pixel is the rest of the difference (taking the
 * first sample, the cloud lost 1.2 dB against every sample; the nearest, none:
 * docs/scattering.md). The vrl method's estimates are independent per segment: it gathers
 * every sample. Runs after the keys and by_pixel. */
static int choose_gathered_samples(const ns_scene *scene, const GpuParams *cam, const GpuSegment *segs,
                                   uint32_t n, plan_use use, tile_plan *t)
{
    uint32_t pixels = t->width * t->height, samples = scene->render.gather_camera_samples;
    ns_method method = scene->render.method;
    float inv_spp = 1.0f / (float)scene->render.spp;
    for (uint32_t p = 0; p < pixels; p++)
        memcpy(t->keys[p].gather_weight, t->keys[p].weight, sizeof t->keys[p].gather_weight);
    if (use != PLAN_GATHER || !samples || samples >= scene->render.spp || method == NS_METHOD_VRL || !cam)
        return 0;
    /* A pixel's participating segments (rank << 32 | index, sorted: each sample's first
     * comes first) and its samples (distance bits << 32 | sample: floats >= 0 sort as their
     * bits do). */
    uint64_t *ranks = malloc(sizeof *ranks * (n ? n : 1)), *nearest = malloc(sizeof *nearest * (n ? n : 1));
    uint8_t *chosen = calloc(scene->render.spp, 1); /* per sample of the pixel at hand */
    t->taken = calloc(n ? n : 1, 1);
    if (!ranks || !nearest || !chosen || !t->taken) {
        free(ranks);
        free(nearest);
        free(chosen);
        return -1;
    }
    for (uint32_t p = 0; p < pixels; p++) {
        pixel_key *k = &t->keys[p];
        uint32_t count = 0, sample_count = 0;
        for (uint32_t j = t->segment_start[p]; j < t->segment_start[p + 1]; j++) {
            const GpuSegment *g = &segs[t->by_pixel[j]];
            t->taken[t->by_pixel[j]] = 1;
            if (participates(g, method))
                ranks[count++] = (uint64_t)(g->sample_index * 256u + (g->depth & 255u)) << 32 | t->by_pixel[j];
        }
        if (k->material == NS_NONE)
            continue;
        qsort(ranks, count, sizeof *ranks, compare_u64);
        int same = 1;
        for (uint32_t j = 0; j < count && same; j++) {
            const GpuSegment *g = &segs[(uint32_t)ranks[j]];
            if (j && segs[(uint32_t)ranks[j - 1]].sample_index == g->sample_index)
                continue; /* not its sample's first */
            pixel_key first = {.material = g->material, .distance = distance3(g->entry, scene->camera.position)};
            /* (a sample index beyond spp, from a caller other than the camera pass: every
             * sample's) */
            same = compatible(k, &first) && g->sample_index < scene->render.spp;
            float d = ns_from_pixel_centre(cam, t->width, t->height, p, g->entry);
            uint32_t bits;
            memcpy(&bits, &d, sizeof bits);
            nearest[sample_count++] = (uint64_t)bits << 32 | g->sample_index;
        }
        if (!same || sample_count <= samples)
            continue;
        qsort(nearest, sample_count, sizeof *nearest, compare_u64);
        for (uint32_t q = 0; q < samples; q++)
            chosen[(uint32_t)nearest[q]] = 1;
        memset(k->gather_weight, 0, sizeof k->gather_weight);
        for (uint32_t j = 0; j < count; j++) {
            uint32_t i = (uint32_t)ranks[j];
            t->taken[i] = chosen[segs[i].sample_index];
            for (int c = 0; c < 3 && t->taken[i]; c++)
                k->gather_weight[c] += segs[i].throughput[c] * inv_spp;
        }
        for (uint32_t q = 0; q < samples; q++)
            chosen[(uint32_t)nearest[q]] = 0;
    }
    free(ranks);
    free(nearest);
    free(chosen);
    return 0;
}

static int tile_plan_build(const ns_scene *scene, const GpuParams *frame, const GpuSegment *segs, uint32_t n,
                           plan_use use, tile_plan *t)
{
    const ns_camera *cam = &scene->camera;
    uint32_t pixels = cam->width * cam->height;
    t->width = cam->width;
    t->height = cam->height;
    ns_method method = scene->render.method;
    if (use == PLAN_SINGLE) {
        t->tile = 1;
        t->levels = scene->render.single_levels;
        t->tolerance = scene->render.single_tolerance;
        t->curved = 1;
    } else {
        t->tile = scene->render.gather_tile; /* >= 1: resolved and checked by ns_render */
        /* The vrl method's estimates are noisy (neighbours never agree) and each of its
         * gathers traces new light paths: it gathers every tile. */
        t->levels = method == NS_METHOD_VRL ? 0 : scene->render.gather_levels;
        t->tolerance = scene->render.gather_tolerance;
        t->correction_tolerance = CORRECTION_TOLERANCE * t->tolerance;
    }
    t->tiles_x = (t->width + t->tile - 1) / t->tile;
    t->tiles_y = (t->height + t->tile - 1) / t->tile;
    t->keys = malloc(sizeof *t->keys * pixels);
    t->representative = malloc(sizeof *t->representative * t->tiles_x * t->tiles_y);
    t->state = calloc(pixels, 1);
    t->radiance = calloc(pixels, sizeof *t->radiance);
    if (use == PLAN_GATHER && scene->render.boundary != NS_BOUNDARY_OFF && method != NS_METHOD_VRL &&
        !(t->correction = calloc(pixels, sizeof *t->correction)))
        return -1;
    t->segment_start = calloc(pixels + 1, sizeof *t->segment_start);
    t->by_pixel = malloc(sizeof *t->by_pixel * (n ? n : 1));
    if (!t->keys || !t->representative || !t->state || !t->radiance || !t->segment_start || !t->by_pixel)
        return -1;
    float inv_spp = 1.0f / (float)scene->render.spp;
    for (uint32_t p = 0; p < pixels; p++)
        t->keys[p] = (pixel_key){.material = NS_NONE, .first_rank = UINT32_MAX};
    /* Segments by pixel (counting sort), and each pixel's key. */
    for (uint32_t i = 0; i < n; i++)
        t->segment_start[segs[i].pixel + 1]++;
    for (uint32_t p = 0; p < pixels; p++)
        t->segment_start[p + 1] += t->segment_start[p];
    uint32_t *fill = calloc(pixels, sizeof *fill);
    if (!fill)
        return -1;
    for (uint32_t i = 0; i < n; i++) {
        const GpuSegment *s = &segs[i];
        t->by_pixel[t->segment_start[s->pixel] + fill[s->pixel]++] = i;
        if (use == PLAN_SINGLE ? !visible(s) : !participates(s, method))
            continue;
        pixel_key *k = &t->keys[s->pixel];
        for (int c = 0; c < 3; c++)
            k->weight[c] += s->throughput[c] * inv_spp;
        uint32_t rank = s->sample_index * 256u + (s->depth & 255u);
        if (rank < k->first_rank) {
            k->first_rank = rank;
            k->material = s->material;
            k->distance = distance3(s->entry, cam->position);
        }
    }
    free(fill);
    if (choose_gathered_samples(scene, frame, segs, n, use, t))
        return -1;
    choose_representatives(t);
    return 0;
}

/* ---------------------------------------------------------------------------------------
 * The adaptive gather (render.gather_levels = L > 0). The tiles' representatives are taken
 * on lattices 2^L, 2^(L-1), ..., 1 tiles apart, coarsest first: every one on the coarsest
 * is gathered; one first on a finer lattice lies midway between two of the coarser lattice
 * along a row or a column, or between four at the corners of a square (the midpoint of
 * both diagonals). It takes their mean when all of them see its surface and the error of
 * that mean, estimated from the coarser lattice, is within the tolerance in every channel;
 * else it is gathered. Each lattice is one gather round.
 *
 * The estimate. On a line through the coarser samples a (at -h) and b (at +h), with a' at
 * -3h and b' at +3h, the midpoint's mean (a + b) / 2 misses f(0) by f'' h^2 / 2, and the
 * second differences b - 2a + a' and a - 2b + b' are 4 f'' h^2: each gives the error as
 * its eighth. The larger one counts; where neither outer sample sees the same surface (a
 * silhouette close by) the spread |a - b| must be within the tolerance. A first-order test
 * (the spread alone) would gather most of a medium: multiple scattering falls like
 * exp(-sigma_tr r), several per cent per tile in a dense channel, while the error of the
 * mean is second order. Multiple scattering varies over a mean free path or more, many
 * pixels at any resolution that needs speed, so most of a medium is interpolated; its
 * silhouettes, the boundaries between media and the light's own features are gathered.
 * ------------------------------------------------------------------------------------- */

/* The representative of tile (tx, ty) when it sees the surface of `self`, else NS_NONE. */
static uint32_t same_surface_at(const tile_plan *t, int64_t tx, int64_t ty, uint32_t self)
{
    if (tx < 0 || ty < 0 || tx >= t->tiles_x || ty >= t->tiles_y)
        return NS_NONE;
    uint32_t r = t->representative[(uint32_t)ty * t->tiles_x + (uint32_t)tx];
    return r != NS_NONE && compatible(&t->keys[self], &t->keys[r]) ? r : NS_NONE;
}

/* Twice the midpoint's value on a line through fa (at -h) and fb (at +h), with the outer
 * samples fa_out (-3h) and fb_out (+3h) where they exist (else NAN): the cubic through all
 * four, (9 (fa + fb) - fa_out - fb_out) / 16, or the parabola through three, exact for
 * fields of degree 3 and 2 (unit_adaptive_gather). The plain mean misses by f'' h^2 / 2, as
 * much as the tolerance lets through: while this was written, a sphere's single scattering
 * (brightest by its lit face, falling off inward) came out 1% low over the sphere with the
 * mean at 0.05, 0.4% with this. Never below 0: what is interpolated is light. */
static float curved_pair(float fa, float fb, float fa_out, float fb_out)
{
    float twice;
    if (!isnan(fa_out) && !isnan(fb_out))
        twice = (9.0f * (fa + fb) - fa_out - fb_out) / 8.0f;
    else if (!isnan(fa_out))
        twice = -0.25f * fa_out + 1.5f * fa + 0.75f * fb;
    else if (!isnan(fb_out))
        twice = -0.25f * fb_out + 1.5f * fb + 0.75f * fa;
    else
        twice = fa + fb;
    return fmaxf(twice, 0.0f);
}

/* The error of the midpoint's mean from a line's second differences da (through the outer
 * sample at -3h) and db (+3h), NAN where that sample is missing: the larger one's eighth;
 * without either, the spread of the two inner samples. */
static float line_error(float fa, float fb, float da, float db)
{
    if (isnan(da) && isnan(db))
        return fabsf(fa - fb);
    return fmaxf(isnan(da) ? 0.0f : fabsf(da), isnan(db) ? 0.0f : fabsf(db)) / 8.0f;
}

/* The variance of a line's interpolated value over its samples' common variance: the cubic
 * through four ((81 + 81 + 1 + 1) / 64 of twice the value, so 164/256), the parabola through
 * three ((1 + 36 + 9) / 16 / 4), the mean of two (1/2). interpolation_variance is the same
 * with each sample's own variance. */
static float interpolation_share(int curved, int has_a_out, int has_b_out)
{
    if (!curved || (!has_a_out && !has_b_out))
        return 0.5f;
    return has_a_out && has_b_out ? 164.0f / 256.0f : 46.0f / 64.0f;
}

/* The variance of twice a line's interpolated value (curved_pair's, or the plain sum
 * fa + fb) from its samples' variances: the weights squared. */
static float interpolation_variance(const float (*variance)[3], int c, uint32_t a, uint32_t b,
                                    uint32_t a_out, uint32_t b_out, int curved)
{
    float va = variance[a][c], vb = variance[b][c];
    if (!curved || (a_out == NS_NONE && b_out == NS_NONE))
        return va + vb;
    if (a_out != NS_NONE && b_out != NS_NONE)
        return (81.0f * (va + vb) + variance[a_out][c] + variance[b_out][c]) / 64.0f;
    if (a_out != NS_NONE)
        return (variance[a_out][c] + 36.0f * va + 9.0f * vb) / 16.0f;
    return (variance[b_out][c] + 36.0f * vb + 9.0f * va) / 16.0f;
}

/* line_agrees' test where the values are noisy (t->variance): the error of the interpolation
 * is its bias, f'' h^2 / 2, estimated as before from the second differences d (an eighth of
 * each), whose own noise (weights 1, 4, 1: 6 v at the line's noise level v) is taken off
 * their square, since a second difference of pure noise is not curvature. The pixel is
 * interpolated when that bias is within the tolerance, or within what interpolating saves in
 * noise: computed, the pixel would carry the noise v; interpolated, the bias and the noise
 * of the interpolation (interpolation_share of v), so where the curvature is buried in the
 * noise an interpolation is no worse than computing. In squares:
 * max(0, d^2 - 6 v) / 64 <= allowed^2 + (1 - share) v; without outer samples, the spread's
 * square less 2 v. (What this leaves out: the finer lattices' samples, interpolated from the
 * same coarser ones, are correlated; and curved_pair's clamp at 0.)
 *
 * v is the line's noise level where its inner and outer samples agree on one: the outer
 * samples' mean variance, at most the larger of the inner two's (without outer samples, the
 * smaller of the inner two's). A pixel's variance comes from its own few camera samples, so
 * one that drew a bright outlier also has a large variance, which must not excuse the
 * curvature the outlier made. Measured as the image mean of the bench's bumpy sphere's
 * single scattering over a converged image's (1.000 computing every pixel; docs/bench.md):
 * the mean of the four samples' variances, 1.011 (an inner sample weighs 9/16 in the value,
 * so its outlier was spread around); their median, 1.002; the outer samples' alone, which
 * weigh -1/16, 0.993 at 128² and 0.990 at 256²; the two together, 0.999 and 0.998. */
static int noisy_line_agrees(const float (*variance)[3], int c, uint32_t a, uint32_t b,
                             uint32_t a_out, uint32_t b_out, float fa, float fb, float da,
                             float db, float allowed, int curved)
{
    float inner_max = fmaxf(variance[a][c], variance[b][c]), v;
    if (a_out != NS_NONE && b_out != NS_NONE)
        v = fminf(0.5f * (variance[a_out][c] + variance[b_out][c]), inner_max);
    else if (a_out != NS_NONE || b_out != NS_NONE)
        v = fminf(variance[a_out != NS_NONE ? a_out : b_out][c], inner_max);
    else
        v = fminf(variance[a][c], variance[b][c]);
    float bias2;
    if (isnan(da) && isnan(db))
        bias2 = (fa - fb) * (fa - fb) - 2.0f * v;
    else
        bias2 = (fmaxf(isnan(da) ? 0.0f : da * da, isnan(db) ? 0.0f : db * db) - 6.0f * v) / 64.0f;
    float saved = 1.0f - interpolation_share(curved, a_out != NS_NONE, b_out != NS_NONE);
    return fmaxf(bias2, 0.0f) <= allowed * allowed + saved * v;
}

/* The line from tile (tx, ty) through (tx + dx * step, ty + dy * step) and its mirror: adds
 * the two inner samples of `values` (t->radiance, or t->correction) to sum; returns 0 when
 * they cannot stand for the tile. The error allowed is the tolerance of the pixels' totals
 * (t->radiance, plus t->other: the scattered light the pixels show besides), whichever part
 * is interpolated: a correction near 0 needs no more precision than the image it corrects,
 * and double and multiple scattering under much brighter single scattering (the bench's
 * oil) no more than the pixel shows. With `variance` (else NULL) the values' variances
 * decide too (noisy_line_agrees), and the interpolation's is added to variance_sum. */
static int line_agrees(const tile_plan *t, const float (*values)[3], const float (*variance)[3],
                       float tolerance, uint32_t tx, uint32_t ty, int dx, int dy, uint32_t step,
                       uint32_t self, float sum[3], float variance_sum[3])
{
    int64_t sx = (int64_t)dx * step, sy = (int64_t)dy * step;
    uint32_t a = same_surface_at(t, (int64_t)tx - sx, (int64_t)ty - sy, self);
    uint32_t b = same_surface_at(t, (int64_t)tx + sx, (int64_t)ty + sy, self);
    if (a == NS_NONE || b == NS_NONE)
        return 0;
    uint32_t a_out = same_surface_at(t, (int64_t)tx - 3 * sx, (int64_t)ty - 3 * sy, self);
    uint32_t b_out = same_surface_at(t, (int64_t)tx + 3 * sx, (int64_t)ty + 3 * sy, self);
    for (int c = 0; c < 3; c++) {
        float fa = values[a][c], fb = values[b][c];
        float fa_out = a_out != NS_NONE ? values[a_out][c] : NAN;
        float fb_out = b_out != NS_NONE ? values[b_out][c] : NAN;
        float da = fb - 2.0f * fa + fa_out, db = fa - 2.0f * fb + fb_out; /* NAN: no sample */
        float total = t->radiance[a][c] + t->radiance[b][c];
        if (t->other)
            total += t->other[a][c] + t->other[b][c];
        float allowed = tolerance * 0.5f * total;
        if (variance ? !noisy_line_agrees(variance, c, a, b, a_out, b_out, fa, fb, da, db, allowed,
                                          t->curved)
                     : line_error(fa, fb, da, db) > allowed)
            return 0;
        if (variance)
            variance_sum[c] += interpolation_variance(variance, c, a, b, a_out, b_out, t->curved);
        sum[c] += t->curved ? curved_pair(fa, fb, fa_out, fb_out) : fa + fb;
    }
    return 1;
}

/* Tile (tx, ty)'s value in `values` (t->radiance or t->correction) as the mean of its
 * neighbours on the lattice `step` tiles apart, when they agree within `tolerance`
 * (line_agrees; INFINITY: whenever they see its surface). */
static int interpolate_tile(tile_plan *t, float (*values)[3], float tolerance, uint32_t tx,
                            uint32_t ty, uint32_t step)
{
    uint32_t self = t->representative[ty * t->tiles_x + tx];
    int odd_x = (tx / step) & 1, odd_y = (ty / step) & 1;
    /* Single scattering's noise weighs in, except at tolerance 0, which asks for every pixel
     * whose estimate is not exactly 0, noisy or not. */
    const float(*variance)[3] =
        t->variance && values == t->radiance && tolerance > 0.0f ? (const float(*)[3])t->variance : NULL;
    float sum[3] = {0, 0, 0}, variance_sum[3] = {0, 0, 0};
    int ok = odd_x && odd_y
                 ? line_agrees(t, values, variance, tolerance, tx, ty, 1, 1, step, self, sum,
                               variance_sum) &&
                       line_agrees(t, values, variance, tolerance, tx, ty, 1, -1, step, self, sum,
                                   variance_sum)
                 : line_agrees(t, values, variance, tolerance, tx, ty, odd_x, odd_y, step, self, sum,
                               variance_sum);
    if (!ok)
        return 0;
    float samples = odd_x && odd_y ? 4.0f : 2.0f;
    for (int c = 0; c < 3; c++) {
        values[self][c] = sum[c] / samples;
        /* The finer lattices weigh this value's noise as a computed one's. */
        if (variance)
            t->variance[self][c] = variance_sum[c] / (samples * samples);
    }
    return 1;
}

/* What a round gathers at a marked pixel (bits of `round`): the VRLs, and the boundary
 * sources unless their part was interpolated. */
enum { GATHER_VRLS = 1, GATHER_CORRECTION = 2, GATHER_BOTH = 3 };

/* The level of the first round: with the boundary correction, one coarser than the VRLs'. */
static uint32_t top_level(const tile_plan *t)
{
    return t->levels + (t->correction != NULL ? CORRECTION_LEVELS : 0);
}

/* Marks in `round` the pixels to gather on lattice `level` (2^level tiles apart) and
 * interpolates the rest of that lattice's new tiles. Returns how many were marked.
 *
 * The boundary correction (render.boundary) is smooth where the image is not: it is the
 * light the infinite medium would have beyond the boundary, spread by multiple scattering,
 * while the VRLs' part carries the light's own features. So it has its own lattice, one level
 * coarser than the VRLs' (a first round, top_level, gathers both on it), and a tile that
 * gathers its VRLs takes the correction as the mean of its neighbours on the coarser lattice
 * where the same error estimate allows, measured against the pixels' totals; its neighbours
 * gather both, and wherever the total is interpolated, so is the correction. With the
 * default levels 0 that gathers the boundary sources at a quarter of the tiles where the
 * correction is smooth (docs/scattering.md, *The correction's own lattice*). */
static uint32_t plan_round(tile_plan *t, uint32_t level, uint8_t *round, uint64_t *interpolated)
{
    memset(round, 0, (size_t)t->width * t->height);
    uint32_t marked = 0, step = 1u << level, top = top_level(t);
    if (level == top) /* the pixels no representative stands for go first */
        for (uint32_t p = 0; p < t->width * t->height; p++)
            if (t->state[p] == PIXEL_GATHERED) {
                round[p] = GATHER_BOTH;
                marked++;
            }
    for (uint32_t ty = 0; ty < t->tiles_y; ty += step)
        for (uint32_t tx = 0; tx < t->tiles_x; tx += step) {
            if (level < top && (tx / step) % 2 == 0 && (ty / step) % 2 == 0)
                continue; /* on a coarser lattice: done in an earlier round */
            uint32_t r = t->representative[ty * t->tiles_x + tx];
            if (r == NS_NONE)
                continue;
            if (level < t->levels && interpolate_tile(t, t->radiance, t->tolerance, tx, ty, step)) {
                t->state[r] = PIXEL_INTERPOLATED;
                (*interpolated)++;
                /* Its neighbours saw its surface: the correction takes the same mean, for
                 * the finer lattices to interpolate from. */
                if (t->correction)
                    interpolate_tile(t, t->correction, INFINITY, tx, ty, step);
                continue;
            }
            t->state[r] = PIXEL_GATHERED;
            round[r] = GATHER_BOTH;
            if (t->correction && level < top &&
                interpolate_tile(t, t->correction, t->correction_tolerance, tx, ty, step)) {
                round[r] = GATHER_VRLS;
                t->corrections_interpolated++;
            }
            marked++;
        }
    return marked;
}

/* A round's part of its stage's progress: the tiles it examines, 4^-L of them on the coarsest
 * lattice L (top), 3 * 4^-(l+1) on a lattice l below it. */
static double round_share(int level, int top)
{
    return level == top ? pow(0.25, level) : 3.0 * pow(0.25, level + 1);
}

/* The sums of throughput * L that a round added for its marked pixels, divided by the
 * pixels' throughput: Lbar (top of file), what the finer rounds interpolate from. */
static void per_unit_throughput(tile_plan *t, const uint8_t *round, float (*values)[3])
{
    for (uint32_t p = 0; p < t->width * t->height; p++)
        for (int c = 0; c < 3 && round[p]; c++) {
            float w = t->keys[p].gather_weight[c];
            values[p][c] = w > 0 ? values[p][c] / w : 0.0f;
        }
}

/* Lbar = sum X_j / w (w = sum W_j) is a ratio of spp independent camera samples' parts,
 * whose variance is spp / (spp - 1) sum_j (X_j - Lbar W_j)^2 / w^2. What varies with the
 * weights alone is not noise: a sample that misses the medium (X = W = 0) or sees it through
 * other Fresnel factors adds nothing, so a silhouette's or an edge's pixel has the noise of
 * its estimates only. Where that is not finite (a weight so small that w^2 underflows), or
 * w is 0, or spp < 2, 0: the tolerance alone decides there. */
float ns_ratio_variance(float sum_x, float w, const ns_sample_moments *m, int c, uint32_t spp)
{
    if (!(w > 0.0f) || spp < 2)
        return 0.0f;
    float lbar = sum_x / w;
    float spread = m->xx[c] - 2.0f * lbar * m->xw[c] + lbar * lbar * m->ww[c];
    float variance = fmaxf(spread, 0.0f) * ((float)spp / (float)(spp - 1)) / w / w;
    return isfinite(variance) ? variance : 0.0f;
}

/* The variance of the marked pixels' Lbar, into t->variance, from their sums (before
 * per_unit_throughput), their gather weights and their samples' moments. */
static void pixel_variance(tile_plan *t, const uint8_t *round, const float (*sum)[3],
                           const ns_sample_moments *moments, uint32_t spp)
{
    for (uint32_t p = 0; p < t->width * t->height; p++)
        for (int c = 0; c < 3 && round[p]; c++)
            t->variance[p][c] =
                ns_ratio_variance(sum[p][c], t->keys[p].gather_weight[c], &moments[p], c, spp);
}

/* The rounds as render_double_multiple runs them, on tiles whose keys and radiance the
 * caller gives: coarsest lattice first, plan_round marks the pixels to gather, and they are
 * gathered (their Lbar filled) before the next, finer round reads them; then the pixels
 * between the representatives are upsampled as compose() does. */
int ns_adaptive_tiles(uint32_t width, uint32_t height, uint32_t tile, uint32_t levels,
                      float tolerance, int curved, const uint32_t *material, const float *distance,
                      const float (*other)[3], const float (*variance)[3],
                      void (*gather)(uint32_t pixel, float radiance[3], ns_tile_field *field),
                      ns_tile_field *field, float (*radiance)[3], uint8_t *interpolated)
{
    if (!tile)
        return -1;
    uint32_t pixels = width * height;
    tile_plan t = {.width = width,
                   .height = height,
                   .tile = tile,
                   .tiles_x = (width + tile - 1) / tile,
                   .tiles_y = (height + tile - 1) / tile,
                   .levels = levels,
                   .tolerance = tolerance,
                   .curved = curved};
    t.keys = calloc(pixels, sizeof *t.keys);
    t.representative = malloc(sizeof *t.representative * (pixels ? pixels : 1)); /* >= the tiles */
    t.state = calloc(pixels, 1);
    t.radiance = calloc(pixels, sizeof *t.radiance);
    uint8_t *round = malloc(pixels ? pixels : 1);
    if (other && (t.other = malloc(sizeof *t.other * (pixels ? pixels : 1))))
        memcpy(t.other, other, sizeof *t.other * pixels);
    if (variance && (t.variance = malloc(sizeof *t.variance * (pixels ? pixels : 1))))
        memcpy(t.variance, variance, sizeof *t.variance * pixels);
    int ready = t.keys && t.representative && t.state && t.radiance && round && (!other || t.other) &&
                (!variance || t.variance);
    int status = ready ? NS_OK : -1;
    for (uint32_t p = 0; p < pixels && !status; p++)
        t.keys[p] = (pixel_key){.material = material[p], .distance = distance[p], .weight = {1, 1, 1},
                                .gather_weight = {1, 1, 1}};
    if (!status)
        choose_representatives(&t);
    uint64_t count = 0;
    for (int level = (int)levels; level >= 0 && !status; level--)
        if (plan_round(&t, (uint32_t)level, round, &count))
            for (uint32_t p = 0; p < pixels; p++)
                if (round[p])
                    gather(p, t.radiance[p], field);
    for (uint32_t p = 0; p < pixels && !status; p++) {
        if (t.state[p] == PIXEL_UPSAMPLED && material[p] != NS_NONE)
            upsampled_radiance(&t, p % width, p / width, t.radiance[p]);
        memcpy(radiance[p], t.radiance[p], sizeof radiance[p]);
        interpolated[p] = t.state[p] == PIXEL_INTERPOLATED;
    }
    free(round);
    tile_plan_free(&t);
    return status;
}

/* ---------------------------------------------------------------------------------------
 * Timings of the stages, added to the render's stats once at the end, in this order. Each
 * run of a stage is timed by ns_stage_begin / ns_stage_end, which also report it (progress);
 * a stage appears in the stats when it ran.
 * ------------------------------------------------------------------------------------- */
enum { T_RECONSTRUCT, T_ACCUMULATE, T_VRL, T_BOUNDARY, T_GRID, T_GATHER, T_SINGLE, T_COMPOSITE, T_COUNT };

static const char *const stage_names[T_COUNT] = {"reconstruct", "accumulate", "vrl",    "boundary", "grid",
                                                 "gather",      "single",     "composite"};

typedef struct scatter_times {
    double ms[T_COUNT];
    uint8_t ran[T_COUNT];
} scatter_times;

/* Stage `which` takes the part [a, b] of the current progress span. */
static ns_stage stage_begin(ns_context *ctx, int which, double a, double b)
{
    return ns_stage_begin(ctx, stage_names[which], a, b);
}

static void stage_end(ns_context *ctx, scatter_times *t, int which, const ns_stage *stage)
{
    t->ms[which] += ns_stage_end(ctx, stage);
    t->ran[which] = 1;
}

static void add_times(ns_render_stats *stats, const scatter_times *t)
{
    for (int i = 0; i < T_COUNT; i++)
        if (t->ran[i])
            ns_stats_add_stage(stats, stage_names[i], t->ms[i]);
}

/* ---------------------------------------------------------------------------------------
 * Progress (internal.h): how a camera batch's part of the render is shared out, by nominal
 * relative costs. With the scene files' defaults, a full nn render of a bench scene at 256x256
 * on lavapipe with a new material spends 71-87% of its time in the scattered part (tables,
 * sources, gather) on the analytic scenes and 27-39% on the meshes, single scattering 6-15%
 * and 48-66%, the ray pass 6-14% (docs/bench.md, *The gather's table as texels*, its
 * paired run); with the tables cached single scattering is 20-41% and 76-80%. The shares
 * below follow the analytic scenes. The vrl method's brute-force gather costs more than
 * its single scattering. A part the render does not run weighs nothing. Within the
 * double and multiple part: the VRLs take 10% of the first round that gathers; the rounds of
 * the adaptive gather share it by the tiles each examines (4^-L of them on the coarsest
 * lattice L, 3 * 4^-(l+1) on lattice l < L); a round shares its part among the media by
 * their segments, and a medium's part goes 5% to its grid, 25% to its tables
 * (reconstruct, then accumulate; nothing when cached) and the rest to its gather. The
 * composite stages (CPU bookkeeping between them) take no part of their own.
 * ------------------------------------------------------------------------------------- */
static const struct {
    double ray, single, scattered;
} batch_costs[NS_METHOD_COUNT] = {
    [NS_METHOD_NN] = {0.05, 0.15, 0.80},
    [NS_METHOD_TABLE] = {0.05, 0.15, 0.80},
    [NS_METHOD_VRL] = {0.05, 0.35, 0.60},
    [NS_METHOD_DIPOLE] = {0.10, 0.80, 0.10},
    [NS_METHOD_PT] = {1.0, 0.0, 0.0}, /* pt.c plans its own */
};

#define VRL_SHARE 0.10
#define GRID_SHARE 0.05
#define TABLES_SHARE 0.25

void ns_batch_shares(const ns_scene *scene, double shares[2])
{
    ns_method method = (unsigned)scene->render.method < NS_METHOD_COUNT ? scene->render.method : NS_METHOD_NN;
    uint32_t components = scene->render.components;
    double ray = batch_costs[method].ray;
    double single = components & NS_COMPONENT_SINGLE ? batch_costs[method].single : 0.0;
    double scattered = components & (NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE) ? batch_costs[method].scattered : 0.0;
    double total = ray + single + scattered;
    shares[0] = ray / total;
    shares[1] = (ray + single) / total;
}

/* Radiance inside a medium reaches vacuum divided by ior^2 (see the top of this file). */
static float exit_factor(const GpuMaterial *m)
{
    float ior = m->sigma_t[3];
    return 1.0f / (ior * ior);
}

/* Even bits of v packed into the low half: one coordinate of a Morton code. */
static uint32_t morton_compact(uint32_t v)
{
    v &= 0x55555555u;
    v = (v | (v >> 1)) & 0x33333333u;
    v = (v | (v >> 2)) & 0x0f0f0f0fu;
    v = (v | (v >> 4)) & 0x00ff00ffu;
    v = (v | (v >> 8)) & 0x0000ffffu;
    return v;
}

/* The pixels whose `round` has a bit of `want`, in Morton (Z) order: consecutive segments of the
 * list, which the gather runs side by side in one SIMD group, then lie close together on the image,
 * so their walks of the VRL hierarchy take the same branches (row order put 8 of them along 16
 * pixels of one row). Returns the count; order holds room for every pixel. */
static uint32_t marked_in_z_order(const tile_plan *t, const uint8_t *round, uint8_t want,
                                  uint32_t *order)
{
    uint32_t side = 1, n = 0;
    while (side < t->width || side < t->height)
        side *= 2;
    for (uint64_t code = 0; code < (uint64_t)side * side; code++) {
        uint32_t x = morton_compact((uint32_t)code), y = morton_compact((uint32_t)(code >> 1));
        if (x < t->width && y < t->height && (round[y * t->width + x] & want))
            order[n++] = y * t->width + x;
    }
    return n;
}

/* ---------------------------------------------------------------------------------------
 * Single scattering: every visible segment, or those of the pixels the adaptive rounds pick.
 * ------------------------------------------------------------------------------------- */
/* The visible segments of all, into kept: on a loop-limited device (lavapipe) in pixel order,
 * each pixel's in the order the camera pass wrote them. That pass appends segments as its
 * invocations finish, an order that differs from run to run; single scattering's SIMD groups
 * are made from this order, and there its dispatches are sized from their loop counts
 * (render/single.c; trace.glsl counts a group's, subgroupMax), so without the sort its float
 * sums could differ from one run of a render to the next; adaptive single scattering's
 * decisions (single_unit_image) need it on every device. Elsewhere the sort (75 ms for a million
 * segments) is skipped. Returns the count, or UINT32_MAX when out of memory. */
static uint32_t visible_segments(const GpuSegment *all, uint32_t count, int pixel_order,
                                 GpuSegment *kept)
{
    if (!pixel_order) {
        uint32_t n = 0;
        for (uint32_t i = 0; i < count; i++)
            if (visible(&all[i]))
                kept[n++] = all[i];
        return n;
    }
    uint64_t *order = malloc(sizeof *order * (count ? count : 1));
    if (!order)
        return UINT32_MAX;
    uint32_t n = 0;
    for (uint32_t i = 0; i < count; i++)
        if (visible(&all[i]))
            order[n++] = (uint64_t)all[i].pixel << 32 | i;
    qsort(order, n, sizeof *order, compare_u64);
    for (uint32_t k = 0; k < n; k++)
        kept[k] = all[(uint32_t)order[k]];
    free(order);
    return n;
}

int ns_sample_moments_add(const GpuSegment *segs, const float (*added)[3],
                          const float (*weight)[3], uint32_t count, ns_sample_moments *moments)
{
    uint64_t *key = malloc(sizeof *key * (count ? count : 1));
    if (!key)
        return -1;
    for (uint32_t start = 0, end; start < count; start = end) {
        for (end = start; end < count && segs[end].pixel == segs[start].pixel; end++)
            key[end - start] = (uint64_t)segs[end].sample_index << 32 | end;
        qsort(key, end - start, sizeof *key, compare_u64);
        ns_sample_moments *m = &moments[segs[start].pixel];
        float x[3] = {0, 0, 0}, w[3] = {0, 0, 0};
        for (uint32_t k = 0; k < end - start; k++) {
            uint32_t i = (uint32_t)key[k];
            for (int c = 0; c < 3; c++) {
                x[c] += added[i][c];
                w[c] += weight[i][c];
            }
            if (k + 1 < end - start && key[k + 1] >> 32 == key[k] >> 32)
                continue; /* the sample goes on */
            for (int c = 0; c < 3; c++) {
                m->xx[c] += x[c] * x[c];
                m->xw[c] += x[c] * w[c];
                m->ww[c] += w[c] * w[c];
                x[c] = w[c] = 0.0f;
            }
        }
    }
    free(key);
    return 0;
}

/* Single scattering of `count` segments: each one's throughput * L / spp (times its exit
 * factor, top of file) added into sum at its pixel; with `moments` (else NULL), the moments
 * of its camera samples' parts too (ns_sample_moments_add; `segs` holds each pixel's
 * segments together). */
static int single_segments(ns_context *ctx, const ns_scatter_inputs *in, const GpuSegment *segs,
                           uint32_t count, float (*sum)[3], ns_sample_moments *moments, ns_error *err)
{
    if (!count)
        return NS_OK;
    /* The GPU gets them most strata first (ns_single_order), the results go back to the
     * order of `segs`. */
    uint32_t samples = in->scene->render.single_samples;
    uint32_t *order = malloc(sizeof *order * count), *place = malloc(sizeof *place * count);
    GpuSegment *sorted = malloc(sizeof *sorted * count);
    if (!order || !place || !sorted || ns_single_order(segs, count, samples, order)) {
        free(order);
        free(place);
        free(sorted);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "single: %u segments", count);
    }
    for (uint32_t j = 0; j < count; j++)
        sorted[j] = segs[order[j]];
    gpu_buffer segments = {0}, out = {0};
    int status = gpu_buffer_create(&ctx->dev, &segments,
                                   &(gpu_buffer_desc){.size = sizeof *segs * count,
                                                      .data = sorted,
                                                      .data_size = sizeof *segs * count,
                                                      .label = "ns.single.segments"},
                                   err);
    free(sorted);
    if (!status)
        status = gpu_buffer_create(&ctx->dev, &out,
                                   &(gpu_buffer_desc){.size = 16ull * count,
                                                      .host_reads = 1,
                                                      .label = "ns.single.radiance"},
                                   err);
    if (!status)
        status = ns_single_scatter(ctx, in->scene_buffers, &segments, count, samples, &out, err);
    float (*added)[3] = NULL, (*weight)[3] = NULL;
    if (!status && moments &&
        (!(added = malloc(sizeof *added * count)) || !(weight = malloc(sizeof *weight * count))))
        status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "single: %u segments", count);
    if (!status) {
        const float(*radiance)[4] = out.mapped;
        float inv_spp = 1.0f / (float)in->scene->render.spp;
        /* Back in the order of `segs`, so that the sums add as they always did. */
        for (uint32_t j = 0; j < count; j++)
            place[order[j]] = j;
        for (uint32_t i = 0; i < count; i++) {
            float f = inv_spp * exit_factor(&in->gs->materials[segs[i].material]);
            for (int c = 0; c < 3; c++) {
                float x = segs[i].throughput[c] * radiance[place[i]][c] * f;
                sum[segs[i].pixel][c] += x;
                if (moments) {
                    added[i][c] = x;
                    weight[i][c] = segs[i].throughput[c] * inv_spp;
                }
            }
        }
        if (moments && ns_sample_moments_add(segs, (const float(*)[3])added, (const float(*)[3])weight,
                                             count, moments))
            status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "single: %u segments", count);
    }
    free(added);
    free(weight);
    free(place);
    free(order);
    gpu_buffer_destroy(&ctx->dev, &segments);
    gpu_buffer_destroy(&ctx->dev, &out);
    return status;
}

static void compose(const ns_scatter_inputs *in, const tile_plan *t);

/* Adaptive single scattering (render.single_levels > 0): the adaptive gather's rounds with
 * every pixel its own tile. A round computes the segments of the pixels plan_round marked
 * and stores their Lbar (top of file) for the finer rounds to interpolate from; at the end
 * every pixel takes its throughput times its Lbar, computed or interpolated. A round's
 * segments follow its pixels in Z order and each pixel's in the order of `kept` (the camera
 * pass's on a loop-limited device, visible_segments), so its dispatches are sized alike from
 * run to run. */
static int single_adaptive(ns_context *ctx, const ns_scatter_inputs *in, const GpuSegment *kept,
                           uint32_t n, uint64_t *interpolated, ns_error *err)
{
    const ns_scene *scene = in->scene;
    uint32_t pixels = scene->camera.width * scene->camera.height;
    tile_plan plan = {0};
    uint8_t *round = malloc(pixels ? pixels : 1);
    GpuSegment *list = malloc(sizeof *list * (n ? n : 1));
    uint32_t *order = malloc(sizeof *order * (pixels ? pixels : 1));
    /* The pixels' noise needs two camera samples or more to show. */
    uint32_t spp = scene->render.spp;
    ns_sample_moments *moments = spp > 1 ? calloc(pixels ? pixels : 1, sizeof *moments) : NULL;
    int status = NS_OK;
    if (!round || !list || !order || (spp > 1 && !moments) ||
        tile_plan_build(scene, &in->gs->params, kept, n, PLAN_SINGLE, &plan) ||
        (spp > 1 && !(plan.variance = calloc(pixels ? pixels : 1, sizeof *plan.variance))))
        status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "single: %u segments", n);
    double at = 0.0;
    int top = (int)plan.levels;
    for (int level = top; level >= 0 && !status; level--) {
        double part = round_share(level, top);
        status = ns_run_check(ctx, err);
        if (status)
            break;
        /* In Z order, as the gather's lists: a round's pixels are spread over the image, and
         * pixel order would put far-apart segments side by side in a SIMD group
         * (single_segments then orders them by strata, keeping this order within each). */
        uint32_t count = 0, marked = plan_round(&plan, (uint32_t)level, round, interpolated)
                                         ? marked_in_z_order(&plan, round, GATHER_BOTH, order)
                                         : 0;
        for (uint32_t j = 0; j < marked; j++)
            for (uint32_t k = plan.segment_start[order[j]]; k < plan.segment_start[order[j] + 1]; k++)
                list[count++] = kept[plan.by_pixel[k]];
        ns_span span = ns_progress_push(ctx, at, at + part);
        status = single_segments(ctx, in, list, count, plan.radiance, moments, err);
        ns_progress_pop(ctx, span);
        at += part;
        if (marked && !status) {
            if (plan.variance)
                pixel_variance(&plan, round, plan.radiance, moments, spp);
            per_unit_throughput(&plan, round, plan.radiance);
        }
    }
    if (!status)
        compose(in, &plan);
    tile_plan_free(&plan);
    free(moments);
    free(order);
    free(list);
    free(round);
    return status;
}

/* Single scattering's image per unit sigma_s into unit (zeroed here): the stage with the
 * materials buffer replaced by in->single_materials. */
static int single_unit_image(ns_context *ctx, const ns_scatter_inputs *in, float *unit,
                             uint64_t *interpolated, ns_error *err)
{
    size_t values = (size_t)in->scene->camera.width * in->scene->camera.height * 3;
    memset(unit, 0, sizeof *unit * values);
    if (!in->single_materials)
        return ns_fail(err, NS_ERR_INTERNAL, "single: no materials per unit sigma_s");
    const GpuSegment *all = in->segments->mapped;
    GpuSegment *kept = malloc(sizeof *kept * (in->segment_count ? in->segment_count : 1));
    /* Adaptive rounds decide from sums over a pixel's segments, so those must add in the same
     * order from run to run on every device: pixel order (each pixel's segments in the order
     * its camera path wrote them). */
    int pixel_order = ctx->dev.loop_limited || in->scene->render.single_levels;
    uint32_t n = kept ? visible_segments(all, in->segment_count, pixel_order, kept) : UINT32_MAX;
    if (n == UINT32_MAX) {
        free(kept);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "single: %u segments", in->segment_count);
    }
    ns_gpu_scene unit_scene = *in->gs;
    unit_scene.materials = (GpuMaterial *)in->single_materials;
    gpu_buffer_desc descs[NS_SCENE_BUFFER_COUNT];
    ns_gpu_scene_buffer_descs(&unit_scene, descs);
    gpu_buffer buffers[NS_SCENE_BUFFER_COUNT];
    memcpy(buffers, in->scene_buffers, sizeof buffers);
    gpu_buffer *material_buffer = &buffers[NS_SCENE_BUFFER_MATERIALS];
    memset(material_buffer, 0, sizeof *material_buffer);
    int status =
        gpu_buffer_create(&ctx->dev, material_buffer, &descs[NS_SCENE_BUFFER_MATERIALS], err);
    ns_scatter_inputs unit_in = *in;
    unit_in.scene_buffers = buffers;
    unit_in.pixels = unit;
    if (!status && in->scene->render.single_levels)
        status = single_adaptive(ctx, &unit_in, kept, n, interpolated, err);
    else if (!status)
        status = single_segments(ctx, &unit_in, kept, n, (float(*)[3])unit, NULL, err);
    gpu_buffer_destroy(&ctx->dev, material_buffer);
    free(kept);
    return status;
}

/* Single scattering: its image per unit sigma_s, computed into in->single_image (for render.c
 * to keep) or the one kept (in->single_given), times each channel's reference, added into the
 * pixels. The product comes last, so a kept image gives the pixels a computed one would, bit
 * for bit (render/camera_keep.c). */
static int render_single(ns_context *ctx, const ns_scatter_inputs *in, double a, double b,
                         ns_render_stats *stats, scatter_times *times, ns_error *err)
{
    size_t values = (size_t)in->scene->camera.width * in->scene->camera.height * 3;
    float *unit =
        in->single_image ? in->single_image : malloc(sizeof *unit * (values ? values : 1));
    if (!unit)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "single: %u segments", in->segment_count);
    int status = NS_OK;
    if (!in->single_given) { /* else no stage: nothing is computed */
        ns_stage stage = stage_begin(ctx, T_SINGLE, a, b);
        uint64_t interpolated = 0;
        status = single_unit_image(ctx, in, unit, &interpolated, err);
        if (stats)
            stats->single_interpolated += interpolated;
        stage_end(ctx, times, T_SINGLE, &stage);
    }
    if (!status)
        for (size_t i = 0; i < values; i++)
            in->pixels[i] += unit[i] * in->single_reference[i % 3];
    if (unit != in->single_image)
        free(unit);
    return status;
}

/* ---------------------------------------------------------------------------------------
 * Double and multiple scattering.
 * ------------------------------------------------------------------------------------- */
typedef struct gather_list {
    GpuSegment *segments;   /* gathered segments, grouped by material */
    uint32_t count;
    uint32_t material_first[NS_MAX_MATERIALS + 1]; /* material m: [first[m], first[m + 1]) */
} gather_list;

/* The participating segments of the pixels whose `round` has a bit of `want`. */
static int gather_list_build(const tile_plan *t, const GpuSegment *segs, ns_method method,
                             const uint8_t *round, uint8_t want, gather_list *g)
{
    memset(g, 0, sizeof *g);
    uint32_t pixels = t->width * t->height, n = 0;
    uint32_t *order = malloc(sizeof *order * (pixels ? pixels : 1));
    if (!order)
        return -1;
    uint32_t marked = marked_in_z_order(t, round, want, order);
    for (uint32_t j = 0; j < marked; j++)
        for (uint32_t k = t->segment_start[order[j]]; k < t->segment_start[order[j] + 1]; k++)
            if (gathered(t, segs, t->by_pixel[k], method)) {
                g->material_first[segs[t->by_pixel[k]].material + 1]++;
                n++;
            }
    for (uint32_t m = 0; m < NS_MAX_MATERIALS; m++)
        g->material_first[m + 1] += g->material_first[m];
    g->count = n;
    g->segments = malloc(sizeof *g->segments * (n ? n : 1));
    uint32_t *fill = calloc(NS_MAX_MATERIALS, sizeof *fill);
    if (!g->segments || !fill) {
        free(fill);
        free(order);
        return -1;
    }
    for (uint32_t j = 0; j < marked; j++)
        for (uint32_t k = t->segment_start[order[j]]; k < t->segment_start[order[j] + 1]; k++) {
            uint32_t i = t->by_pixel[k];
            if (!gathered(t, segs, i, method))
                continue;
            uint32_t at = g->material_first[segs[i].material] + fill[segs[i].material]++;
            g->segments[at] = segs[i];
        }
    free(fill);
    free(order);
    return 0;
}

/* Axis-aligned bounds (scene units); empty while lo > hi. */
typedef struct bounds3 {
    double lo[3], hi[3];
} bounds3;

static void bounds_empty(bounds3 *b)
{
    for (int k = 0; k < 3; k++) {
        b->lo[k] = INFINITY;
        b->hi[k] = -INFINITY;
    }
}

static void bounds_add(bounds3 *b, const float p[3])
{
    for (int k = 0; k < 3; k++) {
        b->lo[k] = fmin(b->lo[k], p[k]);
        b->hi[k] = fmax(b->hi[k], p[k]);
    }
}

/* Adds the bounds of the objects of material m to b: 0 where one of them is unbounded (a
 * plane). */
static int objects_bounds_add(const ns_scene *scene, uint32_t m, bounds3 *b)
{
    for (uint32_t i = 0; i < scene->object_count; i++) {
        const ns_object *o = &scene->objects[i];
        if (o->material != m)
            continue;
        if (o->shape == NS_SHAPE_SPHERE) {
            float lo[3], hi[3];
            for (int k = 0; k < 3; k++) {
                lo[k] = o->center[k] - o->radius;
                hi[k] = o->center[k] + o->radius;
            }
            bounds_add(b, lo);
            bounds_add(b, hi);
        } else if (o->shape == NS_SHAPE_BOX) {
            bounds_add(b, o->min);
            bounds_add(b, o->max);
        } else if (o->shape == NS_SHAPE_MESH) {
            for (uint32_t t = o->first_triangle; t < o->first_triangle + o->triangle_count; t++)
                for (int v = 0; v < 3; v++)
                    bounds_add(b, scene->triangles[t].v[v]);
        } else {
            return 0;
        }
    }
    return 1;
}

/* Per medium, the table bins (ns_table_reach_bins) that its gather reads. The gather reads a
 * medium's table only at the offset between a source's origin (where light enters the medium,
 * scatters in it or meets its boundary; a grid's representative lies between such origins)
 * and a camera segment's end, all of them within the bounds of the objects of that material
 * when those are closed: their diagonal, grown by ten ray offsets (common.glsl, ray_epsilon)
 * for hit points a hair outside, in mean free paths of the densest channel, which stays the
 * same from view to view, so a camera move finds its tables cached. The segments' ends and
 * the sources' origins are added all the same: an open mesh lets light and camera paths run
 * on to whatever they meet next, and a plane of the medium reaches everywhere (every cell). */
static void media_reach(const ns_scatter_inputs *in, const ns_vrl_set *vrls,
                        const ns_boundary_groups *groups, uint32_t *reach_bins)
{
    const ns_gpu_scene *gs = in->gs;
    uint32_t materials = gs->material_count;
    bounds3 *b = malloc(materials * sizeof *b);
    for (uint32_t m = 0; m < materials; m++) {
        reach_bins[m] = NS_TABLE_NRHO; /* every cell: slower, never wrong */
        if (!b)
            continue;
        bounds_empty(&b[m]);
        if (!objects_bounds_add(in->scene, m, &b[m]) || !(b[m].lo[0] <= b[m].hi[0])) {
            b[m].lo[0] = -INFINITY; /* unbounded, or no object: every cell */
            continue;
        }
        /* Grown first, so that points a hair outside a closed object leave the reach as the
         * objects alone make it, whatever the view. */
        double size = 1.0;
        for (int k = 0; k < 3; k++)
            size = fmax(size, fmax(fabs(b[m].lo[k]), fabs(b[m].hi[k])));
        for (int k = 0; k < 3; k++) {
            b[m].lo[k] -= 1e-3 * size;
            b[m].hi[k] += 1e-3 * size;
        }
    }
    if (!b)
        return;
    const GpuSegment *segs = in->segments->mapped;
    for (uint32_t i = 0; i < in->segment_count; i++)
        if (segs[i].material < materials) {
            bounds_add(&b[segs[i].material], segs[i].entry);
            bounds_add(&b[segs[i].material], segs[i].exit);
        }
    for (uint32_t i = 0; i < vrls->count; i++)
        if (vrls->vrls[i].material < materials)
            bounds_add(&b[vrls->vrls[i].material], vrls->vrls[i].origin);
    for (uint32_t g = 0; g < groups->count; g++)
        for (uint32_t i = 0; i < groups->group[g].set.count; i++) {
            const GpuVrl *v = &groups->group[g].set.vrls[i];
            if (v->material < materials)
                bounds_add(&b[v->material], v->origin);
        }
    for (uint32_t m = 0; m < materials; m++) {
        const float *s = gs->materials[m].sigma_t;
        double densest = fmax(s[0], fmax(s[1], s[2])), squared = 0.0;
        for (int k = 0; k < 3; k++)
            squared += (b[m].hi[k] - b[m].lo[k]) * (b[m].hi[k] - b[m].lo[k]);
        reach_bins[m] = ns_table_reach_bins(sqrt(squared) * densest); /* not a number: all */
    }
    free(b);
}

static void ns_table_key_for(const GpuMaterial *m, const ns_scene *scene, uint32_t reach_bins,
                             uint32_t orders, ns_table_key *key)
{
    memset(key, 0, sizeof *key);
    key->source = scene->render.method;
    key->g = m->sigma_s[3];
    for (int c = 0; c < 3; c++)
        key->albedo[c] = m->sigma_t[c] > 0 ? m->sigma_s[c] / m->sigma_t[c] : 0.0f;
    key->orders = orders;
    key->accumulation = scene->render.accumulation;
    key->tables = scene->render.tables;
    key->reach_bins = reach_bins;
}

/* What the table and dipole methods gather from, kept across the rounds of an adaptive
 * gather: the VRLs, and each medium's grid, built when a round first needs it. The tables
 * are asked of the cache in every round (a hit costs nothing): a pointer kept across rounds
 * could be evicted by another medium's tables. */
typedef struct vrl_source {
    int ready;
    ns_vrl_set set;
    ns_vrl_grid *grids;       /* per material */
    uint8_t *grid_built;      /* per material */
    uint64_t *table_bytes;    /* per (orders, material): 0 until its tables were used */
    uint32_t *reach_bins;     /* per material: where its gather reads the tables (media_reach) */
    /* render.boundary: the sources by group, and per (group, material) their grid. */
    ns_boundary_groups boundary;
    ns_vrl_grid *boundary_grids;  /* [group * materials + material] */
    uint8_t *boundary_grid_built; /* same index */
} vrl_source;

static void vrl_source_free(vrl_source *v, uint32_t material_count)
{
    for (uint32_t m = 0; v->grids && m < material_count; m++)
        ns_vrl_grid_free(&v->grids[m]);
    for (uint32_t i = 0; v->boundary_grids && i < NS_BOUNDARY_GROUPS * material_count; i++)
        ns_vrl_grid_free(&v->boundary_grids[i]);
    free(v->grids);
    free(v->grid_built);
    free(v->table_bytes);
    free(v->reach_bins);
    free(v->boundary_grids);
    free(v->boundary_grid_built);
    ns_boundary_groups_free(&v->boundary);
    ns_vrl_set_free(&v->set);
    memset(v, 0, sizeof *v);
}

/* A table's orders (NS_COMPONENT_DOUBLE and/or NS_COMPONENT_MULTIPLE) as an index, so that a
 * table read by several grids counts its bytes once. */
#define ORDER_SETS 4u
static uint32_t order_set(uint32_t orders)
{
    return (orders & NS_COMPONENT_DOUBLE ? 1u : 0u) | (orders & NS_COMPONENT_MULTIPLE ? 2u : 0u);
}

/* The VRLs end at their exit, in the gather's bounded form (the beam past the exit
 * subtracted with the same tables), and their internal reflections are VRLs of their own:
 * asked for, and only without the boundary correction. With it the VRLs are endless beams:
 * the walks' ghost at the end of each entry stretch (ns_boundary_sources' entry_ghosts) is
 * the beam past its exit, subtracted as a source on the correction's lattice at the endless
 * form's rate (the bounded form reads the table twice per VRL: docs/bench.md, *End to end at
 * 256², again*), and the walks follow the reflections. */
static int vrls_bounded(const ns_scene *scene)
{
    return scene->render.vrl_beams == NS_VRL_BEAMS_BOUNDED && scene->render.boundary == NS_BOUNDARY_OFF;
}

/* Whether a straight line that leaves an object of a medium can pass through an object of
 * that medium again: a mesh may be non-convex, and two objects of one medium may face each
 * other. A lone sphere, box or plane is convex, and its walks need not trace their lines
 * again; objects of diffuse materials never count (walks live in media only). */
static int lines_may_return(const ns_scene *scene)
{
    for (uint32_t i = 0; i < scene->object_count; i++) {
        const ns_object *o = &scene->objects[i];
        if (scene->materials[o->material].type != NS_MATERIAL_MEDIUM)
            continue;
        if (o->shape == NS_SHAPE_MESH)
            return 1;
        for (uint32_t j = 0; j < i; j++)
            if (scene->objects[j].material == o->material)
                return 1;
    }
    return 0;
}

/* render.boundary: the light's walks inside the objects (the `vrl` method's paths, as many
 * as render.vrls and at least NS_BOUNDARY_MIN_WALKS, on a seed of their own), turned into
 * grouped sources (boundary.c). */
static int boundary_sources_make(ns_context *ctx, const ns_scatter_inputs *in, vrl_source *v,
                                 ns_error *err)
{
    const ns_scene *scene = in->scene;
    ns_vrl_set walks;
    uint32_t paths =
        scene->render.vrls > NS_BOUNDARY_MIN_WALKS ? scene->render.vrls : NS_BOUNDARY_MIN_WALKS;
    /* Marked lines: whether each ghost's line meets its medium again decides whether the
     * ghost reads its first order (ns_boundary_source_orders); it costs a trace per stretch
     * (the bunny's boundary stage at 64²: 1.28 -> 1.73 s). The ends: the reflection at each
     * stretch's end, for unscattered light's reflected sources in expectation. The
     * environment's mark: which of those single.comp has (ns_boundary_source_orders). */
    uint32_t options = NS_VRL_TRACE_ENDS | NS_VRL_TRACE_MARK_ENVIRONMENT |
                       (lines_may_return(scene) ? NS_VRL_TRACE_MARK_LINES : 0u);
    int status = ns_vrl_method_trace(ctx, scene, in->gs, in->scene_buffers, paths,
                                     scene->render.seed ^ 0x9e3779b9u, options, &walks, NULL, err);
    if (status)
        return status;
    GpuVrl *sources = malloc(sizeof *sources * 2 * (walks.count ? walks.count : 1));
    if (!sources) {
        ns_vrl_set_free(&walks);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "boundary: %u stretches", walks.count);
    }
    uint32_t n =
        ns_boundary_sources(walks.vrls, walks.ends, walks.count, in->gs->materials, 1, sources);
    ns_vrl_set_free(&walks);
    /* Only the sources whose orders the components ask for take part (or a budget). */
    uint32_t wanted = 0;
    for (uint32_t i = 0; i < n; i++)
        if (ns_boundary_source_orders(&sources[i], scene->render.components))
            sources[wanted++] = sources[i];
    n = wanted;
    /* Long walks (milk's albedo 0.999) make many weak sources, each costing the gather as
     * much as a strong one: Russian roulette keeps about as many as there are VRLs. */
    uint32_t target =
        v->set.count > NS_BOUNDARY_MIN_SOURCES ? v->set.count : NS_BOUNDARY_MIN_SOURCES;
    float floor = ns_boundary_floor(sources, n, target);
    n = ns_boundary_roulette(sources, n, floor, scene->render.seed ^ 0x85ebca6bu);
    status = ns_boundary_group(sources, n, scene->render.components, &v->boundary, err);
    free(sources);
    return status;
}

static int vrl_source_init(ns_context *ctx, const ns_scatter_inputs *in, vrl_source *v,
                           ns_render_stats *stats, scatter_times *times, ns_error *err)
{
    const ns_scene *scene = in->scene;
    uint32_t materials = in->gs->material_count ? in->gs->material_count : 1;
    memset(v, 0, sizeof *v);
    v->ready = 1;
    v->grids = calloc(materials, sizeof *v->grids);
    v->grid_built = calloc(materials, 1);
    v->table_bytes = calloc(ORDER_SETS * materials, sizeof *v->table_bytes);
    v->reach_bins = calloc(materials, sizeof *v->reach_bins);
    v->boundary_grids = calloc(NS_BOUNDARY_GROUPS * materials, sizeof *v->boundary_grids);
    v->boundary_grid_built = calloc(NS_BOUNDARY_GROUPS * materials, 1);
    if (!v->grids || !v->grid_built || !v->table_bytes || !v->reach_bins || !v->boundary_grids ||
        !v->boundary_grid_built)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "gather: %u materials", materials);
    int boundary = scene->render.boundary != NS_BOUNDARY_OFF;
    /* Bounded beams (nn and table only: scene_check.c): the beam's internal reflections are
     * VRLs of their own, as far as they go (the chain stops at NS_VRL_MAX_CHAIN). */
    uint32_t chain = vrls_bounded(scene) ? NS_VRL_MAX_CHAIN : 1;
    /* The sources do not depend on the camera: a render that makes the same ones as the
     * context's last takes a copy of them (source_keep.c), and lists no stage "vrl" or
     * "boundary". */
    size_t signature_bytes = 0;
    unsigned char *signature = ns_source_signature(scene, in->gs, chain, &signature_bytes);
    int reused = ns_source_keep_take(ctx, signature, signature_bytes, &v->set, &v->boundary);
    int status = NS_OK;
    if (!reused) {
        ns_stage stage = stage_begin(ctx, T_VRL, 0.0, boundary ? 0.5 : 1.0);
        status = ns_vrl_generate(ctx, scene, in->gs, in->scene_buffers, scene->render.vrls, chain,
                                 scene->render.seed, &v->set, err);
        stage_end(ctx, times, T_VRL, &stage);
        if (!status && boundary) {
            stage = stage_begin(ctx, T_BOUNDARY, 0.5, 1.0);
            status = boundary_sources_make(ctx, in, v, err);
            stage_end(ctx, times, T_BOUNDARY, &stage);
        }
        if (!status) {
            ns_source_keep_put(ctx, signature, signature_bytes, &v->set, &v->boundary);
            signature = NULL;
        }
    }
    free(signature);
    if (!status && in->gs->material_count)
        media_reach(in, &v->set, &v->boundary, v->reach_bins);
    /* The VRLs' orders and the groups' tables' (their blurred first order is computed in the
     * gather, not read from a table) are announced, so that a material's tables of two of
     * them share a walk. */
    if (!status && scene->render.method != NS_METHOD_DIPOLE) {
        ns_tables_expect_orders(ctx, scene->render.components);
        for (uint32_t g = 0; g < v->boundary.count; g++)
            if (v->boundary.group[g].orders & ~NS_TABLE_FIRST_BLURRED)
                ns_tables_expect_orders(ctx, v->boundary.group[g].orders & ~NS_TABLE_FIRST_BLURRED);
    }
    if (!status && stats) {
        stats->vrl_paths = v->set.paths;
        stats->vrl_count = v->set.count;
        for (uint32_t g = 0; g < v->boundary.count; g++)
            stats->boundary_sources += v->boundary.group[g].set.count;
        stats->sources_reused |= (uint32_t)reused;
    }
    return status;
}

/* One form of the gather (gather.glsl) of a grid over medium m's segments of the round: into
 * out, or added to it. */
static int gather_form(ns_context *ctx, const ns_scatter_inputs *in, uint32_t m,
                       const ns_vrl_grid *grid, uint32_t mode, const ns_scatter_tables *tables,
                       int bounded, int first_order, const gather_list *list, gpu_buffer *seg_buf,
                       gpu_buffer *out, int add, ns_render_stats *stats, scatter_times *times,
                       ns_error *err)
{
    uint32_t first = list->material_first[m], count = list->material_first[m + 1] - first;
    ns_gather_desc desc = {.segments = seg_buf,
                           .first_segment = first,
                           .segment_count = count,
                           .grid = grid,
                           .table = tables ? &tables->a : NULL,
                           .out = out,
                           .add = add};
    ns_gather_params(&desc.params, &in->gs->materials[m], mode, tables,
                     in->scene->render.cull_solid_angle, bounded);
    if (first_order)
        ns_gather_params_first(&desc.params, &in->gs->materials[m]);
    /* A form other than those made at start-up compiles its shader on first use: its own
     * stage "gather_pipeline" (ns_gather_pipeline reports it). */
    gpu_pipeline *unused;
    double made_ms;
    int status = ns_gather_pipeline(ctx, &desc.params, &unused, &made_ms, err);
    if (made_ms > 0 && stats)
        ns_stats_add_stage(stats, "gather_pipeline", made_ms);
    ns_gather_counts counts;
    ns_stage stage = stage_begin(ctx, T_GATHER, 0.0, 1.0);
    if (!status)
        status = ns_gather_run(ctx, &desc, &counts, err);
    if (!status) /* one submission per grid, form and round */
        ns_progress_tick(ctx, 1.0);
    stage_end(ctx, times, T_GATHER, &stage);
    if (!status && stats && !add) { /* a second walk meets the same pairs */
        stats->interactions += counts.interactions;
        stats->cells_culled += counts.cells_culled;
        stats->cells_represented += counts.cells_represented;
    }
    return status;
}

/* One grid of medium m (its VRLs, or one group of boundary sources) gathered over the medium's
 * segments of the round into out (overwritten there), through the tables of `orders`; the
 * blurred first order of a group of boundary sources is computed instead (gather.glsl,
 * first_order), in the same walk with the default form (gather_exact_first.comp), else
 * alone (gather_first.comp; with the paper's accumulation the exact first order beside the
 * 5-mfp form of the others). Progress: the current span, 5% to the grid's build (done by the
 * caller), 25% to the tables, the rest to the gather. */
static int gather_grid(ns_context *ctx, const ns_scatter_inputs *in, vrl_source *source, uint32_t m,
                       const ns_vrl_grid *grid, uint32_t orders, int bounded,
                       const gather_list *list, gpu_buffer *seg_buf, gpu_buffer *out,
                       ns_render_stats *stats, scatter_times *times, ns_error *err)
{
    const ns_scene *scene = in->scene;
    const GpuMaterial *mat = &in->gs->materials[m];
    uint32_t first = list->material_first[m], count = list->material_first[m + 1] - first;
    int dipole = scene->render.method == NS_METHOD_DIPOLE;
    int first_order = !dipole && (orders & NS_TABLE_FIRST_BLURRED) != 0;
    uint32_t table_orders = orders & ~NS_TABLE_FIRST_BLURRED;
    const ns_scatter_tables *tables = NULL;
    uint32_t mode = NS_GATHER_MODE_DIPOLE;
    int status = NS_OK;
    if (!dipole && table_orders) {
        ns_table_key key;
        ns_table_key_for(mat, scene, source->reach_bins[m], table_orders, &key);
        ns_table_stats ts = {0};
        /* The stages "reconstruct" and "accumulate" run inside, when the cache lacks the
         * tables. */
        ns_span outer = ns_progress_push(ctx, GRID_SHARE, GRID_SHARE + TABLES_SHARE);
        status = ns_tables_get(ctx, &key, &tables, &ts, err);
        ns_progress_pop(ctx, outer);
        times->ms[T_RECONSTRUCT] += ts.reconstruct_ms;
        times->ms[T_ACCUMULATE] += ts.accumulate_ms;
        times->ran[T_RECONSTRUCT] |= (uint8_t)ts.reconstructed;
        times->ran[T_ACCUMULATE] |= (uint8_t)ts.accumulated;
        if (stats) {
            stats->tables_reused += ts.tables_reused;
            stats->tables_made += ts.tables_made;
            stats->tables_blended += ts.tables_blended;
        }
        if (!status) {
            if (stats)
                stats->weights_bytes = ts.weights_bytes;
            source->table_bytes[order_set(table_orders) * in->gs->material_count + m] =
                tables->bytes;
        }
        mode = scene->render.accumulation == NS_ACCUMULATION_PAPER ? NS_GATHER_MODE_PAPER
                                                                  : NS_GATHER_MODE_EXACT;
    }
    ns_span gathering = ns_progress_push(ctx, GRID_SHARE + TABLES_SHARE, 1.0);
    if (!status && grid->vrl_count) {
        /* The default form computes the first order in its own walk over the sources; the
         * others (the paper's accumulation, bounded beams) leave it to a second walk. */
        int together = first_order && mode == NS_GATHER_MODE_EXACT && !bounded;
        int wrote = 0;
        if (dipole || table_orders) {
            status = gather_form(ctx, in, m, grid, mode, tables, bounded, together, list, seg_buf,
                                 out, 0, stats, times, err);
            wrote = 1;
        }
        if (!status && first_order && !(together && wrote))
            status = gather_form(ctx, in, m, grid, NS_GATHER_MODE_FIRST, NULL, 0, 1, list, seg_buf,
                                 out, wrote, stats, times, err);
    } else if (!status) {
        memset((float(*)[4])out->mapped + first, 0, 16ull * count); /* no VRL in this medium */
    }
    ns_progress_pop(ctx, gathering);
    return status;
}

/* Builds a grid of medium m's VRLs in set, once (built[0] says). */
static int grid_once(ns_context *ctx, const ns_vrl_set *set, const GpuMaterial *mat, uint32_t m,
                     float cull_solid_angle, ns_vrl_grid *grid, uint8_t *built, scatter_times *times,
                     ns_error *err)
{
    if (*built)
        return NS_OK;
    float s_max = fmaxf(mat->sigma_t[0], fmaxf(mat->sigma_t[1], mat->sigma_t[2]));
    ns_stage stage = stage_begin(ctx, T_GRID, 0.0, GRID_SHARE);
    /* Representatives pay off only with small leaves (docs/scattering.md). */
    uint32_t leaf_fill = cull_solid_angle > 0 ? NS_VRL_LEAF_FILL_REPRESENTED : 0;
    int status = ns_vrl_grid_build(set, m, s_max > 0 ? 1.0f / s_max : INFINITY, leaf_fill, grid, err);
    stage_end(ctx, times, T_GRID, &stage);
    *built = !status;
    return status;
}

/* A round's segments of one kind (the VRLs' or the boundary correction's) on the device, and
 * what the gather found for each. */
typedef struct round_part {
    gather_list list;
    gpu_buffer segments, out;
} round_part;

/* Table and dipole methods: one round's segments, per medium its grid, tables and gather
 * into vrls->out; with render.boundary, each group of boundary sources of the medium gathered
 * over correction's segments (a subset: plan_round) into scratch and summed into its out. */
static int gather_from_vrls(ns_context *ctx, const ns_scatter_inputs *in, vrl_source *source,
                            round_part *vrls, round_part *correction, gpu_buffer *scratch,
                            ns_render_stats *stats, scatter_times *times, ns_error *err)
{
    const ns_scene *scene = in->scene;
    const gather_list *list = &vrls->list;
    uint32_t orders = scene->render.components & (NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE);
    uint32_t materials = in->gs->material_count;
    int status = NS_OK;
    double start = 0.0; /* of this round's part, after the VRLs */
    if (!source->ready) {
        ns_span outer = ns_progress_push(ctx, 0.0, VRL_SHARE);
        status = vrl_source_init(ctx, in, source, stats, times, err);
        ns_progress_pop(ctx, outer);
        start = VRL_SHARE;
    }
    if (correction && correction->list.count)
        memset(correction->out.mapped, 0, 16ull * correction->list.count);
    for (uint32_t m = 0; m < materials && !status; m++) {
        uint32_t first = list->material_first[m], count = list->material_first[m + 1] - first;
        if (!count)
            continue;
        /* This medium's part of the round: its share of the segments, shared equally by its
         * VRLs' grid and its groups of boundary sources. */
        double part = (1.0 - start) / list->count;
        ns_span medium = ns_progress_push(ctx, start + part * first, start + part * (first + count));
        const GpuMaterial *mat = &in->gs->materials[m];
        uint32_t grids = 1 + source->boundary.count;
        ns_span one = ns_progress_push(ctx, 0.0, 1.0 / grids);
        status = grid_once(ctx, &source->set, mat, m, scene->render.cull_solid_angle, &source->grids[m],
                           &source->grid_built[m], times, err);
        /* Single scattering alone gathers only the boundary's reflected VRLs. */
        if (!status && orders)
            status =
                gather_grid(ctx, in, source, m, &source->grids[m], orders, vrls_bounded(scene),
                            list, &vrls->segments, &vrls->out, stats, times, err);
        else if (!status)
            memset((float(*)[4])vrls->out.mapped + first, 0, 16ull * count);
        ns_progress_pop(ctx, one);
        const gather_list *clist = correction ? &correction->list : NULL;
        uint32_t cfirst = clist ? clist->material_first[m] : 0;
        uint32_t ccount = clist ? clist->material_first[m + 1] - cfirst : 0;
        for (uint32_t g = 0; g < source->boundary.count && ccount && !status; g++) {
            const ns_source_group *group = &source->boundary.group[g];
            uint32_t at = g * materials + m;
            one = ns_progress_push(ctx, (1.0 + g) / grids, (2.0 + g) / grids);
            status = grid_once(ctx, &group->set, mat, m, scene->render.cull_solid_angle,
                               &source->boundary_grids[at], &source->boundary_grid_built[at], times, err);
            /* Sources are endless beams: the walk accounts for where each one ends. */
            if (!status && source->boundary_grids[at].vrl_count)
                status = gather_grid(ctx, in, source, m, &source->boundary_grids[at], group->orders,
                                     0, clist, &correction->segments, scratch, stats, times, err);
            if (!status && source->boundary_grids[at].vrl_count) {
                float(*sum)[4] = correction->out.mapped;
                const float(*add)[4] = scratch->mapped;
                for (uint32_t k = cfirst; k < cfirst + ccount; k++)
                    for (int c = 0; c < 3; c++)
                        sum[k][c] += add[k][c];
            }
            ns_progress_pop(ctx, one);
        }
        ns_progress_pop(ctx, medium);
    }
    return status;
}

/* Adds each segment's throughput * radiance / spp (times its exit factor, top of file) of the
 * list into sum at its pixel. */
static void sum_segments(const ns_scatter_inputs *in, const gather_list *list,
                         const float (*radiance)[4], float (*sum)[3])
{
    const ns_scene *scene = in->scene;
    float inv_spp = 1.0f / (float)scene->render.spp;
    for (uint32_t i = 0; i < list->count; i++) {
        const GpuSegment *s = &list->segments[i];
        /* The dipole's R_d is radiance outside already. */
        float f = inv_spp * (scene->render.method == NS_METHOD_DIPOLE ? 1.0f : exit_factor(&in->gs->materials[s->material]));
        for (int c = 0; c < 3; c++)
            sum[s->pixel][c] += s->throughput[c] * radiance[i][c] * f;
    }
}

/* The gathered radiance of one round, as Lbar of its pixels (top of file): the VRLs' part
 * and, with the boundary correction, the correction's, gathered (GATHER_CORRECTION) or
 * interpolated by plan_round. */
static void store_round(const ns_scatter_inputs *in, tile_plan *t, const uint8_t *round,
                        const round_part *vrls, const round_part *correction)
{
    if (vrls->list.count)
        sum_segments(in, &vrls->list, vrls->out.mapped, t->radiance);
    if (correction && correction->list.count)
        sum_segments(in, &correction->list, correction->out.mapped, t->correction);
    per_unit_throughput(t, round, t->radiance);
    if (!t->correction)
        return;
    /* With the boundary correction ghost sources subtract: the pixel's total, never a
     * source's or a segment's part, is kept from going negative by their noise. */
    for (uint32_t p = 0; p < t->width * t->height; p++)
        for (int c = 0; c < 3 && round[p]; c++) {
            float w = t->keys[p].gather_weight[c];
            if (round[p] & GATHER_CORRECTION)
                t->correction[p][c] = w > 0 ? t->correction[p][c] / w : 0.0f;
            t->radiance[p][c] = fmaxf(t->radiance[p][c] + t->correction[p][c], 0.0f);
        }
}

/* Pixels take their own Lbar (gathered or interpolated) or the mix of their tiles'. */
static void compose(const ns_scatter_inputs *in, const tile_plan *t)
{
    for (uint32_t y = 0; y < t->height; y++)
        for (uint32_t x = 0; x < t->width; x++) {
            uint32_t p = y * t->width + x;
            const pixel_key *k = &t->keys[p];
            if (k->material == NS_NONE)
                continue;
            if (t->state[p] != PIXEL_UPSAMPLED) {
                for (int c = 0; c < 3; c++)
                    in->pixels[3 * p + c] += k->weight[c] * t->radiance[p][c];
                continue;
            }
            float mix[3];
            upsampled_radiance(t, x, y, mix);
            for (int c = 0; c < 3; c++)
                in->pixels[3 * p + c] += k->weight[c] * mix[c];
        }
}

/* A round part's segments (those of the pixels whose round has a bit of `want`) to the
 * device, with room for what the gather finds. */
static int round_part_make(ns_context *ctx, const ns_scatter_inputs *in, const tile_plan *t,
                           const uint8_t *round, uint8_t want, round_part *part, ns_error *err)
{
    if (gather_list_build(t, in->segments->mapped, in->scene->render.method, round, want,
                          &part->list))
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "gather: %u segments", in->segment_count);
    uint32_t n = part->list.count;
    if (!n)
        return NS_OK;
    int status = gpu_buffer_create(&ctx->dev, &part->segments,
                                   &(gpu_buffer_desc){.size = sizeof(GpuSegment) * n,
                                                      .data = part->list.segments,
                                                      .data_size = sizeof(GpuSegment) * n,
                                                      /* the vrl method's CPU side reads
                                                       * each segment's material */
                                                      .host_reads = 1,
                                                      .label = "ns.gather.segments"},
                                   err);
    if (!status)
        status = gpu_buffer_create(
            &ctx->dev, &part->out,
            &(gpu_buffer_desc){.size = 16ull * n, .host_reads = 1, .label = "ns.gather.radiance"},
            err);
    return status;
}

static void round_part_free(ns_context *ctx, round_part *part)
{
    gpu_buffer_destroy(&ctx->dev, &part->segments);
    gpu_buffer_destroy(&ctx->dev, &part->out);
    free(part->list.segments);
}

/* One round: its segments to the device, gathered, stored as Lbar. */
static int gather_round(ns_context *ctx, const ns_scatter_inputs *in, tile_plan *t, const uint8_t *round,
                        vrl_source *source, ns_render_stats *stats, scatter_times *times, ns_error *err)
{
    const ns_scene *scene = in->scene;
    round_part vrls = {0}, correction = {0};
    gpu_buffer scratch = {0};
    ns_stage stage = stage_begin(ctx, T_COMPOSITE, 0.0, 0.0);
    int status = round_part_make(ctx, in, t, round, GATHER_VRLS, &vrls, err);
    if (!status && t->correction)
        status = round_part_make(ctx, in, t, round, GATHER_CORRECTION, &correction, err);
    stage_end(ctx, times, T_COMPOSITE, &stage);
    if (!status && stats)
        stats->gather_segments += vrls.list.count;
    /* The vrl method's second order, or the boundary sources' groups one at a time. */
    uint32_t scratch_count = t->correction ? correction.list.count : vrls.list.count;
    if (!status && scratch_count)
        status = gpu_buffer_create(
            &ctx->dev, &scratch,
            &(gpu_buffer_desc){.size = 16ull * scratch_count,
                               .host_reads = 1,
                               .label = "ns.gather.radiance"},
            err);
    if (!status && vrls.list.count) {
        if (scene->render.method == NS_METHOD_VRL) {
            /* Light paths and gather in one stage; vrl_method.c shares its part out. */
            stage = stage_begin(ctx, T_GATHER, 0.0, 1.0);
            status = ns_vrl_method_gather(ctx, scene, in->gs, in->scene_buffers, &vrls.segments,
                                          vrls.list.count, &vrls.out, &scratch, stats, err);
            stage_end(ctx, times, T_GATHER, &stage);
            if (!status) {
                /* Keep the orders asked for, summed into vrls.out. */
                float(*d)[4] = vrls.out.mapped;
                const float(*mult)[4] = scratch.mapped;
                int want_double = scene->render.components & NS_COMPONENT_DOUBLE;
                int want_multiple = scene->render.components & NS_COMPONENT_MULTIPLE;
                for (uint32_t i = 0; i < vrls.list.count; i++)
                    for (int c = 0; c < 3; c++)
                        d[i][c] = (want_double ? d[i][c] : 0.0f) + (want_multiple ? mult[i][c] : 0.0f);
            }
        } else {
            status = gather_from_vrls(ctx, in, source, &vrls, t->correction ? &correction : NULL,
                                      &scratch, stats, times, err);
        }
    }
    if (!status) {
        stage = stage_begin(ctx, T_COMPOSITE, 1.0, 1.0);
        store_round(in, t, round, &vrls, t->correction ? &correction : NULL);
        stage_end(ctx, times, T_COMPOSITE, &stage);
    }
    round_part_free(ctx, &vrls);
    round_part_free(ctx, &correction);
    gpu_buffer_destroy(&ctx->dev, &scratch);
    return status;
}

/* t->other from what in->pixels already holds (single scattering, earlier camera batches);
 * left NULL where they hold nothing. Returns -1 out of memory. */
static int other_light(const ns_scatter_inputs *in, tile_plan *t)
{
    size_t pixels = (size_t)t->width * t->height;
    int any = 0;
    for (size_t i = 0; i < 3 * pixels && !any; i++)
        any = in->pixels[i] != 0.0f;
    if (!any)
        return 0;
    if (!(t->other = calloc(pixels, sizeof *t->other)))
        return -1;
    for (size_t p = 0; p < pixels; p++)
        for (int c = 0; c < 3; c++) {
            float w = t->keys[p].weight[c];
            t->other[p][c] = t->keys[p].material != NS_NONE && w > 0 ? in->pixels[3 * p + c] / w : 0.0f;
        }
    return 0;
}

static int render_double_multiple(ns_context *ctx, const ns_scatter_inputs *in, ns_render_stats *stats,
                                  scatter_times *times, ns_error *err)
{
    const ns_scene *scene = in->scene;
    ns_stage stage = stage_begin(ctx, T_COMPOSITE, 0.0, 0.0);
    tile_plan plan = {0};
    vrl_source source = {0};
    uint8_t *round = malloc((size_t)scene->camera.width * scene->camera.height + 1);
    int status = NS_OK;
    if (!round || tile_plan_build(scene, &in->gs->params, in->segments->mapped, in->segment_count, PLAN_GATHER, &plan) ||
        other_light(in, &plan))
        status = ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "gather: %u segments", in->segment_count);
    stage_end(ctx, times, T_COMPOSITE, &stage);
    uint64_t interpolated = 0;
    /* The rounds of the adaptive gather, coarsest lattice first (a single round, every tile,
     * without render.gather_levels): each gathers what plan_round marked before the next,
     * finer round interpolates from it. Each round's part of the progress: the tiles it
     * examines (the top of the file's progress section). */
    double at = 0.0;
    int top = (int)top_level(&plan);
    for (int level = top; level >= 0 && !status; level--) {
        double part = round_share(level, top);
        status = ns_run_check(ctx, err);
        if (status)
            break;
        stage = stage_begin(ctx, T_COMPOSITE, at, at);
        uint32_t marked = plan_round(&plan, (uint32_t)level, round, &interpolated);
        stage_end(ctx, times, T_COMPOSITE, &stage);
        ns_span outer = ns_progress_push(ctx, at, at + part);
        if (marked)
            status = gather_round(ctx, in, &plan, round, &source, stats, times, err);
        ns_progress_pop(ctx, outer);
        at += part;
    }
    if (!status) {
        stage = stage_begin(ctx, T_COMPOSITE, 1.0, 1.0);
        compose(in, &plan);
        stage_end(ctx, times, T_COMPOSITE, &stage);
    }
    if (stats) {
        stats->tiles_interpolated += interpolated;
        stats->corrections_interpolated += plan.corrections_interpolated;
        uint64_t table_bytes = 0; /* of this call's media; a render may call once per sample batch */
        for (uint32_t i = 0; source.table_bytes && i < ORDER_SETS * in->gs->material_count; i++)
            table_bytes += source.table_bytes[i];
        if (table_bytes > stats->table_bytes)
            stats->table_bytes = table_bytes;
    }
    vrl_source_free(&source, in->gs->material_count);
    tile_plan_free(&plan);
    free(round);
    return status;
}

int ns_scatter_render(ns_context *ctx, const ns_scatter_inputs *in, ns_render_stats *stats, ns_error *err)
{
    uint32_t components = in->scene->render.components;
    scatter_times times = {0};
    int status = NS_OK;
    /* This call stands for a camera batch; its ray pass took the batch's first share. */
    double shares[2];
    ns_batch_shares(in->scene, shares);
    if (in->segment_count && (components & NS_COMPONENT_SINGLE))
        status = render_single(ctx, in, shares[0], shares[1], stats, &times, err);
    /* With the boundary correction the gather also carries single scattering after an
     * internal reflection. */
    int gathers = (components & (NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE)) ||
                  ((components & NS_COMPONENT_SINGLE) && in->scene->render.boundary != NS_BOUNDARY_OFF);
    if (!status && in->segment_count && gathers) {
        status = ns_run_check(ctx, err);
        ns_span outer = ns_progress_push(ctx, shares[1], 1.0);
        if (!status)
            status = render_double_multiple(ctx, in, stats, &times, err);
        ns_progress_pop(ctx, outer);
    }
    add_times(stats, &times);
    return status;
}
