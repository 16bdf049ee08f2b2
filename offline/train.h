/* train.h — `nscatter train`: fits the double and multiple scattering networks to the
 * Monte Carlo grid written by `nscatter mc --grid` (docs/network.md). */
#ifndef NS_TRAIN_H
#define NS_TRAIN_H

#include <stddef.h>
#include <stdint.h>

#include "nn_weights.h"
#include "table_io.h"

/* Default held-out materials (g, albedo pairs of the grid, never trained on). */
extern const double ns_train_holdout_default[][2];
extern const int ns_train_holdout_default_count;

/* Parses "DIR/g0.30_a0.900_double.json"-style names written by the grid: 0 or -1. */
int ns_train_parse_table_name(const char *name, double *g, double *albedo, ns_order *order);

/* What `nscatter train` does (docs/network.md); ns_train_options_default() fills the
 * defaults its usage text names. data is required; ckpt_dir NULL means data. */
typedef struct ns_train_options {
    const char *data, *out_dir, *ckpt_dir;
    const char *init_dir; /* NULL, or a folder of weights to start from (DIR/<order>.bin) */
    unsigned orders;
    ns_nn_target target;
    int epochs, resume, quiet, threads, calibrate;
    uint32_t input_map; /* NS_NN_INPUT_MAP_*: how g enters the network */
    uint32_t batch, samples_per_table;
    uint32_t near_samples; /* more per table, energy-proportional within near_radius mfp */
    double lr, time_budget, eps, zero_floor, oversample_albedo, oversample_factor, near_radius;
    double near_uniform; /* the share of near_samples drawn uniformly over the near cells */
    uint64_t seed;
    char command[2048];
} ns_train_options;

ns_train_options ns_train_options_default(void);

/* The training samples `nscatter train` draws for one order, before standardisation: the
 * first `regular` alternate uniform / energy-proportional (the energy calibration reads the
 * odd ones), the near-field ones (--near-samples) follow. For tests of the sampling. 0, or
 * 2 with the message on stderr. */
typedef struct ns_train_samples {
    ns_nn_header h;      /* the inputs' map and extent (from the tables) */
    float *x, *t;        /* n x NS_NN_INPUTS inputs; n targets */
    uint32_t n, regular;
} ns_train_samples;
int ns_train_samples_load(const ns_train_options *o, ns_order order, ns_train_samples *s);
void ns_train_samples_free(ns_train_samples *s);

/* Trains the orders o->orders asks for, one after the other, writing OUT_DIR/<order>.bin and
 * .json; progress on stderr. 0 done, 2 bad input (the message is on stderr), 1 failure. */
int ns_train(const ns_train_options *o);

#endif
