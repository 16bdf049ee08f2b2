/* cmd_train.c — `nscatter train`: the command line of offline/train.c (fits the double and
 * multiple scattering networks to the Monte Carlo grid, docs/network.md). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "args.h"
#include "commands.h"
#include "train.h"

static const char usage_text[] =
    "usage: nscatter train --data DIR [--order double|multiple|both] [--out-dir weights]\n"
    "                      [--target logrel|paper] [--epochs N (200)] [--batch B (8192)]\n"
    "                      [--lr L (0.003)] [--samples-per-table N (24000)] [--seed S]\n"
    "                      [--time-budget SECONDS] [--checkpoint-dir DIR] [--resume]\n"
    "                      [--eps E (logrel floor, 1e-13)] [--zero-floor F (10)]\n"
    "                      [--oversample-albedo A:F] [--near-samples R:N] [--near-uniform F]\n"
    "                      [--init DIR]\n"
    "                      [--g-map linear|log] [--no-calibrate]\n"
    "                      [--threads T] [--quiet]\n"
    "\n"
    "Trains the 6->50->50->1 tanh network on the tables DIR/g<G>_a<A>_<order>.* written by\n"
    "`nscatter mc --grid`; the materials g/a 0.3/0.8 0.5/0.95 0.7/0.5 0.9/0.9 0.0/0.3\n"
    "0.95/0.99 0.5/0.2 are held out as the test set. Writes OUT/<order>.bin (weights) and\n"
    "OUT/<order>.json (how they were made). A checkpoint is written every epoch to\n"
    "CHECKPOINT_DIR/train_<order>.ckpt (default: DIR); --resume continues from it (with\n"
    "--epochs at the checkpoint's epoch it only writes the weights). logrel weights get an\n"
    "energy calibration factor (docs/network.md) unless --no-calibrate. --zero-floor F:\n"
    "the written weights decode every J/E_k below (F - 1) eps as 0 (the network's noise\n"
    "about its floor would otherwise light the far field; 1 keeps the training's eps).\n"
    "--oversample-albedo A:F: tables with albedo >= A give F times the samples (the\n"
    "far-reaching high-albedo tables are the ones the network fits worst).\n"
    "--init DIR: start from DIR/<order>.bin and the JSON beside it (weights this command\n"
    "wrote with the same --target, --g-map and --eps) instead of a random initialisation: a\n"
    "fine tuning, typically with a lower --lr and a few tens of epochs. Its checkpoints go to\n"
    "--checkpoint-dir like any run's (give one, or the data folder's are overwritten).\n"
    "--near-samples R:N: N more samples per table (times F above where it applies), drawn\n"
    "in proportion to the energy of the cells within R mfp of the source: the near field\n"
    "a small object integrates, which holds under 1% of a high-albedo table's energy.\n"
    "--near-uniform F (0): the share F of those drawn uniformly over the near cells instead,\n"
    "the dim directions as much as the bright ones.\n"
    "--g-map log: g enters as the mean of g/0.99 and ln(1 - g)/ln(0.01), which widens the\n"
    "forward-scattering end (input map 2); linear (the default): g as it is (map 1).\n";

#define usage_error(...) cli_usage_error("nscatter train", __VA_ARGS__)
#define parse_number(...) cli_parse_number("nscatter train", __VA_ARGS__)
#define parse_uint(...) cli_parse_uint("nscatter train", __VA_ARGS__)

/* =======================================================================================
 * Options
 * ===================================================================================== */

static int parse_value(ns_train_options *o, const char *arg, const char *val)
{
    uint64_t u = 0;
    int rc = 0;
    if (!strcmp(arg, "--data"))
        o->data = val;
    else if (!strcmp(arg, "--out-dir"))
        o->out_dir = val;
    else if (!strcmp(arg, "--checkpoint-dir"))
        o->ckpt_dir = val;
    else if (!strcmp(arg, "--order")) {
        ns_order ord;
        if (!strcmp(val, "both"))
            o->orders = 3;
        else if (!ns_order_parse(val, &ord))
            o->orders = 1u << ord;
        else
            return usage_error("--order: '%s' is not double, multiple or both", val);
    } else if (!strcmp(arg, "--target")) {
        if (!strcmp(val, "paper"))
            o->target = NS_NN_TARGET_PAPER;
        else if (!strcmp(val, "logrel"))
            o->target = NS_NN_TARGET_LOGREL;
        else
            return usage_error("--target: '%s' is not logrel or paper", val);
    } else if (!strcmp(arg, "--g-map")) {
        if (!strcmp(val, "linear"))
            o->input_map = NS_NN_INPUT_MAP_ASINH;
        else if (!strcmp(val, "log"))
            o->input_map = NS_NN_INPUT_MAP_ASINH_LOGG;
        else
            return usage_error("--g-map: '%s' is not linear or log", val);
    } else if (!strcmp(arg, "--epochs")) {
        if (!(rc = parse_uint(arg, val, 1, 1000000, &u)))
            o->epochs = (int)u;
    } else if (!strcmp(arg, "--batch")) {
        if (!(rc = parse_uint(arg, val, 16, 1u << 20, &u)))
            o->batch = (uint32_t)u;
    } else if (!strcmp(arg, "--samples-per-table")) {
        /* even: samples alternate uniform / energy-proportional (the calibration uses it) */
        if (!(rc = parse_uint(arg, val, 100, 10000000, &u)))
            o->samples_per_table = (uint32_t)u & ~1u;
    } else if (!strcmp(arg, "--lr"))
        rc = parse_number(arg, val, 1e-7, 1, &o->lr);
    else if (!strcmp(arg, "--eps"))
        rc = parse_number(arg, val, 1e-30, 1e-3, &o->eps);
    else if (!strcmp(arg, "--oversample-albedo")) {
        double a = NAN, f = NAN;
        if (cli_number_pair(val, ':', &a, &f) || !(a >= 0 && a <= 1) || !(f >= 1 && f <= 100))
            return usage_error("--oversample-albedo: '%s' is not A:F with A in [0, 1] and F in "
                               "[1, 100]",
                               val);
        o->oversample_albedo = a;
        o->oversample_factor = f;
    } else if (!strcmp(arg, "--near-samples")) {
        double r = NAN, n = NAN;
        if (cli_number_pair(val, ':', &r, &n) || !(r > 0 && r <= 1000) || !(n >= 0 && n <= 1e7) ||
            n != floor(n))
            return usage_error("--near-samples: '%s' is not R:N with R in (0, 1000] mfp and N a "
                               "whole number in [0, 10000000]",
                               val);
        o->near_radius = r;
        o->near_samples = (uint32_t)n;
    } else if (!strcmp(arg, "--near-uniform"))
        rc = parse_number(arg, val, 0, 1, &o->near_uniform);
    else if (!strcmp(arg, "--init"))
        o->init_dir = val;
    else if (!strcmp(arg, "--zero-floor"))
        rc = parse_number(arg, val, 1, 1e6, &o->zero_floor);
    else if (!strcmp(arg, "--time-budget"))
        rc = parse_number(arg, val, 1, 1e7, &o->time_budget);
    else if (!strcmp(arg, "--seed")) {
        if (!(rc = parse_uint(arg, val, 0, 9007199254740992ull, &u)))
            o->seed = u;
    } else if (!strcmp(arg, "--threads")) {
        if (!(rc = parse_uint(arg, val, 1, 256, &u)))
            o->threads = (int)u;
    } else
        return usage_error("unknown option '%s' (see nscatter train --help)", arg);
    return rc;
}

static int parse_options(int argc, char **argv, ns_train_options *o)
{
    *o = ns_train_options_default();
    size_t len = (size_t)snprintf(o->command, sizeof o->command, "nscatter");
    for (int i = 0; i < argc && len < sizeof o->command; i++)
        len += (size_t)snprintf(o->command + len, sizeof o->command - len, " %s", argv[i]);
    for (int i = 1; i < argc; i++) {
        const char *arg = argv[i];
        if (!strcmp(arg, "--help") || !strcmp(arg, "-h")) {
            fputs(usage_text, stdout);
            return -1;
        }
        if (!strcmp(arg, "--resume") || !strcmp(arg, "--quiet")) {
            *(!strcmp(arg, "--resume") ? &o->resume : &o->quiet) = 1;
            continue;
        }
        if (!strcmp(arg, "--no-calibrate")) {
            o->calibrate = 0;
            continue;
        }
        if (strncmp(arg, "--", 2) != 0)
            return usage_error("unexpected argument '%s' (see nscatter train --help)", arg);
        if (i + 1 >= argc)
            return usage_error("%s: missing value", arg);
        int rc = parse_value(o, arg, argv[++i]);
        if (rc)
            return rc;
    }
    if (!o->data)
        return usage_error("--data: missing (the directory written by nscatter mc --grid)");
    /* A share of no samples would train as if it were not given. */
    if (o->near_uniform > 0 && !o->near_samples)
        return usage_error("--near-uniform: a share of the near samples, which need "
                           "--near-samples R:N");
    if (!o->ckpt_dir)
        o->ckpt_dir = o->data;
    return 0;
}

int cmd_train(int argc, char **argv)
{
    ns_train_options o;
    int rc = parse_options(argc, argv, &o);
    if (rc)
        return rc < 0 ? 0 : rc;
    return ns_train(&o);
}
