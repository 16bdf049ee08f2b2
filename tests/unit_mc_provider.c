/* unit_mc_provider.c — the Monte Carlo table provider of method "table" (offline/mc_provider.c)
 * at a tiny budget: where its cache directory comes from, that it computes both orders with
 * the exact energies (to Monte Carlo accuracy), serves them from disk the second time (the
 * same bytes), never trusts a damaged file (recomputes it, same bytes again: fixed seed), still
 * answers when the directory cannot be written, and refuses bad materials naming them. Also
 * that the renderer's default grid (render/scatter_tables.c) is offline/mc.c's. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "harness.h"
#include "mc.h"
#include "mc_provider.h"
#include "scatter.h"

static const size_t cells = (size_t)NS_TABLE_NZ * NS_TABLE_NRHO * NS_MC_NDIR;
static char root[256];

static ns_mc_provider *tiny_provider(const char *dir)
{
    ns_mc_provider *p = NULL;
    ns_error err = {0};
    ns_mc_provider_desc desc = {
        .cache_dir = dir, .collisions = 4e4, .lobe_in_samples = 1, .lobe_out_samples = 4};
    int status = ns_mc_provider_create(&desc, &p, &err);
    if (status)
        fprintf(stderr, "ns_mc_provider_create: %s\n", err.message);
    CHECK_INT(status, NS_OK);
    return p;
}

static double energy_of(const float *j)
{
    static const uint32_t n[NS_AXIS_COUNT] = {NS_TABLE_NZ, NS_TABLE_NRHO, NS_TABLE_NTHETA,
                                              NS_TABLE_NPHI};
    ns_table t;
    if (ns_table_create(&t, n, NULL))
        return NAN;
    ns_mc_default_edges(&t);
    memcpy(t.data, j, cells * sizeof(float));
    double e = ns_table_energy(&t);
    ns_table_free(&t);
    return e;
}

static int call(ns_mc_provider *p, double g, double albedo, float *jd, float *jm)
{
    ns_error err = {0};
    int status = ns_mc_provider_tables(p, g, albedo, jd, jm, &err);
    if (status)
        fprintf(stderr, "ns_mc_provider_tables: %s\n", err.message);
    return status;
}

static void test_default_grid_matches_offline(void)
{
    ns_table_grid grid;
    ns_table_grid_default(&grid);
    static const uint32_t n[NS_AXIS_COUNT] = {NS_TABLE_NZ, NS_TABLE_NRHO, NS_TABLE_NTHETA,
                                              NS_TABLE_NPHI};
    ns_table t;
    if (ns_table_create(&t, n, NULL))
        return;
    ns_mc_default_edges(&t);
    const double *mine[NS_AXIS_COUNT] = {grid.z, grid.rho, grid.theta, grid.phi};
    int differ = 0;
    for (int a = 0; a < NS_AXIS_COUNT; a++)
        for (uint32_t i = 0; i <= n[a]; i++)
            differ += fabs(mine[a][i] - t.edges[a][i]) > 1e-12 * fmax(1.0, fabs(t.edges[a][i]));
    CHECK_INT(differ, 0);
    CHECK_INT(NS_TABLE_CELLS, cells);
    CHECK_NEAR(grid.extent, NS_TABLE_EXTENT, 0);
    CHECK_NEAR(grid.scale, NS_TABLE_SINH_SCALE, 0);
    ns_table_free(&t);
}

static void expect_dir(const char *want)
{
    ns_mc_provider *p = NULL;
    ns_error err = {0};
    CHECK_INT(ns_mc_provider_create(NULL, &p, &err), NS_OK);
    if (p)
        CHECK_STR_CONTAINS(ns_mc_provider_dir(p), want);
    if (p)
        CHECK_INT(strlen(ns_mc_provider_dir(p)), strlen(want));
    ns_mc_provider_destroy(p);
}

static void test_cache_directory_from_environment(void)
{
    char *saved[3];
    const char *names[3] = {"NSCATTER_CACHE_DIR", "XDG_CACHE_HOME", "HOME"};
    for (int i = 0; i < 3; i++) {
        const char *v = getenv(names[i]);
        saved[i] = v ? strdup(v) : NULL;
    }
    setenv("NSCATTER_CACHE_DIR", "/x/mine", 1);
    setenv("XDG_CACHE_HOME", "/x/xdg", 1);
    setenv("HOME", "/x/home", 1);
    expect_dir("/x/mine");
    unsetenv("NSCATTER_CACHE_DIR");
    expect_dir("/x/xdg/nscatter");
    unsetenv("XDG_CACHE_HOME");
    expect_dir("/x/home/.cache/nscatter");
    unsetenv("HOME");
    ns_mc_provider *p = NULL;
    ns_error err = {0};
    CHECK_INT(ns_mc_provider_create(NULL, &p, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "NSCATTER_CACHE_DIR");
    for (int i = 0; i < 3; i++) {
        if (saved[i])
            setenv(names[i], saved[i], 1);
        free(saved[i]);
    }
}

static void corrupt_npy(const char *path)
{
    FILE *f = fopen(path, "r+b");
    CHECK(f != NULL);
    if (!f)
        return;
    /* A value well inside the data (past the header) changes: 1e3 where the light is. */
    float v = 1e3f;
    fseek(f, -(long)(cells / 3 * sizeof(float)), SEEK_END);
    fwrite(&v, sizeof v, 1, f);
    fclose(f);
}

static void test_compute_cache_and_distrust(void)
{
    char dir[512];
    snprintf(dir, sizeof dir, "%s/nested/cache", root); /* parents made on first write */
    ns_mc_provider *p = tiny_provider(dir);
    if (!p)
        return;
    float *jd = malloc(cells * sizeof(float)), *jm = malloc(cells * sizeof(float));
    float *jd2 = malloc(cells * sizeof(float)), *jm2 = malloc(cells * sizeof(float));
    double g = 0.3, a = 0.6;
    ns_mc_provider_counts n;
    CHECK_INT(call(p, g, a, jd, jm), NS_OK);
    ns_mc_provider_get_counts(p, &n);
    CHECK_INT(n.simulations, 2);
    /* E_double = a^2, E_multiple = a^3 / (1 - a); ~1e4 photons: a few percent. */
    CHECK_REL(energy_of(jd), a * a, 0.05);
    CHECK_REL(energy_of(jm), a * a * a / (1 - a), 0.05);

    CHECK_INT(call(p, g, a, jd2, jm2), NS_OK);
    ns_mc_provider_get_counts(p, &n);
    CHECK_INT(n.simulations, 2);
    CHECK_INT(n.files_read, 2);
    CHECK(memcmp(jd, jd2, cells * sizeof(float)) == 0 &&
          memcmp(jm, jm2, cells * sizeof(float)) == 0);

    char path[1024];
    snprintf(path, sizeof path, "%s/mc_g0.29999999999999999_a0.59999999999999998_double.npy", dir);
    struct stat st;
    CHECK(stat(path, &st) == 0);
    corrupt_npy(path);
    /* A new provider (a new process): nothing remembered, the damaged file is traced again. */
    ns_mc_provider_destroy(p);
    p = tiny_provider(dir);
    if (!p)
        return;
    CHECK_INT(call(p, g, a, jd2, jm2), NS_OK);
    ns_mc_provider_get_counts(p, &n);
    CHECK_INT(n.files_rejected, 1);
    CHECK_INT(n.simulations, 1);
    CHECK(memcmp(jd, jd2, cells * sizeof(float)) == 0); /* fixed seed: the same table */

    snprintf(path, sizeof path, "%s/mc_g0.29999999999999999_a0.59999999999999998_multiple.json",
             dir);
    FILE *f = fopen(path, "w");
    if (f) {
        fputs("{\"quantity\": \"J\", \"order\": \"mul", f); /* cut short */
        fclose(f);
    }
    CHECK_INT(call(p, g, a, jd2, jm2), NS_OK);
    ns_mc_provider_get_counts(p, &n);
    CHECK_INT(n.files_rejected, 2);
    CHECK_INT(n.simulations, 2);
    CHECK(memcmp(jm, jm2, cells * sizeof(float)) == 0);

    /* Another albedo of the same g: its double table is the first one times (a / a0)^2,
     * without a simulation; only the multiple table is traced. */
    double a2 = 0.5;
    CHECK_INT(call(p, g, a2, jd2, jm2), NS_OK);
    ns_mc_provider_get_counts(p, &n);
    CHECK_INT(n.simulations, 3);
    CHECK_INT(n.doubles_rescaled, 1);
    int off = 0;
    float k = (float)((a2 * a2) / (a * a));
    for (size_t i = 0; i < cells; i++)
        off += fabsf(jd2[i] - jd[i] * k) > 1e-6f * jd[i] * k;
    CHECK_INT(off, 0);
    CHECK_REL(energy_of(jm2), a2 * a2 * a2 / (1 - a2), 0.05);
    float *again = malloc(cells * sizeof(float));
    CHECK_INT(call(p, g, a2, again, jm2), NS_OK); /* and it was written to the cache */
    ns_mc_provider_get_counts(p, &n);
    CHECK_INT(n.simulations, 3);
    CHECK(memcmp(again, jd2, cells * sizeof(float)) == 0);
    free(again);
    free(jd);
    free(jm);
    free(jd2);
    free(jm2);
    ns_mc_provider_destroy(p);
}

static void test_unwritable_directory_still_answers(void)
{
    char file[512], dir[600];
    snprintf(file, sizeof file, "%s/plain_file", root);
    FILE *f = fopen(file, "w");
    if (f)
        fclose(f);
    snprintf(dir, sizeof dir, "%s/below", file); /* a directory under a regular file */
    ns_mc_provider *p = tiny_provider(dir);
    if (!p)
        return;
    float *jd = malloc(cells * sizeof(float)), *jm = malloc(cells * sizeof(float));
    CHECK_INT(call(p, 0.0, 0.2, jd, jm), NS_OK);
    ns_mc_provider_counts n;
    ns_mc_provider_get_counts(p, &n);
    CHECK_INT(n.write_failures, 2);
    CHECK_REL(energy_of(jd), 0.04, 0.05);
    free(jd);
    free(jm);
    ns_mc_provider_destroy(p);
}

static void test_bad_material_refused(void)
{
    ns_mc_provider *p = tiny_provider(root);
    if (!p)
        return;
    float one[1];
    ns_error err = {0};
    CHECK_INT(ns_mc_provider_tables(p, 0.5, 1.0, one, one, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "albedo");
    CHECK_INT(ns_mc_provider_tables(p, 1.0, 0.5, one, one, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "g");
    ns_mc_provider_destroy(p);
}

int main(void)
{
    snprintf(root, sizeof root, "/tmp/nscatter_mc_provider_XXXXXX");
    if (!mkdtemp(root)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(test_default_grid_matches_offline);
    RUN(test_cache_directory_from_environment);
    RUN(test_compute_cache_and_distrust);
    RUN(test_unwritable_directory_still_answers);
    RUN(test_bad_material_refused);
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", root);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", root);
    return harness_report();
}
