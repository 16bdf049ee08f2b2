/* http.c — the HTTP render service (libmicrohttpd) behind http_serve() (http.h).
 *
 * One thread per connection. The render context is made once, before the socket opens;
 * renders run one at a time as jobs on the job store's worker (jobs.h), and a full queue
 * answers 503 at once. Asynchronous renders and sweeps are jobs kept under an id, with
 * their status, Server-Sent Events, image and cancel routes. Errors are RFC 9457 problem details (problem.h). Every request owns
 * an http_request, made on the first callback and freed in the completion callback,
 * whatever happened in between (client gone, body too large, render failure).
 */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <netdb.h>
#include <fcntl.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/random.h>
#include <sys/socket.h>
#include <sys/types.h>
#include <time.h>
#include <unistd.h>

#include <linux/tcp.h> /* struct tcp_info: tcpi_bytes_received */
#include <netinet/in.h>

#include <jansson.h>
#include <microhttpd.h>

#include "encode.h"
#include "http.h"
#include "mc_provider.h"
#include "nscatter.h"
#include "problem.h"
#include "render_job.h"
#include "jobs.h"
#include "metrics.h"
#include "openapi.h"
#include "scene_json.h"
#include "sweep.h"
#include "web_assets.h"

/* How often the connection guard looks at the open connections (guard_sweep). */
#define HTTP_GUARD_PERIOD_MS 200
/* A body that is still arriving gets one more second per this many bytes received. */
#define HTTP_BODY_BYTES_PER_S 65536u
#define HTTP_DEVICE_HEADER "X-Nscatter-Device"
/* Counts and memory of the render (VRLs, interactions, table bytes...) as compact JSON. */
#define HTTP_STATS_HEADER "X-Nscatter-Stats"
#define HTTP_INSTANCE_HEADER "X-Nscatter-Instance"

typedef struct http_server {
    ns_context *ctx; /* NULL when the context could not be made: /readyz says 503 */
    ns_error ctx_err;
    ns_device_info device;
    job_store *jobs;
    uint64_t max_body;
    uint32_t queue_capacity;
    uint32_t job_ttl_s;
    uint64_t job_bytes;
    uint32_t sse_keepalive_s;
    uint32_t max_deadline_ms;
    const char *asset_dir;
    const char *instance;           /* serve --instance NAME, or NULL: X-Nscatter-Instance */
    scene_parse_options parse_opts; /* asset folder and the service's limits */
    atomic_int renders_in_flight; /* admitted renders whose response is not yet sent */
    atomic_int event_streams;     /* open event streams (each holds a connection) */
    atomic_int stopping;          /* a stop signal came: /readyz and new renders answer 503 */
    int access_log;               /* one JSON line per request on stderr */
    uint32_t request_timeout_s;   /* a request must arrive whole within this (408) */
    uint32_t idle_timeout_s;      /* a silent connection is closed after this */
    uint32_t max_connections;     /* connections open at once */
} http_server;

/* ---------------------------------------------------------------------------------------
 * The connection guard.
 *
 * libmicrohttpd's own timeout counts inactivity: a client that sends a byte a second never
 * reaches it and holds its connection (and thread) for ever. The guard bounds the whole
 * arrival of a request instead. Every connection has an entry (made and dropped through
 * MHD_OPTION_NOTIFY_CONNECTION) that says what it is doing:
 *   WAITING  between requests: no request line and headers yet
 *   BODY     headers done, the body arriving
 *   BUSY     the service is answering (a render waits, an event stream runs)
 * Every HTTP_GUARD_PERIOD_MS the main thread looks at them all (guard_sweep): a WAITING
 * connection whose client has sent bytes of a request (the kernel's count of bytes received,
 * TCP_INFO) that did not become whole headers within --request-timeout, or a body still
 * arriving past --request-timeout (plus one second per 64 KiB received), is answered
 * 408 request_timeout and shut down. A WAITING connection that sent nothing is idle: its
 * client is not doing anything wrong; libmicrohttpd closes it after --idle-timeout, and
 * when the connections open reach 7/8 of --max-connections the guard closes idle ones, the
 * oldest first, down to 3/4, so that idle sockets never keep real clients out.
 *
 * The guard writes on a socket only while its connection's own thread is reading (WAITING or
 * BODY): libmicrohttpd writes nothing then. The entry's lock is held from the decision to
 * the shutdown, and libmicrohttpd reports a connection closed (dropping its entry under the
 * lock) before it closes the socket, so the guard never touches a socket that was reused.
 * ------------------------------------------------------------------------------------- */
typedef enum { CONN_WAITING, CONN_BODY, CONN_BUSY } conn_phase;

typedef struct conn_entry {
    struct conn_entry *prev, *next;
    int fd;
    conn_phase phase;
    double since_ms;       /* when this phase began */
    double first_byte_ms;  /* WAITING: when bytes of a new request were first seen; 0: none */
    uint64_t rx_mark;      /* WAITING: the bytes received when it began */
    uint64_t body_bytes;   /* BODY: received so far */
    int cut;               /* the guard shut it down */
    int linked;            /* in the guard's list */
} conn_entry;

static pthread_mutex_t guard_lock = PTHREAD_MUTEX_INITIALIZER;
static conn_entry *guard_head;
static unsigned guard_count;

/* The kernel's count of bytes received on a TCP socket; 0 where it is not known. */
static uint64_t tcp_bytes_received(int fd)
{
    struct tcp_info info;
    socklen_t len = sizeof info;
    memset(&info, 0, sizeof info);
    if (getsockopt(fd, IPPROTO_TCP, TCP_INFO, &info, &len) ||
        len < offsetof(struct tcp_info, tcpi_bytes_received) + sizeof info.tcpi_bytes_received)
        return 0;
    return info.tcpi_bytes_received;
}

static void guard_notify(void *cls, struct MHD_Connection *conn, void **socket_context,
                         enum MHD_ConnectionNotificationCode code)
{
    (void)cls;
    if (code == MHD_CONNECTION_NOTIFY_STARTED) {
        const union MHD_ConnectionInfo *info =
            MHD_get_connection_info(conn, MHD_CONNECTION_INFO_CONNECTION_FD);
        conn_entry *e = calloc(1, sizeof *e);
        *socket_context = e;
        if (!e || !info)
            return; /* unguarded: libmicrohttpd's own timeout still applies */
        e->fd = info->connect_fd;
        e->phase = CONN_WAITING;
        e->since_ms = ns_now_ms();
        pthread_mutex_lock(&guard_lock);
        e->linked = 1;
        e->next = guard_head;
        if (guard_head)
            guard_head->prev = e;
        guard_head = e;
        guard_count++;
        pthread_mutex_unlock(&guard_lock);
        return;
    }
    conn_entry *e = *socket_context;
    *socket_context = NULL;
    if (!e)
        return;
    pthread_mutex_lock(&guard_lock);
    if (e->linked) {
        if (e->prev)
            e->prev->next = e->next;
        else if (guard_head == e)
            guard_head = e->next;
        if (e->next)
            e->next->prev = e->prev;
        guard_count--;
    }
    pthread_mutex_unlock(&guard_lock);
    free(e);
}

static conn_entry *guard_entry(struct MHD_Connection *conn)
{
    const union MHD_ConnectionInfo *info =
        MHD_get_connection_info(conn, MHD_CONNECTION_INFO_SOCKET_CONTEXT);
    return info ? info->socket_context : NULL;
}

/* The connection moves to `phase` (the request's headers arrived: BODY; it is answered: BUSY;
 * its answer is sent: WAITING for the next). */
static void guard_phase(struct MHD_Connection *conn, conn_phase phase)
{
    conn_entry *e = guard_entry(conn);
    if (!e)
        return;
    pthread_mutex_lock(&guard_lock);
    if (e->phase != phase) {
        e->phase = phase;
        e->since_ms = ns_now_ms();
        e->first_byte_ms = 0;
        e->body_bytes = 0;
        if (phase == CONN_WAITING)
            e->rx_mark = tcp_bytes_received(e->fd);
    }
    pthread_mutex_unlock(&guard_lock);
}

static void guard_body_bytes(struct MHD_Connection *conn, size_t n)
{
    conn_entry *e = guard_entry(conn);
    if (!e)
        return;
    pthread_mutex_lock(&guard_lock);
    e->body_bytes += n;
    pthread_mutex_unlock(&guard_lock);
}

/* 408 with its problem body, written straight on the socket, then the socket shut down; the
 * connection's thread sees it closed and ends. Called with guard_lock held. */
static void guard_cut(conn_entry *e, const char *detail)
{
    char id[40];
    unsigned char bytes[16] = {0};
    if (getrandom(bytes, sizeof bytes, GRND_NONBLOCK) != (ssize_t)sizeof bytes)
        memset(bytes, 0, sizeof bytes);
    for (size_t i = 0; i < sizeof bytes; i++)
        snprintf(id + 2 * i, 3, "%02x", bytes[i]);
    json_t *p = problem_new(PROBLEM_REQUEST_TIMEOUT, detail);
    char *body = NULL;
    if (p) {
        json_object_set_new(p, "request_id", json_string(id));
        body = json_dumps(p, JSON_INDENT(2));
        json_decref(p);
    }
    if (body) {
        char head[512];
        size_t len = strlen(body);
        int n = snprintf(head, sizeof head,
                         "HTTP/1.1 408 Request Timeout\r\nConnection: close\r\n"
                         "Content-Type: " PROBLEM_CONTENT_TYPE "\r\n"
                         "X-Content-Type-Options: nosniff\r\nX-Request-Id: %s\r\n"
                         "Content-Length: %zu\r\n\r\n",
                         id, len + 1);
        /* Non-blocking: a client that reads nothing only misses its answer. */
        if (n > 0 && send(e->fd, head, (size_t)n, MSG_NOSIGNAL | MSG_DONTWAIT) == n &&
            send(e->fd, body, len, MSG_NOSIGNAL | MSG_DONTWAIT) == (ssize_t)len)
            (void)!send(e->fd, "\n", 1, MSG_NOSIGNAL | MSG_DONTWAIT);
        free(body);
    }
    shutdown(e->fd, SHUT_RDWR);
    e->cut = 1;
    /* Counted as a request of no route (its line may never have arrived). */
    metrics_request_done(METRICS_OTHER, "other", 408, 0);
}

/* One look at every connection (the main thread, every HTTP_GUARD_PERIOD_MS). */
static void guard_sweep(const http_server *srv)
{
    double now = ns_now_ms();
    double limit_ms = srv->request_timeout_s * 1000.0;
    pthread_mutex_lock(&guard_lock);
    unsigned idle = 0;
    for (conn_entry *e = guard_head; e; e = e->next) {
        if (e->cut)
            continue;
        if (e->phase == CONN_WAITING) {
            if (!e->first_byte_ms && tcp_bytes_received(e->fd) > e->rx_mark)
                e->first_byte_ms = now;
            if (!e->first_byte_ms) {
                idle++;
                continue;
            }
            if (now - e->first_byte_ms > limit_ms) {
                char detail[200];
                snprintf(detail, sizeof detail,
                         "the request line and headers did not arrive within %u s "
                         "(--request-timeout)", srv->request_timeout_s);
                guard_cut(e, detail);
            }
        } else if (e->phase == CONN_BODY) {
            double allowed = limit_ms + 1000.0 * (double)(e->body_bytes / HTTP_BODY_BYTES_PER_S);
            if (now - e->since_ms > allowed) {
                char detail[200];
                snprintf(detail, sizeof detail,
                         "the request body did not arrive within %u s (--request-timeout; "
                         "%llu bytes came)", srv->request_timeout_s,
                         (unsigned long long)e->body_bytes);
                guard_cut(e, detail);
            }
        }
    }
    /* Nearly full (7/8): idle connections make room, the oldest first (the list is newest
     * first), down to 3/4, so that clients waiting in the listen backlog get in. */
    unsigned high = srv->max_connections - srv->max_connections / 8;
    unsigned low = srv->max_connections - srv->max_connections / 4;
    if (guard_count >= high && idle) {
        unsigned excess = guard_count - low;
        conn_entry *last = guard_head;
        while (last && last->next)
            last = last->next;
        for (conn_entry *e = last; e && excess; e = e->prev)
            if (!e->cut && e->phase == CONN_WAITING && !e->first_byte_ms) {
                shutdown(e->fd, SHUT_RDWR);
                e->cut = 1;
                excess--;
            }
    }
    pthread_mutex_unlock(&guard_lock);
}

typedef enum {
    ROUTE_NONE = 0,
    ROUTE_LIVEZ,
    ROUTE_READYZ,
    ROUTE_INFO,
    ROUTE_METRICS,        /* GET: the Prometheus text exposition (metrics.h) */
    ROUTE_OPENAPI,        /* GET /openapi.json: the API's description (openapi.h) */
    ROUTE_RENDERS,        /* POST: a render; GET: the asynchronous renders */
    ROUTE_VALIDATE,       /* POST /v1/renders/validate: the checks of a render, no render */
    ROUTE_MATERIALS,      /* GET /v1/materials: the presets */
    ROUTE_RENDER_JOB,     /* /v1/renders/{id} */
    ROUTE_RENDER_IMAGE,   /* /v1/renders/{id}/image */
    ROUTE_RENDER_EVENTS,  /* /v1/renders/{id}/events */
    ROUTE_SWEEPS,         /* POST: a sweep; GET: the sweeps */
    ROUTE_SWEEP_JOB,      /* /v1/sweeps/{id} */
    ROUTE_SWEEP_IMAGE,    /* /v1/sweeps/{id}/images/{n} */
    ROUTE_SWEEP_SHEET,    /* /v1/sweeps/{id}/sheet.png */
    ROUTE_SWEEP_MANIFEST, /* /v1/sweeps/{id}/manifest.json */
    ROUTE_SWEEP_EVENTS,   /* /v1/sweeps/{id}/events */
    ROUTE_WEB,
} http_route;

/* Per request, made on the first callback, freed in http_request_completed(). */
typedef struct http_request {
    http_route route;
    char job_id[JOB_ID_MAX + 8]; /* the {id} of a job route, as given (checked on lookup) */
    int variant;                   /* the {n} of /images/{n} */
    int async;                     /* POST /v1/renders with Prefer: respond-async */
    uint64_t last_event_id;        /* Last-Event-ID or ?last_event_id= */
    const char *allow;     /* Allow header of a 405 */
    json_t *early_problem; /* answer decided before the body was read; the body is drained */
    int too_large;         /* the body grew past the limit (chunked or lying length) */
    encode_format format;
    char *body;
    size_t size, cap;
    uint64_t drained;        /* bytes read and thrown away after an early decision */
    http_server *counted_in; /* set while this request counts in renders_in_flight */
    double started_ms;
    /* For the access log, X-Request-Id and X-Nscatter-Instance. */
    const char *instance; /* the server's --instance, or NULL */
    char request_id[130];
    char method[16];
    char path[256];
    int status;
    uint64_t bytes;
    json_t *stages; /* a render's stage times, when one was answered */
    int answered;   /* answered in the first callback, without reading the body */
} http_request;

/* The request this connection thread is answering (libmicrohttpd runs one thread per
 * connection, and every callback of a request runs on it): what every answer reads its
 * X-Request-Id from and writes its status and size into, without threading the request
 * through every send function. */
static _Thread_local http_request *current_request;

/* ---------------------------------------------------------------------------------------
 * Responses.
 * ------------------------------------------------------------------------------------- */
/* Queues resp (and releases it) with the request's X-Request-Id (and X-Nscatter-Instance
 * under --instance, so that a client behind a load balancer sees which instance answered);
 * notes status and size for the access log. Every answer goes through here. */
static enum MHD_Result queue_answer(struct MHD_Connection *conn, int status,
                                    struct MHD_Response *resp, uint64_t size)
{
    http_request *req = current_request;
    if (req) {
        MHD_add_response_header(resp, "X-Request-Id", req->request_id);
        if (req->instance)
            MHD_add_response_header(resp, HTTP_INSTANCE_HEADER, req->instance);
        req->status = status;
        req->bytes = size;
    }
    enum MHD_Result ret = MHD_queue_response(conn, (unsigned)status, resp);
    MHD_destroy_response(resp);
    return ret;
}

static enum MHD_Result send_bytes(struct MHD_Connection *conn, int status, const char *type,
                                  void *data, size_t size, enum MHD_ResponseMemoryMode mode,
                                  const char *const *headers)
{
    struct MHD_Response *resp = MHD_create_response_from_buffer(size, data, mode);
    if (!resp) {
        if (mode == MHD_RESPMEM_MUST_FREE)
            free(data);
        return MHD_NO;
    }
    if (status != 204 || size)
        MHD_add_response_header(resp, MHD_HTTP_HEADER_CONTENT_TYPE, type);
    MHD_add_response_header(resp, "X-Content-Type-Options", "nosniff");
    for (size_t i = 0; headers && headers[i]; i += 2)
        MHD_add_response_header(resp, headers[i], headers[i + 1]);
    return queue_answer(conn, status, resp, size);
}

/* Sends `body` (consumed) as JSON. headers: NULL-terminated name/value pairs or NULL. */
static enum MHD_Result send_json(struct MHD_Connection *conn, int status, const char *type,
                                 json_t *body, const char *const *headers)
{
    char *text = body ? json_dumps(body, JSON_INDENT(2) | JSON_REAL_PRECISION(6)) : NULL;
    json_decref(body);
    if (!text) {
        /* Out of memory for the JSON itself: a short problem built without allocating. */
        char fallback[160];
        int fallback_status = problem_http_status(PROBLEM_STATUS_INTERNAL);
        int n = snprintf(fallback, sizeof fallback,
                         "{\"title\": \"%s\", \"status\": %d, \"code\": \"%s\"}\n",
                         problem_title(PROBLEM_STATUS_INTERNAL), fallback_status,
                         ns_status_name(NS_ERR_INTERNAL));
        return send_bytes(conn, fallback_status, PROBLEM_CONTENT_TYPE, fallback, (size_t)n,
                          MHD_RESPMEM_MUST_COPY, NULL);
    }
    size_t len = strlen(text);
    char *with_newline = realloc(text, len + 2);
    if (with_newline) {
        text = with_newline;
        text[len++] = '\n';
        text[len] = 0;
    }
    return send_bytes(conn, status, type, text, len, MHD_RESPMEM_MUST_FREE, headers);
}

static enum MHD_Result send_problem_json(struct MHD_Connection *conn, json_t *problem,
                                         const char *const *headers)
{
    if (problem && current_request)
        json_object_set_new(problem, "request_id", json_string(current_request->request_id));
    int status = (int)json_integer_value(json_object_get(problem, "status"));
    return send_json(conn, status ? status : 500, PROBLEM_CONTENT_TYPE, problem, headers);
}

/* problem_new() and problem_from_status() with a printf-formatted detail. */
static json_t *problemf(problem_kind kind, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));
static json_t *problemf(problem_kind kind, const char *fmt, ...)
{
    char detail[768];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(detail, sizeof detail, fmt, ap);
    va_end(ap);
    return problem_new(kind, detail);
}

static json_t *status_problemf(problem_kind kind, int status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static json_t *status_problemf(problem_kind kind, int status, const char *fmt, ...)
{
    char detail[768];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(detail, sizeof detail, fmt, ap);
    va_end(ap);
    return problem_from_status(kind, status, detail);
}

/* 503 with the reason the render context could not be made, from /readyz and from a render
 * request alike: a client polling either learns the same code. */
static json_t *no_context_problem(const http_server *srv)
{
    return status_problemf(PROBLEM_STATUS_UNAVAILABLE, srv->ctx_err.status,
                           "render context not available: %s", srv->ctx_err.message);
}

static enum MHD_Result send_out_of_memory(struct MHD_Connection *conn)
{
    return send_problem_json(
        conn,
        problem_from_status(PROBLEM_STATUS_UNAVAILABLE, NS_ERR_OUT_OF_HOST_MEMORY, "out of memory"),
        NULL);
}

/* ---------------------------------------------------------------------------------------
 * Header parsing: media types, Accept, Content-Length.
 * ------------------------------------------------------------------------------------- */
static const char *skip_space(const char *s)
{
    while (*s == ' ' || *s == '\t')
        s++;
    return s;
}

/* The HTTP layer's one number parser, for header values (Content-Length, the q of an Accept
 * range): the whole of `text`, spaces and tabs around it allowed, as decimal digits and, when
 * `fraction` is set, a '.' and more digits. No sign, exponent, hex, "inf" or "nan": no header
 * grammar here has them, though strtoull and strtod would take some ("-5" as a huge length).
 * Returns 0 with the integer part in *whole (saturated at UINT64_MAX, larger than any limit)
 * and the value in *value (either may be NULL), or -1. */
static int parse_header_number(const char *text, int fraction, uint64_t *whole, double *value)
{
    const char *s = skip_space(text);
    uint64_t w = 0, frac = 0, scale = 1;
    int digits = 0;
    for (; *s >= '0' && *s <= '9'; s++, digits++) {
        unsigned d = (unsigned)(*s - '0');
        w = w > (UINT64_MAX - d) / 10 ? UINT64_MAX : w * 10 + d;
    }
    if (fraction && *s == '.')
        for (s++; *s >= '0' && *s <= '9'; s++, digits++)
            if (scale < 1000000000000000000ull) { /* later digits cannot change a double */
                frac = frac * 10 + (uint64_t)(*s - '0');
                scale *= 10;
            }
    if (!digits || *skip_space(s))
        return -1;
    if (whole)
        *whole = w;
    if (value)
        *value = (double)w + (double)frac / (double)scale;
    return 0;
}

/* Copies the token [s, end) trimmed and lower-cased into out. */
static void copy_trimmed_lower(const char *s, const char *end, char *out, size_t cap)
{
    s = skip_space(s);
    while (end > s && (end[-1] == ' ' || end[-1] == '\t'))
        end--;
    size_t n = 0;
    for (; s < end && n + 1 < cap; s++)
        out[n++] = (char)((*s >= 'A' && *s <= 'Z') ? *s - 'A' + 'a' : *s);
    out[n] = 0;
}

/* One media range of a header: "type/subtype; name=value; ...". Parameters other than q,
 * charset and format are kept out: nothing here depends on them. */
typedef struct media_range {
    char type[96];
    double q;
    char charset[32];
    char format[32];
} media_range;

/* Parses the element [s, end) into *m; returns 0, or -1 for a malformed q. */
static int parse_media_range(const char *s, const char *end, media_range *m)
{
    memset(m, 0, sizeof *m);
    m->q = 1.0;
    const char *semi = memchr(s, ';', (size_t)(end - s));
    copy_trimmed_lower(s, semi ? semi : end, m->type, sizeof m->type);
    while (semi) {
        const char *p = semi + 1;
        semi = memchr(p, ';', (size_t)(end - p));
        const char *stop = semi ? semi : end;
        const char *eq = memchr(p, '=', (size_t)(stop - p));
        if (!eq)
            continue;
        char name[16], value[32];
        copy_trimmed_lower(p, eq, name, sizeof name);
        copy_trimmed_lower(eq + 1, stop, value, sizeof value);
        size_t vlen = strlen(value);
        if (vlen >= 2 && value[0] == '"' && value[vlen - 1] == '"') {
            memmove(value, value + 1, vlen - 2);
            value[vlen - 2] = 0;
        }
        if (!strcmp(name, "q")) {
            if (parse_header_number(value, 1, NULL, &m->q) || !(m->q >= 0.0 && m->q <= 1.0))
                return -1;
        } else if (!strcmp(name, "charset")) {
            snprintf(m->charset, sizeof m->charset, "%s", value);
        } else if (!strcmp(name, "format")) {
            snprintf(m->format, sizeof m->format, "%s", value);
        }
    }
    return 0;
}

/* Content-Type of a render request: application/json, optionally charset=utf-8. */
static int content_type_is_json(const char *header)
{
    if (!header)
        return 0;
    media_range m;
    if (parse_media_range(header, header + strlen(header), &m))
        return 0;
    return !strcmp(m.type, "application/json") && (!m.charset[0] || !strcmp(m.charset, "utf-8"));
}

/* How well one media range matches `type` ("image/png"): 3 exact, 2 "image/x", 1 any. */
static int range_specificity(const char *range, const char *type)
{
    if (!strcmp(range, type))
        return 3;
    if (!strcmp(range, "image/*"))
        return 2;
    if (!strcmp(range, "*/*"))
        return 1;
    return 0;
}

typedef struct accept_choice {
    double q;
    int specificity;
    char format[32];
} accept_choice;

/* Content negotiation between PNG and EXR (RFC 9110 12.5.1): each type takes the q of the
 * most specific range that matches it; the higher q wins, then the more specific match,
 * then PNG. Returns 0 and the format, or -1 when neither is acceptable. */
static int negotiate_format(const char *accept, encode_format *format, char *exr_param,
                            size_t exr_param_cap)
{
    exr_param[0] = 0;
    if (!accept || !*skip_space(accept)) {
        *format = ENCODE_PNG;
        return 0;
    }
    static const char *const types[2] = {"image/png", "image/x-exr"};
    accept_choice best[2] = {{0.0, 0, ""}, {0.0, 0, ""}};
    const char *s = accept;
    while (*s) {
        const char *comma = strchr(s, ',');
        const char *end = comma ? comma : s + strlen(s);
        media_range m;
        if (end > s && parse_media_range(s, end, &m) == 0) {
            for (int t = 0; t < 2; t++) {
                int spec = range_specificity(m.type, types[t]);
                if (spec > best[t].specificity) {
                    best[t].specificity = spec;
                    best[t].q = m.q;
                    snprintf(best[t].format, sizeof best[t].format, "%s", m.format);
                }
            }
        }
        s = comma ? comma + 1 : end;
    }
    int png_ok = best[0].specificity && best[0].q > 0.0;
    int exr_ok = best[1].specificity && best[1].q > 0.0;
    if (!png_ok && !exr_ok)
        return -1;
    int exr_wins =
        exr_ok && (!png_ok || best[1].q > best[0].q ||
                   (best[1].q == best[0].q && best[1].specificity > best[0].specificity));
    *format = exr_wins ? ENCODE_EXR_FLOAT : ENCODE_PNG;
    if (exr_wins)
        snprintf(exr_param, exr_param_cap, "%s", best[1].format);
    return 0;
}

/* Content-Length as a number; -1 when absent (chunked), -2 when not a plain number. */
static long long content_length(struct MHD_Connection *conn)
{
    const char *v =
        MHD_lookup_connection_value(conn, MHD_HEADER_KIND, MHD_HTTP_HEADER_CONTENT_LENGTH);
    if (!v)
        return -1;
    uint64_t n = 0;
    if (parse_header_number(v, 0, &n, NULL))
        return -2;
    return n > (uint64_t)LLONG_MAX ? LLONG_MAX : (long long)n; /* larger than any limit */
}

/* Counts the Content-Length headers and whether their values differ. */
typedef struct framing_scan {
    unsigned lengths;
    int differ;
    const char *first;
} framing_scan;

static enum MHD_Result scan_framing(void *cls, enum MHD_ValueKind kind, const char *key,
                                    const char *value)
{
    (void)kind;
    framing_scan *f = cls;
    if (key && !strcasecmp(key, MHD_HTTP_HEADER_CONTENT_LENGTH)) {
        if (f->lengths++ == 0)
            f->first = value;
        else if (strcmp(skip_space(value ? value : ""), skip_space(f->first ? f->first : "")))
            f->differ = 1;
    }
    return MHD_YES;
}

/* A request whose body length is ambiguous (RFC 9112 6.1, 6.3): Transfer-Encoding together
 * with Content-Length, Content-Length given twice with different values, or a transfer
 * coding other than chunked alone (which libmicrohttpd would read until the connection
 * closes). Such requests are how bodies are smuggled past proxies: the answer is 400 and the
 * connection is closed without reading the body. NULL when the framing is plain. */
static json_t *framing_problem(struct MHD_Connection *conn)
{
    framing_scan f = {0};
    MHD_get_connection_values(conn, MHD_HEADER_KIND, scan_framing, &f);
    const char *te =
        MHD_lookup_connection_value(conn, MHD_HEADER_KIND, MHD_HTTP_HEADER_TRANSFER_ENCODING);
    if (te && f.lengths)
        return problemf(PROBLEM_BAD_FRAMING, "Transfer-Encoding and Content-Length together "
                                             "make the body's length ambiguous; send one");
    if (f.differ)
        return problemf(PROBLEM_BAD_FRAMING, "%u Content-Length headers with different values",
                        f.lengths);
    if (te) {
        const char *v = skip_space(te);
        size_t n = strlen(v);
        while (n && (v[n - 1] == ' ' || v[n - 1] == '\t'))
            n--;
        if (n != 7 || strncasecmp(v, "chunked", 7))
            return problemf(PROBLEM_BAD_FRAMING, "Transfer-Encoding '%.64s' is not supported; "
                                                 "send the body as is or as 'chunked'", te);
    }
    return NULL;
}

/* ---------------------------------------------------------------------------------------
 * GET endpoints.
 * ------------------------------------------------------------------------------------- */
static json_t *methods_json(void)
{
    json_t *list = json_array();
    for (int m = 0; m < NS_METHOD_COUNT; m++) {
        uint32_t missing = ns_unsupported_components((ns_method)m, NS_COMPONENT_ALL);
        json_t *available = json_array(), *unavailable = json_array();
        render_components_append(available, NS_COMPONENT_ALL & ~missing);
        render_components_append(unavailable, missing);
        json_array_append_new(list, json_pack("{s:s, s:o, s:o}", "name",
                                              ns_method_name((ns_method)m), "components", available,
                                              "unavailable_components", unavailable));
    }
    return list;
}

/* GET /v1/materials: the presets a medium may name, with what they stand for. */
static json_t *materials_json(void)
{
    json_t *list = json_array();
    for (uint32_t i = 0; i < scene_preset_count(); i++) {
        scene_preset p;
        if (scene_preset_get(i, &p))
            continue;
        json_array_append_new(
            list, json_pack("{s:s, s:s, s:[fff], s:[fff], s:f, s:f}", "name", p.name, "type",
                            "medium", "albedo", p.albedo[0], p.albedo[1], p.albedo[2], "mfp",
                            p.mfp[0], p.mfp[1], p.mfp[2], "g", p.g, "ior", p.ior));
    }
    return json_pack("{s:o}", "materials", list);
}

static json_t *device_json(const http_server *srv)
{
    if (!srv->ctx)
        return json_pack("{s:n, s:s, s:s}", "name", "status", ns_status_name(srv->ctx_err.status),
                         "error", srv->ctx_err.message);
    const ns_device_info *d = &srv->device;
    char api[32];
    snprintf(api, sizeof api, "%u.%u.%u", d->api_version >> 22, (d->api_version >> 12) & 0x3ffu,
             d->api_version & 0xfffu);
    return json_pack("{s:s, s:s, s:s, s:s, s:I, s:I, s:b, s:I}", "name", d->device_name, "driver",
                     d->driver_name, "driver_info", d->driver_info, "api_version", api, "vendor_id",
                     (json_int_t)d->vendor_id, "device_id", (json_int_t)d->device_id, "is_cpu",
                     d->is_cpu, "live_buffers", (json_int_t)ns_context_live_buffers(srv->ctx));
}

/* A service limit (0: none) within the hard one, as the parser applies it. */
static json_int_t effective_limit(uint32_t service, uint32_t hard)
{
    return service && service < hard ? service : hard;
}

static json_t *info_json(const http_server *srv)
{
    const scene_parse_options *o = &srv->parse_opts;
    json_t *limits = json_pack(
        "{s:I, s:I, s:I, s:I, s:I, s:I, s:I, s:I, s:I, s:I, s:I, s:I, s:I}", "max_body_bytes",
        (json_int_t)srv->max_body, "queue_capacity", (json_int_t)srv->queue_capacity,
        "max_image_side", (json_int_t)NS_MAX_IMAGE_SIDE, "max_pixels",
        effective_limit(o->max_pixels, NS_MAX_PIXELS), "max_spp",
        effective_limit(o->max_spp, NS_MAX_SPP), "max_depth", (json_int_t)NS_MAX_DEPTH,
        "max_materials", (json_int_t)NS_MAX_MATERIALS, "max_objects", (json_int_t)NS_MAX_OBJECTS,
        "max_lights", (json_int_t)NS_MAX_LIGHTS, "max_triangles",
        effective_limit(o->max_triangles, NS_MAX_TRIANGLES), "job_ttl_s",
        (json_int_t)srv->job_ttl_s, "job_store_bytes", (json_int_t)srv->job_bytes,
        "max_sweep_variants", (json_int_t)SWEEP_MAX_VARIANTS);
    json_object_set_new(limits, "max_vrls", json_integer(effective_limit(o->max_vrls, NS_MAX_VRLS)));
    json_object_set_new(limits, "max_deadline_ms",
                        srv->max_deadline_ms ? json_integer(srv->max_deadline_ms) : json_null());
    json_object_set_new(limits, "request_timeout_s", json_integer(srv->request_timeout_s));
    json_object_set_new(limits, "idle_timeout_s", json_integer(srv->idle_timeout_s));
    json_object_set_new(limits, "max_connections", json_integer(srv->max_connections));
    job_store_counts counts = {0};
    if (srv->jobs)
        job_store_count(srv->jobs, &counts);
    json_t *jobs = json_object();
    for (int st = 0; st < JOB_STATE_COUNT; st++)
        json_object_set_new(jobs, job_state_name((job_state)st),
                            json_integer(counts.by_state[st]));

    json_t *info = json_pack("{s:s, s:b, s:o, s:o, s:o, s:[ss], s:I, s:o, s:I}", "version",
                             NS_VERSION, "ready", srv->ctx != NULL, "device", device_json(srv),
                             "limits", limits, "methods", methods_json(), "formats", "image/png",
                             "image/x-exr", "queue_length", (json_int_t)counts.admitted, "jobs",
                             jobs, "job_store_bytes_used", (json_int_t)counts.bytes);
    if (info)
        json_object_set_new(info, "instance",
                            srv->instance ? json_string(srv->instance) : json_null());
    return info;
}

static enum MHD_Result send_shutting_down(struct MHD_Connection *conn);

static enum MHD_Result answer_readyz(struct MHD_Connection *conn, http_server *srv)
{
    if (atomic_load(&srv->stopping))
        return send_shutting_down(conn);
    if (srv->ctx)
        return send_json(
            conn, 200, "application/json",
            json_pack("{s:s, s:s}", "status", "ready", "device", srv->device.device_name), NULL);
    return send_problem_json(conn, no_context_problem(srv), NULL);
}

/* GET /metrics: the registry's counters and the gauges of this moment (metrics.h). */
static enum MHD_Result answer_metrics(struct MHD_Connection *conn, http_server *srv)
{
    metrics_scrape_desc desc = {.ctx = srv->ctx,
                                .device = srv->ctx ? &srv->device : NULL,
                                .jobs = srv->jobs,
                                .queue_capacity = srv->queue_capacity,
                                .job_store_capacity_bytes = srv->job_bytes,
                                .event_streams = (uint32_t)atomic_load(&srv->event_streams)};
    char *text = NULL;
    size_t size = 0;
    if (metrics_render_text(&desc, &text, &size))
        return send_out_of_memory(conn);
    static const char *const headers[] = {"Cache-Control", "no-store", NULL};
    return send_bytes(conn, 200, METRICS_CONTENT_TYPE, text, size, MHD_RESPMEM_MUST_FREE, headers);
}

/* GET /openapi.json: the embedded OpenAPI document. It changes only with the binary, so a
 * client may keep it and revalidate (no-cache), as for the page. */
static enum MHD_Result answer_openapi(struct MHD_Connection *conn)
{
    static const char *const headers[] = {"Cache-Control", "no-cache", NULL};
    return send_bytes(conn, 200, OPENAPI_CONTENT_TYPE, (void *)openapi_json, openapi_json_size,
                      MHD_RESPMEM_PERSISTENT, headers);
}

/* GET / and GET /<file>: the embedded web page. */
static enum MHD_Result answer_web(struct MHD_Connection *conn, const char *url)
{
    const char *name = strcmp(url, "/") ? url + 1 : "index.html";
    const web_asset *asset = strchr(name, '/') ? NULL : web_asset_find(name);
    if (!asset)
        return send_problem_json(conn, problemf(PROBLEM_NOT_FOUND, "no resource at %s", url), NULL);
    static const char *const headers[] = {"Cache-Control", "no-cache", NULL};
    return send_bytes(conn, 200, asset->content_type, (void *)asset->data, asset->size,
                      MHD_RESPMEM_PERSISTENT, headers);
}

/* ---------------------------------------------------------------------------------------
 * What the request line and headers decide: query, Prefer, Accept, Content-Type.
 * ------------------------------------------------------------------------------------- */
/* The query of a render or job request: format=half|float where an image is answered,
 * last_event_id=N on an event stream; any other parameter is an error there (a misspelt
 * option must not be ignored silently). The health, info and web routes do not look. */
typedef struct query_check {
    http_route route;
    int post;
    int half, has_format;
    int has_last_event_id;
    uint64_t last_event_id;
    char problem[256];
} query_check;

/* Routes whose POST carries a scene (or a sweep) to read. */
static int route_takes_body(http_route route)
{
    return route == ROUTE_RENDERS || route == ROUTE_SWEEPS || route == ROUTE_VALIDATE;
}

/* Routes that answer an image: a synchronous render, a job's image. */
static int route_has_image(http_route route, int post)
{
    return (route == ROUTE_RENDERS && post) || route == ROUTE_RENDER_IMAGE ||
           route == ROUTE_SWEEP_IMAGE;
}

static int route_is_events(http_route route)
{
    return route == ROUTE_RENDER_EVENTS || route == ROUTE_SWEEP_EVENTS;
}

/* The routes of one job: /v1/renders/{id}... and /v1/sweeps/{id}... */
static int route_is_job(http_route route)
{
    return route == ROUTE_RENDER_JOB || route == ROUTE_RENDER_IMAGE ||
           route == ROUTE_RENDER_EVENTS || route == ROUTE_SWEEP_JOB || route == ROUTE_SWEEP_IMAGE ||
           route == ROUTE_SWEEP_SHEET || route == ROUTE_SWEEP_MANIFEST || route == ROUTE_SWEEP_EVENTS;
}

static int route_is_sweep_job(http_route route)
{
    return route == ROUTE_SWEEP_JOB || route == ROUTE_SWEEP_IMAGE || route == ROUTE_SWEEP_SHEET ||
           route == ROUTE_SWEEP_MANIFEST || route == ROUTE_SWEEP_EVENTS;
}

static enum MHD_Result check_query_arg(void *cls, enum MHD_ValueKind kind, const char *key,
                                       const char *value)
{
    (void)kind;
    query_check *q = cls;
    if (q->problem[0])
        return MHD_YES;
    int events = route_is_events(q->route);
    int image = route_has_image(q->route, q->post);
    if (image && !strcmp(key, "format")) {
        if (value && (!strcmp(value, "half") || !strcmp(value, "float"))) {
            q->half = !strcmp(value, "half");
            q->has_format = 1;
        } else {
            snprintf(q->problem, sizeof q->problem,
                     "query parameter format=%.64s: use format=half or format=float",
                     value ? value : "");
        }
    } else if (events && !strcmp(key, "last_event_id")) {
        if (!value || parse_header_number(value, 0, &q->last_event_id, NULL))
            snprintf(q->problem, sizeof q->problem,
                     "query parameter last_event_id=%.64s: an event id is a whole number",
                     value ? value : "");
        q->has_last_event_id = 1;
    } else {
        snprintf(q->problem, sizeof q->problem, "unknown query parameter '%.64s'%s", key,
                 image    ? " (only format=half|float)"
                 : events ? " (only last_event_id=N)"
                          : " (this resource takes none)");
    }
    return MHD_YES;
}

/* "Prefer: respond-async" (RFC 7240): one of the comma-separated preferences, any case,
 * possibly with parameters. */
static int prefers_async(struct MHD_Connection *conn)
{
    const char *prefer = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Prefer");
    for (const char *s = prefer; s && *s;) {
        const char *comma = strchr(s, ',');
        const char *end = comma ? comma : s + strlen(s);
        const char *stop = end;
        for (const char *c = s; c < end; c++)
            if (*c == ';' || *c == '=') {
                stop = c;
                break;
            }
        char token[32];
        copy_trimmed_lower(s, stop, token, sizeof token);
        if (!strcmp(token, "respond-async"))
            return 1;
        s = comma ? comma + 1 : end;
    }
    return 0;
}

/* The image format from Accept and the query (shared by POST /v1/renders and the image
 * routes of jobs): returns a problem, or NULL and *format. */
static json_t *negotiate_image(struct MHD_Connection *conn, const query_check *query,
                               encode_format *format)
{
    const char *accept = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, MHD_HTTP_HEADER_ACCEPT);
    char exr_param[32];
    if (negotiate_format(accept, format, exr_param, sizeof exr_param))
        return problemf(PROBLEM_NOT_ACCEPTABLE,
                        "Accept '%.200s' allows neither image/png nor image/x-exr", accept);
    if (exr_param[0] && strcmp(exr_param, "half") && strcmp(exr_param, "float"))
        return problemf(PROBLEM_NOT_ACCEPTABLE,
                        "Accept image/x-exr; format=%s: use format=half or format=float",
                        exr_param);
    int half = query->has_format ? query->half : !strcmp(exr_param, "half");
    if ((query->has_format || exr_param[0]) && *format == ENCODE_PNG)
        return problem_new(PROBLEM_BAD_QUERY, "format=half|float applies to image/x-exr; the "
                                              "Accept header selected image/png");
    if (*format != ENCODE_PNG && half)
        *format = ENCODE_EXR_HALF;
    return NULL;
}

/* Decides what the headers alone can: returns a problem to answer with, or NULL with the
 * request's format, async flag and last event id filled. */
static json_t *check_headers(struct MHD_Connection *conn, const http_server *srv,
                             http_request *req, const char *method)
{
    int post = !strcmp(method, MHD_HTTP_METHOD_POST);
    query_check query = {.route = req->route, .post = post};
    MHD_get_connection_values(conn, MHD_GET_ARGUMENT_KIND, check_query_arg, &query);
    if (post) {
        const char *type =
            MHD_lookup_connection_value(conn, MHD_HEADER_KIND, MHD_HTTP_HEADER_CONTENT_TYPE);
        if (!content_type_is_json(type))
            return problemf(PROBLEM_UNSUPPORTED_MEDIA_TYPE,
                            "Content-Type must be application/json (charset utf-8), got '%.100s'",
                            type ? type : "(none)");
        req->async = req->route == ROUTE_SWEEPS || (req->route == ROUTE_RENDERS && prefers_async(conn));
    }
    if (query.problem[0])
        return problem_new(PROBLEM_BAD_QUERY, query.problem);
    if (req->route == ROUTE_RENDERS && post && req->async && query.has_format)
        return problem_new(PROBLEM_BAD_QUERY, "format=half|float is chosen when the image of an "
                                              "asynchronous render is fetched: "
                                              "GET /v1/renders/{id}/image?format=half");
    /* An image is negotiated where it is answered: a synchronous render, or a job's image. */
    if (route_has_image(req->route, post) && !(req->route == ROUTE_RENDERS && req->async)) {
        json_t *p = negotiate_image(conn, &query, &req->format);
        if (p)
            return p;
    }
    if (query.has_last_event_id)
        req->last_event_id = query.last_event_id;
    const char *last = route_is_events(req->route)
                           ? MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Last-Event-ID")
                           : NULL;
    if (last && !query.has_last_event_id && parse_header_number(last, 0, &req->last_event_id, NULL))
        return problemf(PROBLEM_BAD_QUERY, "Last-Event-ID '%.64s' is not an event id (a whole "
                                           "number)", last);
    /* Validation renders nothing, so it answers without a render context too. */
    if (post && !srv->ctx && req->route != ROUTE_VALIDATE)
        return no_context_problem(srv);
    return NULL;
}

/* Appends upload data; past the limit the body is dropped and the rest drained. */
static void collect_body(const http_server *srv, http_request *req, const char *data, size_t n)
{
    if (req->early_problem || req->too_large || !route_takes_body(req->route)) {
        req->drained += n;
        return;
    }
    if ((uint64_t)req->size + n > srv->max_body) {
        req->too_large = 1;
        free(req->body);
        req->body = NULL;
        req->drained += req->size + n;
        req->size = req->cap = 0;
        return;
    }
    if (req->size + n + 1 > req->cap) {
        size_t cap = req->cap ? req->cap : 64 * 1024;
        while (cap < req->size + n + 1)
            cap *= 2;
        char *grown = realloc(req->body, cap);
        if (!grown) {
            req->early_problem =
                problem_from_status(PROBLEM_STATUS_UNAVAILABLE, NS_ERR_OUT_OF_HOST_MEMORY,
                                    "out of memory while reading the request body");
            free(req->body);
            req->body = NULL;
            req->size = req->cap = 0;
            return;
        }
        req->body = grown;
        req->cap = cap;
    }
    memcpy(req->body + req->size, data, n);
    req->size += n;
    req->body[req->size] = 0;
}

static json_t *issues_problem(const scene_issues *issues)
{
    if (issues->syntax_error) {
        const char *what = issues->count ? issues->items[0].detail : "not valid JSON";
        /* The parser's detail normally names the position already; never lose it. */
        char detail[600];
        if (strstr(what, "line"))
            snprintf(detail, sizeof detail, "%s", what);
        else
            snprintf(detail, sizeof detail, "line %d, column %d: %s", issues->line, issues->column,
                     what);
        json_t *p = problem_new(PROBLEM_MALFORMED_JSON, detail);
        json_object_set_new(p, "line", json_integer(issues->line));
        json_object_set_new(p, "column", json_integer(issues->column));
        problem_add_error(p, issues->count ? issues->items[0].pointer : "", detail);
        return p;
    }
    json_t *p;
    if (issues->count)
        p = problemf(PROBLEM_INVALID_SCENE, "the scene has %u problem%s; first: %s: %s",
                     issues->total, issues->total == 1 ? "" : "s",
                     issues->items[0].pointer[0] ? issues->items[0].pointer : "(document)",
                     issues->items[0].detail);
    else
        p = problem_new(PROBLEM_INVALID_SCENE, "the scene is not valid");
    for (uint32_t i = 0; i < issues->count && i < SCENE_MAX_ISSUES; i++)
        problem_add_error(p, issues->items[i].pointer, issues->items[i].detail);
    return p;
}

/* "parse;dur=1.234, queue;dur=0.012, ..." — metric names are HTTP tokens. */
static void server_timing(const ns_render_stats *stats, char *out, size_t cap)
{
    size_t at = 0;
    out[0] = 0;
    for (uint32_t i = 0; i < stats->stage_count && i < NS_MAX_STAGES; i++) {
        char name[32];
        size_t n = 0;
        for (const char *c = stats->stages[i].name; *c && n + 1 < sizeof name; c++)
            name[n++] = (char)((*c >= 'a' && *c <= 'z') || (*c >= 'A' && *c <= 'Z') ||
                                       (*c >= '0' && *c <= '9') || *c == '_' || *c == '-'
                                   ? *c
                                   : '_');
        name[n] = 0;
        if (!n)
            continue;
        int w = snprintf(out + at, cap - at, "%s%s;dur=%.3f", at ? ", " : "", name,
                         stats->stages[i].ms);
        if (w < 0 || (size_t)w >= cap - at) {
            out[at] = 0; /* drop a metric that did not fit whole */
            break;
        }
        at += (size_t)w;
    }
}

/* Header values must not carry control characters; a device name is plain text anyway. */
static void header_safe(const char *in, char *out, size_t cap)
{
    size_t n = 0;
    for (; in && *in && n + 1 < cap; in++)
        out[n++] = (*in >= 32 && *in < 127) ? *in : '?';
    out[n] = 0;
}

/* The answer of a full queue: 503 with Retry-After. */
static enum MHD_Result send_queue_full(struct MHD_Connection *conn, const http_server *srv,
                                       uint32_t retry_after)
{
    char seconds[16];
    snprintf(seconds, sizeof seconds, "%u", retry_after);
    const char *headers[] = {MHD_HTTP_HEADER_RETRY_AFTER, seconds, NULL};
    json_t *p = problemf(PROBLEM_QUEUE_FULL,
                         "%u render%s already admitted (queue capacity); retry in %s s",
                         srv->queue_capacity, srv->queue_capacity == 1 ? "" : "s", seconds);
    return send_problem_json(conn, p, headers);
}

/* A stop signal came: no new renders (docs/http.md, "Running the service"). */
static enum MHD_Result send_shutting_down(struct MHD_Connection *conn)
{
    const char *headers[] = {MHD_HTTP_HEADER_RETRY_AFTER, "5", NULL};
    return send_problem_json(conn,
                             problemf(PROBLEM_SHUTTING_DOWN,
                                      "the service is stopping: it finishes what it admitted "
                                      "and takes nothing new; retry on another instance"),
                             headers);
}

/* An encoded image with the headers every image answer carries. */
static enum MHD_Result send_image(struct MHD_Connection *conn, const http_server *srv,
                                  encode_format format, encode_buffer *image,
                                  const ns_render_stats *stats)
{
    char device[256], timing[1024];
    header_safe(srv->device.device_name, device, sizeof device);
    server_timing(stats, timing, sizeof timing);
    json_t *counts_json = render_stats_counts_json(stats);
    char *counts = json_dumps(counts_json, JSON_COMPACT);
    json_decref(counts_json);
    const char *headers[] = {"Server-Timing", timing, HTTP_DEVICE_HEADER, device, HTTP_STATS_HEADER,
                             counts ? counts : "{}", "Cache-Control", "no-store", NULL};
    if (current_request && !current_request->stages)
        current_request->stages = render_stats_stages_json(stats);
    /* MHD frees the image with free() once sent (or when the client is gone). */
    enum MHD_Result ret = send_bytes(conn, 200, encode_mime_type(format), image->data, image->size,
                                     MHD_RESPMEM_MUST_FREE, headers);
    image->data = NULL;
    free(counts);
    return ret;
}

/* A synchronous render's client is gone when its socket reads end-of-file (or an error):
 * peeked without consuming, so a pipelined next request stays where it is. */
static int client_gone(void *user)
{
    struct MHD_Connection *conn = user;
    const union MHD_ConnectionInfo *info =
        MHD_get_connection_info(conn, MHD_CONNECTION_INFO_CONNECTION_FD);
    if (!info)
        return 0;
    char byte;
    ssize_t n = recv(info->connect_fd, &byte, 1, MSG_PEEK | MSG_DONTWAIT);
    return n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR);
}

/* A job's description, with Location when it was just made. */
static enum MHD_Result send_job(struct MHD_Connection *conn, http_server *srv, job *j, int status,
                                int created)
{
    json_t *body = job_json(srv->jobs, j);
    const char *self = json_string_value(json_object_get(json_object_get(body, "links"), "self"));
    char location[96];
    snprintf(location, sizeof location, "%s", self ? self : "");
    const char *headers[] = {MHD_HTTP_HEADER_LOCATION, location, "Preference-Applied",
                             "respond-async", "Cache-Control", "no-store", NULL};
    const char *plain[] = {"Cache-Control", "no-store", NULL};
    return send_json(conn, status, "application/json", body, created ? headers : plain);
}

/* An asynchronous result is kept as linear float RGB; one larger than the store's whole
 * byte budget would be dropped the moment it finished, so it is refused up front. */
static json_t *over_job_budget(const http_server *srv, uint64_t pixels, const char *what)
{
    uint64_t bytes = pixels * 3 * sizeof(float);
    if (bytes <= srv->job_bytes)
        return NULL;
    return status_problemf(problem_kind_of_status(NS_ERR_LIMIT), NS_ERR_LIMIT,
                           "%s would keep %llu bytes of images, more than the service keeps for "
                           "all jobs together (%llu, --job-bytes); render fewer or smaller images",
                           what, (unsigned long long)bytes, (unsigned long long)srv->job_bytes);
}

/* Parses the request's scene (timed as the "parse" stage into *stats) and drops the body,
 * which should not sit in memory while the render waits. Returns NULL and *doc, or the
 * problem to answer with. */
static json_t *parse_scene_body(http_server *srv, http_request *req, scene_doc **doc,
                                ns_render_stats *stats)
{
    memset(stats, 0, sizeof *stats);
    *doc = NULL;
    double t0 = ns_now_ms();
    scene_issues *issues = calloc(1, sizeof *issues);
    if (!issues)
        return problem_from_status(PROBLEM_STATUS_UNAVAILABLE, NS_ERR_OUT_OF_HOST_MEMORY,
                                   "out of memory");
    int rc = scene_parse(req->body ? req->body : "", req->size,
                         &srv->parse_opts, doc, issues);
    ns_stats_add_stage(stats, "parse", ns_now_ms() - t0);
    json_t *p = NULL;
    if (rc)
        p = rc == NS_ERR_INVALID_ARGUMENT ? issues_problem(issues)
                                          : problem_from_status(problem_kind_of_status(rc), rc,
                                                                ns_status_message(rc));
    free(issues);
    free(req->body);
    req->body = NULL;
    req->size = req->cap = 0;
    return p;
}

/* POST /v1/renders/validate: every check a render makes before it renders, and nothing
 * more: 204, or the problem the render would have answered with. */
static enum MHD_Result answer_validate(struct MHD_Connection *conn, http_server *srv,
                                       http_request *req)
{
    ns_render_stats stats;
    scene_doc *doc = NULL;
    json_t *p = parse_scene_body(srv, req, &doc, &stats);
    scene_doc_free(doc);
    if (p)
        return send_problem_json(conn, p, NULL);
    return send_bytes(conn, 204, "application/json", "", 0, MHD_RESPMEM_PERSISTENT, NULL);
}

static enum MHD_Result answer_render(struct MHD_Connection *conn, http_server *srv,
                                     http_request *req)
{
    ns_render_stats stats;
    scene_doc *doc = NULL;
    json_t *problem = parse_scene_body(srv, req, &doc, &stats);
    if (problem)
        return send_problem_json(conn, problem, NULL);
    int rc;

    if (atomic_load(&srv->stopping)) {
        scene_doc_free(doc);
        return send_shutting_down(conn);
    }
    const ns_scene *scene = scene_doc_scene(doc);
    json_t *over = req->async ? over_job_budget(srv, (uint64_t)scene->camera.width *
                                                         scene->camera.height,
                                                "the render")
                              : NULL;
    if (over) {
        scene_doc_free(doc);
        return send_problem_json(conn, over, NULL);
    }
    uint32_t retry_after = 1;
    job *j = NULL;
    /* A synchronous render counts until the completion callback, so shutdown can wait for
     * the answer to be sent, not only rendered. Counted BEFORE the job becomes visible in
     * the queue: a signal arriving between the two must not find an admitted render
     * uncounted. */
    if (!req->async) {
        atomic_fetch_add(&srv->renders_in_flight, 1);
        req->counted_in = srv;
    }
    rc = job_submit_render(srv->jobs, doc, req->async, req->format, &stats, &j, &retry_after);
    if (rc) {
        if (!req->async) {
            atomic_fetch_sub(&srv->renders_in_flight, 1);
            req->counted_in = NULL;
        }
        scene_doc_free(doc);
        if (rc == NS_ERR_LIMIT)
            return send_queue_full(conn, srv, retry_after);
        return send_out_of_memory(conn);
    }
    if (req->async) {
        enum MHD_Result ret = send_job(conn, srv, j, 202, 1);
        job_release(srv->jobs, j);
        return ret;
    }
    job_wait(srv->jobs, j, client_gone, conn);
    encode_buffer image = {0};
    ns_error err = {0};
    rc = job_take_sync_result(srv->jobs, j, &image, &stats, &err);
    job_release(srv->jobs, j);
    if (rc == NS_ERR_CANCELLED) /* nobody is there to answer */
        return MHD_NO;
    if (rc) {
        char device[256];
        header_safe(srv->device.device_name, device, sizeof device);
        json_t *p = status_problemf(problem_kind_of_status(rc), rc, "%s",
                                    err.message[0] ? err.message : ns_status_message(rc));
        const char *headers[] = {HTTP_DEVICE_HEADER, device, NULL};
        return send_problem_json(conn, p, headers);
    }
    return send_image(conn, srv, req->format, &image, &stats);
}

/* ---------------------------------------------------------------------------------------
 * Sweeps and the routes of jobs.
 * ------------------------------------------------------------------------------------- */
static enum MHD_Result answer_sweep_post(struct MHD_Connection *conn, http_server *srv,
                                         http_request *req)
{
    ns_render_stats stats;
    memset(&stats, 0, sizeof stats);
    double t0 = ns_now_ms();
    sweep *sw = NULL;
    json_t *problem = NULL;
    sweep_parse(req->body, req->size, &srv->parse_opts, &sw,
                &problem);
    ns_stats_add_stage(&stats, "parse", ns_now_ms() - t0);
    if (!sw)
        return send_problem_json(conn, problem, NULL);
    json_t *over = over_job_budget(srv, sweep_pixels(sw), "the sweep");
    if (over) {
        sweep_free(sw);
        return send_problem_json(conn, over, NULL);
    }
    free(req->body);
    req->body = NULL;
    req->size = req->cap = 0;
    uint32_t retry_after = 1;
    job *j = NULL;
    int rc = job_submit_sweep(srv->jobs, sw, &stats, &j, &retry_after);
    if (rc) {
        sweep_free(sw);
        return rc == NS_ERR_LIMIT ? send_queue_full(conn, srv, retry_after)
                                  : send_out_of_memory(conn);
    }
    enum MHD_Result ret = send_job(conn, srv, j, 202, 1);
    job_release(srv->jobs, j);
    return ret;
}

/* The event stream of one job (text/event-stream), read by MHD from its connection thread:
 * it blocks there until events come, sending a keep-alive comment after a quiet while, and
 * looks at the socket every second so that a client that went away frees its connection
 * (and thread) then, not at the next write. */
#define HTTP_MAX_EVENT_STREAMS 32u /* of --max-connections: the rest stay for renders */
typedef struct event_stream {
    http_server *srv;
    struct MHD_Connection *conn;
    job *job;
    uint64_t last;
    char *pending;
    size_t pending_size, pending_sent;
    int ended;
} event_stream;

static ssize_t event_stream_read(void *cls, uint64_t pos, char *buf, size_t max)
{
    (void)pos;
    event_stream *es = cls;
    double quiet_since = ns_now_ms();
    while (es->pending_sent == es->pending_size) {
        free(es->pending);
        es->pending = NULL;
        es->pending_size = es->pending_sent = 0;
        if (es->ended)
            return MHD_CONTENT_READER_END_OF_STREAM;
        char *text = NULL;
        if (job_events_wait(es->srv->jobs, es->job, es->last, 1000.0, &text, &es->last,
                            &es->ended))
            return MHD_CONTENT_READER_END_WITH_ERROR;
        if (!text[0] && !es->ended) {
            free(text);
            text = NULL;
            if (client_gone(es->conn))
                return MHD_CONTENT_READER_END_WITH_ERROR;
            if (ns_now_ms() - quiet_since < es->srv->sse_keepalive_s * 1000.0)
                continue;
            if (!(text = strdup(": keep-alive\n\n")))
                return MHD_CONTENT_READER_END_WITH_ERROR;
        }
        es->pending = text;
        es->pending_size = strlen(text);
    }
    size_t n = es->pending_size - es->pending_sent;
    n = n < max ? n : max;
    memcpy(buf, es->pending + es->pending_sent, n);
    es->pending_sent += n;
    return (ssize_t)n;
}

static void event_stream_free(void *cls)
{
    event_stream *es = cls;
    atomic_fetch_sub(&es->srv->event_streams, 1);
    job_release(es->srv->jobs, es->job);
    free(es->pending);
    free(es);
}

static enum MHD_Result answer_events(struct MHD_Connection *conn, http_server *srv, job *j,
                                     uint64_t after)
{
    /* A finished job whose every event the client has seen: 204, which tells an
     * EventSource to stop reconnecting (an empty 200 would start it again and again). */
    char *text = NULL;
    uint64_t last = after;
    int ended = 0;
    if (job_events_wait(srv->jobs, j, after, 0, &text, &last, &ended) == 0 && !text[0] && ended) {
        free(text);
        job_release(srv->jobs, j);
        return send_bytes(conn, 204, "text/event-stream", "", 0, MHD_RESPMEM_PERSISTENT, NULL);
    }
    free(text);
    if (atomic_fetch_add(&srv->event_streams, 1) >= (int)HTTP_MAX_EVENT_STREAMS) {
        atomic_fetch_sub(&srv->event_streams, 1);
        job_release(srv->jobs, j);
        const char *headers[] = {MHD_HTTP_HEADER_RETRY_AFTER, "5", NULL};
        return send_problem_json(conn,
                                 problemf(PROBLEM_TOO_MANY_STREAMS,
                                          "%u event streams are open, the most this service "
                                          "keeps; poll the job instead, or retry",
                                          HTTP_MAX_EVENT_STREAMS),
                                 headers);
    }
    event_stream *es = calloc(1, sizeof *es);
    if (!es) {
        atomic_fetch_sub(&srv->event_streams, 1);
        job_release(srv->jobs, j);
        return send_out_of_memory(conn);
    }
    *es = (event_stream){.srv = srv, .conn = conn, .job = j, .last = after};
    struct MHD_Response *resp = MHD_create_response_from_callback(
        MHD_SIZE_UNKNOWN, 16 * 1024, event_stream_read, es, event_stream_free);
    if (!resp) {
        event_stream_free(es);
        return MHD_NO;
    }
    MHD_add_response_header(resp, MHD_HTTP_HEADER_CONTENT_TYPE, "text/event-stream");
    MHD_add_response_header(resp, "Cache-Control", "no-store");
    MHD_add_response_header(resp, "X-Content-Type-Options", "nosniff");
    /* nginx and other proxies: pass events on as they come. */
    MHD_add_response_header(resp, "X-Accel-Buffering", "no");
    return queue_answer(conn, 200, resp, 0);
}

static enum MHD_Result answer_job_route(struct MHD_Connection *conn, http_server *srv,
                                        http_request *req, const char *method)
{
    if (!srv->jobs)
        return send_problem_json(conn, no_context_problem(srv), NULL);
    int sweep_route = route_is_sweep_job(req->route);
    const char *what = sweep_route ? "sweep" : "render";
    int gone = 0;
    job *j = job_find(srv->jobs, req->job_id, sweep_route ? JOB_SWEEP : JOB_RENDER, &gone);
    if (!j)
        return send_problem_json(
            conn,
            gone ? problemf(PROBLEM_JOB_GONE,
                            "the %s %.40s has expired or was deleted; its results are gone", what,
                            req->job_id)
                 : problemf(PROBLEM_NOT_FOUND, "no %s with id %.40s", what, req->job_id),
            NULL);
    enum MHD_Result ret;
    if (route_is_events(req->route))
        return answer_events(conn, srv, j, req->last_event_id); /* it keeps the reference */
    if ((req->route == ROUTE_RENDER_JOB || req->route == ROUTE_SWEEP_JOB) &&
        !strcmp(method, MHD_HTTP_METHOD_DELETE)) {
        job_cancel_result result = job_cancel(srv->jobs, j);
        if (result == JOB_DISCARDED)
            ret = send_bytes(conn, 204, "application/json", "", 0, MHD_RESPMEM_PERSISTENT, NULL);
        else
            ret = send_job(conn, srv, j, result == JOB_CANCELLED_QUEUED ? 200 : 202, 0);
    } else if (req->route == ROUTE_RENDER_JOB || req->route == ROUTE_SWEEP_JOB) {
        ret = send_job(conn, srv, j, 200, 0);
    } else if (req->route == ROUTE_SWEEP_MANIFEST) {
        ret = send_json(conn, 200, "application/json", job_manifest_json(srv->jobs, j), NULL);
    } else if (req->route == ROUTE_SWEEP_SHEET) {
        encode_buffer sheet = {0};
        ns_error err = {0};
        int rc = job_sweep_sheet(srv->jobs, j, &sheet, &err);
        static const char *const headers[] = {"Cache-Control", "no-store", NULL};
        ret = rc ? send_problem_json(conn,
                                     status_problemf(problem_kind_of_status(rc), rc, "%s",
                                                     err.message),
                                     NULL)
                 : send_bytes(conn, 200, "image/png", sheet.data, sheet.size, MHD_RESPMEM_MUST_FREE,
                              headers);
    } else { /* an image */
        encode_buffer image = {0};
        ns_render_stats stats;
        memset(&stats, 0, sizeof stats);
        job_state state = JOB_QUEUED;
        ns_error err = {0};
        int variant = req->route == ROUTE_SWEEP_IMAGE ? req->variant : -1;
        int rc = job_encode_image(srv->jobs, j, variant, req->format, &image, &stats, &state, &err);
        if (rc == NS_ERR_NOT_AVAILABLE)
            ret = send_problem_json(
                conn,
                problemf(PROBLEM_JOB_NOT_DONE, "the %s%s is %s: its image %s", what,
                         variant >= 0 ? "'s variant" : "", job_state_name(state),
                         state == JOB_QUEUED || state == JOB_RUNNING
                             ? "is not ready yet; follow its events or poll its status"
                             : "does not exist"),
                NULL);
        else if (rc == NS_ERR_INVALID_ARGUMENT)
            ret = send_problem_json(conn,
                                    problemf(PROBLEM_NOT_FOUND, "the sweep %.40s has no variant %d",
                                             req->job_id, variant),
                                    NULL);
        else if (rc)
            ret = send_problem_json(
                conn, status_problemf(problem_kind_of_status(rc), rc, "%s", err.message), NULL);
        else
            ret = send_image(conn, srv, req->format, &image, &stats);
    }
    job_release(srv->jobs, j);
    return ret;
}

/* ---------------------------------------------------------------------------------------
 * Routing and the MHD callbacks.
 * ------------------------------------------------------------------------------------- */
/* Splits "/v1/renders/ID/rest" style paths. Returns the route; fills req's id and variant. */
static http_route route_for(const char *url, http_request *req)
{
    if (!strcmp(url, "/livez"))
        return ROUTE_LIVEZ;
    if (!strcmp(url, "/readyz"))
        return ROUTE_READYZ;
    if (!strcmp(url, "/v1/info"))
        return ROUTE_INFO;
    if (!strcmp(url, "/metrics"))
        return ROUTE_METRICS;
    if (!strcmp(url, "/openapi.json"))
        return ROUTE_OPENAPI;
    if (!strcmp(url, "/v1/renders"))
        return ROUTE_RENDERS;
    if (!strcmp(url, "/v1/sweeps"))
        return ROUTE_SWEEPS;
    if (!strcmp(url, "/v1/renders/validate"))
        return ROUTE_VALIDATE;
    if (!strcmp(url, "/v1/materials"))
        return ROUTE_MATERIALS;
    const char *rest = NULL;
    int sweep_route = 0;
    if (!strncmp(url, "/v1/renders/", 12))
        rest = url + 12;
    else if (!strncmp(url, "/v1/sweeps/", 11))
        rest = url + 11, sweep_route = 1;
    if (rest) {
        const char *slash = strchr(rest, '/');
        size_t len = slash ? (size_t)(slash - rest) : strlen(rest);
        if (len == 0 || len >= sizeof req->job_id)
            return ROUTE_NONE;
        memcpy(req->job_id, rest, len);
        req->job_id[len] = 0;
        const char *tail = slash ? slash : "";
        if (!*tail)
            return sweep_route ? ROUTE_SWEEP_JOB : ROUTE_RENDER_JOB;
        if (!strcmp(tail, "/events"))
            return sweep_route ? ROUTE_SWEEP_EVENTS : ROUTE_RENDER_EVENTS;
        if (!sweep_route)
            return !strcmp(tail, "/image") ? ROUTE_RENDER_IMAGE : ROUTE_NONE;
        if (!strcmp(tail, "/sheet.png"))
            return ROUTE_SWEEP_SHEET;
        if (!strcmp(tail, "/manifest.json"))
            return ROUTE_SWEEP_MANIFEST;
        if (!strncmp(tail, "/images/", 8)) {
            uint64_t n = 0;
            const char *digits = tail + 8;
            size_t count = strspn(digits, "0123456789");
            if (count == 0 || count > 6 || digits[count] ||
                parse_header_number(digits, 0, &n, NULL))
                return ROUTE_NONE;
            req->variant = (int)n;
            return ROUTE_SWEEP_IMAGE;
        }
        return ROUTE_NONE;
    }
    if (url[0] == '/' && !strchr(url + 1, '/'))
        return ROUTE_WEB;
    return ROUTE_NONE;
}

static enum MHD_Result answer_get(struct MHD_Connection *conn, http_server *srv, http_route route,
                                  const char *url)
{
    switch (route) {
    case ROUTE_LIVEZ:
        return send_json(conn, 200, "application/json", json_pack("{s:s}", "status", "alive"),
                         NULL);
    case ROUTE_READYZ:
        return answer_readyz(conn, srv);
    case ROUTE_INFO:
        return send_json(conn, 200, "application/json", info_json(srv), NULL);
    case ROUTE_MATERIALS:
        return send_json(conn, 200, "application/json", materials_json(), NULL);
    case ROUTE_METRICS:
        return answer_metrics(conn, srv);
    case ROUTE_OPENAPI:
        return answer_openapi(conn);
    case ROUTE_RENDERS:
    case ROUTE_SWEEPS:
        if (!srv->jobs)
            return send_problem_json(conn, no_context_problem(srv), NULL);
        return send_json(conn, 200, "application/json",
                         json_pack("{s:o}", "jobs",
                                   job_list_json(srv->jobs,
                                                 route == ROUTE_RENDERS ? JOB_RENDER : JOB_SWEEP)),
                         NULL);
    default:
        return answer_web(conn, url);
    }
}

/* The methods each route takes, as its Allow header says. */
static const char *route_allow(http_route route)
{
    switch (route) {
    case ROUTE_RENDERS:
    case ROUTE_SWEEPS:
        return "GET, HEAD, POST";
    case ROUTE_RENDER_JOB:
    case ROUTE_SWEEP_JOB:
        return "GET, HEAD, DELETE";
    case ROUTE_VALIDATE:
        return "POST";
    default:
        return "GET, HEAD";
    }
}

/* The route as a template, for logs and metrics: never the id itself. */
static const char *route_name(http_route route)
{
    static const char *const names[] = {
        [ROUTE_NONE] = "other",
        [ROUTE_LIVEZ] = "/livez",
        [ROUTE_READYZ] = "/readyz",
        [ROUTE_INFO] = "/v1/info",
        [ROUTE_METRICS] = "/metrics",
        [ROUTE_OPENAPI] = "/openapi.json",
        [ROUTE_RENDERS] = "/v1/renders",
        [ROUTE_VALIDATE] = "/v1/renders/validate",
        [ROUTE_MATERIALS] = "/v1/materials",
        [ROUTE_RENDER_JOB] = "/v1/renders/{id}",
        [ROUTE_RENDER_IMAGE] = "/v1/renders/{id}/image",
        [ROUTE_RENDER_EVENTS] = "/v1/renders/{id}/events",
        [ROUTE_SWEEPS] = "/v1/sweeps",
        [ROUTE_SWEEP_JOB] = "/v1/sweeps/{id}",
        [ROUTE_SWEEP_IMAGE] = "/v1/sweeps/{id}/images/{n}",
        [ROUTE_SWEEP_SHEET] = "/v1/sweeps/{id}/sheet.png",
        [ROUTE_SWEEP_MANIFEST] = "/v1/sweeps/{id}/manifest.json",
        [ROUTE_SWEEP_EVENTS] = "/v1/sweeps/{id}/events",
        [ROUTE_WEB] = "/{file}",
    };
    return (unsigned)route < sizeof names / sizeof names[0] && names[route] ? names[route] : "other";
}

/* Whether `method` is one of the comma-separated `methods`. */
static int method_listed(const char *methods, const char *method)
{
    size_t n = strlen(method);
    for (const char *s = methods; (s = strstr(s, method)); s += n)
        if ((s == methods || s[-1] == ' ') && (s[n] == 0 || s[n] == ','))
            return 1;
    return 0;
}

/* Decides what the request line alone can: a problem (404, 405) with its Allow header, or
 * NULL when the route takes this method. */
static json_t *check_route(http_route route, const char *url, const char *method,
                           const char **allow)
{
    *allow = NULL;
    if (route == ROUTE_NONE)
        return problemf(PROBLEM_NOT_FOUND, "no resource at %.200s", url);
    const char *methods = route_allow(route);
    if (method_listed(methods, method))
        return NULL;
    *allow = methods;
    return problemf(PROBLEM_METHOD_NOT_ALLOWED, "%.16s is not allowed on %.200s; use %s", method,
                    url, methods);
}

/* The first callback of a request: everything the request line and headers decide. The
 * answer itself waits for the last callback (after any body has been read and dropped), so
 * the connection stays usable; only a body declared too large is refused at once. */
/* X-Request-Id: the client's when it is a plain token (1 to 128 of A-Z a-z 0-9 . _ : -),
 * so that one id follows a request through proxies and logs; else 128 random bits. */
static void request_id_of(struct MHD_Connection *conn, char *out, size_t cap)
{
    const char *given = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "X-Request-Id");
    size_t n = given ? strlen(given) : 0;
    if (n >= 1 && n <= 128 && n < cap &&
        strspn(given, "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789._:-") == n) {
        memcpy(out, given, n + 1);
        return;
    }
    unsigned char bytes[16] = {0};
    size_t got = 0;
    while (got < sizeof bytes) {
        ssize_t r = getrandom(bytes + got, sizeof bytes - got, 0);
        if (r <= 0)
            break; /* an id of zeros, still an id */
        got += (size_t)r;
    }
    for (size_t i = 0; i < sizeof bytes && 2 * i + 2 < cap; i++)
        snprintf(out + 2 * i, 3, "%02x", bytes[i]);
}

/* The first callback of a request: everything the request line and headers decide. The
 * answer itself waits for the last callback (after any body has been read and dropped), so
 * the connection stays usable; only what must not read the body is answered at once: a body
 * declared too large, and a render or sweep that the service cannot admit now (stopping, or
 * the queue full), so that a client is not made to upload a large scene to hear 503. */
static enum MHD_Result first_call(struct MHD_Connection *conn, http_server *srv, const char *url,
                                  const char *method, void **con_cls)
{
    http_request *req = calloc(1, sizeof *req);
    if (!req)
        return MHD_NO;
    *con_cls = req;
    current_request = req;
    req->started_ms = ns_now_ms();
    req->instance = srv->instance;
    request_id_of(conn, req->request_id, sizeof req->request_id);
    snprintf(req->method, sizeof req->method, "%s", method);
    snprintf(req->path, sizeof req->path, "%s", url);
    http_route route = route_for(url, req);
    req->route = route;
    json_t *framing = framing_problem(conn);
    if (framing) {
        req->answered = 1;
        /* Without reading the body, whose end is not known: MHD then closes the connection. */
        return send_problem_json(conn, framing, NULL);
    }
    req->early_problem = check_route(route, url, method, &req->allow);
    if (req->early_problem)
        return MHD_YES;
    int post = !strcmp(method, MHD_HTTP_METHOD_POST);
    long long length = content_length(conn);
    if (route_takes_body(route) && post && length > 0 &&
        (unsigned long long)length > srv->max_body) {
        req->answered = 1;
        /* Without reading a byte of the body: MHD then closes the connection. */
        return send_problem_json(conn,
                                 problemf(PROBLEM_BODY_TOO_LARGE,
                                          "Content-Length %lld is over the limit of %llu bytes",
                                          length, (unsigned long long)srv->max_body),
                                 NULL);
    }
    if (post && (route == ROUTE_RENDERS || route == ROUTE_SWEEPS) && srv->jobs) {
        uint32_t retry_after = 1;
        if (atomic_load(&srv->stopping)) {
            req->answered = 1;
            return send_shutting_down(conn);
        }
        if (job_store_full(srv->jobs, &retry_after)) {
            req->answered = 1;
            return send_queue_full(conn, srv, retry_after);
        }
    }
    if (route != ROUTE_WEB && route != ROUTE_LIVEZ && route != ROUTE_READYZ &&
        route != ROUTE_INFO && route != ROUTE_MATERIALS)
        req->early_problem = check_headers(conn, srv, req, method);
    return MHD_YES;
}

/* One JSON line per request on stderr, written with one write() so that lines of
 * concurrent requests do not interleave. */
static void access_log(const http_request *req)
{
    struct timespec now;
    clock_gettime(CLOCK_REALTIME, &now);
    struct tm tm;
    gmtime_r(&now.tv_sec, &tm);
    char when[40];
    size_t n = strftime(when, sizeof when, "%Y-%m-%dT%H:%M:%S", &tm);
    snprintf(when + n, sizeof when - n, ".%03ldZ", now.tv_nsec / 1000000);
    json_t *line = json_pack("{s:s, s:s, s:s, s:s, s:s, s:i, s:I, s:f}", "time", when,
                             "request_id", req->request_id, "method", req->method, "path",
                             req->path, "route", route_name(req->route), "status", req->status,
                             "bytes", (json_int_t)req->bytes, "duration_ms",
                             ns_now_ms() - req->started_ms);
    if (line && req->stages)
        json_object_set(line, "stages", req->stages);
    char *text = line ? json_dumps(line, JSON_COMPACT | JSON_REAL_PRECISION(6)) : NULL;
    json_decref(line);
    if (!text)
        return;
    size_t len = strlen(text);
    char *with_newline = realloc(text, len + 2);
    if (with_newline) {
        text = with_newline;
        text[len++] = '\n';
        text[len] = 0;
        ssize_t written = write(STDERR_FILENO, text, len);
        (void)written; /* nothing to do about a log that cannot be written */
    }
    free(text);
}

static enum MHD_Result http_handler(void *cls, struct MHD_Connection *conn, const char *url,
                                    const char *method, const char *version,
                                    const char *upload_data, size_t *upload_data_size,
                                    void **con_cls)
{
    (void)version;
    http_server *srv = cls;
    http_request *req = *con_cls;
    if (!req) {
        guard_phase(conn, CONN_BODY);
        enum MHD_Result ret = first_call(conn, srv, url, method, con_cls);
        req = *con_cls;
        if (req && req->answered)
            guard_phase(conn, CONN_BUSY);
        return ret;
    }
    current_request = req;
    if (req->answered) { /* answered without its body, which is not read */
        *upload_data_size = 0;
        return MHD_YES;
    }
    if (*upload_data_size) {
        guard_body_bytes(conn, *upload_data_size);
        collect_body(srv, req, upload_data, *upload_data_size);
        *upload_data_size = 0;
        /* Draining is bounded too: a client that keeps sending past twice the limit after
         * being refused is cut off. */
        if (req->drained > 2 * srv->max_body + (1u << 20))
            return MHD_NO;
        return MHD_YES;
    }
    /* The whole body has arrived. */
    guard_phase(conn, CONN_BUSY);
    if (req->early_problem) {
        json_t *p = req->early_problem;
        req->early_problem = NULL;
        const char *allow[] = {MHD_HTTP_HEADER_ALLOW, req->allow, NULL};
        return send_problem_json(conn, p, req->allow ? allow : NULL);
    }
    int post = !strcmp(method, MHD_HTTP_METHOD_POST);
    if (post && req->too_large)
        return send_problem_json(conn,
                                 problemf(PROBLEM_BODY_TOO_LARGE,
                                          "the request body is over the limit of %llu bytes",
                                          (unsigned long long)srv->max_body),
                                 NULL);
    if (post && req->route == ROUTE_RENDERS)
        return answer_render(conn, srv, req);
    if (post && req->route == ROUTE_SWEEPS)
        return answer_sweep_post(conn, srv, req);
    if (post && req->route == ROUTE_VALIDATE)
        return answer_validate(conn, srv, req);
    if (route_is_job(req->route))
        return answer_job_route(conn, srv, req, method);
    return answer_get(conn, srv, req->route, url);
}

static void http_request_completed(void *cls, struct MHD_Connection *conn, void **con_cls,
                                   enum MHD_RequestTerminationCode toe)
{
    (void)toe;
    guard_phase(conn, CONN_WAITING);
    http_request *req = *con_cls;
    if (!req)
        return;
    http_server *srv = cls;
    if (srv->access_log)
        access_log(req);
    current_request = NULL;
    /* A one-segment path is a file of the page or nothing: a 404 there is no route. */
    metrics_request_done(req->route == ROUTE_WEB && req->status == 404 ? METRICS_OTHER
                                                                        : route_name(req->route),
                         req->method, req->status > 0 ? (unsigned)req->status : 0,
                         (ns_now_ms() - req->started_ms) / 1000.0);
    if (req->counted_in)
        atomic_fetch_sub(&req->counted_in->renders_in_flight, 1);
    json_decref(req->stages);
    json_decref(req->early_problem);
    free(req->body);
    free(req);
    *con_cls = NULL;
}

/* ---------------------------------------------------------------------------------------
 * The service's life: context, queue, daemon, signals, drain.
 * ------------------------------------------------------------------------------------- */
/* Resolves --host to one socket address (numeric or a name such as localhost). */
static int resolve_host(const char *host, unsigned port, struct sockaddr_storage *addr)
{
    struct addrinfo hints = {.ai_family = AF_UNSPEC,
                             .ai_socktype = SOCK_STREAM,
                             .ai_flags = AI_PASSIVE | AI_NUMERICSERV};
    struct addrinfo *res = NULL;
    char port_text[8];
    snprintf(port_text, sizeof port_text, "%u", port);
    int rc = getaddrinfo(host, port_text, &hints, &res);
    if (rc) {
        fprintf(stderr, "nscatter serve: --host '%s': %s\n", host, gai_strerror(rc));
        return -1;
    }
    memset(addr, 0, sizeof *addr);
    memcpy(addr, res->ai_addr, res->ai_addrlen);
    freeaddrinfo(res);
    return 0;
}

static void make_context(http_server *srv, const char *device)
{
    double t0 = ns_now_ms();
    ns_context_desc desc = {.device = device};
    /* Monte Carlo tables for method "table" and the albedo nodes of render.tables
     * "interpolated": cached on disk. */
    ns_table_caches_attach(&desc);
    int rc = ns_context_create(&desc, &srv->ctx, &srv->ctx_err);
    if (rc) {
        srv->ctx = NULL;
        srv->ctx_err.status = rc;
        fprintf(stderr, "nscatter serve: no render context (%s: %s); /readyz answers 503\n",
                ns_status_name(rc), srv->ctx_err.message);
        return;
    }
    ns_context_device_info(srv->ctx, &srv->device);
    fprintf(stderr, "nscatter serve: device %s (%s), ready in %.0f ms\n", srv->device.device_name,
            srv->device.driver_name, ns_now_ms() - t0);
}

/* Graceful stop: no new connections, renders already admitted are finished and answered
 * (for at most HTTP_DRAIN_S, or until a second signal), then every connection is closed.
 * MHD_stop_daemon alone would shut the sockets of requests still waiting for a render. */
#define HTTP_DRAIN_S 120
/* SIGINT and SIGTERM. Threads that nscatter does not make (OpenBLAS starts its pool when the
 * library loads, before http_serve runs) do not block them, and the kernel may deliver a
 * process-directed signal to any thread that does not: so they get a handler, which only
 * writes the signal to a pipe, wherever it runs, and the main thread waits on the pipe. */
static int stop_pipe[2] = {-1, -1};

static void on_stop_signal(int sig)
{
    unsigned char byte = (unsigned char)sig;
    ssize_t written = write(stop_pipe[1], &byte, 1);
    (void)written; /* a full pipe already holds a signal */
}

/* The next stop signal, waiting up to timeout_ms (-1: for ever); 0 when none came. Without
 * the pipe (a service started with http_start, outside http_serve) it only waits: poll()
 * ignores a negative descriptor. */
static int wait_stop_signal(int timeout_ms)
{
    struct pollfd fd = {.fd = stop_pipe[0], .events = POLLIN};
    for (;;) {
        int n = poll(&fd, 1, timeout_ms);
        if (n < 0 && errno == EINTR)
            continue; /* the handler ran on this thread: the byte is in the pipe */
        unsigned char byte = 0;
        if (n > 0 && read(stop_pipe[0], &byte, 1) == 1)
            return byte;
        return 0;
    }
}

static void drain_and_stop(struct MHD_Daemon *daemon, http_server *srv)
{
    atomic_store(&srv->stopping, 1); /* /readyz and new renders answer 503 from now on */
    MHD_socket listen_fd = MHD_quiesce_daemon(daemon);
    if (listen_fd != MHD_INVALID_SOCKET)
        close(listen_fd);
    /* Asynchronous jobs are cancelled (their results would die with the process) and event
     * streams end; synchronous renders are finished and answered. */
    job_store_shutdown(srv->jobs);
    double deadline = ns_now_ms() + HTTP_DRAIN_S * 1000.0;
    while (atomic_load(&srv->renders_in_flight) > 0 && ns_now_ms() < deadline) {
        if (wait_stop_signal(50)) {
            fprintf(stderr, "nscatter serve: second signal, not waiting for renders\n");
            break;
        }
    }
    MHD_stop_daemon(daemon);
}

/* A running service: what http_start made and http_stop ends. */
struct http_service {
    http_server srv;
    struct MHD_Daemon *daemon;
};

int http_start(const http_serve_desc *desc, http_service **out, unsigned *port_out)
{
    *out = NULL;
    http_serve_desc args = *desc;
    if (!args.host)
        args.host = "127.0.0.1";
    if (!args.queue)
        args.queue = HTTP_DEFAULT_QUEUE;
    if (!args.max_body)
        args.max_body = HTTP_DEFAULT_MAX_BODY;
    struct sockaddr_storage addr;
    if (resolve_host(args.host, args.port, &addr))
        return 2;

    /* On the heap: the daemon's threads keep pointing at it after this function returns. */
    http_service *svc = calloc(1, sizeof *svc);
    if (!svc) {
        fprintf(stderr, "nscatter serve: out of memory\n");
        return 1;
    }
    http_server *srv = &svc->srv;
    *srv = (http_server){.max_body = args.max_body,
                         .queue_capacity = args.queue,
                         .asset_dir = args.asset_dir,
                         .instance = args.instance && *args.instance ? args.instance : NULL,
                         .job_ttl_s = args.job_ttl_s ? args.job_ttl_s : JOB_DEFAULT_TTL_S,
                         .job_bytes = args.job_bytes ? args.job_bytes : JOB_DEFAULT_STORE_BYTES,
                         .sse_keepalive_s = args.sse_keepalive_s ? args.sse_keepalive_s
                                                                 : HTTP_DEFAULT_SSE_KEEPALIVE_S,
                         .access_log = !args.no_access_log,
                         .max_deadline_ms = args.max_deadline_ms,
                         .request_timeout_s = args.request_timeout_s ? args.request_timeout_s
                                                                     : HTTP_DEFAULT_REQUEST_TIMEOUT_S,
                         .idle_timeout_s = args.idle_timeout_s ? args.idle_timeout_s
                                                               : HTTP_DEFAULT_IDLE_TIMEOUT_S,
                         .max_connections = args.max_connections ? args.max_connections
                                                                 : HTTP_DEFAULT_MAX_CONNECTIONS,
                         .parse_opts = {.asset_dir = args.asset_dir,
                                        .max_pixels = args.max_pixels,
                                        .max_spp = args.max_spp,
                                        .max_vrls = args.max_vrls,
                                        .max_triangles = args.max_triangles}};
    /* An event stream with nothing to say must speak before the idle timeout cuts it. */
    if (srv->sse_keepalive_s >= srv->idle_timeout_s)
        srv->sse_keepalive_s = srv->idle_timeout_s > 1 ? srv->idle_timeout_s / 2 : 1;
    if (args.no_device) /* the state of a device that could not be made, without Vulkan */
        ns_fail(&srv->ctx_err, NS_ERR_NO_DEVICE, "the service was started without a render device");
    else
        make_context(srv, args.device);
    if (srv->ctx && job_store_create(&(job_store_desc){.ctx = srv->ctx,
                                                       .capacity = args.queue,
                                                       .ttl_s = srv->job_ttl_s,
                                                       .max_bytes = srv->job_bytes,
                                                       .asset_dir = args.asset_dir,
                                                       .max_deadline_ms = args.max_deadline_ms,
                                                       .instance = args.instance,
                                                       .no_idle_work = args.no_idle_work},
                                     &srv->jobs, &srv->ctx_err)) {
        fprintf(stderr, "nscatter serve: %s\n", srv->ctx_err.message);
        ns_context_destroy(srv->ctx);
        free(svc);
        return 1;
    }

    /* ITC lets MHD_quiesce_daemon wake the polling thread at shutdown. */
    unsigned flags = MHD_USE_THREAD_PER_CONNECTION | MHD_USE_INTERNAL_POLLING_THREAD |
                     MHD_USE_ERROR_LOG | MHD_USE_ITC;
    if (addr.ss_family == AF_INET6)
        flags |= MHD_USE_IPv6;
    svc->daemon = MHD_start_daemon(
        flags, (uint16_t)args.port, NULL, NULL, http_handler, srv, MHD_OPTION_SOCK_ADDR,
        (struct sockaddr *)&addr, MHD_OPTION_NOTIFY_COMPLETED, http_request_completed, srv,
        MHD_OPTION_NOTIFY_CONNECTION, guard_notify, NULL, MHD_OPTION_CONNECTION_LIMIT,
        srv->max_connections, MHD_OPTION_CONNECTION_TIMEOUT, srv->idle_timeout_s,
        MHD_OPTION_END);
    if (!svc->daemon) {
        fprintf(stderr, "nscatter serve: cannot listen on %s:%u: %s\n", args.host, args.port,
                strerror(errno));
        job_store_destroy(srv->jobs);
        ns_context_destroy(srv->ctx);
        free(svc);
        return 1;
    }
    const union MHD_DaemonInfo *bound =
        MHD_get_daemon_info(svc->daemon, MHD_DAEMON_INFO_BIND_PORT);
    *port_out = bound && bound->port ? bound->port : args.port;
    *out = svc;
    return 0;
}

void http_stop(http_service *svc)
{
    if (!svc)
        return;
    drain_and_stop(svc->daemon, &svc->srv);
    job_store_destroy(svc->srv.jobs);
    ns_context_destroy(svc->srv.ctx);
    free(svc);
}

unsigned http_connections(const http_service *svc)
{
    const union MHD_DaemonInfo *info =
        MHD_get_daemon_info(svc->daemon, MHD_DAEMON_INFO_CURRENT_CONNECTIONS);
    return info ? info->num_connections : 0;
}

int http_serve(const http_serve_desc *desc)
{
    if (stop_pipe[0] < 0) {
        if (pipe(stop_pipe)) {
            fprintf(stderr, "nscatter serve: pipe: %s\n", strerror(errno));
            return 1;
        }
        for (int i = 0; i < 2; i++) {
            fcntl(stop_pipe[i], F_SETFD, FD_CLOEXEC);
            fcntl(stop_pipe[i], F_SETFL, O_NONBLOCK); /* the handler never blocks */
        }
    }
    struct sigaction on_stop = {.sa_handler = on_stop_signal, .sa_flags = SA_RESTART};
    sigemptyset(&on_stop.sa_mask);
    sigaction(SIGINT, &on_stop, NULL);
    sigaction(SIGTERM, &on_stop, NULL);
    /* Every thread made from here on inherits this mask, so no render or connection thread
     * is interrupted by them. A client that disconnects must not kill the process. */
    sigset_t stop_signals;
    sigemptyset(&stop_signals);
    sigaddset(&stop_signals, SIGINT);
    sigaddset(&stop_signals, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &stop_signals, NULL);
    signal(SIGPIPE, SIG_IGN);

    http_service *svc = NULL;
    unsigned port = 0;
    int rc = http_start(desc, &svc, &port);
    if (rc) {
        pthread_sigmask(SIG_UNBLOCK, &stop_signals, NULL);
        return rc;
    }
    const char *host = desc->host ? desc->host : "127.0.0.1";
    int v6 = strchr(host, ':') != NULL; /* an IPv6 literal needs brackets in a URL */
    printf("listening on http://%s%s%s:%u\n", v6 ? "[" : "", host, v6 ? "]" : "", port);
    fflush(stdout);

    int sig = 0;
    /* The main thread takes the signals now (the handler runs here or on a foreign thread,
     * and either way the pipe has it); the threads nscatter made keep them blocked. */
    pthread_sigmask(SIG_UNBLOCK, &stop_signals, NULL);
    while (!(sig = wait_stop_signal(HTTP_GUARD_PERIOD_MS)))
        guard_sweep(&svc->srv);
    fprintf(stderr, "nscatter serve: %s, shutting down\n", sig == SIGINT ? "SIGINT" : "SIGTERM");
    http_stop(svc);
    return 0;
}
