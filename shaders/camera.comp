#version 450
// camera.comp — the camera ray-tracing pass: one invocation per pixel, `spp` pinhole
// samples at low-discrepancy points of the pixel. Diffuse surfaces take direct light from
// every light and the environment with render.light_samples shadow rays each (one for a
// point or directional light), low-discrepancy across the pixel's samples (common.glsl,
// DirectNumbers), and end the path;
// medium boundaries are smooth dielectrics (Fresnel reflection/refraction, total internal
// reflection; ior 1 passes straight through); Beer-Lambert attenuates every
// stretch inside a medium, and each such stretch is recorded in the segment buffer for the
// scattering passes. The environment is seen directly and through reflection/refraction.
//
// The same pipeline takes the added samples of render.adaptive_spp (push.added_count > 0):
// one invocation per sample, for the pixel and sample index render.c listed, recording no
// segments (they add surface light only) and writing the sample's radiance back.
//
// Media are assumed not to nest or overlap: crossing a medium's boundary from the outside
// enters it, crossing from the inside returns to vacuum (ior 1).
#extension GL_GOOGLE_include_directive : require
#include "shared.h"
#include "trace.glsl"

layout(local_size_x = NS_CAMERA_GROUP_X, local_size_y = NS_CAMERA_GROUP_Y) in;
#include "groups.glsl"

layout(std430, binding = 3) readonly buffer MaterialBlock { GpuMaterial materials[]; };
layout(std430, binding = 4) readonly buffer LightBlock { GpuLight lights[]; };
layout(std430, binding = 5) buffer ImageBlock { vec4 pixels[]; };
layout(std430, binding = 6) writeonly buffer SegmentBlock { GpuSegment segments[]; };
layout(std430, binding = 7) buffer CounterBlock { uint counters[]; };
layout(std430, binding = 8) buffer AddedBlock { GpuAddedSample added[]; };
layout(push_constant) uniform PushBlock { GpuSamplePush ns_push[1]; };
#define push ns_push[NS_OPAQUE_ZERO] /* shared.h: NS_OPAQUE_ZERO */

#define NS_COMMON_TRACE
#define NS_COMMON_LIGHTS
#include "common.glsl"

// How this pass traces its shadow rays (common.glsl, transmittance).
const uint SHADOW_RAYS = SHADOW_ANY_HIT;

// False for the added samples: the scattering stages take the first spp samples' segments.
bool recording = true;

void record_segment(vec3 a, vec3 b, vec3 d, vec3 w, uint material, uint pixel, uint s, uint depth)
{
    if (!recording)
        return;
    uint index = atomicAdd(counters[NS_COUNTER_SEGMENTS], 1u);
    if (index >= params.counts.z) {
        atomicAdd(counters[NS_COUNTER_OVERFLOW], 1u);
        return;
    }
    segments[index].entry = a;
    segments[index].pixel = pixel;
    segments[index].exit = b;
    segments[index].material = material;
    segments[index].direction = d;
    segments[index].sample_index = s;
    segments[index].throughput = w;
    segments[index].depth = depth;
}

// ---------------------------------------------------------------------------------------
// One camera path with deterministic Fresnel splitting while the branch stack has room.
// ---------------------------------------------------------------------------------------
struct PathState {
    vec3 o;
    vec3 d;
    vec3 w;      // throughput
    uint medium; // material index of the medium the ray is in, NS_NONE outside
    uint depth;  // boundary bounces so far
    bool entered; // crossed into the medium from outside since the last recorded stretch
    bool weak;    // fell below NS_MIN_SEGMENT_THROUGHPUT: records no stretch, plays roulette
};

PathState branch_stack[NS_BRANCH_STACK];

vec3 trace_path(PathState s, uint pixel, uint sample_index, DirectNumbers numbers)
{
    vec3 radiance = vec3(0.0);
    uint top = 0u;
    bool alive = true;
    while (alive) {
        if (out_of_budget())
            break;
        // A branch too weak to record stretches (below NS_MIN_SEGMENT_THROUGHPUT in every
        // channel: a Fresnel reflection of a reflection, or deep in an absorbing medium) goes
        // on with probability w / NS_MIN_SEGMENT_THROUGHPUT at that throughput: the same
        // surface light in expectation, and most of such branches are not traced. Inside a
        // refracting scattering mesh they had been most of the pass's rays (at 256² the bumpy
        // sphere's and the bunny's camera passes 2.2-2.4x shorter; docs/bench.md, *Weak
        // branches*).
        float strongest = max(s.w.x, max(s.w.y, s.w.z));
        if (strongest < NS_MIN_SEGMENT_THROUGHPUT) {
            s.weak = true;
            float keep = strongest / NS_MIN_SEGMENT_THROUGHPUT;
            if (rnd() >= keep) {
                if (top == 0u)
                    break;
                s = branch_stack[--top];
                continue;
            }
            s.w /= keep;
        }
        Hit h;
        bool any = trace_scene(s.o, s.d, 0.0, NS_INF, h);
        uint light_index;
        float t_light = hit_sphere_lights(s.o, s.d, any ? h.t : NS_INF, light_index);
        bool ends_at_light = light_index != NS_NONE;
        float t_end = ends_at_light ? t_light : (any ? h.t : NS_INF);

        if (s.medium != NS_NONE) {
            if (t_end < NS_INF && !s.weak)
                record_segment(s.o, s.o + t_end * s.d, s.d, s.w, s.medium, pixel, sample_index,
                               s.depth | (s.entered ? NS_SEGMENT_ENTERED : 0u));
            s.entered = false;
            s.w *= beer_lambert(sigma_t_of(s.medium), t_end);
        }

        bool terminated = true;
        if (ends_at_light) {
            radiance += s.w * lights[light_index].color.rgb;
        } else if (!any) {
            radiance += s.w * params.environment.rgb;
        } else {
            vec3 p = s.o + h.t * s.d;
            uint m = prim_at(h.prim).info.y;
            GpuMaterial mat = materials[m];
            vec3 n = h.front ? h.normal : -h.normal; // faces the incoming ray
            if (mat.reflectance.w == 0.0) {
                // As many light samples as the surface's weight in its pixel deserves (as
                // single.comp's segment_strata): one seen in a Fresnel reflection of a few per
                // cent does not need N to hide its noise. A prefix of the sample's points.
                DirectNumbers here = numbers;
                float weight = min(max(s.w.x, max(s.w.y, s.w.z)), 1.0);
                here.samples =
                    clamp(uint(ceil(float(numbers.samples) * weight)), 1u, numbers.samples);
                radiance +=
                    s.w * lambert_direct(p, n, mat.reflectance.rgb, s.medium, SHADOW_RAYS, here);
            } else if (s.depth < params.counts.x) {
                terminated = false;
                float eps = ray_epsilon(p);
                uint next_medium = h.front ? m : NS_NONE;
                float ior = mat.sigma_t.w;
                s.depth++;
                if (ior == 1.0) {
                    // Index matched: no Fresnel, no bending; only the medium changes.
                    s.o = p - n * eps;
                    s.medium = next_medium;
                    s.entered = next_medium != NS_NONE;
                } else {
                    float eta = h.front ? 1.0 / ior : ior;
                    float cos_i = -dot(s.d, n);
                    float cos_t;
                    float f = fresnel(cos_i, eta, cos_t);
                    PathState reflected = s;
                    reflected.o = p + n * eps;
                    reflected.d = normalize(reflect(s.d, n));
                    reflected.entered = false;
                    PathState refracted = s;
                    refracted.o = p - n * eps;
                    refracted.d = refract_direction(s.d, n, eta, cos_i, cos_t);
                    refracted.medium = next_medium;
                    refracted.entered = next_medium != NS_NONE;
                    if (f >= 1.0) {
                        s = reflected;
                    } else if (top < NS_BRANCH_STACK) {
                        reflected.w *= f;
                        branch_stack[top++] = reflected;
                        s = refracted;
                        s.w *= 1.0 - f;
                    } else {
                        // Stack full: pick one branch with the Fresnel probability; the
                        // weight stays unchanged (f / f and (1 - f) / (1 - f)).
                        s = rnd() < f ? reflected : refracted;
                    }
                }
            }
        }
        if (terminated) {
            if (top == 0u)
                alive = false;
            else
                s = branch_stack[--top];
        }
    }
    return radiance;
}

// Camera sample i of a pixel: where in the pixel, its random stream and its light numbers
// are functions of the pixel and i alone, so the image does not depend on how the samples
// were split into dispatches, and an added sample (i >= spp) is one the pixel had not taken.
vec3 camera_sample(uvec2 xy, uint pixel, uint i)
{
    uint width = params.image.x, height = params.image.y;
    uint pixel_seed = pcg_hash(pcg_hash(params.image.w) + pixel);
    DirectNumbers numbers;
    numbers.samples = params.surface.x;
    numbers.shift = uvec2(pcg_hash(pixel_seed ^ 0x5bd1e995u), pcg_hash(pixel_seed ^ 0x27d4eb2fu));
    numbers.first = i * params.surface.x;
    uvec2 jitter_shift =
        uvec2(pcg_hash(pixel_seed ^ 0x68e31da4u), pcg_hash(pixel_seed ^ 0xb5297a4du));
    rng_state = pcg_hash(pixel_seed + i);
    // Where in the pixel: point i of the R2 sequence under the pixel's own shift, so that
    // its spp samples cover it evenly (an edge or a highlight's footprint is then
    // measured, not drawn: the surface image 0.5-5 dB nearer a converged one at 4 spp,
    // docs/bench.md). Each point is uniform in the pixel: unbiased.
    vec2 jitter = r2_point(i, jitter_shift);
    float u = (float(xy.x) + jitter.x) / float(width);
    float v = (float(xy.y) + jitter.y) / float(height);
    vec3 d = params.cam_forward.xyz + params.cam_right.xyz * ((2.0 * u - 1.0) * params.cam_position.w) +
             params.cam_up.xyz * ((1.0 - 2.0 * v) * params.cam_right.w);
    PathState s;
    s.o = params.cam_position.xyz;
    s.d = normalize(d);
    s.w = vec3(1.0);
    s.medium = NS_NONE;
    s.depth = 0u;
    s.entered = false;
    s.weak = false;
    return trace_path(s, pixel, i, numbers);
}

// lavapipe stops loops silently once an invocation has run 65535 iterations in all
// (shared.h), and from then on every loop ends after its first iteration; its count
// includes iterations loop_count does not see (a leaf's primitives, the planes), so a loop
// of two iterations here tells whether that happened anywhere above. Its trip count comes
// from the push block so that the compiler cannot unroll it away.
void check_loop_limit()
{
    uint canary = 0u;
    for (uint i = 0u; i < 2u + (push.pad0 >> 31); i++)
        canary++;
    if (canary != 2u || (params.limits.x != 0u && loop_count > params.limits.x))
        atomicAdd(counters[NS_COUNTER_LOOP_LIMIT], 1u);
}

void main()
{
    uint width = params.image.x, height = params.image.y;
    if (push.added_count != 0u) {
        // One added sample per invocation, the groups in one dimension.
        uint entry = push.first_sample +
                     interleaved_group(gl_WorkGroupID.x, gl_NumWorkGroups.x) *
                         (NS_CAMERA_GROUP_X * NS_CAMERA_GROUP_Y) +
                     gl_LocalInvocationIndex;
        if (entry >= push.added_count)
            return;
        recording = false;
        uint pixel = added[entry].words.x;
        uint i = added[entry].words.y;
        vec3 radiance = camera_sample(uvec2(pixel % width, pixel / width), pixel, i);
        check_loop_limit();
        added[entry].words = uvec4(floatBitsToUint(radiance), 0u);
        return;
    }
    uvec2 xy = interleaved_invocation_xy();
    if (xy.x >= width || xy.y >= height)
        return;
    uint pixel = xy.y * width + xy.x;
    // The pixel's sum and sum of squared lengths: render.c reads the samples' spread from
    // them (render.adaptive_spp).
    vec3 sum = vec3(0.0);
    float squares = 0.0;
    uint spp = params.image.z;
    for (uint i = push.first_sample; i < push.first_sample + push.sample_count; i++) {
        vec3 radiance = camera_sample(xy, pixel, i);
        sum += radiance;
        squares += dot(radiance, radiance);
    }
    check_loop_limit();
    vec4 previous = push.first_sample == 0u ? vec4(0.0) : pixels[pixel];
    pixels[pixel] = previous + vec4(sum, squares) / float(spp);
}
