/* gltf_shim.h — glTF 2.0 meshes to flat triangle lists, through tinygltf.
 *
 * The only C++ in the project lives behind this header (io/gltf_shim.cpp): tinygltf is
 * compiled there with its own file access, image decoding and image writing switched off,
 * and every C++ exception is caught inside the shim. The C side reads asset files itself
 * (after checking the name) and hands bytes over.
 *
 * Accepted input: a GLB container (magic "glTF", version 2) or glTF JSON text whose
 * buffers are embedded as data: URIs. Any other buffer URI is refused, since the shim has
 * no file system. The default scene (else scene 0; else every mesh once, untransformed) is
 * walked with its node transforms (matrix or TRS), and every primitive of mode TRIANGLES,
 * indexed or not, contributes its triangles. Other primitive modes, sparse accessors,
 * non-float positions and out-of-bounds accessors are refused with a message.
 */
#ifndef NS_GLTF_SHIM_H
#define NS_GLTF_SHIM_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Input over this size is refused before parsing. */
#define GLTF_MAX_BYTES ((size_t)64 * 1024 * 1024)

/* Loads the triangles of `bytes` (GLB or glTF JSON, `len` bytes) in the glTF scene's
 * space: 9 floats per triangle (three xyz vertices), counter-clockwise seen from outside
 * (winding is swapped under mirroring node transforms).
 *
 * On success returns 0, *positions_out points to 9 * *triangle_count floats allocated
 * with malloc() (the caller frees them with free()), and *triangle_count >= 1.
 * On failure returns a negative ns_status (render/include/nscatter.h) and writes a one-line
 * message to err: NS_ERR_INVALID_ARGUMENT for anything wrong with the file,
 * NS_ERR_LIMIT when it is over GLTF_MAX_BYTES or holds more than max_triangles triangles,
 * NS_ERR_OUT_OF_HOST_MEMORY when allocation fails. *positions_out is then NULL. */
int gltf_load(const void *bytes, size_t len, size_t max_triangles, float **positions_out,
              size_t *triangle_count, char *err, size_t errlen);

/* The same, with the vertex normals (the NORMAL attribute) when normals_out is not NULL:
 * *normals_out then points to 9 * *triangle_count floats (malloc'd; three unit xyz normals
 * per triangle, in its corners' order, carried by the inverse transpose of the node
 * transforms; zero for the triangles of a primitive without NORMAL), or is NULL when no
 * primitive has NORMAL. NORMAL must be VEC3 FLOAT with one element per vertex, each a
 * direction (not zero, finite); otherwise the file is refused. */
int gltf_load_shaded(const void *bytes, size_t len, size_t max_triangles, float **positions_out,
                     float **normals_out, size_t *triangle_count, char *err, size_t errlen);

#ifdef __cplusplus
}
#endif
#endif
