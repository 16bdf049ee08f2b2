/* fuzz_sweep.c — libFuzzer target for the sweep parser (server/sweep.h): a base scene and
 * variants of RFC 6901 pointer overrides, as a list or a grid. Built only with
 * -DNS_FUZZ=ON and clang; run by scripts/fuzz.sh (docs/development.md, "Fuzzing").
 *
 * Besides ASan, UBSan and LeakSanitizer, the parser's contract is checked: a refusal is a
 * problem with status 400, 422 or 503; an accepted sweep has 1 to SWEEP_MAX_VARIANTS
 * variants, its render order is a permutation of them, and every variant's scene, made
 * again from the base and its overrides as the render worker makes it, parses (the sweep
 * was validated whole before it was accepted). */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "fuzz_options.h"
#include "sweep.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    sweep *sw = NULL;
    json_t *problem = NULL;
    int rc = sweep_parse((const char *)data, size, &fuzz_parse_options, &sw, &problem);
    if (rc) {
        json_int_t status = json_integer_value(json_object_get(problem, "status"));
        if (sw || !problem || !(status == 400 || status == 422 || status == 503))
            abort();
        json_decref(problem);
        return 0;
    }
    if (!sw || problem)
        abort();
    uint32_t n = sweep_variant_count(sw);
    if (n == 0 || n > SWEEP_MAX_VARIANTS)
        abort();
    const uint32_t *order = sweep_order(sw);
    unsigned char seen[SWEEP_MAX_VARIANTS];
    memset(seen, 0, sizeof seen);
    for (uint32_t i = 0; i < n; i++) {
        if (order[i] >= n || seen[order[i]]++)
            abort();
        scene_doc *doc = NULL;
        ns_error err;
        if (sweep_variant_scene(sw, order[i], &doc, &err) || !doc)
            abort();
        scene_doc_free(doc);
        char lines[8][96];
        sweep_label_lines(sw, order[i], lines, 8);
    }
    sweep_free(sw);
    return 0;
}
