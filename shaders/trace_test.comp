#version 450
// trace_test.comp — nearest hit of one ray per invocation, for the BVH known-answer test
// (tests/gpu_bvh.c compares it with brute force on the CPU).
#extension GL_GOOGLE_include_directive : require
#include "shared.h"
#include "trace.glsl"

layout(local_size_x = NS_TRACE_GROUP) in;

layout(std430, binding = 3) readonly buffer RayBlock { GpuRay rays[]; };
layout(std430, binding = 4) writeonly buffer HitBlock { GpuHit hits[]; };

void main()
{
    uint i = gl_GlobalInvocationID.x;
    if (i >= params.prims.w)
        return;
    GpuRay ray = rays[i];
    Hit h;
    bool any = trace_scene(ray.origin.xyz, ray.direction.xyz, 0.0, ray.origin.w, h);
    hits[i].t = any ? h.t : -1.0;
    hits[i].prim = any ? h.prim : NS_NONE;
    hits[i].front = h.front ? 1u : 0u;
    hits[i].pad = 0u;
}
