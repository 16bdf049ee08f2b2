/* gpu_render_control.c — ns_render_controlled: progress reports, cancellation and what a
 * render takes from the context's caches (docs/rendering.md, "Progress, cancellation and
 * reuse").
 *
 *   - progress of a pt and an nn render: every START has its END with the same name, stages
 *     do not nest, TICKs come inside a stage, the names are the stats' stages and the END
 *     times add up to the stats' times, the fraction never decreases, stays in [0, 1] and is
 *     exactly 1 at the last END; pt_pass ticks several times with a growing fraction;
 *   - cancellation from inside the callback (pt at the first pt_pass tick; nn at the START of
 *     "accumulate", at the first "single" tick and at the first "gather" tick), and with the
 *     flag set before the render: NS_ERR_CANCELLED naming the stage, no submission after the
 *     flag was set, nothing but ENDs reported after it, every buffer freed, and the next
 *     render on that context equal, float for float, to a render on a context that never saw
 *     a cancellation; a table whose accumulation was cancelled is made again, not taken from
 *     the cache;
 *   - reuse: tables_made then tables_reused for a material, nothing made the second time;
 *     a table walked only within its medium's reach gives the image a table of every cell
 *     gives, bit for bit (a sphere and a box of one medium; an open square, whose paths run
 *     on far outside it), and is not taken for a scene that reaches farther;
 *     bvh_reused 0, then 1 for the same geometry with other materials (images equal to a
 *     render that built its BVH), 0 after a geometry change; camera_reused 1 for another
 *     albedo and g at the same extinction (the image equal, bit for bit, to a render that
 *     traced), 0 after an extinction one ulp away, an ior or a light changed and for pt,
 *     the kept buffers not counted as live; sources_reused 1 for another camera, image size
 *     and spp with the boundary correction (the image equal, bit for bit, to a fresh
 *     context's), 0 after a light, a material, the seed, the VRL count or the components
 *     changed and for pt, a preview's and its full image's both kept (two renders');
 *     single_reused 1 for another albedo and back, with and without
 *     adaptive single scattering (the image equal, bit for bit, to a fresh context's), 0
 *     for a channel that stops scattering, another g or other samples, and the rule on
 *     made-up materials: two media in one ratio, apart, a channel that starts to scatter,
 *     another g, other settings, quotients far apart; two media: single scattering adds
 *     up per medium (linear in each sigma_s), both halved kept (bit for bit a fresh
 *     context's, half the image), one halved alone not; two passes kept, a preview and its
 *     full image alternating, the least recently kept pushed out by a third;
 *   - a zeroed control renders what ns_render renders.
 * Small images (16 x 12): a few seconds on lavapipe. */
#include "gpu_util.h"
#include "scatter.h"

/* ---------------------------------------------------------------------------------------
 * The recorder: every report, and a cancellation when a chosen report comes.
 * ------------------------------------------------------------------------------------- */
#define MAX_EVENTS 4096

typedef struct event {
    ns_progress_kind kind;
    char stage[32];
    double fraction, stage_ms;
} event;

typedef struct recorder {
    event events[MAX_EVENTS];
    uint32_t count, overflow;
    int cancel; /* the flag the render reads */
    /* Cancel when a report of this kind for this stage comes (stage NULL: never). */
    ns_progress_kind cancel_kind;
    const char *cancel_stage;
    uint32_t cancelled_at;          /* index of that report; UINT32_MAX: not yet */
    uint64_t submissions_at_cancel; /* the device's submissions when the flag was set */
    const gpu_device *dev;
} recorder;

static void on_progress(void *user, const ns_progress *p)
{
    recorder *r = user;
    if (r->count == MAX_EVENTS) {
        r->overflow++;
        return;
    }
    event *e = &r->events[r->count];
    e->kind = p->kind;
    snprintf(e->stage, sizeof e->stage, "%s", p->stage ? p->stage : "(null)");
    e->fraction = p->fraction;
    e->stage_ms = p->stage_ms;
    if (r->cancel_stage && r->cancelled_at == UINT32_MAX && p->kind == r->cancel_kind &&
        strcmp(p->stage, r->cancel_stage) == 0) {
        __atomic_store_n(&r->cancel, 1, __ATOMIC_RELEASE);
        r->cancelled_at = r->count;
        r->submissions_at_cancel = r->dev->submissions;
    }
    r->count++;
}

static recorder *recorder_new(ns_context *ctx, ns_progress_kind kind, const char *stage)
{
    recorder *r = calloc(1, sizeof *r);
    if (!r) {
        fprintf(stderr, "out of memory\n");
        exit(1);
    }
    r->cancel_kind = kind;
    r->cancel_stage = stage;
    r->cancelled_at = UINT32_MAX;
    r->dev = &ctx->dev;
    return r;
}

static int render_with(ns_context *ctx, const ns_scene *s, recorder *r, ns_image *img,
                       ns_render_stats *stats, ns_error *err)
{
    ns_render_control control = {.cancel = &r->cancel, .progress = on_progress, .user = r};
    return ns_render_controlled(ctx, s, &control, img, stats, err);
}

/* ns_render, which must succeed. */
static int plain(ns_context *ctx, const ns_scene *s, ns_image *img, ns_render_stats *stats)
{
    ns_error err = {0};
    int status = ns_render(ctx, s, img, stats, &err);
    if (status)
        fprintf(stderr, "ns_render: %s (%s)\n", err.message, ns_status_name(status));
    CHECK_INT(status, NS_OK);
    return status == NS_OK;
}

static int same_image(const ns_image *a, const ns_image *b)
{
    return a->rgb && b->rgb && a->width == b->width && a->height == b->height &&
           memcmp(a->rgb, b->rgb, sizeof(float) * 3 * a->width * a->height) == 0;
}

static int is_stats_stage(const ns_render_stats *stats, const char *name, double *ms)
{
    for (uint32_t i = 0; i < stats->stage_count; i++)
        if (strcmp(stats->stages[i].name, name) == 0) {
            *ms = stats->stages[i].ms;
            return 1;
        }
    return 0;
}

/* The reports are well formed: START/END pairs of one name that do not nest, TICKs inside a
 * stage, times only on ENDs, the fraction in [0, 1] and never decreasing. With `complete`
 * (a render that finished): the names are the stats' stages, each stage's END times add up
 * to its time there, and the last report is an END at exactly 1. */
static void check_well_formed(const recorder *r, const ns_render_stats *stats, int complete)
{
    CHECK_INT(r->overflow, 0);
    CHECK(r->count > 0);
    const char *open = NULL;
    double last = 0.0;
    int nested = 0, unmatched = 0, stray_ticks = 0, bad_times = 0, decreasing = 0, outside = 0;
    for (uint32_t i = 0; i < r->count; i++) {
        const event *e = &r->events[i];
        if (e->kind == NS_PROGRESS_STAGE_START) {
            nested += open != NULL;
            open = e->stage;
        } else if (e->kind == NS_PROGRESS_STAGE_END) {
            unmatched += !open || strcmp(open, e->stage) != 0;
            open = NULL;
        } else {
            stray_ticks += !open || strcmp(open, e->stage) != 0;
        }
        bad_times += e->kind == NS_PROGRESS_STAGE_END ? !(e->stage_ms >= 0) : e->stage_ms != 0;
        outside += !(e->fraction >= 0.0 && e->fraction <= 1.0);
        decreasing += e->fraction < last;
        last = e->fraction;
    }
    CHECK_INT(nested, 0);
    CHECK_INT(unmatched, 0);
    CHECK(open == NULL); /* the last START was ended */
    CHECK_INT(stray_ticks, 0);
    CHECK_INT(bad_times, 0);
    CHECK_INT(outside, 0);
    CHECK_INT(decreasing, 0);
    if (!complete)
        return;
    const event *end = &r->events[r->count - 1];
    CHECK_INT(end->kind, NS_PROGRESS_STAGE_END);
    CHECK(end->fraction == 1.0);
    /* Every stage of the stats was reported, with the same time in all. */
    for (uint32_t s = 0; s < stats->stage_count; s++) {
        const char *name = stats->stages[s].name;
        double sum = 0.0;
        int starts = 0;
        for (uint32_t i = 0; i < r->count; i++)
            if (strcmp(r->events[i].stage, name) == 0) {
                starts += r->events[i].kind == NS_PROGRESS_STAGE_START;
                sum += r->events[i].kind == NS_PROGRESS_STAGE_END ? r->events[i].stage_ms : 0.0;
            }
        if (!starts)
            fprintf(stderr, "stage %s of the stats was never reported\n", name);
        CHECK(starts > 0);
        CHECK_NEAR(sum, stats->stages[s].ms, 1e-6 * (1.0 + stats->stages[s].ms));
    }
    /* ... and nothing else. */
    int foreign = 0;
    for (uint32_t i = 0; i < r->count; i++) {
        double ms;
        if (!is_stats_stage(stats, r->events[i].stage, &ms)) {
            fprintf(stderr, "reported stage %s is not in the stats\n", r->events[i].stage);
            foreign++;
        }
    }
    CHECK_INT(foreign, 0);
}

/* After a cancellation: nothing but ENDs reported after the flag was set, no submission, the
 * status and message, the buffers freed. */
static void check_cancelled(const recorder *r, int status, const ns_error *err, const char *message,
                            uint32_t buffers_before)
{
    CHECK_INT(status, NS_ERR_CANCELLED);
    CHECK_INT(err->status, NS_ERR_CANCELLED);
    CHECK_STR_CONTAINS(err->message, message);
    CHECK(r->cancelled_at != UINT32_MAX);
    if (r->cancelled_at == UINT32_MAX)
        return;
    int reported = 0;
    for (uint32_t i = r->cancelled_at + 1; i < r->count; i++)
        reported += r->events[i].kind != NS_PROGRESS_STAGE_END;
    CHECK_INT(reported, 0);
    CHECK_INT(r->dev->submissions, r->submissions_at_cancel);
    CHECK_INT(r->dev->live_buffers, buffers_before);
    check_well_formed(r, NULL, 0);
}

/* ---------------------------------------------------------------------------------------
 * Scenes
 * ------------------------------------------------------------------------------------- */
static ns_material mats[2];
static ns_object objs[2];
static ns_light lights[2];

static ns_scene pt_scene(void)
{
    ns_scene s = base_scene(16, 12, 35);
    lit_medium_sphere(&s, mats, objs, lights);
    s.render.method = NS_METHOD_PT;
    s.render.components = NS_COMPONENT_ALL;
    s.render.spp = 128; /* the pass takes several submissions on lavapipe */
    return s;
}

/* Every component of the default method, with a medium whose tables no other render of
 * this program asks for before the cancellation tests (their cache state matters). */
static ns_material nn_mats[2];

static ns_scene nn_scene(void)
{
    ns_scene s = base_scene(16, 12, 35);
    lit_medium_sphere(&s, mats, objs, lights);
    memcpy(nn_mats, mats, sizeof nn_mats);
    nn_mats[1].g = 0.3f;
    s.materials = nn_mats;
    s.render.method = NS_METHOD_NN;
    s.render.components = NS_COMPONENT_ALL;
    s.render.spp = 1;
    return s;
}

/* The reference: a context that never saw a cancellation, and its images. */
static ns_context *fresh;
static ns_image fresh_pt, fresh_nn;

static void make_references(void)
{
    ns_error err = {0};
    int status = ns_context_create(&(ns_context_desc){0}, &fresh, &err);
    if (status) {
        fprintf(stderr, "ns_context_create: %s\n", err.message);
        exit(1);
    }
    ns_scene pt = pt_scene(), nn = nn_scene();
    plain(fresh, &pt, &fresh_pt, NULL);
    plain(fresh, &nn, &fresh_nn, NULL);
}

/* ---------------------------------------------------------------------------------------
 * Progress
 * ------------------------------------------------------------------------------------- */
static void test_pt_progress(void)
{
    ns_context *ctx = test_context();
    ns_scene s = pt_scene();
    recorder *r = recorder_new(ctx, 0, NULL);
    ns_image img = {0};
    ns_render_stats stats = {0};
    ns_error err = {0};
    int status = render_with(ctx, &s, r, &img, &stats, &err);
    CHECK_INT(status, NS_OK);
    check_well_formed(r, &stats, 1);
    /* The first pt render of the context makes the pipeline: the first stage. */
    CHECK(r->count > 0 && strcmp(r->events[0].stage, "pt_pipeline") == 0);
    /* Ticks after the pt pass's submissions, by the samples finished. */
    uint32_t ticks = 0;
    double first = -1, last = -1;
    for (uint32_t i = 0; i < r->count; i++)
        if (r->events[i].kind == NS_PROGRESS_TICK && strcmp(r->events[i].stage, "pt_pass") == 0) {
            if (!ticks++)
                first = r->events[i].fraction;
            last = r->events[i].fraction;
        }
    printf("pt_pass: %u ticks, fraction %.3f -> %.3f\n", ticks, first, last);
    /* lavapipe's loop limit splits the pass into many submissions, each a tick; other
     * drivers have no such limit and run the pass in one (NVIDIA's did), which ticks once. */
    ns_device_info info;
    ns_context_device_info(ctx, &info);
    if (strstr(info.device_name, "llvmpipe")) {
        CHECK(ticks >= 3);
        CHECK(last > first);
        CHECK(first < 0.9); /* the first submission does not finish the samples */
    } else {
        CHECK(ticks >= 1);
    }
    CHECK_NEAR(last, 0.99, 1e-9); /* every sample done: the end of pt_pass's part */
    CHECK(same_image(&img, &fresh_pt));
    ns_image_free(&img);
    free(r);
}

/* The other methods' stages: the vrl method's gather (resumed dispatches), the dipole's
 * rounds of the adaptive gather. Few light paths: well formed is all that is checked. */
static void test_vrl_and_dipole_progress(void)
{
    ns_context *ctx = test_context();
    const ns_method methods[] = {NS_METHOD_VRL, NS_METHOD_DIPOLE};
    for (size_t m = 0; m < sizeof methods / sizeof methods[0]; m++) {
        ns_scene s = nn_scene();
        s.render.method = methods[m];
        s.render.vrls = 300;
        if (methods[m] == NS_METHOD_DIPOLE) {
            s.render.gather_levels = 2;
            s.render.gather_tolerance = NS_DEFAULT_GATHER_TOLERANCE;
        }
        recorder *r = recorder_new(ctx, 0, NULL);
        ns_image img = {0};
        ns_render_stats stats = {0};
        ns_error err = {0};
        int status = render_with(ctx, &s, r, &img, &stats, &err);
        if (status)
            fprintf(stderr, "%s: %s\n", ns_method_name(methods[m]), err.message);
        CHECK_INT(status, NS_OK);
        check_well_formed(r, &stats, 1);
        uint32_t gather_ticks = 0;
        for (uint32_t i = 0; i < r->count; i++)
            gather_ticks +=
                r->events[i].kind == NS_PROGRESS_TICK && strcmp(r->events[i].stage, "gather") == 0;
        CHECK(gather_ticks >= 1);
        ns_image_free(&img);
        free(r);
    }
}

/* ---------------------------------------------------------------------------------------
 * Cancellation
 * ------------------------------------------------------------------------------------- */
static void test_pt_cancel_at_first_tick(void)
{
    ns_context *ctx = test_context();
    ns_scene s = pt_scene();
    uint32_t buffers = ctx->dev.live_buffers;
    recorder *r = recorder_new(ctx, NS_PROGRESS_TICK, "pt_pass");
    ns_image img = {0};
    ns_error err = {0};
    int status = render_with(ctx, &s, r, &img, NULL, &err);
    check_cancelled(r, status, &err, "cancelled during pt_pass", buffers);
    CHECK(img.rgb == NULL);
    /* The context goes on as if nothing happened. */
    ns_image again = {0};
    if (plain(ctx, &s, &again, NULL))
        CHECK(same_image(&again, &fresh_pt));
    ns_image_free(&again);
    free(r);
}

static void test_cancel_before_the_render(void)
{
    ns_context *ctx = test_context();
    ns_scene s = nn_scene();
    uint32_t buffers = ctx->dev.live_buffers;
    uint64_t submissions = ctx->dev.submissions;
    recorder *r = recorder_new(ctx, 0, NULL);
    r->cancel = 1;
    ns_image img = {0};
    ns_error err = {0};
    int status = render_with(ctx, &s, r, &img, NULL, &err);
    CHECK_INT(status, NS_ERR_CANCELLED);
    CHECK_STR_CONTAINS(err.message, "cancelled before the first stage");
    CHECK_INT(ctx->dev.submissions, submissions);
    CHECK_INT(r->count, 0);
    CHECK_INT(ctx->dev.live_buffers, buffers);
    CHECK(img.rgb == NULL);
    free(r);
}

/* The START of "accumulate": J was made, A was not; the next render makes A (and only A),
 * and its image is the fresh context's. */
static void test_nn_cancel_during_accumulate(void)
{
    ns_context *ctx = test_context();
    ns_scene s = nn_scene();
    uint32_t buffers = ctx->dev.live_buffers;
    recorder *r = recorder_new(ctx, NS_PROGRESS_STAGE_START, "accumulate");
    ns_image img = {0};
    ns_error err = {0};
    int status = render_with(ctx, &s, r, &img, NULL, &err);
    check_cancelled(r, status, &err, "cancelled during accumulate", buffers);
    free(r);

    /* Then the progress of a whole nn render, which takes J from the cache and makes A. */
    r = recorder_new(ctx, 0, NULL);
    ns_render_stats stats = {0};
    status = render_with(ctx, &s, r, &img, &stats, &err);
    CHECK_INT(status, NS_OK);
    check_well_formed(r, &stats, 1);
    CHECK_INT(stats.tables_made, 1); /* A */
    CHECK(stats.tables_reused >= 1); /* J of the cancelled render */
    CHECK(same_image(&img, &fresh_nn));
    CHECK_INT(ctx->dev.live_buffers, buffers);
    double ms;
    CHECK(is_stats_stage(&stats, "accumulate", &ms));
    CHECK(!is_stats_stage(&stats, "reconstruct", &ms));
    ns_image_free(&img);
    free(r);
}

static void test_nn_cancel_at_first_tick(const char *stage)
{
    ns_context *ctx = test_context();
    ns_scene s = nn_scene();
    /* The context's earlier renders of this scene left its camera pass and single scattering
     * kept, which would stand for the stage: dropped, so that the stage runs. */
    ns_camera_keep_clear(ctx);
    uint32_t buffers = ctx->dev.live_buffers;
    recorder *r = recorder_new(ctx, NS_PROGRESS_TICK, stage);
    ns_image img = {0};
    ns_error err = {0};
    int status = render_with(ctx, &s, r, &img, NULL, &err);
    char message[64];
    snprintf(message, sizeof message, "cancelled during %s", stage);
    check_cancelled(r, status, &err, message, buffers);
    ns_render_stats stats = {0};
    if (plain(ctx, &s, &img, &stats)) {
        CHECK(same_image(&img, &fresh_nn));
        CHECK_INT(stats.tables_made, 0);
        CHECK(stats.tables_reused >= 1);
    }
    ns_image_free(&img);
    free(r);
}

static void test_nn_cancel_at_first_single_tick(void)
{
    test_nn_cancel_at_first_tick("single");
}

static void test_nn_cancel_at_first_gather_tick(void)
{
    test_nn_cancel_at_first_tick("gather");
}

/* ---------------------------------------------------------------------------------------
 * Reuse
 * ------------------------------------------------------------------------------------- */
static void test_tables_counted(void)
{
    ns_context *ctx = test_context();
    ns_scene s = nn_scene();
    ns_material swept[2];
    memcpy(swept, s.materials, sizeof swept);
    swept[1].sigma_s[0] = 2.5f; /* a material no render asked for yet */
    s.materials = swept;
    ns_image img = {0};
    ns_render_stats first = {0}, second = {0};
    if (plain(ctx, &s, &img, &first)) {
        printf("new material: %llu tables made, %llu reused\n",
               (unsigned long long)first.tables_made, (unsigned long long)first.tables_reused);
        CHECK(first.tables_made >= 2); /* J of the new albedo, A */
    }
    ns_image_free(&img);
    if (plain(ctx, &s, &img, &second)) {
        CHECK_INT(second.tables_made, 0);
        CHECK_INT(second.tables_reused, 1); /* A, found whole */
    }
    ns_image_free(&img);
}

/* The medium sphere of nn_scene with a box of the same medium beside it (light leaves one
 * and enters the other: the gather reads the table across both), double and multiple
 * scattering alone; with far_away also a small sphere of the medium behind the camera,
 * some 800 mean free paths off, which takes the medium's table to its whole extent. */
static ns_object reach_objs[4];

static ns_scene reach_scene(int far_away)
{
    ns_scene s = nn_scene();
    s.render.components = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE;
    reach_objs[0] = objs[0];
    reach_objs[1] = objs[1];
    memset(&reach_objs[2], 0, sizeof reach_objs[2]);
    reach_objs[2].shape = NS_SHAPE_BOX;
    set3(reach_objs[2].min, 1.2, -0.8, -0.6);
    set3(reach_objs[2].max, 2.0, 0.2, 0.4);
    reach_objs[2].material = 1;
    reach_objs[3] = sphere(0, 0, 200, 0.5, 1);
    s.objects = reach_objs;
    s.object_count = far_away ? 4 : 3;
    return s;
}

/* An open mesh of the medium: a lone square facing the camera and the light. Light and camera
 * paths that cross it run on inside the medium to the floor, far outside the square's
 * bounds, and the gather reads the table at those offsets. With far_away the small sphere of
 * reach_scene too. */
static ns_triangle open_square[2];
static ns_object open_objs[3];

static ns_scene open_scene(int far_away)
{
    ns_scene s = reach_scene(0);
    const double corners[4][3] = {{-0.5, -0.5, 0}, {0.5, -0.5, 0}, {0.5, 0.5, 0}, {-0.5, 0.5, 0}};
    const int faces[2][3] = {{0, 1, 2}, {0, 2, 3}};
    memset(open_square, 0, sizeof open_square);
    for (int f = 0; f < 2; f++)
        for (int c = 0; c < 3; c++)
            set3(open_square[f].v[c], corners[faces[f][c]][0], corners[faces[f][c]][1],
                 corners[faces[f][c]][2]);
    open_objs[0] = objs[0]; /* the floor */
    memset(&open_objs[1], 0, sizeof open_objs[1]);
    open_objs[1].shape = NS_SHAPE_MESH;
    open_objs[1].material = 1;
    open_objs[1].triangle_count = 2;
    open_objs[2] = sphere(0, 0, 200, 0.5, 1);
    s.triangles = open_square;
    s.triangle_count = 2;
    s.objects = open_objs;
    s.object_count = far_away ? 3 : 2;
    return s;
}

/* The image of `own` on a fresh context equals, bit for bit, its image on a context where
 * `whole` (the same medium with an object far away) made a table of every cell first, which
 * `own` then takes from the cache. */
static void same_as_with_every_cell(const ns_scene *own, const ns_scene *whole, const char *what)
{
    ns_context *fresh_own = NULL, *fresh_whole = NULL;
    ns_error err = {0};
    if (ns_context_create(&(ns_context_desc){0}, &fresh_own, &err) ||
        ns_context_create(&(ns_context_desc){0}, &fresh_whole, &err)) {
        fprintf(stderr, "ns_context_create: %s\n", err.message);
        CHECK(0);
        ns_context_destroy(fresh_own);
        return;
    }
    ns_image a = {0}, b = {0}, w = {0};
    ns_render_stats stats;
    plain(fresh_own, own, &a, NULL);
    plain(fresh_whole, whole, &w, NULL);
    if (plain(fresh_whole, own, &b, &stats)) {
        CHECK_INT(stats.tables_made, 0);
        int same = same_image(&a, &b);
        CHECK(same);
        double sum = 0;
        for (uint32_t i = 0; a.rgb && i < 3u * a.width * a.height; i++)
            sum += a.rgb[i];
        CHECK(sum > 0); /* something was gathered */
        printf("%s: %s a table of every cell\n", what, same ? "the same image as with" : "NOT the image of");
    }
    ns_image_free(&a);
    ns_image_free(&b);
    ns_image_free(&w);
    ns_context_destroy(fresh_own);
    ns_context_destroy(fresh_whole);
}

/* A render walks its table's cells only within its medium's reach (ns_table_key.reach_bins):
 * the image is the same, bit for bit, as with a table of every cell (made for the same
 * medium with an object far away, on another context, and found there in the cache); a
 * table that reaches too short is not taken for a larger scene, one that reaches farther is. */
static void test_tables_reach(void)
{
    ns_context *ctx = NULL;
    ns_error err = {0};
    if (ns_context_create(&(ns_context_desc){0}, &ctx, &err)) {
        fprintf(stderr, "ns_context_create: %s\n", err.message);
        CHECK(0);
        return;
    }
    ns_scene near = reach_scene(0), far = reach_scene(1);
    ns_image own = {0}, again = {0}, far_img = {0};
    ns_render_stats stats; /* one struct for every render: each clears it (ns_render) */
    double ms;
    /* near, then far: far's table reaches farther, so it is walked again (its J is kept). */
    if (plain(ctx, &near, &own, &stats))
        CHECK(stats.tables_made >= 2); /* J, A */
    if (plain(ctx, &far, &far_img, &stats)) {
        CHECK_INT(stats.tables_made, 1); /* A alone: near's reaches too short */
        CHECK(is_stats_stage(&stats, "accumulate", &ms));
    }
    /* ... and near again takes one of the two. */
    if (plain(ctx, &near, &again, &stats)) {
        CHECK_INT(stats.tables_made, 0);
        CHECK(!is_stats_stage(&stats, "accumulate", &ms));
        CHECK(same_image(&own, &again));
    }
    ns_image_free(&own);
    ns_image_free(&again);
    ns_image_free(&far_img);
    ns_context_destroy(ctx);
    /* far first, then near from its table of every cell: near's own image. */
    same_as_with_every_cell(&near, &far, "a sphere and a box of one medium");
    /* The open square's paths run far outside its bounds: its reach follows them. */
    ns_scene open = open_scene(0), open_far = open_scene(1);
    same_as_with_every_cell(&open, &open_far, "an open square of the medium");
}

/* Three diffuse objects and the medium sphere: a BVH of four primitives. */
static ns_object g_objs[5];
static ns_material g_mats[4];

static ns_scene geometry_scene(int variant)
{
    ns_scene s = base_scene(16, 12, 35);
    lit_medium_sphere(&s, mats, objs, lights);
    g_mats[0] = mats[0];
    g_mats[1] = mats[1];
    g_mats[2] = diffuse(0.8, 0.2, 0.1);
    g_mats[3] = diffuse(0.1, 0.7, 0.3);
    g_objs[0] = objs[0];
    g_objs[1] = objs[1];
    g_objs[2] = sphere(-1.6, -0.5, 0.5, 0.5, 2);
    g_objs[3] = sphere(1.5, -0.6, 0.2, 0.4, 3);
    memset(&g_objs[4], 0, sizeof g_objs[4]);
    g_objs[4].shape = NS_SHAPE_BOX;
    set3(g_objs[4].min, -0.5, -1, -2.5);
    set3(g_objs[4].max, 0.5, -0.2, -1.5);
    g_objs[4].material = 2;
    if (variant == 1) { /* other materials, and objects that swap theirs */
        g_mats[1].sigma_s[1] = 1.0f;
        g_mats[2] = diffuse(0.3, 0.3, 0.9);
        g_objs[2].material = 3;
        g_objs[3].material = 2;
    } else if (variant == 2) { /* the geometry moves */
        g_objs[3].center[0] = 1.4f;
    }
    s.materials = g_mats;
    s.material_count = 4;
    s.objects = g_objs;
    s.object_count = 5;
    s.render.components = NS_COMPONENT_SURFACE | NS_COMPONENT_SINGLE;
    return s;
}

static void test_bvh_reused(void)
{
    ns_context *ctx = test_context();
    ns_scene g0 = geometry_scene(0);
    ns_image img = {0}, built = {0};
    ns_render_stats stats = {0};
    if (plain(ctx, &g0, &img, &stats)) {
        CHECK_INT(stats.bvh_reused, 0); /* this context's last geometry was another */
        CHECK_INT(stats.primitives, 5);
    }
    ns_image_free(&img);
    ns_scene g1 = geometry_scene(1);
    memset(&stats, 0, sizeof stats);
    if (plain(ctx, &g1, &img, &stats)) {
        CHECK_INT(stats.bvh_reused, 1);
        double ms;
        CHECK(is_stats_stage(&stats, "bvh", &ms)); /* still a stage, of the comparison */
    }
    /* The same scene on a context whose last BVH was another: built, the same image. */
    ns_render_stats fresh_stats = {0};
    if (plain(fresh, &g1, &built, &fresh_stats)) {
        CHECK_INT(fresh_stats.bvh_reused, 0);
        CHECK(same_image(&img, &built));
        CHECK_INT(stats.bvh_nodes, fresh_stats.bvh_nodes);
    }
    ns_image_free(&img);
    ns_image_free(&built);
    /* The geometry moves: built again, then kept again. */
    ns_scene g2 = geometry_scene(2);
    for (int i = 0; i < 2; i++) {
        memset(&stats, 0, sizeof stats);
        if (plain(ctx, &g2, &img, &stats))
            CHECK_INT(stats.bvh_reused, (uint32_t)i);
        ns_image_free(&img);
    }
    /* pt takes it too, and renders what it would have built. */
    ns_scene pt = geometry_scene(0);
    pt.render.method = NS_METHOD_PT;
    pt.render.spp = 2;
    memset(&stats, 0, sizeof stats);
    ns_render_stats pt_stats = {0};
    if (plain(ctx, &pt, &img, &stats) && plain(ctx, &pt, &built, &pt_stats)) {
        CHECK_INT(stats.bvh_reused, 0);
        CHECK_INT(pt_stats.bvh_reused, 1);
        CHECK(same_image(&img, &built));
    }
    ns_image_free(&img);
    ns_image_free(&built);
}

/* The nn scene's sphere with extinction (4, 3, 2) exactly in floats, split as asked. */
static ns_material camera_mats[2];

static ns_scene camera_scene(const float sigma_s[3], const float sigma_a[3], float g, float ior)
{
    ns_scene s = nn_scene();
    memcpy(camera_mats, nn_mats, sizeof camera_mats);
    memcpy(camera_mats[1].sigma_s, sigma_s, sizeof camera_mats[1].sigma_s);
    memcpy(camera_mats[1].sigma_a, sigma_a, sizeof camera_mats[1].sigma_a);
    camera_mats[1].g = g;
    camera_mats[1].ior = ior;
    s.materials = camera_mats;
    return s;
}

static int has_stage(const ns_render_stats *stats, const char *name)
{
    double ms;
    return is_stats_stage(stats, name, &ms);
}

static void test_camera_reused(void)
{
    ns_context *ctx = test_context();
    const float sa[3] = {3.5f, 2.5f, 1.5f}, aa[3] = {0.5f, 0.5f, 0.5f};
    const float sb[3] = {3.75f, 2.25f, 1.25f}, ab[3] = {0.25f, 0.75f, 0.75f};
    /* One ulp more extinction in red: 4 + 2^-21. */
    const float ac[3] = {0.5f + 0x1p-21f, 0.5f, 0.5f};
    ns_scene a = camera_scene(sa, aa, 0.3f, 1.4f), b, c, d;
    ns_image img = {0}, built = {0};
    ns_render_stats stats = {0}, fresh_stats = {0};
    uint32_t buffers = ctx->dev.live_buffers;
    if (plain(ctx, &a, &img, &stats)) {
        CHECK_INT(stats.camera_reused, 0); /* no pass kept on this context is this one */
        CHECK(has_stage(&stats, "ray_pass"));
    }
    ns_image_free(&img);
    CHECK_INT(ctx->dev.live_buffers, buffers); /* what is kept is not counted */
    /* Another albedo and g at the same extinction: kept, the image the one a pass gives. */
    b = camera_scene(sb, ab, 0.6f, 1.4f);
    memset(&stats, 0, sizeof stats);
    if (plain(ctx, &b, &img, &stats)) {
        CHECK_INT(stats.camera_reused, 1);
        CHECK_INT(stats.bvh_reused, 1);
        CHECK(!has_stage(&stats, "ray_pass"));
        CHECK(stats.camera_segments > 0);
    }
    CHECK_INT(ctx->dev.live_buffers, buffers);
    if (plain(fresh, &b, &built, &fresh_stats)) {
        CHECK_INT(fresh_stats.camera_reused, 0);
        CHECK(same_image(&img, &built));
        CHECK_INT(stats.camera_segments, fresh_stats.camera_segments);
    }
    ns_image_free(&img);
    ns_image_free(&built);
    /* Each change below is the only difference from the pass kept before it (b's, then
     * each one's own), so each is what makes the pass be traced again. Single scattering
     * only from here: the camera pass is what is tested, and it needs no tables. */
    /* An extinction one ulp away from b's (4 / 3 / 2): traced (the bytes are compared
     * whole), and kept in its turn (the same scene again reuses it). */
    c = camera_scene(sa, ac, 0.3f, 1.4f);
    c.render.components = NS_COMPONENT_SINGLE;
    memset(&stats, 0, sizeof stats);
    if (plain(ctx, &c, &img, &stats))
        CHECK_INT(stats.camera_reused, 0);
    ns_image_free(&img);
    memset(&stats, 0, sizeof stats);
    if (plain(ctx, &c, &img, &stats))
        CHECK_INT(stats.camera_reused, 1);
    ns_image_free(&img);
    /* More light samples at the surfaces: another surface image, traced. */
    ns_scene more = c;
    more.render.light_samples = 3;
    memset(&stats, 0, sizeof stats);
    if (plain(ctx, &more, &img, &stats))
        CHECK_INT(stats.camera_reused, 0);
    ns_image_free(&img);
    /* Added camera samples (with the surface, whose light they add, at 2 spp): another
     * surface image, traced; asked again, kept with them, none added the second time and the
     * same image. */
    ns_scene two = c;
    two.render.spp = 2;
    two.render.components = NS_COMPONENT_SURFACE | NS_COMPONENT_SINGLE;
    memset(&stats, 0, sizeof stats);
    if (plain(ctx, &two, &img, &stats))
        CHECK_INT(stats.adaptive_samples, 0);
    ns_image_free(&img);
    ns_scene added = two;
    added.render.adaptive_spp = 1.0f;
    memset(&stats, 0, sizeof stats);
    if (plain(ctx, &added, &img, &stats)) {
        CHECK_INT(stats.camera_reused, 0);
        CHECK(stats.adaptive_samples > 0);
    }
    memset(&stats, 0, sizeof stats);
    if (plain(ctx, &added, &built, &stats)) {
        CHECK_INT(stats.camera_reused, 1);
        CHECK_INT(stats.adaptive_samples, 0);
        CHECK(same_image(&img, &built));
    }
    ns_image_free(&img);
    ns_image_free(&built);
    /* A light that moves: traced. */
    ns_scene moved = c;
    ns_light moved_lights[2];
    memcpy(moved_lights, moved.lights, sizeof moved_lights);
    moved_lights[0].direction[0] = 0.1f;
    moved.lights = moved_lights;
    memset(&stats, 0, sizeof stats);
    if (plain(ctx, &moved, &img, &stats))
        CHECK_INT(stats.camera_reused, 0);
    ns_image_free(&img);
    /* A new ior refracts elsewhere: traced. */
    d = camera_scene(sa, ac, 0.3f, 1.3f);
    d.render.components = NS_COMPONENT_SINGLE;
    d.lights = moved_lights;
    memset(&stats, 0, sizeof stats);
    if (plain(ctx, &d, &img, &stats))
        CHECK_INT(stats.camera_reused, 0);
    ns_image_free(&img);
    /* pt: traced. */
    ns_scene pt = d;
    pt.render.method = NS_METHOD_PT;
    pt.render.components = NS_COMPONENT_ALL;
    memset(&stats, 0, sizeof stats);
    if (plain(ctx, &pt, &img, &stats))
        CHECK_INT(stats.camera_reused, 0);
    ns_image_free(&img);
    CHECK_INT(ctx->dev.live_buffers, buffers);
}

/* Single scattering kept with the camera pass for another albedo (render/camera_keep.c). */
static double channel_mean(const ns_image *img, int c)
{
    double sum = 0.0;
    for (size_t p = 0; p < (size_t)img->width * img->height; p++)
        sum += img->rgb[3 * p + c];
    return sum / ((double)img->width * img->height);
}

static void test_single_reused(void)
{
    ns_context *ctx = test_context();
    uint32_t buffers = ctx->dev.live_buffers;
    /* Extinction (4, 3, 2) in each; the second albedo scales the channels apart. */
    const float sa[3] = {3.5f, 2.5f, 1.5f}, aa[3] = {0.5f, 0.5f, 0.5f};
    const float sb[3] = {2.75f, 2.25f, 1.25f}, ab[3] = {1.25f, 0.75f, 0.75f};
    /* camera_scene's materials are one static array: each scene here gets its own copy. */
    ns_material a_mats[2], b_mats[2], c_mats[2], z_mats[2];
    /* No blue scattered: the blue extinction all absorption. */
    const float sz[3] = {3.5f, 2.5f, 0.0f}, az[3] = {0.5f, 0.5f, 2.0f};
    ns_scene z = camera_scene(sz, az, 0.3f, 1.4f);
    memcpy(z_mats, z.materials, sizeof z_mats);
    z.materials = z_mats;
    ns_scene a = camera_scene(sa, aa, 0.3f, 1.4f);
    memcpy(a_mats, a.materials, sizeof a_mats);
    ns_scene b = camera_scene(sb, ab, 0.3f, 1.4f);
    memcpy(b_mats, b.materials, sizeof b_mats);
    ns_scene c = camera_scene(sb, ab, 0.5f, 1.4f);
    memcpy(c_mats, c.materials, sizeof c_mats);
    a.materials = a_mats;
    b.materials = b_mats;
    c.materials = c_mats;
    for (uint32_t levels = 0; levels <= 2; levels += 2) {
        /* levels 2: adaptive single scattering, whose rounds choose the pixels to compute from
         * the values, with two camera samples for their noise. */
        ns_image img = {0}, again = {0}, built = {0}, first = {0};
        ns_render_stats stats = {0}, fresh_stats = {0};
        ns_scene *all[4] = {&a, &b, &c, &z};
        for (int i = 0; i < 4; i++) {
            all[i]->render.components = NS_COMPONENT_SINGLE;
            all[i]->render.single_levels = levels;
            all[i]->render.single_tolerance = levels ? 0.05f : 0.0f;
            all[i]->render.spp = levels ? 2 : 1;
        }
        if (plain(ctx, &a, &first, &stats)) {
            CHECK_INT(stats.single_reused, 0);
            CHECK(has_stage(&stats, "single"));
        }
        /* Another albedo, the same g: kept, no stage, and the image a fresh context's stage
         * makes, bit for bit; not the first albedo's. */
        memset(&stats, 0, sizeof stats);
        if (plain(ctx, &b, &img, &stats)) {
            CHECK_INT(stats.camera_reused, 1);
            CHECK_INT(stats.single_reused, 1);
            CHECK_INT(stats.single_interpolated, 0);
            CHECK(!has_stage(&stats, "single"));
        }
        if (plain(fresh, &b, &built, &fresh_stats)) {
            CHECK_INT(fresh_stats.single_reused, 0); /* computed there */
            CHECK(same_image(&img, &built));
            CHECK(!same_image(&first, &built));
            CHECK(!levels || fresh_stats.single_interpolated > 0);
        }
        /* And back: the first albedo's image again. */
        memset(&stats, 0, sizeof stats);
        if (plain(ctx, &a, &again, &stats)) {
            CHECK_INT(stats.single_reused, 1);
            CHECK(same_image(&first, &again));
        }
        ns_image_free(&img);
        ns_image_free(&built);
        /* No blue scattered: another image per unit, made (blue black); and back, made. */
        memset(&stats, 0, sizeof stats);
        memset(&fresh_stats, 0, sizeof fresh_stats);
        if (plain(ctx, &z, &img, &stats) && plain(fresh, &z, &built, &fresh_stats)) {
            CHECK_INT(stats.single_reused, 0);
            CHECK_INT(fresh_stats.single_reused, 0);
            CHECK(same_image(&img, &built));
            CHECK(channel_mean(&img, 0) > 0.0);
            CHECK(channel_mean(&img, 2) == 0.0);
        }
        ns_image_free(&img);
        ns_image_free(&again);
        memset(&stats, 0, sizeof stats);
        if (plain(ctx, &a, &again, &stats)) {
            CHECK_INT(stats.single_reused, 0);
            CHECK(same_image(&first, &again));
        }
        /* Another g: the camera pass kept, single scattering made. */
        memset(&stats, 0, sizeof stats);
        if (plain(ctx, &c, &img, &stats)) {
            CHECK_INT(stats.camera_reused, 1);
            CHECK_INT(stats.single_reused, 0);
            CHECK(has_stage(&stats, "single"));
        }
        ns_image_free(&img);
        /* Other single-scattering samples: made. */
        ns_scene d = c;
        d.render.single_samples = 3;
        memset(&stats, 0, sizeof stats);
        if (plain(ctx, &d, &img, &stats)) {
            CHECK_INT(stats.camera_reused, 1);
            CHECK_INT(stats.single_reused, 0);
        }
        ns_image_free(&img);
        ns_image_free(&again);
        ns_image_free(&built);
        ns_image_free(&first);
    }
    CHECK_INT(ctx->dev.live_buffers, buffers); /* what is kept is not counted */
}

/* Two media of different sigma_s, where the stage's per-unit sigma_s of the second is not 1:
 * single scattering is linear in each medium's sigma_s (the two spheres' parts add: full =
 * A alone + B alone, within float rounding), and both scaled by one factor keep the image
 * per unit (taken, the image a fresh context makes, half the first within rounding), one of
 * them scaled alone does not. Extinctions (4, 3, 2) and 3 in every variant, exactly. */
static ns_scene two_media_scene(ns_material m[3], ns_object o[3], ns_light l[2], const double sa[3],
                                const double sb[3])
{
    ns_scene s = base_scene(24, 16, 40);
    set3(s.camera.position, 0, 1, 6);
    set3(s.camera.look_at, 0, 0, 0);
    const double ta[3] = {4, 3, 2}, tb[3] = {3, 3, 3};
    m[0] = diffuse(0.5, 0.5, 0.5);
    m[1] = medium(sa, (double[3]){ta[0] - sa[0], ta[1] - sa[1], ta[2] - sa[2]}, 1.3);
    m[2] = medium(sb, (double[3]){tb[0] - sb[0], tb[1] - sb[1], tb[2] - sb[2]}, 1.3);
    m[1].g = m[2].g = 0.4f;
    o[0] = plane(-1, 0);
    o[1] = sphere(-1.1, 0, 0, 1, 1);
    o[2] = sphere(1.1, 0, 0, 1, 2);
    l[0] = light(NS_LIGHT_DIRECTIONAL, 2, 2, 2);
    set3(l[0].direction, 0.3, -0.8, -0.52);
    l[1] = light(NS_LIGHT_ENVIRONMENT, 0.2, 0.2, 0.25);
    scene_lists(&s, m, 3, o, 3, l, 2);
    s.render.components = NS_COMPONENT_SINGLE;
    s.render.spp = 1;
    return s;
}

static void test_single_two_media(void)
{
    ns_context *ctx = test_context();
    const double sa[3] = {2, 1.5, 1}, sb[3] = {1.5, 1.5, 1.5}, none[3] = {0, 0, 0};
    const double sa_half[3] = {1, 0.75, 0.5}, sb_half[3] = {0.75, 0.75, 0.75};
    ns_material m_full[3], m_a[3], m_b[3], m_half[3], m_one[3];
    ns_object spheres[3];
    ns_light lit[2];
    ns_scene full = two_media_scene(m_full, spheres, lit, sa, sb);
    ns_scene only_a = two_media_scene(m_a, spheres, lit, sa, none);
    ns_scene only_b = two_media_scene(m_b, spheres, lit, none, sb);
    ns_scene half = two_media_scene(m_half, spheres, lit, sa_half, sb_half);
    ns_scene one_halved = two_media_scene(m_one, spheres, lit, sa_half, sb);
    ns_image f = {0}, a = {0}, b = {0}, h = {0}, fresh_h = {0}, o = {0};
    ns_render_stats stats = {0}, fresh_stats = {0};
    if (plain(ctx, &full, &f, NULL) && plain(ctx, &only_a, &a, NULL) &&
        plain(ctx, &only_b, &b, NULL)) {
        double ma[3], mb[3];
        image_mean(&a, ma);
        image_mean(&b, mb);
        CHECK(ma[0] > 0 && ma[2] > 0 && mb[0] > 0 && mb[2] > 0); /* both spheres scatter */
        float peak = 0;
        for (size_t i = 0; i < (size_t)3 * f.width * f.height; i++)
            peak = fmaxf(peak, f.rgb[i]);
        int off = 0;
        for (size_t i = 0; i < (size_t)3 * f.width * f.height; i++) {
            double sum = (double)a.rgb[i] + b.rgb[i];
            off += !(fabs(f.rgb[i] - sum) <= 1e-5 * sum + 1e-7 * peak);
        }
        CHECK_INT(off, 0);
    }
    /* Both halved: taken; what a fresh context computes, bit for bit; half of full. */
    ns_image_free(&f);
    plain(ctx, &full, &f, NULL);
    if (plain(ctx, &half, &h, &stats) && plain(fresh, &half, &fresh_h, &fresh_stats)) {
        CHECK_INT(stats.single_reused, 1);
        CHECK_INT(fresh_stats.single_reused, 0);
        CHECK(same_image(&h, &fresh_h));
        int off = 0;
        for (size_t i = 0; i < (size_t)3 * h.width * h.height; i++)
            off += !(fabsf(h.rgb[i] - 0.5f * f.rgb[i]) <= 1e-6f * f.rgb[i]);
        CHECK_INT(off, 0);
    }
    /* One medium halved alone: its part was never kept apart. */
    memset(&stats, 0, sizeof stats);
    if (plain(ctx, &one_halved, &o, &stats)) {
        CHECK_INT(stats.camera_reused, 1);
        CHECK_INT(stats.single_reused, 0);
    }
    ns_image *all[] = {&f, &a, &b, &h, &fresh_h, &o};
    for (size_t i = 0; i < sizeof all / sizeof all[0]; i++)
        ns_image_free(all[i]);
}

/* Two camera passes kept (render/camera_keep.c): a quarter-size preview and the full image
 * alternate, as the web page renders them, and each takes its own; a third pass pushes out the
 * least recently kept. */
static void test_two_passes_kept(void)
{
    ns_context *ctx = test_context();
    ns_camera_keep_clear(ctx); /* the tests before kept this scene's pass */
    uint32_t buffers = ctx->dev.live_buffers;
    const float s1[3] = {3.5f, 2.5f, 1.5f}, a1[3] = {0.5f, 0.5f, 0.5f};
    const float s2[3] = {3.0f, 2.0f, 1.0f}, a2[3] = {1.0f, 1.0f, 1.0f};
    ns_material full_mats[2], other_mats[2];
    ns_scene full = camera_scene(s1, a1, 0.3f, 1.4f);
    memcpy(full_mats, full.materials, sizeof full_mats);
    full.materials = full_mats;
    ns_scene other = camera_scene(s2, a2, 0.3f, 1.4f); /* another albedo, the same extinction */
    memcpy(other_mats, other.materials, sizeof other_mats);
    other.materials = other_mats;
    full.render.components = other.render.components = NS_COMPONENT_SINGLE;
    ns_scene preview = full, other_preview = other, third = full;
    preview.camera.width = other_preview.camera.width = full.camera.width / 4;
    preview.camera.height = other_preview.camera.height = full.camera.height / 4;
    third.camera.fov_deg = 50.0f;
    const struct {
        const ns_scene *scene;
        uint32_t camera, single;
    } steps[] = {
        {&full, 0, 0},  {&preview, 0, 0},       /* made, each kept */
        {&other, 1, 1}, {&other_preview, 1, 1}, /* a new albedo: both kept */
        {&full, 1, 1},  {&third, 0, 0},         /* the third pushes out the preview */
        {&full, 1, 1},  {&preview, 0, 0},
    };
    for (size_t i = 0; i < sizeof steps / sizeof steps[0]; i++) {
        ns_image img = {0};
        ns_render_stats stats = {0};
        if (plain(ctx, steps[i].scene, &img, &stats)) {
            if (stats.camera_reused != steps[i].camera || stats.single_reused != steps[i].single)
                fprintf(stderr, "step %zu: camera %u single %u\n", i, stats.camera_reused,
                        stats.single_reused);
            CHECK_INT(stats.camera_reused, steps[i].camera);
            CHECK_INT(stats.single_reused, steps[i].single);
        }
        ns_image_free(&img);
    }
    CHECK_INT(ctx->dev.live_buffers, buffers);
}

/* Which materials per unit sigma_s match, on made-up ones: a floor and two media. */
static int keep_matches(const ns_single_keep *keep, const ns_scene *scene, const GpuMaterial *now,
                        uint32_t count)
{
    GpuMaterial unit[3];
    float reference[3];
    ns_single_unit_materials(now, count, unit, reference);
    return ns_single_keep_matches(keep, scene, unit, count);
}

static void test_single_keep_rule(void)
{
    ns_scene scene = {0};
    GpuMaterial was[3] = {0}, now[3] = {0}, unit[3];
    const float sigma_s[2][3] = {{2.0f, 0.0f, 0.0f}, {0.5f, 4.0f, 0.0f}};
    for (int i = 0; i < 2; i++) {
        memcpy(was[i + 1].sigma_s, sigma_s[i], sizeof sigma_s[i]);
        was[i + 1].sigma_s[3] = 0.4f + 0.2f * (float)i; /* g */
    }
    float reference[3];
    ns_single_unit_materials(was, 3, unit, reference);
    /* The largest per channel; blue, which nothing scatters, 0. */
    CHECK(reference[0] == 2.0f && reference[1] == 4.0f && reference[2] == 0.0f);
    CHECK(unit[1].sigma_s[0] == 1.0f && unit[2].sigma_s[0] == 0.25f && unit[2].sigma_s[1] == 1.0f);
    CHECK(unit[0].sigma_s[0] == 0.0f && unit[1].sigma_s[1] == 0.0f && unit[2].sigma_s[2] == 0.0f);
    CHECK(unit[2].sigma_s[3] == was[2].sigma_s[3]);
    /* No overflow where the sigma_s lie far apart: every quotient in [0, 1]. */
    now[1].sigma_s[0] = 1e-40f;
    now[2].sigma_s[0] = 3e38f;
    ns_single_unit_materials(now, 3, unit, reference);
    CHECK(reference[0] == 3e38f && unit[2].sigma_s[0] == 1.0f && unit[1].sigma_s[0] == 0.0f);
    ns_single_keep keep = {0};
    ns_single_unit_materials(was, 3, unit, reference);
    CHECK_INT(ns_single_keep_set(&keep, calloc(6, sizeof(float)), &scene, unit, 3), 0);
    /* Both media to half the red: the same per unit. */
    memcpy(now, was, sizeof was);
    now[1].sigma_s[0] = 1.0f;
    now[2].sigma_s[0] = 0.25f;
    CHECK_INT(keep_matches(&keep, &scene, now, 3), 1);
    /* Only one medium's red halved. */
    now[2].sigma_s[0] = 0.5f;
    CHECK_INT(keep_matches(&keep, &scene, now, 3), 0);
    /* Blue, 0 in both, now scattering in one. */
    memcpy(now, was, sizeof was);
    now[2].sigma_s[2] = 1.0f;
    CHECK_INT(keep_matches(&keep, &scene, now, 3), 0);
    /* Another g in one medium. */
    memcpy(now, was, sizeof was);
    now[2].sigma_s[3] = 0.61f;
    CHECK_INT(keep_matches(&keep, &scene, now, 3), 0);
    /* Other settings, another material count. */
    memcpy(now, was, sizeof was);
    CHECK_INT(keep_matches(&keep, &scene, now, 3), 1);
    ns_scene other = scene;
    other.render.single_tolerance = 0.1f;
    CHECK_INT(keep_matches(&keep, &other, now, 3), 0);
    other = scene;
    other.render.single_samples = 7;
    CHECK_INT(keep_matches(&keep, &other, now, 3), 0);
    CHECK_INT(keep_matches(&keep, &scene, now, 2), 0);
    ns_single_keep_free(&keep);
    CHECK(keep.image == NULL);
}

/* The light's sources (VRLs and the boundary correction's walks) kept across camera changes:
 * reused for another camera, image size, sample count, light samples and added samples,
 * with the image a
 * fresh context gives; made again when a light, a material, the seed, the VRL count or the
 * components change. */
static ns_scene walks_scene(void)
{
    ns_scene s = nn_scene();
    s.render.boundary = NS_BOUNDARY_WALKS;
    s.render.vrls = 600;
    return s;
}

static void test_sources_reused(void)
{
    ns_context *ctx = test_context();
    ns_scene a = walks_scene();
    ns_image img = {0}, built = {0};
    ns_render_stats first = {0}, stats = {0}, fresh_stats = {0};
    if (plain(ctx, &a, &img, &first)) {
        CHECK_INT(first.sources_reused, 0); /* no sources kept on this context are these */
        CHECK(has_stage(&first, "vrl"));
        CHECK(has_stage(&first, "boundary"));
        CHECK(first.boundary_sources > 0);
    }
    ns_image_free(&img);
    /* Another camera, image size, sample count, light samples and added samples (the camera
     * pass's alone): the same sources. */
    ns_scene b = a;
    b.camera.position[0] = 1.5f;
    b.camera.fov_deg = 50.0f;
    b.camera.width = 14;
    b.render.spp = 2;
    b.render.light_samples = 3;
    b.render.adaptive_spp = 1.0f;
    if (plain(ctx, &b, &img, &stats)) {
        CHECK_INT(stats.sources_reused, 1);
        CHECK(!has_stage(&stats, "vrl"));
        CHECK(!has_stage(&stats, "boundary"));
        CHECK(stats.vrl_count == first.vrl_count && stats.vrl_paths == first.vrl_paths);
        CHECK(stats.boundary_sources == first.boundary_sources);
    }
    if (plain(fresh, &b, &built, &fresh_stats)) {
        CHECK_INT(fresh_stats.sources_reused, 0);
        CHECK(same_image(&img, &built));
    }
    ns_image_free(&img);
    ns_image_free(&built);
    /* What the sources depend on: each change traces them again. */
    ns_light moved_lights[2];
    memcpy(moved_lights, b.lights, sizeof moved_lights);
    moved_lights[0].direction[0] = 0.2f;
    ns_material other_mats[2];
    memcpy(other_mats, b.materials, sizeof other_mats);
    other_mats[1].sigma_s[2] *= 0.5f;
    struct {
        const char *what;
        ns_scene scene;
    } changes[5];
    for (int i = 0; i < 5; i++)
        changes[i].scene = b;
    changes[0].what = "a light", changes[0].scene.lights = moved_lights;
    changes[1].what = "a material", changes[1].scene.materials = other_mats;
    changes[2].what = "the seed", changes[2].scene.render.seed = b.render.seed + 1;
    changes[3].what = "the VRL count", changes[3].scene.render.vrls = b.render.vrls + 1;
    changes[4].what = "the components", changes[4].scene.render.components = NS_COMPONENT_MULTIPLE;
    for (int i = 0; i < 5; i++) {
        /* Back to b's sources first (taken, so kept the longest), so that only this change
         * differs from the sources kept. */
        plain(ctx, &b, &img, NULL);
        ns_image_free(&img);
        memset(&stats, 0, sizeof stats);
        if (plain(ctx, &changes[i].scene, &img, &stats)) {
            if (stats.sources_reused)
                fprintf(stderr, "sources reused after a change of %s\n", changes[i].what);
            CHECK_INT(stats.sources_reused, 0);
            CHECK(has_stage(&stats, "vrl"));
        }
        ns_image_free(&img);
    }
    /* A preview (a quarter of the light paths and of the image) and the full image in turn,
     * as the web page renders them: each keeps its own. */
    ns_scene preview = b;
    preview.render.vrls = b.render.vrls / 4;
    preview.camera.width = b.camera.width / 4;
    preview.camera.height = b.camera.height / 4;
    const ns_scene *turns[4] = {&b, &preview, &b, &preview};
    const uint32_t reused[4] = {1, 0, 1, 1}; /* b was taken last, the components' pushed out */
    for (int i = 0; i < 4; i++) {
        memset(&stats, 0, sizeof stats);
        if (plain(ctx, turns[i], &img, &stats))
            CHECK_INT(stats.sources_reused, reused[i]);
        ns_image_free(&img);
    }
    /* pt makes no such sources. */
    ns_scene pt = b;
    pt.render.method = NS_METHOD_PT;
    memset(&stats, 0, sizeof stats);
    if (plain(ctx, &pt, &img, &stats))
        CHECK_INT(stats.sources_reused, 0);
    ns_image_free(&img);
}

static void test_zeroed_control_is_ns_render(void)
{
    ns_context *ctx = test_context();
    ns_scene s = nn_scene();
    ns_image a = {0}, b = {0};
    ns_error err = {0};
    CHECK_INT(ns_render_controlled(ctx, &s, &(ns_render_control){0}, &a, NULL, &err), NS_OK);
    CHECK_INT(ns_render_controlled(ctx, &s, NULL, &b, NULL, &err), NS_OK);
    CHECK(same_image(&a, &fresh_nn));
    CHECK(same_image(&b, &fresh_nn));
    ns_image_free(&a);
    ns_image_free(&b);
}

int main(void)
{
    make_references();
    RUN(test_pt_progress);
    RUN(test_vrl_and_dipole_progress);
    RUN(test_pt_cancel_at_first_tick);
    RUN(test_cancel_before_the_render);
    RUN(test_nn_cancel_during_accumulate);
    RUN(test_nn_cancel_at_first_single_tick);
    RUN(test_nn_cancel_at_first_gather_tick);
    RUN(test_tables_counted);
    RUN(test_tables_reach);
    RUN(test_bvh_reused);
    RUN(test_camera_reused);
    RUN(test_single_reused);
    RUN(test_single_two_media);
    RUN(test_two_passes_kept);
    RUN(test_single_keep_rule);
    RUN(test_sources_reused);
    RUN(test_zeroed_control_is_ns_render);
    ns_image_free(&fresh_pt);
    ns_image_free(&fresh_nn);
    ns_context_destroy(fresh);
    return harness_report();
}
