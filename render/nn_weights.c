/* nn_weights.c — weights file validation, input normalisation, CPU forward pass. */
#include "nn_weights.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gpu.h" /* ns_fail */

_Static_assert(sizeof(ns_nn_header) == NS_NN_HEADER_SIZE, "weights header layout");
_Static_assert(NS_NN_HEADER_SIZE + NS_NN_PARAMS * 4 <= NS_NN_MAX_FILE_BYTES,
               "a network must fit in 12 KB");

/* Monte Carlo table geometry the default input map is built for (offline/mc.h). */
#define NN_EXTENT 200.0f
#define NN_SINH_SCALE 0.5f
#define NN_ALBEDO_MAX 0.999f

uint32_t ns_crc32(const void *data, size_t size)
{
    static uint32_t table[256];
    static int ready; /* benign race: every thread writes the same values */
    if (!ready) {
        for (uint32_t i = 0; i < 256; i++) {
            uint32_t c = i;
            for (int k = 0; k < 8; k++)
                c = c & 1 ? 0xedb88320u ^ (c >> 1) : c >> 1;
            table[i] = c;
        }
        ready = 1;
    }
    const unsigned char *p = data;
    uint32_t crc = 0xffffffffu;
    for (size_t i = 0; i < size; i++)
        crc = table[(crc ^ p[i]) & 0xff] ^ (crc >> 8);
    return crc ^ 0xffffffffu;
}

void ns_nn_header_init(ns_nn_header *h, uint32_t order, ns_nn_target target)
{
    memset(h, 0, sizeof *h);
    memcpy(h->magic, NS_NN_MAGIC, 8);
    h->version = NS_NN_VERSION;
    h->header_size = NS_NN_HEADER_SIZE;
    h->order = order;
    h->inputs = NS_NN_INPUTS;
    h->hidden1 = h->hidden2 = NS_NN_HIDDEN;
    h->outputs = 1;
    h->activation = 1;
    h->target = (uint32_t)target;
    h->input_map = NS_NN_INPUT_MAP_ASINH;
    h->param_count = NS_NN_PARAMS;
    h->target_eps = target == NS_NN_TARGET_LOGREL ? 1e-9f : 1.0f;
    h->target_mean = 0.0f;
    h->target_scale = 1.0f;
    h->extent = NN_EXTENT;
    h->sinh_scale = NN_SINH_SCALE;
    h->albedo_max = NN_ALBEDO_MAX;
    h->g_min = 0.0f;
    h->g_max = 1.0f;
}

static int check_header(const ns_nn_header *h, const char *what, ns_error *err)
{
    if (memcmp(h->magic, NS_NN_MAGIC, 8) != 0)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "%s: not an nscatter weights file (bad magic)",
                       what);
    if (h->version != NS_NN_VERSION || h->header_size != NS_NN_HEADER_SIZE)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "%s: weights format version %u (header %u bytes), this build reads "
                       "version %u (%u bytes)",
                       what, h->version, h->header_size, NS_NN_VERSION, NS_NN_HEADER_SIZE);
    if (ns_crc32(h, offsetof(ns_nn_header, header_crc32)) != h->header_crc32)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "%s: header checksum mismatch (corrupted)",
                       what);
    if (h->inputs != NS_NN_INPUTS || h->hidden1 != NS_NN_HIDDEN || h->hidden2 != NS_NN_HIDDEN ||
        h->outputs != 1 || h->activation != 1 || h->param_count != NS_NN_PARAMS)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "%s: architecture %u->%u->%u->%u (activation %u) does not match this "
                       "build's %d->%d->%d->1 tanh",
                       what, h->inputs, h->hidden1, h->hidden2, h->outputs, h->activation,
                       NS_NN_INPUTS, NS_NN_HIDDEN, NS_NN_HIDDEN);
    if (h->order > 1)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "%s: order %u is neither double (0) nor "
                       "multiple (1)",
                       what, h->order);
    if (h->target > NS_NN_TARGET_LOGREL ||
        (h->input_map != NS_NN_INPUT_MAP_ASINH && h->input_map != NS_NN_INPUT_MAP_ASINH_LOGG))
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "%s: unknown target transform %u or input "
                       "map %u",
                       what, h->target, h->input_map);
    if (!(h->target_eps > 0) || !(h->target_scale > 0) || !isfinite(h->target_mean) ||
        !(h->extent > 0) || !(h->sinh_scale > 0) || !(h->albedo_max > 0 && h->albedo_max < 1) ||
        !(h->g_max > h->g_min) ||
        (h->input_map == NS_NN_INPUT_MAP_ASINH_LOGG && !(h->g_min >= 0 && h->g_max < 1)))
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "%s: invalid normalisation constants", what);
    return 0;
}

int ns_nn_weights_parse(const void *bytes, size_t size, const char *what, ns_nn_weights *w,
                        ns_error *err)
{
    const size_t expected = NS_NN_HEADER_SIZE + (size_t)NS_NN_PARAMS * sizeof(float);
    if (size < NS_NN_HEADER_SIZE)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "%s: truncated weights file (%zu bytes, the header alone is %u)", what, size,
                       NS_NN_HEADER_SIZE);
    memcpy(&w->h, bytes, NS_NN_HEADER_SIZE);
    int status = check_header(&w->h, what, err);
    if (status)
        return status;
    if (size != expected)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "%s: %s weights file (%zu bytes, expected %zu for %d parameters)", what,
                       size < expected ? "truncated" : "oversized", size, expected, NS_NN_PARAMS);
    const unsigned char *payload = (const unsigned char *)bytes + NS_NN_HEADER_SIZE;
    if (ns_crc32(payload, expected - NS_NN_HEADER_SIZE) != w->h.payload_crc32)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "%s: weights checksum mismatch (corrupted parameters)", what);
    memcpy(w->p, payload, sizeof w->p);
    for (int i = 0; i < NS_NN_PARAMS; i++)
        if (!isfinite(w->p[i]))
            return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "%s: parameter %d is not finite", what, i);
    return 0;
}

int ns_nn_weights_load(const char *path, ns_nn_weights *w, ns_error *err)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return ns_fail(err, NS_ERR_IO, "%s: cannot open weights: %s", path, strerror(errno));
    unsigned char buf[NS_NN_MAX_FILE_BYTES + 1];
    size_t n = fread(buf, 1, sizeof buf, f);
    int bad = ferror(f);
    fclose(f);
    if (bad)
        return ns_fail(err, NS_ERR_IO, "%s: read error", path);
    return ns_nn_weights_parse(buf, n, path, w, err);
}

int ns_nn_weights_save(ns_nn_weights *w, const char *path, ns_error *err)
{
    w->h.payload_crc32 = ns_crc32(w->p, sizeof w->p);
    w->h.header_crc32 = ns_crc32(&w->h, offsetof(ns_nn_header, header_crc32));
    const ns_file_part parts[2] = {{&w->h, NS_NN_HEADER_SIZE}, {w->p, sizeof w->p}};
    return ns_write_file_atomic_parts(path, parts, 2, err);
}

/* ---------------------------------------------------------------------------------------
 * Normalisation
 * ------------------------------------------------------------------------------------- */

static float clamp01(double v)
{
    return (float)(v < 0 ? 0 : v > 1 ? 1 : v);
}

float ns_nn_map_rho(const ns_nn_header *h, double rho)
{
    return clamp01(asinh(rho / h->sinh_scale) / asinh((double)h->extent / h->sinh_scale));
}

float ns_nn_map_z(const ns_nn_header *h, double z)
{
    /* z spans [-extent, extent]: the signed asinh map sends it to [-1, 1], then [0, 1]. */
    double u = asinh(z / h->sinh_scale) / asinh((double)h->extent / h->sinh_scale);
    return clamp01(0.5 * (u + 1.0));
}

float ns_nn_map_albedo(const ns_nn_header *h, double albedo)
{
    return clamp01(-log1p(-albedo) / -log1p(-(double)h->albedo_max));
}

float ns_nn_map_g(const ns_nn_header *h, double g)
{
    double linear = (g - h->g_min) / ((double)h->g_max - h->g_min);
    if (h->input_map != NS_NN_INPUT_MAP_ASINH_LOGG || !(g < h->g_max))
        return clamp01(linear);
    return clamp01(0.5 * linear + 0.5 * log1p(-g) / log1p(-(double)h->g_max));
}

void ns_nn_normalise(const ns_nn_header *h, double rho, double z, double theta, double phi,
                     double g, double albedo, float x[NS_NN_INPUTS])
{
    x[0] = ns_nn_map_rho(h, rho);
    x[1] = ns_nn_map_z(h, z);
    x[2] = clamp01(theta / M_PI);
    x[3] = clamp01(phi / M_PI);
    x[4] = ns_nn_map_g(h, g);
    x[5] = ns_nn_map_albedo(h, albedo);
}

float ns_nn_forward(const ns_nn_weights *w, const float x[NS_NN_INPUTS])
{
    const float *p = w->p;
    float h1[NS_NN_HIDDEN], h2[NS_NN_HIDDEN];
    for (int j = 0; j < NS_NN_HIDDEN; j++) {
        float a = p[NS_NN_OFF_B1 + j];
        for (int k = 0; k < NS_NN_INPUTS; k++)
            a += p[NS_NN_OFF_W1 + j * NS_NN_INPUTS + k] * x[k];
        h1[j] = tanhf(a);
    }
    for (int j = 0; j < NS_NN_HIDDEN; j++) {
        float a = p[NS_NN_OFF_B2 + j];
        for (int k = 0; k < NS_NN_HIDDEN; k++)
            a += p[NS_NN_OFF_W2 + j * NS_NN_HIDDEN + k] * h1[k];
        h2[j] = tanhf(a);
    }
    float y = p[NS_NN_OFF_B3];
    for (int k = 0; k < NS_NN_HIDDEN; k++)
        y += p[NS_NN_OFF_W3 + k] * h2[k];
    return y;
}

double ns_nn_output_to_j(const ns_nn_header *h, double y, double energy_expected)
{
    double t = y * h->target_scale + h->target_mean;
    double j =
        h->target == NS_NN_TARGET_PAPER ? expm1(t) : (exp(t) - h->target_eps) * energy_expected;
    return j > 0 ? j : 0.0;
}

double ns_nn_j_to_target(const ns_nn_header *h, double j, double energy_expected)
{
    if (j < 0)
        j = 0;
    double t =
        h->target == NS_NN_TARGET_PAPER ? log1p(j) : log(j / energy_expected + h->target_eps);
    return (t - h->target_mean) / h->target_scale;
}
