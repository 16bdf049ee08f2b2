/* fuzz_gltf.c — libFuzzer target for the glTF shim (io/gltf_shim.h): tinygltf and the
 * shim's own checks of everything tinygltf hands back. Built only with -DNS_FUZZ=ON and
 * clang; run by scripts/fuzz.sh (docs/development.md, "Fuzzing").
 *
 * Every input is loaded as it is: a GLB container, or glTF JSON with data: URI buffers.
 * An input that is not a GLB is also loaded a second time wrapped in a GLB container built
 * here, its bytes up to the first NUL as the JSON chunk and the rest as the BIN chunk: a
 * GLB's length fields must agree with each other, which random mutation rarely keeps, so
 * this form lets the fuzzer reach accessors and buffer views over a GLB-stored buffer.
 *
 * Besides ASan, UBSan and LeakSanitizer, the shim's contract (gltf_shim.h) is checked:
 * success means 1 to max triangles of finite positions; failure means a documented status,
 * a message and no positions. */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gltf_shim.h"
#include "nscatter.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* Small enough to reach the limit from a small input; large enough for the seeds. */
#define FUZZ_MAX_TRIANGLES 4096u

static void load_and_check(const void *bytes, size_t len)
{
    float *positions = NULL, *normals = NULL;
    size_t triangles = 0;
    char err[256] = "";
    /* With the normals: the NORMAL path is the positions' plus its own checks. */
    int rc = gltf_load_shaded(bytes, len, FUZZ_MAX_TRIANGLES, &positions, &normals, &triangles,
                              err, sizeof err);
    if (rc == 0) {
        if (!positions || triangles == 0 || triangles > FUZZ_MAX_TRIANGLES)
            abort();
        for (size_t i = 0; i < 9 * triangles; i++)
            if (!isfinite(positions[i]))
                abort();
        /* Each corner's normal is a unit vector, or zero for a primitive without NORMAL. */
        for (size_t c = 0; normals && c < 3 * triangles; c++) {
            const float *n = normals + 3 * c;
            double len2 = (double)n[0] * n[0] + (double)n[1] * n[1] + (double)n[2] * n[2];
            if (!(len2 == 0.0 || fabs(len2 - 1.0) < 1e-5))
                abort();
        }
    } else if (positions || normals || !err[0] ||
               !(rc == NS_ERR_INVALID_ARGUMENT || rc == NS_ERR_LIMIT ||
                 rc == NS_ERR_OUT_OF_HOST_MEMORY)) {
        fprintf(stderr, "fuzz_gltf: status %d, message '%s'\n", rc, err);
        abort();
    }
    free(positions);
    free(normals);
}

static void put_u32(unsigned char *p, uint32_t v)
{
    p[0] = (unsigned char)v, p[1] = (unsigned char)(v >> 8), p[2] = (unsigned char)(v >> 16),
    p[3] = (unsigned char)(v >> 24);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    load_and_check(data, size);
    if (size >= 4 && !memcmp(data, "glTF", 4))
        return 0;
    const uint8_t *nul = memchr(data, 0, size);
    size_t json_len = nul ? (size_t)(nul - data) : size;
    size_t bin_len = nul ? size - json_len - 1 : 0;
    size_t json_padded = (json_len + 3) & ~(size_t)3, bin_padded = (bin_len + 3) & ~(size_t)3;
    size_t total = 12 + 8 + json_padded + (nul ? 8 + bin_padded : 0);
    unsigned char *glb = calloc(1, total);
    if (!glb)
        return 0;
    memcpy(glb, "glTF", 4);
    put_u32(glb + 4, 2);
    put_u32(glb + 8, (uint32_t)total);
    put_u32(glb + 12, (uint32_t)json_padded);
    put_u32(glb + 16, 0x4E4F534Au); /* "JSON" */
    memcpy(glb + 20, data, json_len);
    memset(glb + 20 + json_len, ' ', json_padded - json_len); /* the spec pads with spaces */
    if (nul) {
        unsigned char *chunk = glb + 20 + json_padded;
        put_u32(chunk, (uint32_t)bin_padded);
        put_u32(chunk + 4, 0x004E4942u); /* "BIN\0" */
        memcpy(chunk + 8, nul + 1, bin_len);
    }
    load_and_check(glb, total);
    free(glb);
    return 0;
}
