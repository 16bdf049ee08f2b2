/* vrl_shared.h — the VRL generation pass's own GPU structs (shaders/vrl.comp, render/vrl.c).
 * Include shared.h first. Sizes checked at the bottom. */
#ifndef NS_SHADERS_VRL_SHARED_H
#define NS_SHADERS_VRL_SHARED_H

/* One (light, target) pair: the light's paths aimed at the bounding sphere of one medium
 * object. The paths [first_path, next stratum's first_path) belong to it; each carries
 * weight = 1 / (paths * probability of the stratum) (render/vrl.c: systematic sampling in
 * proportion to the power the light sends towards the sphere). */
struct GpuVrlStratum {
    ns_vec4 target; /* xyz = centre, w = radius (scene units) */
    ns_vec4 weight; /* x = 1 / (N p), yzw unused */
    ns_uvec4 ids;   /* x = first path, y = light index, z = target object index, w = its paths */
};

/* Push block: path i in [0, path_count) runs in invocation i. budget = loop iterations an
 * invocation may run before it is counted in NS_VRL_COUNTER_LOOP_LIMIT (0 = no limit).
 * chain = stretches a path may store, in [1, NS_VRL_MAX_CHAIN]: the first one and chain - 1
 * internal reflections of the unscattered beam; path i writes slots [i chain, (i + 1) chain). */
struct GpuVrlPush {
    ns_uint path_count;
    ns_uint stratum_count;
    ns_uint seed;
    ns_uint budget;
    ns_uint chain;
    ns_uint pad1;
    ns_uint pad2;
    ns_uint pad3;
};

NS_CONST(uint, NS_VRL_GROUP, 64);

/* The most stretches one light path stores (its beam's first stretch and internal
 * reflections). */
NS_CONST(uint, NS_VRL_MAX_CHAIN, 4);

/* Boundary crossings a light path may make before it enters its medium (index-matched,
 * non-scattering objects are crossed; anything else ends the walk). */
NS_CONST(uint, NS_VRL_MAX_CROSSINGS, 16);

/* Counters (binding 7): VRLs stored, invocations past the loop budget, paths that ended
 * before reaching their medium (blocked, missed, or the cosine was negative). */
NS_CONST(uint, NS_VRL_COUNTER_STORED, 0);
NS_CONST(uint, NS_VRL_COUNTER_LOOP_LIMIT, 1);
NS_CONST(uint, NS_VRL_COUNTER_LOST, 2);
NS_CONST(uint, NS_VRL_COUNTER_COUNT, 4);

#if defined(__STDC__) || defined(__cplusplus)
typedef struct GpuVrlStratum GpuVrlStratum;
typedef struct GpuVrlPush GpuVrlPush;
_Static_assert(sizeof(GpuVrlStratum) == 48 && offsetof(GpuVrlStratum, ids) == 32, "GpuVrlStratum");
_Static_assert(sizeof(GpuVrlPush) == 32, "GpuVrlPush size");
#endif

#endif
