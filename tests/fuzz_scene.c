/* fuzz_scene.c — libFuzzer target for the scene parser (io/scene_json.h), meshes included
 * (inline glTF as data: URIs, named assets of scenes/assets/, generated shapes). Built only
 * with -DNS_FUZZ=ON and clang; run by scripts/fuzz.sh (docs/development.md, "Fuzzing").
 * The glTF shim on its own is fuzz_gltf's.
 *
 * Any input must end in a scene or in issues, never in a crash, a leak or undefined
 * behaviour (the target is built with ASan and UBSan). The asset folder is the repository's
 * scenes/assets, so that names that try to leave it ("../", "/etc/passwd") meet the real
 * check; a service's limits are set, so that the limit paths are reached by small inputs. */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include "fuzz_options.h"
#include "scene_json.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    scene_doc *doc = NULL;
    scene_issues issues;
    int rc = scene_parse((const char *)data, size, &fuzz_parse_options, &doc, &issues);
    if (rc == 0) {
        const ns_scene *s = scene_doc_scene(doc);
        /* A parsed scene must satisfy the contract the renderer relies on. */
        for (uint32_t i = 0; i < s->object_count; i++)
            if (s->objects[i].material >= s->material_count)
                abort();
        scene_doc_free(doc);
    } else if (doc != NULL || (rc == NS_ERR_INVALID_ARGUMENT && issues.count == 0)) {
        abort();
    }
    return 0;
}
