/* unit_mc_cli.c — the real `nscatter mc` binary (NSCATTER_BIN, set by ctest): bad input
 * gets a one-line error naming the argument, exit status 2 and no complete-looking file;
 * a good run writes readable tables; the grid resumes. */
#include <stdlib.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "harness.h"
#include "mc.h"
#include "table_io.h"

static const char *bin;
static char dir[256];
/* The lobe matrix at low quality: these tests are about the command, not the physics. */
#define FAST "--lobe-in 1 --lobe-out 4 --threads 2"

/* Runs `nscatter mc ARGS`, returns the exit status and the captured stderr. */
static int run_mc(const char *args, char *err_text, size_t cap)
{
    char errfile[300], cmd[2048];
    snprintf(errfile, sizeof errfile, "%s/stderr.txt", dir);
    snprintf(cmd, sizeof cmd, "\"%s\" mc %s >/dev/null 2>\"%s\"", bin, args, errfile);
    int status = system(cmd);
    err_text[0] = '\0';
    FILE *f = fopen(errfile, "r");
    if (f) {
        size_t n = fread(err_text, 1, cap - 1, f);
        err_text[n] = '\0';
        fclose(f);
    }
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

static int count_lines(const char *text)
{
    int n = 0;
    for (; *text; text++)
        n += *text == '\n';
    return n;
}

static int exists(const char *prefix, const char *suffix)
{
    char path[512];
    snprintf(path, sizeof path, "%s%s", prefix, suffix);
    return access(path, F_OK) == 0;
}

static void expect_bad(const char *args, const char *argument_named)
{
    char prefix[300], full[1024], err[4096];
    snprintf(prefix, sizeof prefix, "%s/bad", dir);
    snprintf(full, sizeof full, "%s --out %s " FAST, args, prefix);
    int status = run_mc(full, err, sizeof err);
    if (status != 2 || !strstr(err, argument_named) || count_lines(err) != 1)
        fprintf(stderr, "  for `%s`: status %d, stderr: %s", args, status, err);
    CHECK_INT(status, 2);
    CHECK_STR_CONTAINS(err, argument_named);
    CHECK_INT(count_lines(err), 1);
    for (int o = 0; o < 2; o++) {
        char p[400];
        snprintf(p, sizeof p, "%s%s", prefix, o ? "_double" : "");
        CHECK(!exists(p, ".json") && !exists(p, ".npy"));
    }
}

static void test_bad_arguments(void)
{
    expect_bad("--order double --g 1 --albedo 0.5 --photons 100", "--g");
    expect_bad("--order double --g -1 --albedo 0.5 --photons 100", "--g");
    expect_bad("--order double --g nan --albedo 0.5 --photons 100", "--g");
    expect_bad("--order double --g 0.5x --albedo 0.5 --photons 100", "--g");
    expect_bad("--order double --g 0.5 --albedo 1 --photons 100", "--albedo");
    expect_bad("--order double --g 0.5 --albedo -0.01 --photons 100", "--albedo");
    expect_bad("--order double --g 0.5 --albedo 0.5 --photons 0", "--photons");
    expect_bad("--order double --g 0.5 --albedo 0.5 --photons -5", "--photons");
    expect_bad("--order double --g 0.5 --albedo 0.5 --photons 2.5", "--photons");
    expect_bad("--order double --g 0.5 --albedo 0.5", "--photons");
    expect_bad("--order triple --g 0.5 --albedo 0.5 --photons 100", "--order");
    expect_bad("--order double --g 0.5 --albedo 0.5 --photons 100 --frobnicate 3", "--frobnicate");
    expect_bad("--order double --g 0.5 --albedo 0.5 --photons 100 --threads 0", "--threads");
    expect_bad("--order both --g 0.5 --albedo 0.5 --photons 100 --seed -1", "--seed");
}

static void test_unwritable_output(void)
{
    char err[4096];
    int status = run_mc("--order double --g 0.5 --albedo 0.5 --photons 100 "
                        "--out /nonexistent-ns-dir/t " FAST, err, sizeof err);
    CHECK_INT(status, 2);
    CHECK_STR_CONTAINS(err, "--out");
    CHECK_INT(count_lines(err), 1);
    CHECK(!exists("/nonexistent-ns-dir/t", ".json"));
}

static void test_good_run(void)
{
    char prefix[300], args[1024], err[4096];
    snprintf(prefix, sizeof prefix, "%s/ok", dir);
    snprintf(args, sizeof args,
             "--order both --g 0.3 --albedo 0.6 --photons 3000 --seed 9 --out %s " FAST, prefix);
    CHECK_INT(run_mc(args, err, sizeof err), 0);
    for (int o = 0; o < 2; o++) {
        char p[400];
        snprintf(p, sizeof p, "%s_%s", prefix, o ? "multiple" : "double");
        CHECK(ns_table_is_complete(p));
        ns_table t;
        ns_error e = {0};
        CHECK(ns_table_read(p, &t, &e) == 0);
        if (!e.status) {
            CHECK_INT(t.order, o);
            CHECK(t.g == 0.3 && t.albedo == 0.6 && t.photons == 3000 && t.seed == 9);
            CHECK_REL(t.energy_expected, ns_mc_expected_energy((ns_order)o, 0.6), 1e-12);
            CHECK_REL(t.energy_captured, ns_table_energy(&t), 1e-5);
            CHECK_INT(t.n[0], NS_TABLE_NZ);
            CHECK_INT(t.n[3], NS_TABLE_NPHI);
            ns_table_free(&t);
        }
    }
    /* Same seed, same bytes, whatever the threads. */
    char again[300];
    snprintf(again, sizeof again, "%s/again", dir);
    snprintf(args, sizeof args,
             "--order both --g 0.3 --albedo 0.6 --photons 3000 --seed 9 --out %s "
             "--lobe-in 1 --lobe-out 4 --threads 1", again);
    CHECK_INT(run_mc(args, err, sizeof err), 0);
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "cmp -s %s_multiple.npy %s_multiple.npy && cmp -s %s_double.npy %s_double.npy",
             prefix, again, prefix, again);
    CHECK(system(cmd) == 0);
}

static void test_grid_resumes(void)
{
    char grid[300], args[1024], err[4096], path[512];
    snprintf(grid, sizeof grid, "%s/grid", dir);
    snprintf(args, sizeof args,
             "--grid --out %s --g-values 0.5 --albedo-values 0.3,0.9 --collisions 2e4 " FAST,
             grid);
    CHECK_INT(run_mc(args, err, sizeof err), 0);
    CHECK_STR_CONTAINS(err, "0 already complete, 4 to do");
    snprintf(path, sizeof path, "%s/g0.50_a0.900_multiple", grid);
    CHECK(ns_table_is_complete(path));
    ns_table t;
    ns_error e = {0};
    CHECK(ns_table_read(path, &t, &e) == 0);
    if (!e.status) {
        /* The budget is in collisions: 2e4 / (2 + 1/(1 - 0.9)) photons. */
        CHECK_INT(t.photons, 1666);
        ns_table_free(&t);
    }
    /* Killed after writing a .npy but before its .json: that table is redone, others kept. */
    snprintf(path, sizeof path, "%s/g0.50_a0.300_double.json", grid);
    CHECK(unlink(path) == 0);
    CHECK_INT(run_mc(args, err, sizeof err), 0);
    CHECK_STR_CONTAINS(err, "3 already complete, 1 to do");
    CHECK_INT(run_mc(args, err, sizeof err), 0);
    CHECK_STR_CONTAINS(err, "4 already complete, 0 to do");
    expect_bad("--grid --g-values 0.5,1.5", "--g-values");
    expect_bad("--grid --albedo-values 1", "--albedo-values");
}

int main(void)
{
    bin = getenv("NSCATTER_BIN");
    if (!bin) {
        fprintf(stderr, "NSCATTER_BIN is not set: run this test through ctest\n");
        return 1;
    }
    snprintf(dir, sizeof dir, "/tmp/ns_mc_cli_XXXXXX");
    if (!mkdtemp(dir))
        return 1;
    RUN(test_bad_arguments);
    RUN(test_unwritable_output);
    RUN(test_good_run);
    RUN(test_grid_resumes);
    char cmd[400];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", dir);
    return harness_report();
}
