/* unit_mc_table_io.c — the .npy + .json table format (DESIGN.md section 3): round trip,
 * the exact header numpy expects, the energy formula, and what counts as complete. */
#include <dirent.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

#include "harness.h"
#include "mc.h"
#include "table_io.h"

static char dir[256];

static void make_dir(void)
{
    snprintf(dir, sizeof dir, "/tmp/ns_table_io_XXXXXX");
    if (!mkdtemp(dir))
        perror("mkdtemp");
}

static void remove_prefix(const char *prefix)
{
    char path[512];
    static const char *const suffixes[] = {".npy", ".json", ".npy.part", ".json.part"};
    for (int i = 0; i < 4; i++) {
        snprintf(path, sizeof path, "%s%s", prefix, suffixes[i]);
        unlink(path);
    }
}

/* A small table with known values: J = 1 everywhere over a 2x3x2x2 grid. */
static int make_unit_table(ns_table *t)
{
    const uint32_t n[NS_AXIS_COUNT] = {2, 3, 2, 2};
    ns_error err;
    if (ns_table_create(t, n, &err))
        return -1;
    const double z[] = {-1.0, 0.0, 2.0}, rho[] = {0.0, 0.5, 1.0, 3.0};
    const double theta[] = {0.0, M_PI / 2, M_PI}, phi[] = {0.0, M_PI / 3, M_PI};
    memcpy(t->edges[NS_AXIS_Z], z, sizeof z);
    memcpy(t->edges[NS_AXIS_RHO], rho, sizeof rho);
    memcpy(t->edges[NS_AXIS_THETA], theta, sizeof theta);
    memcpy(t->edges[NS_AXIS_PHI], phi, sizeof phi);
    for (size_t i = 0; i < ns_table_size(t); i++)
        t->data[i] = 1.0f;
    t->order = NS_ORDER_MULTIPLE;
    t->g = 0.9;
    t->albedo = 0.995;
    t->photons = 123456789012ull;
    t->seed = 42;
    t->energy_expected = 0.995 * 0.995 * 0.995 / 0.005;
    return 0;
}

/* J = 1 over a cylinder of radius 3, height 3 and the whole sphere of directions holds
 * volume * 4 pi: the ring volumes and the factor 2 of the folded phi must add up to that. */
static void test_energy_formula(void)
{
    ns_table t;
    CHECK(make_unit_table(&t) == 0);
    CHECK_REL(ns_table_energy(&t), M_PI * 9.0 * 3.0 * 4.0 * M_PI, 1e-12);
    CHECK_REL(ns_table_bin_volume(&t, 1, 2), M_PI * (9.0 - 1.0) * 2.0, 1e-12);
    CHECK_REL(ns_table_bin_solid_angle(&t, 0, 1), 1.0 * (2.0 * M_PI / 3.0) * 2.0, 1e-12);
    ns_table_free(&t);
}

static void test_round_trip(void)
{
    ns_table t, back;
    CHECK(make_unit_table(&t) == 0);
    for (size_t i = 0; i < ns_table_size(&t); i++)
        t.data[i] = (float)i * 0.25f + 1e-30f;
    t.energy_captured = ns_table_energy(&t);
    char prefix[400];
    snprintf(prefix, sizeof prefix, "%s/roundtrip", dir);
    ns_error err = {0};
    CHECK(ns_table_write(&t, prefix, &err) == 0);
    CHECK(ns_table_is_complete(prefix));
    CHECK(ns_table_read(prefix, &back, &err) == 0);
    for (int a = 0; a < NS_AXIS_COUNT; a++) {
        CHECK_INT(back.n[a], t.n[a]);
        CHECK(memcmp(back.edges[a], t.edges[a], (t.n[a] + 1) * sizeof(double)) == 0);
    }
    CHECK(memcmp(back.data, t.data, ns_table_size(&t) * sizeof(float)) == 0);
    CHECK_INT(back.order, NS_ORDER_MULTIPLE);
    CHECK(back.g == t.g && back.albedo == t.albedo);
    CHECK(back.photons == t.photons && back.seed == t.seed);
    CHECK(back.energy_captured == t.energy_captured);
    CHECK(back.energy_expected == t.energy_expected);
    CHECK(!strcmp(back.source, "mc"));
    ns_table_free(&back);

    /* The .npy header numpy reads: magic, version 1.0, a dict padded to 64 bytes. */
    char path[512];
    snprintf(path, sizeof path, "%s.npy", prefix);
    FILE *f = fopen(path, "rb");
    char head[128] = {0};
    CHECK(f && fread(head, 1, 128, f) == 128);
    if (f)
        fclose(f);
    CHECK(memcmp(head, "\x93NUMPY\x01\x00", 8) == 0);
    size_t header_len = (unsigned char)head[8] | ((size_t)(unsigned char)head[9] << 8);
    CHECK_INT((10 + header_len) % 64, 0);
    CHECK_INT(head[10 + header_len - 1], '\n');
    CHECK_STR_CONTAINS(head + 10, "'descr': '<f4', 'fortran_order': False, 'shape': (2, 3, 2, 2)");
    struct stat st;
    CHECK(stat(path, &st) == 0 && (size_t)st.st_size == 10 + header_len + 24 * sizeof(float));
    /* No temporary file left behind (ns_write_file_atomic_parts names them NAME.tmp.XXXXXX). */
    DIR *d = opendir(dir);
    for (struct dirent *e; d && (e = readdir(d));)
        CHECK(!strstr(e->d_name, ".tmp."));
    if (d)
        closedir(d);
    ns_table_free(&t);
    remove_prefix(prefix);
}

/* Only a table whose .json is present and whose .npy has the announced size is complete:
 * that is what the grid's resume relies on. */
static void test_completeness(void)
{
    ns_table t;
    CHECK(make_unit_table(&t) == 0);
    char prefix[400], path[512];
    snprintf(prefix, sizeof prefix, "%s/complete", dir);
    ns_error err = {0};
    CHECK(!ns_table_is_complete(prefix));
    CHECK(ns_table_write(&t, prefix, &err) == 0);
    CHECK(ns_table_is_complete(prefix));

    /* A .npy without its .json (killed between the two renames) is not complete. */
    snprintf(path, sizeof path, "%s.json", prefix);
    CHECK(unlink(path) == 0);
    CHECK(!ns_table_is_complete(prefix));
    ns_table back;
    CHECK(ns_table_read(prefix, &back, &err) != 0);

    /* A truncated .npy is not complete, and reading it fails with its name. */
    CHECK(ns_table_write(&t, prefix, &err) == 0);
    snprintf(path, sizeof path, "%s.npy", prefix);
    CHECK(truncate(path, 100) == 0);
    CHECK(!ns_table_is_complete(prefix));
    CHECK(ns_table_read(prefix, &back, &err) != 0);
    CHECK_STR_CONTAINS(err.message, "complete.npy");

    /* A .json that disagrees with the .npy shape is rejected. */
    CHECK(ns_table_write(&t, prefix, &err) == 0);
    snprintf(path, sizeof path, "%s.json", prefix);
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    if (f) {
        fputs("{\"quantity\": \"J\", \"order\": \"double\", \"g\": 0, \"albedo\": 0.5, "
              "\"photons\": 1, \"seed\": 1, \"source\": \"mc\", \"axes\": {\"z\": [0, 1], "
              "\"rho\": [0, 1], \"theta\": [0, 3.14], \"phi\": [0, 3.14]}, "
              "\"energy_captured\": 0, \"energy_expected\": 0.25}\n", f);
        fclose(f);
    }
    CHECK(!ns_table_is_complete(prefix));
    CHECK(ns_table_read(prefix, &back, &err) != 0);
    CHECK_STR_CONTAINS(err.message, "disagrees");
    ns_table_free(&t);
    remove_prefix(prefix);
}

static void test_unwritable(void)
{
    ns_error err = {0};
    CHECK(ns_table_check_writable("/nonexistent-dir/table", &err) != 0);
    CHECK_STR_CONTAINS(err.message, "--out");
    ns_table t;
    CHECK(make_unit_table(&t) == 0);
    CHECK(ns_table_write(&t, "/nonexistent-dir/table", &err) != 0);
    ns_table_free(&t);
}

/* The default bins: increasing, symmetric in z, fine at the source, reaching the extent. */
static void test_default_edges(void)
{
    const uint32_t n[NS_AXIS_COUNT] = {NS_TABLE_NZ, NS_TABLE_NRHO, NS_TABLE_NTHETA, NS_TABLE_NPHI};
    ns_table t;
    ns_error err;
    CHECK(ns_table_create(&t, n, &err) == 0);
    ns_mc_default_edges(&t);
    const double *z = t.edges[NS_AXIS_Z], *rho = t.edges[NS_AXIS_RHO];
    CHECK_NEAR(z[0], -NS_TABLE_EXTENT, 1e-9);
    CHECK_NEAR(z[NS_TABLE_NZ], NS_TABLE_EXTENT, 1e-9);
    CHECK(z[NS_TABLE_NZ / 2] == 0.0 && rho[0] == 0.0);
    CHECK_NEAR(rho[NS_TABLE_NRHO], NS_TABLE_EXTENT, 1e-9);
    CHECK(rho[1] < 0.06); /* fine near the beam */
    CHECK(rho[NS_TABLE_NRHO] - rho[NS_TABLE_NRHO - 1] < 0.12 * NS_TABLE_EXTENT); /* ~11% far away */
    for (int i = 0; i < NS_TABLE_NZ; i++) {
        CHECK(z[i + 1] > z[i]);
        CHECK_NEAR(z[i], -z[NS_TABLE_NZ - i], 1e-9);
    }
    CHECK_NEAR(t.edges[NS_AXIS_THETA][NS_TABLE_NTHETA], M_PI, 1e-12);
    CHECK_NEAR(t.edges[NS_AXIS_PHI][NS_TABLE_NPHI], M_PI, 1e-12);
    CHECK(t.edges[NS_AXIS_THETA][1] <= 10.0 * M_PI / 180.0 + 1e-12);
    ns_table_free(&t);
}

int main(void)
{
    make_dir();
    RUN(test_energy_formula);
    RUN(test_round_trip);
    RUN(test_completeness);
    RUN(test_unwritable);
    RUN(test_default_edges);
    rmdir(dir);
    return harness_report();
}
