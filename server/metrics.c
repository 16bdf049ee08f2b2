/* metrics.c — the Prometheus registry and its text exposition (metrics.h). */
#include "metrics.h"

#include <dirent.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

/* ---------------------------------------------------------------------------------------
 * The bounded label sets and the buckets.
 * ------------------------------------------------------------------------------------- */
static const char *const http_methods[] = {"GET",    "HEAD",  "POST",    "PUT",
                                           "DELETE", "PATCH", "OPTIONS", METRICS_OTHER};
#define METHOD_SLOTS (sizeof http_methods / sizeof http_methods[0])

/* The statuses counted under their own number: every one this service or libmicrohttpd
 * answers with, and the common rest. Slot 0 is "none" (no answer was sent), the last slot
 * "other". */
static const unsigned http_statuses[] = {0,   100, 101, 200, 201, 202, 204, 206, 301, 302, 304,
                                         307, 308, 400, 401, 403, 404, 405, 406, 408, 409, 410,
                                         411, 412, 413, 414, 415, 416, 417, 421, 422, 426, 428,
                                         429, 431, 500, 501, 502, 503, 504, 505};
#define STATUS_KNOWN (sizeof http_statuses / sizeof http_statuses[0])
#define STATUS_SLOTS (STATUS_KNOWN + 1)

/* Requests: from a health check (well under a millisecond) to a synchronous render at the
 * limits (minutes); event streams last as long as their job and land in the last buckets. */
static const double request_bounds[] = {0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5,
                                        1,     2.5,  5,     10,   30,  60,   120};
/* Render stages: a kept BVH's comparison takes microseconds, a pt_pass minutes. */
static const double stage_bounds[] = {0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25,
                                      0.5,   1,      2.5,   5,    10,    30,   60,  120};
#define REQUEST_BOUNDS (sizeof request_bounds / sizeof request_bounds[0])
#define STAGE_BOUNDS (sizeof stage_bounds / sizeof stage_bounds[0])
#define MAX_BOUNDS 16u
_Static_assert(REQUEST_BOUNDS <= MAX_BOUNDS && STAGE_BOUNDS <= MAX_BOUNDS, "bucket count");

/* ---------------------------------------------------------------------------------------
 * The registry.
 * ------------------------------------------------------------------------------------- */
typedef struct histogram {
    uint64_t buckets[MAX_BOUNDS + 1]; /* per bucket, not cumulative; after the bounds: +Inf */
    uint64_t count;
    double sum;
} histogram;

#define ROUTE_CHARS 64u
#define STAGE_CHARS 32u /* ns_stage_time.name */

typedef struct registry {
    /* Names as they first came; slot 0 is "other", which takes what does not fit. */
    char routes[METRICS_MAX_ROUTES][ROUTE_CHARS];
    uint32_t route_count;
    char stages[METRICS_MAX_STAGES][STAGE_CHARS];
    uint32_t stage_count;
    uint64_t requests[METRICS_MAX_ROUTES][METHOD_SLOTS][STATUS_SLOTS];
    histogram request_seconds[METRICS_MAX_ROUTES];
    uint64_t renders[NS_METHOD_COUNT][JOB_STATE_COUNT];
    histogram stage_seconds[METRICS_MAX_STAGES][NS_METHOD_COUNT];
    uint64_t tables_reused, tables_made, bvh_reused, camera_reused, sources_reused, single_reused;
} registry;

static pthread_mutex_t registry_lock = PTHREAD_MUTEX_INITIALIZER;
static registry reg = {
    .routes = {METRICS_OTHER}, .route_count = 1, .stages = {METRICS_OTHER}, .stage_count = 1};

/* The slot of `name` in a name table, added when new and there is room; 0 ("other") for
 * NULL, a name too long to keep, or a full table. Lock held. */
static uint32_t name_slot(char *table, uint32_t width, uint32_t *count, uint32_t max,
                          const char *name)
{
    if (!name || !*name || strlen(name) >= width)
        return 0;
    for (uint32_t i = 0; i < *count; i++)
        if (!strcmp(table + (size_t)i * width, name))
            return i;
    if (*count >= max)
        return 0;
    memcpy(table + (size_t)*count * width, name, strlen(name) + 1);
    return (*count)++;
}

static uint32_t method_slot(const char *method)
{
    for (uint32_t i = 0; method && i + 1 < METHOD_SLOTS; i++)
        if (!strcmp(http_methods[i], method))
            return i;
    return METHOD_SLOTS - 1;
}

static uint32_t status_slot(unsigned status)
{
    for (uint32_t i = 0; i < STATUS_KNOWN; i++)
        if (http_statuses[i] == status)
            return i;
    return STATUS_KNOWN;
}

static void observe(histogram *h, const double *bounds, uint32_t n, double value)
{
    if (!(value >= 0)) /* NaN or a clock that went back */
        value = 0;
    uint32_t b = 0;
    while (b < n && value > bounds[b])
        b++;
    h->buckets[b]++;
    h->count++;
    h->sum += value;
}

void metrics_request_done(const char *route, const char *method, unsigned status, double seconds)
{
    uint32_t m = method_slot(method), s = status_slot(status);
    pthread_mutex_lock(&registry_lock);
    uint32_t r =
        name_slot(&reg.routes[0][0], ROUTE_CHARS, &reg.route_count, METRICS_MAX_ROUTES, route);
    reg.requests[r][m][s]++;
    observe(&reg.request_seconds[r], request_bounds, REQUEST_BOUNDS, seconds);
    pthread_mutex_unlock(&registry_lock);
}

void metrics_render_done(ns_method method, job_state state, const ns_render_stats *stats)
{
    if ((unsigned)method >= NS_METHOD_COUNT || (unsigned)state >= JOB_STATE_COUNT)
        return;
    pthread_mutex_lock(&registry_lock);
    reg.renders[method][state]++;
    if (stats) {
        reg.tables_reused += stats->tables_reused;
        reg.tables_made += stats->tables_made;
        reg.bvh_reused += stats->bvh_reused ? 1 : 0;
        reg.camera_reused += stats->camera_reused ? 1 : 0;
        reg.sources_reused += stats->sources_reused ? 1 : 0;
        reg.single_reused += stats->single_reused ? 1 : 0;
    }
    /* A failed or cancelled render's stages stop part way: they would pull the
     * distribution of each stage's time down, so only a finished render's are observed. */
    for (uint32_t i = 0; stats && state == JOB_DONE && i < stats->stage_count && i < NS_MAX_STAGES;
         i++) {
        char name[STAGE_CHARS];
        snprintf(name, sizeof name, "%s", stats->stages[i].name);
        uint32_t st =
            name_slot(&reg.stages[0][0], STAGE_CHARS, &reg.stage_count, METRICS_MAX_STAGES, name);
        observe(&reg.stage_seconds[st][method], stage_bounds, STAGE_BOUNDS,
                stats->stages[i].ms / 1000.0);
    }
    pthread_mutex_unlock(&registry_lock);
}

/* ---------------------------------------------------------------------------------------
 * Escaping and numbers.
 * ------------------------------------------------------------------------------------- */
/* The length of the well-formed UTF-8 sequence at s (RFC 3629: no overlong forms, no
 * surrogates, nothing above U+10FFFF), or 0 when there is none. */
static size_t utf8_sequence(const unsigned char *s)
{
    unsigned char c = s[0];
    if (c < 0x80)
        return 1;
    size_t n;
    unsigned char lo = 0x80, hi = 0xbf; /* the second byte's range */
    if (c >= 0xc2 && c <= 0xdf)
        n = 2;
    else if (c >= 0xe0 && c <= 0xef) {
        n = 3;
        lo = c == 0xe0 ? 0xa0 : 0x80;
        hi = c == 0xed ? 0x9f : 0xbf;
    } else if (c >= 0xf0 && c <= 0xf4) {
        n = 4;
        lo = c == 0xf0 ? 0x90 : 0x80;
        hi = c == 0xf4 ? 0x8f : 0xbf;
    } else
        return 0;
    if (s[1] < lo || s[1] > hi)
        return 0;
    for (size_t i = 2; i < n; i++)
        if (s[i] < 0x80 || s[i] > 0xbf) /* also stops at the terminating 0 */
            return 0;
    return n;
}

size_t metrics_escape_label_value(const char *in, char *out, size_t cap)
{
    const unsigned char *s = (const unsigned char *)(in ? in : "");
    size_t need = 0, written = 0;
    int full = cap == 0;
    while (*s) {
        char unit[4];
        size_t n = utf8_sequence(s), advance = n ? n : 1;
        if (*s == '\\' || *s == '"') {
            unit[0] = '\\';
            unit[1] = (char)*s;
            n = 2;
        } else if (*s == '\n') {
            memcpy(unit, "\\n", 2);
            n = 2;
        } else if (!n || *s < 0x20 || *s == 0x7f) {
            unit[0] = '?';
            n = 1;
        } else {
            memcpy(unit, s, n);
        }
        /* A unit goes in whole or not at all, and nothing after one that did not fit:
         * a truncated value never ends inside an escape or a character. */
        if (!full && written + n < cap) {
            memcpy(out + written, unit, n);
            written += n;
        } else {
            full = 1;
        }
        need += n;
        s += advance;
    }
    if (cap)
        out[written] = 0;
    return need;
}

/* A sample value: integers as integers, the rest with the digits that read back the same,
 * and the format's spellings of infinities and NaN. */
static void format_value(double v, char out[40])
{
    if (isnan(v)) {
        snprintf(out, 40, "NaN");
    } else if (isinf(v)) {
        snprintf(out, 40, v > 0 ? "+Inf" : "-Inf");
    } else {
        for (int digits = 15; digits <= 17; digits++) {
            snprintf(out, 40, "%.*g", digits, v);
            if (strtod(out, NULL) == v)
                break;
        }
    }
}

/* ---------------------------------------------------------------------------------------
 * The text: a growing buffer and one helper per kind of family.
 * ------------------------------------------------------------------------------------- */
typedef struct text_buf {
    char *data;
    size_t len, cap;
    int failed;
} text_buf;

static void emitf(text_buf *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void emitf(text_buf *b, const char *fmt, ...)
{
    if (b->failed)
        return;
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(b->data ? b->data + b->len : NULL, b->data ? b->cap - b->len : 0, fmt, ap);
    va_end(ap);
    if (n < 0) {
        b->failed = 1;
        return;
    }
    if (b->data && b->len + (size_t)n < b->cap) {
        b->len += (size_t)n;
        return;
    }
    size_t cap = b->cap ? b->cap : 16384;
    while (cap < b->len + (size_t)n + 1)
        cap *= 2;
    char *grown = realloc(b->data, cap);
    if (!grown) {
        b->failed = 1;
        return;
    }
    b->data = grown;
    b->cap = cap;
    va_start(ap, fmt);
    vsnprintf(b->data + b->len, b->cap - b->len, fmt, ap);
    va_end(ap);
    b->len += (size_t)n;
}

/* HELP and TYPE of one family; help texts are constants without '\\' or line feeds. */
static void family(text_buf *b, const char *name, const char *type, const char *help)
{
    emitf(b, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

/* One unlabelled sample of a family of its own. */
static void single(text_buf *b, const char *name, const char *type, const char *help, double v)
{
    char value[40];
    format_value(v, value);
    family(b, name, type, help);
    emitf(b, "%s %s\n", name, value);
}

/* The samples of one histogram series; labels: `name="value"` pairs, already escaped. */
static void histogram_samples(text_buf *b, const char *name, const char *labels,
                              const double *bounds, uint32_t n, const histogram *h)
{
    uint64_t cumulative = 0;
    char value[40];
    for (uint32_t i = 0; i < n; i++) {
        cumulative += h->buckets[i];
        format_value(bounds[i], value);
        emitf(b, "%s_bucket{%s,le=\"%s\"} %llu\n", name, labels, value,
              (unsigned long long)cumulative);
    }
    cumulative += h->buckets[n];
    emitf(b, "%s_bucket{%s,le=\"+Inf\"} %llu\n", name, labels, (unsigned long long)cumulative);
    format_value(h->sum, value);
    emitf(b, "%s_sum{%s} %s\n%s_count{%s} %llu\n", name, labels, value, name, labels,
          (unsigned long long)h->count);
}

static void escaped(const char *in, char *out, size_t cap)
{
    metrics_escape_label_value(in, out, cap);
}

/* ---------------------------------------------------------------------------------------
 * The families.
 * ------------------------------------------------------------------------------------- */
static void http_families(text_buf *b, const registry *r)
{
    char route[2 * ROUTE_CHARS];
    family(b, "nscatter_http_requests_total", "counter",
           "HTTP requests answered, by route template, method and status.");
    for (uint32_t i = 0; i < r->route_count; i++) {
        escaped(r->routes[i], route, sizeof route);
        for (uint32_t m = 0; m < METHOD_SLOTS; m++)
            for (uint32_t s = 0; s < STATUS_SLOTS; s++) {
                if (!r->requests[i][m][s])
                    continue;
                char status[16];
                if (s == STATUS_KNOWN)
                    snprintf(status, sizeof status, METRICS_OTHER);
                else if (http_statuses[s] == 0)
                    snprintf(status, sizeof status, "none");
                else
                    snprintf(status, sizeof status, "%u", http_statuses[s]);
                emitf(
                    b,
                    "nscatter_http_requests_total{route=\"%s\",method=\"%s\",status=\"%s\"} %llu\n",
                    route, http_methods[m], status, (unsigned long long)r->requests[i][m][s]);
            }
    }
    family(b, "nscatter_http_request_duration_seconds", "histogram",
           "Time from a request's arrival to its completion (its answer sent), by route template.");
    for (uint32_t i = 0; i < r->route_count; i++) {
        if (!r->request_seconds[i].count)
            continue;
        char labels[3 * ROUTE_CHARS];
        escaped(r->routes[i], route, sizeof route);
        snprintf(labels, sizeof labels, "route=\"%s\"", route);
        histogram_samples(b, "nscatter_http_request_duration_seconds", labels, request_bounds,
                          REQUEST_BOUNDS, &r->request_seconds[i]);
    }
}

static void render_families(text_buf *b, const registry *r)
{
    static const job_state ended[] = {JOB_DONE, JOB_FAILED, JOB_CANCELLED};
    family(b, "nscatter_renders_total", "counter",
           "Renders the worker ran (each variant of a sweep), by method and how they ended.");
    for (int m = 0; m < NS_METHOD_COUNT; m++)
        for (size_t k = 0; k < sizeof ended / sizeof ended[0]; k++)
            emitf(b, "nscatter_renders_total{method=\"%s\",state=\"%s\"} %llu\n",
                  ns_method_name((ns_method)m), job_state_name(ended[k]),
                  (unsigned long long)r->renders[m][ended[k]]);
    family(b, "nscatter_render_stage_duration_seconds", "histogram",
           "Time of each stage of a render that ended done (parse, queue, the render "
           "library's stages, encode), by stage and method.");
    for (uint32_t st = 0; st < r->stage_count; st++)
        for (int m = 0; m < NS_METHOD_COUNT; m++) {
            if (!r->stage_seconds[st][m].count)
                continue;
            char stage[2 * STAGE_CHARS], labels[3 * STAGE_CHARS + 64];
            escaped(r->stages[st], stage, sizeof stage);
            snprintf(labels, sizeof labels, "stage=\"%s\",method=\"%s\"", stage,
                     ns_method_name((ns_method)m));
            histogram_samples(b, "nscatter_render_stage_duration_seconds", labels, stage_bounds,
                              STAGE_BOUNDS, &r->stage_seconds[st][m]);
        }
    single(b, "nscatter_table_cache_hits_total", "counter",
           "Scattering tables a render found in the context's table cache.",
           (double)r->tables_reused);
    single(b, "nscatter_table_cache_misses_total", "counter",
           "Scattering tables a render had to make (reconstructed or accumulated).",
           (double)r->tables_made);
    single(b, "nscatter_bvh_reused_total", "counter",
           "Renders that kept the BVH of the previous render of the same geometry.",
           (double)r->bvh_reused);
    single(b, "nscatter_camera_reused_total", "counter",
           "Renders that kept the camera pass of one of the last two renders, which made the same "
           "one.",
           (double)r->camera_reused);
    single(b, "nscatter_sources_reused_total", "counter",
           "Renders that kept the light's sources (VRLs, boundary sources) of one of the last two "
           "renders, which made the same ones.",
           (double)r->sources_reused);
    single(b, "nscatter_single_reused_total", "counter",
           "Renders that kept the single scattering made from the same camera pass by one of the "
           "last two renders (another albedo, or the same scene).",
           (double)r->single_reused);
}

static void service_families(text_buf *b, const metrics_scrape_desc *d)
{
    char version[64];
    escaped(NS_VERSION, version, sizeof version);
    family(b, "nscatter_build_info", "gauge", "The running version; always 1.");
    emitf(b, "nscatter_build_info{version=\"%s\"} 1\n", version);
    single(b, "nscatter_ready", "gauge", "1 when the render context exists, else 0.",
           d->ctx ? 1 : 0);
    job_store_counts counts;
    memset(&counts, 0, sizeof counts);
    if (d->jobs)
        job_store_count(d->jobs, &counts);
    single(b, "nscatter_queue_depth", "gauge",
           "Renders and sweeps admitted now, queued or running (/v1/info queue_length).",
           counts.admitted);
    single(b, "nscatter_queue_capacity", "gauge", "Renders admitted at most (--queue).",
           d->queue_capacity);
    family(b, "nscatter_jobs", "gauge", "Asynchronous renders and sweeps kept, by state.");
    for (int st = 0; st < JOB_STATE_COUNT; st++)
        emitf(b, "nscatter_jobs{state=\"%s\"} %u\n", job_state_name((job_state)st),
              counts.by_state[st]);
    single(b, "nscatter_job_store_bytes", "gauge",
           "Bytes the results of kept jobs hold (/v1/info job_store_bytes_used).",
           (double)counts.bytes);
    single(b, "nscatter_job_store_capacity_bytes", "gauge",
           "Bytes of results kept at most (--job-bytes).", (double)d->job_store_capacity_bytes);
    single(b, "nscatter_event_streams", "gauge", "Server-Sent Event streams open now.",
           d->event_streams);
    single(b, "nscatter_idle_work_pending", "gauge",
           "1 while work between renders may still come (after a render, until a call finds "
           "none), else 0.",
           counts.idle_pending);
    single(b, "nscatter_idle_work_running", "gauge",
           "1 while the worker makes tables between renders (serve --idle-work), else 0.",
           counts.idle_running);
    single(b, "nscatter_idle_nodes_made_total", "counter",
           "Albedo nodes of render.tables made between renders, for a material being swept.",
           (double)counts.idle_nodes);
    single(b, "nscatter_idle_work_stopped_total", "counter",
           "Calls of work between renders that an arriving render stopped.",
           (double)counts.idle_stopped);
    single(b, "nscatter_idle_work_seconds_total", "counter",
           "Seconds the worker spent on work between renders.", counts.idle_seconds);
}

static void device_families(text_buf *b, const metrics_scrape_desc *d)
{
    family(b, "nscatter_device_info", "gauge",
           "The render device: name, driver and Vulkan version; always 1.");
    if (d->ctx && d->device) {
        const ns_device_info *dev = d->device;
        char name[2 * sizeof dev->device_name], driver[2 * sizeof dev->driver_name],
            info[2 * sizeof dev->driver_info];
        escaped(dev->device_name, name, sizeof name);
        escaped(dev->driver_name, driver, sizeof driver);
        escaped(dev->driver_info, info, sizeof info);
        emitf(b,
              "nscatter_device_info{name=\"%s\",driver=\"%s\",driver_info=\"%s\","
              "api_version=\"%u.%u.%u\"} 1\n",
              name, driver, info, dev->api_version >> 22, (dev->api_version >> 12) & 0x3ffu,
              dev->api_version & 0xfffu);
    }
    family(b, "nscatter_device_live_buffers", "gauge",
           "Device buffers renders made and have not freed yet (0 between renders).");
    if (d->ctx)
        emitf(b, "nscatter_device_live_buffers %u\n", ns_context_live_buffers(d->ctx));
    family(b, "nscatter_table_cache_bytes", "gauge",
           "Bytes the context's scattering table cache holds (host and device).");
    if (d->ctx)
        emitf(b, "nscatter_table_cache_bytes %llu\n",
              (unsigned long long)ns_context_table_cache_bytes(d->ctx));
}

/* ---------------------------------------------------------------------------------------
 * The process collector's standard families, from /proc (Linux).
 * ------------------------------------------------------------------------------------- */
/* Seconds since the epoch when the process started: its start in clock ticks after boot
 * (/proc/self/stat, field 22) plus the boot time (/proc/stat, btime). -1 when unknown. */
static double process_start_time(void)
{
    char stat[1024];
    FILE *f = fopen("/proc/self/stat", "r");
    size_t n = f ? fread(stat, 1, sizeof stat - 1, f) : 0;
    if (f)
        fclose(f);
    stat[n] = 0;
    /* The command name, field 2, is in parentheses and may hold spaces: count from the
     * last ')'. Field 3 follows it. */
    const char *p = strrchr(stat, ')');
    unsigned long long ticks = 0;
    int ok = 0;
    if (p) {
        p++;
        for (int field = 3; field < 22 && p; field++)
            p = strchr(p + 1, ' ');
        ok = p && sscanf(p, " %llu", &ticks) == 1;
    }
    unsigned long long btime = 0;
    f = fopen("/proc/stat", "r");
    char line[256];
    int have_btime = 0;
    while (f && !have_btime && fgets(line, sizeof line, f))
        have_btime = sscanf(line, "btime %llu", &btime) == 1;
    if (f)
        fclose(f);
    long hz = sysconf(_SC_CLK_TCK);
    if (!ok || !have_btime || hz <= 0)
        return -1;
    return (double)btime + (double)ticks / (double)hz;
}

static void process_families(text_buf *b)
{
    struct rusage usage;
    if (getrusage(RUSAGE_SELF, &usage) == 0)
        single(b, "process_cpu_seconds_total", "counter",
               "Total user and system CPU time spent in seconds.",
               (double)usage.ru_utime.tv_sec + usage.ru_utime.tv_usec * 1e-6 +
                   (double)usage.ru_stime.tv_sec + usage.ru_stime.tv_usec * 1e-6);
    unsigned long long pages_virtual = 0, pages_resident = 0;
    FILE *f = fopen("/proc/self/statm", "r");
    int statm = f && fscanf(f, "%llu %llu", &pages_virtual, &pages_resident) == 2;
    if (f)
        fclose(f);
    long page = sysconf(_SC_PAGESIZE);
    if (statm && page > 0) {
        single(b, "process_virtual_memory_bytes", "gauge", "Virtual memory size in bytes.",
               (double)pages_virtual * (double)page);
        single(b, "process_resident_memory_bytes", "gauge", "Resident memory size in bytes.",
               (double)pages_resident * (double)page);
    }
    double start = process_start_time();
    if (start >= 0)
        single(b, "process_start_time_seconds", "gauge",
               "Start time of the process since unix epoch in seconds.", start);
    DIR *dir = opendir("/proc/self/fd");
    if (dir) {
        /* Every entry but the one this listing itself holds open. */
        long open_fds = 0;
        int self = dirfd(dir);
        for (struct dirent *e; (e = readdir(dir));)
            if (e->d_name[0] != '.' && atoi(e->d_name) != self)
                open_fds++;
        closedir(dir);
        single(b, "process_open_fds", "gauge", "Number of open file descriptors.",
               (double)open_fds);
    }
    struct rlimit limit;
    if (getrlimit(RLIMIT_NOFILE, &limit) == 0 && limit.rlim_cur != RLIM_INFINITY)
        single(b, "process_max_fds", "gauge", "Maximum number of open file descriptors.",
               (double)limit.rlim_cur);
}

int metrics_render_text(const metrics_scrape_desc *desc, char **text, size_t *size)
{
    *text = NULL;
    *size = 0;
    /* A copy, so that formatting (and the job store's and /proc's reads) happen without
     * the registry's lock: requests finishing meanwhile do not wait for a scrape. */
    registry *copy = malloc(sizeof *copy);
    if (!copy)
        return NS_ERR_OUT_OF_HOST_MEMORY;
    pthread_mutex_lock(&registry_lock);
    memcpy(copy, &reg, sizeof *copy);
    pthread_mutex_unlock(&registry_lock);
    text_buf b = {0};
    service_families(&b, desc);
    http_families(&b, copy);
    render_families(&b, copy);
    device_families(&b, desc);
    process_families(&b);
    free(copy);
    if (b.failed || !b.data) {
        free(b.data);
        return NS_ERR_OUT_OF_HOST_MEMORY;
    }
    *text = b.data;
    *size = b.len;
    return NS_OK;
}
