/* boundary.c — the boundary-crossing correction of the gathered scattering (double,
 * multiple, and single scattering after an internal reflection; render.boundary;
 * docs/scattering.md, "The object's boundary"; the estimator is shared/boundary/README.md's).
 *
 * The tables describe an infinite medium: past the point where the real light first reaches
 * the object's boundary, they go on scattering light that has left, and never see the light
 * the boundary reflects back. With T(b, w; k) = what the tables give for a beam from b along
 * w whose light has already scattered k times (orders shifted by k),
 *
 *     B = T(VRL) + sum over the boundary events i of the light's real walk inside the object
 *             W_i [ - T(b_i, w_i; k_i) + 1{reflected} T(b_i, w_i^r; k_i) ]
 *
 * is exact in expectation. The first stretch's own exit is the bounded beams' (gather.glsl
 * subtracts the beam past a VRL's exit); everything after it comes from walks: the `vrl`
 * method's light paths (vrl_trace.comp: free flights, Henyey-Greenstein, Fresnel
 * and total internal reflection with the Fresnel probability, Russian roulette), which
 * return every stretch of every path inside a medium: origin, direction, the distance L to
 * the boundary ahead, the flux at its origin and the events before it. Each stretch gives
 *   - a ghost: -e^{-s L} flux at origin + L d along d, the expected weight with which the
 *     walk reaches that boundary (deterministic per stretch: the walk's own free flight
 *     decides only which stretch comes next);
 *   - when the stretch itself starts where the previous one ended, with another direction
 *     (an internal reflection), the reflected beam: +flux at its origin along its
 *     direction, whose expectation is the F e^{-s L} of the stretch before; for light that
 *     has not scattered yet, given the walk's end records (vrl_trace.comp, ends), that
 *     expectation itself instead, at the end of every unscattered stretch (summed over the
 *     hero channel the walk draws, the walk's beam and F e^{-s L} times the stretch's flux
 *     have the same expectation per channel).
 * Sources are endless beams: each is the infinite medium's continuation, and the walk
 * itself accounts for where it ends. (A reflected or re-entered beam, and the ghost at its
 * stretch's end, keep the stretch's length, which only narrows their first order's tube.)
 *
 * Which table a source reads follows from its events k and the components asked for: its
 * light's next events are orders k + 1 (the first scattering on the camera segment of
 * light that flew straight from the source: a line meets a line with probability zero, so
 * this order is blurred over a tube around the source's line and computed in the gather,
 * gather.glsl's first_order), k + 2 (J_2) and >= k + 3 (J_multiple). Except the first
 * order where single.comp has it: the first stretch's ghost's, and the environment's
 * unscattered light's (ns_boundary_source_orders).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "boundary.h"

/* Two positions closer than this (relative to their size, and at least this in absolute
 * terms) are the same point: vrl_trace.comp starts a reflected stretch ray_epsilon off the
 * boundary point where the previous one ended. */
#define SAME_POINT 1e-3f

static float dist3(const float *a, const float *b)
{
    float d0 = a[0] - b[0], d1 = a[1] - b[1], d2 = a[2] - b[2];
    return sqrtf(d0 * d0 + d1 * d1 + d2 * d2);
}

/* A stretch's or source's scattering events, without its flags (scatter_shared.h). */
static uint32_t events_of(const GpuVrl *v)
{
    return v->events & NS_VRL_EVENT_COUNT;
}

/* The face bits (scatter_shared.h, NS_VRL_FACE_COS_SHIFT) of a beam mirrored by a face, from
 * the cosine of the turn between the incident and the reflected directions: the face's normal
 * lies along their difference, at the angle beta from each with cos beta = sqrt((1 - turn) / 2). */
static uint32_t face_bits(float cos_turn)
{
    float cos_beta = sqrtf(fmaxf(0.5f * (1.0f - cos_turn), 0.0f));
    uint32_t q = (uint32_t)lrintf(fminf(cos_beta, 1.0f) * (float)NS_VRL_FACE_COS_MAX);
    return (q ? q : 1u) << NS_VRL_FACE_COS_SHIFT;
}

static float dot3(const float *a, const float *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* Which of a stretch's flags its reflected beam keeps: where its light came from (the
 * line-returns flag is about the line past the stretch's end: the ghost's). */
static uint32_t reflected_events(const GpuVrl *v)
{
    return events_of(v) | (v->events & NS_VRL_FROM_ENVIRONMENT);
}

static void end_of(const GpuVrl *v, float end[3])
{
    for (int c = 0; c < 3; c++)
        end[c] = v->origin[c] + v->length * v->direction[c];
}

ns_boundary_link ns_boundary_link_of(const GpuVrl *previous, const GpuVrl *v)
{
    if (!previous || events_of(previous) != events_of(v) || !(previous->length > 0.0f))
        return NS_BOUNDARY_LINK_START;
    /* Same events, so the same path (a path starts at 0 and only counts up), unless both are
     * 0: unscattered light never re-enters, so then v starts a path of its own. */
    ns_boundary_link elsewhere =
        events_of(v) > 0 ? NS_BOUNDARY_LINK_REENTERED : NS_BOUNDARY_LINK_START;
    if (previous->material != v->material)
        return elsewhere;
    float end[3];
    end_of(previous, end);
    float size = fmaxf(1.0f, fmaxf(fabsf(end[0]), fmaxf(fabsf(end[1]), fabsf(end[2]))));
    if (dist3(end, v->origin) > SAME_POINT * size)
        return elsewhere;
    float cos_turn = previous->direction[0] * v->direction[0] +
                     previous->direction[1] * v->direction[1] +
                     previous->direction[2] * v->direction[2];
    /* Grazing its own boundary, the walk goes on along the same line (vrl_trace.comp). A
     * reflection that turns by less than this is taken for that too: the stretch before then
     * gets neither a ghost nor an expected reflection, where F is all but 1 anyway. */
    return cos_turn > 1.0f - 1e-5f ? NS_BOUNDARY_LINK_CONTINUED : NS_BOUNDARY_LINK_REFLECTED;
}

uint32_t ns_boundary_sources(const GpuVrl *stretches, const float *ends, uint32_t count,
                             const GpuMaterial *materials, int entry_ghosts, GpuVrl *out)
{
    uint32_t n = 0;
    for (uint32_t i = 0; i < count; i++) {
        const GpuVrl *v = &stretches[i];
        ns_boundary_link link = ns_boundary_link_of(i ? &stretches[i - 1] : NULL, v);
        int entry = events_of(v) == 0 && link == NS_BOUNDARY_LINK_START;
        /* Given the ends, unscattered light's reflected beams come in expectation at the end
         * of the stretch before (below), not from the walk's own choice (a reflected stretch
         * has the events of the one before it). */
        int expected = ends && events_of(v) == 0;
        if ((link == NS_BOUNDARY_LINK_REFLECTED && !expected) ||
            link == NS_BOUNDARY_LINK_REENTERED) {
            /* Endless for the tables; its length, the chord to the boundary ahead, sets the
             * width of its first order's tube (scatter_shared.h, NS_FIRST_BLUR_PER_CHORD), as
             * the ghost's at that chord's end does for the ghost (below). */
            GpuVrl r = *v;
            r.events = reflected_events(v);
            /* A walk's own reflection starts on the face that mirrored the stretch before;
             * a re-entered beam's face is not known (the flight outside is not a stretch). */
            if (link == NS_BOUNDARY_LINK_REFLECTED)
                r.events |= face_bits(dot3(stretches[i - 1].direction, v->direction));
            out[n++] = r;
        }
        /* A stretch that the next one continues along the same line has no boundary event
         * at its end: the next one's ghost stands for both. */
        int continued = i + 1 < count && ns_boundary_link_of(v, &stretches[i + 1]) == NS_BOUNDARY_LINK_CONTINUED;
        if (!(v->length > 0.0f) || continued)
            continue;
        const float *st = materials[v->material].sigma_t;
        /* Its length stays the stretch's: where the ghost keeps its first order (a line that
         * returns into its medium), its tube must be the one of the beam it cancels past the
         * chord's end (gather.glsl, first_order). */
        GpuVrl ghost = *v;
        end_of(v, ghost.origin);
        float largest = 0.0f;
        for (int c = 0; c < 3; c++) {
            ghost.power[c] = -expf(-st[c] * v->length) * v->power[c];
            largest = fmaxf(largest, -ghost.power[c]);
        }
        if (!(largest > 0.0f))
            continue;
        /* The first stretch's line is the VRL's, whose first order (single scattering) the
         * gather never reads (single.comp computes it from the lights): its ghost has none
         * to take away, where its line returns or not. */
        if (entry)
            ghost.events &= ~NS_VRL_LINE_RETURNS;
        if (!entry || entry_ghosts)
            out[n++] = ghost;
        /* Unscattered light: what the boundary reflects back at that end, F of the light
         * reaching it, along the mirror direction: the expectation of the walk's own
         * reflected beam (taken with probability F by the walks that get there, which for
         * light that has not scattered yet is rare: a first free flight as long as the
         * stretch), whatever the walk did. Scattered light keeps the walk's own beams: there
         * every stretch would add a source, mostly weak, and the roulette below them brings
         * back the noise they took away (docs/scattering.md, *Unscattered light's reflections in
         * expectation*). */
        const float *end = expected ? ends + 4 * (size_t)i : NULL;
        float chord = end ? sqrtf(end[0] * end[0] + end[1] * end[1] + end[2] * end[2]) : 0.0f;
        if (end && end[3] > 0.0f && chord > 0.0f) {
            GpuVrl reflected = ghost;
            /* The end's mirror direction comes scaled by its chord (vrl_method_shared.h),
             * which narrows the reflected beam's first order's tube as a walk's own
             * reflected stretch's length does. */
            reflected.length = chord;
            for (int c = 0; c < 3; c++) {
                reflected.direction[c] = end[c] / chord;
                reflected.power[c] = -end[3] * ghost.power[c];
            }
            reflected.events = reflected_events(v) | face_bits(dot3(v->direction, reflected.direction));
            out[n++] = reflected;
        }
    }
    return n;
}

/* boundary.h: the roulette's importance of a source. */
static float source_importance(const GpuVrl *s)
{
    float sum = s->power[0] + s->power[1] + s->power[2];
    return fabsf(sum) / 3.0f * (sum < 0.0f ? NS_BOUNDARY_GHOST_IMPORTANCE : 1.0f);
}

static uint32_t hash32(uint32_t v)
{
    /* PCG's output permutation, as shaders/common.glsl's pcg_hash. */
    uint32_t state = v * 747796405u + 2891336453u;
    uint32_t word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

uint32_t ns_boundary_roulette(GpuVrl *sources, uint32_t n, float floor, uint32_t seed)
{
    if (!(floor > 0.0f))
        return n;
    uint32_t kept = 0;
    for (uint32_t i = 0; i < n; i++) {
        GpuVrl s = sources[i];
        float importance = source_importance(&s);
        if (importance < floor) {
            float u = (float)(hash32(hash32(seed) + i) >> 8) * (1.0f / 16777216.0f);
            if (!(u * floor < importance))
                continue;
            for (int c = 0; c < 3; c++)
                s.power[c] *= floor / importance;
        }
        sources[kept++] = s;
    }
    return kept;
}

/* Whether the components ask for scattering order `order` (>= 1). */
static int order_wanted(uint32_t order, uint32_t components)
{
    uint32_t bit = order == 1 ? NS_COMPONENT_SINGLE : order == 2 ? NS_COMPONENT_DOUBLE : NS_COMPONENT_MULTIPLE;
    return (components & bit) != 0;
}

float ns_boundary_floor(const GpuVrl *sources, uint32_t n, uint32_t target)
{
    if (n <= target || !target)
        return 0.0f;
    /* kept(f) = sum min(1, w / f) falls as f grows: bisect between a floor that keeps
     * everything (the smallest weight) and one that keeps at most target (the total over
     * target), in the logarithm. */
    double total = 0, smallest = INFINITY;
    for (uint32_t i = 0; i < n; i++) {
        double w = source_importance(&sources[i]);
        total += w;
        if (w > 0 && w < smallest)
            smallest = w;
    }
    if (!(total > 0))
        return 0.0f;
    double lo = log(fmin(smallest, total / target)), hi = log(total / target);
    for (int it = 0; it < 40; it++) {
        double mid = 0.5 * (lo + hi), f = exp(mid), kept = 0;
        for (uint32_t i = 0; i < n; i++)
            kept += fmin(1.0, source_importance(&sources[i]) / f);
        if (kept > target)
            lo = mid;
        else
            hi = mid;
    }
    return (float)exp(hi);
}

uint32_t ns_boundary_orders(uint32_t events, uint32_t components)
{
    /* The source's light scatters next as order events + 1 (the blurred first order),
     * events + 2 (J_2) and events + 3 on (J_multiple). */
    return (order_wanted(events + 1, components) ? NS_TABLE_FIRST_BLURRED : 0u) |
           (order_wanted(events + 2, components) ? NS_COMPONENT_DOUBLE : 0u) |
           (order_wanted(events + 3, components) ? NS_COMPONENT_MULTIPLE : 0u);
}

static int is_ghost(const GpuVrl *s)
{
    return s->power[0] + s->power[1] + s->power[2] < 0.0f;
}

uint32_t ns_boundary_source_orders(const GpuVrl *s, uint32_t components)
{
    /* A ghost's light flies on outside the object, from where the walk left it: in a convex
     * object no camera segment meets its next event (order events + 1), so the ghost takes
     * nothing away there. The blurred first order would: its Gaussian tube around the
     * line lies partly inside near the exit, and removed light that is really there (an
     * index-matched sphere 2 mfp across: double scattering 0.907 of pt with it, 0.959
     * without, which is exactly the bounded beams'; the bench's milk 0.948 -> 0.998 with
     * Monte Carlo tables). Where a walk came back into an object of the ghost's medium, a
     * ghost's line may pass through one again, and there its first order must go (two boxes
     * face to face: +8 / +6 / +19% of pt without it, -3 / -5 / +8% with it): the walk
     * marks each stretch whose line past its end meets an object of its medium
     * (NS_VRL_LINE_RETURNS, vrl_trace.comp), and that stretch's ghost keeps its first
     * order. A ghost is gathered onto its own medium's segments only, so other media do not
     * count. docs/scattering.md, *The blur at a ghost*. */
    uint32_t orders = ns_boundary_orders(events_of(s), components);
    /* The environment's unscattered light: single.comp follows it through internal
     * reflections itself, so its reflected beams give no first order, nor do their ghosts
     * take one away. */
    int environment = events_of(s) == 0 && (s->events & NS_VRL_FROM_ENVIRONMENT) != 0;
    int keep = (s->events & NS_VRL_LINE_RETURNS) != 0;
    return environment || (is_ghost(s) && !keep) ? orders & ~NS_TABLE_FIRST_BLURRED : orders;
}

void ns_boundary_groups_free(ns_boundary_groups *g)
{
    for (uint32_t i = 0; i < NS_BOUNDARY_GROUPS; i++)
        ns_vrl_set_free(&g->group[i].set);
    memset(g, 0, sizeof *g);
}

int ns_boundary_group(const GpuVrl *sources, uint32_t count, uint32_t components,
                      ns_boundary_groups *out, ns_error *err)
{
    memset(out, 0, sizeof *out);
    /* Group by (table orders, sign): a grid cell's representative must never mix a ghost
     * with a reflected beam, and one gather reads one table. */
    for (uint32_t pass = 0; pass < 2; pass++) {
        for (uint32_t i = 0; i < count; i++) {
            const GpuVrl *s = &sources[i];
            uint32_t orders = ns_boundary_source_orders(s, components);
            if (!orders)
                continue;
            int negative = is_ghost(s);
            uint32_t g = 0;
            while (g < out->count && !(out->group[g].orders == orders && out->group[g].negative == negative))
                g++;
            if (g == out->count) {
                if (pass == 1 || g == NS_BOUNDARY_GROUPS)
                    return ns_fail(err, NS_ERR_INTERNAL, "boundary: more than %u source groups",
                                   (unsigned)NS_BOUNDARY_GROUPS);
                out->group[g].orders = orders;
                out->group[g].negative = negative;
                out->count++;
            }
            ns_source_group *grp = &out->group[g];
            if (pass == 0)
                grp->set.count++;
            else {
                GpuVrl *kept = &grp->set.vrls[grp->filled++];
                *kept = *s;
                kept->events = events_of(s) | (s->events & (NS_VRL_FACE_COS_MAX << NS_VRL_FACE_COS_SHIFT));
            }
        }
        if (pass == 0)
            for (uint32_t g = 0; g < out->count; g++) {
                out->group[g].set.vrls = malloc(sizeof(GpuVrl) * out->group[g].set.count);
                if (!out->group[g].set.vrls) {
                    ns_boundary_groups_free(out);
                    return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "boundary: %u sources", count);
                }
            }
    }
    return NS_OK;
}
