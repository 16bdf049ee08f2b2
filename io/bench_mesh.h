/* bench_mesh.h — the meshes of `nscatter bench`, made at run time rather than committed:
 * a displaced ("bumpy") sphere and a capped cylinder generated here, and the Stanford bunny
 * converted from the Wavefront OBJ that Debian's glmark2-data installs
 * (/usr/share/glmark2/models/bunny.obj; its licence is the package's, so the repository does
 * not carry a copy). Each becomes a glTF 2.0 binary (GLB) that the scene parser reads as a
 * named asset (docs/scene.md, "Meshes").
 *
 * Ownership: every mesh_* result is malloc'd into the bench_mesh or buffer the caller passes;
 * free with bench_mesh_free / free(). Results are 0 or a negative ns_status; err names the
 * file or the line that is wrong.
 */
#ifndef NS_BENCH_MESH_H
#define NS_BENCH_MESH_H

#include <stddef.h>
#include <stdint.h>

#include "nscatter.h"

typedef struct bench_mesh {
    float *positions;  /* 3 floats per vertex */
    uint32_t *indices; /* 3 per triangle, counter-clockwise seen from outside */
    uint32_t vertex_count, triangle_count;
} bench_mesh;

void bench_mesh_free(bench_mesh *m); /* NULL is allowed; zeroes the struct */

/* Unit sphere subdivided `levels` times from an icosahedron (20 * 4^levels triangles), each
 * vertex moved along its normal by amplitude * (smooth bumps in [-1, 1]). */
int bench_mesh_bumpy_sphere(uint32_t levels, float amplitude, bench_mesh *out, ns_error *err);

/* Closed cylinder of radius 1 around +y from y = 0 to y = 1, `segments` around. */
int bench_mesh_cylinder(uint32_t segments, bench_mesh *out, ns_error *err);

/* Reads the vertices and faces of a Wavefront OBJ (v, f; polygons fanned into triangles;
 * v/vt/vn and negative indices accepted; everything else ignored). The winding is made
 * counter-clockwise seen from outside when the mesh's signed volume says it is not. */
int bench_mesh_load_obj(const char *path, bench_mesh *out, ns_error *err);

/* Signed volume of a closed mesh (positive when wound counter-clockwise from outside). */
double bench_mesh_signed_volume(const bench_mesh *m);

/* The mesh as a GLB: one node, one primitive, float positions with min/max, 32-bit
 * indices. *glb is malloc'd. */
int bench_mesh_to_glb(const bench_mesh *m, unsigned char **glb, size_t *glb_size, ns_error *err);

#endif
