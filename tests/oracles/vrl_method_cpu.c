/* vrl_method_cpu.c — the tests' oracle of the `vrl` method's gather (render/vrl_method.c,
 * shaders/vrl_gather.comp): its estimator on the CPU without visibility, line by line in
 * float, with the same random numbers. It lives with the tests because only they use it: the
 * library keeps the GPU path alone. Keep it in step with vrl_gather.comp; gpu_vrl_method
 * compares the two. */
#include <math.h>
#include <string.h>

#include "vrl_method_cpu.h"

static uint32_t pcg_hash(uint32_t v)
{
    uint32_t state = v * 747796405u + 2891336453u;
    uint32_t word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

static float unit_float(uint32_t h)
{
    return (float)(h >> 8u) * (1.0f / 16777216.0f);
}

static float dot3(const float *a, const float *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static float hg_phase(float cos_t, float g)
{
    float denom = 1.0f + g * g - 2.0f * g * cos_t;
    return (1.0f - g * g) / (4.0f * (float)M_PI * denom * sqrtf(denom));
}

static float clampf(float x, float lo, float hi)
{
    return x < lo ? lo : x > hi ? hi : x;
}

static float asinh_exp(float x)
{
    float root = sqrtf(1.0f + x * x);
    return x >= 0.0f ? x + root : 1.0f / (root - x);
}

static void pair_estimate_cpu(const float e[3], const float dc[3], float lc, const GpuVrl *vrl,
                              const GpuMaterial *m, float xi_t, float xi_u, float out[3])
{
    const float *w = vrl->direction;
    float l = vrl->length, r[3], p[3], x[3], y[3], v[3];
    for (int k = 0; k < 3; k++)
        r[k] = e[k] - vrl->origin[k];
    float b = dot3(dc, w);
    float sin2 = fmaxf(0.0f, 1.0f - b * b), s = sqrtf(sin2);
    float dd = dot3(dc, r), ee = dot3(w, r);
    float floor_h = 1e-6f * fmaxf(lc, l);
    float t, inv_pdf_t;
    int parallel = s < 1e-3f;
    if (!parallel) {
        float t0 = (b * ee - dd) / sin2, u0 = (ee - b * dd) / sin2;
        for (int k = 0; k < 3; k++)
            p[k] = r[k] + t0 * dc[k] - u0 * w[k];
        float h0 = fmaxf(sqrtf(dot3(p, p)), floor_h);
        float kk = s / h0;
        float span = logf(asinh_exp(kk * (lc - t0)) / asinh_exp(-kk * t0));
        float big_e = expf(xi_t * span);
        float q = sqrtf(1.0f / (kk * kk) + t0 * t0);
        float sinh_part = 0.5f * (big_e - 1.0f / big_e);
        t = t0 <= 0.0f ? -t0 * (big_e - 1.0f) * (big_e - 1.0f) / (2.0f * big_e) + q * sinh_part
                       : t0 * (big_e - 1.0f) / big_e + sinh_part / (kk * kk * (q + t0));
        t = clampf(t, 0.0f, lc);
        inv_pdf_t = span / s;
    } else {
        t = xi_t * lc;
        inv_pdf_t = lc;
    }
    for (int k = 0; k < 3; k++)
        x[k] = e[k] + t * dc[k];
    for (int k = 0; k < 3; k++)
        p[k] = x[k] - vrl->origin[k];
    float uc = dot3(p, w);
    for (int k = 0; k < 3; k++)
        p[k] -= uc * w[k];
    float hx = fmaxf(sqrtf(dot3(p, p)), floor_h);
    float th0 = atan2f(-uc, hx), th1 = atan2f(l - uc, hx);
    float u = clampf(uc + hx * tanf(th0 + (th1 - th0) * xi_u), 0.0f, l);
    float geometry = (th1 - th0) * inv_pdf_t / (parallel ? hx : 1.0f);
    for (int k = 0; k < 3; k++) {
        y[k] = vrl->origin[k] + u * w[k];
        v[k] = x[k] - y[k];
    }
    float dist = sqrtf(dot3(v, v));
    for (int k = 0; k < 3; k++)
        out[k] = 0.0f;
    if (!(dist > 0.0f))
        return;
    for (int k = 0; k < 3; k++)
        v[k] /= dist;
    float g = m->sigma_s[3];
    float phases = hg_phase(dot3(w, v), g) * hg_phase(-dot3(v, dc), g);
    for (int k = 0; k < 3; k++)
        out[k] = m->sigma_s[k] * m->sigma_s[k] * expf(-m->sigma_t[k] * (t + u + dist)) * phases *
                 geometry;
}

void ns_vrl_method_gather_cpu(const GpuMaterial *materials, const GpuSegment *segments,
                              uint32_t segment_count, const GpuVrl *vrls, uint32_t vrl_count,
                              uint32_t seed, float (*out_double)[4], float (*out_multiple)[4])
{
    for (uint32_t i = 0; i < segment_count; i++) {
        const GpuSegment *seg = &segments[i];
        float d[3];
        for (int k = 0; k < 3; k++)
            d[k] = seg->exit[k] - seg->entry[k];
        float lc = sqrtf(dot3(d, d));
        uint32_t seg_seed = pcg_hash(pcg_hash(seed ^ 0x68e31da4u) + i);
        memset(out_double[i], 0, sizeof out_double[i]);
        memset(out_multiple[i], 0, sizeof out_multiple[i]);
        for (uint32_t k = 0; k < vrl_count; k++) {
            const GpuVrl *vrl = &vrls[k];
            if (vrl->material != seg->material)
                continue;
            uint32_t h1 = pcg_hash(seg_seed ^ pcg_hash(k));
            uint32_t h2 = pcg_hash(h1);
            float c[3];
            pair_estimate_cpu(seg->entry, seg->direction, lc, vrl, &materials[seg->material],
                              unit_float(h1), unit_float(h2), c);
            float *o = vrl->events == 0 ? out_double[i] : out_multiple[i];
            for (int ch = 0; ch < 3; ch++)
                o[ch] += vrl->power[ch] * c[ch];
        }
    }
}
