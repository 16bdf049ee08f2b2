// groups.glsl — which workgroup a group computes, so that every CPU thread of lavapipe gets
// its share of the costly ones. Needs the workgroup size declared first.
//
// lavapipe splits a dispatch's workgroups among its T threads in contiguous runs, the first
// T-th to the first thread and so on (Mesa 22.3's lp_cs_tpool_queue_task: iter_per_thread =
// groups / threads), and the dispatch ends with its slowest thread. Where the costly work
// lies in one part of the dispatch (an object in the lower half of the image, shadow rays
// after primary ones), one thread does most of it while the others wait. Thread t's groups
// therefore compute the groups t, t + T, t + 2T, ...: every thread's share is spread over the
// whole dispatch, and a thread's consecutive groups stay T groups apart, close enough to
// share its caches (spreading them over the dispatch in a golden-ratio order instead cost
// more in cache misses than it won; docs/bench.md). T is a specialisation constant that
// every pipeline gets from the device (gpu_pipeline.c; gpu_device.c counts lavapipe's
// threads), so the compiler folds it (read from a uniform block it cost 3% of bench_rays);
// 0 on a GPU, which schedules groups itself: groups compute themselves. The last groups % T
// groups stay where they are.
layout(constant_id = NS_SPEC_CPU_THREADS) const uint NS_CPU_THREADS = 0u;

uint interleaved_group(uint g, uint n)
{
    uint threads = NS_CPU_THREADS;
    uint run = threads > 1u ? n / threads : 0u;
    if (run == 0u || g >= run * threads)
        return g;
    // g / run in floating point, corrected to the exact quotient (g < 2^24: lavapipe's groups
    // per dimension are at most 65535): x86 has no vector integer division, so LLVM divides
    // one lane at a time.
    uint q = uint((float(g) + 0.5) / float(run));
    q -= q * run > g ? 1u : 0u;
    q += (q + 1u) * run <= g ? 1u : 0u;
    return (g - q * run) * threads + q;
}

// gl_GlobalInvocationID.x of the interleaved workgroup, for a dispatch of one dimension.
uint interleaved_invocation_x()
{
    return interleaved_group(gl_WorkGroupID.x, gl_NumWorkGroups.x) * gl_WorkGroupSize.x +
           gl_LocalInvocationID.x;
}

// gl_GlobalInvocationID.xy of the interleaved workgroup, for a dispatch of two dimensions
// (lavapipe numbers the groups x fastest). Interleaving whole rows of groups keeps a row's
// neighbours together and needs no division by the row's length.
uvec2 interleaved_invocation_xy()
{
    uvec2 g = uvec2(gl_WorkGroupID.x, interleaved_group(gl_WorkGroupID.y, gl_NumWorkGroups.y));
    return g * gl_WorkGroupSize.xy + gl_LocalInvocationID.xy;
}
