/* unit_nn_train_cli.c — `nscatter train` end to end on a tiny synthetic grid (weights and
 * JSON written, a held-out material kept out, checkpoint and --resume), and the argument
 * errors of `nscatter train` and `nscatter table`, which must name the argument. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "table_io.h"
#include "commands.h"
#include "harness.h"
#include "nn_weights.h"
#include "train.h"

static char dir[256];

/* A small table whose J falls off with distance and angle, like a real one. */
static void write_table(double g, double a, ns_order order)
{
    const uint32_t n[4] = {8, 6, 3, 3};
    ns_table t;
    CHECK_INT(ns_table_create(&t, n, NULL), 0);
    for (uint32_t i = 0; i <= n[0]; i++)
        t.edges[NS_AXIS_Z][i] = -20.0 + 5.0 * i;
    for (uint32_t i = 0; i <= n[1]; i++)
        t.edges[NS_AXIS_RHO][i] = 20.0 * i / n[1];
    for (uint32_t i = 0; i <= n[2]; i++)
        t.edges[NS_AXIS_THETA][i] = M_PI * i / n[2];
    for (uint32_t i = 0; i <= n[3]; i++)
        t.edges[NS_AXIS_PHI][i] = M_PI * i / n[3];
    for (uint32_t iz = 0; iz < n[0]; iz++)
        for (uint32_t ir = 0; ir < n[1]; ir++)
            for (uint32_t it = 0; it < n[2]; it++)
                for (uint32_t ip = 0; ip < n[3]; ip++)
                    t.data[ns_table_index(&t, iz, ir, it, ip)] =
                        (float)(a * a * exp(-0.1 * (iz + ir)) * (1 + g * it) / (1 + ip));
    t.order = order;
    t.g = g;
    t.albedo = a;
    snprintf(t.source, sizeof t.source, "mc");
    t.energy_expected = order == NS_ORDER_DOUBLE ? a * a : a * a * a / (1 - a);
    t.energy_captured = ns_table_energy(&t);
    char prefix[512];
    snprintf(prefix, sizeof prefix, "%s/g%.2f_a%.3f_%s", dir, g, a, ns_order_name(order));
    ns_error err = {0};
    CHECK_INT(ns_table_write(&t, prefix, &err), 0);
    ns_table_free(&t);
}

static int run(int (*cmd)(int, char **), const char *const *args)
{
    char *argv[32];
    int argc = 0;
    for (; args[argc]; argc++)
        argv[argc] = (char *)args[argc];
    argv[argc] = NULL;
    return cmd(argc, argv);
}

static char *read_text(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    static char buf[8192];
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    buf[n] = 0;
    fclose(f);
    return buf;
}

static void test_train_and_resume(void)
{
    /* g 0.3 / a 0.8 is one of the default held-out materials. */
    write_table(0.1, 0.5, NS_ORDER_DOUBLE);
    write_table(0.1, 0.9, NS_ORDER_DOUBLE);
    write_table(0.3, 0.8, NS_ORDER_DOUBLE);
    char out[300], json[320], bin[320];
    snprintf(out, sizeof out, "%s/w", dir);
    snprintf(json, sizeof json, "%s/double.json", out);
    snprintf(bin, sizeof bin, "%s/double.bin", out);
    const char *args[] = {"train",     "--data",  dir,        "--order", "double",
                          "--out-dir", out,       "--epochs", "2",       "--samples-per-table",
                          "400",       "--batch", "64",       "--quiet", NULL};
    CHECK_INT(run(cmd_train, args), 0);
    ns_nn_weights w;
    ns_error err = {0};
    CHECK_INT(ns_nn_weights_load(bin, &w, &err), 0);
    CHECK_NEAR(w.h.extent, 20.0, 1e-6); /* read from the tables */
    const char *text = read_text(json);
    CHECK_STR_CONTAINS(text, "\"epochs\": 2,");
    CHECK_STR_CONTAINS(text, "\"train_materials\": 2");
    CHECK_STR_CONTAINS(text, "\"test_materials\": 1");
    CHECK_STR_CONTAINS(text, "\"command\": \"nscatter train --data");

    const char *resume[] = {"train",     "--data",  dir,        "--order", "double",
                            "--out-dir", out,       "--epochs", "3",       "--samples-per-table",
                            "400",       "--batch", "64",       "--quiet", "--resume",
                            NULL};
    CHECK_INT(run(cmd_train, resume), 0);
    text = read_text(json);
    CHECK_STR_CONTAINS(text, "\"epochs\": 3,");
    CHECK_STR_CONTAINS(text, "\"zero_floor\": 10,");
    ns_nn_weights resumed;
    CHECK_INT(ns_nn_weights_load(bin, &resumed, &err), 0);

    /* The decode floor: the same training (resumed at its last epoch, nothing more to run)
     * written with --zero-floor 1 keeps a tenth of the default's eps, all else equal. */
    const char *floor1[] = {"train",     "--data",  dir,        "--order",      "double",
                            "--out-dir", out,       "--epochs", "3",            "--samples-per-table",
                            "400",       "--batch", "64",       "--zero-floor", "1",
                            "--quiet",   "--resume", NULL};
    CHECK_INT(run(cmd_train, floor1), 0);
    ns_nn_weights unfloored;
    CHECK_INT(ns_nn_weights_load(bin, &unfloored, &err), 0);
    CHECK_NEAR(resumed.h.target_eps / unfloored.h.target_eps, 10.0, 1e-4);
    CHECK(resumed.h.target_mean == unfloored.h.target_mean);
    CHECK(!memcmp(resumed.p, unfloored.p, sizeof resumed.p));

    /* Oversampling: the tables with albedo >= 0.9 give 3x the samples (400 + 3 x 400). */
    const char *oversampled[] = {"train",     "--data",  dir,        "--order", "double",
                                 "--out-dir", out,       "--epochs", "1",       "--samples-per-table",
                                 "400",       "--batch", "64",       "--oversample-albedo", "0.9:3",
                                 "--quiet",   NULL};
    CHECK_INT(run(cmd_train, oversampled), 0);
    text = read_text(json);
    CHECK_STR_CONTAINS(text, "\"train_samples\": 1600,");
    CHECK_STR_CONTAINS(text, "\"oversample_factor\": 3,");

    /* Near-field samples: 100 more per table (x3 where oversampled) from the cells whose
     * centre lies within R of the source: 400 + 1200 + 100 + 300. The nearest centre is 3.0
     * away (z 2.5, rho 1.67), so R = 2 has none to draw from and adds nothing. */
    const char *near[] = {"train",     "--data",  dir,        "--order", "double",
                          "--out-dir", out,       "--epochs", "1",       "--samples-per-table",
                          "400",       "--batch", "64",       "--oversample-albedo", "0.9:3",
                          "--near-samples", "8:100", "--quiet", NULL};
    CHECK_INT(run(cmd_train, near), 0);
    text = read_text(json);
    CHECK_STR_CONTAINS(text, "\"train_samples\": 2000,");
    CHECK_STR_CONTAINS(text, "\"near_samples_per_table\": 100, \"near_radius\": 8,");
    near[16] = "2:100";
    CHECK_INT(run(cmd_train, near), 0);
    text = read_text(json);
    CHECK_STR_CONTAINS(text, "\"train_samples\": 1600,");

    /* --g-map log: input map 2 in the header and the JSON; a checkpoint of map 1 is not
     * resumed into it (the inputs would mean something else). */
    const char *logg[] = {"train",     "--data",  dir,        "--order",  "double",
                          "--out-dir", out,       "--epochs", "1",        "--samples-per-table",
                          "400",       "--batch", "64",       "--g-map",  "log",
                          "--quiet",   "--resume", NULL};
    CHECK_INT(run(cmd_train, logg), 0);
    ns_nn_weights mapped;
    CHECK_INT(ns_nn_weights_load(bin, &mapped, &err), 0);
    CHECK_INT(mapped.h.input_map, NS_NN_INPUT_MAP_ASINH_LOGG);
    CHECK(mapped.h.g_max < 1);
    text = read_text(json);
    CHECK_STR_CONTAINS(text, "\"input_map\": 2,");
    CHECK_STR_CONTAINS(text, "ln(1-g)");
    /* Started afresh, not from the map-1 checkpoint (at epoch 1 too, so resuming it would have
     * trained nothing): the same as a run without --resume, bit for bit. */
    logg[16] = NULL;
    CHECK_INT(run(cmd_train, logg), 0);
    ns_nn_weights fresh;
    CHECK_INT(ns_nn_weights_load(bin, &fresh, &err), 0);
    CHECK(!memcmp(mapped.p, fresh.p, sizeof fresh.p));
}

/* The decoded J of w at a few inputs, relative to `base` (the same inputs): the largest
 * |ln(J_w / J_base)|. */
static double largest_log_ratio(const ns_nn_weights *w, const ns_nn_weights *base)
{
    double worst = 0;
    for (int i = 0; i < 64; i++) {
        float x[NS_NN_INPUTS];
        for (int k = 0; k < NS_NN_INPUTS; k++)
            x[k] = (float)((i * (k + 3) % 17) / 16.0);
        double a = ns_nn_output_to_j(&w->h, ns_nn_forward(w, x), 1.0);
        double b = ns_nn_output_to_j(&base->h, ns_nn_forward(base, x), 1.0);
        if (a > 1e-9 && b > 1e-9)
            worst = fmax(worst, fabs(log(a / b)));
    }
    return worst;
}

/* --init: a fine tuning starts from the given weights. At the smallest learning rate it
 * keeps their answers, also when its samples (here with near-field ones) standardise the
 * targets with another mean and scale than the weights were trained with: the targets are
 * re-expressed in the weights' standardisation (without that the decoded J moved here by
 * e^0.12, with it by e^0.007). Runs on the tables test_train_and_resume wrote. */
static void test_init_from_weights(void)
{
    char out[300], tuned[300], bin[340], tuned_bin[340];
    snprintf(out, sizeof out, "%s/w_init", dir);
    snprintf(tuned, sizeof tuned, "%s/w_tuned", dir);
    snprintf(bin, sizeof bin, "%s/double.bin", out);
    snprintf(tuned_bin, sizeof tuned_bin, "%s/double.bin", tuned);
    const char *args[] = {"train",     "--data",  dir,        "--order", "double",
                          "--out-dir", out,       "--epochs", "3",       "--samples-per-table",
                          "400",       "--batch", "64",       "--quiet", NULL};
    CHECK_INT(run(cmd_train, args), 0);
    const char *tune[] = {"train",     "--data",  dir,          "--order", "double",
                          "--out-dir", tuned,     "--epochs",   "1",       "--samples-per-table",
                          "400",       "--batch", "64",         "--lr",    "1e-7",
                          "--near-samples", "8:4000", "--init", out,       "--quiet", NULL};
    CHECK_INT(run(cmd_train, tune), 0);
    ns_nn_weights base, after;
    ns_error err = {0};
    CHECK_INT(ns_nn_weights_load(bin, &base, &err), 0);
    CHECK_INT(ns_nn_weights_load(tuned_bin, &after, &err), 0);
    double worst = largest_log_ratio(&after, &base);
    fprintf(stderr, "  fine tuning at lr 1e-7: decoded J within a factor e^%.2g; means %g -> %g\n",
            worst, base.h.target_mean, after.h.target_mean);
    CHECK(worst < 0.02);
    char tuned_json[340];
    snprintf(tuned_json, sizeof tuned_json, "%s/double.json", tuned);
    CHECK_STR_CONTAINS(read_text(tuned_json), "--init"); /* the command, as run */
    /* and what it started from: the base's epochs and command */
    CHECK_STR_CONTAINS(read_text(tuned_json), "\"initialised_from\": {\"file\": ");
    CHECK_STR_CONTAINS(read_text(tuned_json), "\"epochs\": 3, \"command\": \"nscatter train --data");

    /* Without the calibration the written mean is the one the base network was trained in:
     * its file's less the log of the calibration its JSON records, whatever the zero floor
     * (which only scales the decode eps). */
    const char *plain[] = {"train",     "--data",  dir,        "--order", "double",
                           "--out-dir", tuned,     "--epochs", "1",       "--samples-per-table",
                           "400",       "--batch", "64",       "--lr",    "1e-7",
                           "--no-calibrate", "--zero-floor", "20", "--init", out, "--quiet", NULL};
    CHECK_INT(run(cmd_train, plain), 0);
    char base_json[340];
    snprintf(base_json, sizeof base_json, "%s/double.json", out);
    const char *text = read_text(base_json), *at = strstr(text, "\"energy_calibration\": ");
    CHECK(at != NULL);
    double c0 = at ? atof(at + strlen("\"energy_calibration\": ")) : NAN;
    CHECK_INT(ns_nn_weights_load(tuned_bin, &after, &err), 0);
    CHECK_NEAR(after.h.target_mean, base.h.target_mean - log(c0), 1e-5);
    CHECK(after.h.target_scale == base.h.target_scale);
    CHECK_NEAR(after.h.target_eps, 20 * 1e-13, 1e-19);

    /* Weights of another target or g map, trained with another eps, or missing: refused. */
    const char *wrong_map[] = {"train",  "--data", dir, "--order", "double", "--out-dir", tuned,
                               "--init", out,      "--g-map", "log", "--quiet", NULL};
    CHECK_INT(run(cmd_train, wrong_map), 2);
    const char *wrong_target[] = {"train",  "--data", dir, "--order", "double", "--out-dir", tuned,
                                  "--init", out,      "--target", "paper", "--quiet", NULL};
    CHECK_INT(run(cmd_train, wrong_target), 2);
    const char *wrong_eps[] = {"train",  "--data", dir, "--order", "double", "--out-dir", tuned,
                               "--init", out,      "--eps", "1e-9", "--quiet", NULL};
    CHECK_INT(run(cmd_train, wrong_eps), 2);
    const char *missing[] = {"train",  "--data", dir, "--order", "double", "--out-dir", tuned,
                             "--init", "/nonexistent-nscatter-dir", "--quiet", NULL};
    CHECK_INT(run(cmd_train, missing), 2);
}

/* The centres of write_table's cells nearest the source (test_near_samples_are_near), and
 * the ring (0: rho bin 0, 1: rho bin 1) of the one within 8 of it that sample i of s sits at,
 * or -1 when it is at none. */
static const double rho_mid[2] = {10.0 / 6, 5.0}, z_mid[4] = {-7.5, -2.5, 2.5, 7.5};

static int near_ring(const ns_train_samples *s, uint32_t i)
{
    const float *x = s->x + (size_t)i * NS_NN_INPUTS;
    for (int r = 0; r < 2; r++)
        for (int k = 0; k < 4; k++) {
            float c[NS_NN_INPUTS];
            ns_nn_normalise(&s->h, rho_mid[r], z_mid[k], 0, 0, 0, 0, c);
            if (hypot(rho_mid[r], z_mid[k]) < 8 && fabsf(x[0] - c[0]) < 1e-6f &&
                fabsf(x[1] - c[1]) < 1e-6f)
                return r;
        }
    return -1;
}

/* The near-field samples themselves (through the loader `nscatter train` uses, on the tables
 * test_train_and_resume wrote: a = 0.5 and 0.9 trained, 0.8 held out). write_table's cells
 * are 5 long in z from -20 and 3.33 wide in rho; their centres within 8 of the source are
 * z = -2.5, 2.5 at rho 1.67 and 5, and z = -7.5, 7.5 at rho 1.67. Every near sample must be
 * one of those, in proportion to their energy (J e^{-0.1 (iz + ir)} times the ring volume,
 * the angular factor being the same in every spatial cell), and come after the regular ones. */
static void test_near_samples_are_near(void)
{
    ns_train_options o = ns_train_options_default();
    o.data = dir;
    o.samples_per_table = 400;
    o.oversample_albedo = 0.9;
    o.oversample_factor = 3;
    o.near_radius = 8;
    o.near_samples = 100;
    ns_train_samples s;
    CHECK_INT(ns_train_samples_load(&o, NS_ORDER_DOUBLE, &s), 0);
    CHECK_INT(s.regular, 1600);
    CHECK_INT(s.n, 2000);
    const int iz_of[4] = {2, 3, 4, 5};
    double weight[2] = {0, 0}; /* energy of the near cells with rho bin 0 and 1 */
    for (int r = 0; r < 2; r++)
        for (int k = 0; k < 4; k++)
            if (hypot(rho_mid[r], z_mid[k]) < 8)
                weight[r] += exp(-0.1 * (iz_of[k] + r)) * M_PI *
                             (pow(20.0 * (r + 1) / 6, 2) - pow(20.0 * r / 6, 2));
    uint32_t outer = 0, unmatched = 0, far_regular = 0;
    for (uint32_t i = 0; i < s.n; i++) {
        int ring = near_ring(&s, i);
        if (i >= s.regular) {
            unmatched += ring < 0;
            outer += ring == 1;
        } else
            far_regular += ring < 0;
    }
    CHECK_INT(unmatched, 0);
    CHECK(far_regular > 800); /* the regular ones cover the whole table */
    double p = weight[1] / (weight[0] + weight[1]), n = s.n - s.regular;
    printf("near samples in the outer ring: %u of %.0f, expected %.1f\n", outer, n, n * p);
    CHECK(fabs(outer - n * p) < 4 * sqrt(n * p * (1 - p)));
    ns_train_samples_free(&s);

    /* --near-uniform 1: every near sample uniform over the near cells, whatever their
     * energy: the outer ring has 2 of the 6 near spatial cells (z = +-2.5 at rho 5), each
     * with the same angular cells, so a third of the samples. */
    o.near_uniform = 1;
    CHECK_INT(ns_train_samples_load(&o, NS_ORDER_DOUBLE, &s), 0);
    CHECK_INT(s.n, 2000);
    outer = unmatched = 0;
    for (uint32_t i = s.regular; i < s.n; i++) {
        int ring = near_ring(&s, i);
        unmatched += ring < 0;
        outer += ring == 1;
    }
    CHECK_INT(unmatched, 0);
    p = 1.0 / 3;
    printf("uniform near samples in the outer ring: %u of %.0f, expected %.1f (by energy %.1f)\n",
           outer, n, n * p, n * weight[1] / (weight[0] + weight[1]));
    CHECK(fabs(outer - n * p) < 4 * sqrt(n * p * (1 - p)));
    ns_train_samples_free(&s);
}

static void test_argument_errors(void)
{
    const char *no_data[] = {"train", NULL};
    CHECK_INT(run(cmd_train, no_data), 2);
    const char *bad_epochs[] = {"train", "--data", dir, "--epochs", "-1", NULL};
    CHECK_INT(run(cmd_train, bad_epochs), 2);
    const char *empty[] = {"train", "--data", "/nonexistent-nscatter-dir", NULL};
    CHECK_INT(run(cmd_train, empty), 2);
    const char *bad_target[] = {"train", "--data", dir, "--target", "log", NULL};
    CHECK_INT(run(cmd_train, bad_target), 2);
    const char *bad_floor[] = {"train", "--data", dir, "--zero-floor", "0.5", NULL};
    CHECK_INT(run(cmd_train, bad_floor), 2);
    const char *bad_gmap[] = {"train", "--data", dir, "--g-map", "sqrt", NULL};
    CHECK_INT(run(cmd_train, bad_gmap), 2);
    const char *bad_oversample[][2] = {{"--oversample-albedo", "0.9"},
                                       {"--oversample-albedo", "0.9:0.5"},
                                       {"--oversample-albedo", "1.5:2"},
                                       {"--oversample-albedo", "0.9:2x"}};
    for (int i = 0; i < 4; i++) {
        const char *bad[] = {"train", "--data", dir, bad_oversample[i][0], bad_oversample[i][1], NULL};
        CHECK_INT(run(cmd_train, bad), 2);
    }
    const char *bad_near[] = {"0", "8", "8:-1", "8:1.5", "-2:10", "8:1e8", "x:10"};
    for (int i = 0; i < 7; i++) {
        const char *bad[] = {"train", "--data", dir, "--near-samples", bad_near[i], NULL};
        CHECK_INT(run(cmd_train, bad), 2);
    }
    const char *bad_uniform[] = {"-0.1", "1.5", "x", "nan"};
    for (int i = 0; i < 4; i++) {
        const char *bad[] = {"train", "--data", dir, "--near-samples", "6:100",
                             "--near-uniform", bad_uniform[i], NULL};
        CHECK_INT(run(cmd_train, bad), 2);
    }
    /* A share of near samples without any near samples, in a command that trains otherwise
     * (the same with --near-samples 8:100 runs). */
    char uniform_out[300];
    snprintf(uniform_out, sizeof uniform_out, "%s/w_uniform", dir);
    const char *uniform_alone[] = {"train", "--data", dir, "--order", "double", "--out-dir",
                                   uniform_out, "--epochs", "1", "--samples-per-table", "400",
                                   "--batch", "64", "--near-uniform", "0.5", "--quiet", NULL};
    CHECK_INT(run(cmd_train, uniform_alone), 2);
    /* A checkpoint folder that cannot be made is refused before any training. */
    char out[300];
    snprintf(out, sizeof out, "%s/w", dir);
    const char *bad_ckpt[] = {"train", "--data", dir, "--out-dir", out, "--checkpoint-dir",
                              "/proc/nscatter-no/ckpt", NULL};
    CHECK_INT(run(cmd_train, bad_ckpt), 2);
    const char *bad_g[] = {"table", "--source", "nn",  "--order", "double", "--g",
                           "1.5",   "--albedo", "0.5", "--out",   "/tmp/x", NULL};
    CHECK_INT(run(cmd_table, bad_g), 2);
    const char *bad_source[] = {"table", "--source", "nerf", NULL};
    CHECK_INT(run(cmd_table, bad_source), 2);
    const char *no_out[] = {"table", "--source", "nn",       "--order", "double",
                            "--g",   "0.5",      "--albedo", "0.5",     NULL};
    CHECK_INT(run(cmd_table, no_out), 2);
    /* --stride: four integers 1 to 16; --full-radius >= 0 (parsed before any device). */
    const char *bad_strides[][2] = {{"--stride", "2,2,2"},
                                    {"--stride", "0,1,1,1"},
                                    {"--stride", "1,1,1,17"},
                                    {"--stride", "1,1,1,1,1"},
                                    {"--full-radius", "-1"}};
    for (int i = 0; i < 5; i++) {
        const char *bad_sampling[] = {"table", "--benchmark", bad_strides[i][0], bad_strides[i][1],
                                      NULL};
        CHECK_INT(run(cmd_table, bad_sampling), 2);
    }
    char trunc[300];
    snprintf(trunc, sizeof trunc, "%s/trunc.bin", dir);
    FILE *f = fopen(trunc, "wb");
    fputs("NSNNWTS1", f);
    fclose(f);
    const char *bad_weights[] = {
        "table",    "--source", "nn",    "--order", "double",           "--g", "0.5",
        "--albedo", "0.5",      "--out", trunc,     "--weights-double", trunc, NULL};
    CHECK_INT(run(cmd_table, bad_weights), 2);
}

int main(void)
{
    snprintf(dir, sizeof dir, "/tmp/unit_nn_train_cli_%d", (int)getpid());
    mkdir(dir, 0755);
    RUN(test_train_and_resume);
    RUN(test_near_samples_are_near);
    RUN(test_init_from_weights);
    RUN(test_argument_errors);
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    if (system(cmd) != 0)
        fprintf(stderr, "warning: could not remove %s\n", dir);
    return harness_report();
}
