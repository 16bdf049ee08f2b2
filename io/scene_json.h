/* scene_json.h — scene JSON (version 1, docs/scene.md) to the render library's ns_scene.
 *
 * Parsing is strict: duplicate keys, unknown keys, wrong types, non-finite numbers,
 * out-of-range values, contradictory fields and unknown material references are errors,
 * each reported with a JSON pointer to the offending field (RFC 6901, e.g.
 * "/materials/wax/g") and a one-line detail. Meshes (glTF 2.0 GLB, via the tinygltf shim)
 * are flattened to world-space triangles here.
 *
 * Ownership: scene_parse() allocates *out; the caller frees it with scene_doc_free(). The
 * ns_scene it exposes points into the doc and lives exactly as long as the doc.
 */
#ifndef NS_SCENE_JSON_H
#define NS_SCENE_JSON_H

#include <stddef.h>
#include <stdint.h>

#include "nscatter.h"

#define SCENE_MAX_ISSUES 32

typedef struct scene_issue {
    char pointer[256]; /* JSON pointer of the field, "" for the document itself */
    char detail[512];  /* one line, names what is wrong and what is allowed */
} scene_issue;

typedef struct scene_issues {
    scene_issue items[SCENE_MAX_ISSUES];
    uint32_t count;   /* stored in items */
    uint32_t total;   /* found; may exceed count */
    int syntax_error; /* 1: the text is not JSON at all (HTTP 400); 0: invalid scene (422) */
    int line, column; /* position of a syntax error, 1-based */
} scene_issues;

typedef struct scene_parse_options {
    /* Folder holding named mesh assets ("asset": "bunny.glb"); NULL: assets are refused.
     * Names only: anything with a path separator or starting with '.' is refused. */
    const char *asset_dir;
    /* A service's own limits, below the hard ones of nscatter.h (0: the hard one): image
     * pixels (width x height), render.spp, render.vrls, triangles of all meshes together. A
     * scene over one is refused at the field's pointer, naming the limit. */
    uint32_t max_pixels, max_spp, max_vrls, max_triangles;
} scene_parse_options;

typedef struct scene_doc scene_doc;

/* Why jansson could not load `json` (json_loadb's error `e`, passed as a pointer to it),
 * classified as scene_parse classifies it, into issues (one item): a duplicate key, a number
 * that overflows and nesting deeper than jansson's 2048 levels are not syntax errors but
 * an invalid document, reported at the field's pointer (the duplicate key, the number; ""
 * for the nesting); anything else is a syntax error (issues->syntax_error, line, column).
 * The sweep parser (server/sweep.c) reads its bodies with the same rules. */
void scene_json_load_error(const char *json, size_t length, const void *e, scene_issues *issues);

/* Returns 0 and *out on success; NS_ERR_INVALID_ARGUMENT (and *out NULL) with issues
 * filled otherwise; NS_ERR_OUT_OF_HOST_MEMORY when allocation fails. */
int scene_parse(const char *json, size_t length, const scene_parse_options *opts, scene_doc **out,
                scene_issues *issues);
const ns_scene *scene_doc_scene(const scene_doc *doc);

/* The material presets a medium may name ("preset": "candle"; docs/scene.md): the paper's
 * Table 1, mfp in scene units. */
typedef struct scene_preset {
    const char *name;
    double albedo[3], mfp[3], g, ior;
} scene_preset;
uint32_t scene_preset_count(void);
/* 0 and *out for index < scene_preset_count(), else NS_ERR_INVALID_ARGUMENT. */
int scene_preset_get(uint32_t index, scene_preset *out);
void scene_doc_free(scene_doc *doc); /* NULL is allowed */

#endif
