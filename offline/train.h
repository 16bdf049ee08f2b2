/* train.h — `nscatter train`: fits the double and multiple scattering networks to the
 * Monte Carlo grid written by `nscatter mc --grid` (docs/network.md). */
#ifndef NS_TRAIN_H
#define NS_TRAIN_H

#include <stddef.h>
#include <stdint.h>

#include "table_io.h"

/* Default held-out materials (g, albedo pairs of the grid, never trained on). */
extern const double ns_train_holdout_default[][2];
extern const int ns_train_holdout_default_count;

/* Parses "DIR/g0.30_a0.900_double.json"-style names written by the grid: 0 or -1. */
int ns_train_parse_table_name(const char *name, double *g, double *albedo, ns_order *order);

#endif
