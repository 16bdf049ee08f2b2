/* unit_metrics.c — the metrics registry and its text (server/metrics.h): label values
 * escaped as the exposition format says, whatever bytes they hold; bounded label sets
 * (routes and stages past the registry's room, unknown methods and statuses count as
 * "other"); histogram buckets cumulative with +Inf equal to the count; only a finished
 * render's stages observed. tests/http_metrics.py checks the same text on the wire with
 * the Prometheus client library's parser. */
#include <stdlib.h>
#include <string.h>

#include "harness.h"
#include "metrics.h"

#define CHECK_STR(got, want)                                                                       \
    do {                                                                                           \
        const char *g_ = (got), *w_ = (want);                                                      \
        if (!strcmp(g_, w_)) {                                                                     \
            harness_passed++;                                                                      \
        } else {                                                                                   \
            harness_failed++;                                                                      \
            fprintf(stderr, "FAIL %s (%s:%d): %s = \"%s\", expected \"%s\"\n", harness_current,    \
                    __FILE__, __LINE__, #got, g_, w_);                                             \
        }                                                                                          \
    } while (0)

static size_t escape(const char *in, char *out, size_t cap)
{
    memset(out, 'X', cap);
    return metrics_escape_label_value(in, out, cap);
}

static void test_escape_specials(void)
{
    char out[128];
    CHECK_INT(escape("plain", out, sizeof out), 5);
    CHECK_STR(out, "plain");
    CHECK_INT(escape("a\\b\"c\nd", out, sizeof out), 10);
    CHECK_STR(out, "a\\\\b\\\"c\\nd");
    CHECK_INT(escape("", out, sizeof out), 0);
    CHECK_STR(out, "");
    CHECK_INT(escape(NULL, out, sizeof out), 0);
    CHECK_STR(out, "");
    /* Other control characters and DEL cannot break a line but are not text either. */
    CHECK_INT(escape("a\tb\rc\x01\x7f", out, sizeof out), 7);
    CHECK_STR(out, "a?b?c??");
}

static void test_escape_utf8(void)
{
    char out[128];
    /* Well-formed sequences of 2, 3 and 4 bytes pass unchanged. */
    const char *ok = "\xc3\xa9t\xc3\xa9 \xe2\x82\xac \xf0\x9f\x98\x80";
    CHECK_INT(escape(ok, out, sizeof out), strlen(ok));
    CHECK_STR(out, ok);
    /* A lone continuation byte, a truncated sequence, an overlong form, a surrogate and a
     * code point past U+10FFFF: each byte that starts no valid sequence becomes '?'. */
    CHECK_INT(escape("\x80", out, sizeof out), 1);
    CHECK_STR(out, "?");
    CHECK_INT(escape("a\xc3", out, sizeof out), 2);
    CHECK_STR(out, "a?");
    CHECK_INT(escape("\xc0\xaf", out, sizeof out), 2);
    CHECK_STR(out, "??");
    CHECK_INT(escape("\xed\xa0\x80", out, sizeof out), 3);
    CHECK_STR(out, "???");
    CHECK_INT(escape("\xf4\x90\x80\x80", out, sizeof out), 4);
    CHECK_STR(out, "????");
    CHECK_INT(escape("\xe2\x82", out, sizeof out), 2);
    CHECK_STR(out, "??");
}

static void test_escape_truncation(void)
{
    char out[8];
    /* The length it needs comes back whatever fits, as snprintf's does. */
    CHECK_INT(escape("abcdefghij", out, sizeof out), 10);
    CHECK_STR(out, "abcdefg");
    /* An escape or a character goes in whole or not at all. */
    CHECK_INT(escape("abcdef\"", out, sizeof out), 8);
    CHECK_STR(out, "abcdef");
    CHECK_INT(escape("abcde\xe2\x82\xac", out, sizeof out), 8);
    CHECK_STR(out, "abcde");
    /* Nothing after a unit that did not fit, even one that would. */
    CHECK_INT(escape("abcdef\"g", out, sizeof out), 9);
    CHECK_STR(out, "abcdef");
    CHECK_INT(metrics_escape_label_value("abc", NULL, 0), 3);
    out[0] = 'X';
    CHECK_INT(metrics_escape_label_value("abc", out, 1), 3);
    CHECK_STR(out, "");
}

/* The exposition with no context: the registry's families and the process's. */
static char *scrape(void)
{
    char *text = NULL;
    size_t size = 0;
    CHECK_INT(metrics_render_text(&(metrics_scrape_desc){.queue_capacity = 3}, &text, &size),
              NS_OK);
    CHECK(text != NULL);
    if (!text)
        return calloc(1, 1);
    CHECK_INT(strlen(text), size);
    CHECK(size > 0 && text[size - 1] == '\n');
    return text;
}

static int has_line(const char *text, const char *line)
{
    size_t n = strlen(line);
    for (const char *p = text; (p = strstr(p, line)); p++)
        if ((p == text || p[-1] == '\n') && p[n] == '\n')
            return 1;
    return 0;
}

#define CHECK_LINE(text, line)                                                                     \
    do {                                                                                           \
        if (has_line((text), (line))) {                                                            \
            harness_passed++;                                                                      \
        } else {                                                                                   \
            harness_failed++;                                                                      \
            fprintf(stderr, "FAIL %s (%s:%d): no line '%s'\n", harness_current, __FILE__,          \
                    __LINE__, (line));                                                             \
        }                                                                                          \
    } while (0)

static void test_requests(void)
{
    metrics_request_done("/v1/renders/{id}", "GET", 404, 0.003);
    metrics_request_done("/v1/renders/{id}", "GET", 404, 0.02);
    metrics_request_done("/v1/renders/{id}", "HEAD", 200, 500.0); /* past the last bound */
    metrics_request_done("/v1/renders/{id}", "BREW", 418, 0.001);
    metrics_request_done(NULL, "GET", 0, -1.0); /* no route, no answer, a clock gone back */
    char *text = scrape();
    CHECK_LINE(text, "# TYPE nscatter_http_requests_total counter");
    CHECK_LINE(text, "nscatter_http_requests_total{route=\"/v1/renders/{id}\",method=\"GET\","
                     "status=\"404\"} 2");
    CHECK_LINE(text, "nscatter_http_requests_total{route=\"/v1/renders/{id}\",method=\"HEAD\","
                     "status=\"200\"} 1");
    CHECK_LINE(text, "nscatter_http_requests_total{route=\"/v1/renders/{id}\",method=\"other\","
                     "status=\"other\"} 1");
    CHECK_LINE(text, "nscatter_http_requests_total{route=\"other\",method=\"GET\","
                     "status=\"none\"} 1");
    /* Cumulative buckets: 0.003 and 0.001 by 5 ms, 0.02 by 25 ms, 500 s only in +Inf. */
    CHECK_LINE(text, "# TYPE nscatter_http_request_duration_seconds histogram");
    CHECK_LINE(text, "nscatter_http_request_duration_seconds_bucket{route=\"/v1/renders/{id}\","
                     "le=\"0.005\"} 2");
    CHECK_LINE(text, "nscatter_http_request_duration_seconds_bucket{route=\"/v1/renders/{id}\","
                     "le=\"0.01\"} 2");
    CHECK_LINE(text, "nscatter_http_request_duration_seconds_bucket{route=\"/v1/renders/{id}\","
                     "le=\"0.025\"} 3");
    CHECK_LINE(text, "nscatter_http_request_duration_seconds_bucket{route=\"/v1/renders/{id}\","
                     "le=\"120\"} 3");
    CHECK_LINE(text, "nscatter_http_request_duration_seconds_bucket{route=\"/v1/renders/{id}\","
                     "le=\"+Inf\"} 4");
    CHECK_LINE(text, "nscatter_http_request_duration_seconds_count{route=\"/v1/renders/{id}\"} 4");
    CHECK_LINE(text,
               "nscatter_http_request_duration_seconds_sum{route=\"/v1/renders/{id}\"} 500.024");
    CHECK_LINE(text,
               "nscatter_http_request_duration_seconds_bucket{route=\"other\",le=\"0.005\"} 1");
    CHECK_LINE(text, "nscatter_http_request_duration_seconds_sum{route=\"other\"} 0");
    free(text);
}

static void test_route_bound(void)
{
    /* More templates than the registry keeps: the first ones keep their names, the rest
     * (and any name too long to keep) count as "other"; nothing grows past the bound. */
    char route[96];
    for (unsigned i = 0; i < METRICS_MAX_ROUTES + 10; i++) {
        snprintf(route, sizeof route, "/bound/%u", i);
        metrics_request_done(route, "GET", 200, 0.001);
    }
    memset(route, 'r', sizeof route - 1);
    route[sizeof route - 1] = 0;
    metrics_request_done(route, "GET", 200, 0.001);
    char *text = scrape();
    CHECK_LINE(text,
               "nscatter_http_requests_total{route=\"/bound/0\",method=\"GET\",status=\"200\"} 1");
    CHECK(!strstr(text, "route=\"/bound/41\""));
    CHECK(!strstr(text, "rrrrrrrr"));
    unsigned named = 0;
    for (unsigned i = 0; i < METRICS_MAX_ROUTES + 10; i++) {
        snprintf(route, sizeof route, "route=\"/bound/%u\",method", i);
        named += strstr(text, route) != NULL;
    }
    /* Two slots went to the templates of test_requests and to "other". */
    CHECK_INT(named, METRICS_MAX_ROUTES - 2);
    /* The 12 without a slot and the long one (test_requests' "other" had status none). */
    CHECK_LINE(text,
               "nscatter_http_requests_total{route=\"other\",method=\"GET\",status=\"200\"} 13");
    free(text);
}

static void test_label_escaping_in_text(void)
{
    /* Names come from the server's and the render library's own tables, but the text must
     * stay valid whatever they hold (the route table is full by now: a stage name it is). */
    ns_render_stats stats;
    memset(&stats, 0, sizeof stats);
    ns_stats_add_stage(&stats, "we\"ird\\st\nage", 2.0);
    metrics_render_done(NS_METHOD_NN, JOB_DONE, &stats);
    char *text = scrape();
    CHECK_LINE(text, "nscatter_render_stage_duration_seconds_count{stage=\"we\\\"ird\\\\st\\nage\","
                     "method=\"nn\"} 1");
    free(text);
}

static void test_renders(void)
{
    ns_render_stats stats;
    memset(&stats, 0, sizeof stats);
    ns_stats_add_stage(&stats, "parse", 0.5);
    ns_stats_add_stage(&stats, "ray_pass", 30.0);
    stats.tables_reused = 3;
    stats.tables_made = 2;
    stats.bvh_reused = 1;
    metrics_render_done(NS_METHOD_VRL, JOB_DONE, &stats);
    metrics_render_done(NS_METHOD_VRL, JOB_DONE, &stats);
    /* Counted, and their reuse too, but their partial stages are not observed. */
    metrics_render_done(NS_METHOD_VRL, JOB_FAILED, &stats);
    metrics_render_done(NS_METHOD_VRL, JOB_CANCELLED, &stats);
    metrics_render_done((ns_method)NS_METHOD_COUNT, JOB_DONE, &stats); /* ignored */
    char *text = scrape();
    CHECK_LINE(text, "# TYPE nscatter_renders_total counter");
    CHECK_LINE(text, "nscatter_renders_total{method=\"vrl\",state=\"done\"} 2");
    CHECK_LINE(text, "nscatter_renders_total{method=\"vrl\",state=\"failed\"} 1");
    CHECK_LINE(text, "nscatter_renders_total{method=\"vrl\",state=\"cancelled\"} 1");
    CHECK_LINE(text, "nscatter_renders_total{method=\"pt\",state=\"done\"} 0");
    CHECK_LINE(text, "nscatter_render_stage_duration_seconds_bucket{stage=\"parse\","
                     "method=\"vrl\",le=\"0.001\"} 2");
    CHECK_LINE(text, "nscatter_render_stage_duration_seconds_bucket{stage=\"ray_pass\","
                     "method=\"vrl\",le=\"0.025\"} 0");
    CHECK_LINE(text, "nscatter_render_stage_duration_seconds_bucket{stage=\"ray_pass\","
                     "method=\"vrl\",le=\"0.05\"} 2");
    CHECK_LINE(text, "nscatter_render_stage_duration_seconds_bucket{stage=\"ray_pass\","
                     "method=\"vrl\",le=\"+Inf\"} 2");
    CHECK_LINE(text, "nscatter_render_stage_duration_seconds_count{stage=\"ray_pass\","
                     "method=\"vrl\"} 2");
    CHECK_LINE(text, "nscatter_render_stage_duration_seconds_sum{stage=\"ray_pass\","
                     "method=\"vrl\"} 0.06");
    CHECK_LINE(text, "nscatter_table_cache_hits_total 12");
    CHECK_LINE(text, "nscatter_table_cache_misses_total 8");
    CHECK_LINE(text, "nscatter_bvh_reused_total 4");
    free(text);
}

static void test_stage_bound(void)
{
    ns_render_stats stats;
    memset(&stats, 0, sizeof stats);
    char name[40];
    /* Three renders of 24 stages each, all named differently: more names than it keeps. */
    const unsigned renders = 3, total = renders * NS_MAX_STAGES;
    for (unsigned r = 0; r < renders; r++) {
        memset(&stats, 0, sizeof stats);
        for (unsigned i = 0; i < NS_MAX_STAGES; i++) {
            snprintf(name, sizeof name, "bound_stage_%u", r * NS_MAX_STAGES + i);
            ns_stats_add_stage(&stats, name, 1.0);
        }
        metrics_render_done(NS_METHOD_DIPOLE, JOB_DONE, &stats);
    }
    char *text = scrape();
    unsigned named = 0;
    for (unsigned i = 0; i < total; i++) {
        snprintf(name, sizeof name, "stage=\"bound_stage_%u\"", i);
        named += strstr(text, name) != NULL;
    }
    /* "other", parse, ray_pass and the odd one of test_label_escaping_in_text came first. */
    CHECK_INT(named, METRICS_MAX_STAGES - 4);
    char line[160];
    snprintf(line, sizeof line,
             "nscatter_render_stage_duration_seconds_count{stage=\"other\",method=\"dipole\"} %u",
             total - (METRICS_MAX_STAGES - 4));
    CHECK_LINE(text, line);
    free(text);
}

static void test_fixed_families(void)
{
    char *text = scrape();
    /* Every family has its HELP and TYPE, with or without samples. */
    static const char *const families[][2] = {
        {"nscatter_build_info", "gauge"},
        {"nscatter_ready", "gauge"},
        {"nscatter_queue_depth", "gauge"},
        {"nscatter_queue_capacity", "gauge"},
        {"nscatter_jobs", "gauge"},
        {"nscatter_job_store_bytes", "gauge"},
        {"nscatter_http_requests_total", "counter"},
        {"nscatter_http_request_duration_seconds", "histogram"},
        {"nscatter_renders_total", "counter"},
        {"nscatter_render_stage_duration_seconds", "histogram"},
        {"nscatter_table_cache_hits_total", "counter"},
        {"nscatter_table_cache_misses_total", "counter"},
        {"nscatter_bvh_reused_total", "counter"},
        {"nscatter_table_cache_bytes", "gauge"},
        {"nscatter_idle_work_pending", "gauge"},
        {"nscatter_idle_work_running", "gauge"},
        {"nscatter_idle_nodes_made_total", "counter"},
        {"nscatter_idle_work_stopped_total", "counter"},
        {"nscatter_idle_work_seconds_total", "counter"},
        {"nscatter_device_info", "gauge"},
        {"nscatter_device_live_buffers", "gauge"},
        {"process_cpu_seconds_total", "counter"},
        {"process_resident_memory_bytes", "gauge"},
        {"process_virtual_memory_bytes", "gauge"},
        {"process_start_time_seconds", "gauge"},
        {"process_open_fds", "gauge"},
    };
    char line[128];
    for (size_t i = 0; i < sizeof families / sizeof families[0]; i++) {
        snprintf(line, sizeof line, "# TYPE %s %s", families[i][0], families[i][1]);
        CHECK_LINE(text, line);
        snprintf(line, sizeof line, "# HELP %s ", families[i][0]);
        CHECK(strstr(text, line) != NULL);
    }
    CHECK_LINE(text, "nscatter_ready 0");
    CHECK_LINE(text, "nscatter_queue_capacity 3");
    CHECK_LINE(text, "nscatter_queue_depth 0");
    CHECK_LINE(text, "nscatter_jobs{state=\"running\"} 0");
    CHECK_LINE(text, "nscatter_build_info{version=\"" NS_VERSION "\"} 1");
    /* No context: the device's families have no sample. */
    CHECK(!strstr(text, "\nnscatter_device_info{"));
    CHECK(!strstr(text, "\nnscatter_device_live_buffers "));
    free(text);
}

int main(void)
{
    RUN(test_escape_specials);
    RUN(test_escape_utf8);
    RUN(test_escape_truncation);
    /* The registry is the process's: these run in order and build on each other. */
    RUN(test_requests);
    RUN(test_route_bound);
    RUN(test_label_escaping_in_text);
    RUN(test_renders);
    RUN(test_stage_bound);
    RUN(test_fixed_families);
    return harness_report();
}
