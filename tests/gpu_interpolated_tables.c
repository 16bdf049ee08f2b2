/* gpu_interpolated_tables.c — render.tables "interpolated" (render/scatter_tables.c): a
 * material's A blended per channel and order from the A of albedo nodes, against the exact
 * path (the networks evaluated and accumulated at the material's own albedos):
 *   (a) off the nodes, every channel within 1% energy-weighted L1 of the exact table
 *       (measured 0.04-0.34%: the cubic's error, far below the networks' own 3-15%), and its
 *       sum within 0.2%; so is each order alone, and double alone plus multiple alone is
 *       both (1e-6: the blend is linear);
 *   (b) at a node's albedo, and beyond the networks' albedo_max (which they clamp), the
 *       exact table itself, within the accumulation's cut (1e-4 of each walk); albedo 0 is 0;
 *       the ends of the stencil (the first and the last interval) as in (a);
 *   (c) a material whose nodes are cached is a blend: no reconstruction, one table made and
 *       nothing else added to the cache;
 *   (d) a render with render.tables "interpolated" whose nodes are cached reconstructs
 *       nothing, and its image means are the exact path's within 0.5%;
 *   (e) keys and scenes refused: interpolated with method table or pt, an unknown mode;
 *   (f) nodes on disk (ns_context_desc.table_node_dir): a second context reads them
 *       instead of making them, bit for bit the same table, and does not rewrite their files
 *       (the first keeps its inode); a corrupted file, a cut one and one that another version of
 *       the code made are each made again, within the accumulation's cut of the first (and
 *       rewritten: a fourth context reads them, the corrupted file's new inode kept); a bound
 *       on the folder keeps it within the bound, the least recently used first; a folder that
 *       cannot be written still gives the table;
 *   (g) where a table's mapping is not host-cached (a discrete GPU's device memory; lavapipe
 *       pretends, gpu_device.pretend_uncached), the blend is built in host memory: a blend of
 *       both orders comes out the sum of each alone made the usual way (1e-6);
 *   (h) render.tables "auto": exact for the first four albedos at a g, then a blend (the
 *       g's nodes made once), an exact table already made kept; with the nodes on disk, a
 *       blend from the first material; between renders (ns_context_idle_work), the nodes of
 *       a g whose albedos auto is exploring.
 * Validation layers on (NSCATTER_VALIDATION=1). */
#include <pthread.h>
#include <sys/stat.h>
#include <unistd.h>

#include "gpu_util.h"
#include "scatter.h"

static const size_t cells = NS_TABLE_CELLS;
static double *cell_volume; /* ring volume x solid angle of each cell: the table's energy weight */

static ns_table_key key_of(float g, float a0, float a1, float a2, ns_tables_mode mode)
{
    return (ns_table_key){.source = NS_METHOD_NN,
                          .g = g,
                          .albedo = {a0, a1, a2},
                          .orders = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE,
                          .accumulation = NS_ACCUMULATION_EXACT,
                          .tables = mode};
}

/* A copy of key's tables (the cache's may be evicted by the next call). */
static float *tables_copy(const ns_table_key *key, ns_table_stats *stats)
{
    const ns_scatter_tables *t = NULL;
    ns_error err = {0};
    int status = ns_tables_get(test_context(), key, &t, stats, &err);
    if (status)
        fprintf(stderr, "ns_tables_get: %s (%s)\n", err.message, ns_status_name(status));
    CHECK_INT(status, NS_OK);
    if (status)
        return NULL;
    /* Through the host-cached path: on a discrete GPU the table's mapping is uncached. */
    float *copy = malloc(3 * cells * sizeof(float));
    status = copy ? ns_scatter_tables_read(test_context(), t, copy, &err) : NS_ERR_OUT_OF_HOST_MEMORY;
    CHECK_INT(status, NS_OK);
    if (status) {
        free(copy);
        return NULL;
    }
    return copy;
}

/* Energy-weighted L1 of channel c of got against want, and the ratio of their sums. */
static double channel_l1(const float *got, const float *want, int c, double *sum_ratio)
{
    double diff = 0, sum_want = 0, sum_got = 0;
    for (size_t i = 0; i < cells; i++) {
        double g = got[c * cells + i], w = want[c * cells + i];
        diff += cell_volume[i] * fabs(g - w);
        sum_want += cell_volume[i] * w;
        sum_got += cell_volume[i] * g;
    }
    *sum_ratio = sum_got / sum_want;
    return diff / sum_want;
}

/* Interpolated against exact for one material; returns the worst channel's L1. */
static double compare_with_exact(ns_table_key key, double l1_bound, double sum_bound)
{
    ns_table_stats stats;
    key.tables = NS_TABLES_EXACT;
    float *exact = tables_copy(&key, &stats);
    key.tables = NS_TABLES_INTERPOLATED;
    float *blend = tables_copy(&key, &stats);
    double worst = 0;
    for (int c = 0; c < 3 && exact && blend; c++) {
        if (key.albedo[c] == 0.0f) {
            int nonzero = 0;
            for (size_t i = 0; i < cells; i++)
                nonzero += blend[c * cells + i] != 0.0f;
            CHECK_INT(nonzero, 0);
            continue;
        }
        double ratio, l1 = channel_l1(blend, exact, c, &ratio);
        printf("  g %.2f albedo %.6f: L1 %.5f, sum ratio %.5f\n", (double)key.g, (double)key.albedo[c],
               l1, ratio);
        CHECK(l1 < l1_bound);
        CHECK(fabs(ratio - 1.0) < sum_bound);
        worst = fmax(worst, l1);
    }
    free(exact);
    free(blend);
    return worst;
}

static void test_off_the_nodes(void)
{
    ns_table_key key = key_of(0.7f, 0.8f, 0.9f, 0.97f, NS_TABLES_INTERPOLATED);
    compare_with_exact(key, 0.01, 0.002);
    /* One order alone (the keys the boundary walks' shifted sources ask for), against the
     * exact path's; and the blend is linear: double alone plus multiple alone is both, to
     * float rounding (A is far above 0 where it counts, so the clamp does not enter). */
    ns_table_key one[2] = {key, key};
    one[0].orders = NS_COMPONENT_DOUBLE;
    one[1].orders = NS_COMPONENT_MULTIPLE;
    compare_with_exact(one[0], 0.01, 0.002);
    compare_with_exact(one[1], 0.01, 0.002);
    ns_table_stats stats;
    float *both = tables_copy(&key, &stats), *parts[2];
    for (int o = 0; o < 2; o++)
        parts[o] = tables_copy(&one[o], &stats);
    if (both && parts[0] && parts[1]) {
        for (int c = 0; c < 3; c++) {
            double diff = 0, sum = 0;
            for (size_t i = c * cells; i < (c + 1) * cells; i++) {
                diff += cell_volume[i % cells] * fabs((double)parts[0][i] + parts[1][i] - both[i]);
                sum += cell_volume[i % cells] * both[i];
            }
            CHECK(diff < 1e-6 * sum);
        }
    }
    free(both);
    free(parts[0]);
    free(parts[1]);
}

static void test_at_nodes_and_beyond(void)
{
    double nodes[NS_TABLE_ALBEDO_NODES];
    ns_error err = {0};
    CHECK_INT(ns_tables_node_albedos(test_context(), nodes, &err), NS_OK);
    for (uint32_t i = 1; i < NS_TABLE_ALBEDO_NODES; i++)
        CHECK(nodes[i] > nodes[i - 1]);
    CHECK(nodes[NS_TABLE_ALBEDO_NODES - 1] < 1.0);
    /* Nodes 4, 5 and 7: their neighbours are the ones test_off_the_nodes made. */
    compare_with_exact(key_of(0.7f, (float)nodes[4], (float)nodes[5], (float)nodes[7], NS_TABLES_INTERPOLATED),
                       3e-4, 3e-4);
    /* Beyond the last node the networks see their albedo_max: the last node, scaled by the
     * exact energies. Albedo 0 is 0 in both paths. */
    compare_with_exact(key_of(0.7f, 0.9995f, 0.0f, 0.9999f, NS_TABLES_INTERPOLATED), 3e-4, 3e-4);
    /* The ends of the stencil: the first interval (node 0 evaluated at albedo 1e-3) and the
     * last one below albedo_max. */
    compare_with_exact(key_of(0.7f, 0.05f, 0.3f, 0.9985f, NS_TABLES_INTERPOLATED), 0.01, 0.002);
}

static void test_cached_nodes_make_a_blend(void)
{
    /* Every channel's four nodes were made by test_off_the_nodes (nodes 2-9 at g 0.7). */
    ns_table_key key = key_of(0.7f, 0.85f, 0.93f, 0.95f, NS_TABLES_INTERPOLATED);
    ns_table_stats stats;
    uint64_t bytes_before, bytes_after;
    uint32_t entries_before, entries_after;
    ns_tables_cache_usage(test_context(), &bytes_before, &entries_before);
    float *blend = tables_copy(&key, &stats);
    ns_tables_cache_usage(test_context(), &bytes_after, &entries_after);
    CHECK(!stats.cache_hit && !stats.reconstructed && stats.reconstruct_ms == 0.0);
    CHECK(stats.accumulated);
    CHECK_INT(stats.tables_made, 1); /* the blend itself */
    CHECK_INT(entries_after, entries_before + 1);
    /* A different material from the first: its own table, not a stale one. */
    ns_table_key first = key_of(0.7f, 0.8f, 0.9f, 0.97f, NS_TABLES_INTERPOLATED);
    float *other = tables_copy(&first, &stats);
    CHECK(stats.cache_hit);
    if (blend && other) {
        double ratio;
        CHECK(channel_l1(blend, other, 0, &ratio) > 0.05);
    }
    free(blend);
    free(other);
}

static void test_uncached_mappings(void)
{
    ns_context *ctx = test_context();
    /* Albedos no other test asks for, between nodes 3-9 at g 0.7 (made above). */
    ns_table_key both = key_of(0.7f, 0.88f, 0.925f, 0.965f, NS_TABLES_INTERPOLATED);
    ns_table_stats stats;
    const ns_scatter_tables *t = NULL;
    ns_error err = {0};
    ctx->dev.pretend_uncached = 1;
    CHECK_INT(ns_tables_get(ctx, &both, &t, &stats, &err), NS_OK);
    CHECK(t && !t->a.host_cached); /* the pretence holds: the blend took the host-memory path */
    CHECK(!stats.reconstructed && stats.tables_made == 1);
    float *blend = tables_copy(&both, &stats);
    ctx->dev.pretend_uncached = 0;
    ns_table_key one[2] = {both, both};
    one[0].orders = NS_COMPONENT_DOUBLE;
    one[1].orders = NS_COMPONENT_MULTIPLE;
    float *parts[2] = {tables_copy(&one[0], &stats), tables_copy(&one[1], &stats)};
    if (blend && parts[0] && parts[1]) {
        for (int c = 0; c < 3; c++) {
            double diff = 0, sum = 0;
            for (size_t i = c * cells; i < (c + 1) * cells; i++) {
                size_t cell = i % cells;
                diff += cell_volume[cell] * fabs((double)parts[0][i] + parts[1][i] - blend[i]);
                sum += cell_volume[cell] * blend[i];
            }
            CHECK(sum > 0 && diff < 1e-6 * sum);
        }
    }
    free(blend);
    free(parts[0]);
    free(parts[1]);
}

static int has_stage(const ns_render_stats *stats, const char *name)
{
    for (uint32_t i = 0; i < stats->stage_count; i++)
        if (strcmp(stats->stages[i].name, name) == 0)
            return 1;
    return 0;
}

static void test_render(void)
{
    ns_scene s = base_scene(32, 32, 40);
    ns_material mats[2];
    ns_object objs[2];
    ns_light lights[2];
    lit_medium_sphere(&s, mats, objs, lights);
    mats[1].g = 0.7f; /* albedos 0.976, 0.9375, 0.870: nodes 3-9, made above */
    s.render.components = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE;
    s.render.vrls = 2000;
    s.render.tables = NS_TABLES_INTERPOLATED;
    ns_image blend = {0}, exact = {0};
    ns_render_stats stats = {0};
    if (render_ok(&s, &blend, &stats)) {
        CHECK(!has_stage(&stats, "reconstruct"));
        CHECK(has_stage(&stats, "accumulate"));
        CHECK_INT(stats.tables_blended, 1); /* one material, one set of orders */
    }
    s.render.tables = NS_TABLES_EXACT;
    stats = (ns_render_stats){0};
    if (render_ok(&s, &exact, &stats) && blend.rgb) {
        CHECK(has_stage(&stats, "reconstruct"));
        CHECK_INT(stats.tables_blended, 0);
        double mb[3], me[3];
        image_mean(&blend, mb);
        image_mean(&exact, me);
        for (int c = 0; c < 3; c++) {
            printf("  image mean, channel %d: interpolated %.6g, exact %.6g\n", c, mb[c], me[c]);
            CHECK(me[c] > 0 && fabs(mb[c] / me[c] - 1) < 0.005);
        }
    }
    ns_image_free(&blend);
    ns_image_free(&exact);

    s.render.tables = NS_TABLES_INTERPOLATED;
    s.render.method = NS_METHOD_PT;
    ns_error err = {0};
    CHECK_INT(ns_scene_validate(&s, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "render.tables");
}

/* render.tables "auto" (ns_tables_get, in a context of its own with no table folder): the
 * first four albedos at a g get their exact tables; the fifth a blend, its nodes made then;
 * later albedos blend from them; a material whose exact table is cached keeps it. Which one
 * a call made shows as a cache hit on the key of that mode, asked for right after (the same
 * entry: nothing was inserted in between). The paper's accumulation, one
 * albedo per material (four nodes): its walks are short. */
/* ns_tables_get of key as "auto" (its stats into *auto_stats), then as `mode`: whether that
 * found the very table auto had made or found, i.e. whether auto chose `mode`. -1 on an
 * error. */
static int auto_chose(ns_context *ctx, ns_table_key key, ns_tables_mode mode, ns_table_stats *auto_stats)
{
    const ns_scatter_tables *t = NULL, *as_mode = NULL;
    ns_table_stats stats;
    ns_error err = {0};
    key.tables = NS_TABLES_AUTO;
    int status = ns_tables_get(ctx, &key, &t, auto_stats, &err);
    CHECK_INT(status, NS_OK);
    key.tables = mode;
    if (!status)
        status = ns_tables_get(ctx, &key, &as_mode, &stats, &err);
    CHECK_INT(status, NS_OK);
    return status ? -1 : stats.cache_hit && as_mode == t;
}

static void test_auto(void)
{
    ns_context *ctx = NULL;
    ns_error err = {0};
    CHECK_INT(ns_context_create(&(ns_context_desc){0}, &ctx, &err), NS_OK);
    if (!ctx)
        return;
    /* 0.95 and 0.96 blend the same four nodes (5-8). */
    const float albedos[7] = {0.8f, 0.85f, 0.9f, 0.92f, 0.95f, 0.96f, 0.9f};
    ns_table_stats stats;
    for (int i = 0; i < 7; i++) {
        float a = albedos[i];
        /* Exact, four times; interpolated twice; the third material's exact table again. */
        ns_tables_mode want = i < 4 || i == 6 ? NS_TABLES_EXACT : NS_TABLES_INTERPOLATED;
        ns_table_key key = key_of(0.45f, a, a, a, NS_TABLES_AUTO);
        key.accumulation = NS_ACCUMULATION_PAPER;
        CHECK_INT(auto_chose(ctx, key, want, &stats), 1);
        CHECK_INT(stats.tables_blended, want == NS_TABLES_INTERPOLATED);
        /* The fifth material makes its nodes: a reconstruction of their albedos. */
        CHECK_INT(stats.reconstructed, i < 5);
        CHECK_INT(stats.cache_hit, i == 6);
        if (i < 4) {
            /* A render asks for several keys of a material (here multiple scattering alone):
             * one material still, not another albedo towards the four. */
            key.orders = NS_COMPONENT_MULTIPLE;
            CHECK_INT(auto_chose(ctx, key, NS_TABLES_EXACT, &stats), 1);
        }
        printf("  auto, albedo %.2f: %s\n", (double)a, want == NS_TABLES_EXACT ? "exact" : "interpolated");
    }
    /* The first material stays exact for a key it had not asked for (double scattering
     * alone), even once the nodes its albedo needs exist (made here by asking for its blend
     * of multiple scattering). */
    ns_table_key later = key_of(0.45f, 0.8f, 0.8f, 0.8f, NS_TABLES_INTERPOLATED);
    later.accumulation = NS_ACCUMULATION_PAPER;
    later.orders = NS_COMPONENT_MULTIPLE;
    const ns_scatter_tables *t = NULL;
    CHECK_INT(ns_tables_get(ctx, &later, &t, &stats, &err), NS_OK);
    later.orders = NS_COMPONENT_DOUBLE;
    CHECK_INT(auto_chose(ctx, later, NS_TABLES_EXACT, &stats), 1);
    ns_context_destroy(ctx);
}

static void test_bad_keys(void)
{
    const ns_scatter_tables *t = NULL;
    ns_error err = {0};
    ns_table_key key = key_of(0.7f, 0.8f, 0.9f, 0.97f, NS_TABLES_INTERPOLATED);
    key.source = NS_METHOD_TABLE;
    CHECK_INT(ns_tables_get(test_context(), &key, &t, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "render.tables");
    key = key_of(0.7f, 0.8f, 0.9f, 0.97f, (ns_tables_mode)7);
    CHECK_INT(ns_tables_get(test_context(), &key, &t, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "render.tables");
}

/* Key's tables from a fresh context whose nodes live in dir: a copy, and whether the networks
 * ran. */
static float *from_context_with(const char *dir, uint64_t dir_bytes, const ns_table_key *key,
                                int *reconstructed)
{
    ns_context *ctx = NULL;
    ns_error err = {0};
    int status = ns_context_create(&(ns_context_desc){.table_node_dir = dir, .table_dir_bytes = dir_bytes},
                                   &ctx, &err);
    CHECK_INT(status, NS_OK);
    if (status)
        return NULL;
    const ns_scatter_tables *t = NULL;
    ns_table_stats stats;
    status = ns_tables_get(ctx, key, &t, &stats, &err);
    CHECK_INT(status, NS_OK);
    float *copy = NULL;
    if (!status) {
        copy = malloc(3 * cells * sizeof(float));
        int read = copy ? ns_scatter_tables_read(ctx, t, copy, &err) : NS_ERR_OUT_OF_HOST_MEMORY;
        CHECK_INT(read, NS_OK);
        if (read) {
            free(copy);
            copy = NULL;
        }
        *reconstructed = stats.reconstructed;
    }
    ns_context_destroy(ctx);
    return copy;
}

/* Nodes made again in other batches of three: a walk stops when all three channels it
 * carries meet the accumulation's cut (1e-4 of each), so a node's A depends on its batch
 * within that, not bit for bit. */
static int same_within_cut(const float *a, const float *b)
{
    for (int c = 0; c < 3; c++) {
        double ratio, l1 = channel_l1(b, a, c, &ratio);
        if (!(l1 < 2e-4))
            return 0;
    }
    return 1;
}

/* The files in dir whose names start with prefix, in name order (up to cap). */
static int list_files(const char *dir, const char *prefix, char names[][512], int cap)
{
    int n = 0;
    char command[600];
    snprintf(command, sizeof command, "ls %s", dir);
    FILE *p = popen(command, "r");
    while (p && n < cap && fgets(names[n], 512, p)) {
        names[n][strcspn(names[n], "\n")] = 0;
        n += strncmp(names[n], prefix, strlen(prefix)) == 0;
    }
    if (p)
        pclose(p);
    return n;
}

/* Changes the byte at offset of the file at path by xor with mask. */
static void flip_bits(const char *path, long offset, int mask)
{
    FILE *f = fopen(path, "r+b");
    CHECK(f != NULL);
    if (!f)
        return;
    fseek(f, offset, SEEK_SET);
    int c = fgetc(f);
    fseek(f, offset, SEEK_SET);
    fputc(c ^ mask, f);
    fclose(f);
}

/* The inode of dir/name: a file rewritten (atomically, by rename) gets a new one. */
static ino_t inode_of(const char *dir, const char *name)
{
    char path[1100];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    struct stat st;
    return stat(path, &st) == 0 ? st.st_ino : 0;
}

/* Bytes of the table files in dir. */
static uint64_t table_file_bytes(const char *dir)
{
    char names[64][512];
    uint64_t total = 0;
    int n = list_files(dir, "node_", names, 64);
    for (int i = 0; i < n; i++) {
        char path[1100];
        snprintf(path, sizeof path, "%.500s/%.500s", dir, names[i]);
        struct stat st;
        total += stat(path, &st) == 0 ? (uint64_t)st.st_size : 0;
    }
    return total;
}

static void test_nodes_on_disk(void)
{
    char dir[] = "/tmp/nscatter_nodes_XXXXXX";
    CHECK(mkdtemp(dir) != NULL);
    /* One albedo in every channel: four nodes (3-6 at g 0.6), two batches. The paper's
     * accumulation, whose
     * walks are short: what is stored and read is the same for both (the mode is part of
     * each file's name), and the exact one's nodes are held to the exact tables above; with
     * it this test took 41 s of the suite's time, 31 s now (alone, 2026-11-30). */
    ns_table_key key = key_of(0.6f, 0.9f, 0.9f, 0.9f, NS_TABLES_INTERPOLATED);
    key.accumulation = NS_ACCUMULATION_PAPER;
    int reconstructed = -1;
    float *made = from_context_with(dir, 0, &key, &reconstructed);
    CHECK_INT(reconstructed, 1);
    char names[8][512];
    CHECK_INT(list_files(dir, "node_", names, 8), 4);
    CHECK(strstr(names[0], "paper") != NULL);
    ino_t inode = inode_of(dir, names[0]);
    CHECK(inode != 0);

    /* Read, not made again: no reconstruction, and the files are not rewritten (they would
     * be, with a new inode, had they been made). */
    float *read = from_context_with(dir, 0, &key, &reconstructed);
    CHECK_INT(reconstructed, 0);
    CHECK(made && read && memcmp(made, read, 3 * cells * sizeof(float)) == 0);
    CHECK(inode_of(dir, names[0]) == inode);
    free(read);
    /* render.tables "auto" in a new context blends where the nodes are on disk, from the
     * first material at their g: the same table, no reconstruction. */
    ns_table_key automatic = key;
    automatic.tables = NS_TABLES_AUTO;
    read = from_context_with(dir, 0, &automatic, &reconstructed);
    CHECK_INT(reconstructed, 0);
    CHECK(made && read && memcmp(made, read, 3 * cells * sizeof(float)) == 0);
    free(read);

    /* One byte of one file's data changed, another file cut short: both made again. */
    char path[1100];
    snprintf(path, sizeof path, "%s/%s", dir, names[0]);
    flip_bits(path, 5000000, 0x10);
    snprintf(path, sizeof path, "%s/%s", dir, names[1]);
    CHECK_INT(truncate(path, 1000000), 0);
    /* A third made by another version of the code (its code hash, after the magic). */
    snprintf(path, sizeof path, "%s/%s", dir, names[3]);
    flip_bits(path, 8, 0x01);
    read = from_context_with(dir, 0, &key, &reconstructed);
    CHECK_INT(reconstructed, 1);
    CHECK(made && read && same_within_cut(made, read));
    free(read);
    ino_t rewritten = inode_of(dir, names[0]);
    CHECK(rewritten != 0 && rewritten != inode);
    read = from_context_with(dir, 0, &key, &reconstructed); /* all rewritten */
    CHECK_INT(reconstructed, 0);
    CHECK(inode_of(dir, names[0]) == rewritten);
    free(read);

    /* A bound on the folder below what is there: the least recently used files go when the
     * context starts, and what it makes next keeps the folder within the bound. */
    uint64_t bound = 50000000;
    CHECK(table_file_bytes(dir) > bound);
    read = from_context_with(dir, bound, &key, &reconstructed);
    CHECK(made && read && same_within_cut(made, read));
    CHECK(table_file_bytes(dir) <= bound);
    free(read);

    /* A folder that cannot be made (under a regular file): the table all the same (the
     * exact path's: one walk instead of two batches). */
    char blocked[1100];
    snprintf(blocked, sizeof blocked, "%s/%s/sub", dir, names[2]);
    ns_table_key exact = key;
    exact.tables = NS_TABLES_EXACT;
    read = from_context_with(blocked, 0, &exact, &reconstructed);
    CHECK_INT(reconstructed, 1);
    if (made && read) {
        double ratio;
        CHECK(channel_l1(read, made, 0, &ratio) < 0.01);
    }
    free(read);
    free(made);
    char command[600];
    snprintf(command, sizeof command, "rm -rf %s", dir);
    CHECK_INT(system(command), 0);
}

/* Sets *flag once the context has device buffers of a call in flight (its build has begun),
 * or after 20 s: a render that arrives while the idle work walks. */
typedef struct {
    ns_context *ctx;
    int flag;
} stop_when_busy;

static void *stop_when_busy_main(void *arg)
{
    stop_when_busy *s = arg;
    for (int ms = 0; ms < 20000 && ns_context_live_buffers(s->ctx) == 0; ms++)
        usleep(1000);
    __atomic_store_n(&s->flag, 1, __ATOMIC_RELEASE);
    return NULL;
}

/* ns_context_idle_work, in a context of its own with a table folder: nothing to do before
 * any material and after one; after a second albedo at its g, a call stopped while it walks
 * returns NS_ERR_CANCELLED and keeps nothing, in the cache or the folder; then calls of at
 * most three nodes until one makes none: the nodes both blends read and one more on each
 * side; a third albedo between them is then a blend without a reconstruction, where auto
 * alone would have made its exact tables (two materials, not four). */
static void test_idle_work(void)
{
    char dir[] = "/tmp/nscatter_idle_XXXXXX";
    CHECK(mkdtemp(dir) != NULL);
    ns_context *ctx = NULL;
    ns_error err = {0};
    CHECK_INT(ns_context_create(&(ns_context_desc){.table_node_dir = dir}, &ctx, &err), NS_OK);
    if (!ctx)
        return;
    uint32_t made = 99;
    CHECK_INT(ns_context_idle_work(NULL, NULL, &made, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "context");
    CHECK_INT(ns_context_idle_work(ctx, NULL, NULL, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "made");
    CHECK_INT(ns_context_idle_work(ctx, NULL, &made, &err), NS_OK);
    CHECK_INT(made, 0); /* nothing rendered yet */
    ns_table_stats stats;
    CHECK_INT(auto_chose(ctx, key_of(0.3f, 0.9f, 0.9f, 0.9f, NS_TABLES_AUTO), NS_TABLES_EXACT, &stats), 1);
    CHECK_INT(ns_context_idle_work(ctx, NULL, &made, &err), NS_OK);
    CHECK_INT(made, 0); /* one material: not a sweep */
    CHECK_INT(auto_chose(ctx, key_of(0.3f, 0.92f, 0.92f, 0.92f, NS_TABLES_AUTO), NS_TABLES_EXACT, &stats), 1);

    uint64_t bytes = ns_context_table_cache_bytes(ctx);
    /* Without room in the cache for a batch, nothing: idle work never evicts. */
    uint64_t bound = ctx->table_cache_bytes;
    ctx->table_cache_bytes = bytes + (1u << 20);
    CHECK_INT(ns_context_idle_work(ctx, NULL, &made, &err), NS_OK);
    CHECK_INT(made, 0);
    CHECK(ns_context_table_cache_bytes(ctx) == bytes);
    ctx->table_cache_bytes = bound;
    stop_when_busy stop = {.ctx = ctx};
    pthread_t thread;
    CHECK_INT(pthread_create(&thread, NULL, stop_when_busy_main, &stop), 0);
    CHECK_INT(ns_context_idle_work(ctx, &stop.flag, &made, &err), NS_ERR_CANCELLED);
    pthread_join(thread, NULL);
    CHECK_STR_CONTAINS(err.message, "cancelled");
    CHECK_INT(made, 0);
    CHECK(ns_context_table_cache_bytes(ctx) == bytes);
    char names[NS_TABLE_ALBEDO_NODES + 1][512];
    CHECK_INT(list_files(dir, "node_", names, NS_TABLE_ALBEDO_NODES + 1), 0);
    CHECK_INT(ns_context_live_buffers(ctx), 0);

    /* The nodes sit at u = -ln(1 - albedo) = 0.4934 i (albedo_max 0.999, 14 intervals):
     * 0.9 blends nodes 3-6, 0.92 nodes 4-7, so nodes 2-8 are made, in three calls, those
     * the blends read first: the first call makes nodes 3, 4 and 5. */
    uint32_t total = 0, calls = 0;
    for (; calls < NS_TABLE_ALBEDO_NODES; calls++) {
        CHECK_INT(ns_context_idle_work(ctx, NULL, &made, &err), NS_OK);
        if (made == 0)
            break;
        CHECK(made <= 3);
        total += made;
        if (calls == 0) {
            int n = list_files(dir, "node_", names, NS_TABLE_ALBEDO_NODES + 1);
            CHECK_INT(n, 3);
            for (int k = 0; k < n && k < 3; k++) {
                char want[16];
                snprintf(want, sizeof want, "_%02d.bin", 3 + k);
                CHECK_STR_CONTAINS(names[k], want);
            }
        }
    }
    printf("  idle work: %u nodes in %u calls\n", total, calls);
    CHECK_INT(total, 7);
    CHECK_INT(calls, 3);
    CHECK(ns_context_table_cache_bytes(ctx) > bytes); /* kept in the cache */
    CHECK_INT(list_files(dir, "node_", names, NS_TABLE_ALBEDO_NODES + 1), 7); /* and the folder */

    CHECK_INT(auto_chose(ctx, key_of(0.3f, 0.91f, 0.91f, 0.91f, NS_TABLES_AUTO), NS_TABLES_INTERPOLATED,
                         &stats), 1);
    CHECK_INT(stats.reconstructed, 0);
    ns_context_destroy(ctx);
    char command[100];
    snprintf(command, sizeof command, "rm -rf %s", dir);
    CHECK_INT(system(command), 0);
}

int main(void)
{
    ns_table_grid grid;
    ns_table_grid_default(&grid);
    cell_volume = malloc(cells * sizeof(double));
    for (size_t i = 0; i < cells; i++) {
        size_t t = (i / NS_TABLE_NPHI) % NS_TABLE_NTHETA;
        size_t r = (i / (NS_TABLE_NPHI * NS_TABLE_NTHETA)) % NS_TABLE_NRHO;
        size_t z = i / (NS_TABLE_NPHI * NS_TABLE_NTHETA * NS_TABLE_NRHO);
        cell_volume[i] = (grid.rho[r + 1] * grid.rho[r + 1] - grid.rho[r] * grid.rho[r]) *
                         (grid.z[z + 1] - grid.z[z]) * (cos(grid.theta[t]) - cos(grid.theta[t + 1]));
    }
    /* Room for every node and table the tests make: an eviction would make test_render's
     * nodes again. */
    test_context()->table_cache_bytes = 4ull << 30;
    RUN(test_off_the_nodes);
    RUN(test_cached_nodes_make_a_blend);
    RUN(test_uncached_mappings);
    RUN(test_at_nodes_and_beyond);
    RUN(test_render);
    RUN(test_nodes_on_disk);
    RUN(test_auto);
    RUN(test_idle_work);
    RUN(test_bad_keys);
    ns_context_destroy(test_context());
    free(cell_volume);
    return harness_report();
}
