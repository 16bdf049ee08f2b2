/* sweep.h — a material sweep (POST /v1/sweeps, docs/http.md): one base scene and a list of
 * variants, each a set of RFC 6901 pointer overrides of the scene JSON, given as a list or
 * as a grid (the cartesian product of a list of values per pointer, first pointer slowest).
 *
 * Every variant is parsed and validated when the sweep is made, before anything renders;
 * the scenes themselves are not kept (a sweep of 256 variants of a mesh would hold 256
 * meshes) but made again from the base and the overrides when each variant renders.
 */
#ifndef NS_SWEEP_H
#define NS_SWEEP_H

#include <stddef.h>
#include <stdint.h>

#include <jansson.h>

#include "nscatter.h"
#include "scene_json.h"

#define SWEEP_MAX_VARIANTS 256u

typedef struct sweep sweep;

/* Parses a request body. Returns 0 and *out, or a nonzero status with *problem (a new
 * problem+json: 400 malformed_json, 422 invalid_sweep naming the variant and the pointer
 * into the body, or 503 when out of memory). */
int sweep_parse(const char *body, size_t size, const scene_parse_options *opts, sweep **out,
                json_t **problem);
void sweep_free(sweep *sweep); /* NULL allowed */

uint32_t sweep_variant_count(const sweep *sweep);
/* {"/pointer": value, ...} of variant i (borrowed). */
const json_t *sweep_overrides(const sweep *sweep, uint32_t i);
/* The variants in the order they render: grouped by the scattering tables they need (g and
 * albedo of every medium), so that those sharing tables render one after the other; in
 * request order within a group. */
const uint32_t *sweep_order(const sweep *sweep);
/* The scene of variant i, parsed again (the caller frees it). */
int sweep_variant_scene(const sweep *sweep, uint32_t i, scene_doc **out, ns_error *err);
/* The pixels of every variant's image together (what the sweep's results will hold). */
uint64_t sweep_pixels(const sweep *sweep);
/* One line per override, "g=0.5", for the contact sheet: at most `max` lines written into
 * lines[k] (96 bytes each). Returns the number written. */
uint32_t sweep_label_lines(const sweep *sweep, uint32_t i, char (*lines)[96], uint32_t max);

#endif
