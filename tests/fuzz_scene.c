/* fuzz_scene.c — libFuzzer target for the scene parser and the glTF shim (built only with
 * -DNS_FUZZ=ON and clang; see docs/development.md or docs/scene.md):
 *
 *   CC=clang CXX=clang++ cmake -S . -B build-fuzz -DNS_FUZZ=ON -DNS_TESTS=OFF
 *   cmake --build build-fuzz --target fuzz_scene
 *   ./build-fuzz/fuzz_scene -max_total_time=60 -max_len=65536 build-fuzz/corpus scenes/
 *
 * Any input must end in a scene or in issues, never in a crash, a leak or undefined
 * behaviour (the target is built with ASan and UBSan). */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include "gltf_shim.h"
#include "scene_json.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    scene_doc *doc = NULL;
    scene_issues issues;
    if (scene_parse((const char *)data, size, NULL, &doc, &issues) == 0) {
        const ns_scene *s = scene_doc_scene(doc);
        /* A parsed scene must satisfy the contract the renderer relies on. */
        for (uint32_t i = 0; i < s->object_count; i++)
            if (s->objects[i].material >= s->material_count)
                abort();
        scene_doc_free(doc);
    } else if (doc != NULL || issues.count == 0) {
        abort();
    }
    /* The same bytes as a glTF file, straight into the shim. */
    float *positions = NULL;
    size_t triangles = 0;
    char err[256];
    if (gltf_load(data, size, 1u << 16, &positions, &triangles, err, sizeof err) == 0 && triangles == 0)
        abort();
    free(positions);
    return 0;
}
