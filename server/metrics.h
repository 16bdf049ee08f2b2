/* metrics.h — the service's Prometheus metrics, answered at GET /metrics in the text
 * exposition format 0.0.4 (docs/http.md "Metrics").
 *
 * One registry per process, like the process collector it sits beside: fixed arrays behind
 * one mutex, no allocation while counting, nothing to make or free. The request path and
 * the render worker report to it (metrics_request_done, metrics_render_done); a scrape
 * copies the counters under the mutex and formats them without it, adding the gauges of
 * the moment (queue, jobs, device, process) that it reads itself.
 *
 * Every label takes its values from a bounded set, so the number of series cannot grow
 * with traffic: routes are templates ("/v1/renders/{id}", never an id) and anything the
 * registry does not know, or has no room for, is counted under "other".
 */
#ifndef NS_METRICS_H
#define NS_METRICS_H

#include <stddef.h>
#include <stdint.h>

#include "jobs.h"
#include "nscatter.h"

#define METRICS_CONTENT_TYPE "text/plain; version=0.0.4; charset=utf-8"
#define METRICS_OTHER "other" /* the label value of whatever is not in a bounded set */

/* Distinct route templates and stage names the registry keeps; more count as "other". */
#define METRICS_MAX_ROUTES 32u
#define METRICS_MAX_STAGES 48u

/* One answered request, from the completion callback. route: the route's template from
 * the server's fixed table ("/v1/renders/{id}/image"), or NULL / METRICS_OTHER for a path
 * that is no route; method: as received (methods outside the usual few count as "other");
 * status: the HTTP status sent, 0 when none was (the client went away first); seconds:
 * from the request's first callback to its completion. Thread-safe. */
void metrics_request_done(const char *route, const char *method, unsigned status, double seconds);

/* One render the worker ran (a synchronous or asynchronous render, or one variant of a
 * sweep), once it has ended: state is JOB_DONE, JOB_FAILED or JOB_CANCELLED. Counts it
 * in nscatter_renders_total; the stages of a render that ended done go into the stage
 * histogram; the table and BVH reuse of stats is counted whatever the state. Thread-safe. */
void metrics_render_done(ns_method method, job_state state, const ns_render_stats *stats);

/* What a scrape reads besides the registry. Zero means "none" everywhere. */
typedef struct metrics_scrape_desc {
    const ns_context *ctx;        /* NULL: no render context (nscatter_ready 0, no device) */
    const ns_device_info *device; /* the context's device; NULL with no context */
    job_store *jobs;              /* queue and job gauges; NULL with no context */
    uint32_t queue_capacity;
    uint64_t job_store_capacity_bytes;
    uint32_t event_streams; /* open Server-Sent Event streams */
} metrics_scrape_desc;

/* The exposition text of every family. On success *text is malloc'ed (the caller frees
 * it) and *size is its length; returns 0, or NS_ERR_OUT_OF_HOST_MEMORY. */
int metrics_render_text(const metrics_scrape_desc *desc, char **text, size_t *size);

/* A label value as the text format writes it between its quotes: backslash, double quote
 * and line feed escaped as \\, \" and \n; other control characters and bytes that are not
 * UTF-8 become '?', so any input gives one valid line. Writes at most cap bytes including
 * the terminating 0 (cap 0: nothing) and returns the length the whole escaped value needs,
 * as snprintf does. */
size_t metrics_escape_label_value(const char *in, char *out, size_t cap);

#endif
