/* table_io.c — .npy + .json scattering tables (DESIGN.md section 3), written atomically. */
#include "table_io.h"

#include <errno.h>
#include <fcntl.h>
#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define TABLE_MAX_BINS_PER_AXIS 4096u
#define PATH_CAP 4096

static const char *const axis_names[NS_AXIS_COUNT] = {"z", "rho", "theta", "phi"};

/* =======================================================================================
 * The table in memory
 * ===================================================================================== */

int ns_table_create(ns_table *t, const uint32_t n[NS_AXIS_COUNT], ns_error *err)
{
    memset(t, 0, sizeof *t);
    for (int a = 0; a < NS_AXIS_COUNT; a++) {
        if (n[a] < 1 || n[a] > TABLE_MAX_BINS_PER_AXIS)
            return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "table axis %s: %u bins, expected 1..%u",
                        axis_names[a], n[a], TABLE_MAX_BINS_PER_AXIS);
        t->n[a] = n[a];
    }
    for (int a = 0; a < NS_AXIS_COUNT; a++) {
        t->edges[a] = calloc(n[a] + 1, sizeof(double));
        if (!t->edges[a]) {
            ns_table_free(t);
            return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "table: out of memory for edges");
        }
    }
    t->data = calloc(ns_table_size(t), sizeof(float));
    if (!t->data) {
        ns_table_free(t);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "table: out of memory for %zu values",
                    (size_t)n[0] * n[1] * n[2] * n[3]);
    }
    snprintf(t->source, sizeof t->source, "mc");
    return NS_OK;
}

void ns_table_free(ns_table *t)
{
    if (!t)
        return;
    for (int a = 0; a < NS_AXIS_COUNT; a++) {
        free(t->edges[a]);
        t->edges[a] = NULL;
    }
    free(t->data);
    t->data = NULL;
}

double ns_table_bin_volume(const ns_table *t, uint32_t iz, uint32_t irho)
{
    const double *z = t->edges[NS_AXIS_Z], *r = t->edges[NS_AXIS_RHO];
    return M_PI * (r[irho + 1] * r[irho + 1] - r[irho] * r[irho]) * (z[iz + 1] - z[iz]);
}

double ns_table_bin_solid_angle(const ns_table *t, uint32_t itheta, uint32_t iphi)
{
    const double *th = t->edges[NS_AXIS_THETA], *ph = t->edges[NS_AXIS_PHI];
    /* Factor 2: phi covers [0, pi] and each bin stands for itself and its mirror image. */
    return (cos(th[itheta]) - cos(th[itheta + 1])) * (ph[iphi + 1] - ph[iphi]) * 2.0;
}

double ns_table_energy(const ns_table *t)
{
    size_t directions = (size_t)t->n[2] * t->n[3];
    double *solid_angle = malloc(directions * sizeof *solid_angle);
    if (!solid_angle)
        return NAN;
    for (uint32_t it = 0; it < t->n[2]; it++)
        for (uint32_t ip = 0; ip < t->n[3]; ip++)
            solid_angle[it * t->n[3] + ip] = ns_table_bin_solid_angle(t, it, ip);
    double total = 0.0;
    for (uint32_t iz = 0; iz < t->n[0]; iz++)
        for (uint32_t ir = 0; ir < t->n[1]; ir++) {
            const float *lobe = t->data + ns_table_index(t, iz, ir, 0, 0);
            double spatial = 0.0;
            for (size_t d = 0; d < directions; d++)
                spatial += lobe[d] * solid_angle[d];
            total += spatial * ns_table_bin_volume(t, iz, ir);
        }
    free(solid_angle);
    return total;
}

const char *ns_order_name(ns_order order)
{
    return order == NS_ORDER_DOUBLE ? "double" : "multiple";
}

int ns_order_parse(const char *name, ns_order *out)
{
    if (!strcmp(name, "double"))
        *out = NS_ORDER_DOUBLE;
    else if (!strcmp(name, "multiple"))
        *out = NS_ORDER_MULTIPLE;
    else
        return NS_ERR_INVALID_ARGUMENT;
    return NS_OK;
}

/* =======================================================================================
 * Paths; each file is written atomically by ns_write_file_atomic_parts (nscatter.h).
 * ===================================================================================== */

static int make_path(char *out, const char *prefix, const char *suffix, ns_error *err)
{
    int len = snprintf(out, PATH_CAP, "%s%s", prefix, suffix);
    if (len < 0 || len >= PATH_CAP)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "--out: path too long (%d bytes)", len);
    return NS_OK;
}

/* Writes count parts to path atomically; a failure's message starts with --out, the option
 * that named the path. */
static int write_atomically(const char *path, const ns_file_part *parts, size_t count,
                            ns_error *err)
{
    ns_error write_err = {0};
    int rc = ns_write_file_atomic_parts(path, parts, count, &write_err);
    return rc ? ns_fail(err, rc, "--out: %s", write_err.message) : NS_OK;
}

int ns_table_check_writable(const char *prefix, ns_error *err)
{
    static const char *const suffixes[] = {".npy.part", ".json.part"};
    for (int i = 0; i < 2; i++) {
        char path[PATH_CAP];
        int rc = make_path(path, prefix, suffixes[i], err);
        if (rc)
            return rc;
        int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC, 0644);
        if (fd < 0)
            return ns_fail(err, NS_ERR_IO, "--out: cannot create '%s': %s", path, strerror(errno));
        close(fd);
        unlink(path);
    }
    return NS_OK;
}

/* =======================================================================================
 * .npy (format version 1.0): magic, header length, a Python dict literal padded with
 * spaces to a multiple of 64 bytes and ended by '\n', then the raw little-endian data.
 * ===================================================================================== */

static size_t npy_header(char *out, size_t cap, const uint32_t n[NS_AXIS_COUNT])
{
    char dict[256];
    int len = snprintf(dict, sizeof dict,
                       "{'descr': '<f4', 'fortran_order': False, 'shape': (%u, %u, %u, %u), }",
                       n[0], n[1], n[2], n[3]);
    size_t total = 10 + (size_t)len + 1;
    size_t padded = (total + 63) / 64 * 64;
    if (padded > cap)
        return 0;
    memcpy(out, "\x93NUMPY\x01\x00", 8);
    uint16_t header_len = (uint16_t)(padded - 10);
    out[8] = (char)(header_len & 0xff);
    out[9] = (char)(header_len >> 8);
    memcpy(out + 10, dict, (size_t)len);
    memset(out + 10 + len, ' ', padded - total);
    out[padded - 1] = '\n';
    return padded;
}

static int parse_npy_header(FILE *f, const char *path, uint32_t shape[NS_AXIS_COUNT],
                            long *data_offset, ns_error *err)
{
    unsigned char head[10];
    if (fread(head, 1, 10, f) != 10 || memcmp(head, "\x93NUMPY", 6) != 0 || head[6] != 1)
        return ns_fail(err, NS_ERR_IO, "'%s': not a version 1 .npy file", path);
    size_t header_len = head[8] | ((size_t)head[9] << 8);
    char dict[1024];
    if (header_len >= sizeof dict || fread(dict, 1, header_len, f) != header_len)
        return ns_fail(err, NS_ERR_IO, "'%s': truncated .npy header", path);
    dict[header_len] = '\0';
    if (!strstr(dict, "'descr': '<f4'") || !strstr(dict, "'fortran_order': False"))
        return ns_fail(err, NS_ERR_IO, "'%s': expected little-endian float32 in C order", path);
    const char *shape_at = strstr(dict, "'shape': (");
    if (!shape_at ||
        sscanf(shape_at, "'shape': (%u, %u, %u, %u)", &shape[0], &shape[1], &shape[2],
               &shape[3]) != 4)
        return ns_fail(err, NS_ERR_IO, "'%s': expected a 4-dimensional array", path);
    *data_offset = (long)(10 + header_len);
    return NS_OK;
}

/* =======================================================================================
 * .json sidecar
 * ===================================================================================== */

static json_t *edges_json(const double *edges, uint32_t n)
{
    json_t *arr = json_array();
    for (uint32_t i = 0; i <= n; i++)
        json_array_append_new(arr, json_real(edges[i]));
    return arr;
}

static char *table_json_text(const ns_table *t)
{
    json_t *axes = json_object();
    for (int a = 0; a < NS_AXIS_COUNT; a++)
        json_object_set_new(axes, axis_names[a], edges_json(t->edges[a], t->n[a]));
    json_t *root = json_object();
    json_object_set_new(root, "quantity", json_string("J"));
    json_object_set_new(root, "order", json_string(ns_order_name(t->order)));
    json_object_set_new(root, "g", json_real(t->g));
    json_object_set_new(root, "albedo", json_real(t->albedo));
    json_object_set_new(root, "photons", json_integer((json_int_t)t->photons));
    json_object_set_new(root, "seed", json_integer((json_int_t)t->seed));
    json_object_set_new(root, "source", json_string(t->source));
    json_object_set_new(root, "axes", axes);
    json_object_set_new(root, "energy_captured", json_real(t->energy_captured));
    json_object_set_new(root, "energy_expected", json_real(t->energy_expected));
    char *text = json_dumps(root, JSON_INDENT(1) | JSON_REAL_PRECISION(17));
    json_decref(root);
    return text;
}

int ns_table_write(const ns_table *t, const char *prefix, ns_error *err)
{
    char npy_path[PATH_CAP], json_path[PATH_CAP];
    int rc = make_path(npy_path, prefix, ".npy", err);
    if (!rc)
        rc = make_path(json_path, prefix, ".json", err);
    if (rc)
        return rc;
    /* Unpublish an older table of the same name before its data changes underneath. */
    if (unlink(json_path) != 0 && errno != ENOENT)
        return ns_fail(err, NS_ERR_IO, "--out: cannot replace '%s': %s", json_path, strerror(errno));

    char header[256];
    size_t header_len = npy_header(header, sizeof header, t->n);
    const ns_file_part npy_parts[2] = {{header, header_len},
                                       {t->data, ns_table_size(t) * sizeof(float)}};
    rc = write_atomically(npy_path, npy_parts, 2, err);
    if (rc)
        return rc;

    char *text = table_json_text(t);
    if (!text)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "table: cannot serialise the JSON sidecar");
    const ns_file_part json_parts[2] = {{text, strlen(text)}, {"\n", 1}};
    rc = write_atomically(json_path, json_parts, 2, err);
    free(text);
    return rc;
}

static int read_edges(json_t *axes, int axis, ns_table *t, const char *path, ns_error *err)
{
    json_t *arr = json_object_get(axes, axis_names[axis]);
    if (!json_is_array(arr) || json_array_size(arr) != (size_t)t->n[axis] + 1)
        return ns_fail(err, NS_ERR_IO, "'%s': axes.%s must hold %u edges", path, axis_names[axis],
                    t->n[axis] + 1);
    for (uint32_t i = 0; i <= t->n[axis]; i++) {
        json_t *v = json_array_get(arr, i);
        if (!json_is_number(v))
            return ns_fail(err, NS_ERR_IO, "'%s': axes.%s[%u] is not a number", path,
                        axis_names[axis], i);
        t->edges[axis][i] = json_number_value(v);
        if (i > 0 && !(t->edges[axis][i] > t->edges[axis][i - 1]))
            return ns_fail(err, NS_ERR_IO, "'%s': axes.%s edges are not increasing", path,
                        axis_names[axis]);
    }
    return NS_OK;
}

static int read_json_number(json_t *root, const char *key, double *out, const char *path,
                            ns_error *err)
{
    json_t *v = json_object_get(root, key);
    if (!json_is_number(v))
        return ns_fail(err, NS_ERR_IO, "'%s': \"%s\" must be a number", path, key);
    *out = json_number_value(v);
    return NS_OK;
}

static int read_metadata(json_t *root, ns_table *t, const char *path, ns_error *err)
{
    json_t *quantity = json_object_get(root, "quantity");
    json_t *order = json_object_get(root, "order");
    json_t *source = json_object_get(root, "source");
    json_t *photons = json_object_get(root, "photons");
    json_t *seed = json_object_get(root, "seed");
    if (!json_is_string(quantity) || strcmp(json_string_value(quantity), "J") != 0)
        return ns_fail(err, NS_ERR_IO, "'%s': \"quantity\" must be \"J\"", path);
    if (!json_is_string(order) || ns_order_parse(json_string_value(order), &t->order) != 0)
        return ns_fail(err, NS_ERR_IO, "'%s': \"order\" must be \"double\" or \"multiple\"", path);
    if (!json_is_string(source) || (strcmp(json_string_value(source), "mc") != 0 &&
                                    strcmp(json_string_value(source), "nn") != 0))
        return ns_fail(err, NS_ERR_IO, "'%s': \"source\" must be \"mc\" or \"nn\"", path);
    snprintf(t->source, sizeof t->source, "%s", json_string_value(source));
    if (!json_is_integer(photons) || json_integer_value(photons) < 0 || !json_is_integer(seed) ||
        json_integer_value(seed) < 0)
        return ns_fail(err, NS_ERR_IO, "'%s': \"photons\" and \"seed\" must be integers >= 0", path);
    t->photons = (uint64_t)json_integer_value(photons);
    t->seed = (uint64_t)json_integer_value(seed);
    int rc = read_json_number(root, "g", &t->g, path, err);
    if (!rc)
        rc = read_json_number(root, "albedo", &t->albedo, path, err);
    if (!rc)
        rc = read_json_number(root, "energy_captured", &t->energy_captured, path, err);
    if (!rc)
        rc = read_json_number(root, "energy_expected", &t->energy_expected, path, err);
    return rc;
}

static int read_axis_counts(json_t *axes, uint32_t n[NS_AXIS_COUNT], const char *path,
                            ns_error *err)
{
    if (!json_is_object(axes))
        return ns_fail(err, NS_ERR_IO, "'%s': \"axes\" must be an object", path);
    for (int a = 0; a < NS_AXIS_COUNT; a++) {
        json_t *arr = json_object_get(axes, axis_names[a]);
        if (!json_is_array(arr) || json_array_size(arr) < 2 ||
            json_array_size(arr) > TABLE_MAX_BINS_PER_AXIS + 1)
            return ns_fail(err, NS_ERR_IO, "'%s': axes.%s must be an array of 2..%u edges", path,
                        axis_names[a], TABLE_MAX_BINS_PER_AXIS + 1);
        n[a] = (uint32_t)json_array_size(arr) - 1;
    }
    return NS_OK;
}

static int read_npy_data(const char *path, ns_table *t, ns_error *err)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return ns_fail(err, NS_ERR_IO, "cannot open '%s': %s", path, strerror(errno));
    uint32_t shape[NS_AXIS_COUNT];
    long offset = 0;
    int rc = parse_npy_header(f, path, shape, &offset, err);
    if (!rc && memcmp(shape, t->n, sizeof shape) != 0)
        rc = ns_fail(err, NS_ERR_IO, "'%s': shape (%u, %u, %u, %u) disagrees with the JSON axes", path,
                  shape[0], shape[1], shape[2], shape[3]);
    size_t count = ns_table_size(t);
    if (!rc && fread(t->data, sizeof(float), count, f) != count)
        rc = ns_fail(err, NS_ERR_IO, "'%s': truncated data (expected %zu values)", path, count);
    if (!rc && fgetc(f) != EOF)
        rc = ns_fail(err, NS_ERR_IO, "'%s': trailing bytes after the data", path);
    fclose(f);
    return rc;
}

int ns_table_read(const char *prefix, ns_table *t, ns_error *err)
{
    memset(t, 0, sizeof *t);
    char npy_path[PATH_CAP], json_path[PATH_CAP];
    int rc = make_path(npy_path, prefix, ".npy", err);
    if (!rc)
        rc = make_path(json_path, prefix, ".json", err);
    if (rc)
        return rc;
    json_error_t jerr;
    json_t *root = json_load_file(json_path, 0, &jerr);
    if (!root)
        return ns_fail(err, NS_ERR_IO, "'%s': %s (line %d)", json_path, jerr.text, jerr.line);
    uint32_t n[NS_AXIS_COUNT];
    json_t *axes = json_object_get(root, "axes");
    rc = read_axis_counts(axes, n, json_path, err);
    if (!rc)
        rc = ns_table_create(t, n, err);
    for (int a = 0; !rc && a < NS_AXIS_COUNT; a++)
        rc = read_edges(axes, a, t, json_path, err);
    if (!rc)
        rc = read_metadata(root, t, json_path, err);
    json_decref(root);
    if (!rc)
        rc = read_npy_data(npy_path, t, err);
    if (rc)
        ns_table_free(t);
    return rc;
}

int ns_table_is_complete(const char *prefix)
{
    char npy_path[PATH_CAP], json_path[PATH_CAP];
    if (make_path(npy_path, prefix, ".npy", NULL) || make_path(json_path, prefix, ".json", NULL))
        return 0;
    json_t *root = json_load_file(json_path, 0, NULL);
    if (!root)
        return 0;
    uint32_t n[NS_AXIS_COUNT];
    int ok = read_axis_counts(json_object_get(root, "axes"), n, json_path, NULL) == 0;
    json_decref(root);
    FILE *f = ok ? fopen(npy_path, "rb") : NULL;
    if (!f)
        return 0;
    uint32_t shape[NS_AXIS_COUNT];
    long offset = 0;
    ok = parse_npy_header(f, npy_path, shape, &offset, NULL) == 0 &&
         memcmp(shape, n, sizeof shape) == 0;
    struct stat st;
    size_t want = (size_t)offset + (size_t)n[0] * n[1] * n[2] * n[3] * sizeof(float);
    ok = ok && fstat(fileno(f), &st) == 0 && (size_t)st.st_size == want;
    fclose(f);
    return ok;
}
