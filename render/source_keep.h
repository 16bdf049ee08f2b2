/* source_keep.h — the light's sources of the last two renders (their VRLs and grouped boundary
 * sources), kept in the context for the next render that would make the same ones: whatever
 * its camera (render/source_keep.c says what they depend on). */
#ifndef NS_RENDER_SOURCE_KEEP_H
#define NS_RENDER_SOURCE_KEEP_H

#include "boundary.h"

/* The bytes the sources of the table and dipole methods depend on (NULL when out of memory:
 * then nothing is reused); chain as ns_vrl_generate takes it. */
unsigned char *ns_source_signature(const ns_scene *scene, const ns_gpu_scene *gs, uint32_t chain,
                                   size_t *bytes);
/* When kept sources have this signature: fills set and boundary with a copy of them and
 * returns 1; else (or out of memory) 0, with both left empty. */
int ns_source_keep_take(ns_context *ctx, const unsigned char *signature, size_t bytes, ns_vrl_set *set,
                        ns_boundary_groups *boundary);
/* Keeps a copy of the sources and the signature (owned from now on; NULL keeps nothing) in
 * place of the least recently kept or taken, when they fit the bound. */
void ns_source_keep_put(ns_context *ctx, unsigned char *signature, size_t bytes, const ns_vrl_set *set,
                        const ns_boundary_groups *boundary);
/* Frees what the context keeps (ns_context_destroy). */
void ns_source_keep_free(ns_context *ctx);

#endif
