/* unit_boundary.c — the host side of the boundary-crossing correction (render/boundary.c):
 *   - which orders a source gives (the blurred first order, computed in the gather, and the
 *     tables'), for every components set and event count;
 *   - the sources of a hand-made walk (entry, scattering, internal reflection, a grazing
 *     continuation): where, which sign, what power;
 *   - the face a reflected beam starts on (its cosine, for the gather's tube), at normal and
 *     oblique incidence;
 *   - grouping by (orders, sign). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "boundary.h"
#include "harness.h"

/* A source's events without its face bits (scatter_shared.h), and the cosine they carry. */
static uint32_t without_face(const GpuVrl *v)
{
    return v->events & ~(NS_VRL_FACE_COS_MAX << NS_VRL_FACE_COS_SHIFT);
}
static float face_cos(const GpuVrl *v)
{
    return (float)(v->events >> NS_VRL_FACE_COS_SHIFT & NS_VRL_FACE_COS_MAX) / (float)NS_VRL_FACE_COS_MAX;
}

static void test_orders(void)
{
    const uint32_t D = NS_COMPONENT_DOUBLE, M = NS_COMPONENT_MULTIPLE, B = NS_TABLE_FIRST_BLURRED;
    /* k = 0: the VRL's own orders, and single scattering through the blurred first order
     * (light reflected before it scattered). */
    CHECK_INT(ns_boundary_orders(0, D | M), D | M);
    CHECK_INT(ns_boundary_orders(0, M | NS_COMPONENT_SINGLE), B | M);
    CHECK_INT(ns_boundary_orders(0, NS_COMPONENT_SINGLE), B);
    /* k = 1: its first scattering after the source is order 2 (double), then 3 (J_2) and
     * beyond (J_multiple). */
    CHECK_INT(ns_boundary_orders(1, D | M), B | D | M);
    CHECK_INT(ns_boundary_orders(1, M), D | M);
    CHECK_INT(ns_boundary_orders(1, D), B);
    /* k >= 2: everything is multiple. */
    CHECK_INT(ns_boundary_orders(2, D | M), B | D | M);
    CHECK_INT(ns_boundary_orders(5, M), B | D | M);
    CHECK_INT(ns_boundary_orders(2, D), 0);
    CHECK_INT(ns_boundary_orders(3, NS_COMPONENT_SINGLE | NS_COMPONENT_SURFACE), 0);
    /* A ghost's next event lies outside its object: it reads no blurred first order, unless
     * its line passes through an object of its medium again (NS_VRL_LINE_RETURNS, set by the
     * walk); a reflected or re-entered beam (positive) always does. The flag is not an
     * event. */
    GpuVrl ghost, beam;
    memset(&ghost, 0, sizeof ghost);
    ghost.events = 2;
    ghost.power[0] = ghost.power[1] = ghost.power[2] = -0.5f;
    beam = ghost;
    beam.power[0] = beam.power[1] = beam.power[2] = 0.5f;
    CHECK_INT(ns_boundary_source_orders(&ghost, D | M), D | M);
    CHECK_INT(ns_boundary_source_orders(&beam, D | M), B | D | M);
    ghost.events = beam.events = 2 | NS_VRL_LINE_RETURNS;
    CHECK_INT(ns_boundary_source_orders(&ghost, D | M), B | D | M);
    CHECK_INT(ns_boundary_source_orders(&beam, D | M), B | D | M);
    ghost.events = beam.events = 1;
    CHECK_INT(ns_boundary_source_orders(&ghost, D), 0);
    CHECK_INT(ns_boundary_source_orders(&beam, D), B);
    ghost.events = 1 | NS_VRL_LINE_RETURNS;
    CHECK_INT(ns_boundary_source_orders(&ghost, D), B);
    /* Unscattered light (k = 0) whose line returns: a reflected stretch's ghost takes away
     * the first order (single scattering) its reflected beam gives past the chord's end. */
    const uint32_t S = NS_COMPONENT_SINGLE;
    ghost.events = NS_VRL_LINE_RETURNS;
    CHECK_INT(ns_boundary_source_orders(&ghost, S | D | M), B | D | M);
    beam.events = 0;
    CHECK_INT(ns_boundary_source_orders(&beam, S | D | M), B | D | M);
    /* The environment's unscattered light leaves its first order to single.comp (which
     * follows it through internal reflections): its reflected beams give none, their ghosts
     * take none away; its orders k + 2 and on stay. The flag is not an event. */
    beam.events = NS_VRL_FROM_ENVIRONMENT;
    CHECK_INT(ns_boundary_source_orders(&beam, S | D | M), D | M);
    CHECK_INT(ns_boundary_source_orders(&beam, S), 0);
    ghost.events = NS_VRL_FROM_ENVIRONMENT | NS_VRL_LINE_RETURNS;
    CHECK_INT(ns_boundary_source_orders(&ghost, S | D | M), D | M);
    /* Scattered light is never marked, but the mark would not matter there. */
    beam.events = 1 | NS_VRL_FROM_ENVIRONMENT;
    CHECK_INT(ns_boundary_source_orders(&beam, D | M), B | D | M);
}

/* Every kind of source at once (both signs; events 0, 1 and 2; the environment's mark; lines
 * that return) falls into at most NS_BOUNDARY_GROUPS groups for any components: single and
 * multiple asked make eight. */
static void test_groups_of_every_kind(void)
{
    const uint32_t kinds[9][2] = {
        {0, 0}, {0, NS_VRL_FROM_ENVIRONMENT}, {1, 0}, {1, NS_VRL_LINE_RETURNS}, {0, 1}, {1, 1},
        {0, 2}, {1, 2 | NS_VRL_LINE_RETURNS}, {1, 2},
    };
    GpuVrl sources[9];
    memset(sources, 0, sizeof sources);
    for (int i = 0; i < 9; i++) {
        for (int c = 0; c < 3; c++)
            sources[i].power[c] = kinds[i][0] ? -0.5f : 0.5f;
        sources[i].events = kinds[i][1];
        sources[i].direction[2] = 1.0f;
    }
    const uint32_t S = NS_COMPONENT_SINGLE, D = NS_COMPONENT_DOUBLE, M = NS_COMPONENT_MULTIPLE;
    const uint32_t asked[7] = {S, D, M, S | D, S | M, D | M, S | D | M};
    uint32_t most = 0;
    for (int a = 0; a < 7; a++) {
        ns_boundary_groups groups;
        ns_error err = {0};
        CHECK_INT(ns_boundary_group(sources, 9, asked[a], &groups, &err), NS_OK);
        most = groups.count > most ? groups.count : most;
        ns_boundary_groups_free(&groups);
    }
    CHECK_INT(most, 8);
}

static GpuVrl stretch(double ox, double oy, double oz, double dx, double dy, double dz, double len,
                      double power, uint32_t events)
{
    GpuVrl v;
    memset(&v, 0, sizeof v);
    v.origin[0] = (float)ox, v.origin[1] = (float)oy, v.origin[2] = (float)oz;
    v.direction[0] = (float)dx, v.direction[1] = (float)dy, v.direction[2] = (float)dz;
    v.length = (float)len;
    v.power[0] = v.power[1] = v.power[2] = (float)power;
    v.events = events;
    return v;
}

static void test_sources_of_a_walk(void)
{
    GpuMaterial m;
    memset(&m, 0, sizeof m);
    m.sigma_t[0] = 1.0f, m.sigma_t[1] = 2.0f, m.sigma_t[2] = 0.5f, m.sigma_t[3] = 1.5f;
    /* Enters at (0, 1, 0) going down 2 to the floor of a slab; scatters at y = 0.5 (k = 1),
     * goes up 0.5 to the top face, is reflected there down to the floor (1 away), grazes it
     * and goes on 0.25 along the same line. Then a second path starts elsewhere. */
    const GpuVrl walk[] = {
        stretch(0, 1, 0, 0, -1, 0, 2, 1.0, 0),          /* entry */
        stretch(0, 0.5, 0, 0, 1, 0, 0.5, 0.8, 1),       /* after a scattering */
        stretch(0, 1, 0, 0, -1, 0, 1.0, 0.3, 1),        /* reflected at the top face */
        stretch(0, 0.0, 0, 0, -1, 0, 0.25, 0.3, 1),     /* grazing continuation */
        stretch(5, 1, 5, 0, -1, 0, 2, 1.0, 0),          /* the next path */
    };
    CHECK_INT(ns_boundary_link_of(NULL, &walk[0]), NS_BOUNDARY_LINK_START);
    CHECK_INT(ns_boundary_link_of(&walk[0], &walk[1]), NS_BOUNDARY_LINK_START);
    CHECK_INT(ns_boundary_link_of(&walk[1], &walk[2]), NS_BOUNDARY_LINK_REFLECTED);
    CHECK_INT(ns_boundary_link_of(&walk[2], &walk[3]), NS_BOUNDARY_LINK_CONTINUED);
    CHECK_INT(ns_boundary_link_of(&walk[3], &walk[4]), NS_BOUNDARY_LINK_START);

    GpuVrl out[10];
    /* Without the entries' ghosts (the renderer asks for them, below): ghost of stretch 1
     * at (0, 1, 0) going up; the reflected beam (stretch 2's start); no ghost at stretch 2's
     * end (stretch 3 continues it); ghost at stretch 3's end (0, -0.25, 0). */
    uint32_t n = ns_boundary_sources(walk, NULL, 5, &m, 0, out);
    CHECK_INT(n, 3);
    if (n != 3)
        return;
    CHECK(fabsf(out[0].origin[1] - 1.0f) < 1e-6f && out[0].direction[1] == 1.0f);
    for (int c = 0; c < 3; c++)
        CHECK(fabsf(out[0].power[c] + 0.8f * expf(-m.sigma_t[c] * 0.5f)) < 1e-6f);
    CHECK(out[0].length == 0.5f && out[0].events == 1); /* the ghost keeps its stretch's chord */
    CHECK(out[1].power[0] == 0.3f && out[1].origin[1] == 1.0f && out[1].direction[1] == -1.0f);
    /* The reflected beam keeps its chord (its first order's tube follows it). */
    CHECK(out[1].length == 1.0f && without_face(&out[1]) == 1);
    /* ... and the face it starts on: the walk turned straight back, so its line runs along
     * the face's normal. The ghosts start on no face of theirs. */
    CHECK(face_cos(&out[1]) == 1.0f && face_cos(&out[0]) == 0.0f && face_cos(&out[2]) == 0.0f);
    CHECK(fabsf(out[2].origin[1] + 0.25f) < 1e-6f);
    for (int c = 0; c < 3; c++)
        CHECK(fabsf(out[2].power[c] + 0.3f * expf(-m.sigma_t[c] * 0.25f)) < 1e-6f);
    /* With them, as the renderer asks (they stand for its endless VRLs' beams past their
     * exits), the entries' ghosts at their exits too: each path's entry stretch ends in a
     * ghost that carries on along it, -e^{-s L} times its flux, no events; exactly what a
     * bounded VRL of that stretch subtracts. First path: from (0, 1, 0) down 2 to
     * (0, -1, 0); second: from (5, 1, 5) down 2 to (5, -1, 5). */
    CHECK_INT(ns_boundary_sources(walk, NULL, 5, &m, 1, out), 5);
    const int entry_ghost[2] = {0, 4};
    const float entry_end[2][3] = {{0, -1, 0}, {5, -1, 5}};
    for (int k = 0; k < 2; k++) {
        const GpuVrl *g = &out[entry_ghost[k]];
        for (int i = 0; i < 3; i++) {
            CHECK(fabsf(g->origin[i] - entry_end[k][i]) < 1e-6f);
            CHECK(fabsf(g->power[i] + expf(-m.sigma_t[i] * 2.0f)) < 1e-6f);
        }
        CHECK(g->direction[1] == -1.0f && g->length == 2.0f && g->events == 0);
    }

    ns_boundary_groups groups;
    ns_error err = {0};
    CHECK_INT(ns_boundary_group(out, 5, NS_COMPONENT_MULTIPLE, &groups, &err), NS_OK);
    /* k = 0 ghosts read M, k = 1 ghosts and the reflected beam read D | M: three groups. */
    CHECK_INT(groups.count, 3);
    uint32_t total = 0;
    for (uint32_t g = 0; g < groups.count; g++) {
        total += groups.group[g].set.count;
        for (uint32_t i = 0; i < groups.group[g].set.count; i++) {
            const GpuVrl *s = &groups.group[g].set.vrls[i];
            CHECK_INT(ns_boundary_source_orders(s, NS_COMPONENT_MULTIPLE), groups.group[g].orders);
            CHECK((s->power[0] < 0) == groups.group[g].negative);
        }
    }
    CHECK_INT(total, 5);
    ns_boundary_groups_free(&groups);
}

/* With the stretches' ends (the mirror direction and the Fresnel reflectance where each
 * stretch ends, vrl_trace.comp): unscattered light's reflected beams come in expectation at
 * every unscattered stretch's end, F times the ghost's light, whether or not the walk
 * reflected there; the walk's own reflected beam of unscattered light is dropped (the
 * expectation stands for it), that of scattered light kept. */
static void test_sources_with_ends(void)
{
    GpuMaterial m;
    memset(&m, 0, sizeof m);
    m.sigma_t[0] = 1.0f, m.sigma_t[1] = 2.0f, m.sigma_t[2] = 0.5f, m.sigma_t[3] = 1.5f;
    /* A slab from y = -1 to 1. Path 1 enters at the top going down 2 to the floor, is
     * reflected there unscattered (a stretch of its own, k = 0, back up 2), scatters at
     * y = 0.5 (k = 1), goes up to the top face and is reflected down 1. Path 2 enters at
     * (5, 1, 5) going down and scatters before the floor (its end: the floor, where the
     * walk never got). */
    const GpuVrl walk[] = {
        stretch(0, 1, 0, 0, -1, 0, 2, 1.0, 0),    /* entry, reflected at its end */
        stretch(0, -1, 0, 0, 1, 0, 2, 0.7, 0),    /* unscattered, reflected */
        stretch(0, 0.5, 0, 0, 1, 0, 0.5, 0.8, 1), /* after a scattering */
        stretch(0, 1, 0, 0, -1, 0, 1.0, 0.3, 1),  /* reflected at the top face */
        stretch(5, 1, 5, 0, -1, 0, 2, 1.0, 0),    /* the next path's entry */
    };
    CHECK_INT(ns_boundary_link_of(&walk[0], &walk[1]), NS_BOUNDARY_LINK_REFLECTED);
    CHECK_INT(ns_boundary_link_of(&walk[2], &walk[3]), NS_BOUNDARY_LINK_REFLECTED);
    /* Each end: mirror direction, F; for unscattered light the direction times the chord
     * ahead along it (2 across the slab). Stretch 0 ends on the floor with F 0.25, stretch 1
     * on the top face with F 0.1, stretch 2 on the top face (F 0.6: not used, k = 1),
     * stretch 3 on the floor (F 1, total reflection: not used), stretch 4 on its floor with
     * F 0.5. */
    const float ends[5][4] = {
        {0, 2, 0, 0.25f}, {0, -2, 0, 0.1f}, {0, -1, 0, 0.6f}, {0, 1, 0, 1.0f}, {0, 2, 0, 0.5f},
    };
    GpuVrl out[15];
    uint32_t n = ns_boundary_sources(walk, &ends[0][0], 5, &m, 1, out);
    /* Stretch 0: ghost, expected reflection. Stretch 1: (its own reflected beam dropped)
     * ghost, expected reflection. Stretch 2: ghost. Stretch 3: the walk's reflected beam
     * (k = 1), ghost. Stretch 4: ghost, expected reflection. */
    CHECK_INT(n, 9);
    if (n != 9)
        return;
    const int reflected[3] = {1, 3, 8}, of_stretch[3] = {0, 1, 4};
    const float y_end[3] = {-1, 1, -1};
    for (int r = 0; r < 3; r++) {
        const GpuVrl *s = &out[reflected[r]], *ghost = &out[reflected[r] - 1];
        const GpuVrl *v = &walk[of_stretch[r]];
        const float *e = ends[of_stretch[r]];
        CHECK(fabsf(s->origin[1] - y_end[r]) < 1e-6f && s->origin[0] == v->origin[0]);
        /* An expected reflection's length is the chord its end record carries (it narrows
         * the first order's tube), its direction the record's, of unit length. */
        CHECK(s->direction[1] == e[1] / 2.0f && s->length == 2.0f && without_face(s) == 0);
        CHECK(face_cos(s) == 1.0f); /* mirrored straight back by the face it starts on */
        CHECK(ghost->length == v->length);
        for (int c = 0; c < 3; c++) {
            CHECK(ghost->power[c] < 0.0f);
            CHECK(fabsf(s->power[c] - e[3] * v->power[c] * expf(-m.sigma_t[c] * v->length)) <
                  1e-6f);
        }
    }
    /* The walk's own reflected beam of scattered light: stretch 3's start, its full flux. */
    CHECK(out[5].power[0] == 0.3f && out[5].origin[1] == 1.0f && without_face(&out[5]) == 1);
    /* A record of chord 0 gives no source: stretch 4's is left out. (vrl_trace.comp writes
     * all zeros where nothing lies ahead, an open mesh where the walk ends; a reflection of
     * F > 0 that meets the boundary at once is refused too rather than divided by 0.) */
    float open_ends[5][4];
    memcpy(open_ends, ends, sizeof open_ends);
    open_ends[4][1] = 0.0f;
    CHECK_INT(ns_boundary_sources(walk, &open_ends[0][0], 5, &m, 1, out), 8);
    /* Without the ends: the walk's own beams only (stretch 1's and stretch 3's starts). */
    CHECK_INT(ns_boundary_sources(walk, NULL, 5, &m, 1, out), 7);
    /* The environment's mark rides on the unscattered stretches' reflected beams, with or
     * without the ends, and never counts as an event (the grouping strips it). */
    GpuVrl marked[5];
    memcpy(marked, walk, sizeof marked);
    marked[0].events = marked[1].events = NS_VRL_FROM_ENVIRONMENT;
    CHECK_INT(ns_boundary_sources(marked, &ends[0][0], 5, &m, 1, out), 9);
    CHECK(without_face(&out[1]) == NS_VRL_FROM_ENVIRONMENT &&
          without_face(&out[3]) == NS_VRL_FROM_ENVIRONMENT);
    CHECK(without_face(&out[5]) == 1 && without_face(&out[8]) == 0);
    CHECK_INT(ns_boundary_sources(marked, NULL, 5, &m, 1, out), 7);
    CHECK(without_face(&out[1]) == NS_VRL_FROM_ENVIRONMENT);
    /* The first stretch's ghost drops the line-returns mark (its line is the VRL's, whose
     * first order is single.comp's); a reflected stretch's ghost keeps it. */
    memcpy(marked, walk, sizeof marked);
    marked[0].events = marked[1].events = NS_VRL_LINE_RETURNS;
    CHECK_INT(ns_boundary_sources(marked, &ends[0][0], 5, &m, 1, out), 9);
    CHECK(out[0].events == 0 && out[0].power[0] < 0.0f);
    CHECK(out[2].events == NS_VRL_LINE_RETURNS && out[2].power[0] < 0.0f);
    memcpy(marked, walk, sizeof marked);
    marked[0].events = marked[1].events = NS_VRL_FROM_ENVIRONMENT;
    ns_boundary_groups groups;
    ns_error err = {0};
    CHECK_INT(ns_boundary_group(out, 7,
                                NS_COMPONENT_SINGLE | NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE,
                                &groups, &err),
              NS_OK);
    /* The marks go; the events and the face bits stay (the gather reads the face). */
    for (uint32_t g = 0; g < groups.count; g++)
        for (uint32_t i = 0; i < groups.group[g].set.count; i++) {
            const GpuVrl *kept = &groups.group[g].set.vrls[i];
            CHECK(without_face(kept) < 2);
            CHECK(face_cos(kept) == (groups.group[g].negative ? 0.0f : 1.0f));
        }
    ns_boundary_groups_free(&groups);
}

/* The face a reflected beam starts on, at oblique incidence: a walk going down at 60 degrees
 * from the floor's normal, reflected up at 60 degrees (its own reflection, and the expected
 * one of an end record): the beam's line is at 60 degrees to the face's normal, cos 0.5. */
static void test_face_of_an_oblique_reflection(void)
{
    GpuMaterial m;
    memset(&m, 0, sizeof m);
    m.sigma_t[0] = m.sigma_t[1] = m.sigma_t[2] = 1.0f;
    const double s60 = sqrt(3.0) / 2.0;
    const GpuVrl walk[] = {
        stretch(0, 1, 0, s60, -0.5, 0, 2, 1.0, 1),
        stretch(s60 * 2, 0, 0, s60, 0.5, 0, 2, 0.5, 1),
    };
    CHECK_INT(ns_boundary_link_of(&walk[0], &walk[1]), NS_BOUNDARY_LINK_REFLECTED);
    GpuVrl out[6];
    uint32_t n = ns_boundary_sources(walk, NULL, 2, &m, 0, out);
    int beams = 0;
    for (uint32_t i = 0; i < n; i++)
        if (out[i].power[0] > 0.0f) {
            beams++;
            CHECK(fabsf(face_cos(&out[i]) - 0.5f) < 1e-4f);
        }
    CHECK_INT(beams, 1);
    /* The expected reflection of unscattered light at the first stretch's end. */
    GpuVrl unscattered[1] = {stretch(0, 1, 0, s60, -0.5, 0, 2, 1.0, 0)};
    const float ends[1][4] = {{(float)(2 * s60), 1.0f, 0.0f, 0.25f}};
    n = ns_boundary_sources(unscattered, &ends[0][0], 1, &m, 1, out);
    beams = 0;
    for (uint32_t i = 0; i < n; i++)
        if (out[i].power[0] > 0.0f) {
            beams++;
            CHECK(fabsf(face_cos(&out[i]) - 0.5f) < 1e-4f);
        }
    CHECK_INT(beams, 1);
}

/* A walk that leaves its object after scattering and enters it (or another object of the
 * same or another medium) again elsewhere (vrl_trace.comp): the stretch after the re-entry
 * is a positive source with the events so far, besides the ghosts at both stretches' ends.
 * Unscattered light never re-enters, so a stretch without events that starts elsewhere is a
 * new path. */
static void test_sources_of_a_reentry(void)
{
    GpuMaterial m[2];
    memset(m, 0, sizeof m);
    for (int k = 0; k < 2; k++)
        for (int c = 0; c < 4; c++)
            m[k].sigma_t[c] = 1.0f;
    GpuVrl walk[] = {
        stretch(0, 1, 0, 0, -1, 0, 2, 1.0, 0),      /* entry */
        stretch(0, 0.5, 0, 1, 0, 0, 1.0, 0.8, 1),   /* after a scattering, leaves at x = 1 */
        stretch(1.5, 0.5, 0, 1, 0, 0, 2.0, 0.6, 1), /* enters at x = 1.5 again */
        stretch(4, 0.5, 0, 1, 0, 0, 1.0, 0.5, 1),   /* and another medium at x = 4 */
        stretch(9, 1, 9, 0, -1, 0, 2, 1.0, 0),      /* the next path */
    };
    walk[3].material = 1;
    /* The walk marked stretch 1's line (past x = 1 it passes through medium 0 again at 1.5):
     * the flag is no event, so the links are the same with it. */
    walk[1].events |= NS_VRL_LINE_RETURNS;
    CHECK_INT(ns_boundary_link_of(&walk[0], &walk[1]), NS_BOUNDARY_LINK_START);
    CHECK_INT(ns_boundary_link_of(&walk[1], &walk[2]), NS_BOUNDARY_LINK_REENTERED);
    CHECK_INT(ns_boundary_link_of(&walk[2], &walk[3]), NS_BOUNDARY_LINK_REENTERED);
    CHECK_INT(ns_boundary_link_of(&walk[3], &walk[4]), NS_BOUNDARY_LINK_START);
    GpuVrl out[10];
    /* The ghost of 1; the re-entry at 2 and its ghost; the one at 3 and its ghost. */
    uint32_t n = ns_boundary_sources(walk, NULL, 5, m, 0, out);
    CHECK_INT(n, 5);
    if (n != 5)
        return;
    CHECK(out[0].power[0] < 0 && fabsf(out[0].origin[0] - 1.0f) < 1e-6f);
    /* Only the ghost whose line comes back reads its first order. */
    CHECK(out[0].events == (1 | NS_VRL_LINE_RETURNS));
    const uint32_t DM = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE;
    CHECK_INT(ns_boundary_source_orders(&out[0], DM), NS_TABLE_FIRST_BLURRED | DM);
    CHECK_INT(ns_boundary_source_orders(&out[2], DM), DM);
    CHECK(out[1].power[0] == 0.6f && out[1].origin[0] == 1.5f && out[1].direction[0] == 1.0f);
    CHECK(out[1].length == 2.0f && out[1].events == 1 && out[1].material == 0); /* its chord */
    CHECK(out[2].length == 2.0f); /* the ghost at its end: the same chord, the same tube */
    CHECK(fabsf(out[2].power[0] + 0.6f * expf(-2.0f)) < 1e-6f);
    CHECK(fabsf(out[2].origin[0] - 3.5f) < 1e-6f);
    CHECK(out[3].power[0] == 0.5f && out[3].origin[0] == 4.0f && out[3].material == 1);
    CHECK(out[4].power[0] < 0 && out[4].material == 1);
    /* Grouped, the marked ghost is the only negative source that reads the first order, and
     * what the gather gets carries its events alone. */
    ns_boundary_groups groups;
    ns_error err = {0};
    CHECK_INT(ns_boundary_group(out, 5, DM, &groups, &err), NS_OK);
    uint32_t ghosts_with_first = 0;
    for (uint32_t g = 0; g < groups.count; g++)
        for (uint32_t i = 0; i < groups.group[g].set.count; i++) {
            CHECK_INT(groups.group[g].set.vrls[i].events, 1);
            if (groups.group[g].negative && (groups.group[g].orders & NS_TABLE_FIRST_BLURRED))
                ghosts_with_first++;
        }
    CHECK_INT(ghosts_with_first, 1);
    ns_boundary_groups_free(&groups);
}

static void test_roulette(void)
{
    /* 100000 weak sources (a tenth of the floor, half of them ghosts) and two strong ones:
     * the strong ones stay as they are, about a tenth of the weak positive ones stay and
     * NS_BOUNDARY_GHOST_IMPORTANCE as many of the ghosts, each at the floor of importance,
     * and the sums of each sign are kept within their noise. */
    enum { WEAK = 100000 };
    GpuVrl *s = malloc(sizeof *s * (WEAK + 2));
    CHECK(s != NULL);
    if (!s)
        return;
    double before[2] = {0, 0};
    for (uint32_t i = 0; i < WEAK + 2; i++) {
        double p = i < WEAK ? 0.1 : 50.0; /* strong: a ghost's importance too is above 1 */
        s[i] = stretch(0, 0, 0, 0, 0, 1, 0, (i & 1) ? -p : p, 1);
        s[i].power[1] *= 0.5f; /* colour: the mean over RGB decides */
        before[i & 1] += s[i].power[0];
    }
    uint32_t n = ns_boundary_roulette(s, WEAK + 2, 1.0f, 42);
    double after[2] = {0, 0};
    uint32_t strong = 0;
    for (uint32_t i = 0; i < n; i++) {
        int negative = s[i].power[0] < 0;
        after[negative] += s[i].power[0];
        float mean = fabsf(s[i].power[0] + s[i].power[1] + s[i].power[2]) / 3.0f;
        float importance = mean * (negative ? NS_BOUNDARY_GHOST_IMPORTANCE : 1.0f);
        strong += fabsf(s[i].power[0]) == 50.0f;
        CHECK(importance >= 1.0f - 1e-5f);
        CHECK(s[i].power[1] == 0.5f * s[i].power[0]);
    }
    fprintf(stderr, "  kept %u of %u; sums %+.1f %+.1f -> %+.1f %+.1f\n", n, WEAK + 2, before[0], before[1],
            after[0], after[1]);
    CHECK_INT(strong, 2);
    /* A weak source's importance is 0.0833 (its mean over RGB), a ghost's 0.0833 g: each is
     * kept that fraction of the time, at power 0.1 over it (binomial noise). */
    const double g = NS_BOUNDARY_GHOST_IMPORTANCE, keep[2] = {0.25 / 3.0, 0.25 / 3.0 * g};
    double kept_weak = n - 2, expected = WEAK / 2 * (keep[0] + keep[1]);
    CHECK(fabs(kept_weak - expected) < 5 * sqrt(expected));
    for (int k = 0; k < 2; k++)
        CHECK(fabs(after[k] - before[k]) < 5 * sqrt(WEAK / 2 * 0.01 * (1 / keep[k] - 1)));
    /* Without the ghosts' lower importance, as many ghosts as positive ones would stay. */
    CHECK(g < 1.0);
    /* A floor of 0 keeps everything. */
    CHECK_INT(ns_boundary_roulette(s, n, 0.0f, 42), n);

    /* The floor for a target count: all kept at or below it; otherwise the expected count
     * at that floor is the target (two strong sources always kept). */
    for (uint32_t i = 0; i < WEAK + 2; i++) {
        double p = i < WEAK ? 0.001 * (1 + i % 100) : 5.0;
        s[i] = stretch(0, 0, 0, 0, 0, 1, 0, p, 1);
    }
    CHECK(ns_boundary_floor(s, WEAK + 2, WEAK + 2) == 0.0f);
    const uint32_t targets[] = {50000, 10000, 100};
    for (size_t k = 0; k < sizeof targets / sizeof targets[0]; k++) {
        float f = ns_boundary_floor(s, WEAK + 2, targets[k]);
        double expected_kept = 0;
        for (uint32_t i = 0; i < WEAK + 2; i++)
            expected_kept += fmin(1.0, s[i].power[0] / f);
        fprintf(stderr, "  target %u: floor %.5g keeps %.1f\n", targets[k], (double)f,
                expected_kept);
        CHECK(fabs(expected_kept / targets[k] - 1) < 1e-3);
    }
    free(s);
}

int main(void)
{
    RUN(test_roulette);
    RUN(test_orders);
    RUN(test_groups_of_every_kind);
    RUN(test_sources_of_a_walk);
    RUN(test_sources_with_ends);
    RUN(test_face_of_an_oblique_reflection);
    RUN(test_sources_of_a_reentry);
    return harness_report();
}
