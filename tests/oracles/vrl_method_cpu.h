/* vrl_method_cpu.h — the tests' CPU oracle of the `vrl` method's gather
 * (tests/oracles/vrl_method_cpu.c). */
#ifndef NS_TEST_VRL_METHOD_CPU_H
#define NS_TEST_VRL_METHOD_CPU_H

#include "vrl_method.h"

/* The gather's estimator on the CPU without visibility: the same sums as
 * ns_vrl_method_gather_vrls for segments[i], i < segment_count, given the VRLs in the order
 * the GPU visits them (grouped by material, in their order within a material: see
 * ns_vrl_method_sort). */
void ns_vrl_method_gather_cpu(const GpuMaterial *materials, const GpuSegment *segments,
                              uint32_t segment_count, const GpuVrl *vrls, uint32_t vrl_count,
                              uint32_t seed, float (*out_double)[4], float (*out_multiple)[4]);

#endif
