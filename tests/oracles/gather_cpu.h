/* gather_cpu.h — the tests' CPU oracle of the gather (tests/oracles/gather_cpu.c). */
#ifndef NS_TEST_GATHER_CPU_H
#define NS_TEST_GATHER_CPU_H

#include "scatter.h"

/* The sum ns_gather_run computes, on the CPU: out[i] for segments[i], i < segment_count;
 * table = A (float [3][NS_TABLE_CELLS]) or NULL in dipole mode. It walks the nodes in
 * lavapipe's dispatch ranges; the exact walk takes its culling decisions for subgroup_size
 * consecutive segments together, as gather.comp does (gpu_device.subgroup_size; the sums do
 * not depend on it, the counts do). Aborts when out of memory (tests only). */
void ns_gather_cpu(const GpuGatherParams *params, const GpuSegment *segments,
                   uint32_t segment_count, const ns_vrl_grid *grid, const float *table,
                   uint32_t subgroup_size, float (*out)[4], ns_gather_counts *counts);

#endif
