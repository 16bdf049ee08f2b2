#version 450
// trace_test.comp — nearest hit of one ray per invocation, for the BVH known-answer test
// (tests/gpu_bvh.c compares it with brute force on the CPU) and the ray benchmark
// (bench/rays.c). A ray with direction.w = 1 asks the any-hit query of shadow rays instead
// (trace_shadow): what it meets first in any order before tmax, written as prim 0 and t 0 when
// that blocks, crossed 1 and t 0 when it is an index-matched boundary (prim NS_NONE), prim
// NS_NONE and t -1 when nothing is met. No nearest hit is found.
#extension GL_GOOGLE_include_directive : require
#include "shared.h"
#include "trace.glsl"

layout(local_size_x = NS_TRACE_GROUP) in;
#include "groups.glsl"

layout(std430, binding = 3) readonly buffer RayBlock { GpuRay rays[]; };
layout(std430, binding = 4) writeonly buffer HitBlock { GpuHit hits[]; };

void main()
{
    uint i = interleaved_invocation_x();
    if (i >= params.prims.w)
        return;
    GpuRay ray = rays[i];
    if (ray.direction.w == 1.0) {
        uint met = trace_shadow(ray.origin.xyz, ray.direction.xyz, 0.0, ray.origin.w, NS_PRIM_SHADOW_PASSES);
        hits[i].t = met == NS_SHADOW_CLEAR ? -1.0 : 0.0;
        hits[i].prim = met == NS_SHADOW_BLOCKED ? 0u : NS_NONE;
        hits[i].front = 0u;
        hits[i].crossed = met == NS_SHADOW_CROSSES ? 1u : 0u;
        return;
    }
    Hit h;
    bool any = trace_scene(ray.origin.xyz, ray.direction.xyz, 0.0, ray.origin.w, h);
    hits[i].t = any ? h.t : -1.0;
    hits[i].prim = any ? h.prim : NS_NONE;
    hits[i].front = h.front ? 1u : 0u;
    hits[i].crossed = 0u;
}
