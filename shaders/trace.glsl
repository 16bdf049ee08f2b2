// trace.glsl — ray/primitive intersection and stack-based BVH traversal, shared by the
// camera pass and the BVH test shader. Needs shared.h included first. Declares bindings
// 0 (parameters), 1 (BVH nodes) and 2 (primitives, planes after the BVH primitives), both
// texel buffers read with node_at and prim_at.
#extension GL_KHR_shader_subgroup_arithmetic : require

layout(std140, binding = 0) uniform ParamsBlock { GpuParams ns_params[1]; };
#define params ns_params[NS_OPAQUE_ZERO] /* shared.h: NS_OPAQUE_ZERO */
// The BVH's nodes and primitives are read as texel buffers of 16-byte texels, not as storage
// buffers: lavapipe reads a storage buffer at addresses that differ per lane one lane and one
// component at a time, and a texel with its texture path: 17% less traversal time
// (docs/bench.md, *Texel buffers*). Storage texel buffers (imageLoad), not uniform ones
// (texelFetch): lavapipe's image load is 6% cheaper still (*Storage texel buffers*). The
// render's pipelines bind them so (render/pipelines.c, NS_TRACE_TEXEL_BINDINGS).
layout(binding = 1, rgba32ui) uniform readonly restrict uimageBuffer node_texels;
layout(binding = 2, rgba32ui) uniform readonly restrict uimageBuffer prim_texels;

GpuNode node_at(uint i)
{
    uvec4 a = imageLoad(node_texels, int(2u * i)), b = imageLoad(node_texels, int(2u * i + 1u));
    GpuNode n;
    n.bmin = uintBitsToFloat(a.xyz);
    n.first = a.w;
    n.bmax = uintBitsToFloat(b.xyz);
    n.count = b.w;
    return n;
}

GpuPrim prim_at(uint i)
{
    GpuPrim p;
    p.a = uintBitsToFloat(imageLoad(prim_texels, int(4u * i)));
    p.b = uintBitsToFloat(imageLoad(prim_texels, int(4u * i + 1u)));
    p.c = uintBitsToFloat(imageLoad(prim_texels, int(4u * i + 2u)));
    p.info = imageLoad(prim_texels, int(4u * i + 3u));
    return p;
}

const float NS_INF = 1.0 / 0.0;

// Loop iterations this invocation has run (see NS_LAVAPIPE_LOOP_BUDGET in shared.h).
uint loop_count = 0u;

bool out_of_budget()
{
    loop_count++;
    return params.limits.x != 0u && loop_count > params.limits.x;
}

struct Hit {
    float t;
    uint prim;     // index into prims[]
    vec3 normal;   // outward normal at the hit (unit): the shading normal of a smooth
                   // triangle where it is consistent with the geometry, else the geometric one
    bool front;    // the ray arrived from the outside (against the outward geometric normal)
};

// Nearest sphere root in (tmin, tmax), or -1. d is unit length. The discriminant is taken
// as r^2 - |oc - b d|^2 (Ray Tracing Gems ch. 7) to avoid cancellation far from the sphere.
float hit_sphere(vec3 o, vec3 d, vec4 s, float tmin, float tmax)
{
    vec3 oc = o - s.xyz;
    float b = dot(oc, d);
    vec3 perp = oc - b * d;
    float disc = s.w * s.w - dot(perp, perp);
    if (disc < 0.0)
        return -1.0;
    float q = sqrt(disc);
    float t = -b - q;
    if (t <= tmin)
        t = -b + q;
    return (t > tmin && t < tmax) ? t : -1.0;
}

// Slab test: entry distance clipped to tmin (so a ray starting inside reports its exit).
float hit_box(vec3 o, vec3 inv_d, vec3 bmin, vec3 bmax, float tmin, float tmax)
{
    vec3 t0 = (bmin - o) * inv_d, t1 = (bmax - o) * inv_d;
    vec3 tn = min(t0, t1), tf = max(t0, t1);
    float near = max(max(tn.x, tn.y), tn.z), far = min(min(tf.x, tf.y), tf.z);
    if (near > far)
        return -1.0;
    float t = near > tmin ? near : far;
    return (t > tmin && t < tmax) ? t : -1.0;
}

// Does the ray overlap the node's box anywhere in [tmin, tmax]? Returns the entry distance.
// inv_d = 1 / d. Each axis's entry plane is chosen by the sign of inv_d (as in PBRT), and the
// distances are folded into [tmin, tmax] by selects that keep the bound when a distance is
// NaN: a ray parallel to a slab (inv_d infinite) that starts on one of its planes gives
// 0 * inf = NaN there, and is inside that slab. Selects also cost lavapipe less than GLSL's
// min and max, which spend a compare and a blend more on returning the other operand of a
// NaN. (Taking min and max of the two planes' distances instead drops such a ray when it
// starts on a box's face: gpu_bvh, *axis-aligned rays on box planes*.)
float enter_box(vec3 o, vec3 inv_d, vec3 bmin, vec3 bmax, float tmin, float tmax)
{
    bvec3 negative = lessThan(inv_d, vec3(0.0));
    vec3 tn = (mix(bmin, bmax, negative) - o) * inv_d, tf = (mix(bmax, bmin, negative) - o) * inv_d;
    float near = tmin, far = tmax;
    near = tn.x > near ? tn.x : near;
    near = tn.y > near ? tn.y : near;
    near = tn.z > near ? tn.z : near;
    far = tf.x < far ? tf.x : far;
    far = tf.y < far ? tf.y : far;
    far = tf.z < far ? tf.z : far;
    return near <= far ? near : NS_INF;
}

// Moller-Trumbore, both faces.
float hit_triangle(vec3 o, vec3 d, vec3 a, vec3 b, vec3 c, float tmin, float tmax)
{
    vec3 e1 = b - a, e2 = c - a;
    vec3 p = cross(d, e2);
    float det = dot(e1, p);
    if (det == 0.0)
        return -1.0;
    float inv = 1.0 / det;
    vec3 s = o - a;
    float u = dot(s, p) * inv;
    if (u < 0.0 || u > 1.0)
        return -1.0;
    vec3 q = cross(s, e1);
    float v = dot(d, q) * inv;
    if (v < 0.0 || u + v > 1.0)
        return -1.0;
    float t = dot(e2, q) * inv;
    return (t > tmin && t < tmax) ? t : -1.0;
}

float hit_plane(vec3 o, vec3 d, vec3 p0, vec3 n, float tmin, float tmax)
{
    float denom = dot(d, n);
    if (denom == 0.0)
        return -1.0;
    float t = dot(p0 - o, n) / denom;
    return (t > tmin && t < tmax) ? t : -1.0;
}

float hit_prim(uint i, vec3 o, vec3 d, vec3 inv_d, float tmin, float tmax)
{
    GpuPrim p = prim_at(i);
    uint kind = p.info.x;
    if (kind == NS_PRIM_SPHERE)
        return hit_sphere(o, d, p.a, tmin, tmax);
    if (kind == NS_PRIM_BOX)
        return hit_box(o, inv_d, p.a.xyz, p.b.xyz, tmin, tmax);
    if (kind == NS_PRIM_TRIANGLE)
        return hit_triangle(o, d, p.a.xyz, p.b.xyz, p.c.xyz, tmin, tmax);
    return hit_plane(o, d, p.a.xyz, p.b.xyz, tmin, tmax);
}

vec3 outward_normal(uint i, vec3 pos)
{
    GpuPrim p = prim_at(i);
    uint kind = p.info.x;
    if (kind == NS_PRIM_SPHERE)
        return normalize(pos - p.a.xyz);
    if (kind == NS_PRIM_BOX) {
        // The face whose slab the point is closest to, measured in half extents.
        vec3 centre = 0.5 * (p.a.xyz + p.b.xyz);
        vec3 half_size = max(0.5 * (p.b.xyz - p.a.xyz), vec3(1e-30));
        vec3 q = (pos - centre) / half_size;
        vec3 aq = abs(q);
        if (aq.x >= aq.y && aq.x >= aq.z)
            return vec3(sign(q.x), 0.0, 0.0);
        if (aq.y >= aq.z)
            return vec3(0.0, sign(q.y), 0.0);
        return vec3(0.0, 0.0, sign(q.z));
    }
    if (kind == NS_PRIM_TRIANGLE)
        return normalize(cross(p.b.xyz - p.a.xyz, p.c.xyz - p.a.xyz));
    return p.b.xyz;
}

// A unit normal stored by scene_gpu.c's store_normal (octahedral, 2 x 16 bits).
vec3 decode_normal(float stored)
{
    vec2 e = unpackSnorm2x16(floatBitsToUint(stored));
    vec3 v = vec3(e, 1.0 - abs(e.x) - abs(e.y));
    if (v.z < 0.0)
        v.xy = (1.0 - abs(v.yx)) * vec2(v.x >= 0.0 ? 1.0 : -1.0, v.y >= 0.0 ? 1.0 : -1.0);
    return normalize(v);
}

// The shading normal of smooth triangle p at pos: its vertex normals blended by the
// barycentric coordinates of pos.
vec3 blended_normal(GpuPrim p, vec3 pos)
{
    vec3 e1 = p.b.xyz - p.a.xyz, e2 = p.c.xyz - p.a.xyz, q = pos - p.a.xyz;
    vec3 n = cross(e1, e2);
    float inv = 1.0 / dot(n, n);
    float wb = dot(cross(q, e2), n) * inv, wc = dot(cross(e1, q), n) * inv;
    vec3 s = (1.0 - wb - wc) * decode_normal(p.a.w) + wb * decode_normal(p.b.w) +
             wc * decode_normal(p.c.w);
    float len = length(s);
    return len > 1e-6 ? s / len : vec3(0.0);
}

// The normal a hit reports: a smooth triangle's blended normal, unless it would contradict
// the geometry for this ray (Veach's shading-normal problem): it must face the ray as the
// geometric normal does, and the mirror direction about it must leave on the ray's side of
// the surface. Otherwise the geometric normal, as for a flat triangle.
vec3 hit_normal(uint i, vec3 d, vec3 pos, vec3 geometric)
{
    GpuPrim p = prim_at(i);
    if (p.info.x != NS_PRIM_TRIANGLE || (p.info.w & NS_PRIM_SMOOTH) == 0u)
        return geometric;
    vec3 s = blended_normal(p, pos);
    float side = dot(d, geometric) < 0.0 ? 1.0 : -1.0; // facing the ray: side * normal
    bool faces_ray = dot(d, side * s) < 0.0;
    bool mirror_stays_out = dot(reflect(d, side * s), side * geometric) > 0.0;
    return faces_ray && mirror_stays_out ? s : geometric;
}

// What the traversal stacks for a node, from the texels its parent read with its box, so
// that popping it reads nothing: an inner node as NS_ENTRY_PAIR | the index of its first
// child (the second follows it); a leaf as NS_ENTRY_LEAF | count << NS_BVH_ENTRY_COUNT_SHIFT |
// its first primitive (render/bvh.c keeps leaves within NS_BVH_LEAF_ENTRY_MAX primitives and
// BVHs within NS_BVH_MAX_PRIMS).
const uint NS_ENTRY_LEAF = 0x80000000u, NS_ENTRY_PAIR = 0x40000000u;

uint node_entry(GpuNode n)
{
    return n.count == 0u ? (NS_ENTRY_PAIR | n.first)
                         : (NS_ENTRY_LEAF | (n.count << NS_BVH_ENTRY_COUNT_SHIFT) | n.first);
}

void open_entry(uint e, out uint first, out uint count)
{
    bool leaf = (e & NS_ENTRY_LEAF) != 0u;
    first = e & (leaf ? NS_BVH_MAX_PRIMS - 1u : ~(NS_ENTRY_LEAF | NS_ENTRY_PAIR));
    count = leaf ? (e >> NS_BVH_ENTRY_COUNT_SHIFT) & NS_BVH_LEAF_ENTRY_MAX : 0u;
}

// An inner node's two children (at first, first + 1), nearer first: where the ray enters
// each box within [tmin, tmax] (NS_INF: it misses it), and their stack entries.
void children_near_far(uint first, vec3 o, vec3 inv_d, float tmin, float tmax,
                       out uint near_child, out uint far_child, out float t_near, out float t_far)
{
    GpuNode nl = node_at(first), nr = node_at(first + 1u);
    float tl = enter_box(o, inv_d, nl.bmin, nl.bmax, tmin, tmax);
    float tr = enter_box(o, inv_d, nr.bmin, nr.bmax, tmin, tmax);
    uint l = node_entry(nl), r = node_entry(nr);
    bool swap = tl > tr;
    near_child = swap ? r : l;
    far_child = swap ? l : r;
    t_near = swap ? tr : tl;
    t_far = swap ? tl : tr;
}

bool is_pair_entry(uint e) { return (e & (NS_ENTRY_LEAF | NS_ENTRY_PAIR)) == NS_ENTRY_PAIR; }

// trace_scene's pop: into `current` the next stacked entry that no hit found since it was
// pushed has overtaken (a hit nearer than where the ray enters its box), or NS_NONE. A macro
// because GLSL passes arrays by value.
#define NS_POP_LIVE_ENTRY()                                                                    \
    while (current == NS_NONE && sp > 0u) {                                                    \
        inner++;                                                                               \
        sp--;                                                                                  \
        current = stack_enter[sp] > best ? NS_NONE : stack[sp];                                \
    }

// Nearest hit in (tmin, tmax) over the BVH primitives and the planes.
//
// Front to back: of an inner node's children the nearer is visited next; the farther is
// stacked with the distance where the ray enters its box, and dropped when popped if a hit
// nearer than that has been found since (the same test as its box against the shrunken
// interval, without reading the node or testing the box again).
//
// While-while (Aila & Laine 2009): each lane takes inner nodes in a loop of its own until it
// holds a leaf (or nothing), then the group tests all its lanes' leaves together. On lavapipe
// an iteration costs the whole loop body for the SIMD group, so one loop doing both made every
// iteration pay for a leaf's primitives and an inner node's boxes whenever its lanes
// disagreed: this way primary rays trace 26% faster (docs/bench.md). A lane waits while the
// others finish their inner nodes, so the group runs more iterations than any one lane does:
// lavapipe's loop limit counts the group's, so the count (loop_count, out_of_budget) adds the
// most inner iterations any lane of the group took in each round, plus a round's loop exits.
// NS_TRACE_ONE_LOOP (pt.comp) keeps the single loop of nodes and leaves, which is what pt's
// yield budget on lavapipe was measured on (NS_PT_YIELD_LAVAPIPE); with this loop pt's
// invocations ran past lavapipe's limit in gpu_pt_consistency and gpu_single.
bool trace_scene(vec3 o, vec3 d, float tmin, float tmax, out Hit hit)
{
    vec3 inv_d = 1.0 / d;
    float best = tmax;
    uint best_prim = NS_NONE;

    uint stack[NS_BVH_STACK];
    float stack_enter[NS_BVH_STACK];
    uint sp = 0u;
#ifdef NS_TRACE_ONE_LOOP
    if (params.counts.w > 0u) {
        GpuNode root = node_at(0u);
        stack[sp] = node_entry(root);
        stack_enter[sp++] = enter_box(o, inv_d, root.bmin, root.bmax, tmin, best);
    }
    while (sp > 0u) {
        if (out_of_budget())
            break;
        sp--;
        if (stack_enter[sp] > best)
            continue;
        uint first, count;
        open_entry(stack[sp], first, count);
        if (count > 0u) {
            for (uint i = first; i < first + count; i++) {
                float t = hit_prim(i, o, d, inv_d, tmin, best);
                if (t > 0.0) {
                    best = t;
                    best_prim = i;
                }
            }
            continue;
        }
        // Push the farther child, then the nearer one.
        uint l, r;
        float tl, tr;
        children_near_far(first, o, inv_d, tmin, best, l, r, tl, tr);
        if (tr != NS_INF && sp < NS_BVH_STACK) {
            stack[sp] = r;
            stack_enter[sp++] = tr;
        }
        if (tl != NS_INF && sp < NS_BVH_STACK) {
            stack[sp] = l;
            stack_enter[sp++] = tl;
        }
    }
#else
    uint current = NS_NONE;
    if (params.counts.w > 0u) {
        GpuNode root = node_at(0u);
        if (enter_box(o, inv_d, root.bmin, root.bmax, tmin, best) != NS_INF)
            current = node_entry(root);
    }
    uint inner = 0u; // this lane's inner iterations and pops in the round
    while (current != NS_NONE) {
        while (is_pair_entry(current)) {
            inner++;
            if (params.limits.x != 0u && loop_count + inner > params.limits.x)
                break;
            uint l, r;
            float tl, tr;
            children_near_far(current & ~NS_ENTRY_PAIR, o, inv_d, tmin, best, l, r, tl, tr);
            if (tr != NS_INF && sp < NS_BVH_STACK) { // (tl <= tr: both children are entered)
                stack[sp] = r;
                stack_enter[sp++] = tr;
            }
            current = tl != NS_INF ? l : NS_NONE;
            NS_POP_LIVE_ENTRY()
        }
        // The round's group iterations: the most any lane took, 3 for the loops' exits (the
        // inner loop's and the pops') and the leaf's loop, and out_of_budget's 1 for this one.
        loop_count += subgroupMax(inner) + 3u;
        inner = 0u;
        if (out_of_budget() || current == NS_NONE)
            break;
        uint first, count;
        open_entry(current, first, count);
        for (uint i = first; i < first + count; i++) {
            float t = hit_prim(i, o, d, inv_d, tmin, best);
            if (t > 0.0) {
                best = t;
                best_prim = i;
            }
        }
        current = NS_NONE;
        NS_POP_LIVE_ENTRY()
    }
#endif
#undef NS_POP_LIVE_ENTRY

    uint first_plane = params.prims.x;
    for (uint i = first_plane; i < first_plane + params.prims.y; i++) {
        float t = hit_prim(i, o, d, inv_d, tmin, best);
        if (t > 0.0) {
            best = t;
            best_prim = i;
        }
    }

    hit.t = best;
    hit.prim = best_prim;
    hit.normal = vec3(0.0, 0.0, 1.0);
    hit.front = true;
    if (best_prim == NS_NONE)
        return false;
    vec3 geometric = outward_normal(best_prim, o + best * d);
    hit.front = dot(d, geometric) < 0.0;
    hit.normal = hit_normal(best_prim, d, o + best * d, geometric);
    return true;
}

// What a shadow ray meets in (tmax > t > tmin), for the any-hit query of shadow rays: the BVH
// primitives and the planes in any order, stopping at the first primitive met; the nearest
// hit is never needed. NS_SHADOW_BLOCKED: that primitive blocks (a diffuse surface, or a
// boundary the ray does not cross). NS_SHADOW_CROSSES: it carries one of the flags in
// `crosses` (NS_PRIM_SHADOW_PASSES: an index-matched medium's boundary, which every shadow
// ray crosses with its Beer-Lambert factor; NS_PRIM_REFRACTS: a refracting one, which only
// single scattering's cross), so the caller must walk the crossings in order
// (transmittance); stopping there keeps such rays no dearer than that walk alone.
// NS_SHADOW_CLEAR: nothing. tmax never shrinks, so a node's box is tested once, before it is
// pushed.
const uint NS_SHADOW_CLEAR = 0u, NS_SHADOW_BLOCKED = 1u, NS_SHADOW_CROSSES = 2u;

uint trace_shadow(vec3 o, vec3 d, float tmin, float tmax, uint crosses)
{
    vec3 inv_d = 1.0 / d;
    uint stack[NS_BVH_STACK];
    uint sp = 0u;
    uint current = NS_NONE;
    if (params.counts.w > 0u) {
        GpuNode root = node_at(0u);
        if (enter_box(o, inv_d, root.bmin, root.bmax, tmin, tmax) != NS_INF)
            current = node_entry(root);
    }
    while (current != NS_NONE || sp > 0u) {
        if (out_of_budget())
            break;
        if (current == NS_NONE)
            current = stack[--sp];
        uint first, count;
        open_entry(current, first, count);
        current = NS_NONE;
        if (count > 0u) {
            for (uint i = first; i < first + count; i++)
                if (hit_prim(i, o, d, inv_d, tmin, tmax) > 0.0)
                    return (prim_at(i).info.w & crosses) != 0u ? NS_SHADOW_CROSSES
                                                               : NS_SHADOW_BLOCKED;
            continue;
        }
        // The nearer child next: what is met near the origin ends the query sooner.
        uint l, r;
        float tl, tr;
        children_near_far(first, o, inv_d, tmin, tmax, l, r, tl, tr);
        if (tl != NS_INF) {
            current = l;
            if (tr != NS_INF && sp < NS_BVH_STACK)
                stack[sp++] = r;
        }
    }
    uint first_plane = params.prims.x;
    for (uint i = first_plane; i < first_plane + params.prims.y; i++)
        if (hit_prim(i, o, d, inv_d, tmin, tmax) > 0.0)
            return (prim_at(i).info.w & crosses) != 0u ? NS_SHADOW_CROSSES : NS_SHADOW_BLOCKED;
    return NS_SHADOW_CLEAR;
}
