/* nn_reconstruct.c — packs the networks for shaders/nn_reconstruct.comp, dispatches it over a
 * whole table (3 channels x 2 orders) and optionally renormalises to the exact energy. */
#include "nn_reconstruct.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "nn_shared.h"
#include "pipelines.h"

_Static_assert(NS_NN_B3_OFF + 1 == NS_NN_NET_VEC4, "nn_shared.h layout");
_Static_assert(NS_NN_W2_OFF == NS_NN_B1_OFF + NS_NN_H4, "nn_shared.h layout");

static double seconds_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Scatters one network's parameters into the padded vec4 layout of nn_shared.h. */
static void pack_network(const ns_nn_weights *w, ns_vec4 *net)
{
    float *f = &net[0][0];
    memset(f, 0, NS_NN_NET_VEC4 * sizeof(ns_vec4));
    const float *p = w->p;
    for (int j = 0; j < NS_NN_HIDDEN; j++) {
        for (int k = 0; k < NS_NN_INPUTS; k++)
            f[4 * (NS_NN_W1_OFF + 2 * j) + k] = p[NS_NN_OFF_W1 + j * NS_NN_INPUTS + k];
        f[4 * NS_NN_B1_OFF + j] = p[NS_NN_OFF_B1 + j];
        for (int k = 0; k < NS_NN_HIDDEN; k++)
            f[4 * (NS_NN_W2_OFF + j * NS_NN_H4) + k] = p[NS_NN_OFF_W2 + j * NS_NN_HIDDEN + k];
        f[4 * NS_NN_B2_OFF + j] = p[NS_NN_OFF_B2 + j];
        f[4 * NS_NN_W3_OFF + j] = p[NS_NN_OFF_W3 + j];
    }
    f[4 * NS_NN_B3_OFF] = p[NS_NN_OFF_B3];
}

static void pack_common(struct GpuNnParams *gp, const ns_nn_weights *const nets[2])
{
    for (int o = 0; o < 2; o++) {
        pack_network(nets[o], gp->net + o * NS_NN_NET_VEC4);
        const ns_nn_header *h = &nets[o]->h;
        gp->target[o][0] = (float)h->target;
        gp->target[o][1] = h->target_eps;
        gp->target[o][2] = h->target_mean;
        gp->target[o][3] = h->target_scale;
    }
}

static int check_nets(const ns_nn_weights *const nets[2], ns_error *err)
{
    for (int o = 0; o < 2; o++) {
        if (!nets[o] || nets[o]->h.order != (uint32_t)o)
            return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                           "weights: the %s network is missing or "
                           "is the other order's",
                           o ? "multiple" : "double");
        /* Both networks must read the same inputs: one input table serves both orders. */
        const ns_nn_header *a = &nets[0]->h, *b = &nets[o]->h;
        if (a->input_map != b->input_map || a->extent != b->extent || a->sinh_scale != b->sinh_scale ||
            a->albedo_max != b->albedo_max || a->g_min != b->g_min || a->g_max != b->g_max)
            return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                           "weights: double and multiple networks normalise inputs differently");
    }
    return 0;
}

int ns_nn_gpu_create(gpu_device *dev, ns_nn_gpu *nn, ns_error *err)
{
    memset(nn, 0, sizeof *nn);
    /* Their rows in render/pipelines.c's table say "with the networks": made here, in a
     * context and in an nn session alike. */
    int status = ns_pipeline_make(dev, NS_PIPELINE_NN_RECONSTRUCT, &nn->pipeline, err);
    if (!status)
        status = ns_pipeline_make(dev, NS_PIPELINE_NN_INTERPOLATE, &nn->interpolate, err);
    if (!status)
        status = gpu_buffer_create(dev, &nn->params,
                                   &(gpu_buffer_desc){.size = sizeof(struct GpuNnParams),
                                                      .kind = GPU_BUFFER_UNIFORM,
                                                      .label = "ns.nn.params"},
                                   err);
    if (!status)
        status = gpu_buffer_create(dev, &nn->dummy,
                                   &(gpu_buffer_desc){.size = 64, .label = "ns.nn.dummy"}, err);
    nn->created = 1;
    /* Warm-up: a zero cell count returns at once, but the driver compiles the pipeline. The
     * generic gpu_pipeline_warm binds a 256-byte uniform buffer, smaller than GpuNnParams. */
    if (!status) {
        gpu_buffer *bound[3] = {&nn->params, &nn->dummy, &nn->dummy};
        status = gpu_dispatch(dev, &nn->pipeline, bound, 3, (uint32_t[3]){1, 1, 1}, err);
        if (!status)
            status = gpu_dispatch(dev, &nn->interpolate, bound, 3, (uint32_t[3]){1, 1, 1}, err);
    }
    if (status)
        ns_nn_gpu_destroy(dev, nn);
    return status;
}

void ns_nn_gpu_destroy(gpu_device *dev, ns_nn_gpu *nn)
{
    if (!nn->created)
        return;
    gpu_buffer_destroy(dev, &nn->dummy);
    gpu_buffer_destroy(dev, &nn->params);
    gpu_pipeline_destroy(dev, &nn->interpolate);
    gpu_pipeline_destroy(dev, &nn->pipeline);
    memset(nn, 0, sizeof *nn);
}

static double mid(const double *edges, uint32_t i)
{
    return 0.5 * (edges[i] + edges[i + 1]);
}

static int check_grid(const ns_nn_grid *g, ns_error *err)
{
    for (int a = 0; a < 4; a++) {
        if (g->n[a] < 1 || g->n[a] > NS_NN_MAX_AXIS || !g->edges[a])
            return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "table axis %d: %u bins (1 to %u)", a,
                           g->n[a], NS_NN_MAX_AXIS);
    }
    uint64_t cells = (uint64_t)g->n[0] * g->n[1] * g->n[2] * g->n[3];
    if (cells * 6 * sizeof(float) > (128u << 20)) /* lavapipe's storage buffer cap */
        return ns_fail(err, NS_ERR_LIMIT, "table of %llu cells: 6 tables exceed 128 MiB",
                       (unsigned long long)cells);
    return 0;
}

double ns_nn_grid_energy(const ns_nn_grid *grid, const float *j)
{
    const double *ez = grid->edges[0], *er = grid->edges[1], *et = grid->edges[2],
                 *ep = grid->edges[3];
    double total = 0.0;
    size_t c = 0;
    for (uint32_t iz = 0; iz < grid->n[0]; iz++)
        for (uint32_t ir = 0; ir < grid->n[1]; ir++) {
            double vol = M_PI * (er[ir + 1] * er[ir + 1] - er[ir] * er[ir]) * (ez[iz + 1] - ez[iz]);
            double spatial = 0.0;
            for (uint32_t it = 0; it < grid->n[2]; it++) {
                double dcos = cos(et[it]) - cos(et[it + 1]);
                for (uint32_t ip = 0; ip < grid->n[3]; ip++, c++)
                    spatial += j[c] * dcos * (ep[ip + 1] - ep[ip]) * 2.0;
            }
            total += spatial * vol;
        }
    return total;
}

double ns_nn_exact_energy(int order, double a)
{
    return order == 0 ? a * a : a * a * a / (1.0 - a);
}

ns_nn_sampling ns_nn_sampling_default(void)
{
    return (ns_nn_sampling){.stride = {4, 4, 1, 2}, .full_radius = 2.0};
}

ns_nn_sampling ns_nn_sampling_every_cell(void)
{
    return (ns_nn_sampling){.stride = {1, 1, 1, 1}, .full_radius = 0.0};
}

static int check_sampling(const ns_nn_sampling *s, ns_error *err)
{
    for (int a = 0; a < 4; a++)
        if (s->stride[a] < 1 || s->stride[a] > 16)
            return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "sampling stride[%d]: %u (1 to 16)", a,
                           s->stride[a]);
    if (!(s->full_radius >= 0))
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "sampling full_radius: %g (>= 0 mfp)",
                       s->full_radius);
    return 0;
}

/* Is bin i of a spatial axis near the source (every such bin is evaluated)? */
static int near_source(const ns_nn_grid *g, int axis, uint32_t i, double radius)
{
    return axis < 2 && fabs(mid(g->edges[axis], i)) <= radius;
}

/* The nodes of one axis (bins where the networks are evaluated) and, for every bin, its
 * lower node and the next node's weight. The weight is linear in the bins' centres (mfp,
 * radians), not in the network's asinh-mapped input: beyond full_radius log J falls about
 * linearly with distance, which the asinh map bends (measured in docs/network.md). A
 * neighbour node outside the trained extent (input x < 0) gets no weight. Returns the
 * node count. */
static uint32_t sample_axis(const ns_nn_grid *g, int axis, const ns_nn_sampling *s, const float *x,
                            ns_vec4 *sample)
{
    uint32_t n = g->n[axis], nodes = 0, stride = s->stride[axis];
    for (uint32_t i = 0; i < n; i++)
        if (i % stride == 0 || i == n - 1 || near_source(g, axis, i, s->full_radius))
            sample[nodes++][0] = (float)i;
    uint32_t k = 0;
    const double *e = g->edges[axis];
    for (uint32_t i = 0; i < n; i++) {
        while (k + 1 < nodes && (uint32_t)sample[k + 1][0] <= i)
            k++;
        uint32_t b0 = (uint32_t)sample[k][0];
        float w = 0.0f;
        if (b0 != i) { /* then k + 1 < nodes: the last bin is a node */
            uint32_t b1 = (uint32_t)sample[k + 1][0];
            w = x[b1] < 0   ? 0.0f
                : x[b0] < 0 ? 1.0f
                            : (float)((mid(e, i) - mid(e, b0)) / (mid(e, b1) - mid(e, b0)));
        }
        sample[i][1] = (float)k;
        sample[i][2] = w;
    }
    return nodes;
}

/* Fills the uniform block's per-axis inputs, node lists and interpolation weights. Cells
 * beyond the extent the networks were trained on get input -1: J is 0 there rather than
 * extrapolated. Returns the node count of the whole table. */
static uint32_t setup_axes(struct GpuNnParams *gp, const ns_nn_grid *grid, const ns_nn_header *h,
                           const ns_nn_sampling *s)
{
    float *axis = &gp->axis[0][0];
    for (uint32_t i = 0; i < grid->n[0]; i++) {
        double z = mid(grid->edges[0], i);
        axis[i] = fabs(z) <= h->extent ? ns_nn_map_z(h, z) : -1.0f;
    }
    for (uint32_t i = 0; i < grid->n[1]; i++) {
        double rho = mid(grid->edges[1], i);
        axis[NS_NN_MAX_AXIS + i] = rho <= h->extent ? ns_nn_map_rho(h, rho) : -1.0f;
    }
    for (uint32_t i = 0; i < grid->n[2]; i++)
        axis[2 * NS_NN_MAX_AXIS + i] = (float)(mid(grid->edges[2], i) / M_PI);
    for (uint32_t i = 0; i < grid->n[3]; i++)
        axis[3 * NS_NN_MAX_AXIS + i] = (float)(mid(grid->edges[3], i) / M_PI);
    uint32_t nodes = 1;
    for (int a = 0; a < 4; a++) {
        gp->counts[a] = grid->n[a];
        gp->nodes[a] =
            sample_axis(grid, a, s, axis + a * NS_NN_MAX_AXIS, gp->interp + a * NS_NN_MAX_AXIS);
        nodes *= gp->nodes[a];
    }
    return nodes;
}

/* Workgroup z is the order less GpuNnParams.orders.x: `orders` of them from that one. */
static int dispatch_table(gpu_device *dev, ns_nn_gpu *nn, const gpu_pipeline *pipe, gpu_buffer *out,
                          gpu_buffer *in, uint32_t items, uint32_t channels, uint32_t orders,
                          ns_error *err)
{
    uint32_t per_group = NS_NN_GROUP * NS_NN_POINTS;
    gpu_buffer *bound[3] = {&nn->params, out, in ? in : &nn->dummy};
    return gpu_dispatch(dev, pipe, bound, 3,
                        (uint32_t[3]){(items + per_group - 1) / per_group, channels, orders}, err);
}

/* Evaluates the networks at the nodes and fills every cell of out: directly when every cell
 * is a node, else through t at the nodes and the interpolation pass. */
static int evaluate(gpu_device *dev, ns_nn_gpu *nn, struct GpuNnParams *gp, uint32_t cells,
                    uint32_t nodes, uint32_t channels, uint32_t orders, gpu_buffer *out,
                    ns_error *err)
{
    gp->info[1] = NS_NN_MODE_TABLE;
    gp->info[3] = nodes;
    if (nodes == cells) {
        gp->info[0] = cells;
        gp->info[2] = 0;
        return dispatch_table(dev, nn, &nn->pipeline, out, NULL, cells, channels, orders, err);
    }
    uint32_t rows = cells / gp->counts[3], row_groups = (rows + NS_NN_GROUP - 1) / NS_NN_GROUP;
    if (row_groups > 65535) /* Vulkan's guaranteed workgroup count per dimension */
        return ns_fail(err, NS_ERR_LIMIT,
                       "table of %u rows along phi: interpolation needs at most %u (use fewer "
                       "cells or more phi bins)",
                       rows, 65535 * NS_NN_GROUP);
    gpu_buffer t = {0};
    int status =
        gpu_buffer_create(dev, &t,
                          &(gpu_buffer_desc){.size = (VkDeviceSize)nodes * 6 * sizeof(float),
                                             .uninitialized = 1,
                                             .label = "ns.nn.nodes"},
                          err);
    if (!status) {
        gp->info[0] = nodes;
        gp->info[2] = 1; /* t, not J */
        status = dispatch_table(dev, nn, &nn->pipeline, &t, NULL, nodes, channels, orders, err);
    }
    if (!status) {
        /* nn_interpolate.comp: one invocation per row of cells along phi. */
        gp->info[0] = cells;
        gpu_buffer *bound[3] = {&nn->params, out, &t};
        status = gpu_dispatch(dev, &nn->interpolate, bound, 3,
                              (uint32_t[3]){row_groups, channels, orders}, err);
    }
    gpu_buffer_destroy(dev, &t);
    return status;
}

/* The network's domain: the media it was trained on (DESIGN.md). */
static int network_covers(double g, const double albedo[3], const char **field, ns_error *err)
{
    *field = "g";
    if (!(g >= 0 && g < 1))
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "g %g is outside the network's [0, 1) (method \"nn\"; method \"table\" "
                       "takes any g)",
                       g);
    *field = "albedo";
    for (int c = 0; c < 3; c++)
        if (!(albedo[c] >= 0 && albedo[c] < 1))
            return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                           "albedo[%d] %g is outside the network's [0, 1) (method \"nn\")", c,
                           albedo[c]);
    *field = NULL;
    return 0;
}

int ns_material_supported(ns_method method, const ns_material *m, const char **field,
                          ns_error *err)
{
    *field = NULL;
    if (method != NS_METHOD_NN || m->type != NS_MATERIAL_MEDIUM)
        return 0;
    double albedo[3];
    for (int c = 0; c < 3; c++) {
        double t = (double)m->sigma_s[c] + m->sigma_a[c];
        albedo[c] = t > 0 ? m->sigma_s[c] / t : 0;
    }
    return network_covers(m->g, albedo, field, err);
}

static int check_material(const ns_nn_reconstruct_desc *desc, uint32_t channels, ns_error *err)
{
    if (channels > 3)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "channels: %u (1 to 3)", channels);
    const double albedo[3] = {desc->albedo[0], desc->albedo[1], desc->albedo[2]};
    const char *field;
    return network_covers(desc->g, albedo, &field, err);
}

/* Energy of each table of orders [first, end) and, if asked, the rescaling to the exact E_k. */
static void finish_tables(const ns_nn_reconstruct_desc *desc, uint32_t cells, uint32_t channels,
                          int first, int end, ns_nn_reconstruct_stats *s)
{
    for (int o = first; o < end; o++)
        for (uint32_t c = 0; c < channels; c++) {
            float *j = desc->out + ((size_t)o * 3 + c) * cells;
            s->energy_raw[o][c] = ns_nn_grid_energy(&desc->grid, j);
            s->energy_exact[o][c] = ns_nn_exact_energy(o, desc->albedo[c]);
            if (desc->renormalise && s->energy_raw[o][c] > 0) {
                float k = (float)(s->energy_exact[o][c] / s->energy_raw[o][c]);
                for (uint32_t i = 0; i < cells; i++)
                    j[i] *= k;
            }
        }
}

int ns_nn_reconstruct(gpu_device *dev, ns_nn_gpu *nn, const ns_nn_reconstruct_desc *desc,
                      ns_nn_reconstruct_stats *stats, ns_error *err)
{
    double t0 = seconds_now();
    uint32_t channels = desc->channels ? desc->channels : 3;
    ns_nn_sampling sampling = desc->sampling ? *desc->sampling : ns_nn_sampling_default();
    int status = check_nets(desc->nets, err);
    if (!status)
        status = check_grid(&desc->grid, err);
    if (!status)
        status = check_material(desc, channels, err);
    if (!status)
        status = check_sampling(&sampling, err);
    if (!status && desc->orders != 0 && desc->orders != NS_NN_ORDER_DOUBLE &&
        desc->orders != NS_NN_ORDER_MULTIPLE)
        status = ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                         "orders: %u (0 for both, NS_NN_ORDER_DOUBLE or NS_NN_ORDER_MULTIPLE)",
                         desc->orders);
    if (status)
        return status;
    int first = desc->orders == NS_NN_ORDER_MULTIPLE,
        end = desc->orders == NS_NN_ORDER_DOUBLE ? 1 : 2;
    const ns_nn_grid *grid = &desc->grid;
    uint32_t cells = grid->n[0] * grid->n[1] * grid->n[2] * grid->n[3];
    struct GpuNnParams *gp = nn->params.mapped;
    memset(gp, 0, sizeof *gp);
    pack_common(gp, desc->nets);
    const ns_nn_header *h = &desc->nets[0]->h;
    uint32_t nodes = setup_axes(gp, grid, h, &sampling);
    gp->orders[0] = (uint32_t)first;
    for (int c = 0; c < 3; c++) {
        gp->channel[c][0] = ns_nn_map_g(h, desc->g);
        gp->channel[c][1] = ns_nn_map_albedo(h, desc->albedo[c]);
        gp->channel[c][2] = (float)ns_nn_exact_energy(0, desc->albedo[c]);
        gp->channel[c][3] = (float)ns_nn_exact_energy(1, desc->albedo[c]);
    }
    gpu_buffer out = {0};
    status = gpu_buffer_create(dev, &out,
                               &(gpu_buffer_desc){.size = (VkDeviceSize)cells * 6 * sizeof(float),
                                                  .uninitialized = 1,
                                                  .host_reads = 1,
                                                  .label = "ns.nn.out"},
                               err);
    if (status)
        return status;
    double t1 = seconds_now();
    status = evaluate(dev, nn, gp, cells, nodes, channels, (uint32_t)(end - first), &out, err);
    double t2 = seconds_now();
    if (!status) /* only the channels and orders computed: the rest is undefined */
        for (int o = first; o < end; o++)
            memcpy(desc->out + (size_t)o * 3 * cells, (float *)out.mapped + (size_t)o * 3 * cells,
                   (size_t)cells * channels * sizeof(float));
    gpu_buffer_destroy(dev, &out);
    if (status)
        return status;
    ns_nn_reconstruct_stats s = {.gpu_seconds = t2 - t1,
                                 .evaluations = (uint64_t)nodes * (end - first) * channels,
                                 .cells = (uint64_t)cells * (end - first) * channels};
    finish_tables(desc, cells, channels, first, end, &s);
    s.total_seconds = seconds_now() - t0;
    if (stats)
        *stats = s;
    return 0;
}

int ns_nn_eval_points(gpu_device *dev, ns_nn_gpu *nn, const ns_nn_weights *nets[2], const float *x,
                      const double *energy, uint32_t n, float *out, ns_error *err)
{
    int status = check_nets(nets, err);
    if (status)
        return status;
    if (n == 0 || n > (1u << 22))
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "points: %u (1 to 4M)", n);
    struct GpuNnParams *gp = nn->params.mapped;
    memset(gp, 0, sizeof *gp);
    pack_common(gp, nets);
    gp->info[0] = n;
    gp->info[1] = NS_NN_MODE_POINTS;
    gpu_buffer pts = {0}, res = {0};
    status = gpu_buffer_create(
        dev, &pts,
        &(gpu_buffer_desc){.size = (VkDeviceSize)n * 2 * sizeof(ns_vec4), .label = "ns.nn.points"},
        err);
    if (!status)
        status = gpu_buffer_create(dev, &res,
                                   &(gpu_buffer_desc){.size = (VkDeviceSize)n * 4 * sizeof(float),
                                                      .host_reads = 1,
                                                      .label = "ns.nn.points_out"},
                                   err);
    if (!status) {
        ns_vec4 *v = pts.mapped;
        for (uint32_t i = 0; i < n; i++) {
            const float *xi = x + (size_t)i * NS_NN_INPUTS;
            memcpy(v[2 * i], xi, 4 * sizeof(float));
            v[2 * i + 1][0] = xi[4];
            v[2 * i + 1][1] = xi[5];
            v[2 * i + 1][2] = (float)energy[i];
            v[2 * i + 1][3] = 0.0f;
        }
        uint32_t per_group = NS_NN_GROUP * NS_NN_POINTS;
        gpu_buffer *bound[3] = {&nn->params, &res, &pts};
        status = gpu_dispatch(dev, &nn->pipeline, bound, 3,
                              (uint32_t[3]){(n + per_group - 1) / per_group, 1, 2}, err);
    }
    if (!status)
        memcpy(out, res.mapped, (size_t)n * 4 * sizeof(float));
    gpu_buffer_destroy(dev, &res);
    gpu_buffer_destroy(dev, &pts);
    return status;
}
